#include <terralign/geo/numeric.hpp>

#include <cmath>
#include <limits>

namespace terralign {
namespace {

// pi / 2 in three parts of 33, 33 and 53 bits (Cody and Waite): k times either of the first
// two is exact for |k| < 2^20, so x - k pi/2 loses nothing to cancellation.
constexpr double kPio2Hi = 0x1.921fb544p+0;
constexpr double kPio2Mid = 0x1.0b4611a6p-34;
constexpr double kPio2Lo = 0x1.3198a2e037073p-69;
constexpr double kTwoOverPi = 0x1.45f306dc9c883p-1;
constexpr double kReduceLimit = 0x1p19 * 1.5707963267948966;  // |k| < 2^19 below it
constexpr double kTwoPi = 6.283185307179586;                    // the double nearest 2 pi
constexpr double kRoundShift = 0x1.8p52;  // x + it - it rounds |x| < 2^51 to an integer
// pi / 2 and pi / 4 as the nearest double and the rest (the answers add the rest first).
constexpr double kPio2 = 1.5707963267948966, kPio2Rest = 6.123233995736766e-17;
constexpr double kPio4 = 0.7853981633974483, kPio4Rest = 3.061616997868383e-17;
// ln 2 in two parts, the first of 42 bits: e times it is exact for the exponents of doubles.
constexpr double kLn2Hi = 0x1.62e42fefa38p-1, kLn2Lo = 0x1.ef35793c7673p-45;
constexpr double kAtanHalf = 0.4636476090008061, kAtanHalfRest = 2.2698777452961687e-17;  // atan(1/2)

// sum over j < terms of (-1)^j z^j / (n0 + 2j)!, by Horner's rule; factorials to 18! are
// exact in double, so each coefficient is 1 / n! rounded once.
double factorial_series(double z, int n0, int terms) {
  double p = 0;
  for (int j = terms - 1; j >= 0; --j) {
    double f = 1;
    for (int i = 2; i <= n0 + 2 * j; ++i) f *= i;
    p = p * z + ((j & 1) ? -1.0 : 1.0) / f;
  }
  return p;
}

// Taylor's series on |r| <= pi / 4 in z = r^2: the first terms left out, r^19 / 19! and
// r^18 / 18!, are below 1e-19 and 3e-18 there.
double sin_series(double r) {
  const double z = r * r;
  return r - r * z * factorial_series(z, 3, 8);  // r - r^3 / 3! + ... + r^17 / 17!
}

double cos_series(double r) {
  const double z = r * r;
  const double p = factorial_series(z, 4, 8);  // 1/4! - z/6! + ... - z^7/18!
  // 1 - z/2 + z^2 p: z/2 is exact, and 1 - z/2 >= 0.69 rounds once.
  const double h = 0.5 * z;
  const double one_minus_h = 1.0 - h;
  return one_minus_h + (((1.0 - one_minus_h) - h) + z * z * p);
}

// atan(u) for |u| < 7/16 by its series (u^49 / 49 < 1e-18 |u| is the first term left out).
double atan_series(double u) {
  const double z = u * u;
  double p = 0;
  for (int k = 24; k >= 1; --k) p = p * z + ((k & 1) ? -1.0 : 1.0) / static_cast<double>(2 * k + 1);
  return u + u * z * p;
}

// atan(t) for t in [0, 1], on three pieces so that no answer cancels much: below 7/16 the
// series; below 11/16 atan(1/2) + atan((2t - 1) / (2 + t)); above, pi / 4 + atan((t - 1) /
// (t + 1)) (2t - 1 and t - 1 are exact there).
double atan_unit(double t) {
  if (t < 0.4375) return atan_series(t);
  if (t < 0.6875) return kAtanHalf + (atan_series((2.0 * t - 1.0) / (2.0 + t)) + kAtanHalfRest);
  return kPio4 + (atan_series((t - 1.0) / (t + 1.0)) + kPio4Rest);
}

// log(m) for m in [sqrt(1/2), sqrt(2)): 2 atanh(s), s = (m - 1) / (m + 1) in [-0.172, 0.172],
// by its series (s^25 / 25 < 1e-19 |s| is the first term left out).
double log_near_one(double m) {
  const double f = m - 1.0;  // exact (Sterbenz)
  const double s = f / (m + 1.0), z = s * s;
  double p = 0;
  for (int k = 12; k >= 1; --k) p = p * z + 1.0 / static_cast<double>(2 * k + 1);
  // 2 s = f - s f; the sum in that order keeps the small terms' bits.
  return f - (s * f - 2.0 * s * z * p);
}

}  // namespace

double log_portable(double x) {
  if (!(x > 0) || std::isinf(x)) {
    if (x == 0) return -HUGE_VAL;
    return x < 0 ? std::numeric_limits<double>::quiet_NaN() : x;  // NaN stays NaN, +inf +inf
  }
  int e = 0;
  double m = std::frexp(x, &e);  // exact: m in [1/2, 1)
  if (m < 0.7071067811865476) {
    m *= 2.0;
    --e;
  }
  return static_cast<double>(e) * kLn2Hi + (log_near_one(m) + static_cast<double>(e) * kLn2Lo);
}

void sin_cos(double x, double& s, double& c) {
  if (x == 0) {  // sin(-0) is -0
    s = x;
    c = 1;
    return;
  }
  if (!(std::fabs(x) <= kReduceLimit)) {
    x = std::fmod(x, kTwoPi);  // NaN for NaN and infinities
    if (std::isnan(x)) {
      s = c = x;
      return;
    }
  }
  const double k = (x * kTwoOverPi + kRoundShift) - kRoundShift;
  const double r = ((x - k * kPio2Hi) - k * kPio2Mid) - k * kPio2Lo;
  const double sr = sin_series(r), cr = cos_series(r);
  switch (static_cast<long long>(k) & 3) {  // the quadrant
    case 0: s = sr, c = cr; break;
    case 1: s = cr, c = -sr; break;
    case 2: s = -sr, c = -cr; break;
    default: s = -cr, c = sr; break;
  }
}

double atan2_portable(double y, double x) {
  if (std::isnan(x) || std::isnan(y)) return x + y;
  const double ax = std::fabs(x), ay = std::fabs(y);
  if ((std::isinf(ay) && !std::isinf(ax)) || (ax == 0 && ay != 0)) return std::copysign(kPio2, y);
  double a;  // the angle for |x|, |y|, in [0, pi / 2]
  if (std::isinf(ax)) {
    a = std::isinf(ay) ? kPio4 : 0.0;
  } else if (ay == 0) {
    a = 0;
  } else if (ay > ax) {
    a = kPio2 - (atan_unit(ax / ay) - kPio2Rest);
  } else {
    a = atan_unit(ay / ax);
  }
  if (std::signbit(x)) a = 2 * kPio2 - (a - 2 * kPio2Rest);  // x < 0, or -0 with y = 0
  return std::copysign(a, y);
}

}  // namespace terralign
