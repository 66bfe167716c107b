// Built with -mavx2 -mfma.
#include "conv_rows.hpp"
#include "simd_avx2.hpp"

namespace terralign::nn {

void conv3x3_rows_avx2(const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1, float* scratch) {
  conv3x3_rows<VecAvx2>(in, w, out, y0, y1, scratch);
}

}  // namespace terralign::nn
