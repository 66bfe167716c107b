#include <terralign/geo/cpu.hpp>

namespace terralign {

const CpuFeatures& cpu_features() {
  static const CpuFeatures f = [] {
    CpuFeatures c;
#if defined(__x86_64__) || defined(__i386__)
    __builtin_cpu_init();
    c.avx2_fma = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    c.avx512f = c.avx2_fma && __builtin_cpu_supports("avx512f");
    c.avx512bw_vl = c.avx512f && __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512vl");
#endif
    return c;
  }();
  return f;
}

}  // namespace terralign
