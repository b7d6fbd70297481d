#!/usr/bin/env bash
# The project's test command (README.md, .ci/run): host tests of the whole workspace, then
# the firmware library built for the bare-metal targets.
set -euo pipefail
cd "$(dirname "$0")/.."
# Lean on disk: a CI machine's disk may be small, and the workspace's ~40 test binaries each link
# the simulator. No incremental caches, line tables only (enough for a backtrace) in host builds.
export CARGO_INCREMENTAL=0
export CARGO_PROFILE_DEV_DEBUG=line-tables-only
export CARGO_PROFILE_TEST_DEBUG=line-tables-only
bash scripts/setup.sh
cargo build -p pam-firmware --lib --target thumbv7em-none-eabihf --release
cargo build -p pam-firmware --lib --target thumbv6m-none-eabi --release
# The fixed-point path calls no soft-float routine and cannot panic (Cortex-M0 assembly check).
bash scripts/check-fixed-no-float.sh >/dev/null
# Firmware images: the QEMU image and the STM32F407 board image (flip-link), no hardware needed.
cargo build -p pam-firmware --bin qemu --features pam-firmware/firmware --release --target thumbv7em-none-eabihf
cargo flash-build
# Formatting (rustfmt's defaults), then lints (the allowed ones and why: the workspace's
# Cargo.toml): the host workspace with its tests, and the firmware's bare-metal images.
cargo fmt --all --check
# No function over 150 lines outside tests and tables (each orchestrator a list of named steps).
python3 scripts/check-fn-length.py
cargo clippy -q --workspace --all-targets -- -D warnings
cargo clippy -q -p pam-firmware --release --target thumbv7em-none-eabihf --features firmware --lib --bins -- -D warnings
cargo clippy -q -p pam-firmware --release --target thumbv7em-none-eabihf --features board --lib --bins -- -D warnings
# Includes tests/qemu_trace.rs: the QEMU run (cargo qemu) bit-for-bit against the host run,
# and the non-zero exit of a panic / HardFault; with CI=true a missing QEMU fails it.
cargo test --workspace
