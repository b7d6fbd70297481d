#!/usr/bin/env python3
"""Per-symbol instruction counts of a benchmark loop of src/bin/qemu.rs (scripts/bench-mcu.sh
--breakdown). Reads a QEMU `-singlestep -d exec,nochain` log (one line per executed
instruction, ending in the symbol name) on stdin; counts the instructions executed from the
first entry into the function argv[2] to the first entry into argv[3], per symbol, divided
by the number of iterations argv[1].

    tick-profile.py <iterations> <start symbol> <end symbol> < exec.log"""
import collections
import re
import subprocess
import sys

ticks = int(sys.argv[1])
start, end = sys.argv[2], sys.argv[3]
counts = collections.Counter()
inside = False
total = 0
for line in sys.stdin:
    sym = line.rsplit("] ", 1)[-1].strip()
    if not inside:
        inside = start in sym
        if not inside:
            continue
    if end in sym:
        break
    counts[sym] += 1
    total += 1
if total == 0:
    sys.exit(f"tick-profile.py: no {start} .. {end} window in the log")

def demangle(names):
    try:
        out = subprocess.run(["c++filt"], input="\n".join(names), capture_output=True,
                             text=True, check=True).stdout.splitlines()
        return [re.sub(r"::h[0-9a-f]{16}$", "", n) for n in out]
    except (OSError, subprocess.CalledProcessError):
        return names

top = counts.most_common(12)
names = demangle([s for s, _ in top])
print(f"{start}: instructions per iteration by symbol ({ticks} iterations, window total {total / ticks:.0f}):")
for (sym, c), name in zip(top, names):
    print(f"  {c / ticks:8.1f}  {name}")
