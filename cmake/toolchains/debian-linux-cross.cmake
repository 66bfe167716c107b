# Shared by the toolchain files for ARM Linux (aarch64-linux-gnu.cmake, arm-linux-gnueabihf.cmake):
# Debian's cross compiler for a GNU triplet, that architecture's libraries installed through
# multiarch, and the tests run under qemu-user. The including file sets
#   _triplet     the GNU triplet (aarch64-linux-gnu, arm-linux-gnueabihf)
#   _processor   CMAKE_SYSTEM_PROCESSOR (aarch64, arm)
#   _qemu        the qemu-user program (qemu-aarch64, qemu-arm)
#   _static      the option that links the executables statically (TERRALIGN_AARCH64_STATIC, ...)
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR ${_processor})
set(CMAKE_C_COMPILER ${_triplet}-gcc)
set(CMAKE_CXX_COMPILER ${_triplet}-g++)
set(CMAKE_LIBRARY_ARCHITECTURE ${_triplet})
set(CMAKE_CROSSCOMPILING_EMULATOR ${_qemu};-L;/usr/${_triplet})
# Headers and CMake packages from the host's /usr (architecture-independent ones and the
# multiarch ones of the target); programs from the host.
set(CMAKE_FIND_ROOT_PATH /usr/${_triplet} /usr)
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE BOTH)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE BOTH)
# Debian's libgeographiclib-dev is not multiarch (installing the target's removes the host's),
# so the target's runtime library is linked directly; the headers are the host's.
set(GeographicLib_LIBRARIES /usr/lib/${_triplet}/libGeographicLib.so.23 CACHE FILEPATH "")

# Static executables (-D${_static}=ON, with the target's libGeographicLib.a given as
# GeographicLib_STATIC). Debian 12's qemu-user hangs at the first thread a dynamically linked
# aarch64 program starts, and runs the same program linked statically; the target's static
# GeographicLib comes from its -dev package unpacked aside (scripts/test-aarch64.sh; the
# armhf file's comment), since installing that package would remove the host's.
option(${_static} "Link the ${_processor} executables statically" OFF)
if(${_static})
  if(NOT EXISTS "${GeographicLib_STATIC}")
    message(FATAL_ERROR "${_static} needs GeographicLib_STATIC, the ${_triplet} libGeographicLib.a (got '${GeographicLib_STATIC}')")
  endif()
  set(GeographicLib_LIBRARIES "${GeographicLib_STATIC}" CACHE FILEPATH "" FORCE)
  set(TIFF_LIBRARY_RELEASE /usr/lib/${_triplet}/libtiff.a CACHE FILEPATH "" FORCE)
  set(CMAKE_EXE_LINKER_FLAGS_INIT "-static")
  # libtiff's own dependencies (pkg-config --static --libs libtiff-4), after everything else.
  set(CMAKE_CXX_STANDARD_LIBRARIES "-lwebp -lLerc -ljbig -lzstd -llzma -ljpeg -ldeflate -lz -lm -pthread")
  set(CMAKE_CROSSCOMPILING_EMULATOR ${_qemu})
endif()
