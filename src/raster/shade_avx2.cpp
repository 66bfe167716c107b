// AVX2 build of the shading kernel: 8 pixels a step, texels fetched with gathers (or, where the
// taps are neighbours, row loads and permutes: contiguous_taps). Same float
// operations in the same order as shade_scalar.cpp (compiled without FMA contraction), so
// the output matches it bit for bit. The tail (n % 8) runs the scalar kernel.
#include <terralign/raster/shade_kernels.hpp>

#include <cmath>
#include <cstring>

#include <immintrin.h>

#include "pack_avx2.hpp"

namespace terralign::raster {
namespace {

struct Acc8 {
  __m256 r, g, b, a;
};

// Neighbouring pixels mostly read neighbouring texels. When the 8 lanes' bilinear taps (x0 ..
// x0 + 1, y0 .. y0 + 1, all inside level L) lie in at most three texel rows and 8 columns, three
// row loads and permutes fetch them instead of four gathers: the same texels, so the same
// bits. The lanes at the ends give the box (a row of pixels over terrain maps to a curve whose
// extremes are mostly at its ends), and every lane is checked to be inside it. Calls
// add_tap(w[k], texels of tap k) for k = 0..3 in the gathers' order and returns true, or
// returns false and reads nothing.
template <class AddTap>
inline bool contiguous_taps(const MipLevel& L, const int* texels, __m256i x0, __m256i y0, const __m256 w[4],
                            AddTap& add_tap) {
  const int xa = _mm256_cvtsi256_si32(x0), xb = _mm256_extract_epi32(x0, 7);
  const int ya = _mm256_cvtsi256_si32(y0), yb = _mm256_extract_epi32(y0, 7);
  const int xlo = xa < xb ? xa : xb, xspan = (xa < xb ? xb : xa) - xlo;
  const int ylo = ya < yb ? ya : yb, yspan = (ya < yb ? yb : ya) - ylo;
  if (xspan > 6 || yspan > 1) return false;
  const __m256i dx = _mm256_sub_epi32(x0, _mm256_set1_epi32(xlo));
  const __m256i dy = _mm256_sub_epi32(y0, _mm256_set1_epi32(ylo));
  const __m256i xs = _mm256_set1_epi32(xspan), ys = _mm256_set1_epi32(yspan);
  // 0 <= d <= span, unsigned: max(d, span) == span.
  const __m256i in = _mm256_and_si256(_mm256_cmpeq_epi32(_mm256_max_epu32(dx, xs), xs),
                                      _mm256_cmpeq_epi32(_mm256_max_epu32(dy, ys), ys));
  if (_mm256_movemask_epi8(in) != -1) return false;
  // Rows ylo .. ylo + yspan + 1 and columns xlo .. xlo + xspan + 1 are inside the level (every
  // lane's taps are); the masked loads read only those.
  const int* row = texels + L.offset + ylo * L.width + xlo;
  const __m256i cols = _mm256_cmpgt_epi32(_mm256_set1_epi32(xspan + 2), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
  const __m256i r0 = _mm256_maskload_epi32(row, cols), r1 = _mm256_maskload_epi32(row + L.width, cols);
  const __m256i right = _mm256_add_epi32(dx, _mm256_set1_epi32(1));
  if (yspan == 0) {
    add_tap(w[0], _mm256_permutevar8x32_epi32(r0, dx));
    add_tap(w[1], _mm256_permutevar8x32_epi32(r0, right));
    add_tap(w[2], _mm256_permutevar8x32_epi32(r1, dx));
    add_tap(w[3], _mm256_permutevar8x32_epi32(r1, right));
    return true;
  }
  // Two rows of lanes: a lane with dy = 1 takes its taps from the next row pair.
  const __m256i r2 = _mm256_maskload_epi32(row + 2 * L.width, cols);
  const __m256 low = _mm256_castsi256_ps(_mm256_cmpeq_epi32(dy, _mm256_setzero_si256()));
  auto pick = [&](__m256i a, __m256i b, __m256i at) {
    return _mm256_castps_si256(_mm256_blendv_ps(_mm256_castsi256_ps(_mm256_permutevar8x32_epi32(b, at)),
                                                _mm256_castsi256_ps(_mm256_permutevar8x32_epi32(a, at)), low));
  };
  add_tap(w[0], pick(r0, r1, dx));
  add_tap(w[1], pick(r0, r1, right));
  add_tap(w[2], pick(r1, r2, dx));
  add_tap(w[3], pick(r1, r2, right));
  return true;
}

inline Acc8 sample8(const ShadeParams& p, __m256i level, __m256 u, __m256 v) {
  const int* lv = reinterpret_cast<const int*>(p.levels);
  __m256i off, wid, hei;
  __m256 scale;
  const MipLevel* one_level = nullptr;
  const int l0 = _mm256_cvtsi256_si32(level);
  if (_mm256_movemask_epi8(_mm256_cmpeq_epi32(level, _mm256_set1_epi32(l0))) == -1) {
    // One level for all lanes (the usual case): broadcast its fields.
    const MipLevel& L = p.levels[l0];
    one_level = &L;
    off = _mm256_set1_epi32(L.offset);
    wid = _mm256_set1_epi32(L.width);
    hei = _mm256_set1_epi32(L.height);
    scale = _mm256_set1_ps(L.scale);
  } else {
    // MipLevel is 4 x 32 bits: gather its fields per lane.
    const __m256i idx = _mm256_slli_epi32(level, 2);
    off = _mm256_i32gather_epi32(lv + 0, idx, 4);
    wid = _mm256_i32gather_epi32(lv + 1, idx, 4);
    hei = _mm256_i32gather_epi32(lv + 2, idx, 4);
    scale = _mm256_castsi256_ps(_mm256_i32gather_epi32(lv + 3, idx, 4));
  }
  const __m256 half = _mm256_set1_ps(0.5f), one = _mm256_set1_ps(1.0f);
  const __m256 ul = _mm256_sub_ps(_mm256_mul_ps(_mm256_add_ps(u, half), scale), half);
  const __m256 vl = _mm256_sub_ps(_mm256_mul_ps(_mm256_add_ps(v, half), scale), half);
  const __m256 fx0 = _mm256_floor_ps(ul), fy0 = _mm256_floor_ps(vl);
  const __m256 fx = _mm256_sub_ps(ul, fx0), fy = _mm256_sub_ps(vl, fy0);
  const __m256i x0 = _mm256_cvttps_epi32(fx0), y0 = _mm256_cvttps_epi32(fy0);
  const __m256 gx = _mm256_sub_ps(one, fx), gy = _mm256_sub_ps(one, fy);
  const __m256 w[4] = {_mm256_mul_ps(gx, gy), _mm256_mul_ps(fx, gy), _mm256_mul_ps(gx, fy),
                       _mm256_mul_ps(fx, fy)};
  const __m256i zero = _mm256_setzero_si256(), ione = _mm256_set1_epi32(1);
  const __m256i wm1 = _mm256_sub_epi32(wid, ione), hm1 = _mm256_sub_epi32(hei, ione);
  const __m256i mask8 = _mm256_set1_epi32(255);
  Acc8 acc{_mm256_setzero_ps(), _mm256_setzero_ps(), _mm256_setzero_ps(), _mm256_setzero_ps()};
  const int* texels = reinterpret_cast<const int*>(p.texels);
  auto add_tap = [&](__m256 wk, __m256i t) {
    const __m256 wa = _mm256_mul_ps(wk, _mm256_cvtepi32_ps(_mm256_srli_epi32(t, 24)));
    acc.r = _mm256_add_ps(acc.r, _mm256_mul_ps(wa, _mm256_cvtepi32_ps(_mm256_and_si256(t, mask8))));
    acc.g = _mm256_add_ps(acc.g, _mm256_mul_ps(wa, _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srli_epi32(t, 8), mask8))));
    acc.b = _mm256_add_ps(acc.b, _mm256_mul_ps(wa, _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srli_epi32(t, 16), mask8))));
    acc.a = _mm256_add_ps(acc.a, wa);
  };
  // 0 <= x0 < w - 1 and 0 <= y0 < h - 1 in every lane (most vectors): all four taps inside,
  // so the masks below would all be set and the clamps change nothing; skipped.
  const __m256i interior = _mm256_andnot_si256(
      _mm256_or_si256(_mm256_cmpgt_epi32(zero, x0), _mm256_cmpgt_epi32(zero, y0)),
      _mm256_and_si256(_mm256_cmpgt_epi32(wm1, x0), _mm256_cmpgt_epi32(hm1, y0)));
  if (_mm256_movemask_epi8(interior) == -1) {
    if (one_level != nullptr && contiguous_taps(*one_level, texels, x0, y0, w, add_tap)) return acc;
    const __m256i row0 = _mm256_add_epi32(off, _mm256_add_epi32(_mm256_mullo_epi32(y0, wid), x0));
    const __m256i row1 = _mm256_add_epi32(row0, wid);
    add_tap(w[0], _mm256_i32gather_epi32(texels, row0, 4));
    add_tap(w[1], _mm256_i32gather_epi32(texels, _mm256_add_epi32(row0, ione), 4));
    add_tap(w[2], _mm256_i32gather_epi32(texels, row1, 4));
    add_tap(w[3], _mm256_i32gather_epi32(texels, _mm256_add_epi32(row1, ione), 4));
    return acc;
  }
  for (int k = 0; k < 4; ++k) {
    const __m256i x = _mm256_add_epi32(x0, _mm256_set1_epi32(k & 1));
    const __m256i y = _mm256_add_epi32(y0, _mm256_set1_epi32(k >> 1));
    // inside: 0 <= x < w and 0 <= y < h
    const __m256i in_x = _mm256_andnot_si256(_mm256_cmpgt_epi32(zero, x), _mm256_cmpgt_epi32(wid, x));
    const __m256i in_y = _mm256_andnot_si256(_mm256_cmpgt_epi32(zero, y), _mm256_cmpgt_epi32(hei, y));
    const __m256i inside = _mm256_and_si256(in_x, in_y);
    const __m256i xc = _mm256_min_epi32(_mm256_max_epi32(x, zero), wm1);
    const __m256i yc = _mm256_min_epi32(_mm256_max_epi32(y, zero), hm1);
    add_tap(_mm256_and_ps(w[k], _mm256_castsi256_ps(inside)),
            _mm256_i32gather_epi32(texels, _mm256_add_epi32(off, _mm256_add_epi32(_mm256_mullo_epi32(yc, wid), xc)), 4));
  }
  return acc;
}

// The depth test of one row of a block where `in` (all-ones lanes) marks the covered pixels:
// where the triangle's 1/z `iz` is larger (nearer), it replaces z and id becomes `ve`.
inline void depth_row(__m256i in, __m256 iz, float* z, int* id, __m256i ve) {
  const __m256 old = _mm256_maskload_ps(z, in);
  const __m256i nearer = _mm256_and_si256(_mm256_castps_si256(_mm256_cmp_ps(iz, old, _CMP_GT_OQ)), in);
  _mm256_maskstore_ps(z, nearer, iz);
  _mm256_maskstore_epi32(id, nearer, ve);
}

}  // namespace

void shade_row_avx2(int n, const float* wx, const float* wy, const float* log2fp,
                    std::uint8_t* rgb, std::uint8_t* valid, const ShadeParams& p) {
  const int top = p.n_levels - 1;
  const __m256 ftop = _mm256_set1_ps(static_cast<float>(top));
  const __m256i itop = _mm256_set1_epi32(top);
  const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.0f), half = _mm256_set1_ps(0.5f);
  int i = 0;
  for (; i + 8 <= n; i += 8) {
    const __m256 x = _mm256_loadu_ps(wx + i), y = _mm256_loadu_ps(wy + i);
    const __m256 terrain = _mm256_cmp_ps(x, x, _CMP_ORD_Q);
    // NaN lanes compute on 0 and are masked at the end.
    const __m256 xs = _mm256_and_ps(x, terrain), ys = _mm256_and_ps(y, terrain);
    const __m256 u = _mm256_add_ps(_mm256_add_ps(_mm256_set1_ps(p.a0), _mm256_mul_ps(_mm256_set1_ps(p.a1), xs)),
                                   _mm256_mul_ps(_mm256_set1_ps(p.a2), ys));
    const __m256 v = _mm256_add_ps(_mm256_add_ps(_mm256_set1_ps(p.b0), _mm256_mul_ps(_mm256_set1_ps(p.b1), xs)),
                                   _mm256_mul_ps(_mm256_set1_ps(p.b2), ys));
    __m256 lod = _mm256_add_ps(_mm256_and_ps(_mm256_loadu_ps(log2fp + i), terrain), _mm256_set1_ps(p.lod_bias));
    // Same as the scalar "lod > 0 ? lod : 0" and "lod < top ? lod : top" (NaN -> 0, top).
    lod = _mm256_blendv_ps(zero, lod, _mm256_cmp_ps(lod, zero, _CMP_GT_OQ));
    lod = _mm256_blendv_ps(ftop, lod, _mm256_cmp_ps(lod, ftop, _CMP_LT_OQ));
    const __m256 fl = _mm256_floor_ps(lod);
    const __m256i l0 = _mm256_cvttps_epi32(fl);
    const __m256i l1 = _mm256_min_epi32(_mm256_add_epi32(l0, _mm256_set1_epi32(1)), itop);
    const __m256 t = _mm256_sub_ps(lod, fl);
    const Acc8 s0 = sample8(p, l0, u, v);
    Acc8 acc;
    if (_mm256_movemask_ps(_mm256_cmp_ps(t, zero, _CMP_GT_OQ)) == 0) {
      // t == 0 in every lane: s0 * 1 + s1 * 0 == s0, as the scalar kernel's shortcut.
      acc = s0;
    } else {
      Acc8 s1 = sample8(p, l1, u, v);
      const __m256 live = _mm256_cmp_ps(t, zero, _CMP_GT_OQ);
      s1.r = _mm256_and_ps(s1.r, live);
      s1.g = _mm256_and_ps(s1.g, live);
      s1.b = _mm256_and_ps(s1.b, live);
      s1.a = _mm256_and_ps(s1.a, live);
      const __m256 w0 = _mm256_sub_ps(one, t);
      acc.r = _mm256_add_ps(_mm256_mul_ps(s0.r, w0), _mm256_mul_ps(s1.r, t));
      acc.g = _mm256_add_ps(_mm256_mul_ps(s0.g, w0), _mm256_mul_ps(s1.g, t));
      acc.b = _mm256_add_ps(_mm256_mul_ps(s0.b, w0), _mm256_mul_ps(s1.b, t));
      acc.a = _mm256_add_ps(_mm256_mul_ps(s0.a, w0), _mm256_mul_ps(s1.a, t));
    }
    acc.a = _mm256_and_ps(acc.a, terrain);
    const __m256 ok = _mm256_cmp_ps(acc.a, _mm256_set1_ps(127.5f), _CMP_GE_OQ);
    const __m256 inv = _mm256_and_ps(_mm256_div_ps(one, acc.a), ok);
    const __m256i r = _mm256_cvttps_epi32(_mm256_add_ps(_mm256_mul_ps(_mm256_and_ps(acc.r, terrain), inv), half));
    const __m256i g = _mm256_cvttps_epi32(_mm256_add_ps(_mm256_mul_ps(_mm256_and_ps(acc.g, terrain), inv), half));
    const __m256i b = _mm256_cvttps_epi32(_mm256_add_ps(_mm256_mul_ps(_mm256_and_ps(acc.b, terrain), inv), half));
    // RGBX per pixel, then 12 bytes of RGB from each 128-bit half.
    const __m256i px = _mm256_or_si256(r, _mm256_or_si256(_mm256_slli_epi32(g, 8), _mm256_slli_epi32(b, 16)));
    store_rgb8_avx2(rgb + 3 * i, px);
    // Validity bytes: 0 / -1 per lane, narrowed to 8 bytes of 0 / 255.
    const __m256i v16 = _mm256_packs_epi32(_mm256_castps_si256(ok), _mm256_castps_si256(ok));
    const __m256i v8 = _mm256_packs_epi16(v16, v16);
    _mm_storel_epi64(reinterpret_cast<__m128i*>(valid + i),
                     _mm_unpacklo_epi32(_mm256_castsi256_si128(v8), _mm256_extracti128_si256(v8, 1)));
  }
  if (i < n) shade_row_scalar(n - i, wx + i, wy + i, log2fp + i, rgb + 3 * i, valid + i, p);
}

void resolve_row_avx2(int n, const int* ids, const float* coef, float dx0, float dy, float* wx, float* wy,
                      float* z, float* log2fp) {
  const __m256 lane = _mm256_setr_ps(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256 one = _mm256_set1_ps(1.0f), nan = _mm256_set1_ps(NAN), zero = _mm256_setzero_ps();
  const __m256 vdy = _mm256_set1_ps(dy);
  auto b = [](float v) { return _mm256_set1_ps(v); };
  int i = 0;
  for (; i + 8 <= n; i += 8) {
    const __m256i id = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(ids + i));
    const __m256 seen = _mm256_castsi256_ps(_mm256_cmpgt_epi32(id, _mm256_set1_epi32(-1)));
    const int seen_bits = _mm256_movemask_ps(seen);
    if (seen_bits == 0) {
      _mm256_storeu_ps(z + i, nan);
      _mm256_storeu_ps(wx + i, nan);
      _mm256_storeu_ps(wy + i, nan);
      _mm256_storeu_ps(log2fp + i, zero);
      continue;
    }
    // The planes of each lane's entry: one broadcast when the eight pixels see one triangle
    // (most of a frame), else gathered lane by lane.
    __m256 c[9];
    const bool one_entry = seen_bits == 0xff &&
        _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(id, _mm256_set1_epi32(ids[i])))) == 0xff;
    if (one_entry) {
      const float* ce = coef + 9 * static_cast<std::ptrdiff_t>(ids[i]);
      for (int k = 0; k < 9; ++k) c[k] = _mm256_set1_ps(ce[k]);
    } else {
      const __m256i idx = _mm256_add_epi32(_mm256_slli_epi32(id, 3), id);  // 9 e
      for (int k = 0; k < 9; ++k) c[k] = _mm256_mask_i32gather_ps(zero, coef + k, idx, seen, 4);
    }
    const __m256 dx = _mm256_add_ps(_mm256_set1_ps(dx0 + static_cast<float>(i)), lane);
    const __m256 iz = _mm256_add_ps(_mm256_add_ps(c[0], _mm256_mul_ps(c[2], vdy)), _mm256_mul_ps(c[1], dx));
    const __m256 zz = _mm256_div_ps(one, iz);
    const __m256 x = _mm256_mul_ps(_mm256_add_ps(_mm256_add_ps(c[3], _mm256_mul_ps(c[5], vdy)), _mm256_mul_ps(c[4], dx)), zz);
    const __m256 y = _mm256_mul_ps(_mm256_add_ps(_mm256_add_ps(c[6], _mm256_mul_ps(c[8], vdy)), _mm256_mul_ps(c[7], dx)), zz);
    const __m256 du_x = _mm256_mul_ps(_mm256_sub_ps(c[4], _mm256_mul_ps(x, c[1])), zz);
    const __m256 du_y = _mm256_mul_ps(_mm256_sub_ps(c[7], _mm256_mul_ps(y, c[1])), zz);
    const __m256 dv_x = _mm256_mul_ps(_mm256_sub_ps(c[5], _mm256_mul_ps(x, c[2])), zz);
    const __m256 dv_y = _mm256_mul_ps(_mm256_sub_ps(c[8], _mm256_mul_ps(y, c[2])), zz);
    const __m256 su = _mm256_add_ps(_mm256_mul_ps(du_x, du_x), _mm256_mul_ps(du_y, du_y));
    const __m256 sv = _mm256_add_ps(_mm256_mul_ps(dv_x, dv_x), _mm256_mul_ps(dv_y, dv_y));
    __m256 d2 = _mm256_blendv_ps(sv, su, _mm256_cmp_ps(su, sv, _CMP_GT_OQ));
    d2 = _mm256_blendv_ps(b(1e-12f), d2, _mm256_cmp_ps(d2, b(1e-12f), _CMP_GT_OQ));
    // fast_log2, lane-wise: exponent + quadratic in the mantissa, as in the scalar twin.
    const __m256i bits = _mm256_castps_si256(d2);
    const __m256 e = _mm256_cvtepi32_ps(_mm256_sub_epi32(_mm256_srli_epi32(bits, 23), _mm256_set1_epi32(127)));
    const __m256 m = _mm256_castsi256_ps(_mm256_or_si256(_mm256_and_si256(bits, _mm256_set1_epi32(0x7fffff)),
                                                         _mm256_set1_epi32(0x3f800000)));
    const __m256 poly = _mm256_sub_ps(_mm256_mul_ps(_mm256_add_ps(_mm256_mul_ps(b(-0.34484843f), m), b(2.02466578f)), m),
                                      b(0.67487759f));
    const __m256 l2 = _mm256_mul_ps(b(0.5f), _mm256_add_ps(e, poly));
    _mm256_storeu_ps(z + i, _mm256_blendv_ps(nan, zz, seen));
    _mm256_storeu_ps(wx + i, _mm256_blendv_ps(nan, x, seen));
    _mm256_storeu_ps(wy + i, _mm256_blendv_ps(nan, y, seen));
    _mm256_storeu_ps(log2fp + i, _mm256_blendv_ps(zero, l2, seen));
  }
  if (i < n) resolve_row_scalar(n - i, ids + i, coef, dx0 + static_cast<float>(i), dy, wx + i, wy + i, z + i, log2fp + i);
}

void depth_block_avx2(int w, int h, float base, float A, float B, int dx, int dy, float* z, int* id,
                      std::ptrdiff_t stride, int e) {
  const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256 ax = _mm256_mul_ps(_mm256_set1_ps(A), _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32(dx), lane)));
  const __m256i ve = _mm256_set1_epi32(e);
  if (w == 8) {  // the usual block: plain loads and stores
    for (int r = 0; r < h; ++r, z += stride, id += stride) {
      const __m256 iz = _mm256_add_ps(_mm256_set1_ps(base + B * static_cast<float>(dy + r)), ax);
      const __m256 old = _mm256_loadu_ps(z);
      const __m256 nearer = _mm256_cmp_ps(iz, old, _CMP_GT_OQ);
      _mm256_storeu_ps(z, _mm256_blendv_ps(old, iz, nearer));
      const __m256i oid = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(id));
      _mm256_storeu_si256(reinterpret_cast<__m256i*>(id), _mm256_blendv_epi8(oid, ve, _mm256_castps_si256(nearer)));
    }
    return;
  }
  const __m256i cols = _mm256_cmpgt_epi32(_mm256_set1_epi32(w), lane);
  for (int r = 0; r < h; ++r, z += stride, id += stride) {
    const __m256 iz = _mm256_add_ps(_mm256_set1_ps(base + B * static_cast<float>(dy + r)), ax);
    const __m256 old = _mm256_maskload_ps(z, cols);
    const __m256i nearer = _mm256_and_si256(_mm256_castps_si256(_mm256_cmp_ps(iz, old, _CMP_GT_OQ)), cols);
    _mm256_maskstore_ps(z, nearer, iz);
    _mm256_maskstore_epi32(id, nearer, ve);
  }
}

long edge_block_avx2(int w, int h, const std::int64_t* E, const std::int64_t* dEx, const std::int64_t* dEy, float base,
                     float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride, int e) {
  // Edge k at columns 0..3 and 4..7 of a row: row start + {0..3} dEx, + {4..7} dEx.
  __m256i step_lo[3], step_hi[3], row[3], down[3];
  for (int k = 0; k < 3; ++k) {
    const std::int64_t d = dEx[k];
    step_lo[k] = _mm256_setr_epi64x(0, d, 2 * d, 3 * d);
    step_hi[k] = _mm256_setr_epi64x(4 * d, 5 * d, 6 * d, 7 * d);
    row[k] = _mm256_set1_epi64x(E[k]);
    down[k] = _mm256_set1_epi64x(dEy[k]);
  }
  const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256i cols = _mm256_cmpgt_epi32(_mm256_set1_epi32(w), lane);
  const __m256 ax = _mm256_mul_ps(_mm256_set1_ps(A), _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32(dx), lane)));
  const __m256i ve = _mm256_set1_epi32(e), none = _mm256_set1_epi64x(-1);
  long covered = 0;
  for (int r = 0; r < h; ++r, z += stride, id += stride) {
    const __m256i lo = _mm256_or_si256(_mm256_or_si256(_mm256_add_epi64(row[0], step_lo[0]), _mm256_add_epi64(row[1], step_lo[1])),
                                       _mm256_add_epi64(row[2], step_lo[2]));
    const __m256i hi = _mm256_or_si256(_mm256_or_si256(_mm256_add_epi64(row[0], step_hi[0]), _mm256_add_epi64(row[1], step_hi[1])),
                                       _mm256_add_epi64(row[2], step_hi[2]));
    for (int k = 0; k < 3; ++k) row[k] = _mm256_add_epi64(row[k], down[k]);
    // All-ones 64-bit lanes where covered, packed to eight 32-bit lanes in column order.
    const __m256i in64_lo = _mm256_cmpgt_epi64(lo, none), in64_hi = _mm256_cmpgt_epi64(hi, none);
    const __m256i in = _mm256_and_si256(
        _mm256_permutevar8x32_epi32(_mm256_blend_epi32(in64_lo, _mm256_slli_epi64(in64_hi, 32), 0xAA),
                                    _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7)),
        cols);
    const int bits = _mm256_movemask_ps(_mm256_castsi256_ps(in));
    if (bits == 0) continue;
    covered += __builtin_popcount(static_cast<unsigned>(bits));
    depth_row(in, _mm256_add_ps(_mm256_set1_ps(base + B * static_cast<float>(dy + r)), ax), z, id, ve);
  }
  return covered;
}

long edge_block32_avx2(int w, int h, const std::int32_t* E, const std::int32_t* dEx, const std::int32_t* dEy, float base,
                       float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride, int e) {
  // Eight columns of edge k a row in one register; 32-bit lanes wrap, and wrapping is exact
  // for every value that fits (the caller's promise for the block's pixels).
  const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  __m256i row[3], down[3];
  for (int k = 0; k < 3; ++k) {
    row[k] = _mm256_add_epi32(_mm256_set1_epi32(E[k]), _mm256_mullo_epi32(_mm256_set1_epi32(dEx[k]), lane));
    down[k] = _mm256_set1_epi32(dEy[k]);
  }
  const __m256i cols = _mm256_cmpgt_epi32(_mm256_set1_epi32(w), lane);
  const __m256 ax = _mm256_mul_ps(_mm256_set1_ps(A), _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32(dx), lane)));
  const __m256i ve = _mm256_set1_epi32(e), none = _mm256_set1_epi32(-1);
  long covered = 0;
  for (int r = 0; r < h; ++r, z += stride, id += stride) {
    const __m256i any = _mm256_or_si256(_mm256_or_si256(row[0], row[1]), row[2]);
    for (int k = 0; k < 3; ++k) row[k] = _mm256_add_epi32(row[k], down[k]);
    const __m256i in = _mm256_and_si256(_mm256_cmpgt_epi32(any, none), cols);  // all three >= 0
    const int bits = _mm256_movemask_ps(_mm256_castsi256_ps(in));
    if (bits == 0) continue;
    covered += __builtin_popcount(static_cast<unsigned>(bits));
    depth_row(in, _mm256_add_ps(_mm256_set1_ps(base + B * static_cast<float>(dy + r)), ax), z, id, ve);
  }
  return covered;
}

}  // namespace terralign::raster
