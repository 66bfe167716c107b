// Arithmetic that gives the same bits on every machine and C library.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>

// Every promise of the same bits (and every NaN check on bad input) rests on IEEE arithmetic
// as written. -ffast-math and -Ofast let the compiler reorder sums, drop signed zeros and
// assume no NaN or infinity exists, so std::isfinite(x) becomes true; the build refuses them
// (cmake/TerralignOptions.cmake checks the flags; this catches what the flags do not show).
#if defined(__FAST_MATH__) || (defined(__FINITE_MATH_ONLY__) && __FINITE_MATH_ONLY__)
#error "terralign needs IEEE floating point: build without -ffast-math, -Ofast or -ffinite-math-only"
#endif

namespace terralign {

// sqrt(a^2 + b^2) in IEEE operations that each round once (the build fuses nothing:
// cmake/TerralignOptions.cmake), so the same bits on every machine. std::hypot's last bit is
// the C library's: glibc's differed between x86-64 and aarch64 (an eval's EPE, session 79).
// No guard against overflow: for lengths in metres and pixels.
inline double hypot_exact(double a, double b) { return std::sqrt(a * a + b * b); }

// The sine and cosine of x (radians), and atan2(y, x) (radians, in [-pi, pi], with the C
// library's signs for zeros and infinities), in plain multiplies and adds (numeric.cpp): within
// 2 ulp of glibc's (tested), and the same bits on every machine and C library, where libm's
// last bit is its own (glibc, newlib and musl each have their own code). SE(3)'s exp and log
// and the rotations of geo/pose.hpp use them. |x| beyond 2^19 pi / 2 (8.2e5) is first reduced
// by std::fmod (exact, so the same everywhere) modulo the double nearest 2 pi, which is not
// 2 pi: there the result is not the sine of x (a rotation's angle never comes near).
void sin_cos(double x, double& s, double& c);
double atan2_portable(double y, double x);
// The natural logarithm in the same way (within 2 ulp of glibc's; -inf at 0, NaN below), for
// the samplers' normal deviates (Box and Muller).
double log_portable(double x);

// a b + c rounded once, as std::fma, in double arithmetic: for targets without a fused
// multiply-add (32-bit ARM with Debian's baseline VFPv3, as the Cortex-A8 and A9 have), where
// std::fma is the C library's fmaf, which glibc computes the same way but writes and restores
// the FPU's rounding mode around every call. The product of two floats is exact in double
// (48 bits); their sum with c is rounded to double and, where that rounding was inexact (its
// exact error by Knuth's two-sum), moved to its odd neighbour: rounded to odd at 53 bits, the
// one rounding to float is then the correct one (Boldo and Melquiond, 2008: 53 >= 2 x 24 + 2,
// subnormal results included). Needs round to nearest, which every frame-level entry of the
// onboard path sets (float_environment.hpp). A NaN result is a NaN, its payload not std::fma's.
inline float fma_float_by_double(float a, float b, float c) {
  const double p = static_cast<double>(a) * static_cast<double>(b);
  const double cd = static_cast<double>(c);
  double s = p + cd;
  const double back = s - p;
  const double err = (p - (s - back)) + (cd - back);
  if (err != 0.0 && std::isfinite(s)) {
    std::uint64_t bits;
    std::memcpy(&bits, &s, sizeof bits);
    if ((bits & 1u) == 0) {
      // Towards the exact sum: up in magnitude where the error has the sum's sign.
      bits = (err > 0.0) == (s > 0.0) ? bits + 1 : bits - 1;
      std::memcpy(&s, &bits, sizeof s);
    }
  }
  return static_cast<float>(s);
}

// a b + c rounded once, as std::fma: fma_float_by_double on 32-bit ARM with a double-precision
// FPU but no fused multiply-add (VFPv3), where std::fma is glibc's fmaf, which switches FPSCR's
// rounding mode twice a call (the firmware's test under qemu-arm: 389-425 s against 702 s, session
// 86). Elsewhere std::fma: the instruction, or on x86-64 built without -mfma glibc's fmaf, which
// runs the instruction where the CPU has one; the emulation measured 1.0-2.4x slower than that
// call on this project's AVX-512 host (bench_nn's scalar rows), so x86-64 keeps the call.
inline float fma_float(float a, float b, float c) {
#if defined(__arm__) && !defined(__ARM_FEATURE_FMA) && defined(__ARM_FP) && (__ARM_FP & 8)
  return fma_float_by_double(a, b, c);
#else
  return std::fma(a, b, c);
#endif
}

}  // namespace terralign
