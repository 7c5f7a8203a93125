#!/usr/bin/env bash
# Runs-to-first-violation of PSY-TaLiRo (psy-taliro from PyPI: DualAnnealing and UniformRandom)
# on the five problems of scripts/falsify-study.sh (same boxes, budgets and seeds), driving
# `mjsafe run --json` as a black box; prints Markdown table rows like falsify-study.sh's
# (docs/falsification.md, docs/psytaliro-results.md). The black box and the score → robustness
# map: scripts/psytaliro_study.py. Makes a venv at $HOME/.cache/mjsafe/psytaliro-venv.
#   scripts/psytaliro-study.sh [MJSAFE_BINARY] [OUT_DIR]     (SEEDS="1 2", ONLY=<problem> to narrow)
# One search at a time, one mjsafe run at a time (no parallel evaluation).
set -euo pipefail
cd "$(dirname "$0")/.."
mjsafe="${1:-target/release/mjsafe}"
out="${2:-logs/psytaliro-study}"
seeds="${SEEDS:-1 2 3 4 5 6 7 8 9 10}"
psy_taliro_version=3.2.0   # the newest on PyPI (Python >= 3.10, < 3.13)
venv="$HOME/.cache/mjsafe/psytaliro-venv"
if ! "$venv/bin/python" -c "import importlib.metadata as m, sys; sys.exit(m.version('psy-taliro') != '$psy_taliro_version')" 2>/dev/null; then
  # (The first of these that runs: a pyenv shim can name a version it does not select.)
  for python in python3.12 python3.11 python3.10 python3; do
    "$python" -c 'import sys; sys.exit(not (3, 10) <= sys.version_info[:2] < (3, 13))' 2>/dev/null && break
  done
  "$python" -m venv "$venv"
  "$venv/bin/pip" install --quiet "psy-taliro==$psy_taliro_version"
fi
only=()
[ -n "${ONLY:-}" ] && only=(--only "$ONLY")
# shellcheck disable=SC2086
exec "$venv/bin/python" scripts/psytaliro_study.py "$mjsafe" "$out" --seeds $seeds "${only[@]}"
