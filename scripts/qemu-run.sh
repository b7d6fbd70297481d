#!/usr/bin/env bash
# Cargo runner for thumbv7em-none-eabihf and thumbv6m-none-eabi (.cargo/config.toml): runs a
# firmware ELF on QEMU's netduinoplus2 (STM32F405, Cortex-M4F) or, for thumbv6m images, its
# microbit (nRF51822, Cortex-M0), and decodes its defmt output (semihosting stdout)
# with defmt-print. Exits with QEMU's status (the firmware's semihosting exit: 0 = success,
# 1 = panic / HardFault), or 124 if QEMU_TIMEOUT_S (default 120 s) runs out.
#
#   scripts/qemu-run.sh <elf> [extra qemu args...]
# Environment: QEMU_EXTRA_ARGS (e.g. "-icount shift=0" for scripts/bench-mcu.sh),
#              QEMU_TIMEOUT_S, DEFMT_PRINT_ARGS (e.g. "--log-format {s}").
set -euo pipefail

elf=${1:?usage: qemu-run.sh <elf> [qemu args...]}
shift
for tool in qemu-system-arm defmt-print; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "qemu-run.sh: '$tool' not found; run scripts/setup.sh" >&2
    exit 127
  fi
done

# shellcheck disable=SC2086
set +e
# Cortex-M0 images (thumbv6m, src/bin/qemu_m0.rs) run on the micro:bit model (nRF51822);
# everything else on netduinoplus2. QEMU_MACHINE overrides.
case "$elf" in
  *thumbv6m*) machine=${QEMU_MACHINE:-microbit} ;;
  *) machine=${QEMU_MACHINE:-netduinoplus2} ;;
esac
timeout "${QEMU_TIMEOUT_S:-120}" qemu-system-arm \
  -machine "$machine" -nographic -monitor none -serial none \
  -semihosting-config enable=on,target=native \
  ${QEMU_EXTRA_ARGS:-} "$@" \
  -kernel "$elf" \
  | defmt-print ${DEFMT_PRINT_ARGS:-} -e "$elf"
status=("${PIPESTATUS[@]}")
set -e
if [ "${status[0]}" -ne 0 ]; then
  echo "qemu-run.sh: qemu-system-arm exited with status ${status[0]}" >&2
  exit "${status[0]}"
fi
if [ "${status[1]}" -ne 0 ]; then
  echo "qemu-run.sh: defmt-print exited with status ${status[1]}" >&2
  exit "${status[1]}"
fi
