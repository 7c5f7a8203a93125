#!/usr/bin/env bash
# The falsification benchmark of issue 53 (docs/falsification.md, "A benchmark with a held-out
# half"): ten rare-failure boxes in a tuning and a test half, their measured rates, and the
# searches' runs to the first qualified violation over seeds 1..30, with pycma and PSY-TaLiRo's
# dual annealing as anchors.
#   scripts/falsify-bench.sh rate  [MJSAFE_BINARY] [OUT_DIR]        (DRAWS=2000; HALF, ONLY as for study)
#   scripts/falsify-bench.sh study [MJSAFE_BINARY] [OUT_DIR]        (SEEDS=1..30, METHODS=guided,cmaes,random,pycma,psytaliro,
#                                                                     HALF=all|tuning|test|fresh, ONLY=<problem>)
#   scripts/falsify-bench.sh cost  [MJSAFE_BINARY] [OUT_DIR]        the searches' own work on one thread
#                                                                    (METHODS, HALF, ONLY as for study)
# Runs with the venv of scripts/setup.sh --test (the mjsafe Python package: pycma's candidates run
# in-process), into which it installs pycma (PyPI `cma`) and psy-taliro. Results are cached under OUT_DIR: an
# interrupted study continues.
set -euo pipefail
cd "$(dirname "$0")/.."
command=${1:?rate or study}
mjsafe="${2:-${CARGO_TARGET_DIR:-target}/debug/mjsafe}"
out="${3:-logs/falsify-bench}"
python="${MJSAFE_VENV:-$HOME/.cache/mjsafe/venv}/bin/python"
cma_version=4.5.0   # the newest on PyPI
psy_taliro_version=3.2.0   # the newest on PyPI; beside the readers without a conflict
for package in "cma==$cma_version" "psy-taliro==$psy_taliro_version"; do
  if ! "$python" -c "import importlib.metadata as m, sys; sys.exit(m.version('${package%%==*}') != '${package##*==}')" 2>/dev/null; then
    "$python" -m pip install --quiet "$package"
  fi
done
args=()
[ -n "${ONLY:-}" ] && args+=(--only "$ONLY")
case "$command" in
  rate) args+=(--draws "${DRAWS:-2000}" --half "${HALF:-all}");;
  study) args+=(--seeds "${SEEDS:-1..30}" --methods "${METHODS:-guided,cmaes,random,pycma,psytaliro}" --half "${HALF:-all}");;
  cost) args+=(--methods "${METHODS:-guided,cmaes,random}" --half "${HALF:-all}");;
esac
exec "$python" -W ignore scripts/falsify_bench.py "$command" "$mjsafe" "$out" "${args[@]}"
