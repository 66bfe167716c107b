#!/usr/bin/env bash
# Builds terralign and runs the whole test suite: a release build with warnings as errors,
# then (unless TERRALIGN_SKIP_SANITIZE=1) the whole tree built by clang under ASan + UBSan and
# the same tests on it.
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
  # The second compiler: clang builds the whole tree (libraries, tools, tests, benches) with
  # warnings as errors, under AddressSanitizer and UndefinedBehaviorSanitizer, and the suite
  # runs on that build. ARM SoC toolchains are often clang's, and GCC accepts a few things
  # clang refuses (session 44 found three). -O1 with line tables only (-g1): the reports
  # still name file and line. Session 67's host built GCC's -O2 -g1 sanitizer tree in about 20
  # minutes and clang's release tree in about 5 (scripts/test-clang.sh, no longer in CI);
  # test_track.cpp under the sanitizers at -O1 -g1 takes 46 s of CPU with clang, 81 with GCC.
  bash scripts/install-deps.sh clang libclang-rt-14-dev
  CC=clang CXX=clang++ cmake -S . -B build/sanitize -DCMAKE_BUILD_TYPE=RelWithDebInfo \
        -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1 -DNDEBUG" -DTERRALIGN_SANITIZE=ON -DTERRALIGN_WERROR=ON
  cmake --build build/sanitize -j "$jobs"
  # The four longest cases (scripts/end-to-end-cases.sh) are over half of this suite's time
  # under the sanitizers; they run in the release suite above, and the same command-line
  # paths stay under the sanitizers through the shorter track, eval and align cases.
  source scripts/end-to-end-cases.sh
  (cd build/sanitize && ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 \
     ctest --output-on-failure -j "$jobs" -E "$END_TO_END_CASES")
  # The same answers from the other compiler: the firmware's test (its host twin, 16 frames of
  # both trackers) built by clang at -O1 under the sanitizers against GCC's release build.
  build/sanitize/firmware/terralign_firmware_host >build/sanitize/firmware-host.log
  TERRALIGN_HOST_BUILD=build/release bash scripts/same-answers-as-host.sh \
    "clang -O1 (ASan + UBSan)" build/sanitize/firmware-host.log
fi
