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
