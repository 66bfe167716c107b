// The AVX-512F vector wrapper (16 floats). Include only from files built with -mavx512f.
#pragma once

#include <immintrin.h>

#include "simd_avx2.hpp"  // the one-output-channel kernel's eight lanes (-mavx512f implies AVX2)

namespace terralign::nn {

// 1 + t + t^2/2 + ... + t^6/720 - 1 = t (1 + t/2 + ... + t^5/720), by Horner.
inline __m512 taylor6_avx512(__m512 t) {
  __m512 q = _mm512_set1_ps(1.0f / 720.0f);
  q = _mm512_fmadd_ps(q, t, _mm512_set1_ps(1.0f / 120.0f));
  q = _mm512_fmadd_ps(q, t, _mm512_set1_ps(1.0f / 24.0f));
  q = _mm512_fmadd_ps(q, t, _mm512_set1_ps(1.0f / 6.0f));
  q = _mm512_fmadd_ps(q, t, _mm512_set1_ps(0.5f));
  q = _mm512_fmadd_ps(q, t, _mm512_set1_ps(1.0f));
  return _mm512_mul_ps(q, t);
}

// exp(x) - 1 for x <= 0, as expm1_neg_avx2 (the same reduction and polynomial).
inline __m512 expm1_neg_avx512(__m512 x) {
  const __m512 shifter = _mm512_set1_ps(kExpShifter);
  x = _mm512_max_ps(_mm512_set1_ps(-87.0f), x);
  const __m512 nb = _mm512_fmadd_ps(x, _mm512_set1_ps(1.44269504088896341f), shifter);
  const __m512 r = _mm512_fnmadd_ps(_mm512_sub_ps(nb, shifter), _mm512_set1_ps(0.693147180559945309f), x);
  const __m512 s = _mm512_castsi512_ps(_mm512_slli_epi32(_mm512_castps_si512(nb), 23));
  return _mm512_fmadd_ps(s, taylor6_avx512(r), _mm512_sub_ps(s, _mm512_set1_ps(1.0f)));
}

struct VecAvx512 {
  static constexpr int kWidth = 16;
  static constexpr int kBlock = 16;       // output channels a weight block holds
  static constexpr int kTilePixels = 6;   // 6 pixels x 4 blocks (64 channels) = 24 of the 32 registers
  static constexpr int kTileBlocks = 4;
  // The one-output-channel kernel sums eight lanes in every build (conv_rows.hpp): AVX2's.
  using Lanes8 = VecAvx2;
  __m512 v;
  static VecAvx512 load(const float* p) { return {_mm512_loadu_ps(p)}; }
  static VecAvx512 set1(float x) { return {_mm512_set1_ps(x)}; }
  void store(float* p) const { _mm512_storeu_ps(p, v); }
  friend VecAvx512 operator+(VecAvx512 a, VecAvx512 b) { return {_mm512_add_ps(a.v, b.v)}; }
  friend VecAvx512 operator-(VecAvx512 a, VecAvx512 b) { return {_mm512_sub_ps(a.v, b.v)}; }
  friend VecAvx512 fmadd(VecAvx512 a, VecAvx512 b, VecAvx512 c) { return {_mm512_fmadd_ps(a.v, b.v, c.v)}; }
  friend VecAvx512 elu(VecAvx512 a) {
    // As VecAvx2's: expm1 of a positive a is garbage, and the blend drops it.
    return {_mm512_mask_blend_ps(_mm512_cmp_ps_mask(a.v, _mm512_setzero_ps(), _CMP_GT_OQ), expm1_neg_avx512(a.v), a.v)};
  }
  friend VecAvx512 relu(VecAvx512 a) { return {_mm512_max_ps(a.v, _mm512_setzero_ps())}; }
};

}  // namespace terralign::nn
