// Texture shading kernels: world (x, y) of each pixel -> bilinear / trilinear mip-mapped
// RGBA sample of one layer. One kernel, a scalar build and an AVX2 build, with the same
// float operations in the same order (no FMA contraction), so the two agree bit for bit.
#pragma once

#include <cstdint>

namespace terralign::raster {

struct MipLevel {
  std::int32_t offset;  // index of the level's first texel in the texel array
  std::int32_t width;
  std::int32_t height;
  float scale;          // 2^-level: level-0 texel coordinate -> this level's, about centres
};

struct ShadeParams {
  const std::uint32_t* texels;  // RGBA8 packed (R in the low byte), every level back to back
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

using ShadeRowFn = void (*)(int, const float*, const float*, const float*, std::uint8_t*,
                            std::uint8_t*, const ShadeParams&);

// True if this CPU runs the AVX2 + FMA kernels (and they were built).
bool cpu_has_avx2();

}  // namespace terralign::raster
