#!/usr/bin/env bash
# Speed of `host-sim diagnose` on a 30 s recording at 1 kHz of the loaded joint (the
# `inertia` truth of diagnose::synth: a load on the joint the plant file does not have),
# angle and pressures only (no force channels), with a CHECK recording of other excitation;
# and the same with friction + leakage concealed and force channels. A timed command, not a
# test: run it on an idle machine (the load average is printed). Release build, 2 threads.
#
# --write-docs: also writes the rows to docs/figures/diagnose.tsv and their table into
# docs/performance.md (scripts/figures.py), the one place the figures are quoted from.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/write-docs-arg.sh
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
cargo build -q --release -p host-sim --bin host-sim
cargo build -q --release -p host-sim --features test-support --example diagnose_synth
load=$(cut -d' ' -f1-3 /proc/loadavg)
plant=host-sim/plants/reference-1dof.toml
rows=$(printf 'key\tfigure\tmeasured\ttarget\tcheck\n')
rows+=$'\n'$(printf 'load\tload average at the start (1, 5, 15 min)\t%s\t\t' "$load")
for spec in "loaded inertia --no-force" "friction_leakage joint_friction,leakage"; do
  set -- $spec
  name=$1; shift
  target/release/examples/diagnose_synth "$out/$name" "$@" --seconds 30 --seed 42 >/dev/null
  t0=$(date +%s.%N)
  status=0
  target/release/host-sim diagnose --plant "$plant" --recording "$out/$name/train.csv" \
    --check "$out/$name/check.csv" --json "$out/$name/d.json" --threads 2 >/dev/null || status=$?
  t1=$(date +%s.%N)
  secs=$(python3 -c "print(f'{$t1 - $t0:.1f}')")
  verdict=$(python3 -c "import json,sys; d=json.load(open(sys.argv[1])); print(d['verdict'], '+'.join([e['id'] for e in d['effects']] + [r['key'] for r in d['recalibrated']]) or '-')" "$out/$name/d.json")
  check=$(python3 -c "print('met' if $secs <= 10 else 'missed')")
  case "$name" in
    loaded) what="30 s at 1 kHz, loaded joint, angle and pressures only, with CHECK" ;;
    *) what="30 s at 1 kHz, friction + leakage, force channels, with CHECK" ;;
  esac
  rows+=$'\n'$(printf '%s_s\tdiagnose wall time, %s (answer: %s, exit %s)\t%s s\t<= 10 s\t%s' \
    "$name" "$what" "$verdict" "$status" "$secs" "$check")
done
printf '%s\n' "$rows" | python3 scripts/figures.py render
if [ "$write_docs" = 1 ]; then
  printf '%s\n' "$rows" | python3 scripts/figures.py write diagnose
fi
