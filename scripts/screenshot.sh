#!/usr/bin/env bash
# Renders a replayed episode headless into docs/replay.png (the picture in the README):
# runs scenarios/bicycle_obstacle_gamma_m.toml, replays its MCAP log into a rerun recording,
# and has the rerun viewer (PyPI rerun-sdk 0.36.3, from the test venv) screenshot it with
# Mesa's software Vulkan driver (Debian: mesa-vulkan-drivers).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh --test
dpkg -s mesa-vulkan-drivers >/dev/null 2>&1 || { apt-get update -qq; DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mesa-vulkan-drivers >/dev/null; }
venv="${MJSAFE_VENV:-$HOME/.cache/mjsafe/venv}"
cargo build --quiet --bin mjsafe
bin="${CARGO_TARGET_DIR:-target}/debug/mjsafe"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
"$bin" run scenarios/bicycle_obstacle_gamma_m.toml --out "$work/episode.mcap" >/dev/null
"$bin" replay "$work/episode.mcap" --rrd "$work/episode.rrd" >/dev/null
# RUST_LOG=error: the viewer's info and warning notifications (software rasteriser, gRPC port,
# loading) would be drawn as toasts over the plots.
export CI=1 WGPU_BACKEND=vulkan RUST_LOG=error
"$venv/bin/rerun" --headless "$work/episode.rrd" --screenshot-to docs/replay.png --window-size 1200x700
echo "wrote docs/replay.png"
