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

# --- Targets: QEMU, defmt decoder, flip-link, size tool ---------------------
# Versions: defmt-print 1.2.0 decodes the defmt 1.x wire format (versions 3, 4) the firmware
# uses; flip-link 0.1.12 (latest, links with rustc's rust-lld).
as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }

if ! command -v qemu-system-arm >/dev/null 2>&1; then
  say "apt-get install qemu-system-arm"
  as_root apt-get update
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends qemu-system-arm
fi

installed_tools=$(cargo install --list)
cargo_tool() { # cargo_tool <crate> <version> <binary>
  if ! command -v "$3" >/dev/null 2>&1 || ! grep -qx "$1 v$2:" <<<"$installed_tools"; then
    say "cargo install $1 --version $2 --locked"
    cargo install "$1" --version "$2" --locked
  fi
}
cargo_tool defmt-print 1.2.0 defmt-print
cargo_tool flip-link 0.1.12 flip-link

# llvm-size for scripts/bench-mcu.sh: rustup's llvm-tools, else Debian's arm-none-eabi-size.
if ! rustup component list --installed 2>/dev/null | grep -q '^llvm-tools'; then
  say "rustup component add llvm-tools"
  if ! rustup component add llvm-tools; then
    if ! command -v arm-none-eabi-size >/dev/null 2>&1; then
      say "llvm-tools unavailable: apt-get install binutils-arm-none-eabi"
      as_root apt-get update
      as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends binutils-arm-none-eabi
    fi
  fi
fi

# clippy for the lint step of scripts/test.sh.
if ! cargo clippy --version >/dev/null 2>&1; then
  say "rustup component add clippy"
  rustup component add clippy
fi
# rustfmt for the formatting check of scripts/test.sh.
if ! cargo fmt --version >/dev/null 2>&1; then
  say "rustup component add rustfmt"
  rustup component add rustfmt
fi

# Plots (host-sim --plot, demo, diagnosis reports) lay out text with a TrueType font read at run
# time (host-sim/src/io/plot.rs): install DejaVu Sans when no usable font is present.
if [ -z "${HOST_SIM_FONT:-}" ] && ! ls /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf \
    /usr/share/fonts/TTF/DejaVuSans.ttf /usr/share/fonts/dejavu/DejaVuSans.ttf \
    /usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf >/dev/null 2>&1; then
  say "apt-get install fonts-dejavu-core"
  as_root apt-get update
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends fonts-dejavu-core
fi
