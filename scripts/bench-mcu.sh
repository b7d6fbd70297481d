#!/usr/bin/env bash
# MCU cost figures (a benchmark, not a test): instructions per control tick and per force-law
# evaluation on the Cortex-M4F build under QEMU, flash / static RAM of the QEMU and board
# images, worst-case stack.
#
# Method
# - Instructions: the QEMU image (src/bin/qemu.rs) reads SysTick (core clock) around each call.
#   Under `-icount shift=0` QEMU advances virtual time by exactly 1 ns per executed instruction,
#   so SysTick counts are proportional to instructions; the factor is calibrated in the same
#   run on an asm loop of a known instruction count (2 x 100000), and the cost of an empty
#   measurement is subtracted. Resolution: one SysTick count (about 6 instructions) per
#   measurement; the mean over all armed ticks of the trace is finer than that.
# - Flash = .vector_table + .text + .rodata + .data (load image); static RAM = .data + .bss +
#   .uninit (llvm-size from rustup's llvm-tools).
# - Stack: the QEMU image paints the free RAM at start-up and reports the deepest overwritten
#   word after the trace and the benchmarks ran (stack painting, measured at run time).
# - --breakdown: also runs QEMU with -singlestep -d exec (one log line per instruction, a few
#   hundred MB under /tmp) and prints where a tick's instructions go (scripts/tick-profile.py).
# --write-docs: also writes the rows to docs/figures/mcu.tsv, their table into
# docs/performance.md and every quote of a row in the docs (scripts/figures.py).
# Exit status 1 if a target is missed (<= 1000 instructions per f32 tick, <= 600 per fixed-point
# force law on the Cortex-M0, worst fixed-point tick on the M0 <= 24000 = half the 48000
# instructions of a 1 kHz tick on a 48 MHz M0, <= 28 KiB flash = 4 KiB headroom in 32 KiB,
# <= 8 KiB static RAM).
set -euo pipefail
# BENCH_EXTRA_FEATURES=pam-firmware/pressure-ff: the benchmark image with extra firmware features
# (e.g. the pressure loop's feed-forward, with config/pressure_ff.toml enabled = true).
cd "$(dirname "$0")/.."
breakdown=0
write_docs=0
for arg in "$@"; do
  case "$arg" in
    --breakdown) breakdown=1 ;;
    --write-docs) write_docs=1 ;;
    *) echo "bench-mcu.sh: unknown argument '$arg' (allowed: --breakdown, --write-docs)" >&2; exit 2 ;;
  esac
done
if [ "$write_docs" = 1 ] && [ -n "${BENCH_EXTRA_FEATURES:-}" ]; then
  echo "bench-mcu.sh: --write-docs records the default images; run it without BENCH_EXTRA_FEATURES" >&2
  exit 2
fi

sysroot=$(rustc --print sysroot)
host=$(rustc -vV | sed -n 's/^host: //p')
llvm_size="$sysroot/lib/rustlib/$host/bin/llvm-size"
if [ ! -x "$llvm_size" ]; then
  llvm_size=$(command -v arm-none-eabi-size || true) # same -A output (Debian binutils-arm-none-eabi)
  [ -n "$llvm_size" ] || { echo "bench-mcu.sh: no size tool: run scripts/setup.sh" >&2; exit 2; }
fi

sizes() { # sizes <elf> -> "flash ram"
  "$llvm_size" -A "$1" | awk '
    $1 == ".vector_table" || $1 == ".text" || $1 == ".rodata" { f += $2 }
    $1 == ".data" { f += $2; r += $2 }
    $1 == ".bss" || $1 == ".uninit" { r += $2 }
    END { print f, r }'
}
# The shipped QEMU image (trace replay and stack report, no benchmarks) for its size; then
# the same binary with the benchmarks (feature mcu-bench) for the instruction counts.
cargo build -q -p pam-firmware --bin qemu --features pam-firmware/firmware --release --target thumbv7em-none-eabihf
read -r qemu_flash qemu_ram < <(sizes "${CARGO_TARGET_DIR:-target}/thumbv7em-none-eabihf/release/qemu")
cargo build -q -p pam-firmware --bin qemu --features pam-firmware/mcu-bench${BENCH_EXTRA_FEATURES:+,$BENCH_EXTRA_FEATURES} --release --target thumbv7em-none-eabihf
cargo flash-build -q
cargo build -q -p pam-firmware --bin qemu_m0 --features pam-firmware/firmware --release --target thumbv6m-none-eabi
# The QEMU image honours CARGO_TARGET_DIR; the board image is always in target/board (the
# flash-build alias's --target-dir wins over the environment).
qemu_elf=${CARGO_TARGET_DIR:-target}/thumbv7em-none-eabihf/release/qemu
board_elf=target/board/thumbv7em-none-eabihf/release/board

log=$(QEMU_EXTRA_ARGS="-icount shift=0" DEFMT_PRINT_ARGS="--log-format {s}" \
  scripts/qemu-run.sh "$qemu_elf" | grep -v '^tick=')
# The 3-DOF arm tick: the same image with the arm benchmark instead of the 1-DOF rows (feature
# mcu-bench-arm; its own target directory, so the 1-DOF image above stays as it is).
arm_dir=${CARGO_TARGET_DIR:-target}/bench-arm
cargo build -q -p pam-firmware --bin qemu --features pam-firmware/mcu-bench-arm --release \
  --target thumbv7em-none-eabihf --target-dir "$arm_dir"
arm_log=$(QEMU_EXTRA_ARGS="-icount shift=0" DEFMT_PRINT_ARGS="--log-format {s}" \
  scripts/qemu-run.sh "$arm_dir/thumbv7em-none-eabihf/release/qemu" | grep -v '^tick=')
# The hybrid volume's rows (seed 004 eq. 12): the benchmark image with the feature volume-fnn
# (the pressure feed-forward switched on in its tick rows, analytical and hybrid, and the
# network alone), in its own target directory so the default image above stays as it is.
fnn_dir=${CARGO_TARGET_DIR:-target}/bench-fnn
cargo build -q -p pam-firmware --bin qemu --features pam-firmware/mcu-bench,pam-firmware/volume-fnn \
  --release --target thumbv7em-none-eabihf --target-dir "$fnn_dir"
fnn_log=$(QEMU_EXTRA_ARGS="-icount shift=0" DEFMT_PRINT_ARGS="--log-format {s}" \
  scripts/qemu-run.sh "$fnn_dir/thumbv7em-none-eabihf/release/qemu" | grep -v '^tick=')
key() { # key <log> <line prefix> <key>: <key>= of the log's first line starting with the prefix
  grep "^$2" <<<"$1" | tr ' ' '\n' | sed -n "s/^$3=//p" | head -1
}
stat() { # stat <log> <bench name> -> "mean worst n" in instructions, calibrated on the same
  # log's "bench calib" line; "? ? 0" without samples
  awk -v ci="$(key "$1" "bench calib" insns)" -v cc="$(key "$1" "bench calib" counts)" \
    -v e="$(key "$1" "bench calib" empty_counts)" -v n="$(key "$1" "bench $2 " n)" \
    -v s="$(key "$1" "bench $2 " sum_counts)" -v m="$(key "$1" "bench $2 " max_counts)" 'BEGIN {
    if (n == "" || n == 0 || cc == "") { print "? ? 0"; exit }
    k = ci / (cc - e); printf "%.0f %.0f %d\n", (s / n - e) * k, (m - e) * k, n }'
}
read -r fnn_tick0_mean fnn_tick0_worst _ < <(stat "$fnn_log" tick)
read -r ff_tick_mean ff_tick_worst ff_tick_n < <(stat "$fnn_log" "ff tick")
read -r hm_tick_mean hm_tick_worst hm_tick_n < <(stat "$fnn_log" "hybrid tick")
read -r ffs_tick_mean ffs_tick_worst ffs_tick_n < <(stat "$fnn_log" "ff split tick")
read -r sp_tick_mean sp_tick_worst sp_tick_n < <(stat "$fnn_log" "split tick")
read -r fnn_mean fnn_worst fnn_n < <(stat "$fnn_log" volume_fnn)
# Cortex-M0 (no FPU) image on QEMU microbit: SysTick runs at 16 MHz there, so 64 ns per
# instruction (-icount shift=6) keeps about one count per instruction.
m0_elf=${CARGO_TARGET_DIR:-target}/thumbv6m-none-eabi/release/qemu_m0
m0_log=$(QEMU_EXTRA_ARGS="-icount shift=6" DEFMT_PRINT_ARGS="--log-format {s}" \
  scripts/qemu-run.sh "$m0_elf")
read -r m0_tk_mean m0_tk_worst m0_tk_n < <(stat "$m0_log" "m0 tick_f32_soft")
read -r m0_ft_mean m0_ft_worst m0_ft_n < <(stat "$m0_log" "m0 tick_fixed")
read -r m0_tf_mean m0_tf_worst _ < <(stat "$m0_log" "m0 torque_fixed_forward")
read -r m0_ti_mean m0_ti_worst _ < <(stat "$m0_log" "m0 torque_fixed_inverse")
read -r m0_fx_mean m0_fx_worst m0_n < <(stat "$m0_log" "m0 force_law_fixed")
read -r m0_fl_mean m0_fl_worst _ < <(stat "$m0_log" "m0 force_law_f32_soft")

cal_insns=$(key "$log" "bench calib" insns)
cal_counts=$(key "$log" "bench calib" counts)
empty=$(key "$log" "bench calib" empty_counts)
read -r tick_mean tick_worst tick_n < <(stat "$log" tick)
read -r st_mean st_worst st_n < <(stat "$log" "start tick")
read -r fl_mean fl_worst fl_n < <(stat "$log" force_law_f32)
read -r fx_mean fx_worst fx_n < <(stat "$log" force_law_fixed)
fx_off=$(key "$log" "bench force_law_fixed" off_by_more_than_0.1N)
read -r arm_mean arm_worst arm_n < <(stat "$arm_log" "arm tick")
arm_ticks=$(key "$arm_log" "bench arm tick" ticks)
stack=$(grep -o 'stack_used_bytes=[0-9]*' <<<"$log" | cut -d= -f2)
unpainted=$(grep -o 'unpainted_top_bytes=[0-9]*' <<<"$log" | cut -d= -f2)
if [ "${stack:-0}" -le "${unpainted:-0}" ]; then stack="<= $unpainted"; fi
for v in cal_insns cal_counts empty arm_ticks stack; do
  [ -n "${!v}" ] || { echo "bench-mcu.sh: no '$v' in the QEMU output:" >&2; echo "$log" >&2; exit 2; }
done
for v in tick_n st_n fl_n fx_n; do
  [ "${!v}" != 0 ] || { echo "bench-mcu.sh: no '$v' in the QEMU output:" >&2; echo "$log" >&2; exit 2; }
done
k=$(awk -v ci="$cal_insns" -v cc="$cal_counts" -v e="$empty" 'BEGIN { printf "%.5f\n", ci / (cc - e) }')

read -r board_flash board_ram < <(sizes "$board_elf")

fail=0
check() { # check <value> <limit>
  if [ "$1" -le "$2" ]; then echo "ok"; else echo "OVER"; fail=1; fi
}
qemu_version=$(qemu-system-arm --version | head -1 | sed 's/ *(.*//')
tsv=$'key\tfigure\tmeasured\ttarget\tcheck'
row() { # row <key> <figure> <measured> [<target> <check>]: one row of the table
  tsv+=$'\n'"$1"$'\t'"$2"$'\t'"$3"$'\t'"${4:-}"$'\t'"${5:-}"
}
row setup "QEMU, machine, time base" "$qemu_version, netduinoplus2, -icount shift=0"
row calibration "calibration (asm loop)" "$cal_insns instructions = $((cal_counts - empty)) SysTick counts (k = $k instructions/count)"
row tick_mean "full f32 control tick, mean over $tick_n armed ticks" "$tick_mean instructions" "<= 1000" "$(check "$tick_mean" 1000)"
row tick_worst "full f32 control tick, worst tick of the trace" "$tick_worst instructions"
row start_tick "the same trace with the reference start phase (ramped set-point and pressure ceiling for up to ~1 s after arming), mean / worst over $st_n armed ticks" "$st_mean / $st_worst instructions"
row arm_tick "3-DOF arm tick (three joint ticks, rigid-body gravity and inertia feed-forward, three valve drivers; tests/traces/arm3_sensor_trace.csv), mean / worst over $arm_n of $arm_ticks ticks with all joints armed" "$arm_mean / $arm_worst instructions"
row fnn_tick_off "image with the feature volume-fnn, pressure feed-forward off (as the default), mean / worst" "$fnn_tick0_mean / $fnn_tick0_worst instructions"
row ff_tick "the same image, pressure feed-forward on, analytical (volume polynomial, seed 004 eq. 7), mean / worst over $ff_tick_n armed ticks" "$ff_tick_mean / $ff_tick_worst instructions"
row ff_split_tick "the same image, pressure feed-forward on, analytical, within the budget: outer loops (position, torque) and feed-forward on every second tick (config/controller.toml [rates] outer_period_ticks = 2, config/pressure_ff.toml update_period_ticks = 2), mean / worst over $ffs_tick_n armed ticks" "$ffs_tick_mean / $ffs_tick_worst instructions" "<= 1000 mean" "$(check "$ffs_tick_mean" 1000)"
row split_tick "the same image, feed-forward off, outer loops on every second tick, mean / worst" "$sp_tick_mean / $sp_tick_worst instructions"
row hybrid_tick "the same image, pressure feed-forward on, hybrid (learned volume, 2 x 8 units, seed 004 eq. 12), mean / worst over $hm_tick_n armed ticks" "$hm_tick_mean / $hm_tick_worst instructions" "reported separately" ""
row fnn_alone "hybrid volume network alone (one muscle: V and its eq. 9 rate), mean / worst over $fnn_n calls" "$fnn_mean / $fnn_worst instructions"
row force_law_f32_mean "force law alone (f32, one muscle), mean over $fl_n calls" "$fl_mean instructions"
row force_law_f32_worst "force law alone (f32), worst call" "$fl_worst instructions"
row force_law_fixed_mean "force law fixed point (32-bit integers, same inputs quantised), mean over $fx_n calls ($fx_off off the f32 law by > 0.1 N)" "$fx_mean instructions"
row force_law_fixed_worst "force law fixed point, worst call" "$fx_worst instructions"
row m0_force_law_fixed "Cortex-M0 (QEMU microbit, no FPU): force law fixed point, mean / worst over $m0_n calls" "$m0_fx_mean / $m0_fx_worst instructions" "<= 600 mean" "$(check "$m0_fx_mean" 600)"
row m0_force_law_soft "Cortex-M0: force law f32 in soft-float, mean / worst" "$m0_fl_mean / $m0_fl_worst instructions"
row m0_torque_forward "Cortex-M0: torque model fixed point, forward, mean / worst over $m0_ft_n calls" "$m0_tf_mean / $m0_tf_worst instructions"
row m0_torque_inverse "Cortex-M0: torque model fixed point, inverse, mean / worst" "$m0_ti_mean / $m0_ti_worst instructions"
row m0_tick_fixed "Cortex-M0: full fixed-point control tick (raw counts -> valve commands), mean / worst over $m0_ft_n armed ticks" "$m0_ft_mean / $m0_ft_worst instructions" "worst <= 24000 (half of 48000 = 1 kHz on a 48 MHz M0 at 1 cycle each)" "$(check "$m0_ft_worst" 24000)"
row m0_tick_soft "Cortex-M0: full control tick (f32 in soft-float), mean / worst over $m0_tk_n armed ticks" "$m0_tk_mean / $m0_tk_worst instructions" "< 48000 (1 kHz at 48 MHz if 1 cycle each; see docs/firmware.md)" "$(check "$m0_tk_worst" 48000)"
row qemu_flash "QEMU image flash (shipped: no benchmarks)" "$qemu_flash B" "<= 28672 (32 KiB - 4 KiB headroom)" "$(check "$qemu_flash" 28672)"
row qemu_ram "QEMU image static RAM" "$qemu_ram B" "<= 8192" "$(check "$qemu_ram" 8192)"
row board_flash "board image flash" "$board_flash B" "<= 28672 (32 KiB - 4 KiB headroom)" "$(check "$board_flash" 28672)"
row board_ram "board image static RAM" "$board_ram B" "<= 8192" "$(check "$board_ram" 8192)"
row stack "worst-case stack (QEMU image, painted)" "$stack B"
printf '## MCU cost (scripts/bench-mcu.sh)\n\n'
python3 scripts/figures.py render <<<"$tsv"
if [ "$write_docs" = 1 ]; then python3 scripts/figures.py write mcu <<<"$tsv"; fi
# check() runs inside the report's command substitutions (subshells): decide the exit status here.
for pair in "$tick_mean 1000" "$ffs_tick_mean 1000" "$m0_fx_mean 600" "$m0_ft_worst 24000" "$qemu_flash 28672" "$qemu_ram 8192" \
  "$board_flash 28672" "$board_ram 8192"; do
  set -- $pair
  [ "$1" -le "$2" ] 2>/dev/null || fail=1
done
if [ "$breakdown" = 1 ]; then
  exec_log=$(mktemp /tmp/bench-mcu-exec.XXXXXX)
  trap 'rm -f "$exec_log"' EXIT
  qemu-system-arm -machine netduinoplus2 -nographic -monitor none -serial none \
    -semihosting-config enable=on,target=native -singlestep -d exec,nochain -D "$exec_log" \
    -kernel "$qemu_elf" >/dev/null
  echo
  python3 scripts/tick-profile.py "$(grep -c . tests/traces/qemu_sensor_trace.csv | awk '{print $1 - 3}')" \
    bench_ticks bench_force_law <"$exec_log"
  echo
  python3 scripts/tick-profile.py "$fx_n" bench_force_law_fixed _defmt_acquire <"$exec_log"
fi
exit $fail
