#!/usr/bin/env bash
# Checks that the fixed-point evaluation path (src/fixed_point.rs) is fit for an FPU-less core:
# built for thumbv6m-none-eabi (Cortex-M0), every function of `fixed_point` except the
# documented float edges (`*_from_f32`, `from_params`, `prescale`) may call only memory
# helpers (memcpy, memset, ...) and each other: no soft-float (`__aeabi_f*`, `__aeabi_d*`),
# no 64-bit multiply or divide (`__aeabi_lmul`, `__aeabi_ldivmod`, `__muldi3`, ...: both laws
# use 32-bit products only), no panic, no call into another crate.
# Usage: bash scripts/check-fixed-no-float.sh   (exit status 1 on a forbidden call)
set -euo pipefail
cd "$(dirname "$0")/.."
target=thumbv6m-none-eabi
cargo rustc -p pam-firmware --lib --target "$target" --release -- --emit=asm,link >&2
asm=$(ls -t target/"$target"/release/deps/pam_firmware-*.s | head -n 1)
awk '
  /^[_A-Za-z][_A-Za-z0-9$.]*:[ \t]*$/ { fn = substr($1, 1, length($1) - 1); next }
  fn ~ /11fixed_point/ && fn !~ /from_f32|from_params|8prescale/ && $1 == "bl" {
    callee = $2
    if (callee ~ /^\.L/) next
    ok = callee ~ /^__aeabi_(memcpy[48]?|memmove[48]?|memclr[48]?|memset[48]?)$/ \
      || (callee ~ /11fixed_point/ && callee !~ /from_f32|from_params|8prescale/)
    printf "%-8s %s -> %s\n", (ok ? "ok" : "FORBIDDEN"), fn, callee
    if (!ok) bad = 1
    n++
  }
  END {
    if (n == 0) { print "no calls found: is the assembly as expected?"; exit 1 }
    exit bad
  }
' "$asm" | sort -u
echo "fixed-point path: no soft-float, no 64-bit multiply or divide, no panic, no foreign call ($asm)" >&2
