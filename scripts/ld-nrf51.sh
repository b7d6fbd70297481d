#!/bin/sh
# Linker for the thumbv6m-none-eabi images (the FPU-less benchmark image on QEMU `microbit`,
# nRF51822). cortex-m-rt's link.x does `INCLUDE memory.x`, and the linker looks for an
# INCLUDEd file in its working directory before the -L paths: from the repository root it
# would take the top-level memory.x (STM32F4). This wrapper runs rust-lld (ld.lld flavour,
# from the toolchain's gcc-ld directory) in scripts/nrf51, so that map wins. Every path rustc
# and cargo pass is absolute, so the change of directory moves nothing else.
set -eu
here=$(cd "$(dirname "$0")/.." && pwd)
lld="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin/gcc-ld/ld.lld"
[ -x "$lld" ] || { echo "ld-nrf51.sh: no $lld (rustup component rust-src/llvm-tools? see scripts/setup.sh)" >&2; exit 2; }
# rustc passes `-flavor gnu` first (the target's linker flavour is rust-lld's); ld.lld is
# already that flavour.
if [ "${1:-}" = "-flavor" ]; then shift 2; fi
cd "$here/scripts/nrf51"
exec "$lld" "$@"
