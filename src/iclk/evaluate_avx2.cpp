// AVX2 build of the residual kernel: eight pixels at once, the same operations in the same
// order as evaluate_scalar.cpp (compiled with -mavx2 and without -mfma, so nothing fuses).
#include "evaluate_kernels.hpp"

#include <immintrin.h>

#include <algorithm>

namespace terralign::iclk::detail {
namespace {

// p[idx[k]] and p[idx[k] + 1] for the eight lanes k, gathered as 64-bit pairs.
inline void pairs(const float* p, __m256i idx, __m256& first, __m256& second) {
  const auto* q = reinterpret_cast<const long long*>(p);
  const __m256 lo = _mm256_castsi256_ps(_mm256_i32gather_epi64(q, _mm256_castsi256_si128(idx), 4));
  const __m256 hi = _mm256_castsi256_ps(_mm256_i32gather_epi64(q, _mm256_extracti128_si256(idx, 1), 4));
  // lo = f0 s0 f1 s1 | f2 s2 f3 s3, hi likewise for lanes 4..7.
  const __m256 f = _mm256_shuffle_ps(lo, hi, _MM_SHUFFLE(2, 0, 2, 0));  // f0 f1 f4 f5 | f2 f3 f6 f7
  const __m256 s = _mm256_shuffle_ps(lo, hi, _MM_SHUFFLE(3, 1, 3, 1));
  first = _mm256_castpd_ps(_mm256_permute4x64_pd(_mm256_castps_pd(f), _MM_SHUFFLE(3, 1, 2, 0)));
  second = _mm256_castpd_ps(_mm256_permute4x64_pd(_mm256_castps_pd(s), _MM_SHUFFLE(3, 1, 2, 0)));
}

}  // namespace

void evaluate_se3_avx2(const Se3EvalInput& in, int i0, int i1, float* r, unsigned char* ok, Se3EvalSums& s) {
  const __m256 one = _mm256_set1_ps(1.0f), zero = _mm256_setzero_ps(), zmin = _mm256_set1_ps(1e-6f);
  const __m256 umax = _mm256_set1_ps(static_cast<float>(in.width - 1));
  const __m256 vmax = _mm256_set1_ps(static_cast<float>(in.height - 1));
  const __m256i xmax = _mm256_set1_epi32(in.width - 2), ymax = _mm256_set1_epi32(in.height - 2);
  const __m256i stride = _mm256_set1_epi32(static_cast<int>(in.stride));
  const __m256i lane_index = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256i all_ones = _mm256_set1_epi32(-1), seven = _mm256_set1_epi32(kLanes - 1);
  __m256 R[9], t[3];
  for (int k = 0; k < 9; ++k) R[k] = _mm256_set1_ps(in.R[k]);
  for (int k = 0; k < 3; ++k) t[k] = _mm256_set1_ps(in.t[k]);
  const __m256 fxv = _mm256_set1_ps(in.fx), fyv = _mm256_set1_ps(in.fy);
  const __m256 cxv = _mm256_set1_ps(in.cx), cyv = _mm256_set1_ps(in.cy);
  __m256 g[6], cost = zero, wsum = zero;
  for (auto& v : g) v = zero;
  int valid = 0, n_out = 0;
  for (int i = i0; i < i1; i += kLanes) {
    const int n = std::min(kLanes, i1 - i);
    const __m256i load = _mm256_cmpgt_epi32(_mm256_set1_epi32(n), lane_index);
    // Whole groups load plainly; the last, partial one with a mask (zeros past the end).
    auto get = [&](const float* p) { return n == kLanes ? _mm256_loadu_ps(p + i) : _mm256_maskload_ps(p + i, load); };
    const __m256 x = get(in.px), y = get(in.py), z = get(in.pz);
    auto row = [&](int k) {
      return _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(R[3 * k], x), _mm256_mul_ps(R[3 * k + 1], y)),
                                         _mm256_mul_ps(R[3 * k + 2], z)),
                           t[k]);
    };
    const __m256 X = row(0), Y = row(1), Z = row(2);
    __m256 u = _mm256_add_ps(_mm256_div_ps(_mm256_mul_ps(fxv, X), Z), cxv);
    __m256 v = _mm256_add_ps(_mm256_div_ps(_mm256_mul_ps(fyv, Y), Z), cyv);
    __m256 inside = _mm256_and_ps(_mm256_castsi256_ps(load), _mm256_cmp_ps(Z, zmin, _CMP_GT_OQ));
    inside = _mm256_and_ps(inside, _mm256_and_ps(_mm256_cmp_ps(u, zero, _CMP_GE_OQ), _mm256_cmp_ps(v, zero, _CMP_GE_OQ)));
    inside = _mm256_and_ps(inside, _mm256_and_ps(_mm256_cmp_ps(u, umax, _CMP_LE_OQ), _mm256_cmp_ps(v, vmax, _CMP_LE_OQ)));
    // Lanes that did not land sample pixel (0, 0); their results are masked below.
    u = _mm256_and_ps(u, inside);
    v = _mm256_and_ps(v, inside);
    const __m256i x0 = _mm256_min_epi32(_mm256_cvttps_epi32(u), xmax);
    const __m256i y0 = _mm256_min_epi32(_mm256_cvttps_epi32(v), ymax);
    const __m256 fx = _mm256_sub_ps(u, _mm256_cvtepi32_ps(x0)), fy = _mm256_sub_ps(v, _mm256_cvtepi32_ps(y0));
    const __m256i idx = _mm256_add_epi32(_mm256_mullo_epi32(y0, stride), x0);
    // Neighbouring reference pixels land near each other: where the eight lanes share a row
    // and their columns lie at most 7 right of lane 0's (none left of it), each tap is a
    // permutation of one 8-float load (from that row or the next, at lane 0's column or one
    // right of it). The same values as the gathers below (lanes that did not land sit at
    // (0, 0), which rarely passes).
    const int bx = _mm256_cvtsi256_si32(x0), by = _mm256_cvtsi256_si32(y0);
    const __m256i dx = _mm256_sub_epi32(x0, _mm256_set1_epi32(bx));
    const __m256i off_row = _mm256_xor_si256(_mm256_cmpeq_epi32(y0, _mm256_set1_epi32(by)), all_ones);
    const __m256i off_window = _mm256_or_si256(_mm256_cmpgt_epi32(dx, seven), _mm256_cmpgt_epi32(_mm256_setzero_si256(), dx));
    const bool window = bx + kLanes + 1 <= in.width && _mm256_testz_si256(_mm256_or_si256(off_row, off_window), all_ones);
    const __m256 gx = _mm256_sub_ps(one, fx), gy = _mm256_sub_ps(one, fy);
    const __m256 w = _mm256_and_ps(get(in.w), inside);
    for (int ch = 0; ch < in.channels; ++ch) {
      const float* live_c = in.live + ch * in.live_plane;
      __m256 a, b, c, d;
      if (window) {
        const float* p = live_c + static_cast<std::ptrdiff_t>(by) * in.stride + bx;
        a = _mm256_permutevar8x32_ps(_mm256_loadu_ps(p), dx);
        b = _mm256_permutevar8x32_ps(_mm256_loadu_ps(p + 1), dx);
        c = _mm256_permutevar8x32_ps(_mm256_loadu_ps(p + in.stride), dx);
        d = _mm256_permutevar8x32_ps(_mm256_loadu_ps(p + in.stride + 1), dx);
      } else {
        // Each pixel's two horizontal neighbours as one 64-bit load: half the gathered elements.
        pairs(live_c, idx, a, b);
        pairs(live_c + in.stride, idx, c, d);
      }
      const __m256 top = _mm256_add_ps(_mm256_mul_ps(gx, a), _mm256_mul_ps(fx, b));
      const __m256 bot = _mm256_add_ps(_mm256_mul_ps(gx, c), _mm256_mul_ps(fx, d));
      const __m256 live = _mm256_add_ps(_mm256_mul_ps(gy, top), _mm256_mul_ps(fy, bot));
      const __m256 res = _mm256_and_ps(_mm256_sub_ps(live, get(in.val + ch * in.plane)), inside);
      const __m256 wr = _mm256_mul_ps(w, res);
      for (int k = 0; k < 6; ++k) g[k] = _mm256_add_ps(g[k], _mm256_mul_ps(wr, get(in.jac[k] + ch * in.jac_plane)));
      cost = _mm256_add_ps(cost, _mm256_mul_ps(wr, res));
      wsum = _mm256_add_ps(wsum, w);
      float* rc = r + ch * in.plane + i;
      if (n == kLanes) _mm256_storeu_ps(rc, res);
      else _mm256_maskstore_ps(rc, load, res);
    }
    const int bits = _mm256_movemask_ps(inside);
    valid += __builtin_popcount(static_cast<unsigned>(bits));
    for (unsigned left = ~static_cast<unsigned>(bits) & ((1u << n) - 1u); left != 0; left &= left - 1u)
      in.out[n_out++] = i + __builtin_ctz(left);
    if (n == kLanes) {
      spread_mask8(static_cast<unsigned>(bits), ok + i);
    } else {
      for (int k = 0; k < n; ++k) ok[i + k] = static_cast<unsigned char>((bits >> k) & 1);
    }
  }
  for (int k = 0; k < 6; ++k) _mm256_storeu_ps(s.g[k], g[k]);
  _mm256_storeu_ps(s.cost, cost);
  _mm256_storeu_ps(s.wsum, wsum);
  s.valid = valid;
  s.n_out = n_out;
}

void se3_jacobians_avx2(const Se3JacobianInput& in, const int* xs, const int* ys, int count, Se3JacobianGroup& out,
                        Se3FinestSums* sums) {
  const __m256i lane_index = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256i used = _mm256_cmpgt_epi32(_mm256_set1_epi32(count), lane_index);
  // Lanes past count repeat lane 0's pixel (inside the level) and are not written.
  const __m256i first_x = _mm256_set1_epi32(xs[0]), first_y = _mm256_set1_epi32(ys[0]);
  const __m256i xi = _mm256_blendv_epi8(first_x, _mm256_maskload_epi32(xs, used), used);
  const __m256i yi = _mm256_blendv_epi8(first_y, _mm256_maskload_epi32(ys, used), used);
  const __m256 u = _mm256_cvtepi32_ps(xi), v = _mm256_cvtepi32_ps(yi);
  // Eight pixels side by side on one row (every pixel selected: the learned tracker's levels)
  // load their taps plainly, one or two channels deinterleaved; else they are gathered.
  const int C = in.channels, row = in.width * C;
  const bool run = count == kLanes && ys[kLanes - 1] == ys[0] && xs[kLanes - 1] - xs[0] == kLanes - 1 && C <= 2;
  const float* at0 = in.ref + static_cast<std::ptrdiff_t>(ys[0]) * row + static_cast<std::ptrdiff_t>(xs[0]) * C;
  const __m256i centre = _mm256_add_epi32(_mm256_mullo_epi32(yi, _mm256_set1_epi32(row)), _mm256_mullo_epi32(xi, _mm256_set1_epi32(C)));
  auto tap = [&](int c, int dx, int dy) {
    if (!run) return _mm256_i32gather_ps(in.ref + c, _mm256_add_epi32(centre, _mm256_set1_epi32(dy * row + dx * C)), 4);
    const float* p = at0 + dy * row + dx * C;
    if (C == 1) return _mm256_loadu_ps(p);
    // lo: lanes 0-3's two channels interleaved, hi: lanes 4-7's; channel c of lanes
    // 0 1 4 5 | 2 3 6 7, then in lane order.
    const __m256 lo = _mm256_loadu_ps(p), hi = _mm256_loadu_ps(p + kLanes);
    const __m256 t = c == 0 ? _mm256_shuffle_ps(lo, hi, _MM_SHUFFLE(2, 0, 2, 0)) : _mm256_shuffle_ps(lo, hi, _MM_SHUFFLE(3, 1, 3, 1));
    return _mm256_castpd_ps(_mm256_permute4x64_pd(_mm256_castps_pd(t), _MM_SHUFFLE(3, 1, 2, 0)));
  };
  const __m256 d = run ? _mm256_loadu_ps(in.depth + static_cast<std::ptrdiff_t>(ys[0]) * in.width + xs[0])
                       : _mm256_i32gather_ps(in.depth, _mm256_add_epi32(_mm256_mullo_epi32(yi, _mm256_set1_epi32(in.width)), xi), 4);
  const __m256 fx = _mm256_set1_ps(in.fx), fy = _mm256_set1_ps(in.fy);
  const __m256 X = _mm256_div_ps(_mm256_mul_ps(d, _mm256_sub_ps(u, _mm256_set1_ps(in.cx))), fx);
  const __m256 Y = _mm256_div_ps(_mm256_mul_ps(d, _mm256_sub_ps(v, _mm256_set1_ps(in.cy))), fy);
  const __m256 Z = d;
  const __m256 iz = _mm256_div_ps(_mm256_set1_ps(1.0f), Z);
  const __m256 xn = _mm256_mul_ps(X, iz), yn = _mm256_mul_ps(Y, iz);
  const __m256 sign = _mm256_set1_ps(-0.0f);
  auto neg = [&](__m256 t) { return _mm256_xor_ps(t, sign); };
  // The projection's derivatives: du/dX, du/dZ, dv/dY, dv/dZ.
  const __m256 ux = _mm256_mul_ps(fx, iz), uz = _mm256_mul_ps(_mm256_mul_ps(neg(fx), xn), iz);
  const __m256 vy = _mm256_mul_ps(fy, iz), vz = _mm256_mul_ps(_mm256_mul_ps(neg(fy), yn), iz);
  const __m256 zero = _mm256_setzero_ps();
  __m256 wu[6], wv[6];
  wu[0] = _mm256_mul_ps(uz, Y);
  wu[1] = _mm256_add_ps(_mm256_mul_ps(ux, Z), _mm256_mul_ps(uz, neg(X)));
  wu[2] = _mm256_mul_ps(ux, neg(Y));
  wu[3] = ux;
  wu[4] = zero;
  wu[5] = uz;
  wv[0] = _mm256_add_ps(_mm256_mul_ps(vy, neg(Z)), _mm256_mul_ps(vz, Y));
  wv[1] = _mm256_mul_ps(vz, neg(X));
  wv[2] = _mm256_mul_ps(vy, X);
  wv[3] = zero;
  wv[4] = vy;
  wv[5] = vz;
  if (sums) {
    // Lanes past count: dW and the offsets +0, as the scalar twin's.
    const __m256 mask = _mm256_castsi256_ps(used);
    __m256 mu = _mm256_and_ps(_mm256_sub_ps(u, _mm256_set1_ps(in.cx)), mask);
    __m256 mv = _mm256_and_ps(_mm256_sub_ps(v, _mm256_set1_ps(in.cy)), mask);
    __m256 su[6], sv[6];
    for (int k = 0; k < 6; ++k) {
      su[k] = _mm256_and_ps(wu[k], mask);
      sv[k] = _mm256_and_ps(wv[k], mask);
    }
    int e = 0;
    for (int a = 0; a < 6; ++a)
      for (int b = 0; b <= a; ++b, ++e) {
        const __m256 m = _mm256_add_ps(_mm256_mul_ps(su[a], su[b]), _mm256_mul_ps(sv[a], sv[b]));
        _mm256_storeu_ps(sums->motion[e], _mm256_add_ps(_mm256_loadu_ps(sums->motion[e]), m));
      }
    for (int a = 0; a < 6; ++a) {
      const __m256 radial = _mm256_add_ps(_mm256_mul_ps(su[a], mu), _mm256_mul_ps(sv[a], mv));
      const __m256 modes[6] = {su[a], sv[a], _mm256_sub_ps(_mm256_mul_ps(sv[a], mu), _mm256_mul_ps(su[a], mv)), radial,
                               _mm256_mul_ps(radial, mu), _mm256_mul_ps(radial, mv)};
      for (int m = 0; m < 6; ++m)
        _mm256_storeu_ps(sums->floor[a][m], _mm256_add_ps(_mm256_loadu_ps(sums->floor[a][m]), modes[m]));
    }
  }
  auto put = [&](float* p, __m256 t) {
    if (count == kLanes) _mm256_storeu_ps(p, t);
    else _mm256_maskstore_ps(p, used, t);
  };
  put(out.pu, u);
  put(out.pv, v);
  put(out.px, X);
  put(out.py, Y);
  put(out.pz, Z);
  const __m256 two = _mm256_set1_ps(2.0f), eighth = _mm256_set1_ps(8.0f);
  for (int c = 0; c < C; ++c) {
    auto I = [&](int dx, int dy) { return tap(c, dx, dy); };
    const __m256 nw = I(-1, -1), n = I(0, -1), ne = I(1, -1), w = I(-1, 0), o = I(0, 0), east = I(1, 0);
    const __m256 sw = I(-1, 1), s = I(0, 1), se = I(1, 1);
    // (ne + 2 e + se - nw - 2 w - sw) / 8 and (sw + 2 s + se - nw - 2 n - ne) / 8, left to right.
    const __m256 gx = _mm256_div_ps(
        _mm256_sub_ps(_mm256_sub_ps(_mm256_sub_ps(_mm256_add_ps(_mm256_add_ps(ne, _mm256_mul_ps(two, east)), se), nw),
                                    _mm256_mul_ps(two, w)),
                      sw),
        eighth);
    const __m256 gy = _mm256_div_ps(
        _mm256_sub_ps(_mm256_sub_ps(_mm256_sub_ps(_mm256_add_ps(_mm256_add_ps(sw, _mm256_mul_ps(two, s)), se), nw),
                                    _mm256_mul_ps(two, n)),
                      ne),
        eighth);
    for (int k = 0; k < 6; ++k) put(out.jac[k] + c * out.jac_plane, _mm256_add_ps(_mm256_mul_ps(gx, wu[k]), _mm256_mul_ps(gy, wv[k])));
    put(out.val + c * out.plane, o);
  }
}

namespace {

// Pixels k of [0, count) in lane k mod kOuterLanes; get(p, k, n) loads the floats of pixels
// k .. k + n - 1 of array p (zeros past n), four of them.
template <class Get>
void outer_sums(const float* const* jac, const float* w, int count, Get get, OuterSums& h) {
  const __m256d zero = _mm256_setzero_pd();
  __m256d acc[21];
  for (int e = 0; e < 21; ++e) acc[e] = _mm256_loadu_pd(h.h[e]);
  for (int k = 0; k < count; k += kOuterLanes) {
    const int n = std::min(kOuterLanes, count - k);
    const __m256d wv = _mm256_cvtps_pd(get(w, k, n));
    const __m256d use = _mm256_cmp_pd(wv, zero, _CMP_GT_OQ);  // zeros past the end do not pass
    const __m256d wd = _mm256_and_pd(wv, use);
    __m256d j[6];
    for (int a = 0; a < 6; ++a) j[a] = _mm256_and_pd(_mm256_cvtps_pd(get(jac[a], k, n)), use);
    int e = 0;
    for (int a = 0; a < 6; ++a) {
      const __m256d wj = _mm256_mul_pd(wd, j[a]);
      for (int b = 0; b <= a; ++b, ++e) acc[e] = _mm256_add_pd(acc[e], _mm256_mul_pd(wj, j[b]));
    }
  }
  for (int e = 0; e < 21; ++e) _mm256_storeu_pd(h.h[e], acc[e]);
}

inline __m128i first_lanes(int n) { return _mm_cmpgt_epi32(_mm_set1_epi32(n), _mm_setr_epi32(0, 1, 2, 3)); }

}  // namespace

void outer_sums_avx2(const float* const* jac, const float* w, int i0, int i1, OuterSums& h) {
  outer_sums(jac, w, i1 - i0, [i0](const float* p, int k, int n) {
    return n == kOuterLanes ? _mm_loadu_ps(p + i0 + k) : _mm_maskload_ps(p + i0 + k, first_lanes(n));
  }, h);
}

void outer_sums_at_avx2(const float* const* jac, const float* w, const int* index, int count, OuterSums& h) {
  const __m128i steps = _mm_setr_epi32(0, 1, 2, 3);
  outer_sums(jac, w, count, [index, steps](const float* p, int k, int n) {
    if (n == kOuterLanes) {
      // The pixels that leave come in runs along rows: four consecutive ones load plainly.
      const __m128i idx = _mm_loadu_si128(reinterpret_cast<const __m128i*>(index + k));
      const __m128i run = _mm_cmpeq_epi32(_mm_sub_epi32(idx, _mm_set1_epi32(index[k])), steps);
      if (_mm_movemask_epi8(run) == 0xFFFF) return _mm_loadu_ps(p + index[k]);
      return _mm_i32gather_ps(p, idx, 4);
    }
    const __m128i m = first_lanes(n);
    const __m128i idx = _mm_and_si128(_mm_maskload_epi32(index + k, m), m);
    return _mm_mask_i32gather_ps(_mm_setzero_ps(), p, idx, _mm_castsi128_ps(m), 4);
  }, h);
}

}  // namespace terralign::iclk::detail
