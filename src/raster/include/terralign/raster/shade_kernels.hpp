// Texture shading kernels: the world (x, y) a pixel sees -> a bilinear / trilinear mip-mapped
// sample of one layer, alone (shade_row, after a separate resolve) or fused with the resolve
// of a pinhole tile row (resolve_shade_row). One kernel of each, a scalar build, AVX2 and
// AVX-512 builds (x86-64) and a NEON build (aarch64), doing the same integer and float
// operations in the same order (no FMA contraction), so they agree bit for bit.
//
// What every build computes:
// - Texels are premultiplied RGBA8 (each colour scaled by alpha / 255, R in the low byte).
//   The renderer's level 0 has alpha 0 (no data) or 255, so premultiplying it is exact; each
//   coarser level is the rounded mean of the 2 x 2 texels below it. Filtering premultiplied
//   texels weights each colour by its alpha: no-data texels do not darken their neighbours.
// - Level of detail per pixel, from its ground footprint (pixel_level()): level l0 = floor(lod)
//   and the next, lod = log2(footprint / texel), clamped to the chain. The fused kernels
//   take level 0 without computing the footprint where a bound over the pixel's triangle in
//   its tile shows the texture magnified there (entry_magnified(): most pixels of views from
//   a few hundred metres over 0.3-5 m orthophotos).
// - At level l a pixel's texel coordinates (centres at integers) in 256ths of a texel are
//   256 ul = a0 + a1 x + a2 y, 256 vl = b0 + b1 x + b2 y (the level's LevelCoords, float, in
//   that order: the coefficients carry the 256, which as a power of two leaves every rounding
//   as it would be in texels), and U = floor(256 ul) (V likewise) gives the left tap's column
//   U >> 8 and the column fraction F = (U & 255) << 7, eight bits of it in the 15 of the fixed
//   point below.
// - A channel c enters as C = c << 7 (0 .. 32640: a difference of two fits 16 bits signed), and
//     lerp(a, b, F) = a + (((b - a) * F + 2^14) >> 15)
//   (x86's pmulhrsw, NEON's vqrdmulh: one instruction for 16, 8 or 4 pixels' channels).
//   Bilinear: the top taps lerped by the column fraction, the bottom taps likewise, then the
//   two by the row fraction. Taps outside the level read as 0 (transparent). Trilinear: the
//   samples of levels l and l + 1 lerped by the level fraction (15 bits; 0 takes level l
//   alone, exactly what the lerp would give).
// - The result S (RGBA, x128) is valid where S_a >= 16320: at least half of the filter's
//   weight on valid texels. Its colour is c = min(255, (int)(float(S_c * 255) / float(S_a) +
//   0.5f)); where S_a = 32640 (opaque, most pixels) that is exactly (S_c + 64) >> 7, the
//   shortcut the vector builds take.
// So the float work is the resolve, the footprint and the texel coordinates. A vector's lanes
// mostly share a level; its fetches are then row loads where its taps lie in a few texel rows
// (nadir views, and rows that run along the texture's rows), gathers elsewhere. Where its
// lanes need different levels, it samples each of them and picks per lane (AVX-512: gathers
// each lane's two levels, two samples where the levels l .. l + 2 took three).
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace terralign::raster {

// The most levels the renderer's chains have (down to 1 x 1 from up to 32768 texels a side;
// a larger texture's chain stops there). The AVX-512 kernels pick a lane's level from one
// vector of 16.
constexpr int kMaxMipLevels = 16;

struct MipLevel {
  std::int32_t offset;  // index of the level's first texel in the texel array
  std::int32_t width;
  std::int32_t height;
  float scale;          // 2^-level: level-0 texel coordinate -> this level's, about centres
};

// The levels of a mip chain over a width x height level 0, laid out in one texel array after
// its leading guard texel: each level half the last (rounded up) down to 1 x 1, at most
// max_levels of them, back to back from index 1. The array holds mip_chain_end(levels) + 1
// texels (the trailing guard last).
std::vector<MipLevel> mip_chain(int width, int height, int max_levels);
inline std::size_t mip_chain_end(const std::vector<MipLevel>& levels) {
  const MipLevel& last = levels.back();
  return static_cast<std::size_t>(last.offset) + static_cast<std::size_t>(last.width) * static_cast<std::size_t>(last.height);
}

// A level's texel coordinates (centres at integers) of a local world point (x, y):
// ul = a0 + a1 x + a2 y, vl = b0 + b1 x + b2 y.
struct LevelCoords {
  float a0, a1, a2, b0, b1, b2;
};

// The coordinates of every level of `levels` in 256ths of a texel, given level 0's in texels
// (u0 = a0 + a1 x + a2 y, ...), computed in double: ul = (u0 + 0.5) scale - 0.5.
std::vector<LevelCoords> level_coords(const std::vector<MipLevel>& levels, double a0, double a1, double a2, double b0,
                                      double b1, double b2);

struct ShadeParams {
  const std::uint32_t* texels;  // premultiplied RGBA8 (R in the low byte), every level back to
                                // back, and a readable guard texel before the first and after the last
  const MipLevel* levels;
  const LevelCoords* coords;    // per level
  int n_levels;                 // 1 .. kMaxMipLevels
  float lod_bias;               // added to log2(footprint in metres): -log2(texel size)
};

// A chain's per-level values one array a quantity, kMaxMipLevels each (zero past the chain):
// coefficient[0 .. 5] = a0, a1, a2, b0, b1, b2 of coords, level[0 .. 2] = offset, width,
// height. The vector kernels load them as tables from which each lane picks its own level.
struct LevelArrays {
  alignas(64) float coefficient[6][kMaxMipLevels];
  alignas(64) std::int32_t level[3][kMaxMipLevels];
};
inline void level_arrays(const ShadeParams& p, LevelArrays& a) {
  a = LevelArrays{};
  for (int l = 0; l < p.n_levels && l < kMaxMipLevels; ++l) {
    const LevelCoords& k = p.coords[l];
    const float c[6] = {k.a0, k.a1, k.a2, k.b0, k.b1, k.b2};
    for (int q = 0; q < 6; ++q) a.coefficient[q][l] = c[q];
    a.level[0][l] = p.levels[l].offset;
    a.level[1][l] = p.levels[l].width;
    a.level[2][l] = p.levels[l].height;
  }
}

// A pixel's levels: l0 alone where t == 0, else lerped towards l1 by t (15 bits).
struct LevelPair {
  int l0, l1, t;
};

// The level pair of a pixel whose ground footprint is 2^log2fp metres.
inline LevelPair pixel_level(float log2fp, const ShadeParams& p) {
  const int top = p.n_levels - 1;
  float lod = log2fp + p.lod_bias;
  lod = lod > 0.0f ? lod : 0.0f;  // NaN -> 0
  lod = lod < static_cast<float>(top) ? lod : static_cast<float>(top);
  const int l0 = static_cast<int>(lod);  // lod >= 0: truncation is floor
  const int t = static_cast<int>((lod - static_cast<float>(l0)) * 32768.0f);
  return {l0, l0 < top ? l0 + 1 : top, t < 32767 ? t : 32767};
}

// For n pixels: wx, wy local world coordinates (NaN: no terrain), log2fp the log2 of the
// pixel's ground footprint in metres. Writes 3 bytes of colour and one validity byte (255 /
// 0) per pixel; colour is 0 where invalid. Reads only [0, n) of each input, and texels of taps
// inside their level or (a tap pair at a level's edge) next to one, hence the guard texels;
// no allocation.
void shade_row_scalar(int n, const float* wx, const float* wy, const float* log2fp,
                      std::uint8_t* rgb, std::uint8_t* valid, const ShadeParams& p);
#if defined(TERRALIGN_HAVE_AVX2)
void shade_row_avx2(int n, const float* wx, const float* wy, const float* log2fp,
                    std::uint8_t* rgb, std::uint8_t* valid, const ShadeParams& p);
void shade_row_avx512(int n, const float* wx, const float* wy, const float* log2fp,
                      std::uint8_t* rgb, std::uint8_t* valid, const ShadeParams& p);
#endif
#if defined(TERRALIGN_HAVE_NEON)
void shade_row_neon(int n, const float* wx, const float* wy, const float* log2fp,
                    std::uint8_t* rgb, std::uint8_t* valid, const ShadeParams& p);
#endif
using ShadeRowFn = void (*)(int, const float*, const float*, const float*, std::uint8_t*,
                            std::uint8_t*, const ShadeParams&);

// One layer a fused kernel shades: its parameters and the row's output. A call shades at
// most kMaxShadeTargets layers.
constexpr int kMaxShadeTargets = 64;
struct ShadeTarget {
  const ShadeParams* params;
  std::uint8_t* rgb;    // 3 bytes a pixel
  std::uint8_t* valid;  // 1 byte a pixel
};

// A bin entry's planes at a tile's corner, kPlaneFloats floats: c[0 .. 8] = {q0, dq0/dx,
// dq0/dy, q1, dq1/dx, dq1/dy, q2, dq2/dx, dq2/dy} for q0 = 1/z, q1 = x/z, q2 = y/z (local
// world x, y), and c[9] an upper bound of plane_footprint_log2() over the pixels the entry
// covers in the tile (plane_footprint_bound_log2(); +inf where none is known).
constexpr int kPlaneFloats = 10;

// log2 of the ground footprint in metres at the pixel dx, dy from the corner: the larger of
// the lengths of d(x, y)/du and d(x, y)/dv. Inline (below, after fast_log2): the NEON kernel
// calls it per lane, and a call from vector code would spill every vector register; the AVX2
// and AVX-512 kernels do the same operations lane by lane.
inline float plane_footprint_log2(const float* c, float dx, float dy);

// An upper bound of plane_footprint_log2(c, dx, dy) over the box dx0 <= dx <= dx1, dy0 <= dy
// <= dy1 (c[0 .. 8] as above): d(x, y)/du is (a + b dy) z^2 and d(x, y)/dv is (a' + b' dx)
// z^2 with a, b, a', b' fixed by the planes, so the box's corners bound the numerators and
// its nearest corner z. Computed in double, with 1/64 added for fast_log2's error and float
// rounding; +inf where 1/z is not positive over the whole box.
float plane_footprint_bound_log2(const float* c, float dx0, float dx1, float dy0, float dy1);

// A pixel whose entry's bound says the layer is magnified there, bound + lod_bias <= 0 (its
// footprint is at most a level-0 texel), takes level 0 alone: exactly what its own footprint
// would give, and the fused kernels skip computing it. A NaN or +inf bound never qualifies.
inline bool entry_magnified(float bound, float lod_bias) { return bound + lod_bias <= 0.0f; }

// One row of a pinhole tile after visibility, resolved and shaded: pixel i, dx0 + i columns
// right of the tile's corner and dy rows below it, sees bin entry ids[i] (-1: no terrain).
// Per pixel, in float and in this order: iz = (q0 + dq0/dy dy) + dq0/dx dx, z = 1 / iz,
// x = ((q1 + dq1/dy dy) + dq1/dx dx) z, y likewise; writes z (NaN: no terrain) and shades
// every target as shade_row would with log2fp = plane_footprint_log2() of the pixel, or -inf
// (level 0) where entry_magnified(c[9], the target's lod_bias). dx0 is a whole number.
// Reads coefficients only of the entries named; no allocation.
void resolve_shade_row_scalar(int n, const int* ids, const float* coef, float dx0, float dy, float* z, int n_targets,
                              const ShadeTarget* targets);
#if defined(TERRALIGN_HAVE_AVX2)
void resolve_shade_row_avx2(int n, const int* ids, const float* coef, float dx0, float dy, float* z, int n_targets,
                            const ShadeTarget* targets);
void resolve_shade_row_avx512(int n, const int* ids, const float* coef, float dx0, float dy, float* z, int n_targets,
                              const ShadeTarget* targets);
#endif
#if defined(TERRALIGN_HAVE_NEON)
void resolve_shade_row_neon(int n, const int* ids, const float* coef, float dx0, float dy, float* z, int n_targets,
                            const ShadeTarget* targets);
#endif
using ResolveShadeRowFn = void (*)(int, const int*, const float*, float, float, float*, int, const ShadeTarget*);

// The largest lod_bias of the targets (-inf for none): an entry magnified for it is for
// every target (float addition rounds monotonically), and its pixels need no footprint.
inline float max_lod_bias(int n_targets, const ShadeTarget* targets) {
  float b = -INFINITY;
  for (int k = 0; k < n_targets; ++k) b = b > targets[k].params->lod_bias ? b : targets[k].params->lod_bias;
  return b;
}

// Visibility in a block that one triangle covers wholly: rows r < h, columns i < w
// (w <= kDepthBlockMaxW) from z and id (row stride `stride`); the triangle's 1/z there is
// (base + B (dy + r)) + A (dx + i), in that order; where it is larger than z (nearer), it
// replaces z and id becomes e. Only the block's pixels change; the AVX2 build reads and
// writes back (unchanged) each row's columns up to the next multiple of 8 past w, so every
// row must have 8 columns of memory past the block that no other thread writes meanwhile (the
// renderer pads its rows by 8). The renderer passes blocks of 8 x 8 pixels, or 32 x 32 where
// one triangle covers a whole group of 4 x 4 blocks.
constexpr int kDepthBlockMaxW = 32;
void depth_block_scalar(int w, int h, float base, float A, float B, int dx, int dy, float* z, int* id,
                        std::ptrdiff_t stride, int e);
#if defined(TERRALIGN_HAVE_AVX2)
void depth_block_avx2(int w, int h, float base, float A, float B, int dx, int dy, float* z, int* id,
                      std::ptrdiff_t stride, int e);
void depth_block_avx512(int w, int h, float base, float A, float B, int dx, int dy, float* z, int* id,
                        std::ptrdiff_t stride, int e);
#endif
#if defined(TERRALIGN_HAVE_NEON)
void depth_block_neon(int w, int h, float base, float A, float B, int dx, int dy, float* z, int* id,
                      std::ptrdiff_t stride, int e);
#endif
using DepthBlockFn = void (*)(int, int, float, float, float, int, int, float*, int*, std::ptrdiff_t, int);

// The same in a block the triangle's edges cross: pixel (i, r) is covered where all three
// 64-bit edge functions E[k] + dEx[k] i + dEy[k] r (at the block's corner) are >= 0, and
// only covered pixels are depth-tested. Returns the number of covered pixels. Blocks of at
// most 8 columns; the vector builds read and write back 8 (AVX2) or 4 (NEON) columns at a time,
// as depth_block's.
long edge_block_scalar(int w, int h, const std::int64_t* E, const std::int64_t* dEx, const std::int64_t* dEy, float base,
                       float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride, int e);
#if defined(TERRALIGN_HAVE_AVX2)
long edge_block_avx2(int w, int h, const std::int64_t* E, const std::int64_t* dEx, const std::int64_t* dEy, float base,
                     float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride, int e);
#endif
#if defined(TERRALIGN_HAVE_NEON)
long edge_block_neon(int w, int h, const std::int64_t* E, const std::int64_t* dEx, const std::int64_t* dEy, float base,
                     float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride, int e);
#endif
using EdgeBlockFn = long (*)(int, int, const std::int64_t*, const std::int64_t*, const std::int64_t*, float, float, float,
                             int, int, float*, int*, std::ptrdiff_t, int);

// The same with 32-bit edge functions, for a block where every pixel's three values fit in
// 32 bits (the renderer checks the block's corners: the functions are linear, so the corners
// bound them): twice the lanes of the 64-bit kernel, and the same results (compared with
// edge_block_scalar in the tests). AVX2 and NEON; elsewhere the 64-bit kernel runs.
#if defined(TERRALIGN_HAVE_AVX2)
long edge_block32_avx2(int w, int h, const std::int32_t* E, const std::int32_t* dEx, const std::int32_t* dEy, float base,
                       float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride, int e);
#endif
#if defined(TERRALIGN_HAVE_NEON)
long edge_block32_neon(int w, int h, const std::int32_t* E, const std::int32_t* dEx, const std::int32_t* dEy, float base,
                       float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride, int e);
#endif
using EdgeBlock32Fn = long (*)(int, int, const std::int32_t*, const std::int32_t*, const std::int32_t*, float, float, float,
                               int, int, float*, int*, std::ptrdiff_t, int);

// log2 to about 0.005 (exponent plus a quadratic in the mantissa): enough to pick a mip
// level, and the same on every machine.
inline float fast_log2(float x) {
  std::uint32_t i;
  __builtin_memcpy(&i, &x, 4);
  const float e = static_cast<float>(static_cast<int>(i >> 23) - 127);
  const std::uint32_t mi = (i & 0x7fffffu) | 0x3f800000u;
  float m;
  __builtin_memcpy(&m, &mi, 4);
  return e + ((-0.34484843f * m + 2.02466578f) * m - 1.67487759f);
}

inline float plane_footprint_log2(const float* c, float dx, float dy) {
  const float iz = (c[0] + c[2] * dy) + c[1] * dx;
  const float zz = 1.0f / iz;
  const float x = ((c[3] + c[5] * dy) + c[4] * dx) * zz;
  const float y = ((c[6] + c[8] * dy) + c[7] * dx) * zz;
  // d(x, y)/du from the planes' column derivatives c[1], c[4], c[7]; d/dv from the row ones.
  const float du_x = (c[4] - x * c[1]) * zz, du_y = (c[7] - y * c[1]) * zz;
  const float dv_x = (c[5] - x * c[2]) * zz, dv_y = (c[8] - y * c[2]) * zz;
  const float su = du_x * du_x + du_y * du_y, sv = dv_x * dv_x + dv_y * dv_y;
  float d2 = su > sv ? su : sv;
  d2 = d2 > 1e-12f ? d2 : 1e-12f;
  return 0.5f * fast_log2(d2);
}

// True if this CPU runs the AVX2 + FMA kernels (and they were built); the AVX-512 ones
// (F, BW and VL).
bool cpu_has_avx2();
bool cpu_has_avx512();

}  // namespace terralign::raster
