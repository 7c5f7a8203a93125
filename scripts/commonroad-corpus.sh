#!/usr/bin/env bash
# Every CommonRoad file under the given directories, run with its defaults and checked against
# CommonRoad's own reader: what a user bringing a set of files gets (docs/commonroad.md, "Files
# from elsewhere"). Each XML file holding a <commonRoad> root (Git LFS pointers and solution files
# are skipped) runs with `mjsafe run FILE`; a run's log then goes through tests/commonroad_check.py
# (road users against commonroad-io's `state_at_time` at every recorded step, contacts against its
# shapes, the goal against `GoalRegion.is_reached`), in the venv scripts/setup.sh --test makes
# (or $MJSAFE_CR_PYTHON). Prints one line per file, then the counts.
# --set KEY=VALUE (repeatable) passes an override to every run, e.g. --set 'filter={kind="none"}'
# for the nominal alone.
#   scripts/commonroad-corpus.sh [--mjsafe BINARY] [--out DIR] [--set KEY=VALUE]... DIR...
set -euo pipefail
cd "$(dirname "$0")/.."
mjsafe="${CARGO_TARGET_DIR:-target}/debug/mjsafe"
out=logs/commonroad-corpus
sets=()
while [[ $# -gt 0 && $1 == --* ]]; do
  case $1 in
    --mjsafe) mjsafe=$2; shift 2 ;;
    --out) out=$2; shift 2 ;;
    --set) sets+=(--set "$2"); shift 2 ;;
    *) echo "commonroad-corpus: unknown option $1" >&2; exit 2 ;;
  esac
done
[[ $# -gt 0 ]] || { echo "usage: scripts/commonroad-corpus.sh [--mjsafe BINARY] [--out DIR] [--set KEY=VALUE]... DIR..." >&2; exit 2; }
python="${MJSAFE_CR_PYTHON:-$HOME/.cache/mjsafe/cr-venv/bin/python}"
"$python" -c "import commonroad" 2>/dev/null || { echo "commonroad-corpus: no commonroad-io at $python (scripts/setup.sh --test makes it)" >&2; exit 2; }
mkdir -p "$out"
declare -A seen
ran=0 refused=0 checked=0 mismatched=0
while IFS= read -r -d '' xml; do
  head -c 4096 "$xml" | grep -q "<commonRoad" || continue
  digest=$(sha256sum "$xml" | cut -c1-16)
  [[ -z ${seen[$digest]:-} ]] || continue
  seen[$digest]=1
  log="$out/$digest.mcap"
  if ! line=$("$mjsafe" run "$xml" --out "$log" "${sets[@]}" 2>&1); then
    refused=$((refused + 1))
    echo "refused  $xml: $(grep '^error' <<<"$line" | head -1)"
    continue
  fi
  ran=$((ran + 1))
  goal=$("$mjsafe" analyze "$log" --json | python3 -c "import json, sys; d = json.load(sys.stdin); d = d[0] if isinstance(d, list) else d; t = d.get('time_to_goal'); print('none' if t is None else repr(float(t)))")
  if check=$("$python" tests/commonroad_check.py "$xml" "$log" --time-to-goal "$goal" --contacts 2>&1) && grep -q " 0 mismatches" <<<"$check"; then
    checked=$((checked + 1))
    echo "ran      $xml: $(tail -1 <<<"$line")"
  else
    mismatched=$((mismatched + 1))
    echo "MISMATCH $xml: $(tail -2 <<<"$check" | tr '\n' ' ')"
  fi
done < <(find "$@" -name '*.xml' -not -name 'solution*' -print0 | sort -z)
echo "files: $((ran + refused)); ran: $ran ($checked agree with commonroad-io, $mismatched do not); refused with one line: $refused"
[[ $mismatched -eq 0 ]]
