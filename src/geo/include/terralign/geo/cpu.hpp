// What the CPU this runs on can execute, asked once at start-up by the modules that carry
// SIMD kernels (each also needs its kernels to have been built: see TERRALIGN_SIMD).
#pragma once

namespace terralign {

struct CpuFeatures {
  bool avx2_fma = false;  // AVX2 and FMA3
  bool avx512f = false;
  bool avx512bw_vl = false;  // AVX-512 BW and VL as well as F
};

const CpuFeatures& cpu_features();

}  // namespace terralign
