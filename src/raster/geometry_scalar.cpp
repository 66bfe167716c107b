// The scalar build of the geometry's kernels (geometry_kernels.hpp).
#include <terralign/raster/geometry_kernels.hpp>

#include <cmath>

namespace terralign::raster {

bool project_posts_scalar(const PostFrame& f, const float* x, const float* y, const float* z, int n, int k0, const ClipGrid& cv,
                          const ProjGrid& proj, std::uint8_t* out, bool* no_height) {
  bool all = true;
  for (int a = 0; a < n; ++a) {
    const int k = k0 + a;
    no_height[k] = !std::isfinite(z[a]);
    const float dx = x[a] - f.t[0], dy = y[a] - f.t[1], dz = (no_height[k] ? 0.0f : z[a]) - f.t[2];
    const ClipVert v{(f.R[0] * dx + f.R[1] * dy) + f.R[2] * dz, (f.R[3] * dx + f.R[4] * dy) + f.R[5] * dz,
                     (f.R[6] * dx + f.R[7] * dy) + f.R[8] * dz, x[a], y[a]};
    cv.x[k] = v.x;
    cv.y[k] = v.y;
    cv.z[k] = v.z;
    cv.wx[k] = v.wx;
    cv.wy[k] = v.wy;
    out[k] = outcode(f, v);
    if (out[k] == 0) proj.set(k, project_vertex(f, v));
    all = all && out[k] == 0 && !no_height[k];
  }
  return all;
}

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
