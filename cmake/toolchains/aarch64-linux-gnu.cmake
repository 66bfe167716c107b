# Cross-compiling for 64-bit ARM Linux with Debian's g++-aarch64-linux-gnu, the arm64
# libraries installed through multiarch (dpkg --add-architecture arm64), and the tests run
# under qemu-user (scripts/test-aarch64.sh does all of it). Static executables:
# -DTERRALIGN_AARCH64_STATIC=ON with GeographicLib_STATIC (debian-linux-cross.cmake).
set(_triplet aarch64-linux-gnu)
set(_processor aarch64)
set(_qemu qemu-aarch64)
set(_static TERRALIGN_AARCH64_STATIC)
include(${CMAKE_CURRENT_LIST_DIR}/debian-linux-cross.cmake)
