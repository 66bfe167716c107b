// The scalar twin of evaluate_avx2.cpp: the same operations in the same order per lane.
// Built with -ffp-contract=off (CMakeLists.txt) so no compiler fuses a multiply and an add.
#include "evaluate_kernels.hpp"

#include <algorithm>

namespace terralign::iclk::detail {

void evaluate_se3_scalar(const Se3EvalInput& in, int i0, int i1, float* r, unsigned char* ok, Se3EvalSums& s) {
  for (int a = 0; a < 6; ++a) std::fill(s.g[a], s.g[a] + kLanes, 0.0f);
  std::fill(s.cost, s.cost + kLanes, 0.0f);
  std::fill(s.wsum, s.wsum + kLanes, 0.0f);
  s.valid = 0;
  s.n_out = 0;
  const float* R = in.R;
  const float umax = static_cast<float>(in.width - 1), vmax = static_cast<float>(in.height - 1);
  for (int i = i0; i < i1; ++i) {
    const int lane = (i - i0) % kLanes;
    const float x = in.px[i], y = in.py[i], z = in.pz[i];
    const float X = R[0] * x + R[1] * y + R[2] * z + in.t[0];
    const float Y = R[3] * x + R[4] * y + R[5] * z + in.t[1];
    const float Z = R[6] * x + R[7] * y + R[8] * z + in.t[2];
    const float u = in.fx * X / Z + in.cx;
    const float v = in.fy * Y / Z + in.cy;
    // NaN compares false: a NaN coordinate is outside.
    const bool inside = Z > 1e-6f && u >= 0.0f && v >= 0.0f && u <= umax && v <= vmax;
    ok[i] = inside;
    int x0 = 0, y0 = 0;
    float fx = 0.0f, fy = 0.0f;
    if (inside) {
      x0 = std::min(static_cast<int>(u), in.width - 2);
      y0 = std::min(static_cast<int>(v), in.height - 2);
      fx = u - static_cast<float>(x0);
      fy = v - static_cast<float>(y0);
      ++s.valid;
    } else {
      in.out[s.n_out++] = i;
    }
    for (int c = 0; c < in.channels; ++c) {
      float wr = 0.0f, res = 0.0f, w = 0.0f;
      if (inside) {
        const float* p = in.live + c * in.live_plane + static_cast<std::ptrdiff_t>(y0) * in.stride + x0;
        const float a = p[0], b = p[1], cc = p[in.stride], d = p[in.stride + 1];
        const float live = (1.0f - fy) * ((1.0f - fx) * a + fx * b) + fy * ((1.0f - fx) * cc + fx * d);
        res = live - in.val[c * in.plane + i];
        w = in.w[i];
        wr = w * res;
      }
      r[c * in.plane + i] = res;
      for (int k = 0; k < 6; ++k) s.g[k][lane] += wr * in.jac[k][c * in.jac_plane + i];
      s.cost[lane] += wr * res;
      s.wsum[lane] += w;
    }
  }
}

void se3_jacobians_scalar(const Se3JacobianInput& in, const int* xs, const int* ys, int count, Se3JacobianGroup& out,
                          Se3FinestSums* sums) {
  const std::ptrdiff_t row = static_cast<std::ptrdiff_t>(in.width) * in.channels;
  // dW's rows and the pixel's offset from the principal point per lane (+0 past count).
  float wu[6][kLanes] = {}, wv[6][kLanes] = {}, mu[kLanes] = {}, mv[kLanes] = {};
  for (int l = 0; l < count; ++l) {
    const int x = xs[l], y = ys[l];
    const float u = static_cast<float>(x), v = static_cast<float>(y);
    const float d = in.depth[static_cast<std::ptrdiff_t>(y) * in.width + x];
    const float X = d * (u - in.cx) / in.fx, Y = d * (v - in.cy) / in.fy, Z = d;
    const float iz = 1.0f / Z, xn = X * iz, yn = Y * iz;
    // The projection's derivatives du/dX, du/dZ, dv/dY, dv/dZ: [ux 0 uz; 0 vy vz] times
    // [-hat(X) I] gives the rows of dW.
    const float ux = in.fx * iz, uz = -in.fx * xn * iz, vy = in.fy * iz, vz = -in.fy * yn * iz;
    wu[0][l] = uz * Y;
    wu[1][l] = ux * Z + uz * -X;
    wu[2][l] = ux * -Y;
    wu[3][l] = ux;
    wu[5][l] = uz;
    wv[0][l] = vy * -Z + vz * Y;
    wv[1][l] = vz * -X;
    wv[2][l] = vy * X;
    wv[4][l] = vy;
    wv[5][l] = vz;
    const float* p = in.ref + static_cast<std::ptrdiff_t>(y) * row + static_cast<std::ptrdiff_t>(x) * in.channels;
    const std::ptrdiff_t dx = in.channels;
    for (int c = 0; c < in.channels; ++c, ++p) {
      const float gx = (p[dx - row] + 2.0f * p[dx] + p[dx + row] - p[-dx - row] - 2.0f * p[-dx] - p[-dx + row]) / 8.0f;
      const float gy = (p[row - dx] + 2.0f * p[row] + p[row + dx] - p[-row - dx] - 2.0f * p[-row] - p[-row + dx]) / 8.0f;
      for (int k = 0; k < 6; ++k) out.jac[k][c * out.jac_plane + l] = gx * wu[k][l] + gy * wv[k][l];
      out.val[c * out.plane + l] = p[0];
    }
    out.pu[l] = u;
    out.pv[l] = v;
    out.px[l] = X;
    out.py[l] = Y;
    out.pz[l] = Z;
    mu[l] = u - in.cx;
    mv[l] = v - in.cy;
  }
  if (!sums) return;
  // Lane by lane, the lanes innermost (the loops a compiler vectorises).
  int e = 0;
  for (int a = 0; a < 6; ++a)
    for (int b = 0; b <= a; ++b, ++e)
      for (int l = 0; l < kLanes; ++l) sums->motion[e][l] += wu[a][l] * wu[b][l] + wv[a][l] * wv[b][l];
  for (int a = 0; a < 6; ++a)
    for (int l = 0; l < kLanes; ++l) {
      const float radial = wu[a][l] * mu[l] + wv[a][l] * mv[l];
      sums->floor[a][0][l] += wu[a][l];
      sums->floor[a][1][l] += wv[a][l];
      sums->floor[a][2][l] += wv[a][l] * mu[l] - wu[a][l] * mv[l];
      sums->floor[a][3][l] += radial;
      sums->floor[a][4][l] += radial * mu[l];
      sums->floor[a][5][l] += radial * mv[l];
    }
}

namespace {

// Pixel at(k) of k in [0, count) into lane k mod kOuterLanes.
template <class At>
void outer_sums(const float* const* jac, const float* w, int count, At at, OuterSums& h) {
  for (int k = 0; k < count; ++k) {
    const int i = at(k), lane = k % kOuterLanes;
    const bool use = w[i] > 0.0f;  // NaN compares false
    const double wd = use ? static_cast<double>(w[i]) : 0.0;
    double j[6];
    for (int a = 0; a < 6; ++a) j[a] = use ? static_cast<double>(jac[a][i]) : 0.0;
    int e = 0;
    for (int a = 0; a < 6; ++a) {
      const double wj = wd * j[a];
      for (int b = 0; b <= a; ++b) h.h[e++][lane] += wj * j[b];
    }
  }
}

}  // namespace

void outer_sums_scalar(const float* const* jac, const float* w, int i0, int i1, OuterSums& h) {
  outer_sums(jac, w, i1 - i0, [i0](int k) { return i0 + k; }, h);
}

void outer_sums_at_scalar(const float* const* jac, const float* w, const int* index, int count, OuterSums& h) {
  outer_sums(jac, w, count, [index](int k) { return index[k]; }, h);
}

}  // namespace terralign::iclk::detail
