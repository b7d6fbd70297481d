#!/usr/bin/env bash
# Runner of `cargo flash` (.cargo/config.toml): flashes the board ELF to an STM32F407
# Discovery over its on-board ST-LINK and runs it with probe-rs, printing defmt logs (RTT).
# Needs probe-rs (`cargo install probe-rs-tools --locked`, see README "Real board").
#   scripts/flash-run.sh <elf> [probe-rs run args...]
# Environment: PROBE_RS_CHIP (default STM32F407VGTx).
set -euo pipefail
elf=${1:?usage: flash-run.sh <elf> [probe-rs args...]}
shift
if ! command -v probe-rs >/dev/null 2>&1; then
  echo "flash-run.sh: probe-rs not found; install it with 'cargo install probe-rs-tools --locked'" >&2
  echo "flash-run.sh: the board image is built: $elf" >&2
  exit 127
fi
exec probe-rs run --chip "${PROBE_RS_CHIP:-STM32F407VGTx}" "$@" "$elf"
