// The NEON vector wrapper (4 floats): aarch64, where NEON and FMA are always present, and 32-bit
// ARM built for NEON with VFPv4's fused multiply-add (-mfpu=neon-vfpv4: Cortex-A7, A15 and later;
// the Cortex-A8 and A9 have no fused NEON multiply-add, so they keep the scalar kernels).
// 32-bit ARM's NEON flushes subnormal inputs and results to zero whatever FPSCR says, so a
// convolution there differs from the other builds where a value falls below 2^-126 in magnitude
// (tests/test_nn.cpp's "subnormal values"); under qemu-arm, which flushes as the cores do, the
// suite's bit-for-bit cases and the firmware's answers are the host's.
#pragma once

#include <arm_neon.h>

#include "simd_scalar.hpp"  // kExpShifter

namespace terralign::nn {

// t (1 + t/2 + ... + t^5/720) by Horner: exp(t) - 1 to degree 6, as the AVX2 build.
inline float32x4_t taylor6_neon(float32x4_t t) {
  float32x4_t q = vdupq_n_f32(1.0f / 720.0f);
  q = vfmaq_f32(vdupq_n_f32(1.0f / 120.0f), q, t);
  q = vfmaq_f32(vdupq_n_f32(1.0f / 24.0f), q, t);
  q = vfmaq_f32(vdupq_n_f32(1.0f / 6.0f), q, t);
  q = vfmaq_f32(vdupq_n_f32(0.5f), q, t);
  q = vfmaq_f32(vdupq_n_f32(1.0f), q, t);
  return vmulq_f32(q, t);
}

// exp(x) - 1 for x <= 0, the same range reduction and polynomial as expm1_neg_avx2.
inline float32x4_t expm1_neg_neon(float32x4_t x) {
  const float32x4_t shifter = vdupq_n_f32(kExpShifter);
  x = vmaxq_f32(vdupq_n_f32(-87.0f), x);
  const float32x4_t nb = vfmaq_f32(shifter, x, vdupq_n_f32(1.44269504088896341f));
  const float32x4_t r = vfmsq_f32(x, vsubq_f32(nb, shifter), vdupq_n_f32(0.693147180559945309f));
  const float32x4_t s = vreinterpretq_f32_s32(vshlq_n_s32(vreinterpretq_s32_f32(nb), 23));
  return vfmaq_f32(vsubq_f32(s, vdupq_n_f32(1.0f)), s, taylor6_neon(r));
}

struct VecNeon {
  static constexpr int kWidth = 4;
  static constexpr int kBlock = 8;  // output channels a weight block holds (two vectors)
#if defined(__aarch64__)
  static constexpr int kTilePixels = 6;  // output pixels a register tile holds
  static constexpr int kTileBlocks = 2;  // 6 x 2 x 2 = 24 accumulators of 32 registers
#else
  static constexpr int kTilePixels = 4;  // 32-bit ARM: 4 x 1 x 2 = 8 accumulators of 16 registers
  static constexpr int kTileBlocks = 1;
#endif
  using Lanes8 = VecNeon;                // the one-output-channel kernel's eight lanes: two vectors
  float32x4_t v;
  static VecNeon load(const float* p) { return {vld1q_f32(p)}; }
  static VecNeon set1(float x) { return {vdupq_n_f32(x)}; }
  void store(float* p) const { vst1q_f32(p, v); }
  friend VecNeon operator+(VecNeon a, VecNeon b) { return {vaddq_f32(a.v, b.v)}; }
  friend VecNeon operator-(VecNeon a, VecNeon b) { return {vsubq_f32(a.v, b.v)}; }
  friend VecNeon fmadd(VecNeon a, VecNeon b, VecNeon c) { return {vfmaq_f32(c.v, a.v, b.v)}; }
  friend VecNeon elu(VecNeon a) {
    const float32x4_t zero = vdupq_n_f32(0.0f);
    // As VecAvx2's: expm1 of a positive a is garbage, and the select drops it.
    return {vbslq_f32(vcgtq_f32(a.v, zero), a.v, expm1_neg_neon(a.v))};
  }
  friend VecNeon relu(VecNeon a) { return {vmaxq_f32(a.v, vdupq_n_f32(0.0f))}; }
};

}  // namespace terralign::nn
