# Cross-compiling for 64-bit ARM Linux with Debian's g++-aarch64-linux-gnu, the arm64
# libraries installed through multiarch (dpkg --add-architecture arm64), and the tests run
# under qemu-user (scripts/test-aarch64.sh does all of it).
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)
set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)
set(CMAKE_LIBRARY_ARCHITECTURE aarch64-linux-gnu)
set(CMAKE_CROSSCOMPILING_EMULATOR qemu-aarch64;-L;/usr/aarch64-linux-gnu)
# Headers and CMake packages from the host's /usr (architecture-independent ones and the
# multiarch arm64 ones); programs from the host.
set(CMAKE_FIND_ROOT_PATH /usr/aarch64-linux-gnu /usr)
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE BOTH)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE BOTH)
# Debian's libgeographiclib-dev is not multiarch (installing the arm64 one removes the
# host's), so the arm64 runtime library is linked directly; the headers are the host's.
set(GeographicLib_LIBRARIES /usr/lib/aarch64-linux-gnu/libGeographicLib.so.23 CACHE FILEPATH "")

# Static executables (-DTERRALIGN_AARCH64_STATIC=ON, with the arm64 libGeographicLib.a given
# as GeographicLib_STATIC). Debian 12's qemu-user hangs at the first thread a dynamically
# linked aarch64 program starts, and runs the same program linked statically; the arm64
# static GeographicLib comes from its -dev package unpacked aside (scripts/test-aarch64.sh),
# since installing that package would remove the host's.
option(TERRALIGN_AARCH64_STATIC "Link the aarch64 executables statically" OFF)
if(TERRALIGN_AARCH64_STATIC)
  if(NOT EXISTS "${GeographicLib_STATIC}")
    message(FATAL_ERROR "TERRALIGN_AARCH64_STATIC needs GeographicLib_STATIC, the arm64 libGeographicLib.a (got '${GeographicLib_STATIC}')")
  endif()
  set(GeographicLib_LIBRARIES "${GeographicLib_STATIC}" CACHE FILEPATH "" FORCE)
  set(TIFF_LIBRARY_RELEASE /usr/lib/aarch64-linux-gnu/libtiff.a CACHE FILEPATH "" FORCE)
  set(CMAKE_EXE_LINKER_FLAGS_INIT "-static")
  # libtiff's own dependencies (pkg-config --static --libs libtiff-4), after everything else.
  set(CMAKE_CXX_STANDARD_LIBRARIES "-lwebp -lLerc -ljbig -lzstd -llzma -ljpeg -ldeflate -lz -lm -pthread")
  set(CMAKE_CROSSCOMPILING_EMULATOR qemu-aarch64)
endif()
