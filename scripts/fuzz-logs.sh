#!/usr/bin/env bash
# The log fuzz test (tests/fuzz_logs.rs) at a larger count: seeded mutations of a real log
# (bit flips in every record type, random overwrites, truncations) read by `analyze` and
# `info`; any panic, hang or damaged log taken as valid fails it.
#   scripts/fuzz-logs.sh [CASES (default 100000)] [SEED (default 1)]
set -euo pipefail
cd "$(dirname "$0")/.."
export MJSAFE_FUZZ_CASES="${1:-100000}"
export MJSAFE_FUZZ_SEED="${2:-1}"
# The dev profile is optimised (Cargo.toml): no separate release build.
cargo test --test fuzz_logs -- --nocapture
