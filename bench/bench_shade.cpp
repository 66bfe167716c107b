// The texture shading kernels alone on a 752 x 480 frame's worth of rows as a flat view
// gives them (world x, y along each image row; one footprint), against the scalar kernel in
// the same run: how the vector kernels' texel fetches scale with the view. Nadir at several
// ground sample distances and headings (heading turns a row across texel rows, so a vector's
// taps span more of them), over a 2048^2 random texture with its mip chain.
//   build/release/bench/bench_shade
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <random>
#include <vector>

#include <terralign/raster/shade_kernels.hpp>

using namespace terralign::raster;

namespace {

struct Kernel {
  const char* name;
  ShadeRowFn fn;
};

}  // namespace

int main() {
  std::vector<Kernel> kernels{{"scalar", shade_row_scalar}};
#if defined(TERRALIGN_HAVE_AVX2)
  if (cpu_has_avx2()) kernels.push_back({"avx2", shade_row_avx2});
  if (cpu_has_avx512()) kernels.push_back({"avx512", shade_row_avx512});
#endif
#if defined(TERRALIGN_HAVE_NEON)
  kernels.push_back({"neon", shade_row_neon});
#endif
  // The texture: 5 m texels, random opaque colours, levels back to back with a guard texel
  // at each end (shade_kernels.hpp).
  std::mt19937 rng(1);
  const std::vector<MipLevel> levels = mip_chain(2048, 2048, 16);
  std::vector<std::uint32_t> texels(mip_chain_end(levels) + 1, 0xffffffffu);
  for (std::size_t k = 1; k < mip_chain_end(levels); ++k) texels[k] = rng() | 0xff000000u;
  const float texel_m = 5.0f;
  // World (0, 0) at texel (1000, 1000); v grows southwards.
  const std::vector<LevelCoords> coords = level_coords(levels, 1000.0, 1 / texel_m, 0.0, 1000.0, 0.0, -1 / texel_m);
  const ShadeParams p{texels.data(), levels.data(), coords.data(), static_cast<int>(levels.size()), -std::log2(texel_m)};
  const int W = 752, H = 480;
  std::vector<float> wx(W * H), wy(W * H), lf(W * H);
  std::vector<std::uint8_t> rgb(3 * W * H), valid(W * H), rgb_ref(3 * W * H), valid_ref(W * H);
  std::printf("| ground m/px | heading deg | texels per 8 pixels |");
  for (const Kernel& k : kernels) std::printf(" %s ms |", k.name);
  for (std::size_t i = 1; i < kernels.size(); ++i) std::printf(" %s / scalar |", kernels[i].name);
  std::printf("\n|---|---|---|");
  for (std::size_t i = 0; i < 2 * kernels.size() - 1; ++i) std::printf("---|");
  std::printf("\n");
  const double views[][2] = {{1.2, 0}, {2.1, 0}, {2.1, 30}, {4, 10}, {8, 0}, {12, 45}};
  for (const auto& view : views) {
    const double gsd = view[0], yaw = view[1] * 3.14159265358979323846 / 180;
    for (int r = 0; r < H; ++r)
      for (int c = 0; c < W; ++c) {
        const double east = (c - W / 2) * gsd, north = -(r - H / 2) * gsd;
        wx[static_cast<std::size_t>(r * W + c)] = static_cast<float>(std::cos(yaw) * east - std::sin(yaw) * north);
        wy[static_cast<std::size_t>(r * W + c)] = static_cast<float>(std::sin(yaw) * east + std::cos(yaw) * north);
        lf[static_cast<std::size_t>(r * W + c)] = static_cast<float>(std::log2(gsd));
      }
    // Best of 15 batches of 10 frames per kernel, the kernels in turn within each batch so
    // that a change in the machine's speed falls on all alike.
    std::vector<double> best(kernels.size(), 1e30);
    for (int batch = 0; batch < 15; ++batch)
      for (std::size_t k = 0; k < kernels.size(); ++k) {
        const auto t0 = std::chrono::steady_clock::now();
        for (int f = 0; f < 10; ++f)
          for (int r = 0; r < H; ++r) {
            const std::size_t o = static_cast<std::size_t>(r * W);
            kernels[k].fn(W, wx.data() + o, wy.data() + o, lf.data() + o, rgb.data() + 3 * o, valid.data() + o, p);
          }
        best[k] = std::min(best[k], std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / 10);
        if (k == 0) {
          rgb_ref = rgb;
          valid_ref = valid;
        } else if (rgb != rgb_ref || valid != valid_ref) {
          std::fprintf(stderr, "bench_shade: %s differs from the scalar kernel\n", kernels[k].name);
          return 1;
        }
      }
    std::printf("| %.1f | %.0f | %.1f |", gsd, view[1], 8 * gsd / texel_m);
    for (double b : best) std::printf(" %.3f |", 1e3 * b);
    for (std::size_t k = 1; k < kernels.size(); ++k) std::printf(" %.2f |", best[0] / best[k]);
    std::printf("\n");
    std::fflush(stdout);
  }
  return 0;
}
