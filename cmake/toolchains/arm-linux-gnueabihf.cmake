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
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR arm)
set(CMAKE_C_COMPILER arm-linux-gnueabihf-gcc)
set(CMAKE_CXX_COMPILER arm-linux-gnueabihf-g++)
set(CMAKE_LIBRARY_ARCHITECTURE arm-linux-gnueabihf)
# Debian's armhf defaults: ARMv7-A, VFPv3-D16, hard float, Thumb-2; no NEON, so every kernel
# runs its scalar twin (terralign's NEON kernels are AArch64's). -Wno-psabi: GCC's notes on a
# 2017 ABI change, not our code's.
set(CMAKE_CXX_FLAGS_INIT "-Wno-psabi")
set(CMAKE_CROSSCOMPILING_EMULATOR qemu-arm;-L;/usr/arm-linux-gnueabihf)
# Headers and CMake packages from the host's /usr (architecture-independent ones and the
# multiarch armhf ones); programs from the host.
set(CMAKE_FIND_ROOT_PATH /usr/arm-linux-gnueabihf /usr)
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE BOTH)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE BOTH)
# Debian's libgeographiclib-dev is not multiarch (installing the armhf one removes the
# host's), so the armhf runtime library is linked directly; the headers are the host's.
set(GeographicLib_LIBRARIES /usr/lib/arm-linux-gnueabihf/libGeographicLib.so.23 CACHE FILEPATH "")

# Static executables (-DTERRALIGN_ARM_STATIC=ON, with the armhf libGeographicLib.a given
# as GeographicLib_STATIC), as the aarch64 build's (Debian 12's qemu-user hangs at the first
# thread a dynamically linked aarch64 program starts); the armhf static GeographicLib comes
# from its -dev package unpacked aside (above), since installing that package would remove
# the host's.
option(TERRALIGN_ARM_STATIC "Link the armhf executables statically" OFF)
if(TERRALIGN_ARM_STATIC)
  if(NOT EXISTS "${GeographicLib_STATIC}")
    message(FATAL_ERROR "TERRALIGN_ARM_STATIC needs GeographicLib_STATIC, the armhf libGeographicLib.a (got '${GeographicLib_STATIC}')")
  endif()
  set(GeographicLib_LIBRARIES "${GeographicLib_STATIC}" CACHE FILEPATH "" FORCE)
  set(TIFF_LIBRARY_RELEASE /usr/lib/arm-linux-gnueabihf/libtiff.a CACHE FILEPATH "" FORCE)
  set(CMAKE_EXE_LINKER_FLAGS_INIT "-static")
  # libtiff's own dependencies (pkg-config --static --libs libtiff-4), after everything else.
  set(CMAKE_CXX_STANDARD_LIBRARIES "-lwebp -lLerc -ljbig -lzstd -llzma -ljpeg -ldeflate -lz -lm -pthread")
  set(CMAKE_CROSSCOMPILING_EMULATOR qemu-arm)
endif()
