#!/usr/bin/env bash
# The aarch64 build and its tests under qemu-user, on an x86-64 Debian 12 machine: Debian's
# cross compiler, the arm64 libraries through multiarch, -Werror, NEON kernels (compared with
# their scalar twins by the tests). Build folder: build/aarch64 (or $ARM_BUILD).
#
# LIMIT (README, Onboard): Debian 12's qemu-user hangs at the first thread an aarch64
# program starts (a ten-line std::thread program does too), so the tests that start a thread
# pool are listed in THREADED_TESTS and skipped here; everything else runs. On a real
# aarch64 machine run scripts/test.sh instead. Set ARM_ALL=1 to run them all.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "$(uname -m)" = aarch64 ]; then
  echo "native aarch64: use scripts/test.sh"
  exit 0
fi
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
bash scripts/install-deps.sh
# The cross tools: a machine that cannot get them (no arm64 packages on its mirror) skips
# this step with a message; a build or test failure is a failure.
install_cross() {
  if ! dpkg --print-foreign-architectures | grep -qx arm64; then
    $SUDO dpkg --add-architecture arm64 && $SUDO apt-get update -qq
  fi
  # libgeographiclib-dev is not multiarch: the host's headers, arm64's runtime library.
  bash scripts/install-deps.sh g++-aarch64-linux-gnu qemu-user libgeographiclib23:arm64 libtiff-dev:arm64
}
if ! install_cross; then
  echo "aarch64: the cross compiler or the arm64 libraries could not be installed; skipped"
  exit 0
fi
jobs=$(nproc)
cmake -S . -B ${ARM_BUILD:-build/aarch64} -DCMAKE_TOOLCHAIN_FILE=cmake/toolchains/aarch64-linux-gnu.cmake \
  -DCMAKE_BUILD_TYPE=Release -DTERRALIGN_WERROR=ON -DTERRALIGN_BUILD_BENCH=OFF >/dev/null
cmake --build ${ARM_BUILD:-build/aarch64} -j "$jobs"
THREADED_TESTS='abuse|learned tracker: the C|learned tracker: same bytes|rendered|no texture|1 and 2 threads|allocates nothing|parity with PyTorch|depth is the analytic|no cracks|ortho texel|bad poses|unknown layer|ray-caster|registration|flight|track reports|dataset|cli_render'
if [ "${ARM_ALL:-0}" = 1 ]; then
  ctest --test-dir ${ARM_BUILD:-build/aarch64} --output-on-failure -j "$jobs" --timeout 1800
else
  ctest --test-dir ${ARM_BUILD:-build/aarch64} --output-on-failure -j "$jobs" --timeout 120 -E "$THREADED_TESTS"
fi
