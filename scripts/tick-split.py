#!/usr/bin/env python3
"""Where a benchmark tick's instructions go, by part of the tick (the feed-forward's parts, the
force-law estimate, the loops, the validators, ...), from a QEMU `-singlestep -d exec,nochain`
log of a benchmark image of src/bin/qemu.rs. Counts the instructions executed in the n-th call
of `bench_ticks` (1 = "tick", 2 = "start tick", 3 = "ff tick" and 4 = "hybrid tick" in the
image with the feature volume-fnn), attributes each to the innermost inlined function of the
list below (debug info through llvm-symbolizer; the release profile keeps it), and divides by
the trace's rows. The harness's own instructions (frame decoding, SysTick reads, the tally)
are listed too: the benchmark subtracts only the empty measurement, so they are not all
outside the measured figure.

    qemu-system-arm -machine netduinoplus2 -nographic -monitor none -serial none \\
      -semihosting-config enable=on,target=native -singlestep -d exec,nochain \\
      -D /tmp/exec.log -kernel <elf>
    python3 scripts/tick-split.py <elf> <n-th bench_ticks call> <trace rows> < /tmp/exec.log"""
import collections
import subprocess
import sys

if len(sys.argv) != 4:
    sys.exit(__doc__)
elf, nth, rows = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
sysroot = subprocess.run(["rustc", "--print", "sysroot"], capture_output=True, text=True,
                         check=True).stdout.strip()
host = [l.split(": ")[1] for l in subprocess.run(["rustc", "-vV"], capture_output=True, text=True,
                                                 check=True).stdout.splitlines()
        if l.startswith("host: ")][0]
nm = subprocess.run([f"{sysroot}/lib/rustlib/{host}/bin/llvm-nm", elf], capture_output=True,
                    text=True, check=True).stdout
entry = [l.split()[0] for l in nm.splitlines() if "bench11bench_ticks" in l]
if not entry:
    sys.exit("tick-split.py: no bench_ticks in the image (build it with the feature mcu-bench)")
entry = f"{int(entry[0], 16) & ~1:08x}"

pcs = collections.Counter()
calls = 0
for line in sys.stdin:
    pc = line.split("[", 1)[1].split("/")[1]
    if pc == entry:
        calls += 1
        if calls > nth:
            break
    if calls == nth:
        pcs[pc] += 1
if not pcs:
    sys.exit(f"tick-split.py: the log has no call {nth} of bench_ticks")

# (part, pattern in the demangled function name), first match from the innermost frame out.
PARTS = [
    ("feed-forward: duty (ISO 6358 inversion, flow function, clamp)", "InverseModel::duty"),
    ("feed-forward: duty (ISO 6358 inversion, flow function, clamp)", "InverseModel::phi"),
    ("feed-forward: eq. 7 mass flow", "InverseModel::mass_flow_kg_s"),
    ("feed-forward: P' filter, volume and its rate, per-muscle loop", "PressureFeedforward::"),
    ("feed-forward: tick side (options, desired pressures, sum and clamp)", "add_pressure_ff"),
    ("force-law torque estimate (both muscles)", "torque_from"),
    ("channel validators (p1, p2, angle)", "ChannelValidator::"),
    ("velocity estimator", "VelocityEstimator"),
    ("valve / supply residual", "ResidualMonitor"),
    ("torque loop", "TorqueController"),
    ("pressure loops", "PressureController"),
    ("position loop", "PositionController"),
    ("trajectory feed-forward", "feedforward::"),
    ("pressure tracking monitors", "TrackingMonitor"),
    ("on/off valve driver", "OnOffValves"),
    ("benchmark harness", "qemu::"),
    ("benchmark harness", "__aeabi_ul2f"),
]
keys = list(pcs)
out = subprocess.run(["llvm-symbolizer", f"--obj={elf}", "--inlining", "--demangle"],
                     input="\n".join("0x" + k for k in keys), capture_output=True, text=True,
                     check=True).stdout
parts = collections.Counter()
for pc, block in zip(keys, out.strip("\n").split("\n\n")):
    lines = block.split("\n")
    part = "rest of the tick (ControlTick::step)"
    for fn in lines[0::2]:
        hit = [p for p, pat in PARTS if pat in fn]
        if hit:
            part = hit[0]
            break
    parts[part] += pcs[pc]
print(f"bench_ticks call {nth}: instructions per trace row ({rows} rows) by part of the tick")
for part, n in parts.most_common():
    print(f"  {n / rows:7.1f}  {part}")
print(f"  {sum(parts.values()) / rows:7.1f}  total")
