#!/usr/bin/env bash
# Long fuzz runs of every input a user gives mjsafe: scenarios and sweep files
# (tests/fuzz_scenarios.rs) and logs (tests/fuzz_logs.rs), with many more cases than the test
# command runs. Any panic, hang, unclear error or damaged log taken as valid fails it.
#   scripts/fuzz.sh [CASES_PER_SCENARIO (default 9000: ~100k scenario + 36k sweep-file cases)]
#                   [SEED (default: the time)] [LOG_CASES (default 100000)]
set -euo pipefail
cd "$(dirname "$0")/.."
export MJSAFE_FUZZ_SEED="${2:-$(date +%s)}"
echo "fuzz: seed $MJSAFE_FUZZ_SEED"
MJSAFE_FUZZ_CASES="${1:-9000}" cargo test --quiet --test fuzz_scenarios -- --nocapture
scripts/fuzz-logs.sh "${3:-100000}" "$MJSAFE_FUZZ_SEED"
