#!/usr/bin/env bash
# Usage: scripts/test-arm-linux.sh [aarch64|armhf [CMAKE_ARGS...]]   (default aarch64: scripts/test-aarch64.sh)
# An ARM Linux build and its tests under qemu-user, on an x86-64 Debian 12 machine: Debian's
# cross compiler, the target's libraries through multiarch, -Werror. Build folder:
# build/aarch64 or build/armhf (or $ARM_BUILD).
# - aarch64: NEON kernels, compared with their scalar twins by the tests.
# - armhf (32-bit ARMv7-A, hard float): with Debian's baseline FPU (VFPv3-D16) every kernel
#   runs its scalar twin, each fused multiply-add is computed in double (fma_float), and the
#   firmware's test alone takes about 7 minutes under qemu-arm. CI builds for NEON and VFPv4
#   (-DTERRALIGN_ARM_FPU=neon-vfpv4: cmake/toolchains/arm-linux-gnueabihf.cmake): the
#   convolutions run their NEON kernel, tested against the scalar twin, and the rest its
#   scalar twin with one instruction a multiply-add.
# CI (.ci/run) runs aarch64's and armhf NEON's suites and firmware tests, and the baseline
# armhf build's firmware test alone (its whole suite takes about an hour under qemu-arm: by
# hand). Arguments after the architecture go to CMake; ARM_SUITE=0 builds and runs the
# firmware's test alone.
#
# Debian 12's qemu-user hangs at the first thread a dynamically linked aarch64 program
# starts (a ten-line std::thread program does too) and runs the same program linked
# statically, so the executables are linked statically: the target's libGeographicLib.a comes
# from its libgeographiclib-dev unpacked into the build folder (installing it would remove
# the host's). Where that package cannot be fetched, the build is dynamic and the tests that
# start a thread pool (THREADED_TESTS) are skipped, with a message. On a real ARM Linux
# machine run scripts/test.sh instead.
set -euo pipefail
cd "$(dirname "$0")/.."
arch=${1:-aarch64}
shift $(( $# > 0 ? 1 : 0 ))
case "$arch" in
  aarch64) deb=arm64 triplet=aarch64-linux-gnu qemu=qemu-aarch64 static_option=TERRALIGN_AARCH64_STATIC
           native=aarch64 ;;
  armhf) deb=armhf triplet=arm-linux-gnueabihf qemu=qemu-arm static_option=TERRALIGN_ARM_STATIC native=armv7l ;;
  *) echo "usage: $0 [aarch64|armhf] (got '$arch')" >&2; exit 2 ;;
esac
if [ "$(uname -m)" = "$native" ]; then
  echo "native $arch: use scripts/test.sh"
  exit 0
fi
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
bash scripts/install-deps.sh
# The cross tools: a machine that cannot get them (no $deb packages on its mirror) skips
# this step with a message; a build or test failure is a failure.
install_cross() {
  if ! dpkg --print-foreign-architectures | grep -qx "$deb"; then
    $SUDO dpkg --add-architecture "$deb" && $SUDO apt-get update -qq
  fi
  # libgeographiclib-dev is not multiarch: the host's headers, the target's runtime library.
  bash scripts/install-deps.sh "g++-$triplet" qemu-user "libgeographiclib23:$deb" "libtiff-dev:$deb"
}
if ! install_cross; then
  echo "$arch: the cross compiler or the $deb libraries could not be installed; skipped"
  exit 0
fi
jobs=$(nproc)
build=${ARM_BUILD:-build/$arch}
mkdir -p "$build"
static=()
geo_a="$build/deps/usr/lib/$triplet/libGeographicLib.a"
if [ ! -f "$geo_a" ]; then
  rm -rf "$build/deps" && mkdir -p "$build/deps"
  (cd "$build/deps" && apt-get download "libgeographiclib-dev:$deb" >/dev/null 2>&1 &&
     dpkg -x libgeographiclib-dev_*_"$deb".deb .) || true
fi
if [ -f "$geo_a" ]; then
  static=("-D$static_option=ON" "-DGeographicLib_STATIC=$(realpath "$geo_a")")
else
  echo "$arch: libgeographiclib-dev:$deb could not be fetched: dynamic build, threaded tests skipped"
fi
cmake -S . -B "$build" -DCMAKE_TOOLCHAIN_FILE="cmake/toolchains/$triplet.cmake" \
  -DCMAKE_BUILD_TYPE=Release -DTERRALIGN_WERROR=ON -DTERRALIGN_BUILD_BENCH=OFF "${static[@]}" "$@" >/dev/null
# ARM_SUITE=0 builds the firmware's test alone, not the suite it skips.
targets=()
if [ "${ARM_SUITE:-1}" = 0 ]; then targets=(--target terralign_firmware_host); fi
cmake --build "$build" -j "$jobs" "${targets[@]}"
THREADED_TESTS='abuse|no-data texels|learned tracker: the C|learned tracker: same bytes|rendered|no texture|1 and 2 threads|allocates nothing|parity with PyTorch|depth is the analytic|no cracks|ortho texel|bad poses|unknown layer|ray-caster|registration|flight|track reports|dataset|cli_render'
# The cases that run the command-line program over a flight or an eval (tests/test_track.cpp:
# track, eval, align on a flight's frames) run natively only: 1-11 s each on x86, 1.5-30
# minutes each under qemu, where on session 63's AVX2 host they took CI past its 90 minutes.
# They run in the x86 suites (release; clang's under ASan + UBSan, but for the three
# longest); their code is the same on every ISA, and the NEON code they go through is tested
# here case by case (the kernels against their scalar twins, the learned tracker's PyTorch parity, its
# 1-against-2-thread bytes, refinement, layers, the abuse test's 1000 poses).
source scripts/end-to-end-cases.sh
NATIVE_ONLY="$END_TO_END_CASES|a rendered flight is tracked, and a frame of pure noise"
NATIVE_ONLY+="|align on a flight's first frame takes the learned tracker's converged tests|eval --noise/--blur/--exposure"
NATIVE_ONLY+="|track starts from --init-velocity|track holds each answer's|track reports bad frames by name"
NATIVE_ONLY+="|eval's metrics of an answer do not depend on the methods"  # eval's bookkeeping: 32 learned pairs
# Five of the learned tracker's library cases test what it decides (which layer is tried next,
# which answers a refinement pass takes and how, the covariance's floor), not how a kernel
# computes: 130-165 s each under qemu. The refinement's and the layers' cases for bytes and
# allocations stay here, and go through the same NEON code.
NATIVE_ONLY+="|layers: the next layer is tried only where the one before did not converge"
NATIVE_ONLY+="|refinement: asked to, the learned tracker weighs every pixel alike|refinement: a reference rendered at the answer"
NATIVE_ONLY+="|refinement: the learned tracker refines on three levels|the registration floor grows with the final residual"
# The firmware's test runs below instead, compared with the host's answers.
FIRMWARE_TEST="firmware's test on the host"
NATIVE_ONLY+="|$FIRMWARE_TEST"
if [ "${ARM_SUITE:-1}" = 0 ]; then
  echo "$arch: ARM_SUITE=0: the suite skipped, the firmware's test alone"
elif [ ${#static[@]} -gt 0 ]; then
  ctest --test-dir "$build" --output-on-failure -j "$jobs" --timeout 1800 -E "$NATIVE_ONLY"
else
  ctest --test-dir "$build" --output-on-failure -j "$jobs" --timeout 120 -E "$THREADED_TESTS|$FIRMWARE_TEST"
fi
# The firmware's test (firmware/scenario.cpp: 16 frames of both trackers through the
# localiser, about 80 s under qemu-aarch64): every frame's answer must be this host's x86-64
# build's to the bit (scripts/same-answers-as-host.sh).
timeout "${ARM_FIRMWARE_TIMEOUT:-1200}" "$qemu" -L "/usr/$triplet" "$build/firmware/terralign_firmware_host" \
  >"$build/firmware-host.log"
bash scripts/same-answers-as-host.sh "the $arch build under qemu" "$build/firmware-host.log"
