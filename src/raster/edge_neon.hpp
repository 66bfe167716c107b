// The 32-bit edge kernel (shade_kernels.hpp's edge_block32) in NEON, inline so that the
// renderer's run of small entries (geometry_neon.cpp's draw_small_entries_neon) runs it
// without a call, as edge_avx2.hpp does for the AVX2 builds; and the depth test of four
// columns that it and the 64-bit edge kernel (shade_neon.cpp) share.
#pragma once

#include <cstddef>
#include <cstdint>

#include <arm_neon.h>

namespace terralign::raster {

// The depth test of four columns of a row where `in` (all-ones lanes) marks the covered
// pixels: where the triangle's 1/z `iz` is larger (nearer), it replaces z and id becomes `ve`.
// The four columns are loaded and stored back whole. `count` gains one a covered lane.
inline void depth_quad(uint32x4_t in, float32x4_t iz, float* z, int* id, int32x4_t ve, uint32x4_t& count) {
  count = vsubq_u32(count, in);  // an all-ones lane is -1
  const float32x4_t old = vld1q_f32(z);
  const uint32x4_t nearer = vandq_u32(vcgtq_f32(iz, old), in);
  vst1q_f32(z, vbslq_f32(nearer, iz, old));
  vst1q_s32(id, vbslq_s32(nearer, ve, vld1q_s32(id)));
}

inline long edge_block32_neon_inline(int w, int h, const std::int32_t* E, const std::int32_t* dEx, const std::int32_t* dEy,
                                     float base, float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride, int e) {
  // Four columns of edge k a row in one register, two halves for the eight (the second only
  // where w > 4); 32-bit lanes wrap, and wrapping is exact for every value that fits (the
  // caller's promise for the block's pixels). Like the AVX2 build, a half's four columns are
  // loaded and stored back whole (the row stride holds them, shade_kernels.hpp).
  static const std::int32_t lanes[8] = {0, 1, 2, 3, 4, 5, 6, 7};
  const int halves = w > 4 ? 2 : 1;
  int32x4_t row[2][3], down[3];
  uint32x4_t cols[2];
  float32x4_t ax[2];
  for (int k = 0; k < 3; ++k) down[k] = vdupq_n_s32(dEy[k]);
  for (int half = 0; half < halves; ++half) {
    const int32x4_t lane = vld1q_s32(lanes + 4 * half);
    for (int k = 0; k < 3; ++k) row[half][k] = vaddq_s32(vdupq_n_s32(E[k]), vmulq_s32(vdupq_n_s32(dEx[k]), lane));
    cols[half] = vcgtq_s32(vdupq_n_s32(w), lane);
    ax[half] = vmulq_f32(vdupq_n_f32(A), vcvtq_f32_s32(vaddq_s32(vdupq_n_s32(dx), lane)));
  }
  const int32x4_t ve = vdupq_n_s32(e), zero = vdupq_n_s32(0);
  uint32x4_t count = vdupq_n_u32(0);
  for (int r = 0; r < h; ++r, z += stride, id += stride) {
    const float32x4_t rowz = vdupq_n_f32(base + B * static_cast<float>(dy + r));
    for (int half = 0; half < halves; ++half) {
      int32x4_t* v = row[half];
      const uint32x4_t in = vandq_u32(vcgeq_s32(vorrq_s32(vorrq_s32(v[0], v[1]), v[2]), zero), cols[half]);  // all three >= 0
      for (int k = 0; k < 3; ++k) v[k] = vaddq_s32(v[k], down[k]);
      depth_quad(in, vaddq_f32(rowz, ax[half]), z + 4 * half, id + 4 * half, ve, count);
    }
  }
  return static_cast<long>(vaddvq_u32(count));
}

}  // namespace terralign::raster
