#!/usr/bin/env python3
"""Per-symbol instruction counts of the control-tick benchmark loop (scripts/bench-mcu.sh
--breakdown). Reads a QEMU `-singlestep -d exec,nochain` log (one line per executed
instruction, ending in the symbol name) on stdin; counts the instructions executed from the
first entry into `bench_ticks` to the first entry into `bench_force_law` (src/bin/qemu.rs),
per symbol, divided by the number of ticks given as argv[1]."""
import collections
import re
import subprocess
import sys

ticks = int(sys.argv[1])
counts = collections.Counter()
inside = False
total = 0
for line in sys.stdin:
    sym = line.rsplit("] ", 1)[-1].strip()
    if not inside:
        inside = "bench_ticks" in sym
        if not inside:
            continue
    if "bench_force_law" in sym:
        break
    counts[sym] += 1
    total += 1
if total == 0:
    sys.exit("tick-profile.py: no bench_ticks window in the log")

def demangle(names):
    try:
        out = subprocess.run(["c++filt"], input="\n".join(names), capture_output=True,
                             text=True, check=True).stdout.splitlines()
        return [re.sub(r"::h[0-9a-f]{16}$", "", n) for n in out]
    except (OSError, subprocess.CalledProcessError):
        return names

top = counts.most_common(12)
names = demangle([s for s, _ in top])
print(f"instructions per tick by symbol (all {ticks} ticks of the trace, window total {total / ticks:.0f}):")
for (sym, c), name in zip(top, names):
    print(f"  {c / ticks:8.1f}  {name}")
