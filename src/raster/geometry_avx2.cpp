// The AVX2 builds of the geometry kernels (geometry_kernels.hpp): the vertex stage, eight
// posts a vector (a row's last post by the scalar build); the triangle set-up, four quads'
// first triangles in one set of vectors and their second in another (the planes in four
// doubles a vector), the kept ones copied out lane by lane in quad order; the set-up of a
// tile's entries eight at a time (two halves of a batch of 16) from their transposed
// triangles; and the drawing of a run of small entries through the inlined 32-bit edge kernel
// (which the AVX-512 renderer uses too). Each step is the scalar build's operation lane by
// lane, in its order (the raster target says -ffp-contract=off: -mfma fuses nothing), so the
// results are the scalar kernels' bit for bit.
#include <terralign/raster/geometry_kernels.hpp>

#include <immintrin.h>

#include <cmath>

#include "edge_avx2.hpp"
#include "quad_row4.hpp"

namespace terralign::raster {
namespace {

// rows[i] <- column i of the 8 x 8 matrix of 32-bit elements whose row j is rows[j].
inline void transpose8(__m256i* rows) {
  __m256i t[8], u[8];
  for (int i = 0; i < 4; ++i) {
    t[2 * i] = _mm256_unpacklo_epi32(rows[2 * i], rows[2 * i + 1]);
    t[2 * i + 1] = _mm256_unpackhi_epi32(rows[2 * i], rows[2 * i + 1]);
  }
  for (int i = 0; i < 2; ++i) {
    u[4 * i] = _mm256_unpacklo_epi64(t[4 * i], t[4 * i + 2]);
    u[4 * i + 1] = _mm256_unpackhi_epi64(t[4 * i], t[4 * i + 2]);
    u[4 * i + 2] = _mm256_unpacklo_epi64(t[4 * i + 1], t[4 * i + 3]);
    u[4 * i + 3] = _mm256_unpackhi_epi64(t[4 * i + 1], t[4 * i + 3]);
  }
  // 128-bit lane L of u[4 i + j] holds column 4 L + j of rows 4 i .. 4 i + 3.
  for (int j = 0; j < 4; ++j) {
    rows[j] = _mm256_permute2x128_si256(u[j], u[4 + j], 0x20);
    rows[4 + j] = _mm256_permute2x128_si256(u[j], u[4 + j], 0x31);
  }
}

// (C + A dx) + B dy in double, four lanes at a time, then float.
inline __m256 plane_at_corner(__m256 C, __m256 A, __m256 B, __m256i dx, __m256i dy) {
  __m128 half[2];
  for (int h = 0; h < 2; ++h) {
    auto pd = [h](__m256 v) { return _mm256_cvtps_pd(h ? _mm256_extractf128_ps(v, 1) : _mm256_castps256_ps128(v)); };
    auto pi = [h](__m256i v) { return _mm256_cvtepi32_pd(h ? _mm256_extracti128_si256(v, 1) : _mm256_castsi256_si128(v)); };
    const __m256d c_plus_a = _mm256_add_pd(pd(C), _mm256_mul_pd(pd(A), pi(dx)));
    half[h] = _mm256_cvtpd_ps(_mm256_add_pd(c_plus_a, _mm256_mul_pd(pd(B), pi(dy))));
  }
  return _mm256_set_m128(half[1], half[0]);
}

// Entries 8 h .. 8 h + 7 of a batch (those below n).
inline void setup_half(const Tri* tris, const int* ids, int n, int h, int x0, int y0, int x1, int y1, int vw, int vh,
                       EntrySetup& s, float* coef) {
  const int e0 = 8 * h, m = n - e0 < 8 ? n - e0 : 8;
  // The triangles' fields 0-7 and 8-15, one triangle a row, then one field a row.
  __m256i lo[8], hi[8];
  for (int i = 0; i < 8; ++i) {
    const auto* t = reinterpret_cast<const __m256i*>(&tris[ids[e0 + (i < m ? i : 0)]]);
    lo[i] = _mm256_loadu_si256(t);
    hi[i] = _mm256_loadu_si256(t + 1);
  }
  transpose8(lo);
  transpose8(hi);
  const __m256i X[3] = {lo[0], lo[1], lo[2]}, Y[3] = {lo[3], lo[4], lo[5]};
  const __m256i A[3] = {lo[6], lo[7], hi[0]}, B[3] = {hi[1], hi[2], hi[3]}, C[3] = {hi[4], hi[5], hi[6]};
  const __m256i half_up = _mm256_set1_epi32((1 << kSubBits) - 1), zero = _mm256_setzero_si256();
  const __m256i xmin = _mm256_min_epi32(_mm256_min_epi32(X[0], X[1]), X[2]);
  const __m256i xmax = _mm256_max_epi32(_mm256_max_epi32(X[0], X[1]), X[2]);
  const __m256i ymin = _mm256_min_epi32(_mm256_min_epi32(Y[0], Y[1]), Y[2]);
  const __m256i ymax = _mm256_max_epi32(_mm256_max_epi32(Y[0], Y[1]), Y[2]);
  const __m256i bx0 = _mm256_max_epi32(zero, _mm256_srai_epi32(_mm256_add_epi32(xmin, half_up), kSubBits));
  const __m256i by0 = _mm256_max_epi32(zero, _mm256_srai_epi32(_mm256_add_epi32(ymin, half_up), kSubBits));
  const __m256i bx1 = _mm256_min_epi32(_mm256_set1_epi32(vw - 1), _mm256_srai_epi32(xmax, kSubBits));
  const __m256i by1 = _mm256_min_epi32(_mm256_set1_epi32(vh - 1), _mm256_srai_epi32(ymax, kSubBits));
  // Planes at the tile's corner, one quantity a row (c[0 .. 9], then zeros), transposed to one
  // entry a row: its first eight floats from the first transpose, c[8], c[9] from the second.
  const __m256i dx = _mm256_sub_epi32(_mm256_set1_epi32(x0), bx0), dy = _mm256_sub_epi32(_mm256_set1_epi32(y0), by0);
  __m256i c[8], d[8];
  for (int q = 0; q < 3; ++q) {
    const __m256 at = plane_at_corner(_mm256_castsi256_ps(C[q]), _mm256_castsi256_ps(A[q]), _mm256_castsi256_ps(B[q]), dx, dy);
    const __m256i row[3] = {_mm256_castps_si256(at), A[q], B[q]};
    for (int r = 0; r < 3; ++r) (3 * q + r < 8 ? c[3 * q + r] : d[3 * q + r - 8]) = row[r];
  }
  d[1] = _mm256_castps_si256(_mm256_set1_ps(INFINITY));
  for (int r = 2; r < 8; ++r) d[r] = zero;
  transpose8(c);
  transpose8(d);
  for (int i = 0; i < m; ++i) {
    float* out = coef + kPlaneFloats * (e0 + i);
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out), c[i]);
    _mm_storel_epi64(reinterpret_cast<__m128i*>(out + 8), _mm256_castsi256_si128(d[i]));
  }
  // Small: corners spanning under 8 pixels each way, the box non-empty and in the tile.
  const __m256i eight = _mm256_set1_epi32(8 << kSubBits);
  __m256i small = _mm256_and_si256(_mm256_cmpgt_epi32(eight, _mm256_sub_epi32(xmax, xmin)),
                                   _mm256_cmpgt_epi32(eight, _mm256_sub_epi32(ymax, ymin)));
  const __m256i outside = _mm256_or_si256(
      _mm256_or_si256(_mm256_cmpgt_epi32(_mm256_set1_epi32(x0), bx0), _mm256_cmpgt_epi32(bx1, _mm256_set1_epi32(x1))),
      _mm256_or_si256(_mm256_cmpgt_epi32(_mm256_set1_epi32(y0), by0), _mm256_cmpgt_epi32(by1, _mm256_set1_epi32(y1))));
  const __m256i empty = _mm256_or_si256(_mm256_cmpgt_epi32(bx0, bx1), _mm256_cmpgt_epi32(by0, by1));
  small = _mm256_andnot_si256(_mm256_or_si256(outside, empty), small);
  const unsigned bits = static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(small))) & ((1u << m) - 1);
  s.small |= bits << e0;
  if (bits == 0) return;
  const __m256i one = _mm256_set1_epi32(1);
  auto store = [e0](std::int32_t* dst, __m256i v) { _mm256_storeu_si256(reinterpret_cast<__m256i*>(dst + e0), v); };
  store(s.x0, bx0);
  store(s.y0, by0);
  store(s.w, _mm256_add_epi32(_mm256_sub_epi32(bx1, bx0), one));
  store(s.h, _mm256_add_epi32(_mm256_sub_epi32(by1, by0), one));
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(s.base + e0), C[0]);
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(s.A + e0), A[0]);
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(s.B + e0), B[0]);
  const __m256i px = _mm256_slli_epi32(bx0, kSubBits), py = _mm256_slli_epi32(by0, kSubBits);
  for (int k = 0; k < 3; ++k) {
    const int k1 = (k + 1) % 3;
    const __m256i ex = _mm256_sub_epi32(X[k1], X[k]), ey = _mm256_sub_epi32(Y[k1], Y[k]);
    const __m256i top_left = _mm256_or_si256(_mm256_and_si256(_mm256_cmpeq_epi32(ey, zero), _mm256_cmpgt_epi32(ex, zero)),
                                             _mm256_cmpgt_epi32(zero, ey));
    const __m256i e =
        _mm256_sub_epi32(_mm256_mullo_epi32(ex, _mm256_sub_epi32(py, Y[k])), _mm256_mullo_epi32(ey, _mm256_sub_epi32(px, X[k])));
    // Less one where the edge is not top or left: adding ~top_left (-1 there, 0 elsewhere).
    store(s.E[k], _mm256_add_epi32(e, _mm256_xor_si256(top_left, _mm256_set1_epi32(-1))));
    store(s.dEx[k], _mm256_slli_epi32(_mm256_sub_epi32(zero, ey), kSubBits));
    store(s.dEy[k], _mm256_slli_epi32(ex, kSubBits));
  }
}

// Four vertices, one a lane.
struct Vert4 {
  __m256d sx, sy, iz, qx, qy;
  __m128i X, Y;
};

inline Vert4 load4(const ProjGrid& g, int k) {
  return {_mm256_loadu_pd(g.sx + k), _mm256_loadu_pd(g.sy + k), _mm256_loadu_pd(g.iz + k), _mm256_loadu_pd(g.qx + k),
          _mm256_loadu_pd(g.qy + k), _mm_loadu_si128(reinterpret_cast<const __m128i*>(g.X + k)),
          _mm_loadu_si128(reinterpret_cast<const __m128i*>(g.Y + k))};
}

inline void setup4(const Vert4& a, const Vert4& b, const Vert4& c, int vw, int vh, Tri4& t) {
  // The doubled area, in 64 bits: differences of corners inside the guard band fit 31 bits.
  const __m256i dx1 = _mm256_cvtepi32_epi64(_mm_sub_epi32(b.X, a.X)), dy2 = _mm256_cvtepi32_epi64(_mm_sub_epi32(c.Y, a.Y));
  const __m256i dy1 = _mm256_cvtepi32_epi64(_mm_sub_epi32(b.Y, a.Y)), dx2 = _mm256_cvtepi32_epi64(_mm_sub_epi32(c.X, a.X));
  const __m256i area = _mm256_sub_epi64(_mm256_mul_epi32(dx1, dy2), _mm256_mul_epi32(dy1, dx2));
  // One 32-bit lane a triangle: the area's sign and whether it is 0.
  const __m256i pick = _mm256_setr_epi32(1, 3, 5, 7, 0, 2, 4, 6);
  const __m256i zero64 = _mm256_setzero_si256();
  const __m128i flip = _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(_mm256_cmpgt_epi64(zero64, area), pick));
  const __m128i none = _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(_mm256_cmpeq_epi64(area, zero64), pick));
  const __m128i X1 = _mm_blendv_epi8(b.X, c.X, flip), X2 = _mm_blendv_epi8(c.X, b.X, flip);
  const __m128i Y1 = _mm_blendv_epi8(b.Y, c.Y, flip), Y2 = _mm_blendv_epi8(c.Y, b.Y, flip);
  // pixel_box(): the first pixel centre at or after the least corner, the last at or before
  // the greatest, clamped to the view.
  const __m128i half_up = _mm_set1_epi32((1 << kSubBits) - 1), zero = _mm_setzero_si128();
  const __m128i bx0 = _mm_max_epi32(zero, _mm_srai_epi32(_mm_add_epi32(_mm_min_epi32(_mm_min_epi32(a.X, X1), X2), half_up), kSubBits));
  const __m128i by0 = _mm_max_epi32(zero, _mm_srai_epi32(_mm_add_epi32(_mm_min_epi32(_mm_min_epi32(a.Y, Y1), Y2), half_up), kSubBits));
  const __m128i bx1 = _mm_min_epi32(_mm_set1_epi32(vw - 1), _mm_srai_epi32(_mm_max_epi32(_mm_max_epi32(a.X, X1), X2), kSubBits));
  const __m128i by1 = _mm_min_epi32(_mm_set1_epi32(vh - 1), _mm_srai_epi32(_mm_max_epi32(_mm_max_epi32(a.Y, Y1), Y2), kSubBits));
  const __m128i empty = _mm_or_si128(_mm_cmpgt_epi32(bx0, bx1), _mm_cmpgt_epi32(by0, by1));
  const __m256d e1x = _mm256_sub_pd(b.sx, a.sx), e1y = _mm256_sub_pd(b.sy, a.sy);
  const __m256d e2x = _mm256_sub_pd(c.sx, a.sx), e2y = _mm256_sub_pd(c.sy, a.sy);
  const __m256d det = _mm256_sub_pd(_mm256_mul_pd(e1x, e2y), _mm256_mul_pd(e2x, e1y));
  const int flat = _mm256_movemask_pd(_mm256_cmp_pd(det, _mm256_setzero_pd(), _CMP_EQ_OQ));  // det == 0
  t.keep = static_cast<unsigned>(~(_mm_movemask_ps(_mm_castsi128_ps(_mm_or_si128(none, empty))) | flat)) & 0xFu;
  if (t.keep == 0) return;
  const __m256d inv_det = _mm256_div_pd(_mm256_set1_pd(1.0), det);
  const __m256d ox = _mm256_sub_pd(_mm256_cvtepi32_pd(bx0), a.sx), oy = _mm256_sub_pd(_mm256_cvtepi32_pd(by0), a.sy);
  const __m256d* q[3][3] = {{&a.iz, &b.iz, &c.iz}, {&a.qx, &b.qx, &c.qx}, {&a.qy, &b.qy, &c.qy}};
  for (int k = 0; k < 3; ++k) {
    const __m256d d1 = _mm256_sub_pd(*q[k][1], *q[k][0]), d2 = _mm256_sub_pd(*q[k][2], *q[k][0]);
    const __m256d A = _mm256_mul_pd(_mm256_sub_pd(_mm256_mul_pd(d1, e2y), _mm256_mul_pd(d2, e1y)), inv_det);
    const __m256d B = _mm256_mul_pd(_mm256_sub_pd(_mm256_mul_pd(d2, e1x), _mm256_mul_pd(d1, e2x)), inv_det);
    const __m256d C = _mm256_add_pd(_mm256_add_pd(*q[k][0], _mm256_mul_pd(A, ox)), _mm256_mul_pd(B, oy));
    _mm_store_ps(t.A[k], _mm256_cvtpd_ps(A));
    _mm_store_ps(t.B[k], _mm256_cvtpd_ps(B));
    _mm_store_ps(t.C[k], _mm256_cvtpd_ps(C));
  }
  const __m128i* corners[6] = {&a.X, &X1, &X2, &a.Y, &Y1, &Y2};
  for (int k = 0; k < 3; ++k) {
    _mm_store_si128(reinterpret_cast<__m128i*>(t.X[k]), *corners[k]);
    _mm_store_si128(reinterpret_cast<__m128i*>(t.Y[k]), *corners[3 + k]);
  }
  _mm_store_si128(reinterpret_cast<__m128i*>(t.box[0]), bx0);
  _mm_store_si128(reinterpret_cast<__m128i*>(t.box[1]), by0);
  _mm_store_si128(reinterpret_cast<__m128i*>(t.box[2]), bx1);
  _mm_store_si128(reinterpret_cast<__m128i*>(t.box[3]), by1);
}

}  // namespace

int emit_quad_row_avx2(const ProjGrid& g, int top, int bottom, int n, bool anti, int vw, int vh, Tri* out, PixelBox* boxes) {
  return emit_quad_row_by4<load4, setup4>(g, top, bottom, n, anti, vw, vh, out, boxes);
}

bool project_posts_avx2(const PostFrame& f, const float* x, const float* y, const float* z, int n, int k0, const ClipGrid& cv,
                        const ProjGrid& proj, std::uint8_t* out, bool* no_height) {
  const __m256 zero = _mm256_setzero_ps();
  bool all = true;
  int a0 = 0;
  for (; a0 + 8 <= n; a0 += 8) {
    const int k = k0 + a0;
    const __m256 X = _mm256_loadu_ps(x + a0), Y = _mm256_loadu_ps(y + a0), Z = _mm256_loadu_ps(z + a0);
    const __m256 none = _mm256_cmp_ps(_mm256_sub_ps(Z, Z), zero, _CMP_NEQ_UQ);  // NaN or infinite
    const __m256 dx = _mm256_sub_ps(X, _mm256_set1_ps(f.t[0])), dy = _mm256_sub_ps(Y, _mm256_set1_ps(f.t[1]));
    const __m256 dz = _mm256_sub_ps(_mm256_blendv_ps(Z, zero, none), _mm256_set1_ps(f.t[2]));
    auto row = [&](int i) {
      const __m256 xy = _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(f.R[3 * i]), dx), _mm256_mul_ps(_mm256_set1_ps(f.R[3 * i + 1]), dy));
      return _mm256_add_ps(xy, _mm256_mul_ps(_mm256_set1_ps(f.R[3 * i + 2]), dz));
    };
    const __m256 cx = row(0), cy = row(1), cz = row(2);
    _mm256_storeu_ps(cv.x + k, cx);
    _mm256_storeu_ps(cv.y + k, cy);
    _mm256_storeu_ps(cv.z + k, cz);
    _mm256_storeu_ps(cv.wx + k, X);
    _mm256_storeu_ps(cv.wy + k, Y);
    // clip_distance() of each plane, >= 0 inside.
    const __m256 d[5] = {_mm256_sub_ps(cz, _mm256_set1_ps(f.near)),
                         _mm256_sub_ps(cx, _mm256_mul_ps(_mm256_set1_ps(f.guard[0]), cz)),
                         _mm256_sub_ps(_mm256_mul_ps(_mm256_set1_ps(f.guard[1]), cz), cx),
                         _mm256_sub_ps(cy, _mm256_mul_ps(_mm256_set1_ps(f.guard[2]), cz)),
                         _mm256_sub_ps(_mm256_mul_ps(_mm256_set1_ps(f.guard[3]), cz), cy)};
    int in[5];
    for (int p = 0; p < 5; ++p) in[p] = _mm256_movemask_ps(_mm256_cmp_ps(d[p], zero, _CMP_GE_OQ));
    const int empty = _mm256_movemask_ps(none);
    for (int i = 0; i < 8; ++i) {
      std::uint8_t code = 0;
      for (int p = 0; p < 5; ++p) code = static_cast<std::uint8_t>(code | ((in[p] >> i & 1) ? 0 : 1) << p);
      out[k + i] = code;
      no_height[k + i] = (empty >> i & 1) != 0;
    }
    all = all && (in[0] & in[1] & in[2] & in[3] & in[4] & ~empty & 0xFF) == 0xFF;
    // project_vertex() in two halves of four, every lane (those outside hold scratch).
    const __m256d magic = _mm256_set1_pd(6755399441055744.0), sub = _mm256_set1_pd(1 << kSubBits);
    auto fixed = [&](__m256d v) { return _mm256_cvtpd_epi32(_mm256_sub_pd(_mm256_add_pd(_mm256_mul_pd(v, sub), magic), magic)); };
    for (int h = 0; h < 2; ++h) {
      auto part = [h](__m256 v) { return _mm256_cvtps_pd(h ? _mm256_extractf128_ps(v, 1) : _mm256_castps256_ps128(v)); };
      const __m256d iz = _mm256_div_pd(_mm256_set1_pd(1.0), part(cz));
      const __m256d sx = _mm256_add_pd(_mm256_mul_pd(_mm256_mul_pd(_mm256_set1_pd(f.fx), part(cx)), iz), _mm256_set1_pd(f.cx));
      const __m256d sy = _mm256_add_pd(_mm256_mul_pd(_mm256_mul_pd(_mm256_set1_pd(f.fy), part(cy)), iz), _mm256_set1_pd(f.cy));
      const int kh = k + 4 * h;
      _mm256_storeu_pd(proj.iz + kh, iz);
      _mm256_storeu_pd(proj.sx + kh, sx);
      _mm256_storeu_pd(proj.sy + kh, sy);
      _mm256_storeu_pd(proj.qx + kh, _mm256_mul_pd(part(X), iz));
      _mm256_storeu_pd(proj.qy + kh, _mm256_mul_pd(part(Y), iz));
      _mm_storeu_si128(reinterpret_cast<__m128i*>(proj.X + kh), fixed(sx));
      _mm_storeu_si128(reinterpret_cast<__m128i*>(proj.Y + kh), fixed(sy));
    }
  }
  if (a0 < n) all = project_posts_scalar(f, x + a0, y + a0, z + a0, n - a0, k0 + a0, cv, proj, out, no_height) && all;
  return all;
}

void setup_entries_avx2(const Tri* tris, const int* ids, int n, int x0, int y0, int x1, int y1, int vw, int vh, EntrySetup& s,
                        float* coef) {
  s.small = 0;
  for (int h = 0; 8 * h < n; ++h) setup_half(tris, ids, n, h, x0, y0, x1, y1, vw, vh, s, coef);
}

int draw_small_entries_avx2(const EntrySetup& s, int from, int n, int x0, int y0, float* z, int* id, std::ptrdiff_t stride,
                            int e0, int* covered) {
  return draw_small_entries_through<edge_block32_avx2_inline>(s, from, n, x0, y0, z, id, stride, e0, covered);
}

}  // namespace terralign::raster
