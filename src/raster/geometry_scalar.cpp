// The scalar build of the triangle set-up kernel (geometry_kernels.hpp).
#include <terralign/raster/geometry_kernels.hpp>

namespace terralign::raster {

int emit_quad_row_scalar(const ProjGrid& g, int top, int bottom, int n, int vw, int vh, Tri* out, PixelBox* boxes) {
  int count = 0;
  for (int a = 0; a < n; ++a) {
    const ProjVert p00 = g.at(top + a), p10 = g.at(top + a + 1), p01 = g.at(bottom + a), p11 = g.at(bottom + a + 1);
    if (setup_triangle(p00, p10, p11, vw, vh, out[count], boxes[count])) ++count;
    if (setup_triangle(p00, p11, p01, vw, vh, out[count], boxes[count])) ++count;
  }
  return count;
}

}  // namespace terralign::raster
