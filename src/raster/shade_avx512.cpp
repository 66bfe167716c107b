// AVX-512 build of the shading kernel: 16 pixels a step, texels fetched with gathers. Same
// float operations in the same order as shade_scalar.cpp (compiled without FMA contraction),
// so the output matches it bit for bit. The shading tail (n % 16) runs the scalar kernel, the
// resolve tail the AVX2 one.
#include <terralign/raster/shade_kernels.hpp>

#include <immintrin.h>

#include <cmath>

#include "pack_avx2.hpp"

namespace terralign::raster {
namespace {

struct Acc16 {
  __m512 r, g, b, a;
};

inline Acc16 sample16(const ShadeParams& p, __m512i level, __m512 u, __m512 v) {
  const int* lv = reinterpret_cast<const int*>(p.levels);
  __m512i off, wid, hei;
  __m512 scale;
  const int l0 = _mm_cvtsi128_si32(_mm512_castsi512_si128(level));
  if (_mm512_cmpeq_epi32_mask(level, _mm512_set1_epi32(l0)) == 0xFFFF) {
    const MipLevel& L = p.levels[l0];  // one level for all lanes (the usual case)
    off = _mm512_set1_epi32(L.offset);
    wid = _mm512_set1_epi32(L.width);
    hei = _mm512_set1_epi32(L.height);
    scale = _mm512_set1_ps(L.scale);
  } else {
    const __m512i idx = _mm512_slli_epi32(level, 2);  // MipLevel is 4 x 32 bits
    off = _mm512_i32gather_epi32(idx, lv + 0, 4);
    wid = _mm512_i32gather_epi32(idx, lv + 1, 4);
    hei = _mm512_i32gather_epi32(idx, lv + 2, 4);
    scale = _mm512_castsi512_ps(_mm512_i32gather_epi32(idx, lv + 3, 4));
  }
  const __m512 half = _mm512_set1_ps(0.5f), one = _mm512_set1_ps(1.0f);
  const __m512 ul = _mm512_sub_ps(_mm512_mul_ps(_mm512_add_ps(u, half), scale), half);
  const __m512 vl = _mm512_sub_ps(_mm512_mul_ps(_mm512_add_ps(v, half), scale), half);
  const __m512 fx0 = _mm512_roundscale_ps(ul, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
  const __m512 fy0 = _mm512_roundscale_ps(vl, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
  const __m512 fx = _mm512_sub_ps(ul, fx0), fy = _mm512_sub_ps(vl, fy0);
  const __m512i x0 = _mm512_cvttps_epi32(fx0), y0 = _mm512_cvttps_epi32(fy0);
  const __m512 gx = _mm512_sub_ps(one, fx), gy = _mm512_sub_ps(one, fy);
  const __m512 w[4] = {_mm512_mul_ps(gx, gy), _mm512_mul_ps(fx, gy), _mm512_mul_ps(gx, fy), _mm512_mul_ps(fx, fy)};
  const __m512i zero = _mm512_setzero_si512(), ione = _mm512_set1_epi32(1), mone = _mm512_set1_epi32(-1);
  const __m512i wm1 = _mm512_sub_epi32(wid, ione), hm1 = _mm512_sub_epi32(hei, ione);
  const __m512i mask8 = _mm512_set1_epi32(255);
  const __m512i even = _mm512_set_epi32(30, 28, 26, 24, 22, 20, 18, 16, 14, 12, 10, 8, 6, 4, 2, 0);
  const __m512i odd = _mm512_add_epi32(even, ione);
  const long long* base = reinterpret_cast<const long long*>(p.texels);
  Acc16 acc{_mm512_setzero_ps(), _mm512_setzero_ps(), _mm512_setzero_ps(), _mm512_setzero_ps()};
  auto add_tap = [&](__m512 wk, __m512i t) {
    const __m512 wa = _mm512_mul_ps(wk, _mm512_cvtepi32_ps(_mm512_srli_epi32(t, 24)));
    acc.r = _mm512_add_ps(acc.r, _mm512_mul_ps(wa, _mm512_cvtepi32_ps(_mm512_and_si512(t, mask8))));
    acc.g = _mm512_add_ps(acc.g, _mm512_mul_ps(wa, _mm512_cvtepi32_ps(_mm512_and_si512(_mm512_srli_epi32(t, 8), mask8))));
    acc.b = _mm512_add_ps(acc.b, _mm512_mul_ps(wa, _mm512_cvtepi32_ps(_mm512_and_si512(_mm512_srli_epi32(t, 16), mask8))));
    acc.a = _mm512_add_ps(acc.a, wa);
  };
  // Each row's two taps are neighbours in memory: one 64-bit gather fetches both (half the
  // elements of two 32-bit gathers), split into the left and the right tap.
  auto row_pair = [&](__m512i at, __m512i pair[2]) {
    const __m512i q0 = _mm512_i32gather_epi64(_mm512_castsi512_si256(at), base, 4);
    const __m512i q1 = _mm512_i32gather_epi64(_mm512_extracti64x4_epi64(at, 1), base, 4);
    pair[0] = _mm512_permutex2var_epi32(q0, even, q1);
    pair[1] = _mm512_permutex2var_epi32(q0, odd, q1);
  };
  const __mmask16 interior = _mm512_cmpge_epi32_mask(x0, zero) & _mm512_cmplt_epi32_mask(x0, wm1) &
                             _mm512_cmpge_epi32_mask(y0, zero) & _mm512_cmplt_epi32_mask(y0, hm1);
  if (interior == 0xFFFF) {
    // Every lane's four taps inside the level (most vectors): the masks below would all be
    // set and the clamps change nothing, so they are skipped; the same operations otherwise.
    for (int row = 0; row < 2; ++row) {
      const __m512i y = _mm512_add_epi32(y0, _mm512_set1_epi32(row));
      __m512i pair[2];
      row_pair(_mm512_add_epi32(off, _mm512_add_epi32(_mm512_mullo_epi32(y, wid), x0)), pair);
      add_tap(w[2 * row], pair[0]);
      add_tap(w[2 * row + 1], pair[1]);
    }
    return acc;
  }
  // The pair starts at x0 clamped to [-1, width - 1]; a tap outside the level gets weight 0,
  // as in the scalar kernel, whatever texel it read (the array has a guard texel at each end,
  // so the pair never leaves it).
  const __m512i xp = _mm512_min_epi32(_mm512_max_epi32(x0, mone), wm1);
  for (int row = 0; row < 2; ++row) {
    const __m512i y = _mm512_add_epi32(y0, _mm512_set1_epi32(row));
    const __mmask16 yin = _mm512_cmpge_epi32_mask(y, zero) & _mm512_cmplt_epi32_mask(y, hei);
    const __m512i yc = _mm512_min_epi32(_mm512_max_epi32(y, zero), hm1);
    __m512i pair[2];
    row_pair(_mm512_add_epi32(off, _mm512_add_epi32(_mm512_mullo_epi32(yc, wid), xp)), pair);
    for (int dx = 0; dx < 2; ++dx) {
      const __m512i x = _mm512_add_epi32(x0, _mm512_set1_epi32(dx));
      const __mmask16 inside = yin & _mm512_cmpge_epi32_mask(x, zero) & _mm512_cmplt_epi32_mask(x, wid);
      add_tap(_mm512_maskz_mov_ps(inside, w[2 * row + dx]), pair[dx]);
    }
  }
  return acc;
}

}  // namespace

void shade_row_avx512(int n, const float* wx, const float* wy, const float* log2fp, std::uint8_t* rgb,
                      std::uint8_t* valid, const ShadeParams& p) {
  const int top = p.n_levels - 1;
  const __m512 ftop = _mm512_set1_ps(static_cast<float>(top));
  const __m512i itop = _mm512_set1_epi32(top);
  const __m512 zero = _mm512_setzero_ps(), one = _mm512_set1_ps(1.0f), half = _mm512_set1_ps(0.5f);
  int i = 0;
  for (; i + 16 <= n; i += 16) {
    const __m512 x = _mm512_loadu_ps(wx + i), y = _mm512_loadu_ps(wy + i);
    const __mmask16 terrain = _mm512_cmp_ps_mask(x, x, _CMP_ORD_Q);
    const __m512 xs = _mm512_maskz_mov_ps(terrain, x), ys = _mm512_maskz_mov_ps(terrain, y);
    const __m512 u = _mm512_add_ps(_mm512_add_ps(_mm512_set1_ps(p.a0), _mm512_mul_ps(_mm512_set1_ps(p.a1), xs)),
                                   _mm512_mul_ps(_mm512_set1_ps(p.a2), ys));
    const __m512 v = _mm512_add_ps(_mm512_add_ps(_mm512_set1_ps(p.b0), _mm512_mul_ps(_mm512_set1_ps(p.b1), xs)),
                                   _mm512_mul_ps(_mm512_set1_ps(p.b2), ys));
    __m512 lod = _mm512_add_ps(_mm512_maskz_loadu_ps(terrain, log2fp + i), _mm512_set1_ps(p.lod_bias));
    // "lod > 0 ? lod : 0" and "lod < top ? lod : top" (NaN -> 0, top), as the scalar twin.
    lod = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(lod, zero, _CMP_GT_OQ), zero, lod);
    lod = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(lod, ftop, _CMP_LT_OQ), ftop, lod);
    const __m512 fl = _mm512_roundscale_ps(lod, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
    const __m512i l0 = _mm512_cvttps_epi32(fl);
    const __m512i l1 = _mm512_min_epi32(_mm512_add_epi32(l0, _mm512_set1_epi32(1)), itop);
    const __m512 t = _mm512_sub_ps(lod, fl);
    const Acc16 s0 = sample16(p, l0, u, v);
    const __mmask16 live = _mm512_cmp_ps_mask(t, zero, _CMP_GT_OQ);
    Acc16 acc;
    if (live == 0) {
      acc = s0;  // t == 0 in every lane: s0 * 1 + s1 * 0 == s0, the scalar kernel's shortcut
    } else {
      Acc16 s1 = sample16(p, l1, u, v);
      s1.r = _mm512_maskz_mov_ps(live, s1.r);
      s1.g = _mm512_maskz_mov_ps(live, s1.g);
      s1.b = _mm512_maskz_mov_ps(live, s1.b);
      s1.a = _mm512_maskz_mov_ps(live, s1.a);
      const __m512 w0 = _mm512_sub_ps(one, t);
      acc.r = _mm512_add_ps(_mm512_mul_ps(s0.r, w0), _mm512_mul_ps(s1.r, t));
      acc.g = _mm512_add_ps(_mm512_mul_ps(s0.g, w0), _mm512_mul_ps(s1.g, t));
      acc.b = _mm512_add_ps(_mm512_mul_ps(s0.b, w0), _mm512_mul_ps(s1.b, t));
      acc.a = _mm512_add_ps(_mm512_mul_ps(s0.a, w0), _mm512_mul_ps(s1.a, t));
    }
    acc.a = _mm512_maskz_mov_ps(terrain, acc.a);
    const __mmask16 ok = _mm512_cmp_ps_mask(acc.a, _mm512_set1_ps(127.5f), _CMP_GE_OQ);
    const __m512 inv = _mm512_maskz_div_ps(ok, one, acc.a);
    const __m512i r = _mm512_cvttps_epi32(_mm512_add_ps(_mm512_mul_ps(_mm512_maskz_mov_ps(terrain, acc.r), inv), half));
    const __m512i g = _mm512_cvttps_epi32(_mm512_add_ps(_mm512_mul_ps(_mm512_maskz_mov_ps(terrain, acc.g), inv), half));
    const __m512i b = _mm512_cvttps_epi32(_mm512_add_ps(_mm512_mul_ps(_mm512_maskz_mov_ps(terrain, acc.b), inv), half));
    const __m512i px = _mm512_or_si512(r, _mm512_or_si512(_mm512_slli_epi32(g, 8), _mm512_slli_epi32(b, 16)));
    store_rgb8_avx2(rgb + 3 * i, _mm512_castsi512_si256(px));
    store_rgb8_avx2(rgb + 3 * i + 24, _mm512_extracti64x4_epi64(px, 1));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(valid + i), _mm512_cvtepi32_epi8(_mm512_maskz_set1_epi32(ok, 255)));
  }
  if (i < n) shade_row_scalar(n - i, wx + i, wy + i, log2fp + i, rgb + 3 * i, valid + i, p);
}

void resolve_row_avx512(int n, const int* ids, const float* coef, float dx0, float dy, float* wx, float* wy,
                        float* z, float* log2fp) {
  const __m512 lane = _mm512_setr_ps(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m512 one = _mm512_set1_ps(1.0f), nan = _mm512_set1_ps(NAN), zero = _mm512_setzero_ps();
  const __m512 vdy = _mm512_set1_ps(dy);
  auto b = [](float v) { return _mm512_set1_ps(v); };
  int i = 0;
  for (; i + 16 <= n; i += 16) {
    const __m512i id = _mm512_loadu_si512(ids + i);
    const __mmask16 seen = _mm512_cmpgt_epi32_mask(id, _mm512_set1_epi32(-1));
    if (seen == 0) {
      _mm512_storeu_ps(z + i, nan);
      _mm512_storeu_ps(wx + i, nan);
      _mm512_storeu_ps(wy + i, nan);
      _mm512_storeu_ps(log2fp + i, zero);
      continue;
    }
    // The planes of each lane's entry: broadcast when the 16 pixels see one triangle (most
    // of a frame), else gathered.
    __m512 c[9];
    if (seen == 0xFFFF && _mm512_cmpeq_epi32_mask(id, _mm512_set1_epi32(ids[i])) == 0xFFFF) {
      const float* ce = coef + 9 * static_cast<std::ptrdiff_t>(ids[i]);
      for (int k = 0; k < 9; ++k) c[k] = _mm512_set1_ps(ce[k]);
    } else {
      const __m512i idx = _mm512_add_epi32(_mm512_slli_epi32(id, 3), id);  // 9 e
      for (int k = 0; k < 9; ++k) c[k] = _mm512_mask_i32gather_ps(zero, seen, idx, coef + k, 4);
    }
    // The AVX2 kernel's operations in the same order, 16 lanes wide.
    const __m512 dx = _mm512_add_ps(_mm512_set1_ps(dx0 + static_cast<float>(i)), lane);
    const __m512 iz = _mm512_add_ps(_mm512_add_ps(c[0], _mm512_mul_ps(c[2], vdy)), _mm512_mul_ps(c[1], dx));
    const __m512 zz = _mm512_div_ps(one, iz);
    const __m512 x = _mm512_mul_ps(_mm512_add_ps(_mm512_add_ps(c[3], _mm512_mul_ps(c[5], vdy)), _mm512_mul_ps(c[4], dx)), zz);
    const __m512 y = _mm512_mul_ps(_mm512_add_ps(_mm512_add_ps(c[6], _mm512_mul_ps(c[8], vdy)), _mm512_mul_ps(c[7], dx)), zz);
    const __m512 du_x = _mm512_mul_ps(_mm512_sub_ps(c[4], _mm512_mul_ps(x, c[1])), zz);
    const __m512 du_y = _mm512_mul_ps(_mm512_sub_ps(c[7], _mm512_mul_ps(y, c[1])), zz);
    const __m512 dv_x = _mm512_mul_ps(_mm512_sub_ps(c[5], _mm512_mul_ps(x, c[2])), zz);
    const __m512 dv_y = _mm512_mul_ps(_mm512_sub_ps(c[8], _mm512_mul_ps(y, c[2])), zz);
    const __m512 su = _mm512_add_ps(_mm512_mul_ps(du_x, du_x), _mm512_mul_ps(du_y, du_y));
    const __m512 sv = _mm512_add_ps(_mm512_mul_ps(dv_x, dv_x), _mm512_mul_ps(dv_y, dv_y));
    __m512 d2 = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(su, sv, _CMP_GT_OQ), sv, su);
    d2 = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(d2, b(1e-12f), _CMP_GT_OQ), b(1e-12f), d2);
    const __m512i bits = _mm512_castps_si512(d2);
    const __m512 e = _mm512_cvtepi32_ps(_mm512_sub_epi32(_mm512_srli_epi32(bits, 23), _mm512_set1_epi32(127)));
    const __m512 m = _mm512_castsi512_ps(_mm512_or_si512(_mm512_and_si512(bits, _mm512_set1_epi32(0x7fffff)),
                                                         _mm512_set1_epi32(0x3f800000)));
    const __m512 poly = _mm512_sub_ps(_mm512_mul_ps(_mm512_add_ps(_mm512_mul_ps(b(-0.34484843f), m), b(2.02466578f)), m),
                                      b(0.67487759f));
    const __m512 l2 = _mm512_mul_ps(b(0.5f), _mm512_add_ps(e, poly));
    _mm512_storeu_ps(z + i, _mm512_mask_blend_ps(seen, nan, zz));
    _mm512_storeu_ps(wx + i, _mm512_mask_blend_ps(seen, nan, x));
    _mm512_storeu_ps(wy + i, _mm512_mask_blend_ps(seen, nan, y));
    _mm512_storeu_ps(log2fp + i, _mm512_mask_blend_ps(seen, zero, l2));
  }
  if (i < n) resolve_row_avx2(n - i, ids + i, coef, dx0 + static_cast<float>(i), dy, wx + i, wy + i, z + i, log2fp + i);
}

}  // namespace terralign::raster

