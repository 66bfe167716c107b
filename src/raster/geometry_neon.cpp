// The NEON (aarch64) builds of the geometry kernels (geometry_kernels.hpp): the vertex stage,
// four posts a vector (float32x4, their projections in two float64x2 halves; a row's last
// posts by the scalar build); the triangle set-up, four quads' first triangles in one set of
// vectors and their second in another (the corners in int32x4, the planes in two float64x2
// halves; the row's loop is quad_row4.hpp's, shared with AVX2); the set-up of a tile's entries
// four at a time from their transposed triangles; and the drawing of a run of small entries
// through the inlined 32-bit edge kernel (edge_neon.hpp). Each step is the scalar build's
// operation lane by lane, in its order (the raster target says -ffp-contract=off, so no
// multiply and add fuse; AArch64's divisions and conversions to float round to nearest, as
// the scalar ones do), so the results are the scalar kernels' bit for bit.
#include <terralign/raster/geometry_kernels.hpp>

#include <arm_neon.h>

#include <cmath>

#include "edge_neon.hpp"
#include "quad_row4.hpp"

namespace terralign::raster {
namespace {

// Lanes 0-1 and 2-3 of a float32x4 widened to double.
inline float64x2_t low_pd(float32x4_t v) { return vcvt_f64_f32(vget_low_f32(v)); }
inline float64x2_t high_pd(float32x4_t v) { return vcvt_high_f64_f32(v); }
inline float64x2_t low_pd(int32x4_t v) { return vcvtq_f64_s64(vmovl_s32(vget_low_s32(v))); }
inline float64x2_t high_pd(int32x4_t v) { return vcvtq_f64_s64(vmovl_high_s32(v)); }

// Two float64x2 rounded to four floats.
inline float32x4_t to_ps(float64x2_t lo, float64x2_t hi) { return vcvt_high_f32_f64(vcvt_f32_f64(lo), hi); }

// Two 64-bit masks narrowed to the lanes of one 32-bit mask.
inline uint32x4_t narrow_mask(uint64x2_t lo, uint64x2_t hi) { return vcombine_u32(vmovn_u64(lo), vmovn_u64(hi)); }

// Bit i set where lane i of m is set.
inline unsigned lane_bits(uint32x4_t m) {
  static const std::uint32_t weights[4] = {1, 2, 4, 8};
  return vaddvq_u32(vandq_u32(m, vld1q_u32(weights)));
}

// r0 .. r3 <- the columns of the 4 x 4 matrix whose rows are r0 .. r3.
inline void transpose4(int32x4_t& r0, int32x4_t& r1, int32x4_t& r2, int32x4_t& r3) {
  const int32x4x2_t a = vtrnq_s32(r0, r1), b = vtrnq_s32(r2, r3);
  r0 = vcombine_s32(vget_low_s32(a.val[0]), vget_low_s32(b.val[0]));
  r1 = vcombine_s32(vget_low_s32(a.val[1]), vget_low_s32(b.val[1]));
  r2 = vcombine_s32(vget_high_s32(a.val[0]), vget_high_s32(b.val[0]));
  r3 = vcombine_s32(vget_high_s32(a.val[1]), vget_high_s32(b.val[1]));
}

// (C + A dx) + B dy in double, two lanes at a time, then float.
inline float32x4_t plane_at_corner(float32x4_t C, float32x4_t A, float32x4_t B, int32x4_t dx, int32x4_t dy) {
  const float64x2_t lo = vaddq_f64(vaddq_f64(low_pd(C), vmulq_f64(low_pd(A), low_pd(dx))), vmulq_f64(low_pd(B), low_pd(dy)));
  const float64x2_t hi =
      vaddq_f64(vaddq_f64(high_pd(C), vmulq_f64(high_pd(A), high_pd(dx))), vmulq_f64(high_pd(B), high_pd(dy)));
  return to_ps(lo, hi);
}

// Entries 4 g .. 4 g + 3 of a batch (those below n).
inline void setup_group(const Tri* tris, const int* ids, int n, int g, int x0, int y0, int x1, int y1, int vw, int vh,
                        EntrySetup& s, float* coef) {
  const int e0 = 4 * g, m = n - e0 < 4 ? n - e0 : 4;
  // The triangles' 16 words, one triangle a row, transposed in 4 x 4 blocks to one field a row:
  // f[0 .. 14] = X0 X1 X2 Y0 Y1 Y2 A0 A1 A2 B0 B1 B2 C0 C1 C2.
  int32x4_t f[16];
  for (int i = 0; i < 4; ++i) {
    const auto* t = reinterpret_cast<const std::int32_t*>(&tris[ids[e0 + (i < m ? i : 0)]]);
    for (int b = 0; b < 4; ++b) f[4 * b + i] = vld1q_s32(t + 4 * b);
  }
  for (int b = 0; b < 4; ++b) transpose4(f[4 * b], f[4 * b + 1], f[4 * b + 2], f[4 * b + 3]);
  const int32x4_t* X = f;
  const int32x4_t* Y = f + 3;
  auto fl = [&f](int k) { return vreinterpretq_f32_s32(f[k]); };
  const float32x4_t A[3] = {fl(6), fl(7), fl(8)}, B[3] = {fl(9), fl(10), fl(11)}, C[3] = {fl(12), fl(13), fl(14)};
  const int32x4_t zero = vdupq_n_s32(0);
  const int32x4_t xmin = vminq_s32(vminq_s32(X[0], X[1]), X[2]), xmax = vmaxq_s32(vmaxq_s32(X[0], X[1]), X[2]);
  const int32x4_t ymin = vminq_s32(vminq_s32(Y[0], Y[1]), Y[2]), ymax = vmaxq_s32(vmaxq_s32(Y[0], Y[1]), Y[2]);
  const int32x4_t half_up = vdupq_n_s32((1 << kSubBits) - 1);
  const int32x4_t bx0 = vmaxq_s32(zero, vshrq_n_s32(vaddq_s32(xmin, half_up), kSubBits));
  const int32x4_t by0 = vmaxq_s32(zero, vshrq_n_s32(vaddq_s32(ymin, half_up), kSubBits));
  const int32x4_t bx1 = vminq_s32(vdupq_n_s32(vw - 1), vshrq_n_s32(xmax, kSubBits));
  const int32x4_t by1 = vminq_s32(vdupq_n_s32(vh - 1), vshrq_n_s32(ymax, kSubBits));
  // Planes at the tile's corner; one entry's ten floats at a time.
  const int32x4_t dx = vsubq_s32(vdupq_n_s32(x0), bx0), dy = vsubq_s32(vdupq_n_s32(y0), by0);
  float at[3][4], a[3][4], b[3][4];
  for (int q = 0; q < 3; ++q) {
    vst1q_f32(at[q], plane_at_corner(C[q], A[q], B[q], dx, dy));
    vst1q_f32(a[q], A[q]);
    vst1q_f32(b[q], B[q]);
  }
  for (int i = 0; i < m; ++i) {
    float* c = coef + kPlaneFloats * (e0 + i);
    for (int q = 0; q < 3; ++q) {
      c[3 * q] = at[q][i];
      c[3 * q + 1] = a[q][i];
      c[3 * q + 2] = b[q][i];
    }
    c[9] = INFINITY;
  }
  // Small: corners spanning under 8 pixels each way, the box non-empty and in the tile.
  const int32x4_t eight = vdupq_n_s32(8 << kSubBits);
  const uint32x4_t spans = vandq_u32(vcltq_s32(vsubq_s32(xmax, xmin), eight), vcltq_s32(vsubq_s32(ymax, ymin), eight));
  const uint32x4_t inside = vandq_u32(vandq_u32(vcgeq_s32(bx0, vdupq_n_s32(x0)), vcleq_s32(bx1, vdupq_n_s32(x1))),
                                      vandq_u32(vcgeq_s32(by0, vdupq_n_s32(y0)), vcleq_s32(by1, vdupq_n_s32(y1))));
  const uint32x4_t filled = vandq_u32(vcleq_s32(bx0, bx1), vcleq_s32(by0, by1));
  const unsigned bits = lane_bits(vandq_u32(vandq_u32(spans, inside), filled)) & ((1u << m) - 1);
  s.small |= bits << e0;
  if (bits == 0) return;
  const int32x4_t one = vdupq_n_s32(1);
  vst1q_s32(s.x0 + e0, bx0);
  vst1q_s32(s.y0 + e0, by0);
  vst1q_s32(s.w + e0, vaddq_s32(vsubq_s32(bx1, bx0), one));
  vst1q_s32(s.h + e0, vaddq_s32(vsubq_s32(by1, by0), one));
  vst1q_f32(s.base + e0, C[0]);
  vst1q_f32(s.A + e0, A[0]);
  vst1q_f32(s.B + e0, B[0]);
  const int32x4_t px = vshlq_n_s32(bx0, kSubBits), py = vshlq_n_s32(by0, kSubBits);
  for (int k = 0; k < 3; ++k) {
    const int k1 = (k + 1) % 3;
    const int32x4_t ex = vsubq_s32(X[k1], X[k]), ey = vsubq_s32(Y[k1], Y[k]);
    const uint32x4_t top_left = vorrq_u32(vandq_u32(vceqq_s32(ey, zero), vcgtq_s32(ex, zero)), vcltq_s32(ey, zero));
    const int32x4_t e = vsubq_s32(vmulq_s32(ex, vsubq_s32(py, Y[k])), vmulq_s32(ey, vsubq_s32(px, X[k])));
    // Less one where the edge is not top or left: adding ~top_left (-1 there, 0 elsewhere).
    vst1q_s32(s.E[k] + e0, vaddq_s32(e, vreinterpretq_s32_u32(vmvnq_u32(top_left))));
    vst1q_s32(s.dEx[k] + e0, vshlq_n_s32(vnegq_s32(ey), kSubBits));
    vst1q_s32(s.dEy[k] + e0, vshlq_n_s32(ex, kSubBits));
  }
}

// Four vertices, one a lane: the doubles in two halves (lanes 0-1, 2-3).
struct Vert4 {
  float64x2_t sx[2], sy[2], iz[2], qx[2], qy[2];
  int32x4_t X, Y;
};

inline Vert4 load4(const ProjGrid& g, int k) {
  Vert4 v;
  const double* fields[5] = {g.sx, g.sy, g.iz, g.qx, g.qy};
  float64x2_t* halves[5] = {v.sx, v.sy, v.iz, v.qx, v.qy};
  for (int j = 0; j < 5; ++j) {
    halves[j][0] = vld1q_f64(fields[j] + k);
    halves[j][1] = vld1q_f64(fields[j] + k + 2);
  }
  v.X = vld1q_s32(g.X + k);
  v.Y = vld1q_s32(g.Y + k);
  return v;
}

inline void setup4(const Vert4& a, const Vert4& b, const Vert4& c, int vw, int vh, Tri4& t) {
  // The doubled area, in 64 bits: differences of corners inside the guard band fit 31 bits.
  const int32x4_t dx1 = vsubq_s32(b.X, a.X), dy2 = vsubq_s32(c.Y, a.Y), dy1 = vsubq_s32(b.Y, a.Y), dx2 = vsubq_s32(c.X, a.X);
  const int64x2_t area_lo = vsubq_s64(vmull_s32(vget_low_s32(dx1), vget_low_s32(dy2)), vmull_s32(vget_low_s32(dy1), vget_low_s32(dx2)));
  const int64x2_t area_hi = vsubq_s64(vmull_high_s32(dx1, dy2), vmull_high_s32(dy1, dx2));
  const uint32x4_t flip = narrow_mask(vcltzq_s64(area_lo), vcltzq_s64(area_hi));
  const uint32x4_t none = narrow_mask(vceqzq_s64(area_lo), vceqzq_s64(area_hi));
  const int32x4_t X1 = vbslq_s32(flip, c.X, b.X), X2 = vbslq_s32(flip, b.X, c.X);
  const int32x4_t Y1 = vbslq_s32(flip, c.Y, b.Y), Y2 = vbslq_s32(flip, b.Y, c.Y);
  // pixel_box(): the first pixel centre at or after the least corner, the last at or before
  // the greatest, clamped to the view.
  const int32x4_t half_up = vdupq_n_s32((1 << kSubBits) - 1), zero = vdupq_n_s32(0);
  const int32x4_t bx0 = vmaxq_s32(zero, vshrq_n_s32(vaddq_s32(vminq_s32(vminq_s32(a.X, X1), X2), half_up), kSubBits));
  const int32x4_t by0 = vmaxq_s32(zero, vshrq_n_s32(vaddq_s32(vminq_s32(vminq_s32(a.Y, Y1), Y2), half_up), kSubBits));
  const int32x4_t bx1 = vminq_s32(vdupq_n_s32(vw - 1), vshrq_n_s32(vmaxq_s32(vmaxq_s32(a.X, X1), X2), kSubBits));
  const int32x4_t by1 = vminq_s32(vdupq_n_s32(vh - 1), vshrq_n_s32(vmaxq_s32(vmaxq_s32(a.Y, Y1), Y2), kSubBits));
  const uint32x4_t empty = vorrq_u32(vcgtq_s32(bx0, bx1), vcgtq_s32(by0, by1));
  float64x2_t e1x[2], e1y[2], e2x[2], e2y[2], det[2];
  for (int h = 0; h < 2; ++h) {
    e1x[h] = vsubq_f64(b.sx[h], a.sx[h]);
    e1y[h] = vsubq_f64(b.sy[h], a.sy[h]);
    e2x[h] = vsubq_f64(c.sx[h], a.sx[h]);
    e2y[h] = vsubq_f64(c.sy[h], a.sy[h]);
    det[h] = vsubq_f64(vmulq_f64(e1x[h], e2y[h]), vmulq_f64(e2x[h], e1y[h]));
  }
  const uint32x4_t flat = narrow_mask(vceqzq_f64(det[0]), vceqzq_f64(det[1]));  // det == 0
  t.keep = ~lane_bits(vorrq_u32(vorrq_u32(none, empty), flat)) & 0xFu;
  if (t.keep == 0) return;
  const float64x2_t ox[2] = {vsubq_f64(low_pd(bx0), a.sx[0]), vsubq_f64(high_pd(bx0), a.sx[1])};
  const float64x2_t oy[2] = {vsubq_f64(low_pd(by0), a.sy[0]), vsubq_f64(high_pd(by0), a.sy[1])};
  const float64x2_t* q[3][3] = {{a.iz, b.iz, c.iz}, {a.qx, b.qx, c.qx}, {a.qy, b.qy, c.qy}};
  for (int k = 0; k < 3; ++k) {
    float64x2_t A[2], B[2], C[2];
    for (int h = 0; h < 2; ++h) {
      const float64x2_t inv_det = vdivq_f64(vdupq_n_f64(1.0), det[h]);
      const float64x2_t d1 = vsubq_f64(q[k][1][h], q[k][0][h]), d2 = vsubq_f64(q[k][2][h], q[k][0][h]);
      A[h] = vmulq_f64(vsubq_f64(vmulq_f64(d1, e2y[h]), vmulq_f64(d2, e1y[h])), inv_det);
      B[h] = vmulq_f64(vsubq_f64(vmulq_f64(d2, e1x[h]), vmulq_f64(d1, e2x[h])), inv_det);
      C[h] = vaddq_f64(vaddq_f64(q[k][0][h], vmulq_f64(A[h], ox[h])), vmulq_f64(B[h], oy[h]));
    }
    vst1q_f32(t.A[k], to_ps(A[0], A[1]));
    vst1q_f32(t.B[k], to_ps(B[0], B[1]));
    vst1q_f32(t.C[k], to_ps(C[0], C[1]));
  }
  const int32x4_t corners[6] = {a.X, X1, X2, a.Y, Y1, Y2};
  for (int k = 0; k < 3; ++k) {
    vst1q_s32(t.X[k], corners[k]);
    vst1q_s32(t.Y[k], corners[3 + k]);
  }
  vst1q_s32(t.box[0], bx0);
  vst1q_s32(t.box[1], by0);
  vst1q_s32(t.box[2], bx1);
  vst1q_s32(t.box[3], by1);
}

}  // namespace

int emit_quad_row_neon(const ProjGrid& g, int top, int bottom, int n, bool anti, int vw, int vh, Tri* out, PixelBox* boxes) {
  return emit_quad_row_by4<load4, setup4>(g, top, bottom, n, anti, vw, vh, out, boxes);
}

bool project_posts_neon(const PostFrame& f, const float* x, const float* y, const float* z, int n, int k0, const ClipGrid& cv,
                        const ProjGrid& proj, std::uint8_t* out, bool* no_height) {
  const float32x4_t zero = vdupq_n_f32(0.0f);
  bool all = true;
  int a0 = 0;
  for (; a0 + 4 <= n; a0 += 4) {
    const int k = k0 + a0;
    const float32x4_t X = vld1q_f32(x + a0), Y = vld1q_f32(y + a0), Z = vld1q_f32(z + a0);
    const uint32x4_t none = vmvnq_u32(vceqq_f32(vsubq_f32(Z, Z), zero));  // NaN or infinite
    const float32x4_t dx = vsubq_f32(X, vdupq_n_f32(f.t[0])), dy = vsubq_f32(Y, vdupq_n_f32(f.t[1]));
    const float32x4_t dz = vsubq_f32(vbslq_f32(none, zero, Z), vdupq_n_f32(f.t[2]));
    auto row = [&](int i) {
      const float32x4_t xy = vaddq_f32(vmulq_n_f32(dx, f.R[3 * i]), vmulq_n_f32(dy, f.R[3 * i + 1]));
      return vaddq_f32(xy, vmulq_n_f32(dz, f.R[3 * i + 2]));
    };
    const float32x4_t cx = row(0), cy = row(1), cz = row(2);
    vst1q_f32(cv.x + k, cx);
    vst1q_f32(cv.y + k, cy);
    vst1q_f32(cv.z + k, cz);
    vst1q_f32(cv.wx + k, X);
    vst1q_f32(cv.wy + k, Y);
    // clip_distance() of each plane, >= 0 inside (a NaN is outside, as in outcode()).
    const float32x4_t d[5] = {vsubq_f32(cz, vdupq_n_f32(f.near)), vsubq_f32(cx, vmulq_n_f32(cz, f.guard[0])),
                              vsubq_f32(vmulq_n_f32(cz, f.guard[1]), cx), vsubq_f32(cy, vmulq_n_f32(cz, f.guard[2])),
                              vsubq_f32(vmulq_n_f32(cz, f.guard[3]), cy)};
    unsigned in[5];
    for (int p = 0; p < 5; ++p) in[p] = lane_bits(vcgeq_f32(d[p], zero));
    const unsigned empty = lane_bits(none);
    for (int i = 0; i < 4; ++i) {
      std::uint8_t code = 0;
      for (int p = 0; p < 5; ++p) code = static_cast<std::uint8_t>(code | ((in[p] >> i & 1) ? 0 : 1) << p);
      out[k + i] = code;
      no_height[k + i] = (empty >> i & 1) != 0;
    }
    all = all && (in[0] & in[1] & in[2] & in[3] & in[4] & ~empty & 0xFu) == 0xFu;
    // project_vertex() in two halves of two, every lane (those outside hold scratch). The
    // snapped positions are whole numbers, so the conversion's rounding does not matter.
    const float64x2_t magic = vdupq_n_f64(6755399441055744.0), sub = vdupq_n_f64(1 << kSubBits);
    auto fixed = [&](float64x2_t v) { return vmovn_s64(vcvtq_s64_f64(vsubq_f64(vaddq_f64(vmulq_f64(v, sub), magic), magic))); };
    for (int h = 0; h < 2; ++h) {
      auto part = [h](float32x4_t v) { return h ? high_pd(v) : low_pd(v); };
      const float64x2_t iz = vdivq_f64(vdupq_n_f64(1.0), part(cz));
      const float64x2_t sx = vaddq_f64(vmulq_f64(vmulq_n_f64(part(cx), f.fx), iz), vdupq_n_f64(f.cx));
      const float64x2_t sy = vaddq_f64(vmulq_f64(vmulq_n_f64(part(cy), f.fy), iz), vdupq_n_f64(f.cy));
      const int kh = k + 2 * h;
      vst1q_f64(proj.iz + kh, iz);
      vst1q_f64(proj.sx + kh, sx);
      vst1q_f64(proj.sy + kh, sy);
      vst1q_f64(proj.qx + kh, vmulq_f64(part(X), iz));
      vst1q_f64(proj.qy + kh, vmulq_f64(part(Y), iz));
      vst1_s32(proj.X + kh, fixed(sx));
      vst1_s32(proj.Y + kh, fixed(sy));
    }
  }
  if (a0 < n) all = project_posts_scalar(f, x + a0, y + a0, z + a0, n - a0, k0 + a0, cv, proj, out, no_height) && all;
  return all;
}

void setup_entries_neon(const Tri* tris, const int* ids, int n, int x0, int y0, int x1, int y1, int vw, int vh, EntrySetup& s,
                        float* coef) {
  s.small = 0;
  for (int g = 0; 4 * g < n; ++g) setup_group(tris, ids, n, g, x0, y0, x1, y1, vw, vh, s, coef);
}

int draw_small_entries_neon(const EntrySetup& s, int from, int n, int x0, int y0, float* z, int* id, std::ptrdiff_t stride,
                            int e0, int* covered) {
  return draw_small_entries_through<edge_block32_neon_inline>(s, from, n, x0, y0, z, id, stride, e0, covered);
}

}  // namespace terralign::raster
