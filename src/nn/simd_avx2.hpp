// The AVX2 + FMA vector wrapper (8 floats). Include only from files built with -mavx2 -mfma.
#pragma once

#include <immintrin.h>

#include "simd_scalar.hpp"  // kExpShifter

namespace terralign::nn {

// 1 + t + t^2/2 + ... + t^6/720 - 1 = t (1 + t/2 + ... + t^5/720), by Horner.
inline __m256 taylor6_avx2(__m256 t) {
  __m256 q = _mm256_set1_ps(1.0f / 720.0f);
  q = _mm256_fmadd_ps(q, t, _mm256_set1_ps(1.0f / 120.0f));
  q = _mm256_fmadd_ps(q, t, _mm256_set1_ps(1.0f / 24.0f));
  q = _mm256_fmadd_ps(q, t, _mm256_set1_ps(1.0f / 6.0f));
  q = _mm256_fmadd_ps(q, t, _mm256_set1_ps(0.5f));
  q = _mm256_fmadd_ps(q, t, _mm256_set1_ps(1.0f));
  return _mm256_mul_ps(q, t);
}

// exp(x) - 1 for x <= 0 (ELU's negative branch): x = n ln2 + r, |r| <= ln2 / 2, and
// exp(x) - 1 = 2^n (exp(r) - 1) + (2^n - 1) with exp(r) - 1 a degree-6 polynomial in r
// (about 3.5e-7 relative). 2^n - 1 is exact, and for |x| < 0.35 (n = 0) the result is the
// polynomial itself: no cancellation near 0, one polynomial for the whole range.
// n comes from one multiply-add: x log2(e) + (1.5 2^23 + 127) rounds x log2(e) to the nearest
// integer (held in the low mantissa bits, with the exponent's bias 127 added), and shifting
// those bits left by 23 makes 2^n itself (the constant's own bits leave the word); x >= -87
// keeps n + 127 >= 1. r = x - n ln2 in one multiply-add: ln2's float error (2e-9) times |n|
// moves exp(x) by |n| 2e-9 of itself (at most 3e-7), and as exp(x) <= 2^(n + 1/2), by under
// 1e-8 of expm1(x).
// NaN stays NaN: max() returns its second operand when either is NaN. Session 70: ELU in 14
// operations, where the clamp to x <= 0, the round, the conversion, the two-step reduction and
// the compare made 19 (1.4x on its own).
inline __m256 expm1_neg_avx2(__m256 x) {
  const __m256 shifter = _mm256_set1_ps(kExpShifter);
  x = _mm256_max_ps(_mm256_set1_ps(-87.0f), x);
  const __m256 nb = _mm256_fmadd_ps(x, _mm256_set1_ps(1.44269504088896341f), shifter);
  const __m256 r = _mm256_fnmadd_ps(_mm256_sub_ps(nb, shifter), _mm256_set1_ps(0.693147180559945309f), x);
  const __m256 s = _mm256_castsi256_ps(_mm256_slli_epi32(_mm256_castps_si256(nb), 23));
  return _mm256_fmadd_ps(s, taylor6_avx2(r), _mm256_sub_ps(s, _mm256_set1_ps(1.0f)));
}

struct VecAvx2 {
  static constexpr int kWidth = 8;
  static constexpr int kBlock = 8;       // output channels a weight block holds
  static constexpr int kTilePixels = 6;  // output pixels a register tile holds
  static constexpr int kTileBlocks = 2;  // weight blocks a register tile holds
  using Lanes8 = VecAvx2;                // the one-output-channel kernel's eight lanes (conv_rows.hpp)
  __m256 v;
  static VecAvx2 load(const float* p) { return {_mm256_loadu_ps(p)}; }
  static VecAvx2 set1(float x) { return {_mm256_set1_ps(x)}; }
  void store(float* p) const { _mm256_storeu_ps(p, v); }
  friend VecAvx2 operator+(VecAvx2 a, VecAvx2 b) { return {_mm256_add_ps(a.v, b.v)}; }
  friend VecAvx2 operator-(VecAvx2 a, VecAvx2 b) { return {_mm256_sub_ps(a.v, b.v)}; }
  friend VecAvx2 fmadd(VecAvx2 a, VecAvx2 b, VecAvx2 c) { return {_mm256_fmadd_ps(a.v, b.v, c.v)}; }
  // expm1 of a positive a is garbage (a > 88 overflows 2^n), and the blend on a's sign bit
  // drops it: -0 takes expm1(-0) = 0.
  friend VecAvx2 elu(VecAvx2 a) { return {_mm256_blendv_ps(a.v, expm1_neg_avx2(a.v), a.v)}; }
  friend VecAvx2 relu(VecAvx2 a) { return {_mm256_max_ps(a.v, _mm256_setzero_ps())}; }
};

}  // namespace terralign::nn
