// Texture shading kernels: world (x, y) of each pixel -> bilinear / trilinear mip-mapped
// RGBA sample of one layer. One kernel, a scalar build, AVX2 and AVX-512 builds (x86-64;
// the depth kernel has no AVX-512 build) and a NEON build (aarch64), with the same float
// operations in the same order (no FMA contraction),
// so they agree bit for bit.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace terralign::raster {

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

struct ShadeParams {
  const std::uint32_t* texels;  // RGBA8 packed (R in the low byte), every level back to back,
                                // and a readable guard texel before the first and after the last
  const MipLevel* levels;
  int n_levels;                 // >= 1
  // Level-0 texel coordinates (pixel centres at integers) of a local world point:
  // u = a0 + a1 x + a2 y, v = b0 + b1 x + b2 y.
  float a0, a1, a2, b0, b1, b2;
  float lod_bias;               // added to log2(footprint in metres): -log2(texel size)
};

// For n pixels: wx, wy local world coordinates (NaN: no terrain), log2fp the log2 of the
// pixel's ground footprint in metres. Writes 3 bytes of colour and one validity byte (255 /
// 0) per pixel; colour is 0 where invalid. Reads only [0, n) of each input; no allocation.
void shade_row_scalar(int n, const float* wx, const float* wy, const float* log2fp,
                      std::uint8_t* rgb, std::uint8_t* valid, const ShadeParams& p);
#if defined(TERRALIGN_HAVE_AVX2)
void shade_row_avx2(int n, const float* wx, const float* wy, const float* log2fp,
                    std::uint8_t* rgb, std::uint8_t* valid, const ShadeParams& p);
#endif
#if defined(TERRALIGN_HAVE_AVX2)
void shade_row_avx512(int n, const float* wx, const float* wy, const float* log2fp,
                      std::uint8_t* rgb, std::uint8_t* valid, const ShadeParams& p);
#endif
#if defined(TERRALIGN_HAVE_NEON)
void shade_row_neon(int n, const float* wx, const float* wy, const float* log2fp,
                    std::uint8_t* rgb, std::uint8_t* valid, const ShadeParams& p);
#endif

// One row of a tile after visibility: pixel i, dx0 + i columns right of the tile's corner and
// dy rows below it, sees bin entry ids[i] (-1: no terrain), whose planes at the tile's corner
// are coef[9 e .. 9 e + 8] = {q0, dq0/dx, dq0/dy, q1, dq1/dx, dq1/dy, q2, dq2/dx, dq2/dy} for
// q0 = 1/z, q1 = x/z, q2 = y/z (local world x, y). Writes world x, y, depth z (NaN: no
// terrain) and log2 of the ground footprint in metres (0: no terrain) for n pixels. Reads
// coefficients only of the entries named.
void resolve_row_scalar(int n, const int* ids, const float* coef, float dx0, float dy, float* wx, float* wy,
                        float* z, float* log2fp);
#if defined(TERRALIGN_HAVE_AVX2)
void resolve_row_avx2(int n, const int* ids, const float* coef, float dx0, float dy, float* wx, float* wy,
                      float* z, float* log2fp);
#endif
#if defined(TERRALIGN_HAVE_AVX2)
void resolve_row_avx512(int n, const int* ids, const float* coef, float dx0, float dy, float* wx, float* wy,
                        float* z, float* log2fp);
#endif
#if defined(TERRALIGN_HAVE_NEON)
void resolve_row_neon(int n, const int* ids, const float* coef, float dx0, float dy, float* wx, float* wy,
                      float* z, float* log2fp);
#endif
using ResolveRowFn = void (*)(int, const int*, const float*, float, float, float*, float*, float*, float*);

// Visibility in a block that one triangle covers wholly: rows r < h, columns i < w (w <= 8)
// from z and id (row stride `stride`); the triangle's 1/z there is (base + B (dy + r)) +
// A (dx + i), in that order; where it is larger than z (nearer), it replaces z and id
// becomes e. The block's rows and ids are the only memory read or written.
void depth_block_scalar(int w, int h, float base, float A, float B, int dx, int dy, float* z, int* id,
                        std::ptrdiff_t stride, int e);
#if defined(TERRALIGN_HAVE_AVX2)
void depth_block_avx2(int w, int h, float base, float A, float B, int dx, int dy, float* z, int* id,
                      std::ptrdiff_t stride, int e);
#endif
#if defined(TERRALIGN_HAVE_NEON)
void depth_block_neon(int w, int h, float base, float A, float B, int dx, int dy, float* z, int* id,
                      std::ptrdiff_t stride, int e);
#endif
using DepthBlockFn = void (*)(int, int, float, float, float, int, int, float*, int*, std::ptrdiff_t, int);

// The same in a block the triangle's edges cross: pixel (i, r) is covered where all three
// 64-bit edge functions E[k] + dEx[k] i + dEy[k] r (at the block's corner) are >= 0, and
// only covered pixels are depth-tested. Returns the number of covered pixels. No NEON build
// (aarch64 runs the scalar one).
long edge_block_scalar(int w, int h, const std::int64_t* E, const std::int64_t* dEx, const std::int64_t* dEy, float base,
                       float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride, int e);
#if defined(TERRALIGN_HAVE_AVX2)
long edge_block_avx2(int w, int h, const std::int64_t* E, const std::int64_t* dEx, const std::int64_t* dEy, float base,
                     float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride, int e);
#endif
using EdgeBlockFn = long (*)(int, int, const std::int64_t*, const std::int64_t*, const std::int64_t*, float, float, float,
                             int, int, float*, int*, std::ptrdiff_t, int);

// The same with 32-bit edge functions, for a block where every pixel's three values fit in
// 32 bits (the renderer checks the block's corners: the functions are linear, so the corners
// bound them): twice the lanes of the 64-bit kernel, and the same results (compared with
// edge_block_scalar in the tests). AVX2 only; elsewhere the 64-bit kernel runs.
#if defined(TERRALIGN_HAVE_AVX2)
long edge_block32_avx2(int w, int h, const std::int32_t* E, const std::int32_t* dEx, const std::int32_t* dEy, float base,
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
  return e + ((-0.34484843f * m + 2.02466578f) * m - 0.67487759f);
}

using ShadeRowFn = void (*)(int, const float*, const float*, const float*, std::uint8_t*,
                            std::uint8_t*, const ShadeParams&);

// True if this CPU runs the AVX2 + FMA kernels (and they were built); the AVX-512F ones.
bool cpu_has_avx2();
bool cpu_has_avx512();

}  // namespace terralign::raster
