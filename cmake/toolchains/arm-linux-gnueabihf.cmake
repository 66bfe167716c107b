# Cross-compiling for 32-bit ARM Linux (ARMv7-A, hard float) with Debian's
# g++-arm-linux-gnueabihf, the armhf libraries installed through multiarch, and the tests run
# under qemu-user. Not in CI: with no NEON kernels (every kernel is its scalar twin) the
# learned tracker's cases take 2-10 minutes each under qemu-arm; the firmware's test did not
# finish in 25 (session 83). By hand:
#   dpkg --add-architecture armhf && apt-get update
#   apt-get install g++-arm-linux-gnueabihf qemu-user libgeographiclib23:armhf libtiff-dev:armhf
#   (mkdir -p /tmp/armhf && cd /tmp/armhf && apt-get download libgeographiclib-dev:armhf &&
#    dpkg -x libgeographiclib-dev_*_armhf.deb .)
#   cmake -S . -B build/armhf -DCMAKE_TOOLCHAIN_FILE=cmake/toolchains/arm-linux-gnueabihf.cmake \
#     -DCMAKE_BUILD_TYPE=Release -DTERRALIGN_WERROR=ON -DTERRALIGN_BUILD_BENCH=OFF -DTERRALIGN_ARM_STATIC=ON \
#     -DGeographicLib_STATIC=/tmp/armhf/usr/lib/arm-linux-gnueabihf/libGeographicLib.a
#   cmake --build build/armhf -j2 && ctest --test-dir build/armhf -j2 --timeout 1800
# Debian's armhf defaults: ARMv7-A, VFPv3-D16, hard float, Thumb-2; no NEON, so every kernel
# runs its scalar twin (terralign's NEON kernels are AArch64's). -Wno-psabi: GCC's notes on a
# 2017 ABI change, not our code's.
set(CMAKE_CXX_FLAGS_INIT "-Wno-psabi")
set(_triplet arm-linux-gnueabihf)
set(_processor arm)
set(_qemu qemu-arm)
set(_static TERRALIGN_ARM_STATIC)
include(${CMAKE_CURRENT_LIST_DIR}/debian-linux-cross.cmake)
