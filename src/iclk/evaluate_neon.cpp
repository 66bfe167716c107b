// NEON build (aarch64) of the residual, Jacobian and J^T W J kernels: the eight lanes of
// evaluate_kernels.hpp as two float32x4 halves, the four double lanes of the outer sums as two
// float64x2, the same operations in the same order as evaluate_scalar.cpp (the library is
// built with -ffp-contract=off, so no multiply and add fuse; AArch64's vdivq_f32 is the
// correctly rounded division). The live image's taps are read lane by lane; the Jacobian
// kernel's reference taps too, unless eight pixels lie side by side on a row.
#include "evaluate_kernels.hpp"

#include <arm_neon.h>

#include <algorithm>
#include <cstring>

namespace terralign::iclk::detail {
namespace {

// Eight lanes: lanes 0-3 in v[0], 4-7 in v[1].
struct F8 {
  float32x4_t v[2];
};

// Floats i .. i + n - 1 of p (n <= 8), zeros past n.
inline F8 load8(const float* p, int i, int n) {
  if (n == kLanes) return {{vld1q_f32(p + i), vld1q_f32(p + i + 4)}};
  float tmp[kLanes] = {};
  std::memcpy(tmp, p + i, sizeof(float) * static_cast<std::size_t>(n));
  return {{vld1q_f32(tmp), vld1q_f32(tmp + 4)}};
}

inline float32x4_t masked(float32x4_t v, uint32x4_t m) { return vreinterpretq_f32_u32(vandq_u32(vreinterpretq_u32_f32(v), m)); }

}  // namespace

void evaluate_se3_neon(const Se3EvalInput& in, int i0, int i1, float* r, unsigned char* ok, Se3EvalSums& s) {
  const float32x4_t one = vdupq_n_f32(1.0f), zero = vdupq_n_f32(0.0f), zmin = vdupq_n_f32(1e-6f);
  const float32x4_t umax = vdupq_n_f32(static_cast<float>(in.width - 1)), vmax = vdupq_n_f32(static_cast<float>(in.height - 1));
  const int32x4_t xmax = vdupq_n_s32(in.width - 2), ymax = vdupq_n_s32(in.height - 2);
  const uint32_t lane_ids[kLanes] = {0, 1, 2, 3, 4, 5, 6, 7};
  float32x4_t R[9], t[3];
  for (int k = 0; k < 9; ++k) R[k] = vdupq_n_f32(in.R[k]);
  for (int k = 0; k < 3; ++k) t[k] = vdupq_n_f32(in.t[k]);
  const float32x4_t fxv = vdupq_n_f32(in.fx), fyv = vdupq_n_f32(in.fy), cxv = vdupq_n_f32(in.cx), cyv = vdupq_n_f32(in.cy);
  F8 g[6], cost{{zero, zero}}, wsum{{zero, zero}};
  for (auto& v : g) v = {{zero, zero}};
  int valid = 0, n_out = 0;
  for (int i = i0; i < i1; i += kLanes) {
    const int n = std::min(kLanes, i1 - i);
    const F8 x = load8(in.px, i, n), y = load8(in.py, i, n), z = load8(in.pz, i, n);
    const F8 wgt = load8(in.w, i, n);
    // Where each lane lands, four lanes at a time (the scalar twin's operations).
    float32x4_t fx[2], fy[2], w[2];
    uint32x4_t inside[2];
    int32_t xs[kLanes], ys[kLanes];
    for (int h = 0; h < 2; ++h) {
      auto row = [&](int k) {
        return vaddq_f32(vaddq_f32(vaddq_f32(vmulq_f32(R[3 * k], x.v[h]), vmulq_f32(R[3 * k + 1], y.v[h])),
                                   vmulq_f32(R[3 * k + 2], z.v[h])),
                         t[k]);
      };
      const float32x4_t X = row(0), Y = row(1), Z = row(2);
      float32x4_t u = vaddq_f32(vdivq_f32(vmulq_f32(fxv, X), Z), cxv);
      float32x4_t v = vaddq_f32(vdivq_f32(vmulq_f32(fyv, Y), Z), cyv);
      uint32x4_t in_h = vandq_u32(vcltq_u32(vld1q_u32(lane_ids + 4 * h), vdupq_n_u32(static_cast<uint32_t>(n))), vcgtq_f32(Z, zmin));
      in_h = vandq_u32(in_h, vandq_u32(vcgeq_f32(u, zero), vcgeq_f32(v, zero)));
      in_h = vandq_u32(in_h, vandq_u32(vcleq_f32(u, umax), vcleq_f32(v, vmax)));
      // Lanes that did not land sample pixel (0, 0); their results are masked below.
      u = masked(u, in_h);
      v = masked(v, in_h);
      const int32x4_t x0 = vminq_s32(vcvtq_s32_f32(u), xmax), y0 = vminq_s32(vcvtq_s32_f32(v), ymax);
      fx[h] = vsubq_f32(u, vcvtq_f32_s32(x0));
      fy[h] = vsubq_f32(v, vcvtq_f32_s32(y0));
      vst1q_s32(xs + 4 * h, x0);
      vst1q_s32(ys + 4 * h, y0);
      inside[h] = in_h;
      w[h] = masked(wgt.v[h], in_h);
    }
    // Each channel's taps, residuals and sums, in channel order.
    for (int c = 0; c < in.channels; ++c) {
      const float* live_c = in.live + c * in.live_plane;
      const F8 val = load8(in.val + c * in.plane, i, n);
      F8 jac[6];
      for (int k = 0; k < 6; ++k) jac[k] = load8(in.jac[k] + c * in.jac_plane, i, n);
      float res_lanes[kLanes];
      for (int h = 0; h < 2; ++h) {
        float ta[4], tb[4], tc[4], td[4];
        for (int l = 0; l < 4; ++l) {
          const float* p = live_c + static_cast<std::ptrdiff_t>(ys[4 * h + l]) * in.stride + xs[4 * h + l];
          ta[l] = p[0];
          tb[l] = p[1];
          tc[l] = p[in.stride];
          td[l] = p[in.stride + 1];
        }
        const float32x4_t gx = vsubq_f32(one, fx[h]);
        const float32x4_t top = vaddq_f32(vmulq_f32(gx, vld1q_f32(ta)), vmulq_f32(fx[h], vld1q_f32(tb)));
        const float32x4_t bot = vaddq_f32(vmulq_f32(gx, vld1q_f32(tc)), vmulq_f32(fx[h], vld1q_f32(td)));
        const float32x4_t live = vaddq_f32(vmulq_f32(vsubq_f32(one, fy[h]), top), vmulq_f32(fy[h], bot));
        const float32x4_t res = masked(vsubq_f32(live, val.v[h]), inside[h]);
        const float32x4_t wr = vmulq_f32(w[h], res);
        for (int k = 0; k < 6; ++k) g[k].v[h] = vaddq_f32(g[k].v[h], vmulq_f32(wr, jac[k].v[h]));
        cost.v[h] = vaddq_f32(cost.v[h], vmulq_f32(wr, res));
        wsum.v[h] = vaddq_f32(wsum.v[h], w[h]);
        vst1q_f32(res_lanes + 4 * h, res);
      }
      std::memcpy(r + c * in.plane + i, res_lanes, sizeof(float) * static_cast<std::size_t>(n));
    }
    uint32_t in_lanes[kLanes];
    vst1q_u32(in_lanes, inside[0]);
    vst1q_u32(in_lanes + 4, inside[1]);
    for (int l = 0; l < n; ++l) {
      ok[i + l] = in_lanes[l] != 0;
      if (in_lanes[l] != 0) ++valid;
      else in.out[n_out++] = i + l;
    }
  }
  for (int h = 0; h < 2; ++h) {
    for (int k = 0; k < 6; ++k) vst1q_f32(s.g[k] + 4 * h, g[k].v[h]);
    vst1q_f32(s.cost + 4 * h, cost.v[h]);
    vst1q_f32(s.wsum + 4 * h, wsum.v[h]);
  }
  s.valid = valid;
  s.n_out = n_out;
}

void se3_jacobians_neon(const Se3JacobianInput& in, const int* xs, const int* ys, int count, Se3JacobianGroup& out,
                        Se3FinestSums* sums) {
  // Lanes past count repeat lane 0's pixel (inside the level) and are not written.
  int x8[kLanes], y8[kLanes];
  for (int l = 0; l < kLanes; ++l) {
    x8[l] = xs[l < count ? l : 0];
    y8[l] = ys[l < count ? l : 0];
  }
  // Eight pixels side by side on one row (every pixel selected: the learned tracker's levels)
  // load their taps plainly, two channels deinterleaved by vld2q; else lane by lane.
  const int C = in.channels, row = in.width * C;
  const bool run = count == kLanes && ys[kLanes - 1] == ys[0] && xs[kLanes - 1] - xs[0] == kLanes - 1 && C <= 2;
  auto at = [&](int l) { return in.ref + static_cast<std::ptrdiff_t>(y8[l]) * row + static_cast<std::ptrdiff_t>(x8[l]) * C; };
  auto tap = [&](int c, int dx, int dy) -> F8 {
    const std::ptrdiff_t off = static_cast<std::ptrdiff_t>(dy) * row + dx * C;
    if (run) {
      const float* p = at(0) + off;
      if (C == 1) return {{vld1q_f32(p), vld1q_f32(p + 4)}};
      const float32x4x2_t lo = vld2q_f32(p), hi = vld2q_f32(p + kLanes);
      return {{lo.val[c], hi.val[c]}};
    }
    float t[kLanes];
    for (int l = 0; l < kLanes; ++l) t[l] = at(l)[off + c];
    return {{vld1q_f32(t), vld1q_f32(t + 4)}};
  };
  float dl[kLanes];
  if (run) {
    std::memcpy(dl, in.depth + static_cast<std::ptrdiff_t>(ys[0]) * in.width + xs[0], sizeof dl);
  } else {
    for (int l = 0; l < kLanes; ++l) dl[l] = in.depth[static_cast<std::ptrdiff_t>(y8[l]) * in.width + x8[l]];
  }
  const uint32_t lane_ids[kLanes] = {0, 1, 2, 3, 4, 5, 6, 7};
  const float32x4_t fx = vdupq_n_f32(in.fx), fy = vdupq_n_f32(in.fy), cx = vdupq_n_f32(in.cx), cy = vdupq_n_f32(in.cy);
  const float32x4_t zero = vdupq_n_f32(0.0f), two = vdupq_n_f32(2.0f), eighth = vdupq_n_f32(8.0f);
  // Per half h: the pixel, the point, dW's rows (the scalar twin's operations, lane by lane).
  F8 u, v, X, Y, Z, wu[6], wv[6];
  for (int h = 0; h < 2; ++h) {
    u.v[h] = vcvtq_f32_s32(vld1q_s32(x8 + 4 * h));
    v.v[h] = vcvtq_f32_s32(vld1q_s32(y8 + 4 * h));
    const float32x4_t d = vld1q_f32(dl + 4 * h);
    X.v[h] = vdivq_f32(vmulq_f32(d, vsubq_f32(u.v[h], cx)), fx);
    Y.v[h] = vdivq_f32(vmulq_f32(d, vsubq_f32(v.v[h], cy)), fy);
    Z.v[h] = d;
    const float32x4_t iz = vdivq_f32(vdupq_n_f32(1.0f), d);
    const float32x4_t xn = vmulq_f32(X.v[h], iz), yn = vmulq_f32(Y.v[h], iz);
    // The projection's derivatives: du/dX, du/dZ, dv/dY, dv/dZ.
    const float32x4_t ux = vmulq_f32(fx, iz), uz = vmulq_f32(vmulq_f32(vnegq_f32(fx), xn), iz);
    const float32x4_t vy = vmulq_f32(fy, iz), vz = vmulq_f32(vmulq_f32(vnegq_f32(fy), yn), iz);
    wu[0].v[h] = vmulq_f32(uz, Y.v[h]);
    wu[1].v[h] = vaddq_f32(vmulq_f32(ux, d), vmulq_f32(uz, vnegq_f32(X.v[h])));
    wu[2].v[h] = vmulq_f32(ux, vnegq_f32(Y.v[h]));
    wu[3].v[h] = ux;
    wu[4].v[h] = zero;
    wu[5].v[h] = uz;
    wv[0].v[h] = vaddq_f32(vmulq_f32(vy, vnegq_f32(d)), vmulq_f32(vz, Y.v[h]));
    wv[1].v[h] = vmulq_f32(vz, vnegq_f32(X.v[h]));
    wv[2].v[h] = vmulq_f32(vy, X.v[h]);
    wv[3].v[h] = zero;
    wv[4].v[h] = vy;
    wv[5].v[h] = vz;
  }
  if (sums) {
    for (int h = 0; h < 2; ++h) {
      // Lanes past count: dW and the offsets +0, as the scalar twin's.
      const uint32x4_t used = vcltq_u32(vld1q_u32(lane_ids + 4 * h), vdupq_n_u32(static_cast<uint32_t>(count)));
      const float32x4_t mu = masked(vsubq_f32(u.v[h], cx), used), mv = masked(vsubq_f32(v.v[h], cy), used);
      float32x4_t su[6], sv[6];
      for (int k = 0; k < 6; ++k) {
        su[k] = masked(wu[k].v[h], used);
        sv[k] = masked(wv[k].v[h], used);
      }
      auto add = [h](float* lanes, float32x4_t t) { vst1q_f32(lanes + 4 * h, vaddq_f32(vld1q_f32(lanes + 4 * h), t)); };
      int e = 0;
      for (int a = 0; a < 6; ++a)
        for (int b = 0; b <= a; ++b, ++e) add(sums->motion[e], vaddq_f32(vmulq_f32(su[a], su[b]), vmulq_f32(sv[a], sv[b])));
      for (int a = 0; a < 6; ++a) {
        const float32x4_t radial = vaddq_f32(vmulq_f32(su[a], mu), vmulq_f32(sv[a], mv));
        const float32x4_t modes[6] = {su[a], sv[a], vsubq_f32(vmulq_f32(sv[a], mu), vmulq_f32(su[a], mv)), radial,
                                      vmulq_f32(radial, mu), vmulq_f32(radial, mv)};
        for (int m = 0; m < 6; ++m) add(sums->floor[a][m], modes[m]);
      }
    }
  }
  auto put = [&](float* p, const F8& t) {
    if (count == kLanes) {
      vst1q_f32(p, t.v[0]);
      vst1q_f32(p + 4, t.v[1]);
      return;
    }
    float tmp[kLanes];
    vst1q_f32(tmp, t.v[0]);
    vst1q_f32(tmp + 4, t.v[1]);
    std::memcpy(p, tmp, sizeof(float) * static_cast<std::size_t>(count));
  };
  put(out.pu, u);
  put(out.pv, v);
  put(out.px, X);
  put(out.py, Y);
  put(out.pz, Z);
  for (int c = 0; c < C; ++c) {
    const F8 nw = tap(c, -1, -1), n = tap(c, 0, -1), ne = tap(c, 1, -1), w = tap(c, -1, 0), o = tap(c, 0, 0);
    const F8 east = tap(c, 1, 0), sw = tap(c, -1, 1), s = tap(c, 0, 1), se = tap(c, 1, 1);
    F8 jac[6];
    for (int h = 0; h < 2; ++h) {
      // (ne + 2 e + se - nw - 2 w - sw) / 8 and (sw + 2 s + se - nw - 2 n - ne) / 8, left to right.
      const float32x4_t gx = vdivq_f32(
          vsubq_f32(vsubq_f32(vsubq_f32(vaddq_f32(vaddq_f32(ne.v[h], vmulq_f32(two, east.v[h])), se.v[h]), nw.v[h]),
                              vmulq_f32(two, w.v[h])),
                    sw.v[h]),
          eighth);
      const float32x4_t gy = vdivq_f32(
          vsubq_f32(vsubq_f32(vsubq_f32(vaddq_f32(vaddq_f32(sw.v[h], vmulq_f32(two, s.v[h])), se.v[h]), nw.v[h]),
                              vmulq_f32(two, n.v[h])),
                    ne.v[h]),
          eighth);
      for (int k = 0; k < 6; ++k) jac[k].v[h] = vaddq_f32(vmulq_f32(gx, wu[k].v[h]), vmulq_f32(gy, wv[k].v[h]));
    }
    for (int k = 0; k < 6; ++k) put(out.jac[k] + c * out.jac_plane, jac[k]);
    put(out.val + c * out.plane, o);
  }
}

namespace {

// Pixels k of [0, count) in lane k mod kOuterLanes (lanes 0-1 and 2-3 as two float64x2);
// get(p, k, n, dst) writes the floats of pixels k .. k + n - 1 of array p to dst[0 .. 4)
// (zeros past n).
template <class Get>
void outer_sums(const float* const* jac, const float* w, int count, Get get, OuterSums& h) {
  static_assert(kOuterLanes == 4, "two float64x2 halves");
  const float64x2_t zero = vdupq_n_f64(0.0);
  float64x2_t acc[21][2];
  for (int e = 0; e < 21; ++e) {
    acc[e][0] = vld1q_f64(h.h[e]);
    acc[e][1] = vld1q_f64(h.h[e] + 2);
  }
  // A float32x4's four values in double, as two halves.
  auto wide = [](const float* f, float64x2_t out[2]) {
    const float32x4_t v = vld1q_f32(f);
    out[0] = vcvt_f64_f32(vget_low_f32(v));
    out[1] = vcvt_high_f64_f32(v);
  };
  auto keep = [](float64x2_t v, uint64x2_t m) { return vreinterpretq_f64_u64(vandq_u64(vreinterpretq_u64_f64(v), m)); };
  for (int k = 0; k < count; k += kOuterLanes) {
    const int n = std::min(kOuterLanes, count - k);
    float buf[kOuterLanes];
    get(w, k, n, buf);
    float64x2_t wv[2], wd[2], j[6][2];
    uint64x2_t use[2];
    wide(buf, wv);
    for (int q = 0; q < 2; ++q) {
      use[q] = vcgtq_f64(wv[q], zero);  // zeros past the end do not pass; NaN compares false
      wd[q] = keep(wv[q], use[q]);
    }
    for (int a = 0; a < 6; ++a) {
      get(jac[a], k, n, buf);
      wide(buf, j[a]);
      for (int q = 0; q < 2; ++q) j[a][q] = keep(j[a][q], use[q]);
    }
    for (int q = 0; q < 2; ++q) {
      int e = 0;
      for (int a = 0; a < 6; ++a) {
        const float64x2_t wj = vmulq_f64(wd[q], j[a][q]);
        for (int b = 0; b <= a; ++b, ++e) acc[e][q] = vaddq_f64(acc[e][q], vmulq_f64(wj, j[b][q]));
      }
    }
  }
  for (int e = 0; e < 21; ++e) {
    vst1q_f64(h.h[e], acc[e][0]);
    vst1q_f64(h.h[e] + 2, acc[e][1]);
  }
}

}  // namespace

void outer_sums_neon(const float* const* jac, const float* w, int i0, int i1, OuterSums& h) {
  outer_sums(jac, w, i1 - i0, [i0](const float* p, int k, int n, float* dst) {
    for (int l = 0; l < kOuterLanes; ++l) dst[l] = l < n ? p[i0 + k + l] : 0.0f;
  }, h);
}

void outer_sums_at_neon(const float* const* jac, const float* w, const int* index, int count, OuterSums& h) {
  outer_sums(jac, w, count, [index](const float* p, int k, int n, float* dst) {
    for (int l = 0; l < kOuterLanes; ++l) dst[l] = l < n ? p[index[k + l]] : 0.0f;
  }, h);
}

}  // namespace terralign::iclk::detail
