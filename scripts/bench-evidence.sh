#!/usr/bin/env bash
# The diagnosis on recordings it was not written against: the independent rig's evidence
# base (host-sim/tests/support/testrig.rs: forms unlike the candidates', mis-set keys,
# nominal data on several time bases, out-of-catalogue forms), every case on the tuning
# seeds and on the held-out seeds, sensitivity and honesty apart (release build; about 15
# minutes on 2 cores). The per-case table goes to stdout; the rates are the last rows.
#
# --write-docs: also writes the rates to docs/figures/evidence.tsv and their table into
# docs/performance.md (scripts/figures.py), the one place the figures are quoted from.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/write-docs-arg.sh
log=$(mktemp)
trap 'rm -f "$log"' EXIT
cargo test -q --release -p host-sim --features test-support --test diagnose_independent -- \
  --ignored --nocapture --exact evidence_full_matrix | tee "$log"
rows=$( (printf 'key\tfigure\tmeasured\ttarget\tcheck\n'; sed -n 's/^FIGURE\t//p' "$log") )
if [ "$(printf '%s\n' "$rows" | wc -l)" -lt 2 ]; then
  echo "bench-evidence.sh: the matrix printed no FIGURE rows" >&2
  exit 1
fi
printf '%s\n' "$rows" | python3 scripts/figures.py render
if [ "$write_docs" = 1 ]; then
  printf '%s\n' "$rows" | python3 scripts/figures.py write evidence
fi
