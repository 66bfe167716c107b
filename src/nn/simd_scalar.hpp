// The one-lane scalar vector wrapper: the scalar build of every kernel. Every operation is the
// vector builds' one lane at a time, multiply-adds rounded once (fma_float: std::fma, or on
// 32-bit ARM without a fused multiply-add the same rounding in double arithmetic) and ELU's
// exp the same polynomial, so this build gives their bits on any CPU (the tests compare them).
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>

#include <terralign/geo/numeric.hpp>  // fma_float

namespace terralign::nn {

// taylor6_avx2 and expm1_neg_avx2 (simd_avx2.hpp, where the reduction is explained), one lane.
inline float taylor6_scalar(float t) {
  float q = 1.0f / 720.0f;
  q = fma_float(q, t, 1.0f / 120.0f);
  q = fma_float(q, t, 1.0f / 24.0f);
  q = fma_float(q, t, 1.0f / 6.0f);
  q = fma_float(q, t, 0.5f);
  q = fma_float(q, t, 1.0f);
  return q * t;
}

// x log2(e) + kExpShifter rounds x log2(e) to an integer n held in the word's low bits with
// the exponent's bias added (expm1_neg_avx2), and pow2_of_shifted() makes 2^n of that word.
inline constexpr float kExpShifter = 12583039.0f;  // 1.5 2^23 + 127

// 2^n from the word x log2(e) + kExpShifter.
inline float pow2_of_shifted(float nb) {
  std::uint32_t bits;
  std::memcpy(&bits, &nb, sizeof bits);
  bits <<= 23;
  float s;
  std::memcpy(&s, &bits, sizeof s);
  return s;
}

// exp(x) - 1 for x <= 0 (expm1_neg_avx2). The clamp is max_ps's: a NaN x stays NaN.
inline float expm1_neg_scalar(float x) {
  x = -87.0f > x ? -87.0f : x;
  const float nb = fma_float(x, 1.44269504088896341f, kExpShifter);
  const float r = fma_float(-(nb - kExpShifter), 0.693147180559945309f, x);
  const float s = pow2_of_shifted(nb);
  return fma_float(s, taylor6_scalar(r), s - 1.0f);
}

struct VecScalar {
  static constexpr int kWidth = 1;
  static constexpr int kBlock = 8;       // output channels a weight block holds
  static constexpr int kTilePixels = 6;  // output pixels a register tile holds
  static constexpr int kTileBlocks = 2;  // weight blocks a register tile holds
  using Lanes8 = VecScalar;              // the one-output-channel kernel's eight lanes (conv_rows.hpp)
  float v;
  static VecScalar load(const float* p) { return {*p}; }
  static VecScalar set1(float x) { return {x}; }
  void store(float* p) const { *p = v; }
  friend VecScalar operator+(VecScalar a, VecScalar b) { return {a.v + b.v}; }
  friend VecScalar operator-(VecScalar a, VecScalar b) { return {a.v - b.v}; }
  friend VecScalar fmadd(VecScalar a, VecScalar b, VecScalar c) { return {fma_float(a.v, b.v, c.v)}; }
  friend VecScalar elu(VecScalar a) { return {a.v > 0.0f ? a.v : expm1_neg_scalar(a.v)}; }
  friend VecScalar relu(VecScalar a) { return {a.v > 0.0f ? a.v : 0.0f}; }
};

}  // namespace terralign::nn
