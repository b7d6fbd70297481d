#!/usr/bin/env bash
# How the cascade / PD / PID comparison depends on how fast the set-point moves.
# For each move duration T (0 = the jumps of scenarios/step.toml and random.toml), all three
# laws are re-tuned on the suite with that T (tune_pid --transition-s T, the same procedure
# and cost as config/control_tuned.toml, starting also from its gains) and scored on it
# (suite_transition). Prints one Markdown row per T. ~1 min per T on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
ts=("$@")
if [ ${#ts[@]} -eq 0 ]; then ts=(0 0.05 0.1 0.15 0.2 0.3 0.5); fi
cargo build --release -q -p host-sim --example tune_pid --example suite_transition
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
for t in "${ts[@]}"; do
  cp config/control_tuned.toml "$dir/t$t.toml"
  target/release/examples/tune_pid --transition-s "$t" --out "$dir/t$t.toml" >/dev/null 2>&1
  target/release/examples/suite_transition "$dir/t$t.toml" "$t" | tail -1
done
