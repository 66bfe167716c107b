# Cross-compiling for 32-bit ARM Linux (ARMv7-A, hard float) with Debian's
# g++-arm-linux-gnueabihf, the armhf libraries installed through multiarch, and the tests run
# under qemu-user: `bash scripts/test-arm-linux.sh armhf [-DTERRALIGN_ARM_FPU=...]` does all of
# it, and CI runs it with -DTERRALIGN_ARM_FPU=neon-vfpv4.
# Debian's armhf defaults: ARMv7-A, VFPv3-D16, hard float, Thumb-2. VFPv3 has no fused
# multiply-add, so the scalar kernels' multiply-adds (917 sites in the firmware's test) are
# computed exactly in double arithmetic, inline (fma_float, geo/numeric.hpp; until session 86
# each was a call to glibc's fmaf, which switches FPSCR's rounding mode twice).
# -DTERRALIGN_ARM_FPU=vfpv4-d16 (Cortex-A5, A7, A12, A15, A17, and ARMv8 cores running 32-bit
# code) makes each one instruction, vfma.f32; both round once, so the answers are the same.
# -DTERRALIGN_ARM_FPU=neon-vfpv4 (the same cores with NEON, as most have) adds the NEON
# convolution kernel (src/nn/simd_neon.hpp), which needs NEON's fused multiply-add: the
# convolutions are most of the learned tracker's time. The solver's and the renderer's NEON
# kernels are AArch64's (double lanes, vector division): their scalar twins run here.
# -Wno-psabi: GCC's notes on a 2017 ABI change, not our code's.
set(TERRALIGN_ARM_FPU "" CACHE STRING "-mfpu for the armhf build: vfpv4-d16, neon-vfpv4 (empty: Debian's vfpv3-d16)")
set(CMAKE_CXX_FLAGS_INIT "-Wno-psabi")
if(TERRALIGN_ARM_FPU)
  string(APPEND CMAKE_CXX_FLAGS_INIT " -mfpu=${TERRALIGN_ARM_FPU}")
endif()
set(_triplet arm-linux-gnueabihf)
set(_processor arm)
set(_qemu qemu-arm)
set(_static TERRALIGN_ARM_STATIC)
include(${CMAKE_CURRENT_LIST_DIR}/debian-linux-cross.cmake)
