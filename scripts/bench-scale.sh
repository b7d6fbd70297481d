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
set -euo pipefail
cd "$(dirname "$0")/.."
plant=../shared/plant/reference-1dof.toml
fixture=../shared/conformance/pulses_nominal.csv
other=${1:-}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
cargo build -q --release -p host-sim --bin host-sim
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"
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
python3 - "$peer" "${other:-}" $times <<'PY'
import sys
peer, other = float(sys.argv[1]), sys.argv[2]
t = [float(a) for a in sys.argv[3:]]
sim, mean, sd = t[0:3]
ratio = peer / sim
print(f"host-sim simulate, 20 s fixture end to end (best of 10): {sim * 1e3:.1f} ms "
      f"(mean {mean * 1e3:.1f} ms, sd {sd * 1e3:.1f} ms: {peer / mean:.0f}x on the mean)")
if other:
    o_sim, o_mean, o_sd = t[3:6]
    print(f"{other} (alternating with it):  {o_sim * 1e3:.1f} ms (mean {o_mean * 1e3:.1f} ms, "
          f"sd {o_sd * 1e3:.1f} ms): {peer / o_sim:.0f}x")
print(f"SciPy RK45 peer, same file end to end:                 {peer:.2f} s")
print(f"ratio: {ratio:.0f}x (target >= 500x): {'met' if ratio >= 500 else 'NOT met'}")
sys.exit(0 if ratio >= 500 else 1)
PY
