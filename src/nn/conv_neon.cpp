// aarch64, and 32-bit ARM with NEON and VFPv4 (simd_neon.hpp).
#include "conv_rows.hpp"
#include "simd_neon.hpp"

namespace terralign::nn {

void conv3x3_rows_neon(const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1, float* scratch) {
  conv3x3_rows<VecNeon>(in, w, out, y0, y1, scratch);
}

}  // namespace terralign::nn
