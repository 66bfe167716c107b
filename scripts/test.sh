#!/usr/bin/env bash
# Builds terralign and runs the whole test suite: a release build with warnings as errors,
# then (unless TERRALIGN_SKIP_SANITIZE=1) an ASan + UBSan build of the same tests.
# On a fresh Debian 12 machine this installs what it needs first.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
jobs=$(nproc)

cmake -S . -B build/release -DCMAKE_BUILD_TYPE=Release -DTERRALIGN_WERROR=ON
cmake --build build/release -j "$jobs"
(cd build/release && ctest --output-on-failure -j "$jobs")

# The installed package works for a downstream project.
prefix=$(mktemp -d)
cmake --install build/release --prefix "$prefix" >/dev/null
cmake -S tests/install -B build/consumer -DCMAKE_PREFIX_PATH="$prefix" >/dev/null
cmake --build build/consumer -j "$jobs" >/dev/null
build/consumer/consumer
rm -rf "$prefix"

if [ "${TERRALIGN_SKIP_SANITIZE:-0}" != "1" ]; then
  # Line tables only (-g1): the sanitizers' reports name file and line, and the build takes
  # about an eighth less time than with full debug information (test_track.cpp: 128 s, 145 s).
  cmake -S . -B build/sanitize -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG" \
        -DTERRALIGN_SANITIZE=ON -DTERRALIGN_WERROR=ON -DTERRALIGN_BUILD_BENCH=OFF
  cmake --build build/sanitize -j "$jobs"
  # The three longest cases (scripts/end-to-end-cases.sh) are over half of this suite's time
  # under the sanitizers; they run in the release suite above and in clang's, and the same
  # command-line paths stay under the sanitizers through the shorter track, eval and align cases.
  source scripts/end-to-end-cases.sh
  (cd build/sanitize && ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 \
     ctest --output-on-failure -j "$jobs" -E "$END_TO_END_CASES")
fi
