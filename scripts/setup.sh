#!/usr/bin/env bash
# Installs everything the project needs on a fresh machine (idempotent).
# Rust targets for the firmware, QEMU for the emulated board, defmt-print / flip-link.
set -euo pipefail
cd "$(dirname "$0")/.."

say() { printf '[setup] %s\n' "$*" >&2; }

need_targets=(thumbv7em-none-eabihf thumbv6m-none-eabi)
installed=$(rustup target list --installed)
for t in "${need_targets[@]}"; do
  if ! grep -qx "$t" <<<"$installed"; then
    say "rustup target add $t"
    rustup target add "$t"
  fi
done
