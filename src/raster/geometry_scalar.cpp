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

int emit_quad_row_scalar(const ProjGrid& g, int top, int bottom, int n, bool anti, int vw, int vh, Tri* out, PixelBox* boxes) {
  int count = 0;
  for (int a = 0; a < n; ++a) {
    const ProjVert p00 = g.at(top + a), p10 = g.at(top + a + 1), p01 = g.at(bottom + a), p11 = g.at(bottom + a + 1);
    if (setup_triangle(p00, p10, anti ? p01 : p11, vw, vh, out[count], boxes[count])) ++count;
    if (setup_triangle(anti ? p10 : p00, p11, p01, vw, vh, out[count], boxes[count])) ++count;
  }
  return count;
}

void setup_entries_scalar(const Tri* tris, const int* ids, int n, int x0, int y0, int x1, int y1, int vw, int vh,
                          EntrySetup& s, float* coef) {
  s.small = 0;
  for (int i = 0; i < n; ++i) {
    const Tri& t = tris[ids[i]];
    const PixelBox b = pixel_box(t.X, t.Y, vw, vh);
    float* c = coef + kPlaneFloats * i;
    for (int q = 0; q < 3; ++q) {
      c[3 * q] = static_cast<float>(static_cast<double>(t.C[q]) + static_cast<double>(t.A[q]) * (x0 - b.x0) +
                                    static_cast<double>(t.B[q]) * (y0 - b.y0));
      c[3 * q + 1] = t.A[q];
      c[3 * q + 2] = t.B[q];
    }
    c[9] = INFINITY;
    const std::int32_t span_x = std::max({t.X[0], t.X[1], t.X[2]}) - std::min({t.X[0], t.X[1], t.X[2]});
    const std::int32_t span_y = std::max({t.Y[0], t.Y[1], t.Y[2]}) - std::min({t.Y[0], t.Y[1], t.Y[2]});
    if (!(span_x < (8 << kSubBits) && span_y < (8 << kSubBits) && b.x0 >= x0 && b.x1 <= x1 && b.y0 >= y0 && b.y1 <= y1 &&
          b.x0 <= b.x1 && b.y0 <= b.y1))
      continue;
    s.small |= 1u << i;
    s.x0[i] = b.x0;
    s.y0[i] = b.y0;
    s.w[i] = b.x1 - b.x0 + 1;
    s.h[i] = b.y1 - b.y0 + 1;
    s.base[i] = t.C[0];
    s.A[i] = t.A[0];
    s.B[i] = t.B[0];
    const std::int32_t px = b.x0 * (1 << kSubBits), py = b.y0 * (1 << kSubBits);
    for (int k = 0; k < 3; ++k) {
      const int k1 = (k + 1) % 3;
      const std::int32_t ex = t.X[k1] - t.X[k], ey = t.Y[k1] - t.Y[k];
      const bool top_left = (ey == 0 && ex > 0) || ey < 0;
      s.E[k][i] = ex * (py - t.Y[k]) - ey * (px - t.X[k]) - (top_left ? 0 : 1);
      s.dEx[k][i] = -ey * (1 << kSubBits);
      s.dEy[k][i] = ex * (1 << kSubBits);
    }
  }
}

}  // namespace terralign::raster
