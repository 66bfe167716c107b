// Shared by the AVX2 and AVX-512 builds (both compiled with -mavx2): the depth test of a row
// of eight pixels, and the 32-bit edge kernel (shade_kernels.hpp's edge_block32), inline so
// that the AVX-512 rasterizer's loop over small triangles runs it without a call.
#pragma once

#include <cstddef>
#include <cstdint>

#include <immintrin.h>

namespace terralign::raster {

// The depth test of one row of a block where `in` (all-ones lanes) marks the covered pixels:
// where the triangle's 1/z `iz` is larger (nearer), it replaces z and id becomes `ve`. All 8
// columns are loaded and stored back (the row stride holds them, shade_kernels.hpp): masked
// stores (vmaskmov) cost tens of cycles on some cores, AMD's among them.
inline void depth_row(__m256i in, __m256 iz, float* z, int* id, __m256i ve) {
  const __m256 old = _mm256_loadu_ps(z);
  const __m256 nearer = _mm256_and_ps(_mm256_cmp_ps(iz, old, _CMP_GT_OQ), _mm256_castsi256_ps(in));
  _mm256_storeu_ps(z, _mm256_blendv_ps(old, iz, nearer));
  const __m256i oid = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(id));
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(id), _mm256_blendv_epi8(oid, ve, _mm256_castps_si256(nearer)));
}

// edge_block32 (shade_kernels.hpp), eight columns a row.
inline long edge_block32_avx2_inline(int w, int h, const std::int32_t* E, const std::int32_t* dEx, const std::int32_t* dEy,
                                     float base, float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride,
                                     int e) {
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
    // No branch on an empty row: with triangles of a few pixels, whether a row is empty is a
    // coin toss, and the depth test of an empty row writes back what it read.
    covered += __builtin_popcount(static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(in))));
    depth_row(in, _mm256_add_ps(_mm256_set1_ps(base + B * static_cast<float>(dy + r)), ax), z, id, ve);
  }
  return covered;
}

}  // namespace terralign::raster
