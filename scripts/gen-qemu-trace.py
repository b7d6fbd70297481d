#!/usr/bin/env python3
"""Generates tests/traces/qemu_sensor_trace.csv: the deterministic raw-sensor trace that the QEMU
firmware (src/bin/qemu.rs) and tests/qemu_trace.rs feed to the control tick.

One row per control tick (1 kHz). Raw counts, as the board delivers them: 12-bit ADC counts of
the two pressure transducers (src/wiring.rs: 455 counts = 0 Pa, 4095 counts = 1 MPa) and the x4
quadrature count of the 8000 counts/turn encoder. An empty field is a missing sample.

Scenario (a recorded-like, open-loop trace; the trace does not react to the commands):
  ticks 0..2     sensors not ready yet (missing samples) -> tick stays disarmed
  tick 50        set-point step 0 -> 0.300 rad, tick 250 -> -0.200 rad, tick 400 -> 0
  angle          first-order lag (60 ms) behind the set-point, quantized to encoder counts
  pressures      p0 = 300 kPa -+ dp, dp follows the angle error, 0.5 kPa noise (seeded LCG)
  ticks 150,151  muscle 1 pressure missing (below the stale limit: no fault)
  ticks 200,201  encoder missing
  tick 460       muscle 2 transducer shorted (ADC 4095) -> fault latched, safe valve state
Re-run only to change the scenario; the CSV in the repository is the source of truth.
"""
import math, os, sys

N = 500
DT = 1e-3
P0 = 300e3
PA_PER_COUNT = 1e6 / 3640.0
ZERO = 455
CPR = 8000

state = 12345
def rnd():  # LCG, uniform in [-1, 1)
    global state
    state = (1103515245 * state + 12345) % (1 << 31)
    return state / float(1 << 30) - 1.0

def adc(p):
    return max(0, min(4095, int(round(p / PA_PER_COUNT)) + ZERO))

rows = []
angle = 0.0
dp = 0.0
for k in range(N):
    sp = 0.0 if k < 50 else 0.300 if k < 250 else -0.200 if k < 400 else 0.0
    angle += (sp - angle) * DT / 0.060
    dp += ((-(sp - angle) * 400e3) - dp) * DT / 0.030
    dp = max(-280e3, min(280e3, dp))
    p1 = P0 - dp + 500.0 * rnd()
    p2 = P0 + dp + 500.0 * rnd()
    enc = int(round(angle / (2 * math.pi) * CPR))
    a1, a2, e = str(adc(p1)), str(adc(p2)), str(enc)
    if k < 3:
        a1 = a2 = e = ""
    if k in (150, 151):
        a1 = ""
    if k in (200, 201):
        e = ""
    if k == 460:
        a2 = "4095"
    rows.append(f"{k},{int(round(sp * 1000))},{a1},{a2},{e}")

out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "traces", "qemu_sensor_trace.csv")
tmp = out + ".tmp"
with open(tmp, "w") as f:
    f.write("# Raw sensor trace for the QEMU run and tests/qemu_trace.rs (scripts/gen-qemu-trace.py).\n")
    f.write("# tick_hz = 1000; empty field = missing sample; counts per src/wiring.rs.\n")
    f.write("tick,angle_set_mrad,p1_adc_counts,p2_adc_counts,encoder_counts\n")
    f.write("\n".join(rows) + "\n")
os.replace(tmp, out)
print(f"wrote {out} ({N} rows)", file=sys.stderr)
