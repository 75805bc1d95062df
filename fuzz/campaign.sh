#!/usr/bin/env bash
# Runs every fuzz target in turn for SECONDS each (default 600), from the committed corpora.
# Usage: fuzz/campaign.sh [SECONDS] [TARGET...]   (needs nightly and cargo-fuzz)
# Prints one line per target with its executions; stops at the first crash (its input is
# left under fuzz/artifacts/TARGET/).
# What a campaign finds goes to fuzz/campaign/TARGET (ignored by git), never into the
# committed corpus; afterwards only the inputs that add coverage are merged into
# fuzz/corpus/TARGET (libFuzzer's -merge=1), so the committed corpus stays minimized.
set -euo pipefail
cd "$(dirname "$0")"
seconds=${1:-600}
shift || true
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
  mapfile -t targets < <(cargo +nightly fuzz list)
fi
for target in "${targets[@]}"; do
  log=$(mktemp)
  mkdir -p "campaign/$target" "corpus/$target"
  if ! cargo +nightly fuzz run "$target" "campaign/$target" "corpus/$target" -- \
      -max_total_time="$seconds" -print_final_stats=1 >"$log" 2>&1; then
    grep -A4 'panicked' "$log" || tail -n 40 "$log"
    echo "$target: FAILED (see fuzz/artifacts/$target/)"
    exit 1
  fi
  runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo "?")
  cargo +nightly fuzz run "$target" "corpus/$target" "campaign/$target" -- -merge=1 >"$log" 2>&1
  echo "$target: ${seconds} s, ${runs} executions, no failure; corpus $(ls "corpus/$target" | wc -l) inputs"
  rm -f "$log"
done
