#!/usr/bin/env bash
# Instructions one `mjsafe run` spends, by part (callgrind): the measure of the stepping loop's
# cost that does not depend on the machine or on what else it is doing (docs/performance.md,
# "Stop 78"). Wall-clock figures on a shared 2-vCPU machine vary by up to 1.6x between
# invocations of the same binary; these counts repeat to a few parts per million.
#
#   scripts/instructions.sh [BINARY] [SCENARIO] [--set KEY=VALUE ...]
#
# BINARY defaults to $CARGO_TARGET_DIR/debug/mjsafe (or target/debug/mjsafe). Measure a binary
# from `cargo build --bin mjsafe`: the one `cargo test` leaves in the same place is built under
# [profile.test] (debug assertions on, 256 codegen units) and counts about 8 % more.
# SCENARIO defaults to the 25-car file of issue 49, data/commonroad/USA_US101-5_1_T-1.xml.
set -euo pipefail
cd "$(dirname "$0")/.."
binary=${1:-${CARGO_TARGET_DIR:-target}/debug/mjsafe}
scenario=${2:-data/commonroad/USA_US101-5_1_T-1.xml}
shift $(($# < 2 ? $# : 2))
if ! command -v valgrind > /dev/null; then
  apt-get install -y -qq valgrind > /dev/null
fi
[ -x "$binary" ] || { echo "instructions.sh: no mjsafe binary at $binary (cargo build --bin mjsafe)" >&2; exit 2; }
[ -f "$scenario" ] || { echo "instructions.sh: no scenario at $scenario" >&2; exit 2; }
work=$(mktemp -d)
[ -z "${KEEP:-}" ] || echo "kept: $work" >&2
trap '[ -n "${KEEP:-}" ] || rm -rf "$work"' EXIT
if ! valgrind --tool=callgrind --callgrind-out-file="$work/callgrind.out" \
  "$binary" run "$scenario" --out "$work/run.mcap" --json "$@" > "$work/summary.json" 2> "$work/stderr"; then
  echo "instructions.sh: the run failed:" >&2
  tail -5 "$work/stderr" >&2
  exit 1
fi
callgrind_annotate --inclusive=yes "$work/callgrind.out" 2> /dev/null > "$work/inclusive.txt"
steps=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["steps"])' "$work/summary.json")
# Part, and the function whose inclusive count it is: callgrind_annotate lists a function
# once per source file its instructions come from (inlining) and once as its callers see it;
# the largest of those lines is the whole inclusive count.
parts=(
  "stepping loop|mjsafe::episode::Episode::advance"
  "  control callback|<mjsafe::episode::control::ControlLoop as mjsafe::plant::Controller>::input"
  "    recursive prediction|mjsafe_maths::predictor::PredictorContext::predict_into"
  "    reach tests|mjsafe::episode::reach::Reach::mark"
  "  records to sinks|<mjsafe::log::Tee as mjsafe::log::Sink>::record"
  "log writer thread (zstd, writes)|mjsafe::log::mcap_writer::DataSection<W>::write"
  "analysis after the run|mjsafe::analyze::analyze_file_with"
)
printf '%s: %s steps (%s)\n' "$scenario" "$steps" "$binary"
printf '%-34s %15s %14s\n' part instructions "per step"
for part in "${parts[@]}"; do
  name=${part%%|*}
  function=${part#*|}
  count=$(awk -v f="$function" '{
      line = $0; sub(/ \[[^]]*\]$/, "", line)
      n = length(line) - length(f)
      if (n > 0 && substr(line, n + 1) == f && substr(line, n, 1) == ":") {
        c = $1; gsub(",", "", c); if (c + 0 > best) best = c + 0
      }
    } END { if (best > 0) printf "%.0f", best }' "$work/inclusive.txt")
  if [ -z "$count" ]; then
    printf '%-34s %15s %14s\n' "$name" "-" "-"
  else
    printf '%-34s %15s %14s\n' "$name" "$count" "$((count / steps))"
  fi
done
total=$(awk '/PROGRAM TOTALS/ {gsub(",", "", $1); print $1; exit}' "$work/inclusive.txt")
printf '%-34s %15s %14s\n' "whole process" "$total" "$((total / steps))"
