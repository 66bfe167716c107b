// NEON (aarch64) build of the shading kernels: four pixels a step, texels fetched lane by
// lane (NEON has no gather). Same float operations in the same order as shade_scalar.cpp
// (the raster target compiles with -ffp-contract=off), so the output matches it bit for bit.
#include <terralign/raster/shade_kernels.hpp>

#include <arm_neon.h>

#include <cmath>

namespace terralign::raster {
namespace {

struct Acc4 {
  float32x4_t r, g, b, a;
};

inline Acc4 sample4(const ShadeParams& p, int32x4_t level, float32x4_t u, float32x4_t v) {
  int32_t lv[4];
  vst1q_s32(lv, level);
  int32_t off_a[4], wid_a[4], hei_a[4];
  float scale_a[4];
  for (int k = 0; k < 4; ++k) {
    const MipLevel& L = p.levels[lv[k]];
    off_a[k] = L.offset;
    wid_a[k] = L.width;
    hei_a[k] = L.height;
    scale_a[k] = L.scale;
  }
  const int32x4_t off = vld1q_s32(off_a), wid = vld1q_s32(wid_a), hei = vld1q_s32(hei_a);
  const float32x4_t scale = vld1q_f32(scale_a);
  const float32x4_t half = vdupq_n_f32(0.5f), one = vdupq_n_f32(1.0f);
  const float32x4_t ul = vsubq_f32(vmulq_f32(vaddq_f32(u, half), scale), half);
  const float32x4_t vl = vsubq_f32(vmulq_f32(vaddq_f32(v, half), scale), half);
  const float32x4_t fx0 = vrndmq_f32(ul), fy0 = vrndmq_f32(vl);
  const float32x4_t fx = vsubq_f32(ul, fx0), fy = vsubq_f32(vl, fy0);
  const int32x4_t x0 = vcvtq_s32_f32(fx0), y0 = vcvtq_s32_f32(fy0);
  const float32x4_t gx = vsubq_f32(one, fx), gy = vsubq_f32(one, fy);
  const float32x4_t w[4] = {vmulq_f32(gx, gy), vmulq_f32(fx, gy), vmulq_f32(gx, fy), vmulq_f32(fx, fy)};
  const int32x4_t zero = vdupq_n_s32(0), ione = vdupq_n_s32(1);
  const int32x4_t wm1 = vsubq_s32(wid, ione), hm1 = vsubq_s32(hei, ione);
  const uint32x4_t mask8 = vdupq_n_u32(255);
  Acc4 acc{vdupq_n_f32(0.0f), vdupq_n_f32(0.0f), vdupq_n_f32(0.0f), vdupq_n_f32(0.0f)};
  for (int k = 0; k < 4; ++k) {
    const int32x4_t x = vaddq_s32(x0, vdupq_n_s32(k & 1));
    const int32x4_t y = vaddq_s32(y0, vdupq_n_s32(k >> 1));
    const uint32x4_t inside = vandq_u32(vandq_u32(vcgeq_s32(x, zero), vcltq_s32(x, wid)),
                                        vandq_u32(vcgeq_s32(y, zero), vcltq_s32(y, hei)));
    const int32x4_t xc = vminq_s32(vmaxq_s32(x, zero), wm1);
    const int32x4_t yc = vminq_s32(vmaxq_s32(y, zero), hm1);
    const int32x4_t at = vaddq_s32(off, vaddq_s32(vmulq_s32(yc, wid), xc));
    uint32x4_t t = vdupq_n_u32(0);
    t = vld1q_lane_u32(p.texels + vgetq_lane_s32(at, 0), t, 0);
    t = vld1q_lane_u32(p.texels + vgetq_lane_s32(at, 1), t, 1);
    t = vld1q_lane_u32(p.texels + vgetq_lane_s32(at, 2), t, 2);
    t = vld1q_lane_u32(p.texels + vgetq_lane_s32(at, 3), t, 3);
    const float32x4_t wk = vreinterpretq_f32_u32(vandq_u32(vreinterpretq_u32_f32(w[k]), inside));
    const float32x4_t wa = vmulq_f32(wk, vcvtq_f32_u32(vshrq_n_u32(t, 24)));
    acc.r = vaddq_f32(acc.r, vmulq_f32(wa, vcvtq_f32_u32(vandq_u32(t, mask8))));
    acc.g = vaddq_f32(acc.g, vmulq_f32(wa, vcvtq_f32_u32(vandq_u32(vshrq_n_u32(t, 8), mask8))));
    acc.b = vaddq_f32(acc.b, vmulq_f32(wa, vcvtq_f32_u32(vandq_u32(vshrq_n_u32(t, 16), mask8))));
    acc.a = vaddq_f32(acc.a, wa);
  }
  return acc;
}

inline float32x4_t mask(float32x4_t v, uint32x4_t m) { return vreinterpretq_f32_u32(vandq_u32(vreinterpretq_u32_f32(v), m)); }

}  // namespace

void shade_row_neon(int n, const float* wx, const float* wy, const float* log2fp, std::uint8_t* rgb,
                    std::uint8_t* valid, const ShadeParams& p) {
  const int top = p.n_levels - 1;
  const float32x4_t ftop = vdupq_n_f32(static_cast<float>(top));
  const int32x4_t itop = vdupq_n_s32(top);
  const float32x4_t zero = vdupq_n_f32(0.0f), one = vdupq_n_f32(1.0f), half = vdupq_n_f32(0.5f);
  int i = 0;
  for (; i + 4 <= n; i += 4) {
    const float32x4_t x = vld1q_f32(wx + i), y = vld1q_f32(wy + i);
    const uint32x4_t terrain = vceqq_f32(x, x);  // not NaN
    const float32x4_t xs = mask(x, terrain), ys = mask(y, terrain);
    const float32x4_t u = vaddq_f32(vaddq_f32(vdupq_n_f32(p.a0), vmulq_f32(vdupq_n_f32(p.a1), xs)),
                                    vmulq_f32(vdupq_n_f32(p.a2), ys));
    const float32x4_t v = vaddq_f32(vaddq_f32(vdupq_n_f32(p.b0), vmulq_f32(vdupq_n_f32(p.b1), xs)),
                                    vmulq_f32(vdupq_n_f32(p.b2), ys));
    float32x4_t lod = vaddq_f32(mask(vld1q_f32(log2fp + i), terrain), vdupq_n_f32(p.lod_bias));
    lod = vbslq_f32(vcgtq_f32(lod, zero), lod, zero);  // lod > 0 ? lod : 0 (NaN -> 0)
    lod = vbslq_f32(vcltq_f32(lod, ftop), lod, ftop);  // lod < top ? lod : top
    const float32x4_t fl = vrndmq_f32(lod);
    const int32x4_t l0 = vcvtq_s32_f32(fl);
    const int32x4_t l1 = vminq_s32(vaddq_s32(l0, vdupq_n_s32(1)), itop);
    const float32x4_t t = vsubq_f32(lod, fl);
    const Acc4 s0 = sample4(p, l0, u, v);
    const uint32x4_t live = vcgtq_f32(t, zero);
    Acc4 acc;
    if (vmaxvq_u32(live) == 0) {
      acc = s0;  // t == 0 in every lane: s0 * 1 + s1 * 0 == s0, as the scalar kernel's shortcut
    } else {
      Acc4 s1 = sample4(p, l1, u, v);
      s1.r = mask(s1.r, live);
      s1.g = mask(s1.g, live);
      s1.b = mask(s1.b, live);
      s1.a = mask(s1.a, live);
      const float32x4_t w0 = vsubq_f32(one, t);
      acc.r = vaddq_f32(vmulq_f32(s0.r, w0), vmulq_f32(s1.r, t));
      acc.g = vaddq_f32(vmulq_f32(s0.g, w0), vmulq_f32(s1.g, t));
      acc.b = vaddq_f32(vmulq_f32(s0.b, w0), vmulq_f32(s1.b, t));
      acc.a = vaddq_f32(vmulq_f32(s0.a, w0), vmulq_f32(s1.a, t));
    }
    acc.a = mask(acc.a, terrain);
    const uint32x4_t ok = vcgeq_f32(acc.a, vdupq_n_f32(127.5f));
    const float32x4_t inv = mask(vdivq_f32(one, acc.a), ok);
    std::uint32_t r[4], g[4], b[4], okb[4];
    vst1q_u32(r, vreinterpretq_u32_s32(vcvtq_s32_f32(vaddq_f32(vmulq_f32(mask(acc.r, terrain), inv), half))));
    vst1q_u32(g, vreinterpretq_u32_s32(vcvtq_s32_f32(vaddq_f32(vmulq_f32(mask(acc.g, terrain), inv), half))));
    vst1q_u32(b, vreinterpretq_u32_s32(vcvtq_s32_f32(vaddq_f32(vmulq_f32(mask(acc.b, terrain), inv), half))));
    vst1q_u32(okb, ok);
    for (int k = 0; k < 4; ++k) {
      rgb[3 * (i + k) + 0] = static_cast<std::uint8_t>(r[k]);
      rgb[3 * (i + k) + 1] = static_cast<std::uint8_t>(g[k]);
      rgb[3 * (i + k) + 2] = static_cast<std::uint8_t>(b[k]);
      valid[i + k] = okb[k] ? 255 : 0;
    }
  }
  if (i < n) shade_row_scalar(n - i, wx + i, wy + i, log2fp + i, rgb + 3 * i, valid + i, p);
}

void resolve_row_neon(int n, const int* ids, const float* coef, float dx0, float dy, float* wx, float* wy,
                      float* z, float* log2fp) {
  const float32x4_t one = vdupq_n_f32(1.0f), vdy = vdupq_n_f32(dy);
  auto b = [](float v) { return vdupq_n_f32(v); };
  static const float lanes[4] = {0, 1, 2, 3};
  int i = 0;
  for (; i + 4 <= n; i += 4) {
    // Each lane's planes, loaded lane by lane (NEON has no gather); lanes with no terrain
    // compute on zeros and are overwritten below.
    float cl[9][4];
    for (int l = 0; l < 4; ++l)
      for (int k = 0; k < 9; ++k) cl[k][l] = ids[i + l] < 0 ? 0.0f : coef[9 * static_cast<std::ptrdiff_t>(ids[i + l]) + k];
    float32x4_t c[9];
    for (int k = 0; k < 9; ++k) c[k] = vld1q_f32(cl[k]);
    const float32x4_t dx = vaddq_f32(vdupq_n_f32(dx0 + static_cast<float>(i)), vld1q_f32(lanes));
    const float32x4_t iz = vaddq_f32(vaddq_f32(c[0], vmulq_f32(c[2], vdy)), vmulq_f32(c[1], dx));
    const float32x4_t zz = vdivq_f32(one, iz);
    const float32x4_t x = vmulq_f32(vaddq_f32(vaddq_f32(c[3], vmulq_f32(c[5], vdy)), vmulq_f32(c[4], dx)), zz);
    const float32x4_t y = vmulq_f32(vaddq_f32(vaddq_f32(c[6], vmulq_f32(c[8], vdy)), vmulq_f32(c[7], dx)), zz);
    vst1q_f32(z + i, zz);
    vst1q_f32(wx + i, x);
    vst1q_f32(wy + i, y);
    const float32x4_t du_x = vmulq_f32(vsubq_f32(c[4], vmulq_f32(x, c[1])), zz);
    const float32x4_t du_y = vmulq_f32(vsubq_f32(c[7], vmulq_f32(y, c[1])), zz);
    const float32x4_t dv_x = vmulq_f32(vsubq_f32(c[5], vmulq_f32(x, c[2])), zz);
    const float32x4_t dv_y = vmulq_f32(vsubq_f32(c[8], vmulq_f32(y, c[2])), zz);
    const float32x4_t su = vaddq_f32(vmulq_f32(du_x, du_x), vmulq_f32(du_y, du_y));
    const float32x4_t sv = vaddq_f32(vmulq_f32(dv_x, dv_x), vmulq_f32(dv_y, dv_y));
    float32x4_t d2 = vbslq_f32(vcgtq_f32(su, sv), su, sv);
    d2 = vbslq_f32(vcgtq_f32(d2, b(1e-12f)), d2, b(1e-12f));
    // fast_log2, lane-wise: exponent plus a quadratic in the mantissa.
    const uint32x4_t bits = vreinterpretq_u32_f32(d2);
    const float32x4_t e = vcvtq_f32_s32(vsubq_s32(vreinterpretq_s32_u32(vshrq_n_u32(bits, 23)), vdupq_n_s32(127)));
    const float32x4_t m = vreinterpretq_f32_u32(vorrq_u32(vandq_u32(bits, vdupq_n_u32(0x7fffff)), vdupq_n_u32(0x3f800000)));
    const float32x4_t poly = vsubq_f32(vmulq_f32(vaddq_f32(vmulq_f32(b(-0.34484843f), m), b(2.02466578f)), m), b(0.67487759f));
    vst1q_f32(log2fp + i, vmulq_f32(b(0.5f), vaddq_f32(e, poly)));
    for (int l = 0; l < 4; ++l)
      if (ids[i + l] < 0) {
        wx[i + l] = wy[i + l] = z[i + l] = NAN;
        log2fp[i + l] = 0.0f;
      }
  }
  if (i < n) resolve_row_scalar(n - i, ids + i, coef, dx0 + static_cast<float>(i), dy, wx + i, wy + i, z + i, log2fp + i);
}

void depth_block_neon(int w, int h, float base, float A, float B, int dx, int dy, float* z, int* id,
                      std::ptrdiff_t stride, int e) {
  if (w < 4) {
    depth_block_scalar(w, h, base, A, B, dx, dy, z, id, stride, e);
    return;
  }
  static const std::int32_t lanes[4] = {0, 1, 2, 3};
  const int32x4_t lane = vld1q_s32(lanes);
  const float32x4_t a0 = vmulq_n_f32(vcvtq_f32_s32(vaddq_s32(vdupq_n_s32(dx), lane)), A);
  const float32x4_t a1 = vmulq_n_f32(vcvtq_f32_s32(vaddq_s32(vdupq_n_s32(dx + 4), lane)), A);
  const int32x4_t ve = vdupq_n_s32(e);
  for (int r = 0; r < h; ++r, z += stride, id += stride) {
    const float rowz = base + B * static_cast<float>(dy + r);
    const float32x4_t rz = vdupq_n_f32(rowz);
    const float32x4_t iz = vaddq_f32(rz, a0);
    const float32x4_t old = vld1q_f32(z);
    const uint32x4_t nearer = vcgtq_f32(iz, old);
    vst1q_f32(z, vbslq_f32(nearer, iz, old));
    vst1q_s32(id, vbslq_s32(nearer, ve, vld1q_s32(id)));
    if (w == 8) {
      const float32x4_t iz1 = vaddq_f32(rz, a1);
      const float32x4_t old1 = vld1q_f32(z + 4);
      const uint32x4_t nearer1 = vcgtq_f32(iz1, old1);
      vst1q_f32(z + 4, vbslq_f32(nearer1, iz1, old1));
      vst1q_s32(id + 4, vbslq_s32(nearer1, ve, vld1q_s32(id + 4)));
    } else {
      for (int i = 4; i < w; ++i) {
        const float izs = rowz + A * static_cast<float>(dx + i);
        if (izs > z[i]) {
          z[i] = izs;
          id[i] = e;
        }
      }
    }
  }
}

}  // namespace terralign::raster

