// The geometry's kernels. The vertex stage: terrain posts into the camera frame, their
// outcodes against the clip volume, and the projection of those inside (project_posts, a row
// of a chunk's posts at once; project_vertex() alone, for the clipped polygons' corners).
// Triangle set-up: a screen triangle from three projected vertices (its snapped corners made
// clockwise, its pixel box, the planes of 1/z, x/z and y/z fitted in double), one at a time
// (setup_triangle(): the clipped triangles) or for a row of a terrain chunk's quads at once
// (emit_quad_row: most of a frame's triangles). A scalar build, AVX2 and AVX-512 builds (8 or
// 16 posts, four or eight triangles a vector) and a NEON build (four of each) do the same
// integer, float and double operations in the same order, so they agree bit for bit.
#pragma once

#include <algorithm>
#include <cstdint>

#include <terralign/geo/thread_pool.hpp>
#include <terralign/raster/shade_kernels.hpp>

namespace terralign::raster {

constexpr int kSubBits = 8;  // sub-pixel bits of the fixed-point screen positions

// A vertex in the camera frame, and its local world position (metres from the renderer's
// origin).
struct ClipVert {
  float x, y, z;
  float wx, wy;
};

// A grid of ClipVerts, one array a quantity (vertex k of each).
struct ClipGrid {
  float *x, *y, *z, *wx, *wy;
  ClipVert at(int k) const { return {x[k], y[k], z[k], wx[k], wy[k]}; }
};

// The vertex stage's constants for a frame: the camera's rotation R_C_W (row major) and
// local centre, the clip volume (the near plane; the guard band's bounds of x/z left and
// right, y/z top and bottom) and the pinhole.
struct PostFrame {
  float R[9], t[3];
  float near, guard[4];
  double fx, fy, cx, cy;
};

// Signed distance of v to clip plane p (>= 0: inside): the near plane, then the guard band's
// left, right, top and bottom.
inline float clip_distance(const PostFrame& f, int plane, const ClipVert& v) {
  switch (plane) {
    case 0: return v.z - f.near;
    case 1: return v.x - f.guard[0] * v.z;
    case 2: return f.guard[1] * v.z - v.x;
    case 3: return v.y - f.guard[2] * v.z;
    default: return f.guard[3] * v.z - v.y;
  }
}

// Bit p set where v is outside clip plane p.
inline std::uint8_t outcode(const PostFrame& f, const ClipVert& v) {
  std::uint8_t code = 0;
  for (int plane = 0; plane < 5; ++plane) code |= static_cast<std::uint8_t>((clip_distance(f, plane, v) >= 0 ? 0 : 1) << plane);
  return code;
}

// Nearest integer (ties to even) of |v| < 2^51 in two additions: adding 1.5 * 2^52 leaves no
// fraction bits, so the sum is rounded in the FPU's default mode (the same IEEE operation on
// every machine). std::llround is a library call, 4 % of a synthetic-terrain frame.
inline double round_fixed(double v) {
  constexpr double kMagic = 6755399441055744.0;
  return (v + kMagic) - kMagic;
}

// A vertex inside the clip volume, projected: screen position (pixel centres at integers),
// 1/z and local world x/z, y/z (the planes' values there), and the fixed-point snap of the
// position (inside the renderer's guard band: |X|, |Y| < 2^29).
struct ProjVert {
  double sx, sy, iz, qx, qy;
  std::int32_t X, Y;
};

// A grid of projected vertices, one array a quantity (vertex k of each), for the vector
// kernels' loads.
struct ProjGrid {
  double *sx, *sy, *iz, *qx, *qy;
  std::int32_t *X, *Y;
  ProjVert at(int k) const { return {sx[k], sy[k], iz[k], qx[k], qy[k], X[k], Y[k]}; }
  void set(int k, const ProjVert& p) const {
    sx[k] = p.sx; sy[k] = p.sy; iz[k] = p.iz; qx[k] = p.qx; qy[k] = p.qy; X[k] = p.X; Y[k] = p.Y;
  }
};

// v (inside the clip volume: the guard band keeps |X|, |Y| < 2^29) projected.
inline ProjVert project_vertex(const PostFrame& f, const ClipVert& v) {
  ProjVert p;
  p.iz = 1.0 / static_cast<double>(v.z);
  p.sx = f.fx * v.x * p.iz + f.cx;
  p.sy = f.fy * v.y * p.iz + f.cy;
  p.qx = v.wx * p.iz;
  p.qy = v.wy * p.iz;
  p.X = static_cast<std::int32_t>(round_fixed(p.sx * (1 << kSubBits)));
  p.Y = static_cast<std::int32_t>(round_fixed(p.sy * (1 << kSubBits)));
  return p;
}

// Posts k0 .. k0 + n - 1 of a grid, at local world (x[a], y[a]) with heights z[a] (not
// finite: no height; placed at 0 and flagged): their camera-frame positions R (p - t) (each
// coordinate (R_i0 dx + R_i1 dy) + R_i2 dz) into cv, their outcodes into out[k] and no_height[k],
// and where out[k] is 0 their projections into proj (elsewhere proj is left as it was or
// holds scratch). Returns whether all n have a height and lie inside the clip volume.
bool project_posts_scalar(const PostFrame& f, const float* x, const float* y, const float* z, int n, int k0, const ClipGrid& cv,
                          const ProjGrid& proj, std::uint8_t* out, bool* no_height);
#if defined(TERRALIGN_HAVE_AVX2)
bool project_posts_avx2(const PostFrame& f, const float* x, const float* y, const float* z, int n, int k0, const ClipGrid& cv,
                        const ProjGrid& proj, std::uint8_t* out, bool* no_height);
bool project_posts_avx512(const PostFrame& f, const float* x, const float* y, const float* z, int n, int k0, const ClipGrid& cv,
                          const ProjGrid& proj, std::uint8_t* out, bool* no_height);
#endif
#if defined(TERRALIGN_HAVE_NEON)
bool project_posts_neon(const PostFrame& f, const float* x, const float* y, const float* z, int n, int k0, const ClipGrid& cv,
                        const ProjGrid& proj, std::uint8_t* out, bool* no_height);
#endif
using ProjectPostsFn = bool (*)(const PostFrame&, const float*, const float*, const float*, int, int, const ClipGrid&,
                                const ProjGrid&, std::uint8_t*, bool*);

// A screen triangle ready for rasterization: its snapped corners, and for 1/z, x_world/z and
// y_world/z the planes q(x, y) = A (x - x0) + B (y - y0) + C in pixel coordinates (centres at
// integers), (x0, y0) the corner of its pixel box (pixel_box()). Fitted in double, kept in
// float relative to that corner: one cache line a triangle (kUnsharedAlign is the line), where
// the planes in double at the image's corner took 112 bytes (with the renderer's 8-byte tile
// span beside each, max_triangles a thread take 38 MB a thread at the default, were 59 MB). A
// pixel's 1/z from the float planes is within about 1e-7 relative of the double ones.
struct alignas(kUnsharedAlign) Tri {
  std::int32_t X[3], Y[3];  // fixed point, kSubBits
  float A[3], B[3], C[3];   // [0]: 1/z, [1]: wx/z, [2]: wy/z
};

// A triangle's inclusive pixel box, clamped to the view: the pixels whose centres (whole
// coordinates) lie within its snapped corners' box. Only they can be covered.
struct PixelBox {
  int x0, y0, x1, y1;
};
inline PixelBox pixel_box(const std::int32_t* X, const std::int32_t* Y, int vw, int vh) {
  constexpr std::int32_t kHalfUp = (1 << kSubBits) - 1;
  // (int casts: std::int32_t is long on some targets, arm-none-eabi's among them.)
  return {std::max(0, static_cast<int>((std::min({X[0], X[1], X[2]}) + kHalfUp) >> kSubBits)),
          std::max(0, static_cast<int>((std::min({Y[0], Y[1], Y[2]}) + kHalfUp) >> kSubBits)),
          std::min(vw - 1, static_cast<int>(std::max({X[0], X[1], X[2]}) >> kSubBits)),
          std::min(vh - 1, static_cast<int>(std::max({Y[0], Y[1], Y[2]}) >> kSubBits))};
}

// Triangle (a, b, c) of a vw x vh view into t and its pixel box into box: corners b and c
// swapped where needed to make it clockwise on screen (y down), the planes fitted from the
// unsnapped positions in double (exact depth whatever the snapping), in a's, b's, c's order.
// False (t and box then hold scratch) where it has no area or covers no pixel centre: a
// triangle of a few pixels often holds none.
inline bool setup_triangle(const ProjVert& a, const ProjVert& b, const ProjVert& c, int vw, int vh, Tri& t, PixelBox& box) {
  t.X[0] = a.X; t.X[1] = b.X; t.X[2] = c.X;
  t.Y[0] = a.Y; t.Y[1] = b.Y; t.Y[2] = c.Y;
  const std::int64_t area = (std::int64_t{t.X[1]} - t.X[0]) * (std::int64_t{t.Y[2]} - t.Y[0]) -
                            (std::int64_t{t.Y[1]} - t.Y[0]) * (std::int64_t{t.X[2]} - t.X[0]);
  if (area == 0) return false;
  if (area < 0) {
    std::swap(t.X[1], t.X[2]);
    std::swap(t.Y[1], t.Y[2]);
  }
  box = pixel_box(t.X, t.Y, vw, vh);
  if (box.x0 > box.x1 || box.y0 > box.y1) return false;
  const double e1x = b.sx - a.sx, e1y = b.sy - a.sy, e2x = c.sx - a.sx, e2y = c.sy - a.sy;
  const double det = e1x * e2y - e2x * e1y;
  if (det == 0) return false;
  const double inv_det = 1.0 / det;  // one division, not six
  const double q[3][3] = {{a.iz, b.iz, c.iz}, {a.qx, b.qx, c.qx}, {a.qy, b.qy, c.qy}};
  for (int k = 0; k < 3; ++k) {
    const double d1 = q[k][1] - q[k][0], d2 = q[k][2] - q[k][0];
    const double A = (d1 * e2y - d2 * e1y) * inv_det, B = (d2 * e1x - d1 * e2x) * inv_det;
    t.A[k] = static_cast<float>(A);
    t.B[k] = static_cast<float>(B);
    t.C[k] = static_cast<float>(q[k][0] + A * (box.x0 - a.sx) + B * (box.y0 - a.sy));
  }
  return true;
}

// The triangles of quads a = 0 .. n - 1 (n <= 32, a Wide terrain chunk's row) between the grid rows whose vertices start
// at `top` and at `bottom`, each quad split along its diagonal from top + a to bottom + a + 1:
// (top + a, top + a + 1, bottom + a + 1), then (top + a, bottom + a + 1, bottom + a); or, with
// `anti`, along the other one: (top + a, top + a + 1, bottom + a), then (top + a + 1, bottom +
// a + 1, bottom + a) (TerrainChunk::anti). Each as setup_triangle() makes it; those it keeps
// are written in that order to out and boxes (room for 2 n each). Returns how many.
int emit_quad_row_scalar(const ProjGrid& g, int top, int bottom, int n, bool anti, int vw, int vh, Tri* out, PixelBox* boxes);
#if defined(TERRALIGN_HAVE_AVX2)
int emit_quad_row_avx2(const ProjGrid& g, int top, int bottom, int n, bool anti, int vw, int vh, Tri* out, PixelBox* boxes);
int emit_quad_row_avx512(const ProjGrid& g, int top, int bottom, int n, bool anti, int vw, int vh, Tri* out, PixelBox* boxes);
#endif
#if defined(TERRALIGN_HAVE_NEON)
int emit_quad_row_neon(const ProjGrid& g, int top, int bottom, int n, bool anti, int vw, int vh, Tri* out, PixelBox* boxes);
#endif
using EmitQuadRowFn = int (*)(const ProjGrid&, int, int, int, bool, int, int, Tri*, PixelBox*);

// The set-up of up to 16 of a tile's bin entries for the rasterizer. A small entry is a
// triangle whose corners span under 8 pixels each way and whose pixel box lies wholly in the
// tile: every edge value over its box fits 24 bits, so it is set up in 32 bits for the
// 32-bit edge kernel (edge k from corner k to corner k + 1, E >= 0 inside with the top-left
// rule's bias, at the box's corner; steps per column and row). Every entry also gets its
// planes at the tile's corner for the resolve (kPlaneFloats floats, shade_kernels.hpp): c[3 q]
// = (C + A (x0 - box x0)) + B (y0 - box y0) in double, then float; c[3 q + 1] = A, c[3 q + 2] =
// B; c[9] = +inf (no footprint bound: the rasterizer sets one where the entry covers many
// pixels).
struct EntrySetup {
  static constexpr int kMax = 16;
  std::uint32_t small;  // bit i: entry i is small
  alignas(64) std::int32_t x0[kMax], y0[kMax], w[kMax], h[kMax];  // small entries' pixel boxes
  alignas(64) std::int32_t E[3][kMax], dEx[3][kMax], dEy[3][kMax];
  alignas(64) float base[kMax], A[kMax], B[kMax];  // small entries' 1/z at the box's corner (C), and its slopes
};
// Entries tris[ids[i]], i < n <= 16, of the tile whose pixels are x0 .. x1, y0 .. y1 in a
// vw x vh view; their planes to coef[kPlaneFloats i ...].
void setup_entries_scalar(const Tri* tris, const int* ids, int n, int x0, int y0, int x1, int y1, int vw, int vh,
                          EntrySetup& s, float* coef);
#if defined(TERRALIGN_HAVE_AVX2)
void setup_entries_avx2(const Tri* tris, const int* ids, int n, int x0, int y0, int x1, int y1, int vw, int vh,
                        EntrySetup& s, float* coef);
void setup_entries_avx512(const Tri* tris, const int* ids, int n, int x0, int y0, int x1, int y1, int vw, int vh,
                          EntrySetup& s, float* coef);
#endif
#if defined(TERRALIGN_HAVE_NEON)
void setup_entries_neon(const Tri* tris, const int* ids, int n, int x0, int y0, int x1, int y1, int vw, int vh,
                        EntrySetup& s, float* coef);
#endif
using SetupEntriesFn = void (*)(const Tri*, const int*, int, int, int, int, int, int, int, EntrySetup&, float*);

// Draws the small entries of a set-up batch from entry `from` on, in order, up to the first
// that is not small (or n): each as edge_block32 (shade_kernels.hpp) draws its box into the
// tile's visibility buffers z and id (row stride `stride`, the tile's corner at pixel x0, y0)
// as entry e0 + i. covered[i] gets the pixels each covers. Returns where it stopped. (The
// AVX2 build, with the edge kernel inlined, serves the AVX-512 renderer too.) Built where
// edge_block32 is; a scalar renderer draws no entry as small.
#if defined(TERRALIGN_HAVE_AVX2)
int draw_small_entries_avx2(const EntrySetup& s, int from, int n, int x0, int y0, float* z, int* id, std::ptrdiff_t stride,
                            int e0, int* covered);
#endif
#if defined(TERRALIGN_HAVE_NEON)
int draw_small_entries_neon(const EntrySetup& s, int from, int n, int x0, int y0, float* z, int* id, std::ptrdiff_t stride,
                            int e0, int* covered);
#endif
using DrawSmallEntriesFn = int (*)(const EntrySetup&, int, int, int, int, float*, int*, std::ptrdiff_t, int, int*);

// draw_small_entries through the 32-bit edge kernel Edge (edge_block32's signature): each
// vector build's, with its kernel inlined.
template <auto Edge>
inline int draw_small_entries_through(const EntrySetup& s, int from, int n, int x0, int y0, float* z, int* id,
                                      std::ptrdiff_t stride, int e0, int* covered) {
  int i = from;
  for (; i < n && (s.small >> i & 1); ++i) {
    const std::ptrdiff_t at = (s.y0[i] - y0) * stride + (s.x0[i] - x0);
    const std::int32_t E[3] = {s.E[0][i], s.E[1][i], s.E[2][i]};
    const std::int32_t dEx[3] = {s.dEx[0][i], s.dEx[1][i], s.dEx[2][i]}, dEy[3] = {s.dEy[0][i], s.dEy[1][i], s.dEy[2][i]};
    covered[i] = static_cast<int>(Edge(s.w[i], s.h[i], E, dEx, dEy, s.base[i], s.A[i], s.B[i], 0, 0, z + at, id + at, stride, e0 + i));
  }
  return i;
}

}  // namespace terralign::raster
