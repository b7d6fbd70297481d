#!/usr/bin/env bash
# The project's test command (README.md, .ci/run): host tests of the whole workspace, then
# the firmware library built for the bare-metal targets.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo build -p pam-firmware --lib --target thumbv7em-none-eabihf --release
cargo build -p pam-firmware --lib --target thumbv6m-none-eabi --release
cargo test --workspace
