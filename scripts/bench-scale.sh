#!/usr/bin/env bash
# Speed of `host-sim simulate` end to end (read, simulate, write) on the 20 s conformance
# fixture against the SciPy RK45 peer (scripts/rk45_peer.py: solve_ivp RK45 per sample,
# rtol = atol = 1e-6) on the same file. A benchmark, not a test: run it on an idle machine
# (the load average is printed). 10 runs of host-sim (best, mean and standard deviation; the
# ratio is taken on the best), one run of the peer.
# Exit status 1 when host-sim is less than 500x faster.
set -euo pipefail
cd "$(dirname "$0")/.."
plant=../shared/plant/reference-1dof.toml
fixture=../shared/conformance/pulses_nominal.csv
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
cargo build -q --release -p host-sim --bin host-sim
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg)"
ns=$(python3 - "$plant" "$fixture" "$out/sim.csv" <<'PY'
import subprocess, sys, time
runs = []
for _ in range(10):
    t0 = time.perf_counter()
    subprocess.run(["target/release/host-sim", "simulate", "--plant", sys.argv[1], "--inputs",
                    sys.argv[2], "--out", sys.argv[3]], check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    runs.append(time.perf_counter() - t0)
import statistics
print(min(runs), statistics.mean(runs), statistics.stdev(runs))
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
python3 - $ns "$peer" <<'PY'
import sys
sim, mean, sd, peer = (float(a) for a in sys.argv[1:5])
ratio = peer / sim
print(f"host-sim simulate, 20 s fixture end to end (best of 10): {sim * 1e3:.1f} ms "
      f"(mean {mean * 1e3:.1f} ms, sd {sd * 1e3:.1f} ms: {peer / mean:.0f}x on the mean)")
print(f"SciPy RK45 peer, same file end to end:                 {peer:.2f} s")
print(f"ratio: {ratio:.0f}x (target >= 500x): {'met' if ratio >= 500 else 'NOT met'}")
sys.exit(0 if ratio >= 500 else 1)
PY
