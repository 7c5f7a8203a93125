#!/usr/bin/env bash
# README command 1: install what is missing, build, and show the point of mjsafe on the Ch. 4
# bicycle (Example 2, Table 4.1: steering delayed 0.2 s, acceleration 1.5 s, an obstacle that
# becomes known at t = 2.75 s), run headless with three safety filters:
#   the delay-free CBF-QP (4.9)-(4.11), the predictor filter (4.34) and the gamma-m filter (4.67).
# Prints one comparison table (collision, min h, min clearance per filter) and writes the
# overlay plots (trajectories with the obstacle and the barrier radius, h(t), inputs) and the
# three logs into logs/ch4-<UTC time>/.
# With arguments, runs that one scenario instead: scripts/run.sh SCENARIO [--set …]
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
bin="${CARGO_TARGET_DIR:-target}/debug/mjsafe"
stamp="$(date -u +%Y%m%dT%H%M%S)"
if [ $# -gt 0 ]; then
  cargo build --quiet --bin mjsafe
  scenario="$1"
  log="logs/$(basename "$scenario" .toml)-$stamp.mcap"
  "$bin" run "$scenario" --out "$log" "${@:2}"
  "$bin" analyze "$log"
  exit
fi
# The comparison first, from the quickest build: headless (without the rerun SDK) and without
# optimisation (Cargo.toml's `quick` profile: the same results, a third of the cold build), so
# the table comes before the rest is built (docs/performance.md, "Set-up time").
echo "run: building mjsafe for the comparison (headless, unoptimised: cargo build --profile quick --no-default-features)"
cargo build --quiet --profile quick --bin mjsafe --no-default-features
full="$bin"
bin="${CARGO_TARGET_DIR:-target}/quick/mjsafe"
dir="logs/ch4-$stamp"
scenario=scenarios/bicycle_obstacle.toml
"$bin" run "$scenario" --out "$dir/delay_free.mcap"
"$bin" run "$scenario" --out "$dir/predictor.mcap" \
  --set "filter={kind='cbf_qp', l0=4.0, l1=4.0, compensation='predictor'}"
"$bin" run "$scenario" --out "$dir/gamma_m.mcap" \
  --set "filter={kind='gamma_m', l0=4.0, l1=4.0, m=50.0}"
echo
echo "Ch. 4, Example 2: the same delayed bicycle and obstacle, three safety filters"
"$bin" analyze --brief --plot "$dir/plots" "$dir/delay_free.mcap" "$dir/predictor.mcap" "$dir/gamma_m.mcap" \
  2> >(grep -v '^plot: ' >&2)
echo
echo "Only (4.67), which compensates each channel's own delay, keeps h >= 0 and avoids the obstacle."
echo "Overlay plots: $dir/plots/overlay-trajectory.png, overlay-barriers.png, overlay-inputs.png"
# Then everything else: the default build with the rerun feature (`--rerun`, `--rrd`, `replay`).
echo
echo "run: building mjsafe with the rerun viewer support (cargo build), for --rerun, --rrd and replay"
cargo build --quiet --bin mjsafe
echo "run: done: $full has every feature"
