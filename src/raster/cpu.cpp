#include <terralign/raster/shade_kernels.hpp>

namespace terralign::raster {

bool cpu_has_avx2() {
#if defined(TERRALIGN_HAVE_AVX2) && (defined(__x86_64__) || defined(__i386__))
  __builtin_cpu_init();
  return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
#else
  return false;
#endif
}

}  // namespace terralign::raster
