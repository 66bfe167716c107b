#!/usr/bin/env bash
# Builds the libFuzzer targets with clang (ASan + UBSan, with line tables for the reports; the
# libraries they link, geo and nn, with warnings as errors) and runs each for SECONDS
# (default 30), FUZZ_JOBS targets at a time (default: one per core; each is one process on one
# core), starting from the committed corpus in fuzz/corpus/<target>. New inputs go to a scratch
# folder; a crash fails the run with a non-zero exit and leaves the input in fuzz/artifacts.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-30}
jobs=${FUZZ_JOBS:-$(nproc)}
targets=(manifest camera world_file geotiff pfm pose weights)
bash scripts/install-deps.sh clang libclang-rt-14-dev
CC=clang CXX=clang++ cmake -S . -B build/fuzz -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG" \
  -DTERRALIGN_FUZZ=ON -DTERRALIGN_WERROR=ON -DTERRALIGN_SANITIZE=ON -DTERRALIGN_BUILD_TESTS=OFF -DTERRALIGN_BUILD_TOOLS=OFF \
  -DTERRALIGN_BUILD_BENCH=OFF >/dev/null
# Only the targets and what they link: the renderer and the trackers read no outside input.
cmake --build build/fuzz -j "$(nproc)" --target "${targets[@]/#/fuzz_}"
mkdir -p fuzz/artifacts

# One target's run; its report is printed in one piece when it ends.
fuzz_one() {
  local t=$1 work status=0
  work=$(mktemp -d)
  build/fuzz/fuzz/fuzz_$t "$work" fuzz/corpus/$t -max_total_time="$seconds" -rss_limit_mb=2048 \
    -artifact_prefix=fuzz/artifacts/$t- -print_final_stats=1 >"$work.log" 2>&1 || status=$?
  {
    echo "fuzz_$t: ${seconds} s"
    grep -E "^(stat::number_of_executed_units|stat::peak_rss_mb|SUMMARY)" "$work.log" || true
    [ "$status" -eq 0 ] || { tail -40 "$work.log"; echo "fuzz_$t found a failure (see fuzz/artifacts)"; }
  } >"$work.report"
  cat "$work.report"
  rm -rf "$work" "$work.log" "$work.report"
  return "$status"
}

failed=0
for ((i = 0; i < ${#targets[@]}; i += jobs)); do
  pids=()
  for t in "${targets[@]:i:jobs}"; do
    fuzz_one "$t" & pids+=($!)
  done
  for p in "${pids[@]}"; do wait "$p" || failed=1; done
done
exit "$failed"
