// The renderer against independent references: a slow scalar ray-caster over the DEM, and
// the camera model's own projection of known checkerboard corners.
#include <algorithm>
#include <cmath>

#include <doctest/doctest.h>

#include <Eigen/Dense>

#include <terralign/raster/renderer.hpp>

#include "synthetic.hpp"

using namespace terralign;

namespace {

geo::Layer smooth_layer() {
  return test::make_layer("smooth", 1000, 1000, 0, 2000, 2.0, [](int x, int y, std::uint8_t* p) {
    p[0] = static_cast<std::uint8_t>(128 + 100 * std::sin(x * 0.05) * std::cos(y * 0.03));
    p[1] = static_cast<std::uint8_t>(128 + 90 * std::sin(x * 0.021 + y * 0.043));
    p[2] = static_cast<std::uint8_t>(128 + 80 * std::cos(y * 0.06));
  });
}

// Marches the ray in 0.5 m steps until it passes below the bilinear DEM, then bisects.
bool ray_cast(const geo::Map& map, const Eigen::Vector3d& c, const Eigen::Vector3d& d, Eigen::Vector3d& hit) {
  double t0 = 0;
  const double step = 0.5;
  for (int i = 0; i < 20000; ++i) {
    const double t1 = t0 + step;
    const Eigen::Vector3d p = c + t1 * d;
    const double h = map.dem.height_at(p.x(), p.y());
    if (std::isnan(h)) {
      if (p.z() < map.dem.min_height) return false;
      t0 = t1;
      continue;
    }
    if (p.z() <= h) {
      double a = t0, b = t1;
      for (int k = 0; k < 50; ++k) {
        const double m = 0.5 * (a + b);
        const Eigen::Vector3d q = c + m * d;
        const double hq = map.dem.height_at(q.x(), q.y());
        (std::isnan(hq) || q.z() > hq ? a : b) = m;
      }
      hit = c + b * d;
      return true;
    }
    t0 = t1;
  }
  return false;
}

void bilinear(const geo::Layer& L, double x, double y, double rgb[3]) {
  double u, v;
  L.transform.world_to_pixel(x, y, u, v);
  const int x0 = static_cast<int>(std::floor(u)), y0 = static_cast<int>(std::floor(v));
  const double fx = u - x0, fy = v - y0;
  for (int c = 0; c < 3; ++c) {
    auto at = [&](int xx, int yy) {
      xx = std::clamp(xx, 0, L.rgba.width() - 1);
      yy = std::clamp(yy, 0, L.rgba.height() - 1);
      return static_cast<double>(L.rgba.at(xx, yy, c));
    };
    rgb[c] = (1 - fy) * ((1 - fx) * at(x0, y0) + fx * at(x0 + 1, y0)) + fy * ((1 - fx) * at(x0, y0 + 1) + fx * at(x0 + 1, y0 + 1));
  }
}

}  // namespace

TEST_CASE("the rasterizer agrees with a scalar ray-caster: colour PSNR >= 35 dB, depth within 0.1 % median") {
  geo::CameraModel cam;
  cam.width = 160;
  cam.height = 120;
  cam.fx = cam.fy = 150;
  cam.cx = 79.5;
  cam.cy = 59.5;
  const geo::Map sloped = test::dem_map(201, 201, 0, 2000, 10.0, [](double x, double y) { return 100 + 0.08 * x - 0.05 * y; },
                                        smooth_layer());
  const geo::Map wavy = test::dem_map(251, 251, 0, 2000, 8.0, [](double x, double y) {
    return 150 + 35 * std::sin(x / 90.0) * std::cos(y / 70.0) + 8 * std::sin((x + y) / 23.0);
  }, smooth_layer());
  // The same with its bumps turned to run along the other diagonal of the posts, where coarse
  // chunks split their quads the other way (TerrainChunk::anti).
  const geo::Map turned = test::dem_map(251, 251, 0, 2000, 8.0, [](double x, double y) {
    return 150 + 35 * std::sin(x / 90.0) * std::cos(y / 70.0) + 8 * std::sin((x - y) / 23.0);
  }, smooth_layer());
  for (const geo::Map* map : {&sloped, &wavy, &turned}) {
    auto r = raster::Renderer::create(*map, cam);
    REQUIRE(r.ok());
    auto out = r.value()->make_output({"all"});
    REQUIRE(out.ok());
    // Tilted 35 degrees: the footprint spans near and far terrain (1.5-3 m per pixel, above
    // the 2 m texels only at the far edge, so the mip levels stay close to 0).
    const geo::Pose T = geo::pose_from_ypr({1000, 700, 560}, 15, 0, 0, geo::tilted_mount(35));
    REQUIRE(r.value()->render(T, out.value()).ok());
    double se = 0;
    long n = 0;
    std::vector<double> rel;
    for (int v = 0; v < cam.height; ++v)
      for (int u = 0; u < cam.width; ++u) {
        const Eigen::Vector3d d = (T.R() * Eigen::Vector3d((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0));
        Eigen::Vector3d hit;
        if (!ray_cast(*map, T.t_W_C, d.normalized(), hit)) continue;
        const double depth = (hit - T.t_W_C).dot(T.R().col(2));
        const float z = out->depth.at(u, v);
        if (!std::isfinite(z) || !out->valid[0].at(u, v)) continue;
        rel.push_back(std::abs(z - depth) / depth);
        double rgb[3];
        bilinear(map->layers[0], hit.x(), hit.y(), rgb);
        for (int c = 0; c < 3; ++c) {
          const double e = out->rgb[0].at(u, v, c) - rgb[c];
          se += e * e;
          ++n;
        }
      }
    REQUIRE(n > 3 * cam.width * cam.height * 9 / 10);  // nearly every pixel compared
    std::nth_element(rel.begin(), rel.begin() + static_cast<std::ptrdiff_t>(rel.size() / 2), rel.end());
    const double psnr = 10 * std::log10(255.0 * 255.0 / (se / static_cast<double>(n)));
    MESSAGE(map->dem.heights.width() << " posts: colour PSNR " << psnr << " dB, median depth error " << rel[rel.size() / 2] * 100 << " %");
    CHECK(psnr >= 35.0);
    CHECK(rel[rel.size() / 2] <= 1e-3);
  }
}

TEST_CASE("registration: checkerboard corners land where the camera model (with distortion) projects them, within 0.1 px") {
  // 4 m squares (8 texels of 0.5 m) over a flat map at z = 0.
  const geo::Map map = test::flat_map(0.0, test::make_layer("chk", 800, 800, 0, 400, 0.5, [](int x, int y, std::uint8_t* p) {
    const bool w = ((x / 8) + (y / 8)) % 2 == 0;
    p[0] = p[1] = p[2] = w ? 230 : 25;
  }));
  geo::CameraModel cam;
  cam.width = 320;
  cam.height = 240;
  cam.fx = 420;
  cam.fy = 418;
  cam.cx = 161.2;
  cam.cy = 118.7;
  cam.model = geo::DistortionModel::RadTan;
  cam.k = {-0.12, 0.03, 4e-4, -3e-4, 0.0};
  auto r = raster::Renderer::create(map, cam);
  REQUIRE(r.ok());
  auto out = r.value()->make_output({"chk"});
  REQUIRE(out.ok());
  const geo::Pose T = geo::pose_from_ypr({201.3, 198.6, 160}, 12, 3, -2);
  REQUIRE(r.value()->render(T, out.value()).ok());
  const ImageU8& img = out->rgb[0];
  int checked = 0;
  double worst = 0;
  std::vector<double> errs;
  for (int j = 2; j < 100; ++j)
    for (int i = 2; i < 100; ++i) {
      // Corner between squares: world (4 i, 400 - 4 j).
      const Eigen::Vector3d X(4.0 * i, 400.0 - 4.0 * j, 0.0);
      Eigen::Vector2d p;
      if (!cam.project<double>(T.inverse() * X, p)) continue;
      const int u0 = static_cast<int>(std::lround(p.x())), v0 = static_cast<int>(std::lround(p.y()));
      if (u0 < 4 || v0 < 4 || u0 > cam.width - 5 || v0 > cam.height - 5) continue;
      // A checkerboard corner is point-symmetric: opposite quadrants have the same colour, so
      // I(c + e) = I(c - e) for every offset e. Find c by a coarse-to-fine grid search of that
      // symmetry (bilinear image samples, offsets within 2 px); unbiased for any symmetric blur.
      auto sample = [&](double x, double y) {
        const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
        const double fx = x - x0, fy = y - y0;
        auto I = [&](int xx, int yy) { return static_cast<double>(img.at(xx, yy, 0)); };
        return (1 - fy) * ((1 - fx) * I(x0, y0) + fx * I(x0 + 1, y0)) + fy * ((1 - fx) * I(x0, y0 + 1) + fx * I(x0 + 1, y0 + 1));
      };
      auto asym = [&](double cx, double cy) {
        double e = 0;
        for (int dv = -2; dv <= 2; ++dv)
          for (int du = -2; du <= 2; ++du) {
            const double d = sample(cx + du * 0.8, cy + dv * 0.8) - sample(cx - du * 0.8, cy - dv * 0.8);
            e += d * d;
          }
        return e;
      };
      Eigen::Vector2d c(u0, v0);
      for (double step : {0.1, 0.01, 0.001}) {
        Eigen::Vector2d best = c;
        double be = asym(c.x(), c.y());
        for (int dy = -10; dy <= 10; ++dy)
          for (int dx = -10; dx <= 10; ++dx) {
            const double e = asym(c.x() + dx * step, c.y() + dy * step);
            if (e < be) {
              be = e;
              best = c + Eigen::Vector2d(dx * step, dy * step);
            }
          }
        c = best;
      }
      const Eigen::Vector2d s = c - Eigen::Vector2d(u0, v0);
      const double err = (Eigen::Vector2d(u0 + s.x(), v0 + s.y()) - p).norm();
      errs.push_back(err);
      worst = std::max(worst, err);
      ++checked;
    }
  std::sort(errs.begin(), errs.end());
  MESSAGE(checked << " corners, distance median " << errs[errs.size() / 2] << ", 99th " << errs[errs.size() * 99 / 100] << ", worst " << worst << " px");
  CHECK(checked > 100);
  CHECK(worst < 0.1);
}
