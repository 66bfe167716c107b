// AVX2 build of the shading kernels: 8 pixels a vector, the filter of shade_kernels.hpp in
// 16-bit lanes (R and B words, G and A words of each pixel's 32 bits), so the output matches
// shade_scalar.cpp bit for bit. Where a vector's lanes share a level (most vectors), its
// texels come from row loads and permutes where its taps lie in a window of a few texel rows
// and 8 columns (window_taps), from gathers elsewhere. A row's tail (n % 8) runs the scalar
// kernel. Also the AVX2 depth and edge kernels.
#include <terralign/raster/shade_kernels.hpp>

#include <cmath>
#include <cstring>

#include <immintrin.h>

#include "edge_avx2.hpp"
#include "pack_avx2.hpp"

namespace terralign::raster {
namespace {

#define TL_INLINE inline __attribute__((always_inline))

// A row window holds the taps of lanes spread over at most this many texel rows.
constexpr int kWindowRows = 6;

// A vector seeing more runs of triangles than this gathers its planes lane by lane.
constexpr int kBlendRuns = 2;

struct Taps {
  __m256i t00, t10, t01, t11;  // top-left, top-right, bottom-left, bottom-right
};

// A sample's channels in the filter's fixed point: R|B and G|A word pairs, x128.
struct Sample8 {
  __m256i rb, ga;
};

TL_INLINE __m256i lerp15(__m256i a, __m256i b, __m256i f) {
  return _mm256_add_epi16(a, _mm256_mulhrs_epi16(_mm256_sub_epi16(b, a), f));
}

TL_INLINE Sample8 lerp_row(__m256i left, __m256i right, __m256i fx) {
  const __m256i m = _mm256_set1_epi32(0x7F807F80);
  // R, B of each texel at bits 7-14 and 23-30 (t << 7); G, A likewise (t >> 1).
  const __m256i rb_l = _mm256_and_si256(_mm256_slli_epi32(left, 7), m), rb_r = _mm256_and_si256(_mm256_slli_epi32(right, 7), m);
  const __m256i ga_l = _mm256_and_si256(_mm256_srli_epi32(left, 1), m), ga_r = _mm256_and_si256(_mm256_srli_epi32(right, 1), m);
  return {lerp15(rb_l, rb_r, fx), lerp15(ga_l, ga_r, fx)};
}

// Neighbouring pixels mostly read neighbouring texels. When the 8 lanes' taps (x0 .. x0 + 1,
// y0 .. y0 + 1, all inside level L) lie in at most kWindowRows texel rows and 8 columns, each
// row of the window is one masked load and each lane picks its taps with permutes: the
// texels the gathers would fetch. The lanes at the ends give the box (a row of pixels over
// terrain maps to a curve whose extremes are mostly at its ends), and every lane is checked
// to be inside it. Returns false, having read nothing, when the taps do not fit.
TL_INLINE bool window_taps(const MipLevel& L, const int* texels, __m256i x0, __m256i y0, Taps& t) {
  // Most often (a row of pixels along a texel row, magnified) every lane's taps lie in one
  // pair of texel rows and 8 columns: one plain load a row (the 8 columns inside it).
  const __m256i y_first = _mm256_broadcastd_epi32(_mm256_castsi256_si128(y0));
  const __m256i x_least = _mm256_min_epi32(_mm256_broadcastd_epi32(_mm256_castsi256_si128(x0)),
                                           _mm256_permutevar8x32_epi32(x0, _mm256_set1_epi32(7)));
  const __m256i cx = _mm256_sub_epi32(x0, x_least);
  const __m256i six = _mm256_set1_epi32(6);
  const __m256i one_row = _mm256_and_si256(_mm256_cmpeq_epi32(y0, y_first), _mm256_cmpeq_epi32(_mm256_max_epu32(cx, six), six));
  if (_mm256_movemask_epi8(one_row) == -1) {
    const int xlo = _mm256_cvtsi256_si32(x_least);
    if (xlo <= L.width - 8) {
      const int* row = texels + L.offset + _mm256_cvtsi256_si32(y0) * L.width + xlo;
      const __m256i top = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(row));
      const __m256i bottom = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(row + L.width));
      const __m256i cx1 = _mm256_add_epi32(cx, _mm256_set1_epi32(1));
      t.t00 = _mm256_permutevar8x32_epi32(top, cx);
      t.t10 = _mm256_permutevar8x32_epi32(top, cx1);
      t.t01 = _mm256_permutevar8x32_epi32(bottom, cx);
      t.t11 = _mm256_permutevar8x32_epi32(bottom, cx1);
      return true;
    }
  }
  const int xa = _mm256_cvtsi256_si32(x0), xb = _mm256_extract_epi32(x0, 7);
  const int ya = _mm256_cvtsi256_si32(y0), yb = _mm256_extract_epi32(y0, 7);
  const int xlo = xa < xb ? xa : xb, xspan = (xa < xb ? xb : xa) - xlo;
  const int ylo = ya < yb ? ya : yb, yspan = (ya < yb ? yb : ya) - ylo;
  if (xspan > 6 || yspan > kWindowRows - 2) return false;
  const __m256i dx = _mm256_sub_epi32(x0, _mm256_set1_epi32(xlo));
  const __m256i dy = _mm256_sub_epi32(y0, _mm256_set1_epi32(ylo));
  const __m256i xs = _mm256_set1_epi32(xspan), ys = _mm256_set1_epi32(yspan);
  // 0 <= d <= span, unsigned: max(d, span) == span.
  const __m256i in = _mm256_and_si256(_mm256_cmpeq_epi32(_mm256_max_epu32(dx, xs), xs),
                                      _mm256_cmpeq_epi32(_mm256_max_epu32(dy, ys), ys));
  if (_mm256_movemask_epi8(in) != -1) return false;
  // Columns xlo .. xlo + xspan + 1 of rows ylo .. ylo + yspan + 1 are inside the level (every
  // lane's taps are): the masked loads read only those.
  const int* row = texels + L.offset + ylo * L.width + xlo;
  const __m256i cols = _mm256_cmpgt_epi32(_mm256_set1_epi32(xspan + 2), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
  const __m256i dx1 = _mm256_add_epi32(dx, _mm256_set1_epi32(1));
  __m256i r0 = _mm256_maskload_epi32(row, cols);
  t.t00 = _mm256_permutevar8x32_epi32(r0, dx);
  t.t10 = _mm256_permutevar8x32_epi32(r0, dx1);
  if (yspan == 0) {  // one pair of rows for every lane (a row along a texel row)
    r0 = _mm256_maskload_epi32(row + L.width, cols);
    t.t01 = _mm256_permutevar8x32_epi32(r0, dx);
    t.t11 = _mm256_permutevar8x32_epi32(r0, dx1);
    return true;
  }
  // Row r gives the top taps of the lanes with dy = r and the bottom taps of those with dy + 1 = r.
  t.t01 = t.t11 = _mm256_setzero_si256();
  for (int r = 1; r <= yspan + 1; ++r) {
    row += L.width;
    r0 = _mm256_maskload_epi32(row, cols);
    const __m256i left = _mm256_permutevar8x32_epi32(r0, dx), right = _mm256_permutevar8x32_epi32(r0, dx1);
    const __m256i top = _mm256_cmpeq_epi32(dy, _mm256_set1_epi32(r));
    const __m256i bottom = _mm256_cmpeq_epi32(dy, _mm256_set1_epi32(r - 1));
    t.t00 = _mm256_blendv_epi8(t.t00, left, top);
    t.t10 = _mm256_blendv_epi8(t.t10, right, top);
    t.t01 = _mm256_blendv_epi8(t.t01, left, bottom);
    t.t11 = _mm256_blendv_epi8(t.t11, right, bottom);
  }
  return true;
}

// floor(c) of coordinates c in 256ths of a texel.
TL_INLINE __m256i fixed8(__m256 c) { return _mm256_cvttps_epi32(_mm256_floor_ps(c)); }

// (U & 255) << 7 in both 16-bit halves of each lane: the low byte moved to each word's high
// byte, then halved.
TL_INLINE __m256i fraction_pair(__m256i U) {
  const __m256i to_high = _mm256_setr_epi8(-1, 0, -1, 0, -1, 4, -1, 4, -1, 8, -1, 8, -1, 12, -1, 12,
                                           -1, 0, -1, 0, -1, 4, -1, 4, -1, 8, -1, 8, -1, 12, -1, 12);
  return _mm256_srli_epi16(_mm256_shuffle_epi8(U, to_high), 1);
}

// A vector's taps at one level and its texel coordinates in fixed point (for the fractions).
struct Fetched {
  Taps t;
  __m256i U, V;
};

// The taps of 8 lanes seeing world (x, y) at one level.
// Whether every lane's four taps (x0 .. x0 + 1, y0 .. y0 + 1) lie inside its level
// (0 <= x0 < w - 1 and 0 <= y0 < h - 1): most vectors.
TL_INLINE bool all_interior(__m256i x0, __m256i y0, __m256i wid, __m256i hei) {
  const __m256i zero = _mm256_setzero_si256(), ione = _mm256_set1_epi32(1);
  const __m256i interior = _mm256_andnot_si256(
      _mm256_or_si256(_mm256_cmpgt_epi32(zero, x0), _mm256_cmpgt_epi32(zero, y0)),
      _mm256_and_si256(_mm256_cmpgt_epi32(_mm256_sub_epi32(wid, ione), x0), _mm256_cmpgt_epi32(_mm256_sub_epi32(hei, ione), y0)));
  return _mm256_movemask_epi8(interior) == -1;
}

// Taps (x0 .. x0 + 1, y0 .. y0 + 1) by gathers from the levels whose first texel, width and
// height each lane's off, wid and hei give.
TL_INLINE void gather_taps(const int* texels, __m256i x0, __m256i y0, __m256i off, __m256i wid, __m256i hei, Taps& t) {
  const __m256i zero = _mm256_setzero_si256(), ione = _mm256_set1_epi32(1);
  if (all_interior(x0, y0, wid, hei)) {
    const __m256i row0 = _mm256_add_epi32(off, _mm256_add_epi32(_mm256_mullo_epi32(y0, wid), x0));
    const __m256i row1 = _mm256_add_epi32(row0, wid);
    t.t00 = _mm256_i32gather_epi32(texels, row0, 4);
    t.t10 = _mm256_i32gather_epi32(texels, _mm256_add_epi32(row0, ione), 4);
    t.t01 = _mm256_i32gather_epi32(texels, row1, 4);
    t.t11 = _mm256_i32gather_epi32(texels, _mm256_add_epi32(row1, ione), 4);
    return;
  }
  // Each tap clamped into the level for its fetch, and 0 where it lies outside.
  const __m256i wm1 = _mm256_sub_epi32(wid, ione), hm1 = _mm256_sub_epi32(hei, ione);
  auto tap = [&](int kx, int ky) {
    const __m256i tx = _mm256_add_epi32(x0, _mm256_set1_epi32(kx)), ty = _mm256_add_epi32(y0, _mm256_set1_epi32(ky));
    const __m256i in_x = _mm256_andnot_si256(_mm256_cmpgt_epi32(zero, tx), _mm256_cmpgt_epi32(wid, tx));
    const __m256i in_y = _mm256_andnot_si256(_mm256_cmpgt_epi32(zero, ty), _mm256_cmpgt_epi32(hei, ty));
    const __m256i xc = _mm256_min_epi32(_mm256_max_epi32(tx, zero), wm1), yc = _mm256_min_epi32(_mm256_max_epi32(ty, zero), hm1);
    const __m256i at = _mm256_add_epi32(off, _mm256_add_epi32(_mm256_mullo_epi32(yc, wid), xc));
    return _mm256_and_si256(_mm256_i32gather_epi32(texels, at, 4), _mm256_and_si256(in_x, in_y));
  };
  t.t00 = tap(0, 0);
  t.t10 = tap(1, 0);
  t.t01 = tap(0, 1);
  t.t11 = tap(1, 1);
}

TL_INLINE Fetched fetch8(const ShadeParams& p, int level, __m256 x, __m256 y) {
  const MipLevel& L = p.levels[level];
  const LevelCoords& k = p.coords[level];
  const int* texels = reinterpret_cast<const int*>(p.texels);
  Fetched f;
  f.U = fixed8(_mm256_add_ps(_mm256_add_ps(_mm256_set1_ps(k.a0), _mm256_mul_ps(_mm256_set1_ps(k.a1), x)),
                             _mm256_mul_ps(_mm256_set1_ps(k.a2), y)));
  f.V = fixed8(_mm256_add_ps(_mm256_add_ps(_mm256_set1_ps(k.b0), _mm256_mul_ps(_mm256_set1_ps(k.b1), x)),
                             _mm256_mul_ps(_mm256_set1_ps(k.b2), y)));
  const __m256i x0 = _mm256_srai_epi32(f.U, 8), y0 = _mm256_srai_epi32(f.V, 8);
  const __m256i wid = _mm256_set1_epi32(L.width), hei = _mm256_set1_epi32(L.height);
  if (!all_interior(x0, y0, wid, hei) || !window_taps(L, texels, x0, y0, f.t))
    gather_taps(texels, x0, y0, _mm256_set1_epi32(L.offset), wid, hei, f.t);
  return f;
}

// A chain's levels (at most kMaxMipLevels, 16), one lane each in two vectors of eight: the
// per-level values that fetch8_lanes() picks by each lane's level.
struct LevelTable {
  __m256 a0[2], a1[2], a2[2], b0[2], b1[2], b2[2];
  __m256i off[2], wid[2], hei[2];
};

TL_INLINE LevelTable level_table(const ShadeParams& p) {
  LevelArrays a;
  level_arrays(p, a);
  const float (*c)[kMaxMipLevels] = a.coefficient;
  const std::int32_t (*d)[kMaxMipLevels] = a.level;
  LevelTable T;
  for (int h = 0; h < 2; ++h) {
    T.a0[h] = _mm256_load_ps(c[0] + 8 * h);
    T.a1[h] = _mm256_load_ps(c[1] + 8 * h);
    T.a2[h] = _mm256_load_ps(c[2] + 8 * h);
    T.b0[h] = _mm256_load_ps(c[3] + 8 * h);
    T.b1[h] = _mm256_load_ps(c[4] + 8 * h);
    T.b2[h] = _mm256_load_ps(c[5] + 8 * h);
    T.off[h] = _mm256_load_si256(reinterpret_cast<const __m256i*>(d[0] + 8 * h));
    T.wid[h] = _mm256_load_si256(reinterpret_cast<const __m256i*>(d[1] + 8 * h));
    T.hei[h] = _mm256_load_si256(reinterpret_cast<const __m256i*>(d[2] + 8 * h));
  }
  return T;
}

// fetch8() with each lane at its own level (a vector whose lanes straddle levels): the same
// coordinates and taps lane by lane, by gathers.
TL_INLINE Fetched fetch8_lanes(const ShadeParams& p, const LevelTable& T, __m256i level, __m256 x, __m256 y) {
  const __m256i high = _mm256_cmpgt_epi32(level, _mm256_set1_epi32(7));
  auto pick = [&](const __m256* v) {
    return _mm256_blendv_ps(_mm256_permutevar8x32_ps(v[0], level), _mm256_permutevar8x32_ps(v[1], level), _mm256_castsi256_ps(high));
  };
  auto pick_i = [&](const __m256i* v) {
    return _mm256_blendv_epi8(_mm256_permutevar8x32_epi32(v[0], level), _mm256_permutevar8x32_epi32(v[1], level), high);
  };
  Fetched f;
  f.U = fixed8(_mm256_add_ps(_mm256_add_ps(pick(T.a0), _mm256_mul_ps(pick(T.a1), x)), _mm256_mul_ps(pick(T.a2), y)));
  f.V = fixed8(_mm256_add_ps(_mm256_add_ps(pick(T.b0), _mm256_mul_ps(pick(T.b1), x)), _mm256_mul_ps(pick(T.b2), y)));
  const __m256i x0 = _mm256_srai_epi32(f.U, 8), y0 = _mm256_srai_epi32(f.V, 8);
  gather_taps(reinterpret_cast<const int*>(p.texels), x0, y0, pick_i(T.off), pick_i(T.wid), pick_i(T.hei), f.t);
  return f;
}

// The bilinear sample of fetched taps.
TL_INLINE Sample8 filter8(const Fetched& f) {
  const __m256i fx = fraction_pair(f.U), fy = fraction_pair(f.V);
  const Sample8 top = lerp_row(f.t.t00, f.t.t10, fx), bottom = lerp_row(f.t.t01, f.t.t11, fx);
  return {lerp15(top.rb, bottom.rb, fy), lerp15(top.ga, bottom.ga, fy)};
}

// The colour and validity of 8 pixels' samples (zero where no terrain): 24 bytes of RGB and
// 8 validity bytes.
TL_INLINE void output8(Sample8 s, std::uint8_t* rgb, std::uint8_t* valid) {
  const __m256i sa = _mm256_srli_epi32(s.ga, 16);
  const __m256i ok = _mm256_cmpgt_epi32(sa, _mm256_set1_epi32(16319));
  const __m256i opaque = _mm256_cmpeq_epi32(sa, _mm256_set1_epi32(32640));
  __m256i px;
  if (_mm256_testz_si256(ok, _mm256_xor_si256(ok, opaque))) {
    // (S + 64) >> 7 in every word; the R|B and G|A words interleave into RGBA bytes.
    const __m256i r64 = _mm256_set1_epi16(64);
    const __m256i rb = _mm256_srli_epi16(_mm256_add_epi16(s.rb, r64), 7);
    const __m256i ga = _mm256_srli_epi16(_mm256_add_epi16(s.ga, r64), 7);
    px = _mm256_and_si256(_mm256_or_si256(rb, _mm256_slli_epi16(ga, 8)), ok);
  } else {
    // Some lanes partly transparent: c = min(255, (int)(float(S_c * 255) / float(S_a) + 0.5)).
    const __m256 fa = _mm256_cvtepi32_ps(sa);
    const __m256i lo = _mm256_set1_epi32(0xFFFF), c255 = _mm256_set1_epi32(255);
    auto channel = [&](__m256i sc) {
      const __m256 q = _mm256_div_ps(_mm256_cvtepi32_ps(_mm256_mullo_epi32(sc, c255)), fa);
      return _mm256_min_epi32(_mm256_cvttps_epi32(_mm256_add_ps(q, _mm256_set1_ps(0.5f))), c255);
    };
    const __m256i r = channel(_mm256_and_si256(s.rb, lo)), g = channel(_mm256_and_si256(s.ga, lo));
    const __m256i b = channel(_mm256_srli_epi32(s.rb, 16));
    px = _mm256_and_si256(_mm256_or_si256(r, _mm256_or_si256(_mm256_slli_epi32(g, 8), _mm256_slli_epi32(b, 16))), ok);
  }
  store_rgb8_avx2(rgb, px);
  // Validity bytes: 0 / -1 per lane, narrowed to 8 bytes of 0 / 255.
  const __m256i v16 = _mm256_packs_epi32(ok, ok);
  const __m256i v8 = _mm256_packs_epi16(v16, v16);
  _mm_storel_epi64(reinterpret_cast<__m128i*>(valid), _mm_unpacklo_epi32(_mm256_castsi256_si128(v8), _mm256_extracti128_si256(v8, 1)));
}

// Up to kChunkVectors vectors of a row processed together.
constexpr int kChunkVectors = 8;

// Lanes' level pairs: l0 and the 15-bit fraction t (in both halves of each lane), and the
// least and greatest l0 of the lanes with terrain.
struct Levels8 {
  __m256i l0, t;
  int lo, hi;
};

// pixel_level() lane by lane, the same operations.
TL_INLINE Levels8 levels8(const ShadeParams& p, __m256 log2fp, __m256 terrain) {
  const __m256 zero = _mm256_setzero_ps(), ftop = _mm256_set1_ps(static_cast<float>(p.n_levels - 1));
  __m256 lod = _mm256_add_ps(log2fp, _mm256_set1_ps(p.lod_bias));
  lod = _mm256_blendv_ps(zero, lod, _mm256_cmp_ps(lod, zero, _CMP_GT_OQ));  // NaN -> 0
  lod = _mm256_blendv_ps(ftop, lod, _mm256_cmp_ps(lod, ftop, _CMP_LT_OQ));
  Levels8 v;
  v.l0 = _mm256_cvttps_epi32(lod);  // lod >= 0: truncation is floor
  const __m256i t = _mm256_min_epi32(
      _mm256_cvttps_epi32(_mm256_mul_ps(_mm256_sub_ps(lod, _mm256_cvtepi32_ps(v.l0)), _mm256_set1_ps(32768.0f))),
      _mm256_set1_epi32(32767));
  v.t = _mm256_or_si256(t, _mm256_slli_epi32(t, 16));
  const int bits = _mm256_movemask_ps(terrain);
  alignas(32) int l[8];
  _mm256_store_si256(reinterpret_cast<__m256i*>(l), v.l0);
  v.lo = v.hi = bits ? l[__builtin_ctz(static_cast<unsigned>(bits))] : 0;
  const int same = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(v.l0, _mm256_set1_epi32(v.lo))));
  if ((bits & ~same) != 0)
    for (int k = 0; k < 8; ++k)
      if (bits >> k & 1) {
        v.lo = l[k] < v.lo ? l[k] : v.lo;
        v.hi = l[k] > v.hi ? l[k] : v.hi;
      }
  return v;
}

// Shades `vectors` consecutive vectors of one layer: vector v's pixels see world (x[v], y[v])
// where terrain[v] is all ones, with footprints log2fp[v], or level 0 where their entries'
// bounds bound[v] (if given) say the layer is magnified (entry_magnified()). Each step is taken for every
// vector before the next: a vector's work is one long chain (coordinates, the window's
// bounds, its loads, the filter, the packing), and the vectors' chains are independent, so
// the core overlaps them instead of waiting on each.
TL_INLINE void shade_chunk(const ShadeParams& p, int vectors, const __m256* x, const __m256* y, const __m256* log2fp,
                           const __m256* terrain, const __m256* bound, std::uint8_t* rgb, std::uint8_t* valid) {
  const int top = p.n_levels - 1;
  Fetched f[kChunkVectors];
  // Every lane over terrain whose entry's bound shows the layer magnified: level 0 alone, in
  // two loops that take the level's parameters once (as the AVX-512 build's).
  bool level0 = bound != nullptr;
  for (int v = 0; v < vectors && level0; ++v)
    level0 = _mm256_movemask_ps(_mm256_and_ps(
                 terrain[v], _mm256_cmp_ps(_mm256_add_ps(bound[v], _mm256_set1_ps(p.lod_bias)), _mm256_setzero_ps(), _CMP_LE_OQ))) == 0xFF;
  if (level0) {
    for (int v = 0; v < vectors; ++v) f[v] = fetch8(p, 0, x[v], y[v]);
    for (int v = 0; v < vectors; ++v) output8(filter8(f[v]), rgb + 24 * v, valid + 8 * v);
    return;
  }
  __m256 xs[kChunkVectors], ys[kChunkVectors];
  Levels8 lv[kChunkVectors];
  LevelTable table;
  bool have_table = false;
  Sample8 s[kChunkVectors];
  bool any[kChunkVectors];
  // Lanes without terrain compute on (0, 0) and are cleared at the end.
  for (int v = 0; v < vectors; ++v) {
    any[v] = _mm256_movemask_ps(terrain[v]) != 0;
    xs[v] = _mm256_and_ps(x[v], terrain[v]);
    ys[v] = _mm256_and_ps(y[v], terrain[v]);
    const __m256 magnified =
        bound ? _mm256_and_ps(terrain[v], _mm256_cmp_ps(_mm256_add_ps(bound[v], _mm256_set1_ps(p.lod_bias)), _mm256_setzero_ps(), _CMP_LE_OQ))
              : _mm256_setzero_ps();
    if (_mm256_movemask_ps(magnified) == _mm256_movemask_ps(terrain[v]))  // every lane at level 0 alone
      lv[v] = {_mm256_setzero_si256(), _mm256_setzero_si256(), 0, 0};
    else
      lv[v] = levels8(p, _mm256_blendv_ps(log2fp[v], _mm256_set1_ps(-INFINITY), magnified), terrain[v]);
    s[v] = {_mm256_setzero_si256(), _mm256_setzero_si256()};
  }
  // Vectors whose lanes share a level (most): that level's sample for all lanes ...
  for (int v = 0; v < vectors; ++v)
    if (any[v] && lv[v].lo == lv[v].hi) f[v] = fetch8(p, lv[v].lo, xs[v], ys[v]);
  for (int v = 0; v < vectors; ++v)
    if (any[v] && lv[v].lo == lv[v].hi) s[v] = filter8(f[v]);
  for (int v = 0; v < vectors; ++v) {
    if (!any[v]) continue;
    const Levels8& l = lv[v];
    if (l.lo == l.hi) {
      // ... and the next level's, lerped in by each lane's fraction (a lane's fraction of 0
      // keeps the first sample exactly).
      if (_mm256_testz_si256(_mm256_and_si256(l.t, _mm256_castps_si256(terrain[v])), l.t)) continue;
      const Sample8 s1 = filter8(fetch8(p, l.lo < top ? l.lo + 1 : top, xs[v], ys[v]));
      s[v] = {lerp15(s[v].rb, s1.rb, l.t), lerp15(s[v].ga, s1.ga, l.t)};
      continue;
    }
    // Lanes at different levels: each lane's two, by gathers (one sample where no lane's
    // fraction needs the second).
    if (!have_table) {
      table = level_table(p);
      have_table = true;
    }
    const Sample8 s0 = filter8(fetch8_lanes(p, table, l.l0, xs[v], ys[v]));
    if (_mm256_testz_si256(_mm256_and_si256(l.t, _mm256_castps_si256(terrain[v])), l.t)) {
      s[v] = s0;
      continue;
    }
    const __m256i l1 = _mm256_min_epi32(_mm256_add_epi32(l.l0, _mm256_set1_epi32(1)), _mm256_set1_epi32(top));
    const Sample8 s1 = filter8(fetch8_lanes(p, table, l1, xs[v], ys[v]));
    s[v] = {lerp15(s0.rb, s1.rb, l.t), lerp15(s0.ga, s1.ga, l.t)};
  }
  for (int v = 0; v < vectors; ++v) {
    const __m256i in = _mm256_castps_si256(terrain[v]);
    output8({_mm256_and_si256(s[v].rb, in), _mm256_and_si256(s[v].ga, in)}, rgb + 24 * v, valid + 8 * v);
  }
}

// A vector's planes per lane: the column and row derivatives c[1], c[2], c[4], c[5], c[7],
// c[8], and each row's part summed, r0 = q0 + dq0/dy dy (r3, r6 likewise), formed in scalar,
// the same IEEE operation as lane by lane: iz = r0 + c1 dx, x z = r3 + c4 dx, y z = r6 + c7 dx.
struct Planes8 {
  __m256 r0, c1, c2, r3, c4, c5, r6, c7, c8, bound;
};

// The planes of the triangles the lanes in `seen` (bits) see: broadcast when it is one
// triangle (most vectors), else each triangle's blended into the lanes that see it.
TL_INLINE Planes8 planes8(__m256i id, unsigned seen, const int* ids, const float* coef, float dy) {
  auto row = [dy](const float* c, int q) { return c[3 * q] + c[3 * q + 2] * dy; };
  // Lanes where the entry changes from the lane before: runs of one triangle.
  const __m256i before = _mm256_blend_epi32(_mm256_permutevar8x32_epi32(id, _mm256_setr_epi32(0, 0, 1, 2, 3, 4, 5, 6)),
                                            _mm256_set1_epi32(-2), 1);
  const unsigned starts = seen & ~static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(id, before))));
  if (__builtin_popcount(starts) > kBlendRuns) {
    // Many small triangles: each lane gathers its entry's planes.
    const __m256 in = _mm256_castsi256_ps(_mm256_cmpgt_epi32(id, _mm256_set1_epi32(-1)));
    const __m256i at = _mm256_mullo_epi32(_mm256_and_si256(id, _mm256_castps_si256(in)), _mm256_set1_epi32(kPlaneFloats));
    auto g = [&](int k) { return _mm256_mask_i32gather_ps(_mm256_setzero_ps(), coef + k, at, in, 4); };
    const __m256 vdy = _mm256_set1_ps(dy);
    const __m256 c2 = g(2), c5 = g(5), c8 = g(8);
    return {_mm256_add_ps(g(0), _mm256_mul_ps(c2, vdy)), g(1), c2, _mm256_add_ps(g(3), _mm256_mul_ps(c5, vdy)), g(4), c5,
            _mm256_add_ps(g(6), _mm256_mul_ps(c8, vdy)), g(7), c8, g(9)};
  }
  const int e0 = ids[__builtin_ctz(seen)];
  const float* c = coef + kPlaneFloats * static_cast<std::ptrdiff_t>(e0);
  Planes8 P{_mm256_set1_ps(row(c, 0)), _mm256_set1_ps(c[1]), _mm256_set1_ps(c[2]),
            _mm256_set1_ps(row(c, 1)), _mm256_set1_ps(c[4]), _mm256_set1_ps(c[5]),
            _mm256_set1_ps(row(c, 2)), _mm256_set1_ps(c[7]), _mm256_set1_ps(c[8]),
            _mm256_set1_ps(c[9])};
  unsigned left = seen & ~static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(id, _mm256_set1_epi32(e0)))));
  while (left != 0) {
    const int e = ids[__builtin_ctz(left)];
    const __m256 these = _mm256_castsi256_ps(_mm256_cmpeq_epi32(id, _mm256_set1_epi32(e)));
    c = coef + kPlaneFloats * static_cast<std::ptrdiff_t>(e);
    auto put = [these](__m256& v, float value) { v = _mm256_blendv_ps(v, _mm256_set1_ps(value), these); };
    put(P.r0, row(c, 0));
    put(P.c1, c[1]);
    put(P.c2, c[2]);
    put(P.r3, row(c, 1));
    put(P.c4, c[4]);
    put(P.c5, c[5]);
    put(P.r6, row(c, 2));
    put(P.c7, c[7]);
    put(P.c8, c[8]);
    put(P.bound, c[9]);
    left &= ~static_cast<unsigned>(_mm256_movemask_ps(these));
  }
  return P;
}

// The planes of the vectors before, kept while they see one triangle (a row's vectors over a
// large triangle): the next vector wholly on that triangle takes them as they are.
struct RowPlanes {
  int entry = -1;  // the triangle P is broadcast from; -1: none
  Planes8 P{};
  TL_INLINE const Planes8& of(__m256i id, unsigned seen, const int* ids, const float* coef, float dy) {
    const bool one = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(id, _mm256_set1_epi32(ids[0])))) == 0xFF;
    if (one && ids[0] == entry && entry >= 0) return P;
    P = planes8(id, seen, ids, coef, dy);
    entry = one ? ids[0] : -1;
    return P;
  }
};

// plane_footprint_log2() lane by lane, the same operations, given x, y and z from the planes.
TL_INLINE __m256 footprint8(const Planes8& P, __m256 x, __m256 y, __m256 zz) {
  const __m256 du_x = _mm256_mul_ps(_mm256_sub_ps(P.c4, _mm256_mul_ps(x, P.c1)), zz);
  const __m256 du_y = _mm256_mul_ps(_mm256_sub_ps(P.c7, _mm256_mul_ps(y, P.c1)), zz);
  const __m256 dv_x = _mm256_mul_ps(_mm256_sub_ps(P.c5, _mm256_mul_ps(x, P.c2)), zz);
  const __m256 dv_y = _mm256_mul_ps(_mm256_sub_ps(P.c8, _mm256_mul_ps(y, P.c2)), zz);
  const __m256 su = _mm256_add_ps(_mm256_mul_ps(du_x, du_x), _mm256_mul_ps(du_y, du_y));
  const __m256 sv = _mm256_add_ps(_mm256_mul_ps(dv_x, dv_x), _mm256_mul_ps(dv_y, dv_y));
  const __m256 tiny = _mm256_set1_ps(1e-12f);
  __m256 d2 = _mm256_blendv_ps(sv, su, _mm256_cmp_ps(su, sv, _CMP_GT_OQ));
  d2 = _mm256_blendv_ps(tiny, d2, _mm256_cmp_ps(d2, tiny, _CMP_GT_OQ));
  // fast_log2: the exponent plus a quadratic in the mantissa.
  const __m256i bits = _mm256_castps_si256(d2);
  const __m256 e = _mm256_cvtepi32_ps(_mm256_sub_epi32(_mm256_srli_epi32(bits, 23), _mm256_set1_epi32(127)));
  const __m256 m = _mm256_castsi256_ps(_mm256_or_si256(_mm256_and_si256(bits, _mm256_set1_epi32(0x7fffff)),
                                                       _mm256_set1_epi32(0x3f800000)));
  const __m256 poly = _mm256_sub_ps(
      _mm256_mul_ps(_mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(-0.34484843f), m), _mm256_set1_ps(2.02466578f)), m),
      _mm256_set1_ps(1.67487759f));
  return _mm256_mul_ps(_mm256_set1_ps(0.5f), _mm256_add_ps(e, poly));
}

}  // namespace

void shade_row_avx2(int n, const float* wx, const float* wy, const float* log2fp,
                    std::uint8_t* rgb, std::uint8_t* valid, const ShadeParams& p) {
  __m256 x[kChunkVectors], y[kChunkVectors], l2[kChunkVectors], terrain[kChunkVectors];
  int i = 0;
  while (i + 8 <= n) {
    const int vectors = (n - i) / 8 < kChunkVectors ? (n - i) / 8 : kChunkVectors;
    for (int v = 0; v < vectors; ++v) {
      x[v] = _mm256_loadu_ps(wx + i + 8 * v);
      y[v] = _mm256_loadu_ps(wy + i + 8 * v);
      l2[v] = _mm256_loadu_ps(log2fp + i + 8 * v);
      terrain[v] = _mm256_cmp_ps(x[v], x[v], _CMP_ORD_Q);
    }
    shade_chunk(p, vectors, x, y, l2, terrain, nullptr, rgb + 3 * i, valid + i);
    i += 8 * vectors;
  }
  if (i < n) shade_row_scalar(n - i, wx + i, wy + i, log2fp + i, rgb + 3 * i, valid + i, p);
}

void resolve_shade_row_avx2(int n, const int* ids, const float* coef, float dx0, float dy, float* z, int n_targets,
                            const ShadeTarget* targets) {
  const __m256 lane = _mm256_setr_ps(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256 one = _mm256_set1_ps(1.0f), nan = _mm256_set1_ps(NAN);
  const float max_bias = max_lod_bias(n_targets, targets);
  // Chunks of up to kChunkVectors vectors: the chunk's resolve, then its shading.
  __m256 x[kChunkVectors], y[kChunkVectors], l2[kChunkVectors], in[kChunkVectors], bound[kChunkVectors];
  RowPlanes planes;
  int i = 0;
  while (i + 8 <= n) {
    const int vectors = (n - i) / 8 < kChunkVectors ? (n - i) / 8 : kChunkVectors;
    for (int v = 0; v < vectors; ++v) {
      const int at = i + 8 * v;
      const __m256i id = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(ids + at));
      in[v] = _mm256_castsi256_ps(_mm256_cmpgt_epi32(id, _mm256_set1_epi32(-1)));
      const unsigned seen = static_cast<unsigned>(_mm256_movemask_ps(in[v]));
      x[v] = y[v] = nan;
      l2[v] = _mm256_setzero_ps();
      bound[v] = _mm256_set1_ps(INFINITY);
      if (seen == 0) {
        _mm256_storeu_ps(z + at, nan);
        continue;
      }
      const Planes8& P = planes.of(id, seen, ids + at, coef, dy);
      // The scalar twin's operations in the same order, 8 lanes wide.
      const __m256 dx = _mm256_add_ps(_mm256_set1_ps(dx0 + static_cast<float>(at)), lane);
      const __m256 zz = _mm256_div_ps(one, _mm256_add_ps(P.r0, _mm256_mul_ps(P.c1, dx)));
      x[v] = _mm256_mul_ps(_mm256_add_ps(P.r3, _mm256_mul_ps(P.c4, dx)), zz);
      y[v] = _mm256_mul_ps(_mm256_add_ps(P.r6, _mm256_mul_ps(P.c7, dx)), zz);
      bound[v] = P.bound;
      const __m256 need = _mm256_cmp_ps(_mm256_add_ps(P.bound, _mm256_set1_ps(max_bias)), _mm256_setzero_ps(), _CMP_NLE_UQ);
      if (_mm256_movemask_ps(_mm256_and_ps(need, in[v])) != 0) l2[v] = footprint8(P, x[v], y[v], zz);
      _mm256_storeu_ps(z + at, _mm256_blendv_ps(nan, zz, in[v]));
    }
    for (int k = 0; k < n_targets; ++k)
      shade_chunk(*targets[k].params, vectors, x, y, l2, in, bound, targets[k].rgb + 3 * i, targets[k].valid + i);
    i += 8 * vectors;
  }
  if (i < n) {
    ShadeTarget rest[kMaxShadeTargets];
    for (int k = 0; k < n_targets; ++k) rest[k] = {targets[k].params, targets[k].rgb + 3 * i, targets[k].valid + i};
    resolve_shade_row_scalar(n - i, ids + i, coef, dx0 + static_cast<float>(i), dy, z + i, n_targets, rest);
  }
}

void depth_block_avx2(int w, int h, float base, float A, float B, int dx, int dy, float* z, int* id,
                      std::ptrdiff_t stride, int e) {
  const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256i ve = _mm256_set1_epi32(e);
  // Eight columns at a time, each group's A (dx + i) kept for every row.
  constexpr int kGroups = kDepthBlockMaxW / 8;
  __m256 ax[kGroups];
  __m256i cols[kGroups];
  const int groups = (w + 7) / 8;
  for (int g = 0; g < groups; ++g) {
    ax[g] = _mm256_mul_ps(_mm256_set1_ps(A), _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32(dx + 8 * g), lane)));
    cols[g] = _mm256_cmpgt_epi32(_mm256_set1_epi32(w - 8 * g), lane);
  }
  for (int r = 0; r < h; ++r, z += stride, id += stride) {
    const __m256 rowz = _mm256_set1_ps(base + B * static_cast<float>(dy + r));
    for (int g = 0; g < groups; ++g) depth_row(cols[g], _mm256_add_ps(rowz, ax[g]), z + 8 * g, id + 8 * g, ve);
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
  return edge_block32_avx2_inline(w, h, E, dEx, dEy, base, A, B, dx, dy, z, id, stride, e);
}

}  // namespace terralign::raster
