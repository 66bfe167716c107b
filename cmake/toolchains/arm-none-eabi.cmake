# The onboard core (geo_core, raster, nn, iclk) as static libraries for a microcontroller-
# class core: Cortex-M7 with its double-precision FPU, Thumb-2, no OS, newlib, no
# exceptions, no RTTI, no threads. Debian's gcc-arm-none-eabi and
# libstdc++-arm-none-eabi-newlib; scripts/build-mcu.sh configures and builds it and reports
# the code size. Set TERRALIGN_MCU_CPU to another -mcpu, e.g. cortex-m55+nomve (Debian 12's
# GCC 12 emits a conditional vcvt its assembler rejects when MVE is on; our kernels are
# scalar there anyway). -Wno-psabi: GCC's notes on a 2017 ABI change, not our code's.
set(CMAKE_SYSTEM_NAME Generic)
set(CMAKE_SYSTEM_PROCESSOR arm)
set(CMAKE_C_COMPILER arm-none-eabi-gcc)
set(CMAKE_CXX_COMPILER arm-none-eabi-g++)
# No OS to run a test program on: CMake's compiler checks build a static library instead.
set(CMAKE_TRY_COMPILE_TARGET_TYPE STATIC_LIBRARY)
set(TERRALIGN_MCU_CPU cortex-m7 CACHE STRING "-mcpu for the microcontroller build")
if(TERRALIGN_MCU_CPU STREQUAL "cortex-m7")
  set(_fpu "-mfpu=fpv5-d16")
else()
  set(_fpu "")  # the M55's FPU follows from -mcpu
endif()
set(CMAKE_CXX_FLAGS_INIT "-mcpu=${TERRALIGN_MCU_CPU} -mthumb ${_fpu} -mfloat-abi=hard -fno-exceptions -fno-rtti -ffunction-sections -fdata-sections -Wno-psabi")
set(CMAKE_C_FLAGS_INIT "-mcpu=${TERRALIGN_MCU_CPU} -mthumb ${_fpu} -mfloat-abi=hard -ffunction-sections -fdata-sections")
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
# Eigen is header-only and architecture-independent: the host's.
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE BOTH)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE BOTH)
set(TERRALIGN_ONBOARD_ONLY ON CACHE BOOL "" FORCE)
set(TERRALIGN_THREADS OFF CACHE BOOL "" FORCE)
set(TERRALIGN_SIMD OFF CACHE BOOL "" FORCE)
