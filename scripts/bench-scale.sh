#!/usr/bin/env bash
# Speed of `host-sim simulate` end to end (read, simulate, write) on the 20 s conformance
# fixture against the SciPy RK45 peer (scripts/rk45_peer.py: solve_ivp RK45 per sample,
# rtol = atol = 1e-6) on the same file. A benchmark, not a test: run it on an idle machine
# (the load average is printed). 10 runs of host-sim (best, mean and standard deviation; the
# ratio is taken on the best), one run of the peer.
#
# `bash scripts/bench-scale.sh OTHER_HOST_SIM` also times another build of host-sim (e.g. a
# copy of `main`'s target/release/host-sim) in the same script run, its runs alternating
# with this build's, against the same peer run: a before/after under the same load.
# Exit status 1 when host-sim (this build) is less than 500x faster.
#
# --write-docs: also writes the rows to docs/figures/scale.tsv and their table into
# docs/performance.md (scripts/figures.py), the one place the figures are quoted from.
set -euo pipefail
cd "$(dirname "$0")/.."
plant=../shared/plant/reference-1dof.toml
fixture=../shared/conformance/pulses_nominal.csv
write_docs=0
other=
for arg in "$@"; do
  case "$arg" in
    --write-docs) write_docs=1 ;;
    -*) echo "bench-scale.sh: unknown option '$arg' (allowed: --write-docs, OTHER_HOST_SIM)" >&2; exit 2 ;;
    *) other=$arg ;;
  esac
done
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
cargo build -q --release -p host-sim --bin host-sim
load=$(cut -d' ' -f1-3 /proc/loadavg)
echo "load average: $load"
times=$(python3 - "$plant" "$fixture" "$out/sim.csv" target/release/host-sim $other <<'PY'
import statistics, subprocess, sys, time
plant, fixture, dest, *bins = sys.argv[1:]
runs = {b: [] for b in bins}
for _ in range(10):
    for b in bins:
        t0 = time.perf_counter()
        subprocess.run([b, "simulate", "--plant", plant, "--inputs", fixture, "--out", dest],
                       check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        runs[b].append(time.perf_counter() - t0)
print(" ".join(f"{min(r)} {statistics.mean(r)} {statistics.stdev(r)}" for r in runs.values()))
PY
)
peer=$(python3 - "$plant" "$fixture" "$out/peer.csv" <<'PY'
import subprocess, sys, time
t0 = time.perf_counter()
subprocess.run([sys.executable, "scripts/rk45_peer.py", *sys.argv[1:4]], check=True,
               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
print(time.perf_counter() - t0)
PY
)
status=0
tsv=$(python3 - "$peer" "$load" "${other:-}" $times <<'PY'
import sys
peer, load, other = float(sys.argv[1]), sys.argv[2], sys.argv[3]
t = [float(a) for a in sys.argv[4:]]
sim, mean, sd = t[0:3]
ratio = peer / sim
rows = [("key", "figure", "measured", "target", "check"),
        ("load", "load average at the start (1, 5, 15 min)", load, "", ""),
        ("simulate_ms", "host-sim simulate, 20 s fixture end to end, best of 10 (mean, sd)",
         f"{sim * 1e3:.1f} ms ({mean * 1e3:.1f} ms, sd {sd * 1e3:.1f} ms)", "", "")]
if other:
    o_sim, o_mean, o_sd = t[3:6]
    rows.append(("other_ms", f"{other}, alternating with it, best of 10 (mean, sd)",
                 f"{o_sim * 1e3:.1f} ms ({o_mean * 1e3:.1f} ms, sd {o_sd * 1e3:.1f} ms)", "", ""))
rows += [("peer_s", "SciPy RK45 peer (rtol = atol = 1e-6), same file end to end", f"{peer:.2f} s", "", ""),
         ("ratio", "peer time / host-sim best time", f"{ratio:.0f}x", ">= 500x",
          "met" if ratio >= 500 else "NOT met")]
print("\n".join("\t".join(r) for r in rows))
PY
)
printf '## host-sim simulate vs the SciPy RK45 peer (scripts/bench-scale.sh)\n\n'
python3 scripts/figures.py render <<<"$tsv"
if [ "$write_docs" = 1 ]; then python3 scripts/figures.py write scale <<<"$tsv"; fi
grep -q $'^ratio\t.*\tmet$' <<<"$tsv" || status=1
exit $status
