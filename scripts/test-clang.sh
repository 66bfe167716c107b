#!/usr/bin/env bash
# The second compiler: clang builds the whole tree (libraries, tools, tests, benches) in
# release with warnings as errors, and the suite runs on that build. ARM SoC toolchains are
# often clang's; GCC accepts a few things clang refuses (session 44 found three). Build
# folder: build/clang (or $CLANG_BUILD).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh clang
jobs=$(nproc)
build=${CLANG_BUILD:-build/clang}
CC=clang CXX=clang++ cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=Release -DTERRALIGN_WERROR=ON >/dev/null
cmake --build "$build" -j "$jobs"
(cd "$build" && ctest --output-on-failure -j "$jobs")
