#!/usr/bin/env bash
# Regenerates the README's figures (docs/figures/*.svg: vector, for papers) from fresh runs:
#   ch4-trajectory.svg, ch4-barriers.svg, ch4-inputs.svg: Ch. 4, Example 2 with the delay-free
#     CBF-QP (4.9)-(4.11), the predictor filter (4.34) and the gamma-m filter (4.67) overlaid
#     (as the reference's Figs. 4.6/4.7);
#   sweep-min_h-vs-delay.svg: min h against the acceleration delay D2 (0.25 ... 2 s; (4.67)
#     needs D1 = 0.2 <= D2) for the delay-free CBF-QP and (4.67) (a sweep, `mjsafe plot-sweep`);
#   falsify-convergence.svg: best score against runs of `mjsafe falsify` (guided search) and random
#     search on (4.67) with the delay-free baseline (docs/falsification.md, problem 1, seed 7).
# The text is laid out with the font embedded in mjsafe (DejaVu Sans), so the figures do not
# depend on the machine; the SVGs name that font, falling back to the reader's sans-serif.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
cargo build --quiet --bin mjsafe
bin="${CARGO_TARGET_DIR:-target}/debug/mjsafe"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
scenario=scenarios/bicycle_obstacle.toml
"$bin" run "$scenario" --out "$work/delay_free.mcap"
"$bin" run "$scenario" --out "$work/predictor.mcap" \
  --set "filter={kind='cbf_qp', l0=4.0, l1=4.0, compensation='predictor'}"
"$bin" run "$scenario" --out "$work/gamma_m.mcap" \
  --set "filter={kind='gamma_m', l0=4.0, l1=4.0, m=50.0}"
"$bin" analyze --brief --plot "$work/plots" --plot-format svg "$work/delay_free.mcap" "$work/predictor.mcap" "$work/gamma_m.mcap"
mkdir -p docs/figures
for f in trajectory barriers inputs; do
  cp "$work/plots/overlay-$f.svg" "docs/figures/ch4-$f.svg"
done
"$bin" sweep "$scenario" --out "$work/sweep" --threads 2 \
  --grid "delays.acceleration=0.25,0.5,0.75,1.0,1.25,1.5,1.75,2.0" \
  --grid "filter={kind='cbf_qp', l0=4.0, l1=4.0},{kind='gamma_m', l0=4.0, l1=4.0, m=50.0}" >/dev/null
"$bin" plot-sweep "$work/sweep" --x delays.acceleration --y min_h --out docs/figures/sweep-min_h-vs-delay.svg
bicycle=scenarios/bicycle_obstacle_gamma_m.toml
"$bin" falsify "$bicycle" --range vehicle.initial_state.0=-26..-16 --range obstacles.0.centre.1=-3..3 \
  --range delays.acceleration=0.5..2.0:0.1 --baseline delays.steering=0.0 --baseline delays.acceleration=0.0 \
  --baseline "filter={kind='cbf_qp', l0=4.0, l1=4.0}" --budget 120 --worst --seed 7 --compare-random \
  --out "$work/falsify" >/dev/null
cp "$work/falsify/convergence.svg" docs/figures/falsify-convergence.svg
ls -l docs/figures
