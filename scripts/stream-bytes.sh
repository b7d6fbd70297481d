#!/usr/bin/env bash
# Bytes per control tick of the board's stream on the defmt wire (a measurement, not a test):
# builds src/bin/stream_bytes.rs (the board's per-tick `defmt::info!("stream {=[u8]}", ..)` over
# the 500-tick embedded sensor trace, nothing else logged), runs it on QEMU netduinoplus2 and
# splits its raw defmt output (semihosting stdout: the same rzCOBS frames defmt-rtt carries,
# each ended by a 0x00) into frames. Prints mean / max bytes per record and the RTT throughput
# that implies at PAM_TICK_HZ (default 1000). Exit status 2 if a tool is missing or the
# decoded records are not one per tick.
set -euo pipefail
cd "$(dirname "$0")/.."
hz=${PAM_TICK_HZ:-1000}
for tool in qemu-system-arm defmt-print python3; do
  command -v "$tool" >/dev/null 2>&1 || { echo "stream-bytes.sh: '$tool' not found (scripts/setup.sh)" >&2; exit 2; }
done
cargo build -q -p pam-firmware --bin stream_bytes --features pam-firmware/stream-bytes \
  --release --target thumbv7em-none-eabihf
elf=${CARGO_TARGET_DIR:-target}/thumbv7em-none-eabihf/release/stream_bytes
raw=$(mktemp /tmp/stream-bytes.XXXXXX)
trap 'rm -f "$raw"' EXIT
timeout 120 qemu-system-arm -machine netduinoplus2 -nographic -monitor none -serial none \
  -semihosting-config enable=on,target=native -kernel "$elf" >"$raw"
records=$(defmt-print -e "$elf" <"$raw" | grep -c '^INFO  stream \[' || true)
python3 - "$raw" "$records" "$hz" <<'PY'
import sys
raw, records, hz = open(sys.argv[1], "rb").read(), int(sys.argv[2]), int(sys.argv[3])
# The stream frames: 46-byte record + 2-byte format index + 1-byte length, rzCOBS-encoded
# (>= 26 bytes each); the few shorter frames are defmt-semihosting's own.
frames = [len(f) + 1 for f in raw.split(b"\x00")[:-1]]
stream = [n for n in frames if n >= 20]
if records == 0 or len(stream) != records:
    print(f"stream-bytes.sh: {records} decoded records but {len(stream)} frames", file=sys.stderr)
    sys.exit(2)
mean, worst = sum(stream) / len(stream), max(stream)
bound = 2 + 1 + 46
bound = bound + -(-bound // 7) + 1
print(f"records: {len(stream)} (one per tick of the trace)")
print(f"bytes per record on the wire: mean {mean:.1f}, max {worst}, bound {bound} (rzCOBS worst case)")
print(f"RTT up-channel throughput at {hz} Hz: mean {mean * hz / 1000:.1f} kB/s, "
      f"max-record {worst * hz / 1000:.1f} kB/s, bound {bound * hz / 1000:.1f} kB/s")
PY
