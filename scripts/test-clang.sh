#!/usr/bin/env bash
# clang builds the whole tree (libraries, tools, tests, benches) in release with warnings as
# errors, and the suite runs on that build: to compare clang's code with GCC's, speed
# included. CI's clang build is scripts/test.sh's sanitizer pass (since session 67); this
# one is not in CI. Build folder: build/clang (or $CLANG_BUILD).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh clang
jobs=$(nproc)
build=${CLANG_BUILD:-build/clang}
CC=clang CXX=clang++ cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=Release -DTERRALIGN_WERROR=ON >/dev/null
cmake --build "$build" -j "$jobs"
(cd "$build" && ctest --output-on-failure -j "$jobs")
