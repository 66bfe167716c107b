// Arithmetic that gives the same bits on every machine and C library.
#pragma once

#include <cmath>

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

}  // namespace terralign
