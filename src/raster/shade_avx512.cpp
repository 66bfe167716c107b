// AVX-512 (F, BW, VL) build of the shading kernels: 16 pixels a vector, the filter of
// shade_kernels.hpp in 16-bit lanes (R and B words, G and A words of each pixel's 32 bits), so
// the output matches shade_scalar.cpp bit for bit. Where a vector's lanes share a level (most
// vectors), its texels come from row loads and permutes where its taps lie in a window of a
// few texel rows and at most 32 columns, from gathers elsewhere. A row's tail (n % 16) of the
// plain shading runs the scalar kernel; of the fused resolve and shading, one vector whose
// lanes past the row see no terrain.
#include <terralign/raster/shade_kernels.hpp>

#include <immintrin.h>

#include <cmath>
#include <cstring>

namespace terralign::raster {
namespace {

#define TL_INLINE inline __attribute__((always_inline))

// A row window holds the taps of lanes spread over at most this many texel rows (a row of
// pixels along a texel row: 2; turned a little, or minified, a few more); beyond, gathers.
constexpr int kWindowRows = 6;

// A vector seeing more runs of triangles than this gathers its planes lane by lane.
constexpr int kBlendRuns = 2;

// The four taps of 16 lanes: top-left, top-right, bottom-left, bottom-right.
struct Taps {
  __m512i t00, t10, t01, t11;
};

// A sample's channels in the filter's fixed point: R|B and G|A word pairs, x128.
struct Sample16 {
  __m512i rb, ga;
};

TL_INLINE int lane0(__m512i v) { return _mm_cvtsi128_si32(_mm512_castsi512_si128(v)); }
TL_INLINE int lane15(__m512i v) { return _mm_extract_epi32(_mm512_extracti32x4_epi32(v, 3), 3); }

// floor(c) of coordinates c in 256ths of a texel.
TL_INLINE __m512i fixed8(__m512 c) { return _mm512_cvt_roundps_epi32(c, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC); }

// (U & 255) << 7 in both 16-bit halves of each lane: the low byte moved to each word's high
// byte, then halved.
TL_INLINE __m512i fraction_pair(__m512i U) {
  const __m512i to_high = _mm512_broadcast_i32x4(_mm_setr_epi8(-1, 0, -1, 0, -1, 4, -1, 4, -1, 8, -1, 8, -1, 12, -1, 12));
  return _mm512_srli_epi16(_mm512_shuffle_epi8(U, to_high), 1);
}

TL_INLINE __m512i lerp15(__m512i a, __m512i b, __m512i f) {
  return _mm512_add_epi16(a, _mm512_mulhrs_epi16(_mm512_sub_epi16(b, a), f));
}

// One row of taps lerped by the column fraction: (left, right) -> x128 word pairs.
TL_INLINE Sample16 lerp_row(__m512i left, __m512i right, __m512i fx) {
  const __m512i m = _mm512_set1_epi32(0x7F807F80);
  // R, B of each texel at bits 7-14 and 23-30 (t << 7); G, A likewise (t >> 1).
  const __m512i rb_l = _mm512_and_si512(_mm512_slli_epi32(left, 7), m), rb_r = _mm512_and_si512(_mm512_slli_epi32(right, 7), m);
  const __m512i ga_l = _mm512_and_si512(_mm512_srli_epi32(left, 1), m), ga_r = _mm512_and_si512(_mm512_srli_epi32(right, 1), m);
  return {lerp15(rb_l, rb_r, fx), lerp15(ga_l, ga_r, fx)};
}

// Row windows: when the lanes' taps (x0 .. x0 + 1, y0 .. y0 + 1, all inside level L) lie in at
// most kWindowRows texel rows and 32 columns, each row of the window is two masked loads and
// each lane picks its taps with permutes: the texels the gathers would fetch. The lanes at the
// ends give the box (a row of pixels over terrain maps to a curve whose extremes are mostly at
// its ends), and every lane is checked to be inside it. Returns false, having read nothing,
// when the taps do not fit.
TL_INLINE bool window_taps(const MipLevel& L, const int* texels, __m512i x0, __m512i y0, Taps& t) {
  // Most often (a row of pixels along a texel row, magnified) every lane's taps lie in one
  // pair of texel rows and 16 columns: one plain load a row (the 16 columns inside it) and a
  // single-source permute a tap, the bounds kept in vector registers.
  const __m512i y_first = _mm512_broadcastd_epi32(_mm512_castsi512_si128(y0));
  const __m512i x_least = _mm512_broadcastd_epi32(_mm512_castsi512_si128(_mm512_min_epi32(x0, _mm512_alignr_epi32(x0, x0, 15))));
  const __m512i cx = _mm512_sub_epi32(x0, x_least);
  if ((_mm512_cmpeq_epi32_mask(y0, y_first) & _mm512_cmple_epu32_mask(cx, _mm512_set1_epi32(14))) == 0xFFFF) {
    const int xlo = _mm_cvtsi128_si32(_mm512_castsi512_si128(x_least));
    if (xlo <= L.width - 16) {
      const int* row = texels + L.offset + lane0(y0) * L.width + xlo;
      const __m512i top = _mm512_loadu_si512(row), bottom = _mm512_loadu_si512(row + L.width);
      const __m512i cx1 = _mm512_add_epi32(cx, _mm512_set1_epi32(1));
      t.t00 = _mm512_permutexvar_epi32(cx, top);
      t.t10 = _mm512_permutexvar_epi32(cx1, top);
      t.t01 = _mm512_permutexvar_epi32(cx, bottom);
      t.t11 = _mm512_permutexvar_epi32(cx1, bottom);
      return true;
    }
  }
  const int xa = lane0(x0), xb = lane15(x0), ya = lane0(y0), yb = lane15(y0);
  const int xlo = xa < xb ? xa : xb, xspan = (xa < xb ? xb : xa) - xlo;
  const int ylo = ya < yb ? ya : yb, yspan = (ya < yb ? yb : ya) - ylo;
  if (xspan > 30 || yspan > kWindowRows - 2) return false;
  const __m512i dx = _mm512_sub_epi32(x0, _mm512_set1_epi32(xlo)), dy = _mm512_sub_epi32(y0, _mm512_set1_epi32(ylo));
  if ((_mm512_cmple_epu32_mask(dx, _mm512_set1_epi32(xspan)) & _mm512_cmple_epu32_mask(dy, _mm512_set1_epi32(yspan))) != 0xFFFF)
    return false;
  // Columns xlo .. xlo + xspan + 1 of rows ylo .. ylo + yspan + 1 are inside the level (every
  // lane's taps are): the masked loads read only those.
  const unsigned cols = static_cast<unsigned>(xspan) + 2;
  const __mmask16 m0 = static_cast<__mmask16>(cols >= 16 ? 0xFFFFu : (1u << cols) - 1);
  const __mmask16 m1 = static_cast<__mmask16>(cols <= 16 ? 0u : (1u << (cols - 16)) - 1);
  const int* row = texels + L.offset + ylo * L.width + xlo;
  const __m512i dx1 = _mm512_add_epi32(dx, _mm512_set1_epi32(1));
  auto load = [&](const int* r, __m512i& left, __m512i& right) {
    const __m512i a = _mm512_maskz_loadu_epi32(m0, r), b = _mm512_maskz_loadu_epi32(m1, r + 16);
    left = _mm512_permutex2var_epi32(a, dx, b);
    right = _mm512_permutex2var_epi32(a, dx1, b);
  };
  load(row, t.t00, t.t10);
  if (yspan == 0) {  // one pair of rows for every lane (a row along a texel row)
    load(row + L.width, t.t01, t.t11);
    return true;
  }
  // Row r gives the top taps of the lanes with dy = r and the bottom taps of those with dy + 1 = r.
  t.t01 = t.t11 = _mm512_setzero_si512();
  for (int r = 1; r <= yspan + 1; ++r) {
    row += L.width;
    __m512i left, right;
    load(row, left, right);
    const __mmask16 top = _mm512_cmpeq_epi32_mask(dy, _mm512_set1_epi32(r));
    const __mmask16 bottom = _mm512_cmpeq_epi32_mask(dy, _mm512_set1_epi32(r - 1));
    t.t00 = _mm512_mask_mov_epi32(t.t00, top, left);
    t.t10 = _mm512_mask_mov_epi32(t.t10, top, right);
    t.t01 = _mm512_mask_mov_epi32(t.t01, bottom, left);
    t.t11 = _mm512_mask_mov_epi32(t.t11, bottom, right);
  }
  return true;
}

// Each row's two taps are neighbours in memory: one 64-bit gather fetches both (half the
// elements of two 32-bit gathers), split into the left and the right tap.
TL_INLINE void gather_pair(const int* texels, __m512i at, __m512i& left, __m512i& right) {
  const long long* base = reinterpret_cast<const long long*>(texels);
  const __m512i q0 = _mm512_i32gather_epi64(_mm512_castsi512_si256(at), base, 4);
  const __m512i q1 = _mm512_i32gather_epi64(_mm512_extracti64x4_epi64(at, 1), base, 4);
  const __m512i even = _mm512_set_epi32(30, 28, 26, 24, 22, 20, 18, 16, 14, 12, 10, 8, 6, 4, 2, 0);
  left = _mm512_permutex2var_epi32(q0, even, q1);
  right = _mm512_permutex2var_epi32(q0, _mm512_add_epi32(even, _mm512_set1_epi32(1)), q1);
}

// A group's taps at one level and its texel coordinates in fixed point (for the fractions).
struct Fetched {
  Taps t;
  __m512i U, V;
};

// Taps (x0 .. x0 + 1, y0 .. y0 + 1) by gathers from the levels whose first texel, width and
// height each lane's off, wid and hei give; `interior`: the lanes whose four taps lie inside.
TL_INLINE void gather_taps(const int* texels, __m512i x0, __m512i y0, __m512i off, __m512i wid, __m512i hei,
                           __mmask16 interior, Taps& t) {
  if (interior == 0xFFFF) {
    const __m512i at = _mm512_add_epi32(off, _mm512_add_epi32(_mm512_mullo_epi32(y0, wid), x0));
    gather_pair(texels, at, t.t00, t.t10);
    gather_pair(texels, _mm512_add_epi32(at, wid), t.t01, t.t11);
    return;
  }
  // The pair starts at x0 clamped to [-1, width - 1] and the row is clamped into the level; a
  // tap outside the level reads as 0, whatever the pair fetched (the array has a guard texel
  // at each end, so the pair never leaves it).
  const __m512i zero = _mm512_setzero_si512(), ione = _mm512_set1_epi32(1);
  const __m512i wm1 = _mm512_sub_epi32(wid, ione), hm1 = _mm512_sub_epi32(hei, ione);
  const __m512i xp = _mm512_min_epi32(_mm512_max_epi32(x0, _mm512_set1_epi32(-1)), wm1);
  const __m512i x1 = _mm512_add_epi32(x0, ione), y1 = _mm512_add_epi32(y0, ione);
  const __mmask16 in_l = _mm512_cmplt_epu32_mask(x0, wid), in_r = _mm512_cmplt_epu32_mask(x1, wid);
  const __mmask16 in_t = _mm512_cmplt_epu32_mask(y0, hei), in_b = _mm512_cmplt_epu32_mask(y1, hei);
  const __m512i yt = _mm512_min_epi32(_mm512_max_epi32(y0, zero), hm1), yb = _mm512_min_epi32(_mm512_max_epi32(y1, zero), hm1);
  gather_pair(texels, _mm512_add_epi32(off, _mm512_add_epi32(_mm512_mullo_epi32(yt, wid), xp)), t.t00, t.t10);
  gather_pair(texels, _mm512_add_epi32(off, _mm512_add_epi32(_mm512_mullo_epi32(yb, wid), xp)), t.t01, t.t11);
  t.t00 = _mm512_maskz_mov_epi32(in_t & in_l, t.t00);
  t.t10 = _mm512_maskz_mov_epi32(in_t & in_r, t.t10);
  t.t01 = _mm512_maskz_mov_epi32(in_b & in_l, t.t01);
  t.t11 = _mm512_maskz_mov_epi32(in_b & in_r, t.t11);
}

// The taps of 16 lanes seeing world (x, y) at one level.
TL_INLINE Fetched fetch16(const ShadeParams& p, int level, __m512 x, __m512 y) {
  const MipLevel& L = p.levels[level];
  const LevelCoords& k = p.coords[level];
  const int* texels = reinterpret_cast<const int*>(p.texels);
  Fetched f;
  f.U = fixed8(_mm512_add_ps(_mm512_add_ps(_mm512_set1_ps(k.a0), _mm512_mul_ps(_mm512_set1_ps(k.a1), x)),
                             _mm512_mul_ps(_mm512_set1_ps(k.a2), y)));
  f.V = fixed8(_mm512_add_ps(_mm512_add_ps(_mm512_set1_ps(k.b0), _mm512_mul_ps(_mm512_set1_ps(k.b1), x)),
                             _mm512_mul_ps(_mm512_set1_ps(k.b2), y)));
  const __m512i x0 = _mm512_srai_epi32(f.U, 8), y0 = _mm512_srai_epi32(f.V, 8);
  // 0 <= x0 < width - 1 and 0 <= y0 < height - 1 unsigned: every lane's four taps inside.
  const __mmask16 interior = _mm512_cmplt_epu32_mask(x0, _mm512_set1_epi32(L.width - 1)) &
                             _mm512_cmplt_epu32_mask(y0, _mm512_set1_epi32(L.height - 1));
  if (interior != 0xFFFF || !window_taps(L, texels, x0, y0, f.t))
    gather_taps(texels, x0, y0, _mm512_set1_epi32(L.offset), _mm512_set1_epi32(L.width), _mm512_set1_epi32(L.height),
                interior, f.t);
  return f;
}

// A chain's levels (at most kMaxMipLevels, 16), one lane each: the per-level values that
// fetch16_lanes() picks by each lane's level.
struct LevelTable {
  __m512 a0, a1, a2, b0, b1, b2;
  __m512i off, wid, hei;
};

TL_INLINE LevelTable level_table(const ShadeParams& p) {
  LevelArrays a;
  level_arrays(p, a);
  const float (*c)[kMaxMipLevels] = a.coefficient;
  const std::int32_t (*d)[kMaxMipLevels] = a.level;
  return {_mm512_load_ps(c[0]), _mm512_load_ps(c[1]), _mm512_load_ps(c[2]), _mm512_load_ps(c[3]), _mm512_load_ps(c[4]),
          _mm512_load_ps(c[5]), _mm512_load_si512(d[0]), _mm512_load_si512(d[1]), _mm512_load_si512(d[2])};
}

// fetch16() with each lane at its own level (a vector whose lanes straddle levels): the same
// coordinates and taps lane by lane, by gathers.
TL_INLINE Fetched fetch16_lanes(const ShadeParams& p, const LevelTable& T, __m512i level, __m512 x, __m512 y) {
  const int* texels = reinterpret_cast<const int*>(p.texels);
  Fetched f;
  f.U = fixed8(_mm512_add_ps(_mm512_add_ps(_mm512_permutexvar_ps(level, T.a0), _mm512_mul_ps(_mm512_permutexvar_ps(level, T.a1), x)),
                             _mm512_mul_ps(_mm512_permutexvar_ps(level, T.a2), y)));
  f.V = fixed8(_mm512_add_ps(_mm512_add_ps(_mm512_permutexvar_ps(level, T.b0), _mm512_mul_ps(_mm512_permutexvar_ps(level, T.b1), x)),
                             _mm512_mul_ps(_mm512_permutexvar_ps(level, T.b2), y)));
  const __m512i x0 = _mm512_srai_epi32(f.U, 8), y0 = _mm512_srai_epi32(f.V, 8);
  const __m512i wid = _mm512_permutexvar_epi32(level, T.wid), hei = _mm512_permutexvar_epi32(level, T.hei);
  const __m512i ione = _mm512_set1_epi32(1);
  const __mmask16 interior = _mm512_cmplt_epu32_mask(x0, _mm512_sub_epi32(wid, ione)) &
                             _mm512_cmplt_epu32_mask(y0, _mm512_sub_epi32(hei, ione));
  gather_taps(texels, x0, y0, _mm512_permutexvar_epi32(level, T.off), wid, hei, interior, f.t);
  return f;
}

// The bilinear sample of fetched taps.
TL_INLINE Sample16 filter16(const Fetched& f) {
  const __m512i fx = fraction_pair(f.U), fy = fraction_pair(f.V);
  const Sample16 top = lerp_row(f.t.t00, f.t.t10, fx), bottom = lerp_row(f.t.t01, f.t.t11, fx);
  return {lerp15(top.rb, bottom.rb, fy), lerp15(top.ga, bottom.ga, fy)};
}

// The colour and validity of 16 pixels' samples (zero where no terrain): 48 bytes of RGB and
// 16 validity bytes.
TL_INLINE void output16(Sample16 s, std::uint8_t* rgb, std::uint8_t* valid) {
  const __m512i sa = _mm512_srli_epi32(s.ga, 16);
  const __mmask16 ok = _mm512_cmpge_epi32_mask(sa, _mm512_set1_epi32(16320));
  const __mmask16 opaque = _mm512_cmpeq_epi32_mask(sa, _mm512_set1_epi32(32640));
  __m512i px;
  if ((ok & ~opaque) == 0) {
    // (S + 64) >> 7 in every word; the R|B and G|A words interleave into RGBA bytes.
    const __m512i r64 = _mm512_set1_epi16(64);
    const __m512i rb = _mm512_srli_epi16(_mm512_add_epi16(s.rb, r64), 7);
    const __m512i ga = _mm512_srli_epi16(_mm512_add_epi16(s.ga, r64), 7);
    px = _mm512_maskz_mov_epi32(ok, _mm512_or_si512(rb, _mm512_slli_epi16(ga, 8)));
  } else {
    // Some lanes partly transparent: c = min(255, (int)(float(S_c * 255) / float(S_a) + 0.5)).
    const __m512 fa = _mm512_cvtepi32_ps(sa);
    const __m512i lo = _mm512_set1_epi32(0xFFFF), c255 = _mm512_set1_epi32(255);
    auto channel = [&](__m512i sc) {
      const __m512 q = _mm512_div_ps(_mm512_cvtepi32_ps(_mm512_mullo_epi32(sc, c255)), fa);
      return _mm512_min_epi32(_mm512_cvttps_epi32(_mm512_add_ps(q, _mm512_set1_ps(0.5f))), c255);
    };
    const __m512i r = channel(_mm512_and_si512(s.rb, lo)), g = channel(_mm512_and_si512(s.ga, lo));
    const __m512i b = channel(_mm512_srli_epi32(s.rb, 16));
    px = _mm512_maskz_mov_epi32(ok, _mm512_or_si512(r, _mm512_or_si512(_mm512_slli_epi32(g, 8), _mm512_slli_epi32(b, 16))));
  }
  // RGBX -> 48 bytes: each 128-bit lane packs its four pixels' 12 bytes, then the runs join.
  const __m512i pack = _mm512_broadcast_i32x4(_mm_setr_epi8(0, 1, 2, 4, 5, 6, 8, 9, 10, 12, 13, 14, -1, -1, -1, -1));
  const __m512i runs = _mm512_setr_epi32(0, 1, 2, 4, 5, 6, 8, 9, 10, 12, 13, 14, 0, 0, 0, 0);
  _mm512_mask_storeu_epi32(rgb, 0x0FFF, _mm512_permutexvar_epi32(runs, _mm512_shuffle_epi8(px, pack)));
  _mm_storeu_si128(reinterpret_cast<__m128i*>(valid), _mm_movm_epi8(ok));
}

// Up to kChunkGroups vectors of a row processed together (a 128-pixel tile row is eight).
constexpr int kChunkGroups = 8;

// Lanes' level pairs: l0 and the 15-bit fraction t (in both halves of each lane), and the
// least and greatest l0 of the lanes with terrain.
struct Levels16 {
  __m512i l0, t;
  int lo, hi;
};

// pixel_level() lane by lane, the same operations.
TL_INLINE Levels16 levels16(const ShadeParams& p, __m512 log2fp, __mmask16 terrain) {
  const __m512 zero = _mm512_setzero_ps(), ftop = _mm512_set1_ps(static_cast<float>(p.n_levels - 1));
  __m512 lod = _mm512_add_ps(log2fp, _mm512_set1_ps(p.lod_bias));
  lod = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(lod, zero, _CMP_GT_OQ), zero, lod);  // NaN -> 0
  lod = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(lod, ftop, _CMP_LT_OQ), ftop, lod);
  Levels16 v;
  v.l0 = _mm512_cvttps_epi32(lod);  // lod >= 0: truncation is floor
  const __m512i t = _mm512_min_epi32(
      _mm512_cvttps_epi32(_mm512_mul_ps(_mm512_sub_ps(lod, _mm512_cvtepi32_ps(v.l0)), _mm512_set1_ps(32768.0f))),
      _mm512_set1_epi32(32767));
  v.t = _mm512_or_si512(t, _mm512_slli_epi32(t, 16));
  v.lo = v.hi = terrain ? _mm_cvtsi128_si32(_mm512_castsi512_si128(_mm512_permutexvar_epi32(
                              _mm512_set1_epi32(__builtin_ctz(terrain)), v.l0)))
                        : 0;
  if (_mm512_mask_cmpneq_epi32_mask(terrain, v.l0, _mm512_set1_epi32(v.lo)) != 0) {
    v.lo = _mm512_mask_reduce_min_epi32(terrain, v.l0);
    v.hi = _mm512_mask_reduce_max_epi32(terrain, v.l0);
  }
  return v;
}

// Shades `groups` consecutive vectors of one layer: vector g's pixels see world (x[g], y[g])
// where terrain[g] is set, with footprints log2fp[g], or level 0 where their entries' bounds
// bound[g] (if given) say the layer is magnified (entry_magnified()). Each step is taken for every vector
// before the next: a vector's work is one long chain (coordinates, the window's bounds, its
// loads, the filter, the packing), and the vectors' chains are independent, so the core
// overlaps them instead of waiting on each.
TL_INLINE void shade_chunk(const ShadeParams& p, int groups, const __m512* x, const __m512* y, const __m512* log2fp,
                           const __mmask16* terrain, const __m512* bound, std::uint8_t* rgb, std::uint8_t* valid) {
  const int top = p.n_levels - 1;
  Fetched f[kChunkGroups], f1[kChunkGroups];
  // Every lane over terrain whose entry's bound shows the layer magnified (most chunks of
  // views from a few hundred metres): level 0 alone, in two loops that take the level's
  // parameters once and keep nothing else per vector. The general loops below give the same
  // bytes, 20 % slower on a nadir frame (they keep levels, samples and coordinates per vector).
  bool level0 = bound != nullptr;
  for (int g = 0; g < groups && level0; ++g)
    level0 = terrain[g] == 0xFFFF &&
             _mm512_cmp_ps_mask(_mm512_add_ps(bound[g], _mm512_set1_ps(p.lod_bias)), _mm512_setzero_ps(), _CMP_LE_OQ) == 0xFFFF;
  if (level0) {
    for (int g = 0; g < groups; ++g) f[g] = fetch16(p, 0, x[g], y[g]);
    for (int g = 0; g < groups; ++g) output16(filter16(f[g]), rgb + 48 * g, valid + 16 * g);
    return;
  }
  __m512 xs[kChunkGroups], ys[kChunkGroups];
  Levels16 lv[kChunkGroups];
  LevelTable table;
  bool have_table = false;
  Sample16 s[kChunkGroups];
  // Lanes without terrain compute on (0, 0) and are cleared at the end.
  for (int g = 0; g < groups; ++g) {
    xs[g] = _mm512_maskz_mov_ps(terrain[g], x[g]);
    ys[g] = _mm512_maskz_mov_ps(terrain[g], y[g]);
    const __mmask16 magnified =
        bound ? _mm512_mask_cmp_ps_mask(terrain[g], _mm512_add_ps(bound[g], _mm512_set1_ps(p.lod_bias)), _mm512_setzero_ps(), _CMP_LE_OQ)
              : 0;
    if (magnified == terrain[g])  // every lane at level 0 alone, no footprint needed
      lv[g] = {_mm512_setzero_si512(), _mm512_setzero_si512(), 0, 0};
    else
      lv[g] = levels16(p, _mm512_mask_mov_ps(log2fp[g], magnified, _mm512_set1_ps(-INFINITY)), terrain[g]);
    s[g] = {_mm512_setzero_si512(), _mm512_setzero_si512()};
  }
  // Each vector's first level for every lane: the vector's level where its lanes share one
  // (most), a row window or gathers; else each lane's own l0, by gathers. Then the second
  // level (l0 + 1) where some lane's fraction needs it (a fraction of 0 keeps the first sample
  // exactly). The fetches of all the vectors go first, each pass's gathers independent of one
  // another, and the filters after.
  bool second[kChunkGroups];
  for (int g = 0; g < groups; ++g) {
    second[g] = terrain[g] != 0 && _mm512_mask_test_epi32_mask(terrain[g], lv[g].t, lv[g].t) != 0;
    if (terrain[g] == 0) continue;
    if (lv[g].lo == lv[g].hi) {
      f[g] = fetch16(p, lv[g].lo, xs[g], ys[g]);
      continue;
    }
    if (!have_table) {
      table = level_table(p);
      have_table = true;
    }
    f[g] = fetch16_lanes(p, table, lv[g].l0, xs[g], ys[g]);
  }
  for (int g = 0; g < groups; ++g) {
    if (!second[g]) continue;
    const Levels16& l = lv[g];
    if (l.lo == l.hi)
      f1[g] = fetch16(p, l.lo < top ? l.lo + 1 : top, xs[g], ys[g]);
    else
      f1[g] = fetch16_lanes(p, table, _mm512_min_epi32(_mm512_add_epi32(l.l0, _mm512_set1_epi32(1)), _mm512_set1_epi32(top)),
                            xs[g], ys[g]);
  }
  for (int g = 0; g < groups; ++g) {
    if (terrain[g] == 0) continue;
    s[g] = filter16(f[g]);
    if (!second[g]) continue;
    const Sample16 s1 = filter16(f1[g]);
    s[g] = {lerp15(s[g].rb, s1.rb, lv[g].t), lerp15(s[g].ga, s1.ga, lv[g].t)};
  }
  for (int g = 0; g < groups; ++g)
    output16({_mm512_maskz_mov_epi32(terrain[g], s[g].rb), _mm512_maskz_mov_epi32(terrain[g], s[g].ga)},
             rgb + 48 * g, valid + 16 * g);
}

// A vector's planes per lane: the column and row derivatives c[1], c[2], c[4], c[5], c[7],
// c[8], and each row's part summed, r0 = q0 + dq0/dy dy (r3, r6 likewise), formed in scalar,
// the same IEEE operation as lane by lane: iz = r0 + c1 dx, x z = r3 + c4 dx, y z = r6 + c7 dx.
struct Planes16 {
  __m512 r0, c1, c2, r3, c4, c5, r6, c7, c8, bound;
};

// The planes of the triangles the lanes in `seen` see: broadcast when it is one triangle (most
// vectors), else each triangle's blended into the lanes that see it.
TL_INLINE Planes16 planes16(__m512i id, __mmask16 seen, const int* ids, const float* coef, float dy) {
  auto row = [dy](const float* c, int q) { return c[3 * q] + c[3 * q + 2] * dy; };
  // Lanes where the entry changes from the lane before: runs of one triangle.
  const __mmask16 starts = _mm512_mask_cmpneq_epi32_mask(seen, id, _mm512_alignr_epi32(id, _mm512_set1_epi32(-2), 15));
  if (__builtin_popcount(starts) > kBlendRuns) {
    // Many small triangles: each lane gathers its entry's planes.
    // Each lane's planes, two neighbouring floats a 64-bit element (half the elements of
    // 32-bit gathers), then split into the even and the odd one.
    const __m512i at = _mm512_mullo_epi32(_mm512_maskz_mov_epi32(seen, id), _mm512_set1_epi32(kPlaneFloats));
    const __m256i at_lo = _mm512_castsi512_si256(at), at_hi = _mm512_extracti64x4_epi64(at, 1);
    const __mmask8 seen_lo = static_cast<__mmask8>(seen), seen_hi = static_cast<__mmask8>(seen >> 8);
    const __m512i even = _mm512_set_epi32(30, 28, 26, 24, 22, 20, 18, 16, 14, 12, 10, 8, 6, 4, 2, 0);
    const __m512i odd = _mm512_add_epi32(even, _mm512_set1_epi32(1));
    __m512 c[kPlaneFloats];
    for (int k = 0; k < kPlaneFloats; k += 2) {
      const long long* base = reinterpret_cast<const long long*>(coef + k);
      const __m512i lo = _mm512_mask_i32gather_epi64(_mm512_setzero_si512(), seen_lo, at_lo, base, 4);
      const __m512i hi = _mm512_mask_i32gather_epi64(_mm512_setzero_si512(), seen_hi, at_hi, base, 4);
      c[k] = _mm512_castsi512_ps(_mm512_permutex2var_epi32(lo, even, hi));
      c[k + 1] = _mm512_castsi512_ps(_mm512_permutex2var_epi32(lo, odd, hi));
    }
    const __m512 vdy = _mm512_set1_ps(dy);
    return {_mm512_add_ps(c[0], _mm512_mul_ps(c[2], vdy)), c[1], c[2], _mm512_add_ps(c[3], _mm512_mul_ps(c[5], vdy)), c[4], c[5],
            _mm512_add_ps(c[6], _mm512_mul_ps(c[8], vdy)), c[7], c[8], c[9]};
  }
  const int e0 = ids[__builtin_ctz(seen)];
  const float* c = coef + kPlaneFloats * static_cast<std::ptrdiff_t>(e0);
  Planes16 P{_mm512_set1_ps(row(c, 0)), _mm512_set1_ps(c[1]), _mm512_set1_ps(c[2]),
             _mm512_set1_ps(row(c, 1)), _mm512_set1_ps(c[4]), _mm512_set1_ps(c[5]),
             _mm512_set1_ps(row(c, 2)), _mm512_set1_ps(c[7]), _mm512_set1_ps(c[8]),
             _mm512_set1_ps(c[9])};
  __mmask16 left = static_cast<__mmask16>(seen & ~_mm512_mask_cmpeq_epi32_mask(seen, id, _mm512_set1_epi32(e0)));
  while (left != 0) {
    const int e = ids[__builtin_ctz(left)];
    const __mmask16 these = _mm512_mask_cmpeq_epi32_mask(left, id, _mm512_set1_epi32(e));
    c = coef + kPlaneFloats * static_cast<std::ptrdiff_t>(e);
    auto put = [these](__m512& v, float value) { v = _mm512_mask_mov_ps(v, these, _mm512_set1_ps(value)); };
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
    left = static_cast<__mmask16>(left & ~these);
  }
  return P;
}

// The planes of the vectors before, kept while they see one triangle (a row's vectors over a
// large triangle): the next vector wholly on that triangle takes them as they are.
struct RowPlanes {
  int entry = -1;  // the triangle P is broadcast from; -1: none
  Planes16 P{};
  TL_INLINE const Planes16& of(__m512i id, __mmask16 seen, const int* ids, const float* coef, float dy) {
    const bool one = _mm512_cmpneq_epi32_mask(id, _mm512_set1_epi32(ids[0])) == 0;
    if (one && ids[0] == entry && entry >= 0) return P;
    P = planes16(id, seen, ids, coef, dy);
    entry = one ? ids[0] : -1;
    return P;
  }
};

// plane_footprint_log2() lane by lane, the same operations, given x, y and z from the planes.
TL_INLINE __m512 footprint16(const Planes16& P, __m512 x, __m512 y, __m512 zz) {
  const __m512 du_x = _mm512_mul_ps(_mm512_sub_ps(P.c4, _mm512_mul_ps(x, P.c1)), zz);
  const __m512 du_y = _mm512_mul_ps(_mm512_sub_ps(P.c7, _mm512_mul_ps(y, P.c1)), zz);
  const __m512 dv_x = _mm512_mul_ps(_mm512_sub_ps(P.c5, _mm512_mul_ps(x, P.c2)), zz);
  const __m512 dv_y = _mm512_mul_ps(_mm512_sub_ps(P.c8, _mm512_mul_ps(y, P.c2)), zz);
  const __m512 su = _mm512_add_ps(_mm512_mul_ps(du_x, du_x), _mm512_mul_ps(du_y, du_y));
  const __m512 sv = _mm512_add_ps(_mm512_mul_ps(dv_x, dv_x), _mm512_mul_ps(dv_y, dv_y));
  const __m512 tiny = _mm512_set1_ps(1e-12f);
  __m512 d2 = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(su, sv, _CMP_GT_OQ), sv, su);
  d2 = _mm512_mask_blend_ps(_mm512_cmp_ps_mask(d2, tiny, _CMP_GT_OQ), tiny, d2);
  // fast_log2: the exponent plus a quadratic in the mantissa.
  const __m512i bits = _mm512_castps_si512(d2);
  const __m512 e = _mm512_cvtepi32_ps(_mm512_sub_epi32(_mm512_srli_epi32(bits, 23), _mm512_set1_epi32(127)));
  const __m512 m = _mm512_castsi512_ps(_mm512_or_si512(_mm512_and_si512(bits, _mm512_set1_epi32(0x7fffff)),
                                                       _mm512_set1_epi32(0x3f800000)));
  const __m512 poly = _mm512_sub_ps(
      _mm512_mul_ps(_mm512_add_ps(_mm512_mul_ps(_mm512_set1_ps(-0.34484843f), m), _mm512_set1_ps(2.02466578f)), m),
      _mm512_set1_ps(1.67487759f));
  return _mm512_mul_ps(_mm512_set1_ps(0.5f), _mm512_add_ps(e, poly));
}

}  // namespace

void shade_row_avx512(int n, const float* wx, const float* wy, const float* log2fp, std::uint8_t* rgb,
                      std::uint8_t* valid, const ShadeParams& p) {
  __m512 x[kChunkGroups], y[kChunkGroups], l2[kChunkGroups];
  __mmask16 terrain[kChunkGroups];
  int i = 0;
  while (i + 16 <= n) {
    const int groups = (n - i) / 16 < kChunkGroups ? (n - i) / 16 : kChunkGroups;
    for (int g = 0; g < groups; ++g) {
      x[g] = _mm512_loadu_ps(wx + i + 16 * g);
      y[g] = _mm512_loadu_ps(wy + i + 16 * g);
      l2[g] = _mm512_loadu_ps(log2fp + i + 16 * g);
      terrain[g] = _mm512_cmp_ps_mask(x[g], x[g], _CMP_ORD_Q);
    }
    shade_chunk(p, groups, x, y, l2, terrain, nullptr, rgb + 3 * i, valid + i);
    i += 16 * groups;
  }
  if (i < n) shade_row_scalar(n - i, wx + i, wy + i, log2fp + i, rgb + 3 * i, valid + i, p);
}

void resolve_shade_row_avx512(int n, const int* ids, const float* coef, float dx0, float dy, float* z, int n_targets,
                              const ShadeTarget* targets) {
  const __m512 lane = _mm512_setr_ps(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m512 one = _mm512_set1_ps(1.0f), nan = _mm512_set1_ps(NAN);
  const float max_bias = max_lod_bias(n_targets, targets);
  // Chunks of up to kChunkGroups vectors: the chunk's resolve, then its shading.
  __m512 x[kChunkGroups], y[kChunkGroups], l2[kChunkGroups], bound[kChunkGroups];
  __mmask16 seen[kChunkGroups];
  RowPlanes planes;
  int i = 0;
  while (i + 16 <= n) {
    const int groups = (n - i) / 16 < kChunkGroups ? (n - i) / 16 : kChunkGroups;
    for (int g = 0; g < groups; ++g) {
      const int at = i + 16 * g;
      const __m512i id = _mm512_loadu_si512(ids + at);
      seen[g] = _mm512_cmpgt_epi32_mask(id, _mm512_set1_epi32(-1));
      x[g] = y[g] = nan;
      l2[g] = _mm512_setzero_ps();
      bound[g] = _mm512_set1_ps(INFINITY);
      if (seen[g] == 0) {
        _mm512_storeu_ps(z + at, nan);
        continue;
      }
      const Planes16& P = planes.of(id, seen[g], ids + at, coef, dy);
      // The scalar twin's operations in the same order, 16 lanes wide.
      const __m512 dx = _mm512_add_ps(_mm512_set1_ps(dx0 + static_cast<float>(at)), lane);
      const __m512 zz = _mm512_div_ps(one, _mm512_add_ps(P.r0, _mm512_mul_ps(P.c1, dx)));
      x[g] = _mm512_mul_ps(_mm512_add_ps(P.r3, _mm512_mul_ps(P.c4, dx)), zz);
      y[g] = _mm512_mul_ps(_mm512_add_ps(P.r6, _mm512_mul_ps(P.c7, dx)), zz);
      bound[g] = P.bound;
      if (_mm512_mask_cmp_ps_mask(seen[g], _mm512_add_ps(P.bound, _mm512_set1_ps(max_bias)), _mm512_setzero_ps(), _CMP_NLE_UQ))
        l2[g] = footprint16(P, x[g], y[g], zz);
      _mm512_storeu_ps(z + at, _mm512_mask_blend_ps(seen[g], nan, zz));
    }
    for (int k = 0; k < n_targets; ++k)
      shade_chunk(*targets[k].params, groups, x, y, l2, seen, bound, targets[k].rgb + 3 * i, targets[k].valid + i);
    i += 16 * groups;
  }
  if (i < n) {
    // The last n - i (< 16) pixels as one vector (the scalar twin took as long for these as
    // for a 128-pixel row): lanes past the row see no terrain, the vector's results go to
    // scratch and the row's part is copied out.
    const int rest = n - i;
    alignas(64) int tail_ids[16];
    float tail_z[16];
    std::uint8_t tail_rgb[kMaxShadeTargets][48], tail_valid[kMaxShadeTargets][16];
    ShadeTarget tail[kMaxShadeTargets];
    for (int l = 0; l < 16; ++l) tail_ids[l] = l < rest ? ids[i + l] : -1;
    for (int k = 0; k < n_targets; ++k) tail[k] = {targets[k].params, tail_rgb[k], tail_valid[k]};
    resolve_shade_row_avx512(16, tail_ids, coef, dx0 + static_cast<float>(i), dy, tail_z, n_targets, tail);
    std::memcpy(z + i, tail_z, sizeof(float) * static_cast<std::size_t>(rest));
    for (int k = 0; k < n_targets; ++k) {
      std::memcpy(targets[k].rgb + 3 * i, tail_rgb[k], 3 * static_cast<std::size_t>(rest));
      std::memcpy(targets[k].valid + i, tail_valid[k], static_cast<std::size_t>(rest));
    }
  }
}

void depth_block_avx512(int w, int h, float base, float A, float B, int dx, int dy, float* z, int* id,
                        std::ptrdiff_t stride, int e) {
  // Sixteen columns at a time, masked to the block: each group's A (dx + i) kept for every row.
  const __m512 lane = _mm512_setr_ps(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m512i ve = _mm512_set1_epi32(e);
  constexpr int kGroups = kDepthBlockMaxW / 16;
  __m512 ax[kGroups];
  __mmask16 cols[kGroups];
  const int groups = (w + 15) / 16;
  for (int g = 0; g < groups; ++g) {
    ax[g] = _mm512_mul_ps(_mm512_set1_ps(A), _mm512_add_ps(_mm512_set1_ps(static_cast<float>(dx + 16 * g)), lane));
    const int n = w - 16 * g;
    cols[g] = static_cast<__mmask16>(n >= 16 ? 0xFFFF : (1u << n) - 1);
  }
  for (int r = 0; r < h; ++r, z += stride, id += stride) {
    const __m512 rowz = _mm512_set1_ps(base + B * static_cast<float>(dy + r));
    for (int g = 0; g < groups; ++g) {
      const __m512 iz = _mm512_add_ps(rowz, ax[g]);
      const __mmask16 nearer = _mm512_mask_cmp_ps_mask(cols[g], iz, _mm512_maskz_loadu_ps(cols[g], z + 16 * g), _CMP_GT_OQ);
      _mm512_mask_storeu_ps(z + 16 * g, nearer, iz);
      _mm512_mask_storeu_epi32(id + 16 * g, nearer, ve);
    }
  }
}

}  // namespace terralign::raster
