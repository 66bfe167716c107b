// The scalar twin of the shading kernels (shade_kernels.hpp: what they all compute), and the
// scalar depth and edge kernels.
#include <terralign/raster/shade_kernels.hpp>

#include <algorithm>
#include <cmath>

namespace terralign::raster {
namespace {

// lerp(a, b, f) of the filter's fixed point (shade_kernels.hpp).
inline int lerp15(int a, int b, int f) { return a + (((b - a) * f + 0x4000) >> 15); }

// A sample's four channels (RGBA, x128).
struct Sample {
  int c[4];
};

// Bilinear at one level; taps outside it read as 0.
inline Sample sample(const ShadeParams& p, int level, float x, float y) {
  const MipLevel L = p.levels[level];
  const LevelCoords& k = p.coords[level];
  const int U = static_cast<int>(std::floor(k.a0 + k.a1 * x + k.a2 * y));
  const int V = static_cast<int>(std::floor(k.b0 + k.b1 * x + k.b2 * y));
  const int x0 = U >> 8, y0 = V >> 8, fx = (U & 255) << 7, fy = (V & 255) << 7;
  std::uint32_t t[4];
  for (int j = 0; j < 4; ++j) {
    const int tx = x0 + (j & 1), ty = y0 + (j >> 1);
    const bool inside = tx >= 0 && ty >= 0 && tx < L.width && ty < L.height;
    t[j] = inside ? p.texels[L.offset + ty * L.width + tx] : 0u;
  }
  Sample s;
  for (int c = 0; c < 4; ++c) {
    int C[4];
    for (int j = 0; j < 4; ++j) C[j] = static_cast<int>((t[j] >> (8 * c)) & 255u) << 7;
    s.c[c] = lerp15(lerp15(C[0], C[1], fx), lerp15(C[2], C[3], fx), fy);
  }
  return s;
}

// One pixel that sees terrain at (x, y), or none (NaN x): 3 colour bytes and the validity byte.
inline void shade_pixel(const ShadeParams& p, float log2fp, float x, float y, std::uint8_t* rgb, std::uint8_t* valid) {
  Sample s{{0, 0, 0, 0}};
  if (x == x) {
    const LevelPair g = pixel_level(log2fp, p);
    s = sample(p, g.l0, x, y);
    if (g.t > 0) {
      const Sample s1 = sample(p, g.l1, x, y);
      for (int c = 0; c < 4; ++c) s.c[c] = lerp15(s.c[c], s1.c[c], g.t);
    }
  }
  const int a = s.c[3];
  const bool ok = a >= 16320;
  for (int c = 0; c < 3; ++c) {
    int o = 0;
    if (ok) {
      o = static_cast<int>(static_cast<float>(s.c[c] * 255) / static_cast<float>(a) + 0.5f);
      o = o < 255 ? o : 255;
    }
    rgb[c] = static_cast<std::uint8_t>(o);
  }
  *valid = ok ? 255 : 0;
}

}  // namespace

std::vector<MipLevel> mip_chain(int width, int height, int max_levels) {
  std::vector<MipLevel> levels;
  std::size_t offset = 1;
  float scale = 1.0f;
  for (int w = width, h = height;; w = (w + 1) / 2, h = (h + 1) / 2, scale *= 0.5f) {
    levels.push_back({static_cast<std::int32_t>(offset), w, h, scale});
    offset += static_cast<std::size_t>(w) * static_cast<std::size_t>(h);
    if ((w == 1 && h == 1) || static_cast<int>(levels.size()) >= max_levels) break;
  }
  return levels;
}

std::vector<LevelCoords> level_coords(const std::vector<MipLevel>& levels, double a0, double a1, double a2, double b0,
                                      double b1, double b2) {
  std::vector<LevelCoords> out;
  for (const MipLevel& L : levels) {
    const double s = L.scale, f = 256.0;
    out.push_back({static_cast<float>(((a0 + 0.5) * s - 0.5) * f), static_cast<float>(a1 * s * f), static_cast<float>(a2 * s * f),
                   static_cast<float>(((b0 + 0.5) * s - 0.5) * f), static_cast<float>(b1 * s * f), static_cast<float>(b2 * s * f)});
  }
  return out;
}

void shade_row_scalar(int n, const float* wx, const float* wy, const float* log2fp,
                      std::uint8_t* rgb, std::uint8_t* valid, const ShadeParams& p) {
  for (int i = 0; i < n; ++i) shade_pixel(p, log2fp[i], wx[i], wy[i], rgb + 3 * i, valid + i);
}

void resolve_shade_row_scalar(int n, const int* ids, const float* coef, float dx0, float dy, float* z, int n_targets,
                              const ShadeTarget* targets) {
  const float max_bias = max_lod_bias(n_targets, targets);
  for (int i = 0; i < n; ++i) {
    float x = NAN, y = NAN, l2 = 0.0f, bound = INFINITY;
    z[i] = NAN;
    if (ids[i] >= 0) {
      const float* c = coef + kPlaneFloats * static_cast<std::ptrdiff_t>(ids[i]);
      const float dx = dx0 + static_cast<float>(i);
      const float zz = 1.0f / ((c[0] + c[2] * dy) + c[1] * dx);
      x = ((c[3] + c[5] * dy) + c[4] * dx) * zz;
      y = ((c[6] + c[8] * dy) + c[7] * dx) * zz;
      z[i] = zz;
      bound = c[9];
      if (!entry_magnified(bound, max_bias)) l2 = plane_footprint_log2(c, dx, dy);
    }
    for (int k = 0; k < n_targets; ++k) {
      const ShadeParams& p = *targets[k].params;
      shade_pixel(p, entry_magnified(bound, p.lod_bias) ? -INFINITY : l2, x, y, targets[k].rgb + 3 * i, targets[k].valid + i);
    }
  }
}

float plane_footprint_bound_log2(const float* c, float dx0, float dx1, float dy0, float dy1) {
  const double q[9] = {c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8]};
  auto iz = [&](double dx, double dy) { return q[0] + q[1] * dx + q[2] * dy; };
  const double iz_min = std::min(std::min(iz(dx0, dy0), iz(dx1, dy0)), std::min(iz(dx0, dy1), iz(dx1, dy1)));
  if (!(iz_min > 0)) return INFINITY;
  // The numerators of d(x, y)/du (affine in dy) and d(x, y)/dv (affine in dx); each squared
  // length is convex along its variable, so its larger end is its largest.
  auto su = [&](double dy) {
    const double nx = (q[4] * q[0] - q[1] * q[3]) + (q[4] * q[2] - q[1] * q[5]) * dy;
    const double ny = (q[7] * q[0] - q[1] * q[6]) + (q[7] * q[2] - q[1] * q[8]) * dy;
    return nx * nx + ny * ny;
  };
  auto sv = [&](double dx) {
    const double nx = (q[5] * q[0] - q[2] * q[3]) + (q[5] * q[1] - q[2] * q[4]) * dx;
    const double ny = (q[8] * q[0] - q[2] * q[6]) + (q[8] * q[1] - q[2] * q[7]) * dx;
    return nx * nx + ny * ny;
  };
  const double iz2 = iz_min * iz_min;
  const double d2 = std::max(std::max(su(dy0), su(dy1)), std::max(sv(dx0), sv(dx1))) / (iz2 * iz2);
  if (!(d2 < 1e30)) return INFINITY;
  return 0.5f * fast_log2(std::max(static_cast<float>(d2), 1e-12f)) + 1.0f / 64.0f;
}

void depth_block_scalar(int w, int h, float base, float A, float B, int dx, int dy, float* z, int* id,
                        std::ptrdiff_t stride, int e) {
  for (int r = 0; r < h; ++r, z += stride, id += stride) {
    const float rowz = base + B * static_cast<float>(dy + r);
    for (int i = 0; i < w; ++i) {
      const float iz = rowz + A * static_cast<float>(dx + i);
      if (iz > z[i]) {
        z[i] = iz;
        id[i] = e;
      }
    }
  }
}

long edge_block_scalar(int w, int h, const std::int64_t* E, const std::int64_t* dEx, const std::int64_t* dEy, float base,
                       float A, float B, int dx, int dy, float* z, int* id, std::ptrdiff_t stride, int e) {
  long covered = 0;
  for (int r = 0; r < h; ++r, z += stride, id += stride) {
    const float rowz = base + B * static_cast<float>(dy + r);
    std::int64_t e0 = E[0] + dEy[0] * r, e1 = E[1] + dEy[1] * r, e2 = E[2] + dEy[2] * r;
    for (int i = 0; i < w; ++i, e0 += dEx[0], e1 += dEx[1], e2 += dEx[2]) {
      if ((e0 | e1 | e2) < 0) continue;
      ++covered;
      const float iz = rowz + A * static_cast<float>(dx + i);
      if (iz > z[i]) {
        z[i] = iz;
        id[i] = e;
      }
    }
  }
  return covered;
}

}  // namespace terralign::raster

