// Shared by the AVX2 and AVX-512 shading builds (both compiled with -mavx2): eight pixels
// of RGBX (32 bits each, R in the low byte) written as 24 bytes of RGB.
#pragma once

#include <cstdint>
#include <cstring>

#include <immintrin.h>

namespace terralign::raster {

inline void store_rgb8_avx2(std::uint8_t* dst, __m256i px) {
  const __m256i packed = _mm256_shuffle_epi8(px, _mm256_setr_epi8(0, 1, 2, 4, 5, 6, 8, 9, 10, 12, 13, 14, -1, -1, -1, -1,
                                                                  0, 1, 2, 4, 5, 6, 8, 9, 10, 12, 13, 14, -1, -1, -1, -1));
  const __m128i lo = _mm256_castsi256_si128(packed), hi = _mm256_extracti128_si256(packed, 1);
  _mm_storel_epi64(reinterpret_cast<__m128i*>(dst), lo);
  const int lo_tail = _mm_extract_epi32(lo, 2);
  std::memcpy(dst + 8, &lo_tail, 4);
  _mm_storel_epi64(reinterpret_cast<__m128i*>(dst + 12), hi);
  const int hi_tail = _mm_extract_epi32(hi, 2);
  std::memcpy(dst + 20, &hi_tail, 4);
}

}  // namespace terralign::raster
