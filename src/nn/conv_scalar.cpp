#include "conv_rows.hpp"
#include "simd_scalar.hpp"

namespace terralign::nn {

void conv3x3_rows_scalar(const Tensor& in, const ConvWeights& w, Tensor& out, int y0, int y1, float* scratch) {
  conv3x3_rows<VecScalar>(in, w, out, y0, y1, scratch);
}

}  // namespace terralign::nn
