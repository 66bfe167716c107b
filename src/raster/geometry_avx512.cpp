// The AVX-512 (F, BW, VL) build of the geometry's kernels (geometry_kernels.hpp), each step
// the scalar build's operation lane by lane, in its order (no FMA: the raster target says
// -ffp-contract=off and this file is built without -mfma), so the results are the scalar
// kernels' bit for bit. The vertex stage takes 16 posts a vector (their projections in two
// halves of eight doubles); the triangle set-up takes eight quads' first triangles in one set
// of vectors and their second triangles in another, and stores the kept ones in quad order,
// transposed to one triangle a vector; the entries' set-up takes 16 entries' triangles
// transposed to one field a vector.
#include <terralign/raster/geometry_kernels.hpp>

#include <immintrin.h>

#include <cmath>

namespace terralign::raster {
namespace {

// rows[i] <- column i of the 16 x 16 matrix of 32-bit elements whose row j is rows[j].
inline void transpose16(__m512i* rows) {
  __m512i t[16], u[16];
  for (int i = 0; i < 8; ++i) {
    t[2 * i] = _mm512_unpacklo_epi32(rows[2 * i], rows[2 * i + 1]);
    t[2 * i + 1] = _mm512_unpackhi_epi32(rows[2 * i], rows[2 * i + 1]);
  }
  for (int i = 0; i < 4; ++i) {
    u[4 * i] = _mm512_unpacklo_epi64(t[4 * i], t[4 * i + 2]);
    u[4 * i + 1] = _mm512_unpackhi_epi64(t[4 * i], t[4 * i + 2]);
    u[4 * i + 2] = _mm512_unpacklo_epi64(t[4 * i + 1], t[4 * i + 3]);
    u[4 * i + 3] = _mm512_unpackhi_epi64(t[4 * i + 1], t[4 * i + 3]);
  }
  // 128-bit lane L of u[4 i + j] holds column 4 L + j of rows 4 i .. 4 i + 3.
  for (int j = 0; j < 4; ++j) {
    const __m512i a = _mm512_shuffle_i32x4(u[j], u[4 + j], 0x88), b = _mm512_shuffle_i32x4(u[8 + j], u[12 + j], 0x88);
    const __m512i c = _mm512_shuffle_i32x4(u[j], u[4 + j], 0xDD), d = _mm512_shuffle_i32x4(u[8 + j], u[12 + j], 0xDD);
    rows[j] = _mm512_shuffle_i32x4(a, b, 0x88);
    rows[8 + j] = _mm512_shuffle_i32x4(a, b, 0xDD);
    rows[4 + j] = _mm512_shuffle_i32x4(c, d, 0x88);
    rows[12 + j] = _mm512_shuffle_i32x4(c, d, 0xDD);
  }
}

// Eight vertices, one a lane.
struct Vert8 {
  __m512d sx, sy, iz, qx, qy;
  __m256i X, Y;
};

inline Vert8 load8(const ProjGrid& g, int k, __mmask8 lanes) {
  return {_mm512_maskz_loadu_pd(lanes, g.sx + k), _mm512_maskz_loadu_pd(lanes, g.sy + k),
          _mm512_maskz_loadu_pd(lanes, g.iz + k), _mm512_maskz_loadu_pd(lanes, g.qx + k),
          _mm512_maskz_loadu_pd(lanes, g.qy + k), _mm256_maskz_loadu_epi32(lanes, g.X + k),
          _mm256_maskz_loadu_epi32(lanes, g.Y + k)};
}

// Eight triangles set up: their Tri fields (X[3], Y[3], A[3], B[3], C[3]; the 16th is
// zero), one a vector, their boxes, and the lanes kept.
struct Tri8 {
  __m256i field[16];
  alignas(32) std::int32_t box[4][8];
  __mmask8 keep;
};

inline void setup8(const Vert8& a, const Vert8& b, const Vert8& c, __mmask8 lanes, int vw, int vh, Tri8& t) {
  // The doubled area, in 64 bits: differences of corners inside the guard band fit 31 bits.
  const __m512i dx1 = _mm512_cvtepi32_epi64(_mm256_sub_epi32(b.X, a.X)), dy2 = _mm512_cvtepi32_epi64(_mm256_sub_epi32(c.Y, a.Y));
  const __m512i dy1 = _mm512_cvtepi32_epi64(_mm256_sub_epi32(b.Y, a.Y)), dx2 = _mm512_cvtepi32_epi64(_mm256_sub_epi32(c.X, a.X));
  const __m512i area = _mm512_sub_epi64(_mm512_mul_epi32(dx1, dy2), _mm512_mul_epi32(dy1, dx2));
  const __mmask8 flip = _mm512_cmplt_epi64_mask(area, _mm512_setzero_si512());
  __mmask8 keep = static_cast<__mmask8>(lanes & _mm512_cmpneq_epi64_mask(area, _mm512_setzero_si512()));
  const __m256i X1 = _mm256_mask_blend_epi32(flip, b.X, c.X), X2 = _mm256_mask_blend_epi32(flip, c.X, b.X);
  const __m256i Y1 = _mm256_mask_blend_epi32(flip, b.Y, c.Y), Y2 = _mm256_mask_blend_epi32(flip, c.Y, b.Y);
  // pixel_box(): the first pixel centre at or after the least corner, the last at or before
  // the greatest, clamped to the view.
  const __m256i half_up = _mm256_set1_epi32((1 << kSubBits) - 1), zero = _mm256_setzero_si256();
  auto first = [&](__m256i p, __m256i q, __m256i r) {
    return _mm256_max_epi32(zero, _mm256_srai_epi32(_mm256_add_epi32(_mm256_min_epi32(_mm256_min_epi32(p, q), r), half_up), kSubBits));
  };
  auto last = [&](__m256i p, __m256i q, __m256i r, int size) {
    return _mm256_min_epi32(_mm256_set1_epi32(size - 1), _mm256_srai_epi32(_mm256_max_epi32(_mm256_max_epi32(p, q), r), kSubBits));
  };
  const __m256i bx0 = first(a.X, X1, X2), by0 = first(a.Y, Y1, Y2);
  const __m256i bx1 = last(a.X, X1, X2, vw), by1 = last(a.Y, Y1, Y2, vh);
  keep = static_cast<__mmask8>(keep & _mm256_cmple_epi32_mask(bx0, bx1) & _mm256_cmple_epi32_mask(by0, by1));
  const __m512d e1x = _mm512_sub_pd(b.sx, a.sx), e1y = _mm512_sub_pd(b.sy, a.sy);
  const __m512d e2x = _mm512_sub_pd(c.sx, a.sx), e2y = _mm512_sub_pd(c.sy, a.sy);
  const __m512d det = _mm512_sub_pd(_mm512_mul_pd(e1x, e2y), _mm512_mul_pd(e2x, e1y));
  keep = static_cast<__mmask8>(keep & _mm512_cmp_pd_mask(det, _mm512_setzero_pd(), _CMP_NEQ_UQ));  // as !(det == 0)
  t.keep = keep;
  if (keep == 0) return;
  const __m512d inv_det = _mm512_div_pd(_mm512_set1_pd(1.0), det);
  const __m512d ox = _mm512_sub_pd(_mm512_cvtepi32_pd(bx0), a.sx), oy = _mm512_sub_pd(_mm512_cvtepi32_pd(by0), a.sy);
  const __m512d* q[3][3] = {{&a.iz, &b.iz, &c.iz}, {&a.qx, &b.qx, &c.qx}, {&a.qy, &b.qy, &c.qy}};
  for (int k = 0; k < 3; ++k) {
    const __m512d d1 = _mm512_sub_pd(*q[k][1], *q[k][0]), d2 = _mm512_sub_pd(*q[k][2], *q[k][0]);
    const __m512d A = _mm512_mul_pd(_mm512_sub_pd(_mm512_mul_pd(d1, e2y), _mm512_mul_pd(d2, e1y)), inv_det);
    const __m512d B = _mm512_mul_pd(_mm512_sub_pd(_mm512_mul_pd(d2, e1x), _mm512_mul_pd(d1, e2x)), inv_det);
    const __m512d C = _mm512_add_pd(_mm512_add_pd(*q[k][0], _mm512_mul_pd(A, ox)), _mm512_mul_pd(B, oy));
    t.field[6 + k] = _mm256_castps_si256(_mm512_cvtpd_ps(A));
    t.field[9 + k] = _mm256_castps_si256(_mm512_cvtpd_ps(B));
    t.field[12 + k] = _mm256_castps_si256(_mm512_cvtpd_ps(C));
  }
  t.field[0] = a.X;
  t.field[1] = X1;
  t.field[2] = X2;
  t.field[3] = a.Y;
  t.field[4] = Y1;
  t.field[5] = Y2;
  t.field[15] = _mm256_setzero_si256();
  _mm256_store_si256(reinterpret_cast<__m256i*>(t.box[0]), bx0);
  _mm256_store_si256(reinterpret_cast<__m256i*>(t.box[1]), by0);
  _mm256_store_si256(reinterpret_cast<__m256i*>(t.box[2]), bx1);
  _mm256_store_si256(reinterpret_cast<__m256i*>(t.box[3]), by1);
}

// (C + A dx) + B dy in double for eight lanes of one half (h) of 16, then float.
inline __m256 plane_at_corner(__m512 C, __m512 A, __m512 B, __m512i dx, __m512i dy, int h) {
  auto half_ps = [h](__m512 v) {
    return _mm512_cvtps_pd(h ? _mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(v), 1)) : _mm512_castps512_ps256(v));
  };
  auto half_pi = [h](__m512i v) { return _mm512_cvtepi32_pd(h ? _mm512_extracti64x4_epi64(v, 1) : _mm512_castsi512_si256(v)); };
  const __m512d c_plus_a = _mm512_add_pd(half_ps(C), _mm512_mul_pd(half_ps(A), half_pi(dx)));
  return _mm512_cvtpd_ps(_mm512_add_pd(c_plus_a, _mm512_mul_pd(half_ps(B), half_pi(dy))));
}

}  // namespace

bool project_posts_avx512(const PostFrame& f, const float* x, const float* y, const float* z, int n, int k0, const ClipGrid& cv,
                          const ProjGrid& proj, std::uint8_t* out, bool* no_height) {
  const __m512 zero = _mm512_setzero_ps();
  bool all = true;
  for (int a0 = 0; a0 < n; a0 += 16) {
    const int m = n - a0 < 16 ? n - a0 : 16;
    const __mmask16 lanes = static_cast<__mmask16>((1u << m) - 1);
    const int k = k0 + a0;
    const __m512 X = _mm512_maskz_loadu_ps(lanes, x + a0), Y = _mm512_maskz_loadu_ps(lanes, y + a0);
    const __m512 Z = _mm512_maskz_loadu_ps(lanes, z + a0);
    const __mmask16 none = _mm512_mask_cmp_ps_mask(lanes, _mm512_sub_ps(Z, Z), zero, _CMP_NEQ_UQ);  // NaN or infinite
    const __m512 dx = _mm512_sub_ps(X, _mm512_set1_ps(f.t[0])), dy = _mm512_sub_ps(Y, _mm512_set1_ps(f.t[1]));
    const __m512 dz = _mm512_sub_ps(_mm512_mask_mov_ps(Z, none, zero), _mm512_set1_ps(f.t[2]));
    auto row = [&](int i) {
      const __m512 xy = _mm512_add_ps(_mm512_mul_ps(_mm512_set1_ps(f.R[3 * i]), dx), _mm512_mul_ps(_mm512_set1_ps(f.R[3 * i + 1]), dy));
      return _mm512_add_ps(xy, _mm512_mul_ps(_mm512_set1_ps(f.R[3 * i + 2]), dz));
    };
    const __m512 cx = row(0), cy = row(1), cz = row(2);
    _mm512_mask_storeu_ps(cv.x + k, lanes, cx);
    _mm512_mask_storeu_ps(cv.y + k, lanes, cy);
    _mm512_mask_storeu_ps(cv.z + k, lanes, cz);
    _mm512_mask_storeu_ps(cv.wx + k, lanes, X);
    _mm512_mask_storeu_ps(cv.wy + k, lanes, Y);
    // clip_distance() of each plane, >= 0 inside.
    const __m512 d[5] = {_mm512_sub_ps(cz, _mm512_set1_ps(f.near)),
                         _mm512_sub_ps(cx, _mm512_mul_ps(_mm512_set1_ps(f.guard[0]), cz)),
                         _mm512_sub_ps(_mm512_mul_ps(_mm512_set1_ps(f.guard[1]), cz), cx),
                         _mm512_sub_ps(cy, _mm512_mul_ps(_mm512_set1_ps(f.guard[2]), cz)),
                         _mm512_sub_ps(_mm512_mul_ps(_mm512_set1_ps(f.guard[3]), cz), cy)};
    __m512i code = _mm512_setzero_si512();
    __mmask16 inside = lanes;
    for (int p = 0; p < 5; ++p) {
      const __mmask16 in = _mm512_cmp_ps_mask(d[p], zero, _CMP_GE_OQ);
      code = _mm512_mask_or_epi32(code, static_cast<__mmask16>(~in), code, _mm512_set1_epi32(1 << p));
      inside = static_cast<__mmask16>(inside & in);
    }
    _mm512_mask_cvtepi32_storeu_epi8(out + k, lanes, code);
    _mm512_mask_cvtepi32_storeu_epi8(no_height + k, lanes, _mm512_maskz_mov_epi32(none, _mm512_set1_epi32(1)));
    all = all && (inside & ~none & lanes) == lanes;
    // project_vertex() in two halves of eight, every lane (those outside hold scratch).
    for (int h = 0; h < 2 && 8 * h < m; ++h) {
      const __mmask8 half = static_cast<__mmask8>(lanes >> (8 * h));
      auto part = [h](__m512 v) {
        return _mm512_cvtps_pd(h ? _mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(v), 1)) : _mm512_castps512_ps256(v));
      };
      const __m512d iz = _mm512_div_pd(_mm512_set1_pd(1.0), part(cz));
      const __m512d sx = _mm512_add_pd(_mm512_mul_pd(_mm512_mul_pd(_mm512_set1_pd(f.fx), part(cx)), iz), _mm512_set1_pd(f.cx));
      const __m512d sy = _mm512_add_pd(_mm512_mul_pd(_mm512_mul_pd(_mm512_set1_pd(f.fy), part(cy)), iz), _mm512_set1_pd(f.cy));
      // round_fixed(): the nearest integer by adding and taking away 1.5 * 2^52.
      const __m512d magic = _mm512_set1_pd(6755399441055744.0), sub = _mm512_set1_pd(1 << kSubBits);
      auto fixed = [&](__m512d v) { return _mm512_cvtpd_epi32(_mm512_sub_pd(_mm512_add_pd(_mm512_mul_pd(v, sub), magic), magic)); };
      const int kh = k + 8 * h;
      _mm512_mask_storeu_pd(proj.iz + kh, half, iz);
      _mm512_mask_storeu_pd(proj.sx + kh, half, sx);
      _mm512_mask_storeu_pd(proj.sy + kh, half, sy);
      _mm512_mask_storeu_pd(proj.qx + kh, half, _mm512_mul_pd(part(X), iz));
      _mm512_mask_storeu_pd(proj.qy + kh, half, _mm512_mul_pd(part(Y), iz));
      _mm256_mask_storeu_epi32(proj.X + kh, half, fixed(sx));
      _mm256_mask_storeu_epi32(proj.Y + kh, half, fixed(sy));
    }
  }
  return all;
}

int emit_quad_row_avx512(const ProjGrid& g, int top, int bottom, int n, bool anti, int vw, int vh, Tri* out, PixelBox* boxes) {
  int count = 0;
  Tri8 first, second;
  for (int a0 = 0; a0 < n; a0 += 8) {
    const int m = n - a0 < 8 ? n - a0 : 8;
    const __mmask8 lanes = static_cast<__mmask8>((1u << m) - 1);
    const Vert8 v00 = load8(g, top + a0, lanes), v10 = load8(g, top + a0 + 1, lanes);
    const Vert8 v01 = load8(g, bottom + a0, lanes), v11 = load8(g, bottom + a0 + 1, lanes);
    setup8(v00, v10, anti ? v01 : v11, lanes, vw, vh, first);
    setup8(anti ? v10 : v00, v11, v01, lanes, vw, vh, second);
    if ((first.keep | second.keep) == 0) continue;
    // The two sets' fields side by side (first triangles in lanes 0-7, second in 8-15), then
    // one triangle a vector: row i the first triangle of quad a0 + i, row 8 + i its second.
    __m512i rows[16];
    for (int f = 0; f < 16; ++f)
      rows[f] = _mm512_inserti64x4(_mm512_castsi256_si512(first.keep ? first.field[f] : second.field[f]),
                                   second.keep ? second.field[f] : first.field[f], 1);
    transpose16(rows);
    for (int i = 0; i < m; ++i)
      for (const Tri8* t : {&first, &second}) {
        if (!(t->keep >> i & 1)) continue;
        _mm512_storeu_si512(&out[count], rows[t == &first ? i : 8 + i]);
        boxes[count] = {t->box[0][i], t->box[1][i], t->box[2][i], t->box[3][i]};
        ++count;
      }
  }
  return count;
}

void setup_entries_avx512(const Tri* tris, const int* ids, int n, int x0, int y0, int x1, int y1, int vw, int vh,
                          EntrySetup& s, float* coef) {
  // The entries' triangles, one a row (lanes past n repeat the first), then one field a row.
  __m512i f[16];
  for (int i = 0; i < 16; ++i) f[i] = _mm512_loadu_si512(&tris[ids[i < n ? i : 0]]);
  transpose16(f);
  const __m512i X[3] = {f[0], f[1], f[2]}, Y[3] = {f[3], f[4], f[5]};
  const __mmask16 lanes = static_cast<__mmask16>((1u << n) - 1);
  const __m512i half_up = _mm512_set1_epi32((1 << kSubBits) - 1), zero = _mm512_setzero_si512();
  const __m512i xmin = _mm512_min_epi32(_mm512_min_epi32(X[0], X[1]), X[2]);
  const __m512i xmax = _mm512_max_epi32(_mm512_max_epi32(X[0], X[1]), X[2]);
  const __m512i ymin = _mm512_min_epi32(_mm512_min_epi32(Y[0], Y[1]), Y[2]);
  const __m512i ymax = _mm512_max_epi32(_mm512_max_epi32(Y[0], Y[1]), Y[2]);
  const __m512i bx0 = _mm512_max_epi32(zero, _mm512_srai_epi32(_mm512_add_epi32(xmin, half_up), kSubBits));
  const __m512i by0 = _mm512_max_epi32(zero, _mm512_srai_epi32(_mm512_add_epi32(ymin, half_up), kSubBits));
  const __m512i bx1 = _mm512_min_epi32(_mm512_set1_epi32(vw - 1), _mm512_srai_epi32(xmax, kSubBits));
  const __m512i by1 = _mm512_min_epi32(_mm512_set1_epi32(vh - 1), _mm512_srai_epi32(ymax, kSubBits));
  // Planes at the tile's corner, one quantity a row, transposed to one entry a row.
  const __m512i dx = _mm512_sub_epi32(_mm512_set1_epi32(x0), bx0), dy = _mm512_sub_epi32(_mm512_set1_epi32(y0), by0);
  __m512i c[16];
  for (int q = 0; q < 3; ++q) {
    const __m512 A = _mm512_castsi512_ps(f[6 + q]), B = _mm512_castsi512_ps(f[9 + q]), C = _mm512_castsi512_ps(f[12 + q]);
    const __m256 lo = plane_at_corner(C, A, B, dx, dy, 0), hi = plane_at_corner(C, A, B, dx, dy, 1);
    c[3 * q] = _mm512_castpd_si512(_mm512_insertf64x4(_mm512_castps_pd(_mm512_castps256_ps512(lo)), _mm256_castps_pd(hi), 1));
    c[3 * q + 1] = f[6 + q];
    c[3 * q + 2] = f[9 + q];
  }
  c[9] = _mm512_castps_si512(_mm512_set1_ps(INFINITY));
  for (int r = 10; r < 16; ++r) c[r] = zero;
  transpose16(c);
  for (int i = 0; i < n; ++i) _mm512_mask_storeu_epi32(coef + kPlaneFloats * i, (1u << kPlaneFloats) - 1, c[i]);
  const __m512i eight = _mm512_set1_epi32(8 << kSubBits);
  __mmask16 small = _mm512_mask_cmplt_epi32_mask(lanes, _mm512_sub_epi32(xmax, xmin), eight);
  small = _mm512_mask_cmplt_epi32_mask(small, _mm512_sub_epi32(ymax, ymin), eight);
  small = _mm512_mask_cmpge_epi32_mask(small, bx0, _mm512_set1_epi32(x0));
  small = _mm512_mask_cmple_epi32_mask(small, bx1, _mm512_set1_epi32(x1));
  small = _mm512_mask_cmpge_epi32_mask(small, by0, _mm512_set1_epi32(y0));
  small = _mm512_mask_cmple_epi32_mask(small, by1, _mm512_set1_epi32(y1));
  small = _mm512_mask_cmple_epi32_mask(small, bx0, bx1);
  small = _mm512_mask_cmple_epi32_mask(small, by0, by1);
  s.small = small;
  if (small == 0) return;
  const __m512i one = _mm512_set1_epi32(1);
  _mm512_store_si512(s.x0, bx0);
  _mm512_store_si512(s.y0, by0);
  _mm512_store_si512(s.w, _mm512_add_epi32(_mm512_sub_epi32(bx1, bx0), one));
  _mm512_store_si512(s.h, _mm512_add_epi32(_mm512_sub_epi32(by1, by0), one));
  _mm512_store_si512(s.base, f[12]);
  _mm512_store_si512(s.A, f[6]);
  _mm512_store_si512(s.B, f[9]);
  const __m512i px = _mm512_slli_epi32(bx0, kSubBits), py = _mm512_slli_epi32(by0, kSubBits);
  for (int k = 0; k < 3; ++k) {
    const int k1 = (k + 1) % 3;
    const __m512i ex = _mm512_sub_epi32(X[k1], X[k]), ey = _mm512_sub_epi32(Y[k1], Y[k]);
    const __mmask16 top_left = static_cast<__mmask16>(
        (_mm512_cmpeq_epi32_mask(ey, zero) & _mm512_cmpgt_epi32_mask(ex, zero)) | _mm512_cmplt_epi32_mask(ey, zero));
    const __m512i e =
        _mm512_sub_epi32(_mm512_mullo_epi32(ex, _mm512_sub_epi32(py, Y[k])), _mm512_mullo_epi32(ey, _mm512_sub_epi32(px, X[k])));
    _mm512_store_si512(s.E[k], _mm512_mask_sub_epi32(e, static_cast<__mmask16>(~top_left), e, one));
    _mm512_store_si512(s.dEx[k], _mm512_slli_epi32(_mm512_sub_epi32(zero, ey), kSubBits));
    _mm512_store_si512(s.dEy[k], _mm512_slli_epi32(ex, kSubBits));
  }
}

}  // namespace terralign::raster
