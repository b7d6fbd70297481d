#!/usr/bin/env python3
"""Interleaved timing of `host-sim simulate` of the 20 s conformance fixture by several
binaries under the same machine load (A/B comparison; the absolute figure against the peer
is scripts/bench-scale.sh's). 15 rounds, each binary once per round; prints best, median,
mean and standard deviation. Run from the repository root:

    cp target/release/host-sim /tmp/host-sim-new   # and an older build as /tmp/host-sim-old
    python3 scripts/bench-simulate-ab.py /tmp/host-sim-old /tmp/host-sim-new
"""
import statistics
import subprocess
import sys
import tempfile
import time

PLANT = "../shared/plant/reference-1dof.toml"
FIXTURE = "../shared/conformance/pulses_nominal.csv"
bins = sys.argv[1:]
if not bins:
    sys.exit(__doc__)
runs = {b: [] for b in bins}
with tempfile.TemporaryDirectory() as d:
    for _ in range(15):
        for b in bins:
            t0 = time.perf_counter()
            subprocess.run([b, "simulate", "--plant", PLANT, "--inputs", FIXTURE, "--out",
                            f"{d}/out.csv"], check=True, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
            runs[b].append(time.perf_counter() - t0)
for b, r in runs.items():
    print(f"{b}: best {min(r) * 1e3:.1f} ms, median {statistics.median(r) * 1e3:.1f} ms, "
          f"mean {statistics.mean(r) * 1e3:.1f} ms, sd {statistics.stdev(r) * 1e3:.1f} ms")
