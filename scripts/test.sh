#!/usr/bin/env bash
# README command 2: install what is missing (including the Python readers used as independent
# checks), then run the whole test suite: format, lint, unit, integration and fidelity tests,
# then the Python package's tests (python/tests).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh --test
export MJSAFE_PYTHON="${MJSAFE_VENV:-$HOME/.cache/mjsafe/venv}/bin/python"
# CommonRoad's own reader (PyPI commonroad-io) in a venv of its own: tests/commonroad.rs.
export MJSAFE_CR_PYTHON="${MJSAFE_CR_VENV:-$HOME/.cache/mjsafe/cr-venv}/bin/python"
# Its route planner (PyPI commonroad-route-planner, on an older commonroad-io): the route.
export MJSAFE_CR_ROUTE_PYTHON="${MJSAFE_CR_ROUTE_VENV:-$HOME/.cache/mjsafe/cr-route-venv}/bin/python"
# As root, setup.sh --test installed Slurm: tests/cluster.rs must run it, not skip.
[ "$(id -u)" = 0 ] && export MJSAFE_REQUIRE_SLURM="${MJSAFE_REQUIRE_SLURM:-1}"
cargo fmt --check
cargo clippy --quiet --all-targets -- -D warnings
# The Python package's crate (python/, a workspace member the root's commands leave out).
PYO3_PYTHON="$MJSAFE_PYTHON" cargo clippy --quiet -p mjsafe-python --all-targets -- -D warnings
# The public API's rustdoc (docs/writing-a-filter.md links into it) builds without a warning.
RUSTDOCFLAGS="-D warnings" cargo doc --quiet --no-deps
# The documentation's examples compile (`--all-targets` leaves doctests out).
cargo test --quiet --doc
# The examples as programs (tests/examples.rs runs them; `--all-targets` builds them only as tests).
cargo build --quiet --examples
cargo test --all-targets -- --nocapture 2>&1 | tee "${MJSAFE_TEST_LOG:-/dev/null}"
# The Python package (python/, installed into the venv by setup.sh --test): its tests, with the
# mjsafe binary just built as the command line they compare with.
MJSAFE="${CARGO_TARGET_DIR:-target}/debug/mjsafe" "${MJSAFE_VENV:-$HOME/.cache/mjsafe/venv}/bin/python" \
  -m pytest -q -p no:cacheprovider python/tests 2>&1 | tee -a "${MJSAFE_TEST_LOG:-/dev/null}"
