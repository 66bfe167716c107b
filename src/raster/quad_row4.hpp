// Shared by the AVX2 and NEON builds of emit_quad_row (geometry_kernels.hpp): four triangles
// set up field by field, and the row's loop over groups of four quads, each group's first
// triangles set up in one Tri4 and its second in another, the kept ones copied out lane by
// lane in quad order (the scalar build's order); the row's last quads by the scalar build.
#pragma once

#include <terralign/raster/geometry_kernels.hpp>

namespace terralign::raster {

// Four triangles set up, field by field, and the lanes kept (bit i: lane i).
struct Tri4 {
  alignas(16) std::int32_t X[3][4], Y[3][4];
  alignas(16) float A[3][4], B[3][4], C[3][4];
  alignas(16) std::int32_t box[4][4];
  unsigned keep;
};

// Lane i of t, as setup_triangle() writes a triangle and its box.
inline void copy_out(const Tri4& t, int i, Tri& out, PixelBox& box) {
  for (int k = 0; k < 3; ++k) {
    out.X[k] = t.X[k][i];
    out.Y[k] = t.Y[k][i];
    out.A[k] = t.A[k][i];
    out.B[k] = t.B[k][i];
    out.C[k] = t.C[k][i];
  }
  box = {t.box[0][i], t.box[1][i], t.box[2][i], t.box[3][i]};
}

// emit_quad_row through an ISA's Load4(g, k) (vertices k .. k + 3 of g) and
// Setup4(a, b, c, vw, vh, Tri4&) (setup_triangle() lane by lane), both inlined.
template <auto Load4, auto Setup4>
inline int emit_quad_row_by4(const ProjGrid& g, int top, int bottom, int n, bool anti, int vw, int vh, Tri* out,
                             PixelBox* boxes) {
  int count = 0, a0 = 0;
  Tri4 first, second;
  for (; a0 + 4 <= n; a0 += 4) {
    const auto v00 = Load4(g, top + a0), v10 = Load4(g, top + a0 + 1), v01 = Load4(g, bottom + a0), v11 = Load4(g, bottom + a0 + 1);
    Setup4(v00, v10, anti ? v01 : v11, vw, vh, first);
    Setup4(anti ? v10 : v00, v11, v01, vw, vh, second);
    for (int i = 0; i < 4; ++i) {
      if (first.keep >> i & 1) copy_out(first, i, out[count], boxes[count]), ++count;
      if (second.keep >> i & 1) copy_out(second, i, out[count], boxes[count]), ++count;
    }
  }
  if (a0 < n) count += emit_quad_row_scalar(g, top + a0, bottom + a0, n - a0, anti, vw, vh, out + count, boxes + count);
  return count;
}

}  // namespace terralign::raster
