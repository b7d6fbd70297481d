#!/usr/bin/env python3
"""Writes a long recording (RECORDING.md columns t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg) by
repeating the inputs and the measured angle of a conformance fixture, for the scale measurements of
docs/reliability.md:

    python3 scripts/long-recording.py ../shared/conformance/pulses_nominal.csv 3600 /tmp/long.csv
"""
import sys

src, seconds, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
rows = []
dt = None
with open(src) as f:
    header = None
    for line in f:
        if line.startswith("#") or not line.strip():
            continue
        cells = line.strip().split(",")
        if header is None:
            header = cells
            idx = [header.index(c) for c in ("u_in1", "u_ex1", "u_in2", "u_ex2", "angle_deg")]
            continue
        rows.append(",".join(cells[i] for i in idx))
        if len(rows) == 2:
            dt = float(cells[0]) - t0
        t0 = float(cells[0]) if len(rows) == 1 else t0
n = int(round(seconds / dt))
with open(out, "w") as f:
    f.write(f"# sample_period_s = {dt}\n# source = scripts/long-recording.py, inputs of {src} repeated\n")
    f.write("t_s,u_in1,u_ex1,u_in2,u_ex2,angle_deg\n")
    for k in range(n):
        f.write(f"{k * dt:.6f},{rows[k % len(rows)]}\n")
print(f"{out}: {n} samples, {n * dt:.0f} s")
