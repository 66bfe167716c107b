#include <terralign/raster/shade_kernels.hpp>

#include <terralign/geo/cpu.hpp>

namespace terralign::raster {

bool cpu_has_avx2() {
#if defined(TERRALIGN_HAVE_AVX2)
  return cpu_features().avx2_fma;
#else
  return false;
#endif
}

bool cpu_has_avx512() {
#if defined(TERRALIGN_HAVE_AVX2)
  return cpu_features().avx512bw_vl;
#else
  return false;
#endif
}

}  // namespace terralign::raster
