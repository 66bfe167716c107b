// The floating-point environment terralign computes in, whatever its caller's.
//
// Every answer, and the promise of the same bits on every machine, is made in the default
// environment: round to nearest, subnormals kept (no flush to zero, no denormals-are-zero),
// no default-NaN mode, no traps. A program that embeds terralign may run in another: a flight
// stack that traps on FE_INVALID to catch its own bugs, a library that rounds upward for
// interval arithmetic, a component linked with -ffast-math (crtfastmath.o flushes to zero).
// Measured in session 82 (docs/history.md): rounding upward, downward or toward zero moved all
// 16 of the firmware test's answers, and a trap on FE_INVALID or FE_DIVBYZERO killed the
// process in its first render (the renderer's SIMD rows divide in lanes they then discard).
//
// So every frame-level entry of the onboard path (raster::Renderer::render, nn::Network's
// forward, iclk::Tracker's and iclk::DeepAligner's alignments, the tools' Localizer) opens a
// FloatEnvironmentScope. It saves the calling thread's environment, installs the default one,
// and on closing gives the caller's back as it was, its exception flags included (nothing
// raised inside is seen outside). The thread pool's workers compute in the default
// environment from their start. Scopes nest; one costs some hundreds of cycles, so open it
// once a frame, not once a row.
//
// Where: glibc and other C libraries with a working <fenv.h> (fegetenv / fesetenv(FE_DFL_ENV);
// on x86 MXCSR's FTZ and DAZ bits, on AArch64 FPCR's FZ, DN, AHP and FZ16 bits and on 32-bit
// ARM FPSCR's FZ, DN and AHP bits are cleared as well, since FE_DFL_ENV need not); a
// bare-metal M-profile ARM with an FPU (the firmware: newlib's <fenv.h> implements nothing for
// ARM) through FPSCR's RMode, FZ, DN and AHP bits. ARMv7-A's NEON unit flushes subnormals
// whatever the environment says; terralign's AArch64 NEON kernels do not run there.
#pragma once

#include <cstdint>

namespace terralign {

class FloatEnvironmentScope {
 public:
  FloatEnvironmentScope() noexcept;
  ~FloatEnvironmentScope();
  FloatEnvironmentScope(const FloatEnvironmentScope&) = delete;
  FloatEnvironmentScope& operator=(const FloatEnvironmentScope&) = delete;

 private:
  // The caller's environment: an fenv_t (32 bytes on x86-64 glibc, 8 on AArch64), or FPSCR.
  alignas(16) unsigned char saved_[64];
};

// Whether the calling thread computes in the default environment described above (for tests
// and for a caller that would rather check than be switched).
bool float_environment_is_default() noexcept;

// For tests, terralign's and an integrator's: while it lives, the calling thread computes in
// an environment no answer is made in, as much of it as the machine has: rounding upward;
// subnormals flushed to zero (x86's FTZ and DAZ, ARM's FZ); ARM's default NaN; and traps on
// invalid operations and division by zero (x86-64; AArch64 cores mostly ignore the request, and
// M-profile cores have no traps). Gives the caller's environment back when it closes.
class HostileFloatEnvironment {
 public:
  HostileFloatEnvironment() noexcept;
  ~HostileFloatEnvironment();
  HostileFloatEnvironment(const HostileFloatEnvironment&) = delete;
  HostileFloatEnvironment& operator=(const HostileFloatEnvironment&) = delete;

  // What it set on this machine, e.g. "rounding upward, flush to zero, traps on FE_INVALID and
  // FE_DIVBYZERO".
  static const char* description() noexcept;

 private:
  FloatEnvironmentScope saved_;  // installs the default first, and gives the caller's back
};

}  // namespace terralign
