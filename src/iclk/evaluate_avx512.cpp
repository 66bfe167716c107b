// AVX-512 build of the residual kernel: sixteen pixels at once through the warp, the samples
// and the residuals, the same operations in the same order as evaluate_scalar.cpp (compiled
// with -mavx512f and -ffp-contract=off, so nothing fuses). The sums keep the other builds'
// eight lanes and their order: a group's first eight pixels are added for every channel,
// then its last eight, as the AVX2 build adds two groups one after the other. So the bits are
// the scalar, AVX2 and NEON builds'.
#include "evaluate_kernels.hpp"

#include <immintrin.h>

#include <algorithm>

namespace terralign::iclk::detail {
namespace {

constexpr int kWide = 2 * kLanes;
// The AVX2 build's eight-lane sums take a group's channels in turn; with more channels than
// this the products of the last eight pixels would not stay in registers (the learned tracker
// has two a level, the classical one one), and that build runs instead.
constexpr int kMaxChannels = 4;

inline __m256 low(__m512 v) { return _mm512_castps512_ps256(v); }
inline __m256 high(__m512 v) { return _mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(v), 1)); }

// p[idx[k]] and p[idx[k] + 1] for the sixteen lanes k, gathered as 64-bit pairs.
inline void pairs(const float* p, __m512i idx, __m512& first, __m512& second) {
  const __m512 lo = _mm512_castpd_ps(_mm512_i32gather_pd(_mm512_castsi512_si256(idx), p, 4));
  const __m512 hi = _mm512_castpd_ps(_mm512_i32gather_pd(_mm512_extracti64x4_epi64(idx, 1), p, 4));
  // lo = f0 s0 f1 s1 ... f7 s7, hi the same for lanes 8..15.
  const __m512i even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
  const __m512i odd = _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
  first = _mm512_permutex2var_ps(lo, even, hi);
  second = _mm512_permutex2var_ps(lo, odd, hi);
}

}  // namespace

void evaluate_se3_avx512(const Se3EvalInput& in, int i0, int i1, float* r, unsigned char* ok, Se3EvalSums& s) {
  if (in.channels > kMaxChannels) {
    evaluate_se3_avx2(in, i0, i1, r, ok, s);
    return;
  }
  const __m512 one = _mm512_set1_ps(1.0f), zero = _mm512_setzero_ps(), zmin = _mm512_set1_ps(1e-6f);
  const __m512 umax = _mm512_set1_ps(static_cast<float>(in.width - 1));
  const __m512 vmax = _mm512_set1_ps(static_cast<float>(in.height - 1));
  const __m512i xmax = _mm512_set1_epi32(in.width - 2), ymax = _mm512_set1_epi32(in.height - 2);
  const __m512i stride = _mm512_set1_epi32(static_cast<int>(in.stride));
  const __m512i fifteen = _mm512_set1_epi32(kWide - 1);
  __m512 R[9], t[3];
  for (int k = 0; k < 9; ++k) R[k] = _mm512_set1_ps(in.R[k]);
  for (int k = 0; k < 3; ++k) t[k] = _mm512_set1_ps(in.t[k]);
  const __m512 fxv = _mm512_set1_ps(in.fx), fyv = _mm512_set1_ps(in.fy);
  const __m512 cxv = _mm512_set1_ps(in.cx), cyv = _mm512_set1_ps(in.cy);
  __m256 g[6], cost = _mm256_setzero_ps(), wsum = _mm256_setzero_ps();
  for (auto& v : g) v = _mm256_setzero_ps();
  // The products of a group's last eight pixels, per channel, added after its first eight's.
  __m256 later_g[kMaxChannels][6], later_cost[kMaxChannels];
  int valid = 0, n_out = 0;
  for (int i = i0; i < i1; i += kWide) {
    const int n = std::min(kWide, i1 - i);
    const __mmask16 load = n == kWide ? static_cast<__mmask16>(0xFFFF) : static_cast<__mmask16>((1u << n) - 1u);
    auto get = [&](const float* p) { return n == kWide ? _mm512_loadu_ps(p + i) : _mm512_maskz_loadu_ps(load, p + i); };
    const __m512 x = get(in.px), y = get(in.py), z = get(in.pz);
    auto row = [&](int k) {
      return _mm512_add_ps(_mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(R[3 * k], x), _mm512_mul_ps(R[3 * k + 1], y)),
                                         _mm512_mul_ps(R[3 * k + 2], z)),
                           t[k]);
    };
    const __m512 X = row(0), Y = row(1), Z = row(2);
    __m512 u = _mm512_add_ps(_mm512_div_ps(_mm512_mul_ps(fxv, X), Z), cxv);
    __m512 v = _mm512_add_ps(_mm512_div_ps(_mm512_mul_ps(fyv, Y), Z), cyv);
    __mmask16 inside = _mm512_mask_cmp_ps_mask(load, Z, zmin, _CMP_GT_OQ);
    inside = _mm512_mask_cmp_ps_mask(inside, u, zero, _CMP_GE_OQ);
    inside = _mm512_mask_cmp_ps_mask(inside, v, zero, _CMP_GE_OQ);
    inside = _mm512_mask_cmp_ps_mask(inside, u, umax, _CMP_LE_OQ);
    inside = _mm512_mask_cmp_ps_mask(inside, v, vmax, _CMP_LE_OQ);
    // Lanes that did not land sample pixel (0, 0); their results are masked below.
    u = _mm512_maskz_mov_ps(inside, u);
    v = _mm512_maskz_mov_ps(inside, v);
    const __m512i x0 = _mm512_min_epi32(_mm512_cvttps_epi32(u), xmax);
    const __m512i y0 = _mm512_min_epi32(_mm512_cvttps_epi32(v), ymax);
    const __m512 fx = _mm512_sub_ps(u, _mm512_cvtepi32_ps(x0)), fy = _mm512_sub_ps(v, _mm512_cvtepi32_ps(y0));
    const __m512i idx = _mm512_add_epi32(_mm512_mullo_epi32(y0, stride), x0);
    // As the AVX2 build: where the sixteen lanes share a row and their columns lie at most 15
    // right of lane 0's, each tap is a permutation of one 16-float load.
    const int bx = _mm_cvtsi128_si32(_mm512_castsi512_si128(x0)), by = _mm_cvtsi128_si32(_mm512_castsi512_si128(y0));
    const __m512i dx = _mm512_sub_epi32(x0, _mm512_set1_epi32(bx));
    const __mmask16 in_row = _mm512_cmpeq_epi32_mask(y0, _mm512_set1_epi32(by));
    const __mmask16 in_window = _mm512_mask_cmple_epu32_mask(in_row, dx, fifteen);  // unsigned: none left of lane 0
    const bool window = bx + kWide + 1 <= in.width && in_window == 0xFFFF;
    const __m512 gx = _mm512_sub_ps(one, fx), gy = _mm512_sub_ps(one, fy);
    const __m512 w = _mm512_maskz_mov_ps(inside, get(in.w));
    for (int ch = 0; ch < in.channels; ++ch) {
      const float* live_c = in.live + ch * in.live_plane;
      __m512 a, b, c, d;
      if (window) {
        const float* p = live_c + static_cast<std::ptrdiff_t>(by) * in.stride + bx;
        a = _mm512_permutexvar_ps(dx, _mm512_loadu_ps(p));
        b = _mm512_permutexvar_ps(dx, _mm512_loadu_ps(p + 1));
        c = _mm512_permutexvar_ps(dx, _mm512_loadu_ps(p + in.stride));
        d = _mm512_permutexvar_ps(dx, _mm512_loadu_ps(p + in.stride + 1));
      } else {
        pairs(live_c, idx, a, b);
        pairs(live_c + in.stride, idx, c, d);
      }
      const __m512 top = _mm512_add_ps(_mm512_mul_ps(gx, a), _mm512_mul_ps(fx, b));
      const __m512 bot = _mm512_add_ps(_mm512_mul_ps(gx, c), _mm512_mul_ps(fx, d));
      const __m512 live = _mm512_add_ps(_mm512_mul_ps(gy, top), _mm512_mul_ps(fy, bot));
      const __m512 res = _mm512_maskz_sub_ps(inside, live, get(in.val + ch * in.plane));
      const __m512 wr = _mm512_mul_ps(w, res);
      for (int k = 0; k < 6; ++k) {
        const __m512 p = _mm512_mul_ps(wr, get(in.jac[k] + ch * in.jac_plane));
        g[k] = _mm256_add_ps(g[k], low(p));
        later_g[ch][k] = high(p);
      }
      const __m512 e = _mm512_mul_ps(wr, res);
      cost = _mm256_add_ps(cost, low(e));
      later_cost[ch] = high(e);
      wsum = _mm256_add_ps(wsum, low(w));
      float* rc = r + ch * in.plane + i;
      if (n == kWide) _mm512_storeu_ps(rc, res);
      else _mm512_mask_storeu_ps(rc, load, res);
    }
    if (n > kLanes) {  // the group's last eight pixels (the AVX2 build's second group)
      for (int ch = 0; ch < in.channels; ++ch) {
        for (int k = 0; k < 6; ++k) g[k] = _mm256_add_ps(g[k], later_g[ch][k]);
        cost = _mm256_add_ps(cost, later_cost[ch]);
        wsum = _mm256_add_ps(wsum, high(w));
      }
    }
    const unsigned bits = inside;
    valid += __builtin_popcount(bits);
    for (unsigned left = ~bits & load; left != 0; left &= left - 1u) in.out[n_out++] = i + __builtin_ctz(left);
    if (n == kWide) {
      spread_mask8(bits, ok + i);
      spread_mask8(bits >> 8, ok + i + kLanes);
    } else {
      for (int k = 0; k < n; ++k) ok[i + k] = static_cast<unsigned char>((bits >> k) & 1u);
    }
  }
  for (int k = 0; k < 6; ++k) _mm256_storeu_ps(s.g[k], g[k]);
  _mm256_storeu_ps(s.cost, cost);
  _mm256_storeu_ps(s.wsum, wsum);
  s.valid = valid;
  s.n_out = n_out;
}

}  // namespace terralign::iclk::detail
