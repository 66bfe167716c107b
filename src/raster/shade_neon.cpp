// NEON (aarch64) build of the shading kernels: 4 pixels a vector, the filter of
// shade_kernels.hpp in 16-bit lanes (R and B words, G and A words of each pixel's 32
// bits; vqrdmulh is the lerp's rounding multiply), texels fetched lane by lane (NEON has no
// gather). The same integer and float operations in the same order as shade_scalar.cpp (the
// raster target compiles with -ffp-contract=off), so the output matches it bit for bit. The
// tail (n % 4) runs the scalar kernel. Also the NEON depth kernel and edge kernels (64 and 32 bits).
#include <terralign/raster/shade_kernels.hpp>

#include <arm_neon.h>

#include <cmath>

#include "edge_neon.hpp"

namespace terralign::raster {
namespace {

// A sample's channels in the filter's fixed point: R|B and G|A word pairs, x128.
struct Sample4 {
  int16x8_t rb, ga;
};

inline int16x8_t lerp15(int16x8_t a, int16x8_t b, int16x8_t f) { return vaddq_s16(a, vqrdmulhq_s16(vsubq_s16(b, a), f)); }

// (U & 255) << 7 in both 16-bit halves of each lane.
inline int16x8_t fraction_pair(int32x4_t U) {
  const uint32x4_t f = vshlq_n_u32(vandq_u32(vreinterpretq_u32_s32(U), vdupq_n_u32(255)), 7);
  return vreinterpretq_s16_u32(vorrq_u32(f, vshlq_n_u32(f, 16)));
}

// One row of taps lerped by the column fraction.
inline Sample4 lerp_row(uint32x4_t left, uint32x4_t right, int16x8_t fx) {
  const uint32x4_t m = vdupq_n_u32(0x7F807F80u);
  const int16x8_t rb_l = vreinterpretq_s16_u32(vandq_u32(vshlq_n_u32(left, 7), m));
  const int16x8_t rb_r = vreinterpretq_s16_u32(vandq_u32(vshlq_n_u32(right, 7), m));
  const int16x8_t ga_l = vreinterpretq_s16_u32(vandq_u32(vshrq_n_u32(left, 1), m));
  const int16x8_t ga_r = vreinterpretq_s16_u32(vandq_u32(vshrq_n_u32(right, 1), m));
  return {lerp15(rb_l, rb_r, fx), lerp15(ga_l, ga_r, fx)};
}

inline uint32x4_t load_lanes(const std::uint32_t* texels, int32x4_t at) {
  uint32x4_t t = vdupq_n_u32(0);
  t = vld1q_lane_u32(texels + vgetq_lane_s32(at, 0), t, 0);
  t = vld1q_lane_u32(texels + vgetq_lane_s32(at, 1), t, 1);
  t = vld1q_lane_u32(texels + vgetq_lane_s32(at, 2), t, 2);
  t = vld1q_lane_u32(texels + vgetq_lane_s32(at, 3), t, 3);
  return t;
}

// Bilinear sample of 4 lanes seeing world (x, y) at one level.
inline Sample4 sample4(const ShadeParams& p, int level, float32x4_t x, float32x4_t y) {
  const MipLevel& L = p.levels[level];
  const LevelCoords& k = p.coords[level];
  // vcvtm: convert rounding towards minus infinity, floor() then a conversion in one step.
  const int32x4_t U = vcvtmq_s32_f32(vaddq_f32(vaddq_f32(vdupq_n_f32(k.a0), vmulq_f32(vdupq_n_f32(k.a1), x)),
                                               vmulq_f32(vdupq_n_f32(k.a2), y)));
  const int32x4_t V = vcvtmq_s32_f32(vaddq_f32(vaddq_f32(vdupq_n_f32(k.b0), vmulq_f32(vdupq_n_f32(k.b1), x)),
                                               vmulq_f32(vdupq_n_f32(k.b2), y)));
  const int32x4_t x0 = vshrq_n_s32(U, 8), y0 = vshrq_n_s32(V, 8);
  const int32x4_t wid = vdupq_n_s32(L.width), hei = vdupq_n_s32(L.height);
  const int32x4_t zero = vdupq_n_s32(0), ione = vdupq_n_s32(1);
  const int32x4_t wm1 = vsubq_s32(wid, ione), hm1 = vsubq_s32(hei, ione);
  const int32x4_t off = vdupq_n_s32(L.offset);
  uint32x4_t t00, t10, t01, t11;
  // 0 <= x0 < w - 1 and 0 <= y0 < h - 1 unsigned: every lane's four taps inside.
  const uint32x4_t interior = vandq_u32(vcltq_u32(vreinterpretq_u32_s32(x0), vreinterpretq_u32_s32(wm1)),
                                        vcltq_u32(vreinterpretq_u32_s32(y0), vreinterpretq_u32_s32(hm1)));
  if (vminvq_u32(interior) != 0) {
    const int32x4_t at = vaddq_s32(off, vaddq_s32(vmulq_s32(y0, wid), x0));
    t00 = load_lanes(p.texels, at);
    t10 = load_lanes(p.texels, vaddq_s32(at, ione));
    t01 = load_lanes(p.texels, vaddq_s32(at, wid));
    t11 = load_lanes(p.texels, vaddq_s32(vaddq_s32(at, wid), ione));
  } else {
    // Each tap clamped into the level for its fetch, and 0 where it lies outside.
    auto tap = [&](int kx, int ky) {
      const int32x4_t tx = vaddq_s32(x0, vdupq_n_s32(kx)), ty = vaddq_s32(y0, vdupq_n_s32(ky));
      const uint32x4_t inside = vandq_u32(vandq_u32(vcgeq_s32(tx, zero), vcltq_s32(tx, wid)),
                                          vandq_u32(vcgeq_s32(ty, zero), vcltq_s32(ty, hei)));
      const int32x4_t xc = vminq_s32(vmaxq_s32(tx, zero), wm1), yc = vminq_s32(vmaxq_s32(ty, zero), hm1);
      return vandq_u32(load_lanes(p.texels, vaddq_s32(off, vaddq_s32(vmulq_s32(yc, wid), xc))), inside);
    };
    t00 = tap(0, 0);
    t10 = tap(1, 0);
    t01 = tap(0, 1);
    t11 = tap(1, 1);
  }
  const int16x8_t fx = fraction_pair(U), fy = fraction_pair(V);
  const Sample4 top = lerp_row(t00, t10, fx), bottom = lerp_row(t01, t11, fx);
  return {lerp15(top.rb, bottom.rb, fy), lerp15(top.ga, bottom.ga, fy)};
}

// Shades 4 pixels at world (x, y) where `terrain` is all ones (elsewhere colour 0, invalid),
// with footprints log2fp: each lane's level pair is pixel_level()'s.
inline void shade4(const ShadeParams& p, uint32x4_t terrain, float32x4_t x, float32x4_t y, const float* log2fp,
                   std::uint8_t* rgb, std::uint8_t* valid) {
  Sample4 s{vdupq_n_s16(0), vdupq_n_s16(0)};
  std::uint32_t in[4];
  vst1q_u32(in, terrain);
  if (vmaxvq_u32(terrain) != 0) {
    // Lanes without terrain compute on (0, 0) and are cleared below.
    const float32x4_t xs = vreinterpretq_f32_u32(vandq_u32(vreinterpretq_u32_f32(x), terrain));
    const float32x4_t ys = vreinterpretq_f32_u32(vandq_u32(vreinterpretq_u32_f32(y), terrain));
    LevelPair lev[4];
    std::int32_t l0[4], l1[4];
    std::uint32_t t[4];
    int lo = 1 << 30, hi = -1, hi1 = -1;
    for (int k = 0; k < 4; ++k) {
      lev[k] = pixel_level(log2fp[k], p);
      l0[k] = lev[k].l0;
      l1[k] = lev[k].l1;
      t[k] = static_cast<std::uint32_t>(lev[k].t) | static_cast<std::uint32_t>(lev[k].t) << 16;
      if (!in[k]) continue;
      lo = l0[k] < lo ? l0[k] : lo;
      hi = l0[k] > hi ? l0[k] : hi;
      hi1 = l1[k] > hi1 ? l1[k] : hi1;
    }
    const int16x8_t tv = vreinterpretq_s16_u32(vandq_u32(vld1q_u32(t), terrain));
    // Every level from the least l0 to the greatest l1, each lane taking its own two (one
    // level and, where some lane's fraction is not 0, the next, when all share l0).
    const int32x4_t vl0 = vld1q_s32(l0), vl1 = vld1q_s32(l1);
    Sample4 s0 = s, s1 = s;
    const bool blend = vmaxvq_u32(vreinterpretq_u32_s16(tv)) != 0;
    for (int level = lo; level <= (blend ? hi1 : hi); ++level) {
      const Sample4 at = sample4(p, level, xs, ys);
      const uint32x4_t first = vceqq_s32(vl0, vdupq_n_s32(level)), second = vceqq_s32(vl1, vdupq_n_s32(level));
      s0.rb = vbslq_s16(vreinterpretq_u16_u32(first), at.rb, s0.rb);
      s0.ga = vbslq_s16(vreinterpretq_u16_u32(first), at.ga, s0.ga);
      s1.rb = vbslq_s16(vreinterpretq_u16_u32(second), at.rb, s1.rb);
      s1.ga = vbslq_s16(vreinterpretq_u16_u32(second), at.ga, s1.ga);
    }
    s.rb = vreinterpretq_s16_u32(vandq_u32(vreinterpretq_u32_s16(lerp15(s0.rb, s1.rb, tv)), terrain));
    s.ga = vreinterpretq_s16_u32(vandq_u32(vreinterpretq_u32_s16(lerp15(s0.ga, s1.ga, tv)), terrain));
  }
  const uint32x4_t rb = vreinterpretq_u32_s16(s.rb), ga = vreinterpretq_u32_s16(s.ga);
  const uint32x4_t sa = vshrq_n_u32(ga, 16);
  const uint32x4_t ok = vcgeq_u32(sa, vdupq_n_u32(16320));
  std::uint32_t c[3][4], okb[4];
  vst1q_u32(okb, ok);
  if (vmaxvq_u32(vandq_u32(ok, vmvnq_u32(vceqq_u32(sa, vdupq_n_u32(32640))))) == 0) {
    // (S + 64) >> 7 per channel.
    const uint32x4_t lo = vdupq_n_u32(0xFFFF), r64 = vdupq_n_u32(64);
    vst1q_u32(c[0], vshrq_n_u32(vaddq_u32(vandq_u32(rb, lo), r64), 7));
    vst1q_u32(c[1], vshrq_n_u32(vaddq_u32(vandq_u32(ga, lo), r64), 7));
    vst1q_u32(c[2], vshrq_n_u32(vaddq_u32(vshrq_n_u32(rb, 16), r64), 7));
  } else {
    // c = min(255, (int)(float(S_c * 255) / float(S_a) + 0.5)).
    const float32x4_t fa = vcvtq_f32_u32(sa);
    const uint32x4_t lo = vdupq_n_u32(0xFFFF), c255 = vdupq_n_u32(255);
    auto channel = [&](uint32x4_t sc) {
      const float32x4_t q = vdivq_f32(vcvtq_f32_u32(vmulq_u32(sc, c255)), fa);
      return vminq_u32(vcvtq_u32_f32(vaddq_f32(q, vdupq_n_f32(0.5f))), c255);
    };
    vst1q_u32(c[0], channel(vandq_u32(rb, lo)));
    vst1q_u32(c[1], channel(vandq_u32(ga, lo)));
    vst1q_u32(c[2], channel(vshrq_n_u32(rb, 16)));
  }
  for (int k = 0; k < 4; ++k) {
    rgb[3 * k + 0] = static_cast<std::uint8_t>(okb[k] ? c[0][k] : 0);
    rgb[3 * k + 1] = static_cast<std::uint8_t>(okb[k] ? c[1][k] : 0);
    rgb[3 * k + 2] = static_cast<std::uint8_t>(okb[k] ? c[2][k] : 0);
    valid[k] = okb[k] ? 255 : 0;
  }
}

}  // namespace

void shade_row_neon(int n, const float* wx, const float* wy, const float* log2fp, std::uint8_t* rgb,
                    std::uint8_t* valid, const ShadeParams& p) {
  int i = 0;
  for (; i + 4 <= n; i += 4) {
    const float32x4_t x = vld1q_f32(wx + i);
    shade4(p, vceqq_f32(x, x), x, vld1q_f32(wy + i), log2fp + i, rgb + 3 * i, valid + i);
  }
  if (i < n) shade_row_scalar(n - i, wx + i, wy + i, log2fp + i, rgb + 3 * i, valid + i, p);
}

void resolve_shade_row_neon(int n, const int* ids, const float* coef, float dx0, float dy, float* z, int n_targets,
                            const ShadeTarget* targets) {
  static const float lanes[4] = {0, 1, 2, 3};
  const float32x4_t one = vdupq_n_f32(1.0f);
  const float max_bias = max_lod_bias(n_targets, targets);
  int i = 0;
  for (; i + 4 <= n; i += 4) {
    // Each lane's planes with the row's part summed (r = q + dq/dy dy, the scalar twin's
    // first operation), loaded lane by lane; lanes with no terrain compute on zeros. The
    // footprint per lane is the scalar plane_footprint_log2(), where some target needs it.
    float pl[6][4], l2[4], bound[4];
    std::uint32_t seen[4];
    for (int l = 0; l < 4; ++l) {
      const int e = ids[i + l];
      seen[l] = e >= 0 ? 0xFFFFFFFFu : 0u;
      const float* c = coef + kPlaneFloats * static_cast<std::ptrdiff_t>(e < 0 ? 0 : e);
      pl[0][l] = e < 0 ? 0.0f : c[0] + c[2] * dy;
      pl[1][l] = e < 0 ? 0.0f : c[1];
      pl[2][l] = e < 0 ? 0.0f : c[3] + c[5] * dy;
      pl[3][l] = e < 0 ? 0.0f : c[4];
      pl[4][l] = e < 0 ? 0.0f : c[6] + c[8] * dy;
      pl[5][l] = e < 0 ? 0.0f : c[7];
      bound[l] = e < 0 ? INFINITY : c[9];
      l2[l] = e < 0 || entry_magnified(bound[l], max_bias) ? 0.0f : plane_footprint_log2(c, dx0 + static_cast<float>(i + l), dy);
    }
    const uint32x4_t in = vld1q_u32(seen);
    const float32x4_t dx = vaddq_f32(vdupq_n_f32(dx0 + static_cast<float>(i)), vld1q_f32(lanes));
    const float32x4_t zz = vdivq_f32(one, vaddq_f32(vld1q_f32(pl[0]), vmulq_f32(vld1q_f32(pl[1]), dx)));
    const float32x4_t x = vmulq_f32(vaddq_f32(vld1q_f32(pl[2]), vmulq_f32(vld1q_f32(pl[3]), dx)), zz);
    const float32x4_t y = vmulq_f32(vaddq_f32(vld1q_f32(pl[4]), vmulq_f32(vld1q_f32(pl[5]), dx)), zz);
    vst1q_f32(z + i, vbslq_f32(in, zz, vdupq_n_f32(NAN)));
    for (int k = 0; k < n_targets; ++k) {
      const ShadeParams& p = *targets[k].params;
      float l2k[4];
      for (int l = 0; l < 4; ++l) l2k[l] = entry_magnified(bound[l], p.lod_bias) ? -INFINITY : l2[l];
      shade4(p, in, x, y, l2k, targets[k].rgb + 3 * i, targets[k].valid + i);
    }
  }
  if (i < n) {
    ShadeTarget rest[kMaxShadeTargets];
    for (int k = 0; k < n_targets; ++k) rest[k] = {targets[k].params, targets[k].rgb + 3 * i, targets[k].valid + i};
    resolve_shade_row_scalar(n - i, ids + i, coef, dx0 + static_cast<float>(i), dy, z + i, n_targets, rest);
  }
}

void depth_block_neon(int w, int h, float base, float A, float B, int dx, int dy, float* z, int* id,
                      std::ptrdiff_t stride, int e) {
  // Four columns at a time, each group's A (dx + i) kept for every row; a last group of
  // fewer columns pixel by pixel.
  static const std::int32_t lanes[4] = {0, 1, 2, 3};
  const int32x4_t lane = vld1q_s32(lanes);
  constexpr int kGroups = kDepthBlockMaxW / 4;
  float32x4_t ax[kGroups];
  const int groups = w / 4;
  for (int g = 0; g < groups; ++g) ax[g] = vmulq_n_f32(vcvtq_f32_s32(vaddq_s32(vdupq_n_s32(dx + 4 * g), lane)), A);
  const int32x4_t ve = vdupq_n_s32(e);
  for (int r = 0; r < h; ++r, z += stride, id += stride) {
    const float rowz = base + B * static_cast<float>(dy + r);
    const float32x4_t rz = vdupq_n_f32(rowz);
    for (int g = 0; g < groups; ++g) {
      const float32x4_t iz = vaddq_f32(rz, ax[g]);
      const float32x4_t old = vld1q_f32(z + 4 * g);
      const uint32x4_t nearer = vcgtq_f32(iz, old);
      vst1q_f32(z + 4 * g, vbslq_f32(nearer, iz, old));
      vst1q_s32(id + 4 * g, vbslq_s32(nearer, ve, vld1q_s32(id + 4 * g)));
    }
    for (int i = 4 * groups; i < w; ++i) {
      const float izs = rowz + A * static_cast<float>(dx + i);
      if (izs > z[i]) {
        z[i] = izs;
        id[i] = e;
      }
    }
  }
}

long edge_block32_neon(int w, int h, const std::int32_t* E, const std::int32_t* dEx, const std::int32_t* dEy, float base,
                       float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride, int e) {
  return edge_block32_neon_inline(w, h, E, dEx, dEy, base, A, B, dx, dy, z, id, stride, e);
}

long edge_block_neon(int w, int h, const std::int64_t* E, const std::int64_t* dEx, const std::int64_t* dEy, float base,
                     float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride, int e) {
  // Edge k at columns 2 p and 2 p + 1 of a row: row start + {2 p, 2 p + 1} dEx, four pairs
  // for the eight columns (the second four only where w > 4); a half's two pairs' coverage
  // narrowed to four 32-bit lanes for the depth test.
  static const std::int32_t lanes[8] = {0, 1, 2, 3, 4, 5, 6, 7};
  const int halves = w > 4 ? 2 : 1;
  int64x2_t step[3][4], row[3], down[3];
  for (int k = 0; k < 3; ++k) {
    for (int p = 0; p < 4; ++p) {
      const std::int64_t pair[2] = {2 * p * dEx[k], (2 * p + 1) * dEx[k]};
      step[k][p] = vld1q_s64(pair);
    }
    row[k] = vdupq_n_s64(E[k]);
    down[k] = vdupq_n_s64(dEy[k]);
  }
  uint32x4_t cols[2];
  float32x4_t ax[2];
  for (int half = 0; half < halves; ++half) {
    const int32x4_t lane = vld1q_s32(lanes + 4 * half);
    cols[half] = vcgtq_s32(vdupq_n_s32(w), lane);
    ax[half] = vmulq_f32(vdupq_n_f32(A), vcvtq_f32_s32(vaddq_s32(vdupq_n_s32(dx), lane)));
  }
  const int32x4_t ve = vdupq_n_s32(e);
  uint32x4_t count = vdupq_n_u32(0);
  for (int r = 0; r < h; ++r, z += stride, id += stride) {
    const float32x4_t rowz = vdupq_n_f32(base + B * static_cast<float>(dy + r));
    for (int half = 0; half < halves; ++half) {
      uint64x2_t in64[2];
      for (int j = 0; j < 2; ++j) {
        const int p = 2 * half + j;
        const int64x2_t any =
            vorrq_s64(vorrq_s64(vaddq_s64(row[0], step[0][p]), vaddq_s64(row[1], step[1][p])), vaddq_s64(row[2], step[2][p]));
        in64[j] = vcgezq_s64(any);  // all three >= 0
      }
      const uint32x4_t in = vandq_u32(vcombine_u32(vmovn_u64(in64[0]), vmovn_u64(in64[1])), cols[half]);
      depth_quad(in, vaddq_f32(rowz, ax[half]), z + 4 * half, id + 4 * half, ve, count);
    }
    for (int k = 0; k < 3; ++k) row[k] = vaddq_s64(row[k], down[k]);
  }
  return static_cast<long>(vaddvq_u32(count));
}

}  // namespace terralign::raster

