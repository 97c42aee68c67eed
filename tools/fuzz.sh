#!/usr/bin/env bash
# Run every cargo-fuzz target for a set time with debug assertions on, and print a
# table of what each did. Needs the nightly toolchain and cargo-fuzz (installed if
# missing). Usage: tools/fuzz.sh [seconds per target, default 600] [target ...]
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
secs=${1:-600}
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(candump_line dbc config state pipeline)
command -v cargo-fuzz >/dev/null || cargo install -q cargo-fuzz
echo "| target | seconds | runs | exec/s | coverage (edges) | result |"
echo "| --- | --- | --- | --- | --- | --- |"
for t in "${targets[@]}"; do
  log=$(mktemp)
  mkdir -p "corpus/$t"
  if cargo +nightly fuzz run -a "$t" "corpus/$t" -- -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 >"$log" 2>&1; then
    result=ok
  else
    result="FAILED (see fuzz/artifacts/$t)"
  fi
  runs=$(grep -oE 'Done [0-9]+ runs' "$log" | tail -1 | grep -oE '[0-9]+' || echo "?")
  cov=$(grep -oE 'cov: [0-9]+' "$log" | tail -1 | grep -oE '[0-9]+' || echo "?")
  rate="?"
  [ "$runs" != "?" ] && rate=$((runs / secs))
  echo "| $t | $secs | $runs | $rate | $cov | $result |"
  [ "$result" = ok ] || tail -40 "$log" >&2
  rm -f "$log"
done
