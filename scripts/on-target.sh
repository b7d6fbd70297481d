#!/usr/bin/env bash
# On-target tests (src/bin/on_target.rs, defmt-test) on QEMU netduinoplus2 (Cortex-M4F):
# builds them (`cargo on-target-build`: the binary with `--cfg test`, which defmt-test's
# generated entry needs; a `[[test]]` target would build the std-only dev-dependencies for the
# bare-metal target) and runs the image through scripts/qemu-run.sh. Exit status 0 when every
# test passed, 1 at the first failure (semihosting exit from the panic handler), 127 without
# qemu-system-arm / defmt-print (scripts/setup.sh installs them).
#   bash scripts/on-target.sh
set -euo pipefail
cd "$(dirname "$0")/.."
cargo on-target-build
exec scripts/qemu-run.sh "${CARGO_TARGET_DIR:-target}/thumbv7em-none-eabihf/release/on_target"
