#!/usr/bin/env python3
"""Adds an effect outside the diagnosis catalogue to a recording (RECORDING.md columns), for
the scale measurements of the `unexplained` path in docs/performance.md: cross-talk of the
valve drivers onto the angle sensor, a first-order low-pass (time constant 80 ms) of
`u_in1 - u_in2` as large as the angle's own spread (the recording of
`tests/diagnose.rs` `an_effect_outside_the_catalogue...`, written by a code path of its own):

    python3 scripts/add-crosstalk.py /tmp/d600/train.csv /tmp/x600/train.csv

Reads the file twice (the angle's range first), row by row.
"""
import math
import sys

src, out = sys.argv[1], sys.argv[2]


def rows(path):
    with open(path) as f:
        for line in f:
            yield line


lo, hi, header, dt = math.inf, -math.inf, None, None
t_prev = None
for line in rows(src):
    if line.startswith("#") or not line.strip():
        continue
    cells = line.rstrip("\n").split(",")
    if header is None:
        header = cells
        i_angle, i_in1, i_in2 = (header.index(c) for c in ("angle_deg", "u_in1", "u_in2"))
        continue
    a = float(cells[i_angle])
    lo, hi = min(lo, a), max(hi, a)
    t = float(cells[0])
    if t_prev is not None and dt is None:
        dt = t - t_prev
    t_prev = t
alpha = math.exp(-dt / 0.08)
slow = 0.0
seen_header = False
with open(out, "w") as f:
    for line in rows(src):
        if line.startswith("#") or not line.strip():
            f.write(line)
            continue
        if not seen_header:
            seen_header = True
            f.write(line)
            continue
        cells = line.rstrip("\n").split(",")
        slow = alpha * slow + (1.0 - alpha) * (float(cells[i_in1]) - float(cells[i_in2]))
        cells[i_angle] = repr(float(cells[i_angle]) + (hi - lo) * slow)
        f.write(",".join(cells) + "\n")
