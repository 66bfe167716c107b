#!/usr/bin/env bash
# Builds the libFuzzer targets with clang (ASan + UBSan; the libraries with warnings as errors,
# CI's one clang build of them) and runs each for SECONDS (default 30), starting from the
# committed corpus in fuzz/corpus/<target>. New inputs go to a scratch
# folder; a crash stops the run with a non-zero exit and leaves the input in fuzz/artifacts.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-30}
bash scripts/install-deps.sh clang libclang-rt-14-dev
CC=clang CXX=clang++ cmake -S . -B build/fuzz -DCMAKE_BUILD_TYPE=RelWithDebInfo -DTERRALIGN_FUZZ=ON -DTERRALIGN_WERROR=ON \
  -DTERRALIGN_SANITIZE=ON -DTERRALIGN_BUILD_TESTS=OFF -DTERRALIGN_BUILD_TOOLS=OFF -DTERRALIGN_BUILD_BENCH=OFF >/dev/null
cmake --build build/fuzz -j "$(nproc)"
mkdir -p fuzz/artifacts
for t in manifest camera world_file geotiff pfm pose weights; do
  work=$(mktemp -d)
  echo "fuzz_$t: ${seconds} s"
  status=0
  build/fuzz/fuzz/fuzz_$t "$work" fuzz/corpus/$t -max_total_time="$seconds" -rss_limit_mb=2048 \
    -artifact_prefix=fuzz/artifacts/$t- -print_final_stats=1 >"$work.log" 2>&1 || status=$?
  grep -E "^(stat::number_of_executed_units|stat::peak_rss_mb|SUMMARY)" "$work.log" || true
  [ "$status" -eq 0 ] || tail -40 "$work.log"
  rm -f "$work.log"
  rm -rf "$work"
  [ "$status" -eq 0 ] || { echo "fuzz_$t found a failure (see fuzz/artifacts)"; exit 1; }
done
