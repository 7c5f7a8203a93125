#!/usr/bin/env bash
# README command 1: install what is missing, build, run the default scenario headless
# (writes logs/<scenario>-<time>.mcap and prints a one-line summary, then the analysis).
# Extra arguments replace the scenario: scripts/run.sh scenarios/bicycle_obstacle_nodelay.toml
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
cargo build --quiet --bin mjsafe
bin="${CARGO_TARGET_DIR:-target}/debug/mjsafe"
scenario="${1:-scenarios/bicycle_obstacle.toml}"
log="logs/$(basename "$scenario" .toml)-$(date -u +%Y%m%dT%H%M%S).mcap"
"$bin" run "$scenario" --out "$log" "${@:2}"
"$bin" analyze "$log"
