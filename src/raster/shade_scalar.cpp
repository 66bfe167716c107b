// The scalar twin of shade_avx2.cpp: same operations, same order.
#include <terralign/raster/shade_kernels.hpp>

#include <cmath>

namespace terralign::raster {
namespace {

struct Acc {
  float r, g, b, a;
};

// Bilinear, alpha-weighted: texels off the level or with alpha 0 contribute nothing.
inline Acc sample(const ShadeParams& p, int level, float u, float v) {
  const MipLevel L = p.levels[level];
  const float ul = (u + 0.5f) * L.scale - 0.5f;
  const float vl = (v + 0.5f) * L.scale - 0.5f;
  const float fx0 = std::floor(ul), fy0 = std::floor(vl);
  const float fx = ul - fx0, fy = vl - fy0;
  const int x0 = static_cast<int>(fx0), y0 = static_cast<int>(fy0);
  const float w[4] = {(1.0f - fx) * (1.0f - fy), fx * (1.0f - fy), (1.0f - fx) * fy, fx * fy};
  Acc acc{0.0f, 0.0f, 0.0f, 0.0f};
  for (int k = 0; k < 4; ++k) {
    const int x = x0 + (k & 1), y = y0 + (k >> 1);
    const bool inside = x >= 0 && y >= 0 && x < L.width && y < L.height;
    const int xc = x < 0 ? 0 : (x >= L.width ? L.width - 1 : x);
    const int yc = y < 0 ? 0 : (y >= L.height ? L.height - 1 : y);
    const std::uint32_t t = p.texels[L.offset + yc * L.width + xc];
    const float wk = inside ? w[k] : 0.0f;
    const float wa = wk * static_cast<float>(t >> 24);
    acc.r = acc.r + wa * static_cast<float>(t & 255u);
    acc.g = acc.g + wa * static_cast<float>((t >> 8) & 255u);
    acc.b = acc.b + wa * static_cast<float>((t >> 16) & 255u);
    acc.a = acc.a + wa;
  }
  return acc;
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

void shade_row_scalar(int n, const float* wx, const float* wy, const float* log2fp,
                      std::uint8_t* rgb, std::uint8_t* valid, const ShadeParams& p) {
  const int top = p.n_levels - 1;
  for (int i = 0; i < n; ++i) {
    const float x = wx[i], y = wy[i];
    Acc acc{0.0f, 0.0f, 0.0f, 0.0f};
    if (x == x) {  // not NaN: the pixel sees terrain
      const float u = p.a0 + p.a1 * x + p.a2 * y;
      const float v = p.b0 + p.b1 * x + p.b2 * y;
      float lod = log2fp[i] + p.lod_bias;
      lod = lod > 0.0f ? lod : 0.0f;
      lod = lod < static_cast<float>(top) ? lod : static_cast<float>(top);
      const float fl = std::floor(lod);
      const int l0 = static_cast<int>(fl);
      const int l1 = l0 < top ? l0 + 1 : top;
      const float t = lod - fl;
      const Acc s0 = sample(p, l0, u, v);
      // With t = 0 the second level's weight is 0 and s0 * 1 + s1 * 0 == s0 exactly.
      const Acc s1 = t > 0.0f ? sample(p, l1, u, v) : Acc{0.0f, 0.0f, 0.0f, 0.0f};
      const float w0 = 1.0f - t;
      acc.r = s0.r * w0 + s1.r * t;
      acc.g = s0.g * w0 + s1.g * t;
      acc.b = s0.b * w0 + s1.b * t;
      acc.a = s0.a * w0 + s1.a * t;
    }
    // Valid where at least half of the filter's weight lands on valid texels.
    const bool ok = acc.a >= 127.5f;
    const float inv = ok ? 1.0f / acc.a : 0.0f;
    rgb[3 * i + 0] = static_cast<std::uint8_t>(static_cast<int>(acc.r * inv + 0.5f));
    rgb[3 * i + 1] = static_cast<std::uint8_t>(static_cast<int>(acc.g * inv + 0.5f));
    rgb[3 * i + 2] = static_cast<std::uint8_t>(static_cast<int>(acc.b * inv + 0.5f));
    valid[i] = ok ? 255 : 0;
  }
}

void resolve_row_scalar(int n, const int* ids, const float* coef, float dx0, float dy, float* wx, float* wy,
                        float* z, float* log2fp) {
  for (int i = 0; i < n; ++i) {
    if (ids[i] < 0) {
      wx[i] = wy[i] = z[i] = NAN;
      log2fp[i] = 0.0f;
      continue;
    }
    const float* c = coef + 9 * static_cast<std::ptrdiff_t>(ids[i]);
    const float dx = dx0 + static_cast<float>(i);
    const float iz = (c[0] + c[2] * dy) + c[1] * dx;
    const float zz = 1.0f / iz;
    const float x = ((c[3] + c[5] * dy) + c[4] * dx) * zz;
    const float y = ((c[6] + c[8] * dy) + c[7] * dx) * zz;
    z[i] = zz;
    wx[i] = x;
    wy[i] = y;
    // The footprint from the planes' derivatives: A (per column) = c[1], c[4], c[7];
    // B (per row) = c[2], c[5], c[8].
    const float du_x = (c[4] - x * c[1]) * zz, du_y = (c[7] - y * c[1]) * zz;
    const float dv_x = (c[5] - x * c[2]) * zz, dv_y = (c[8] - y * c[2]) * zz;
    const float su = du_x * du_x + du_y * du_y, sv = dv_x * dv_x + dv_y * dv_y;
    float d2 = su > sv ? su : sv;
    d2 = d2 > 1e-12f ? d2 : 1e-12f;
    log2fp[i] = 0.5f * fast_log2(d2);
  }
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

