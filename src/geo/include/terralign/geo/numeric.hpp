// Arithmetic that gives the same bits on every machine.
#pragma once

#include <cmath>

namespace terralign {

// sqrt(a^2 + b^2) in IEEE operations that each round once (the build fuses nothing:
// cmake/TerralignOptions.cmake), so the same bits on every machine. std::hypot's last bit is
// the C library's: glibc's differed between x86-64 and aarch64 (an eval's EPE, session 79).
// No guard against overflow: for lengths in metres and pixels.
inline double hypot_exact(double a, double b) { return std::sqrt(a * a + b * b); }

}  // namespace terralign
