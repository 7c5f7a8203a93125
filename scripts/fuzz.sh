#!/usr/bin/env bash
# Long fuzz run of the inputs a user writes (scenarios, sweep files): the in-process suite of
# tests/fuzz_scenarios.rs with many more cases than the test command runs.
#   scripts/fuzz.sh [CASES_PER_FILE] [SEED]     (default 9000 per file: ~100k scenario cases)
set -euo pipefail
cd "$(dirname "$0")/.."
export MJSAFE_FUZZ_CASES="${1:-9000}"
export MJSAFE_FUZZ_SEED="${2:-$(date +%s)}"
echo "fuzz: $MJSAFE_FUZZ_CASES cases per file, seed $MJSAFE_FUZZ_SEED"
cargo test --quiet --test fuzz_scenarios -- --nocapture --test-threads 1
