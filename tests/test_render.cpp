#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <new>
#include <random>
#include <string>
#include <utility>

#include <doctest/doctest.h>

#include <terralign/raster/geometry_kernels.hpp>
#include <terralign/raster/renderer.hpp>
#include <terralign/raster/shade_kernels.hpp>
#include <terralign/raster/terrain.hpp>

#include <Eigen/Geometry>

#include "alloc_counter.hpp"
#include "support.hpp"
#include "synthetic.hpp"

using namespace terralign;
using namespace terralign::raster;
using terralign::test::make_layer;

namespace {

geo::CameraModel camera(int w = 320, int h = 240, double f = 300) {
  geo::CameraModel c;
  c.width = w;
  c.height = h;
  c.fx = c.fy = f;
  c.cx = (w - 1) / 2.0;
  c.cy = (h - 1) / 2.0;
  return c;
}

// A smooth colour field over a 2 km square of 2 m texels.
geo::Layer smooth_layer() {
  return make_layer("smooth", 1000, 1000, 0, 2000, 2.0, [](int x, int y, std::uint8_t* p) {
    p[0] = static_cast<std::uint8_t>(128 + 100 * std::sin(x * 0.05) * std::cos(y * 0.03));
    p[1] = static_cast<std::uint8_t>(128 + 90 * std::sin(x * 0.021 + y * 0.043));
    p[2] = static_cast<std::uint8_t>(128 + 80 * std::cos(y * 0.06));
  });
}

geo::Pose look_down(double x, double y, double z, double tilt_deg = 0, double yaw_deg = 0) {
  return geo::pose_from_ypr({x, y, z}, yaw_deg, 0, 0, geo::tilted_mount(tilt_deg));
}

// 256 x 256 quads of 10 m over 2.56 km, rolling (to 56 m) with 6 m bumps, flooded to 10 m:
// lakes, flat where the ground lies lower.
geo::Map lake_map() {
  return test::dem_map(257, 257, 0, 2560, 10.0, [](double x, double y) {
    return std::max(10.0, 50 * std::sin(x / 150) * std::cos(y / 170) + 6 * std::sin(x * 0.09 + y * 0.07));
  }, smooth_layer());
}

std::unique_ptr<Renderer> make(const geo::Map& map, const geo::CameraModel& cam, RenderOptions opt = {}) {
  auto r = Renderer::create(map, cam, opt);
  REQUIRE(r.ok());
  return std::move(r.value());
}

}  // namespace

TEST_CASE("depth is the analytic ray-plane depth within 1e-5 relative, nadir and tilted 30 degrees") {
  const geo::Map map = test::flat_map(250.0, smooth_layer());
  const geo::CameraModel cam = camera();
  auto r = make(map, cam);
  auto out = r->make_output({"all"});
  REQUIRE(out.ok());
  for (double tilt : {0.0, 30.0}) {
    CAPTURE(tilt);
    const geo::Pose T = look_down(1000, 1000, 850, tilt, 20);
    RenderStats stats;
    REQUIRE(r->render(T, out.value(), &stats).ok());
    // The flat map is drawn as one quad, and most tiles lie wholly inside one of its
    // triangles: their pixels are resolved without a visibility buffer (raster_tile()).
    CHECK(stats.chunks_one_quad == stats.chunks);
    CHECK(stats.tiles_one_triangle >= 10);  // of 30 (20 and 14 seen)
    double worst = 0;
    int checked = 0;
    for (int v = 0; v < cam.height; ++v)
      for (int u = 0; u < cam.width; ++u) {
        const Eigen::Vector3d d = T.R() * Eigen::Vector3d((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0);
        const double t = (250.0 - T.t_W_C.z()) / d.z();  // depth along the axis: d_C.z = 1
        const float z = out->depth.at(u, v);
        REQUIRE(std::isfinite(z));
        worst = std::max(worst, std::abs(z - t) / t);
        ++checked;
      }
    CHECK(checked == cam.width * cam.height);
    CHECK(worst < 1e-5);
  }
}

TEST_CASE("no cracks and no double coverage: a flat view covers every pixel exactly once") {
  const geo::Map map = test::flat_map(0.0, smooth_layer());
  const geo::CameraModel cam = camera(301, 203, 250);  // odd sizes: partial tiles
  auto r = make(map, cam);
  auto out = r->make_output({"all"});
  REQUIRE(out.ok());
  for (double yaw : {0.0, 17.0, 45.0, 90.0}) {
    CAPTURE(yaw);
    RenderStats stats;
    REQUIRE(r->render(look_down(1000, 1000, 600, 10, yaw), out.value(), &stats).ok());
    // The flat grid has no skirts (its error is 0) and cannot occlude itself, so each pixel
    // passes exactly one triangle's coverage test: a crack makes fewer, a shared edge drawn
    // twice makes more.
    CHECK(stats.fragments == static_cast<long>(cam.width) * cam.height);
  }
  // From 600, 100 and 20 m, 10 to 70 degrees off nadir (the map's edge or the horizon in
  // view): chunks of one level drawn as one quad side by side, and beside chunks of other
  // levels taking their Square (seal_one_quads()). Where all are one quad (no skirts) every
  // pixel that sees the ground is covered once (elsewhere skirts may cover some twice), and
  // no pixel without terrain lies between two with.
  int one_quad_views = 0, side_by_side = 0, mixed = 0, cracks = 0;
  for (double alt : {600.0, 100.0, 20.0})
    for (double tilt : {10.0, 45.0, 70.0})
      for (double yaw : {0.0, 17.0, 45.0, 90.0}) {
        CAPTURE(alt);
        CAPTURE(tilt);
        CAPTURE(yaw);
        RenderStats stats;
        REQUIRE(r->render(look_down(1000, 1000, alt, tilt, yaw), out.value(), &stats).ok());
        one_quad_views += stats.chunks_one_quad > 0;
        side_by_side += stats.chunks_one_quad > 1;
        mixed += stats.chunks > 1 && stats.chunks_one_quad == 0;
        long seen = 0;
        const auto& d = out.value().depth;
        for (float z : d.pixels()) seen += std::isfinite(z);
        if (stats.chunks_one_quad == stats.chunks) CHECK(stats.fragments == seen);
        else CHECK(stats.fragments >= seen);
        for (int y = 1; y + 1 < cam.height; ++y)
          for (int x = 1; x + 1 < cam.width; ++x)
            if (!std::isfinite(d.at(x, y)))
              cracks += (std::isfinite(d.at(x - 1, y)) && std::isfinite(d.at(x + 1, y))) ||
                        (std::isfinite(d.at(x, y - 1)) && std::isfinite(d.at(x, y + 1)));
      }
  MESSAGE("36 views: " << one_quad_views << " drawn as one quad, " << side_by_side << " with several side by side, " << mixed
          << " with chunks of several levels (no one quad)");
  CHECK(one_quad_views >= 18);
  CHECK(side_by_side >= 9);
  CHECK(mixed >= 9);
  CHECK(cracks == 0);
}

TEST_CASE("a chunk's screen error bound holds at every point of its box moved up or down by the error") {
  // Seeded random camera attitudes (any), boxes 100-2000 m ahead and up to 30 degrees off the
  // axis, 1-300 m wide and 0-60 m tall, errors 0.1-2 m; points inside each box moved
  // vertically by the error and projected (f = 650 px). The bound is exact, not first order:
  // 1e-4 is allowed for float rounding. Both the box's own bound and the tighter one of its
  // 4 x 4 columns are checked.
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> unit(0, 1), sym(-1, 1);
  const float f = 650.0f;
  float worst = 0.0f, worst_cells = 0.0f, worst_isotropic = 0.0f, tightest = 1.0f, loosest = 0.0f;
  int boxes = 0;
  for (int trial = 0; trial < 500; ++trial) {
    const Eigen::Quaternionf q = Eigen::Quaternionf(sym(rng), sym(rng), sym(rng), sym(rng)).normalized();
    const Eigen::Matrix3f R_W_C = q.toRotationMatrix(), R_C_W = R_W_C.transpose();
    const Eigen::Vector3f t(sym(rng) * 1000, sym(rng) * 1000, 300 + 500 * unit(rng));
    const float depth = 100 + 1900 * unit(rng), off = 0.55f * depth;
    const Eigen::Vector3f centre = t + R_W_C * Eigen::Vector3f(off * sym(rng), off * sym(rng), depth);
    const float w = 1 + 299 * unit(rng), h = 300 * unit(rng) * unit(rng), tall = 60 * unit(rng);
    TerrainChunk c{};
    c.min_x = centre.x() - w / 2, c.max_x = centre.x() + w / 2;
    c.min_y = centre.y() - h / 2, c.max_y = centre.y() + h / 2;
    c.min_z = centre.z() - tall / 2, c.max_z = centre.z() + tall / 2;
    const float e = 0.1f + 1.9f * unit(rng);
    const float bound = chunk_screen_error_px(c, e, R_C_W, t, f, 1.0f);
    const float bound_cells = chunk_screen_error_px(c, e, R_C_W, t, f, 1.0f, kMaxErrorCells);
    if (!std::isfinite(bound)) continue;
    ++boxes;
    REQUIRE(std::isfinite(bound_cells));
    // Points projected in double: the float difference of two projections loses up to 1e-3 of it.
    const Eigen::Matrix3d R = R_C_W.cast<double>();
    tightest = std::min(tightest, bound_cells / bound);
    loosest = std::max(loosest, bound_cells / bound);
    for (int k = 0; k < 64; ++k) {
      const Eigen::Vector3f P(c.min_x + w * (k < 8 ? static_cast<float>(k & 1) : unit(rng)),
                              c.min_y + h * (k < 8 ? static_cast<float>(k >> 1 & 1) : unit(rng)),
                              c.min_z + tall * (k < 8 ? static_cast<float>(k >> 2 & 1) : unit(rng)));
      for (float sign : {-1.0f, 1.0f}) {
        const Eigen::Vector3d a = R * (P - t).cast<double>(), b = R * (P + Eigen::Vector3f(0, 0, sign * e) - t).cast<double>();
        const float moved = static_cast<float>(f * std::hypot(b.x() / b.z() - a.x() / a.z(), b.y() / b.z() - a.y() / a.z()));
        worst = std::max(worst, moved / bound);
        worst_cells = std::max(worst_cells, moved / bound_cells);
        // The distance-only estimate, f e / |P - t|, misses the perspective's stretch off the
        // axis, even inside a 752 x 480 image's field of view.
        if (std::abs(a.x()) < 0.58f * a.z() && std::abs(a.y()) < 0.37f * a.z())
          worst_isotropic = std::max(worst_isotropic, moved / (f * e / (P - t).norm()));
      }
    }
  }
  CHECK(boxes > 400);
  CHECK(worst <= 1.0001f);
  CHECK(worst_cells <= 1.0001f);
  CHECK(worst > 0.5f);  // and it is not loose everywhere
  CHECK(loosest <= 1.0f + 1e-6f);  // the columns never loosen the bound
  CHECK(tightest < 0.8f);          // and tighten it where a box's depth varies
  MESSAGE("screen error: worst moved / bound " << worst << " (columns " << worst_cells << "); columns / box bound "
          << tightest << " .. " << loosest << "; moved / (f e / distance) up to " << worst_isotropic);
}

TEST_CASE("terrain level of detail: skirts only between chunks whose borders differ, and no crack") {
  // 256 x 256 quads of 10 m: one root chunk (level 4) over 2.56 km, rolling with 6 m bumps.
  const geo::Map map = test::dem_map(257, 257, 0, 2560, 10.0, [](double x, double y) {
    return 50 * std::sin(x / 150) * std::cos(y / 170) + 6 * std::sin(x * 0.09 + y * 0.07);
  }, smooth_layer());
  const geo::CameraModel cam = camera(320, 240, 300);
  {
    // A bound no chunk exceeds: the root alone, whole in view, and nothing across its
    // borders to leave a crack against: its 16 x 16 quads and no skirt.
    RenderOptions opt;
    opt.lod_error_px = 1e6;
    auto r = make(map, cam, opt);
    auto out = r->make_output({"smooth"});
    REQUIRE(out.ok());
    RenderStats stats;
    REQUIRE(r->render(look_down(1280, 1280, 6000), out.value(), &stats).ok());
    CHECK(stats.chunks == 1);
    CHECK(stats.triangles == 2 * 16 * 16);
  }
  // Oblique views over chunks of several levels, the map's edge out of view: a pixel with no
  // terrain between two with terrain at about one depth would be a crack. A bound of 4 px
  // (not the default 0.5) makes the gaps the skirts must close several pixels wide: without
  // skirts this counts 48. The same over bumps whose crests run north-south, where many
  // chunks are drawn with a grid twice as fine along the post rows (Wide) beside Square ones
  // of their level and of others.
  const geo::Map ridged = test::dem_map(257, 257, 0, 2560, 10.0, [](double x, double y) {
    return 50 * std::sin(x / 150) * std::cos(y / 170) + 6 * std::sin(x * 0.042);
  }, smooth_layer());
  // And over rolling ground with lakes, whose chunks wholly on the water offer one quad
  // (kOneQuad), which they may not take beside the Square and finer chunks of the shores
  // (seal_one_quads(): without that rule this view set counts a crack).
  const geo::Map lakes = lake_map();
  RenderOptions opt;
  opt.lod_error_px = 4;
  int cracks = 0, several_chunks = 0, one_way = 0, one_quad = 0;
  for (const geo::Map* m : {&map, &ridged, &lakes}) {
    auto r = make(*m, cam, opt);
    auto out = r->make_output({"smooth"});
    REQUIRE(out.ok());
    for (int k = 0; k < 24; ++k) {
      RenderStats stats;
      const double yaw = 15.0 * k, tilt = 15 + 5 * (k % 6);
      REQUIRE(r->render(look_down(1280 + 200 * std::cos(k), 1280 + 200 * std::sin(k), 300, tilt, yaw), out.value(), &stats).ok());
      several_chunks += stats.chunks > 1;
      one_way += stats.chunks_one_way;
      one_quad += stats.chunks_one_quad;
      const auto& d = out.value().depth;
      for (int y = 1; y + 1 < cam.height; ++y)
        for (int x = 1; x + 1 < cam.width; ++x) {
          if (std::isfinite(d.at(x, y))) continue;
          // Terrain on both sides, left and right or above and below, at about one depth.
          const auto across = [](float a, float b) {
            return std::isfinite(a) && std::isfinite(b) && std::max(a, b) < 1.1f * std::min(a, b);
          };
          cracks += across(d.at(x - 1, y), d.at(x + 1, y)) || across(d.at(x, y - 1), d.at(x, y + 1));
        }
    }
  }
  MESSAGE(one_way << " chunks drawn Wide or Tall, " << one_quad << " as one quad in the 72 views");
  CHECK(several_chunks == 72);
  CHECK(one_way > 48);
  CHECK(cracks == 0);
}

TEST_CASE("a chunk's grids (square, twice as fine along one axis, one quad, either diagonal) each bound their surface by their error") {
  // 256 x 256 quads of 10 m, rolling, with 6 m bumps 15 posts apart whose crests run along one
  // diagonal of the posts (x - y constant: post (i, j) to (i + 1, j + 1), the full-resolution
  // surface's own diagonal, crosses them), along the other, or north-south (down the posts'
  // columns, x constant: no diagonal follows them; a grid finer along the post rows does).
  auto bumps = [](int way) {
    return test::dem_map(257, 257, 0, 2560, 10.0, [way](double x, double y) {
      const double across = way == 0 ? (x - y) * 0.03 : way == 1 ? (x + y) * 0.03 : x * 0.042;
      return 50 * std::sin(x / 150) * std::cos(y / 170) + 6 * std::sin(across);
    }, smooth_layer());
  };
  // And a fourth: rolling ground with lakes, where chunks wholly on the water offer one quad.
  const geo::Map maps[4] = {bumps(0), bumps(1), bumps(2), lake_map()};
  int anti[4] = {0, 0, 0, 0}, coarse[4] = {0, 0, 0, 0}, wide[4] = {0, 0, 0, 0}, tall[4] = {0, 0, 0, 0};
  int one_quad[4] = {0, 0, 0, 0};
  double worst = 0;  // the most a drawn surface leaves its chunk's error, metres
  ThreadPool pool(3);
  for (int m = 0; m < 4; ++m) {
    const Terrain t = Terrain::build(maps[m], 0, 0, 0);
    // Measured by three threads: the same numbers.
    const Terrain threaded = Terrain::build(maps[m], 0, 0, 0, &pool);
    REQUIRE(threaded.chunks().size() == t.chunks().size());
    for (std::size_t i = 0; i < t.chunks().size(); ++i) {
      const TerrainChunk &a = t.chunks()[i], &b = threaded.chunks()[i];
      for (int g = 0; g < kChunkGrids; ++g) REQUIRE((a.error[g] == b.error[g] && a.anti[g] == b.anti[g]));
      REQUIRE((a.min_x == b.min_x && a.max_y == b.max_y && a.min_z == b.min_z && a.max_z == b.max_z && a.child[3] == b.child[3]));
    }
    auto height = [&t](int i, int j) {
      float x, y, z;
      t.post(i, j, x, y, z);
      return static_cast<double>(z);
    };
    // A surface through posts every si along i and sj along j from (i0, j0), its quads split
    // from (i, j) to (i + si, j + sj), or the other way: at (u, v) posts.
    auto surface = [&](double u, double v, int i0, int j0, int si, int sj, int qi, int qj, bool other) {
      const int i = i0 + std::min(static_cast<int>((u - i0) / si), qi - 1) * si;
      const int j = j0 + std::min(static_cast<int>((v - j0) / sj), qj - 1) * sj;
      const double fx = (u - i) / si, fy = (v - j) / sj;
      const double h00 = height(i, j), h10 = height(i + si, j), h01 = height(i, j + sj), h11 = height(i + si, j + sj);
      if (other)
        return fx + fy <= 1 ? h00 + fx * (h10 - h00) + fy * (h01 - h00) : h11 + (1 - fx) * (h01 - h11) + (1 - fy) * (h10 - h11);
      return fx >= fy ? h00 + fx * (h10 - h00) + fy * (h11 - h10) : h00 + fy * (h01 - h00) + fx * (h11 - h01);
    };
    for (const TerrainChunk& c : t.chunks()) {
      one_quad[m] += std::isfinite(c.error[kOneQuad]);
      if (c.level == 0) {
        CHECK_FALSE(c.anti[kSquare]);
        CHECK(c.error[kSquare] == 0.0f);
        CHECK(c.error[kWide] == INFINITY);
      } else {
        ++coarse[m];
        anti[m] += c.anti[kSquare];
        wide[m] += c.error[kWide] < 0.5f * c.error[kSquare];
        tall[m] += c.error[kTall] < 0.5f * c.error[kSquare];
      }
      // Every offered grid's surface against the full-resolution one every quarter post: the
      // two are linear between posts and the crossings of the coarse diagonals with
      // full-resolution edges, which for the Square grids lie on quarter posts (this finds
      // their largest distance exactly) and for the others also at thirds or elsewhere (a
      // lower bound).
      CHECK(std::isfinite(c.error[kSquare]));
      for (int g = 0; g < kChunkGrids; ++g) {
        CAPTURE(g);
        if (c.level == 0 && g != kOneQuad) continue;  // the Square is the full resolution
        if (!std::isfinite(c.error[g])) continue;  // not offered: no better than the Square
        if (g == kWide || g == kTall) CHECK(c.error[g] < c.error[kSquare]);
        if (g == kOneQuad) CHECK(c.error[g] <= std::max(c.error[kSquare], kOneQuadSlack));
        double drawn = 0, kept = 0;
        for (int b = 0; b <= 4 * c.span; ++b)
          for (int a = 0; a <= 4 * c.span; ++a) {
            const double u = c.i0 + a / 4.0, v = c.j0 + b / 4.0;
            const double full = surface(u, v, c.i0, c.j0, 1, 1, c.span, c.span, false);
            auto with = [&](bool other) {
              return surface(u, v, c.i0, c.j0, c.step_i(g), c.step_j(g), c.quads_i(g), c.quads_j(g), other);
            };
            drawn = std::max(drawn, std::abs(with(c.anti[g]) - full));
            if (c.anti[g]) kept = std::max(kept, std::abs(with(false) - full));
          }
        worst = std::max(worst, drawn - c.error[g]);
        // The other diagonal only where it fits better (or, on the lakes' flat water, ties
        // within the float rounding of the two measures).
        if (c.anti[g]) CHECK(drawn < kept + 1e-4);
      }
    }
  }
  MESSAGE("coarse chunks split the other way: " << anti[0] << ", " << anti[1] << ", " << anti[2] << " of " << coarse[0]
          << " (bumps across the diagonal, along it, north-south); Wide under half the Square's error " << wide[0] << ", "
          << wide[1] << ", " << wide[2] << ", Tall " << tall[0] << ", " << tall[1] << ", " << tall[2]
          << "; a drawn surface over its error by at most " << worst << " m");
  // Heights to 56 m in float: their rounding is 4e-6 m; 1e-4 m allows for the error's sums.
  CHECK(worst <= 1e-4);
  // The bumps cut by the full-resolution diagonal: the other one nearly everywhere (not
  // where the 50 m roll matters more); along it, rarely. North-south: a grid finer along the
  // post rows (Wide) fits far better than the Square at most levels, one finer down the
  // columns (Tall) almost nowhere.
  // One quad only on the lakes, where a chunk lies wholly on the water (its error 0).
  MESSAGE("chunks offering one quad: " << one_quad[0] << ", " << one_quad[1] << ", " << one_quad[2] << ", lakes "
          << one_quad[3] << " of " << maps[3].dem.heights.size() / 256 << " or more");
  CHECK(one_quad[0] + one_quad[1] + one_quad[2] == 0);
  CHECK(one_quad[3] >= 20);
  CHECK(anti[0] >= coarse[0] * 9 / 10);
  CHECK(anti[1] <= coarse[1] / 10);
  CHECK(wide[2] >= coarse[2] / 2);
  CHECK(tall[2] <= coarse[2] / 10);
  // Views over the two diagonal maps then need about as many triangles: four headings, 40
  // degrees off nadir, from the same place (the maps are not quite mirror images: the roll
  // is not); over the north-south bumps, some chunks are drawn Wide.
  const geo::CameraModel cam = camera(320, 240, 300);
  long tris[3] = {0, 0, 0};
  int one_way[3] = {0, 0, 0};
  // (The lakes are the crack test's; these views compare the three bumpy maps.)
  for (int m = 0; m < 3; ++m) {
    auto r = make(maps[m], cam);
    auto out = r->make_output({"smooth"});
    REQUIRE(out.ok());
    for (int k = 0; k < 4; ++k) {
      RenderStats st;
      REQUIRE(r->render(look_down(1280, 1280, 400, 40, 45 + 90 * k), out.value(), &st).ok());
      tris[m] += st.triangles;
      one_way[m] += st.chunks_one_way;
    }
  }
  MESSAGE("four views: " << tris[0] << ", " << tris[1] << " and " << tris[2] << " triangles; " << one_way[0] << ", "
          << one_way[1] << " and " << one_way[2] << " chunks drawn Wide or Tall");
  // Without the choice of diagonal the first took 3.4x the second's (31736 against 9302);
  // with it, within 10 %.
  CHECK(std::abs(tris[0] - tris[1]) <= tris[1] / 10);
  CHECK(one_way[2] > 0);
}

TEST_CASE("one ortho texel east moves a nadir image by exactly f * texel / height pixels") {
  // 1 m texels seen from 250 m with f = 500 px: 1 m = 2 px.
  const geo::Map map = test::flat_map(0.0, make_layer("t", 600, 600, 0, 600, 1.0, [](int x, int y, std::uint8_t* p) {
    p[0] = static_cast<std::uint8_t>((x * 37 + y * 11) % 251);
    p[1] = static_cast<std::uint8_t>((x * 5 + y * 23) % 241);
    p[2] = static_cast<std::uint8_t>((x ^ y) & 255);
  }));
  const geo::CameraModel cam = camera(200, 150, 500);
  auto r = make(map, cam);
  auto a = r->make_output({"t"}), b = r->make_output({"t"});
  REQUIRE((a.ok() && b.ok()));
  REQUIRE(r->render(look_down(300.25, 300.5, 250), a.value()).ok());
  REQUIRE(r->render(look_down(301.25, 300.5, 250), b.value()).ok());
  // Moving east moves the scene 2 px left: b(u, v) == a(u + 2, v).
  int worst = 0;
  for (int v = 0; v < cam.height; ++v)
    for (int u = 0; u + 2 < cam.width; ++u)
      for (int c = 0; c < 3; ++c)
        worst = std::max(worst, std::abs(b->rgb[0].at(u, v, c) - a->rgb[0].at(u + 2, v, c)));
  CHECK(worst <= 1);  // float rounding of texel coordinates may flip one level
}

TEST_CASE("the level of detail is log2(ground footprint / texel): a footprint of 4 texels takes level 2") {
  // fast_log2 within 0.005 of log2 (a quadratic in the mantissa; the bound is its fit's
  // error, 0.00494) over 40 octaves.
  double worst = 0;
  for (double x = 1e-6; x < 1e6; x *= 1.001) worst = std::max(worst, std::abs(fast_log2(static_cast<float>(x)) - std::log2(x)));
  CHECK(worst < 0.005);
  // A nadir plane 250 m below (1/z = 1/250) whose pixels step 2 m east and 2 m south: the
  // footprint is 2 m a pixel, log2 = 1 (planes as the fused kernel takes them, at the tile's
  // corner: x = (x0/z + 2/z dx) z).
  const float iz = 1.0f / 250.0f;
  const float c[9] = {iz, 0.0f, 0.0f, 100.0f * iz, 2.0f * iz, 0.0f, 50.0f * iz, 0.0f, -2.0f * iz};
  for (float dx : {0.0f, 13.0f, 63.0f})
    for (float dy : {0.0f, 31.0f}) CHECK(plane_footprint_log2(c, dx, dy) == doctest::Approx(1.0).epsilon(0.005));
  // Texels of 0.5 m (lod_bias = -log2(0.5) = 1): lod = 2, so level 2 with (almost) no blend
  // towards level 3. A footprint taken half a level too large would blend in level 3 halfway.
  const std::vector<MipLevel> levels = mip_chain(64, 64, 16);
  const std::vector<LevelCoords> coords = level_coords(levels, 0, 2, 0, 0, 0, -2);
  std::vector<std::uint32_t> texels(mip_chain_end(levels) + 1, 0xff808080u);
  const ShadeParams p{texels.data(), levels.data(), coords.data(), static_cast<int>(levels.size()), 1.0f};
  const LevelPair g = pixel_level(plane_footprint_log2(c, 5.0f, 5.0f), p);
  CHECK(g.l0 == 2);
  CHECK(g.t < 32768 / 100);  // within 0.01 of a level
}

TEST_CASE("a triangle's footprint bound holds at every pixel of its box in the tile, and is tight seen nadir") {
  // Seeded random planes as a tile sees them: 1/z 1/2000 .. 1/50 at the corner, changing by
  // up to 2 % a pixel (steep oblique views), and x/z, y/z whose footprints are 0.01-20 m a
  // pixel, in any direction; random boxes inside a 64 x 32 tile. The kernels take level 0
  // without a footprint where the bound says so (entry_magnified), so a pixel above its bound
  // would be shaded at the wrong level.
  std::mt19937 rng(99);
  std::uniform_real_distribution<float> u(-1, 1), unit(0, 1);
  int finite = 0, cases = 0;
  float worst_excess = -INFINITY;  // the largest pixel footprint minus its bound (must be < 0)
  for (; cases < 3000; ++cases) {
    const float iz = 1.0f / (50.0f + 1950.0f * unit(rng));
    const float scale = iz * std::pow(10.0f, -2.0f + 3.3f * unit(rng));
    const float c[9] = {iz,
                        0.02f * iz * u(rng),
                        0.02f * iz * u(rng),
                        iz * 500 * u(rng),
                        scale * u(rng),
                        scale * u(rng),
                        iz * 500 * u(rng),
                        scale * u(rng),
                        scale * u(rng)};
    int x0 = static_cast<int>(rng() % 64), x1 = static_cast<int>(rng() % 64);
    int y0 = static_cast<int>(rng() % 32), y1 = static_cast<int>(rng() % 32);
    if (x0 > x1) std::swap(x0, x1);
    if (y0 > y1) std::swap(y0, y1);
    const float bound = plane_footprint_bound_log2(c, static_cast<float>(x0), static_cast<float>(x1), static_cast<float>(y0),
                                                   static_cast<float>(y1));
    if (!std::isfinite(bound)) {
      // Only where 1/z is not positive at some corner of the box.
      const float lo = std::min(std::min(c[0] + c[1] * x0 + c[2] * y0, c[0] + c[1] * x1 + c[2] * y0),
                                std::min(c[0] + c[1] * x0 + c[2] * y1, c[0] + c[1] * x1 + c[2] * y1));
      CHECK(lo <= 1e-6f * iz);
      continue;
    }
    ++finite;
    for (int y = y0; y <= y1; ++y)
      for (int x = x0; x <= x1; ++x)
        worst_excess = std::max(worst_excess, plane_footprint_log2(c, static_cast<float>(x), static_cast<float>(y)) - bound);
  }
  CHECK(finite > cases * 3 / 4);
  CHECK(worst_excess < 0.0f);
  MESSAGE("footprint bound: largest pixel minus bound " << worst_excess << " (log2 units) over " << finite << " boxes");
  // Seen nadir the footprint is the same at every pixel: the bound is it plus the margin
  // (1/64) and at most fast_log2's error (0.005).
  const float iz = 1.0f / 250.0f;
  const float nadir[9] = {iz, 0.0f, 0.0f, 100.0f * iz, 2.0f * iz, 0.0f, 50.0f * iz, 0.0f, -2.0f * iz};
  const float b = plane_footprint_bound_log2(nadir, 0, 63, 0, 31);
  CHECK(b > 1.0f);
  CHECK(b < 1.0f + 1.0f / 64 + 0.005f);
}

TEST_CASE("no-data texels do not darken their neighbours, at any level of detail") {
  // One colour over 1 m texels, with 8 x 8 blocks of no-data on a diagonal lattice; seen from
  // heights where the filter magnifies, takes level 1 and blends levels 2 and 3. The mip chain
  // of premultiplied texels and the filter's division by its alpha leave every valid pixel
  // the layer's colour (to the rounding of the fixed point, 1); a filter of straight colours
  // would mix no-data's black in at the blocks' edges.
  geo::Layer L = make_layer("c", 600, 600, 0, 600, 1.0, [](int, int, std::uint8_t* p) {
    p[0] = 200;
    p[1] = 120;
    p[2] = 40;
  });
  for (int y = 0; y < 600; ++y)
    for (int x = 0; x < 600; ++x)
      if (((x / 8) + (y / 8)) % 3 == 0) {
        L.rgba.at(x, y, 3) = 0;
        --L.valid_pixels;
      }
  const geo::Map map = test::flat_map(0.0, std::move(L));
  const geo::CameraModel cam = camera(200, 150, 500);
  auto r = make(map, cam);
  auto o = r->make_output({"c"});
  REQUIRE(o.ok());
  for (double height : {150.0, 900.0, 2600.0}) {  // 0.3, 1.8 and 5.2 m a pixel
    CAPTURE(height);
    REQUIRE(r->render(look_down(300.3, 299.6, height), o.value()).ok());
    int valid = 0, invalid = 0, worst = 0;
    for (int v = 0; v < cam.height; ++v)
      for (int u = 0; u < cam.width; ++u) {
        if (o->valid[0].at(u, v, 0) == 0) {
          ++invalid;
          continue;
        }
        ++valid;
        const int want[3] = {200, 120, 40};
        for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(o->rgb[0].at(u, v, c) - want[c]));
      }
    // A third of the texels are no-data; at 5 m a pixel many pixels straddle a block.
    CHECK(valid > cam.width * cam.height / 4);
    CHECK(invalid > cam.width * cam.height / 20);  // the blocks still show as no-data
    CHECK(worst <= 1);
  }
}

TEST_CASE("1, 2 and 3 threads, and the scalar and vector (AVX2, AVX-512 or NEON) kernels, give the same bytes, on a pool of its own or the caller's") {
  const geo::Map map = test::dem_map(257, 257, 0, 2000, 7.8125, [](double x, double y) {
    return 100 + 30 * std::sin(x * 0.004) * std::cos(y * 0.006);
  }, smooth_layer());
  const geo::CameraModel cam = camera(333, 211, 280);
  RenderOptions one;
  one.threads = 1;
  one.simd = RenderOptions::Simd::Scalar;
  RenderOptions two;
  two.threads = 2;
  RenderOptions three;  // an odd count: the geometry's and the tiles' runs split unevenly
  three.threads = 3;
  auto r1 = make(map, cam, one);
  auto r2 = make(map, cam, two);
  auto r3 = make(map, cam, three);
  MESSAGE("kernels with 2 threads: " << std::string(r2->simd_name()));
  // Where the CPU has AVX-512 (r2, r3), also the AVX2 kernels (with the scalar entry set-up).
  RenderOptions avx2 = two;
  avx2.simd = RenderOptions::Simd::Avx2;
  auto r4 = make(map, cam, cpu_has_avx2() ? avx2 : two);
  // On a caller's pool of three (as a localizer's, shared with its aligner); one of two
  // threads is refused for three.
  ThreadPool pool3(3), pool2(2);
  auto shared = Renderer::create(map, cam, three, &pool3);
  REQUIRE(shared.ok());
  auto r5 = std::move(shared.value());
  auto mismatch = Renderer::create(map, cam, three, &pool2);
  REQUIRE_FALSE(mismatch.ok());
  CHECK(mismatch.error().message == "render threads 3 but the pool given has 2");
  auto o1 = r1->make_output({"all"}), o2 = r2->make_output({"all"}), o3 = r3->make_output({"all"}), o4 = r4->make_output({"all"}),
       o5 = r5->make_output({"all"});
  REQUIRE((o1.ok() && o2.ok() && o3.ok() && o4.ok() && o5.ok()));
  for (const geo::Pose& T : {look_down(900, 1100, 900), look_down(700, 600, 500, 50, 30)}) {
    RenderStats s1, s3;
    REQUIRE(r1->render(T, o1.value(), &s1).ok());
    REQUIRE(r2->render(T, o2.value()).ok());
    REQUIRE(r3->render(T, o3.value(), &s3).ok());
    REQUIRE(r4->render(T, o4.value()).ok());
    REQUIRE(r5->render(T, o5.value()).ok());
    CHECK(s1.chunks > 3);  // enough chunks that every thread draws some
    CHECK(s1.triangles == s3.triangles);
    for (const RenderOutput* o : {&o2.value(), &o3.value(), &o4.value(), &o5.value()}) {
      CHECK(o1->rgb[0].pixels() == o->rgb[0].pixels());
      CHECK(o1->valid[0].pixels() == o->valid[0].pixels());
      CHECK(std::memcmp(o1->depth.data(), o->depth.data(), o1->depth.size() * sizeof(float)) == 0);
    }
  }
}

TEST_CASE("a distorted camera's render is the same bytes on 1, 2 and 3 threads") {
  const geo::Map map = test::dem_map(257, 257, 0, 2000, 7.8125, [](double x, double y) {
    return 100 + 30 * std::sin(x * 0.004) * std::cos(y * 0.006);
  }, smooth_layer());
  geo::CameraModel cam = camera(333, 211, 280);
  cam.model = geo::DistortionModel::RadTan;
  cam.k = {-0.12, 0.03, 4e-4, -3e-4, 0.0};
  std::vector<std::unique_ptr<Renderer>> r;
  std::vector<RenderOutput> o;
  for (int threads = 1; threads <= 3; ++threads) {
    RenderOptions opt;
    opt.threads = threads;
    r.push_back(make(map, cam, opt));
    auto out = r.back()->make_output({"all"});
    REQUIRE(out.ok());
    o.push_back(std::move(out.value()));
  }
  const geo::Pose T = look_down(700, 600, 500, 50, 30);
  for (std::size_t k = 0; k < r.size(); ++k) REQUIRE(r[k]->render(T, o[k]).ok());
  CHECK(std::count(o[0].valid[0].pixels().begin(), o[0].valid[0].pixels().end(), std::uint8_t{255}) > 333 * 211 / 2);
  for (std::size_t k = 1; k < r.size(); ++k) {
    CHECK(o[0].rgb[0].pixels() == o[k].rgb[0].pixels());
    CHECK(o[0].valid[0].pixels() == o[k].valid[0].pixels());
    CHECK(std::memcmp(o[0].depth.data(), o[k].depth.data(), o[0].depth.size() * sizeof(float)) == 0);
  }
}

TEST_CASE("render options out of range are refused, naming the option and its value") {
  const geo::Map map = test::dem_map(65, 65, 0, 2000, 31.25, [](double, double) { return 10.0; }, smooth_layer());
  auto refused = [&](RenderOptions o, const char* what) {
    auto r = Renderer::create(map, camera(), o);
    REQUIRE_FALSE(r.ok());
    CHECK_MESSAGE(r.error().message.find(what) != std::string::npos, r.error().message);
  };
  RenderOptions o;
  o.threads = 0;
  refused(o, "render threads 0");
  o.threads = 65;
  refused(o, "render threads 65");
  o = {};
  o.lod_error_px = NAN;
  refused(o, "lod_error_px");
  o = {};
  o.max_triangles = 100;
  refused(o, "max_triangles 100");
  o = {};
  o.threads = 4;
  o.max_triangles = 1 << 24;  // each thread's slots would reserve 2.3 GB
  refused(o, "threads x max_triangles (4 x 16777216)");
  o.threads = 3;
  o.max_triangles = 1 << 20;
  CHECK(Renderer::create(map, camera(), o).ok());
}

// The vector builds of a kernel that this CPU runs, by name (a null build: not in this
// build); none, and a message saying so, where there is none.
template <class Fn>
std::vector<std::pair<const char*, Fn>> vector_builds(Fn avx2, Fn avx512, Fn neon) {
  std::vector<std::pair<const char*, Fn>> builds;
  if (avx2 && cpu_has_avx2()) builds.emplace_back("avx2", avx2);
  if (avx512 && cpu_has_avx512()) builds.emplace_back("avx512", avx512);
  if (neon) builds.emplace_back("neon", neon);
  if (builds.empty()) MESSAGE("this CPU or build has no vector build of the kernel: nothing to compare");
  return builds;
}
#if defined(TERRALIGN_HAVE_AVX2)
#define VECTOR_BUILDS(kernel) vector_builds<decltype(&kernel##_scalar)>(kernel##_avx2, kernel##_avx512, nullptr)
#elif defined(TERRALIGN_HAVE_NEON)
#define VECTOR_BUILDS(kernel) vector_builds<decltype(&kernel##_scalar)>(nullptr, nullptr, kernel##_neon)
#else
#define VECTOR_BUILDS(kernel) vector_builds<decltype(&kernel##_scalar)>(nullptr, nullptr, nullptr)
#endif

// The 32-bit edge kernel and the run of small entries drawn through it, where this CPU has
// them (AVX2's serve the AVX-512 renderer too); nulls elsewhere.
struct SmallEntryKernels {
  EdgeBlock32Fn edge32 = nullptr;
  DrawSmallEntriesFn draw = nullptr;
};
SmallEntryKernels built_small_entry_kernels() {
#if defined(TERRALIGN_HAVE_AVX2)
  if (cpu_has_avx2()) return {edge_block32_avx2, draw_small_entries_avx2};
#elif defined(TERRALIGN_HAVE_NEON)
  return {edge_block32_neon, draw_small_entries_neon};
#endif
  return {};
}

TEST_CASE("the shading (alone and fused with the resolve) and depth kernels agree bit for bit on seeded random inputs (AVX2, AVX-512, NEON vs scalar)") {
  struct Kernels {
    const char* name;
    ShadeRowFn shade;
    ResolveShadeRowFn resolve_shade;
    DepthBlockFn depth;
    EdgeBlockFn edge;
  };
  std::vector<Kernels> vector_kernels;
#if defined(TERRALIGN_HAVE_AVX2)
  if (cpu_has_avx2()) vector_kernels.push_back({"avx2", shade_row_avx2, resolve_shade_row_avx2, depth_block_avx2, edge_block_avx2});
  if (cpu_has_avx512()) vector_kernels.push_back({"avx512", shade_row_avx512, resolve_shade_row_avx512, depth_block_avx512, edge_block_avx2});
#endif
#if defined(TERRALIGN_HAVE_NEON)
  vector_kernels.push_back({"neon", shade_row_neon, resolve_shade_row_neon, depth_block_neon, edge_block_neon});
#endif
  if (vector_kernels.empty()) MESSAGE("this CPU or build has no vector shading kernel: nothing to compare");
  std::mt19937 rng(12345);
  // Premultiplied texels (a colour never above its alpha): mostly opaque, some no-data, some
  // half-transparent (as a mip level has them at the edge of no-data). A guard texel at each
  // end, as the renderer's arrays have (shade_kernels.hpp); opaque white, so a kernel that
  // gave one a weight would change the colours compared below.
  const std::vector<MipLevel> levels = mip_chain(37, 23, 16);
  std::vector<std::uint32_t> texels{0xffffffffu};
  for (const MipLevel& L : levels)
    for (int k = 0; k < L.width * L.height; ++k) {
      const std::uint32_t a = k % 7 == 0 ? 0u : k % 11 == 0 ? 128u : 255u;
      std::uint32_t t = a << 24;
      for (int c = 0; c < 3; ++c) t |= (rng() % (a + 1)) << (8 * c);
      texels.push_back(t);
    }
  texels.push_back(0xffffffffu);
  const std::vector<LevelCoords> coords = level_coords(levels, 3.0, 0.9, 0.1, 5.0, -0.05, 1.1);
  const ShadeParams p{texels.data(), levels.data(), coords.data(), static_cast<int>(levels.size()), 0.3f};
  std::uniform_real_distribution<float> pos(-2, 30), fp(-3, 6);  // a few pixels off the edges
  const int n = 1003;  // vectors of every width and a tail
  std::vector<float> wx(n), wy(n), lf(n);
  for (int i = 0; i < n; ++i) {
    wx[i] = pos(rng);
    wy[i] = pos(rng);
    lf[i] = i % 5 == 0 ? -0.3f : fp(rng);  // some at a whole level (fraction 0)
    if (i % 13 == 0 || (i >= 32 && i < 48)) wx[i] = NAN;  // no terrain, a whole vector of it too
  }
  std::vector<std::uint8_t> rgb_s(3 * n), val_s(n);
  auto compare_shading = [&](const Kernels& k) {
    CAPTURE(std::string(k.name));
    std::vector<std::uint8_t> rgb_v(3 * n), val_v(n);
    k.shade(n, wx.data(), wy.data(), lf.data(), rgb_v.data(), val_v.data(), p);
    CHECK(rgb_s == rgb_v);
    CHECK(val_s == val_v);
  };
  shade_row_scalar(n, wx.data(), wy.data(), lf.data(), rgb_s.data(), val_s.data(), p);
  int valid = 0, partial = 0;
  for (int i = 0; i < n; ++i) valid += val_s[static_cast<std::size_t>(i)] != 0;
  CHECK(valid > n / 4);  // the test exercises real samples, not only invalid pixels
  for (const Kernels& k : vector_kernels) compare_shading(k);
  // Positions well inside the texture at levels 0-2, so that every vector's taps are all
  // inside (the kernels' shortcut past the edge masks), and NaN lanes among them.
  std::uniform_real_distribution<float> inner(1, 12), inner_fp(-3, 1.5f);
  for (int i = 0; i < n; ++i) {
    wx[i] = i % 29 == 0 ? NAN : inner(rng);
    wy[i] = inner(rng);
    lf[i] = inner_fp(rng);
  }
  shade_row_scalar(n, wx.data(), wy.data(), lf.data(), rgb_s.data(), val_s.data(), p);
  for (int i = 0; i < n; ++i) {
    const int r = rgb_s[3 * static_cast<std::size_t>(i)], a = val_s[static_cast<std::size_t>(i)];
    partial += a != 0 && r > 0 && r < 255;
  }
  CHECK(partial > 10);
  for (const Kernels& k : vector_kernels) compare_shading(k);
  // Rows of pixels as a render has them: runs of 16 along a line, 0.05-1.4 world units
  // (about texels) apart in eight directions, at level 0 alone or trilinear between 0 and 1,
  // starting anywhere up to the level's far edges. Most vectors' taps then lie in a few
  // neighbouring texel rows (the kernels' row windows instead of gathers), some too far apart
  // (gathers), some across the edges.
  std::uniform_real_distribution<float> start_x(-1, 38), start_y(-2, 18), step(0.05f, 1.4f);
  const float angles[8] = {0.0f, 0.03f, 0.1f, 3.1f, 2.9f, 0.5f, 1.6f, -0.05f};  // mostly along texel rows
  int window = 0, gathered = 0;
  for (int i = 0; i < n; i += 16) {
    const float sx = start_x(rng), sy = start_y(rng), d = step(rng);
    const float angle = angles[(i / 16) % 8];
    const float level_lf = (i / 16) % 3 == 2 ? 0.2f : -1.0f;
    for (int j = i; j < std::min(n, i + 16); ++j) {
      wx[j] = sx + d * std::cos(angle) * static_cast<float>(j - i);
      wy[j] = sy + d * std::sin(angle) * static_cast<float>(j - i);
      lf[j] = level_lf;
    }
    // How the 8-lane vectors at level 0 split: inside the level, the taps within 8 columns
    // and 4 rows (the AVX2 window) or not.
    for (int j = i; j + 8 <= std::min(n, i + 16); j += 8) {
      int xlo = 1 << 30, xhi = -xlo, ylo = xlo, yhi = -xlo;
      bool inside = true;
      for (int k = j; k < j + 8; ++k) {
        const int x0 = static_cast<int>(std::floor((coords[0].a0 + coords[0].a1 * wx[k] + coords[0].a2 * wy[k]) / 256));
        const int y0 = static_cast<int>(std::floor((coords[0].b0 + coords[0].b1 * wx[k] + coords[0].b2 * wy[k]) / 256));
        inside = inside && x0 >= 0 && x0 < levels[0].width - 1 && y0 >= 0 && y0 < levels[0].height - 1;
        xlo = std::min(xlo, x0), xhi = std::max(xhi, x0), ylo = std::min(ylo, y0), yhi = std::max(yhi, y0);
      }
      if (inside) (xhi - xlo <= 6 && yhi - ylo <= 4 ? window : gathered) += 1;
    }
  }
  CHECK(window > 30);    // the inputs reach the row windows ...
  CHECK(gathered > 10);  // ... and the gathers next to them
  shade_row_scalar(n, wx.data(), wy.data(), lf.data(), rgb_s.data(), val_s.data(), p);
  for (const Kernels& k : vector_kernels) compare_shading(k);
  // The same rows over an opaque texture (as most of a real layer is): the vector kernels'
  // shortcut for vectors whose every tap is opaque, (S_c + 64) >> 7.
  std::vector<std::uint32_t> saved = texels;
  for (std::size_t k = 1; k + 1 < texels.size(); ++k) texels[k] = rng() | 0xff000000u;
  shade_row_scalar(n, wx.data(), wy.data(), lf.data(), rgb_s.data(), val_s.data(), p);
  int opaque = 0;
  for (auto v : val_s) opaque += v != 0;
  CHECK(opaque > n / 2);
  for (const Kernels& k : vector_kernels) compare_shading(k);
  texels.swap(saved);  // back to the texture with no-data and transparency
  {
    // A chain of more than eight levels (the AVX2 kernel picks a lane's level from two vectors
    // of eight), lanes straddling levels 5-9: each vector's 16 lanes at footprints around one
    // of those levels, the lanes' levels differing.
    const std::vector<MipLevel> big = mip_chain(600, 520, 16);
    REQUIRE(big.size() >= 10);
    std::vector<std::uint32_t> bt{0xffffffffu};
    for (const MipLevel& L : big)
      for (int k = 0; k < L.width * L.height; ++k) bt.push_back(rng() | 0xff000000u);
    bt.push_back(0xffffffffu);
    const std::vector<LevelCoords> bc = level_coords(big, 1.0, 1.0, 0.0, 2.0, 0.0, 1.0);
    const ShadeParams bp{bt.data(), big.data(), bc.data(), static_cast<int>(big.size()), 0.0f};
    std::uniform_real_distribution<float> where(-20, 620), jitter(-0.6f, 0.6f);
    for (int i = 0; i < n; i += 16) {
      const float level = 5.0f + static_cast<float>((i / 16) % 5);
      const float x = where(rng), y = where(rng);
      for (int j = i; j < std::min(n, i + 16); ++j) {
        wx[j] = x + 40.0f * static_cast<float>(j - i);
        wy[j] = y;
        lf[j] = level + jitter(rng);
      }
    }
    std::vector<std::uint8_t> rgb_b(3 * n), val_b(n);
    shade_row_scalar(n, wx.data(), wy.data(), lf.data(), rgb_b.data(), val_b.data(), bp);
    int shaded = 0;
    for (auto v : val_b) shaded += v != 0;
    CHECK(shaded > n / 2);
    for (const Kernels& k : vector_kernels) {
      CAPTURE(std::string(k.name));
      std::vector<std::uint8_t> rgb_v(3 * n), val_v(n);
      k.shade(n, wx.data(), wy.data(), lf.data(), rgb_v.data(), val_v.data(), bp);
      CHECK(rgb_b == rgb_v);
      CHECK(val_b == val_v);
    }
  }

  // The fused kernel: a row of 93 pixels (vectors and a tail) seeing five tilted planes in
  // runs of every length from 1 to 9, vectors of one plane, of several, and of none (-1), shading two layers (the second's texel coordinates and bias differ). Each plane
  // passes world (15, 10) at the row's middle and runs over the texture and off it, its
  // footprint 0.1-4 world units a pixel (levels 0-2). The entries' footprint bounds (c[9])
  // take every path: none (+inf, NaN), the true bound over the row, and values that make an
  // entry magnified for both layers (entry 5, plane 2's twin) or for the second only (entry
  // 2; the layers' biases are 0.3 and 0.1): the kernels follow c[9] as given, whether or not
  // it bounds the pixels, and plane 2 seen here would take levels 0-1 by its own footprint.
  const int m = 93;
  std::vector<float> coef;
  for (int e = 0; e < 5; ++e) {
    const float s = std::array<float, 5>{10, 40, 100, 200, 400}[static_cast<std::size_t>(e)];
    const float q0 = 0.002f, ax = 2e-5f * s, bx = -1e-5f * s;
    for (float v : {q0, -1.3e-6f, 2.1e-6f, 15 * q0 - 50 * ax, ax, 1e-5f * s, 10 * q0 - 50 * bx, bx, 2e-5f * s}) coef.push_back(v);
    coef.push_back(INFINITY);
  }
  coef[kPlaneFloats * 1 + 9] = NAN;
  coef[kPlaneFloats * 3 + 9] = plane_footprint_bound_log2(coef.data() + 3 * kPlaneFloats, 5.0f, 5.0f + m, 7.0f, 7.0f);
  for (int k = 0; k < kPlaneFloats; ++k) coef.push_back(coef[static_cast<std::size_t>(2 * kPlaneFloats + k)]);
  coef[kPlaneFloats * 2 + 9] = -0.2f;  // magnified for the second layer only
  coef[kPlaneFloats * 5 + 9] = -1.0f;  // for both
  std::vector<int> ids;
  for (int run = 1; static_cast<int>(ids.size()) < m; ++run)
    for (int i = 0; i < run % 10 && static_cast<int>(ids.size()) < m; ++i) ids.push_back(run % 6 - 1);
  for (int i = 16; i < 32; ++i) ids[static_cast<std::size_t>(i)] = 3;  // one plane over a whole vector
  for (int i = 32; i < 48; ++i) ids[static_cast<std::size_t>(i)] = -1;  // and no terrain over one
  for (int i = 48; i < 64; ++i) ids[static_cast<std::size_t>(i)] = i % 4 < 2 ? 5 : 2;  // where planes 2 and 5 are seen
  const std::vector<LevelCoords> coords2 = level_coords(levels, 1.5, 0.7, -0.2, 2.0, 0.1, 0.8);
  const ShadeParams p2{texels.data(), levels.data(), coords2.data(), static_cast<int>(levels.size()), 0.1f};
  struct Fused {
    std::vector<float> z;
    std::vector<std::uint8_t> rgb[2], valid[2];
  };
  // A row of entries `row` from column dx0 (of row 7), through kernel fn.
  auto fused = [&](ResolveShadeRowFn fn, const std::vector<int>& row, float dx0) {
    Fused f;
    f.z.assign(row.size(), 7.0f);
    for (int k = 0; k < 2; ++k) {
      f.rgb[k].assign(3 * row.size(), 1);
      f.valid[k].assign(row.size(), 1);
    }
    const ShadeTarget targets[2] = {{&p, f.rgb[0].data(), f.valid[0].data()}, {&p2, f.rgb[1].data(), f.valid[1].data()}};
    fn(static_cast<int>(row.size()), row.data(), coef.data(), dx0, 7.0f, f.z.data(), 2, targets);
    return f;
  };
  // Every vector kernel's row against the scalar's, bit for bit.
  auto same_as_scalar = [&](const std::vector<int>& row, float dx0, const Fused& ref_row) {
    for (const Kernels& k : vector_kernels) {
      CAPTURE(std::string(k.name));
      const Fused f = fused(k.resolve_shade, row, dx0);
      CHECK(std::memcmp(f.z.data(), ref_row.z.data(), f.z.size() * sizeof(float)) == 0);
      for (int t = 0; t < 2; ++t) {
        CHECK(f.rgb[t] == ref_row.rgb[t]);
        CHECK(f.valid[t] == ref_row.valid[t]);
      }
    }
  };
  const Fused ref = fused(resolve_shade_row_scalar, ids, 5.0f);
  // The fused kernel is the documented resolve followed by shade_row: the same bits.
  {
    std::vector<float> x(m), y(m), z(m), l2(m);
    for (int i = 0; i < m; ++i) {
      x[static_cast<std::size_t>(i)] = y[static_cast<std::size_t>(i)] = z[static_cast<std::size_t>(i)] = NAN;
      l2[static_cast<std::size_t>(i)] = 0.0f;
      if (ids[static_cast<std::size_t>(i)] < 0) continue;
      const float* c = coef.data() + kPlaneFloats * ids[static_cast<std::size_t>(i)];
      const float dx = 5.0f + static_cast<float>(i), dy = 7.0f;
      const float zz = 1.0f / ((c[0] + c[2] * dy) + c[1] * dx);
      z[static_cast<std::size_t>(i)] = zz;
      x[static_cast<std::size_t>(i)] = ((c[3] + c[5] * dy) + c[4] * dx) * zz;
      y[static_cast<std::size_t>(i)] = ((c[6] + c[8] * dy) + c[7] * dx) * zz;
      l2[static_cast<std::size_t>(i)] = plane_footprint_log2(c, dx, dy);
    }
    CHECK(std::memcmp(z.data(), ref.z.data(), z.size() * sizeof(float)) == 0);
    const ShadeParams* ps[2] = {&p, &p2};
    int magnified[2] = {0, 0};
    for (int k = 0; k < 2; ++k) {
      // Level 0 alone (log2fp = -inf) where the entry's bound says this layer is magnified.
      std::vector<float> l2k = l2;
      for (int i = 0; i < m; ++i) {
        const int e = ids[static_cast<std::size_t>(i)];
        if (e >= 0 && entry_magnified(coef[static_cast<std::size_t>(kPlaneFloats * e + 9)], ps[k]->lod_bias)) {
          l2k[static_cast<std::size_t>(i)] = -INFINITY;
          ++magnified[k];
        }
      }
      std::vector<std::uint8_t> rgb(3 * static_cast<std::size_t>(m)), val(static_cast<std::size_t>(m));
      shade_row_scalar(m, x.data(), y.data(), l2k.data(), rgb.data(), val.data(), *ps[k]);
      CHECK(rgb == ref.rgb[k]);
      CHECK(val == ref.valid[k]);
      // The rule changes shown pixels (their own footprints would take coarser levels).
      std::vector<std::uint8_t> rgb_own(rgb.size()), val_own(val.size());
      shade_row_scalar(m, x.data(), y.data(), l2.data(), rgb_own.data(), val_own.data(), *ps[k]);
      int changed = 0;
      for (int i = 0; i < m; ++i)
        changed += val[static_cast<std::size_t>(i)] != 0 &&
                   std::memcmp(&rgb[3 * static_cast<std::size_t>(i)], &rgb_own[3 * static_cast<std::size_t>(i)], 3) != 0;
      CHECK(changed >= 4);
    }
    CHECK(magnified[0] >= 8);             // entry 5's
    CHECK(magnified[1] > magnified[0]);   // and entry 2's, for the second layer only
    int levels_seen = 0;  // the pixels' levels differ (the planes' footprints span levels)
    for (int i = 0; i < m; ++i)
      if (ids[static_cast<std::size_t>(i)] >= 0) levels_seen |= 1 << pixel_level(l2[static_cast<std::size_t>(i)], p).l0;
    CHECK(__builtin_popcount(static_cast<unsigned>(levels_seen)) >= 2);
    int shown = 0;
    for (auto v : ref.valid[0]) shown += v != 0;
    CHECK(shown > 10);
  }
  same_as_scalar(ids, 5.0f, ref);
  // Whole chunks magnified for a layer: a row of 160 pixels over entry 5 (magnified for both
  // layers), then entry 2 (for the second only), which the vector kernels take by their
  // level-0 path (every lane of a chunk magnified) and by their general one.
  {
    std::vector<int> whole(160, 5);
    for (std::size_t i = 128; i < whole.size(); ++i) whole[i] = 2;
    const Fused ref_whole = fused(resolve_shade_row_scalar, whole, 30.0f);
    int shown = 0;
    for (auto v : ref_whole.valid[0]) shown += v != 0;
    CHECK(shown >= 12);  // the small texture spans 15 of the first chunk's pixels (22-36)
    same_as_scalar(whole, 30.0f, ref_whole);
  }
  // And over the opaque texture (the shortcut, as above).
  texels.swap(saved);
  same_as_scalar(ids, 5.0f, fused(resolve_shade_row_scalar, ids, 5.0f));
  texels.swap(saved);
  // The depth kernel: blocks of every width 1..kDepthBlockMaxW and height 1..8 written into a
  // 44 x 10 buffer holding other triangles' depths (some nearer, some farther), with a row
  // stride (8 columns to spare past the widest block, as the renderer's rows have).
  const int stride = kDepthBlockMaxW + 12;
  std::vector<float> z0(static_cast<std::size_t>(stride) * 10);
  std::vector<int> id0(z0.size());
  std::uniform_real_distribution<float> zd(0.0005f, 0.0015f);
  for (std::size_t i = 0; i < z0.size(); ++i) {
    z0[i] = i % 9 == 0 ? 0.0f : zd(rng);
    id0[i] = static_cast<int>(i % 5) - 1;
  }
  z0[stride + 2] = 0.0f;  // every block's first pixel is empty, so every block writes
  int changed = 0;
  for (int bw = 1; bw <= kDepthBlockMaxW; ++bw)
    for (int bh = 1; bh <= 8; ++bh) {
      std::vector<float> zs = z0;
      std::vector<int> is = id0;
      depth_block_scalar(bw, bh, 0.001f, 1.3e-5f, -0.7e-5f, 3, 5, zs.data() + stride + 2, is.data() + stride + 2, stride, 7);
      changed += zs != z0;
      for (const Kernels& k : vector_kernels) {
        CAPTURE(std::string(k.name));
        CAPTURE(bw);
        CAPTURE(bh);
        std::vector<float> zv = z0;
        std::vector<int> iv = id0;
        k.depth(bw, bh, 0.001f, 1.3e-5f, -0.7e-5f, 3, 5, zv.data() + stride + 2, iv.data() + stride + 2, stride, 7);
        CHECK(std::memcmp(zs.data(), zv.data(), zs.size() * sizeof(float)) == 0);
        CHECK(is == iv);
      }
    }
  CHECK(changed == kDepthBlockMaxW * 8);  // every block wrote some pixels (the comparison is not of no-ops)
  // The edge kernel: 200 seeded triangles' edge functions (28.8 fixed point, as the renderer's)
  // crossing blocks of every size; covered counts, depths and ids compared. Every second
  // triangle's functions are scaled by 2^20, as a large triangle's outgrow 32 bits: the same
  // pixels covered (the scalar kernel's count checks it), in the 64-bit kernel alone.
  std::uniform_int_distribution<std::int64_t> corner(-6 * 65536, 6 * 65536), slope(-3 * 65536, 3 * 65536);
  std::uniform_int_distribution<int> side(1, 8);
  long covered_total = 0, blocks_partly = 0;
  int compared32 = 0;
  for (int tri = 0; tri < 200; ++tri) {
    const std::int64_t Ec[3] = {corner(rng), corner(rng), corner(rng)};
    const std::int64_t dx_[3] = {slope(rng), slope(rng), slope(rng)}, dy_[3] = {slope(rng), slope(rng), slope(rng)};
    const int bw = side(rng), bh = side(rng);
    const std::int64_t scale = tri % 2 == 1 ? std::int64_t{1} << 20 : 1;
    const std::int64_t Eb[3] = {Ec[0] * scale, Ec[1] * scale, Ec[2] * scale};
    const std::int64_t dxb[3] = {dx_[0] * scale, dx_[1] * scale, dx_[2] * scale}, dyb[3] = {dy_[0] * scale, dy_[1] * scale, dy_[2] * scale};
    std::vector<float> zs = z0;
    std::vector<int> is = id0;
    const long ns = edge_block_scalar(bw, bh, Eb, dxb, dyb, 0.001f, 1.3e-5f, -0.7e-5f, 3, 5, zs.data() + stride + 2,
                                      is.data() + stride + 2, stride, 7);
    if (scale > 1) {
      std::vector<float> zu = z0;
      std::vector<int> iu = id0;
      CHECK(ns == edge_block_scalar(bw, bh, Ec, dx_, dy_, 0.001f, 1.3e-5f, -0.7e-5f, 3, 5, zu.data() + stride + 2, iu.data() + stride + 2,
                                    stride, 7));
    }
    covered_total += ns;
    blocks_partly += ns > 0 && ns < bw * bh;
    for (const Kernels& k : vector_kernels) {
      CAPTURE(std::string(k.name));
      CAPTURE(tri);
      std::vector<float> zv = z0;
      std::vector<int> iv = id0;
      const long nv = k.edge(bw, bh, Eb, dxb, dyb, 0.001f, 1.3e-5f, -0.7e-5f, 3, 5, zv.data() + stride + 2, iv.data() + stride + 2,
                             stride, 7);
      CHECK(ns == nv);
      CHECK(std::memcmp(zs.data(), zv.data(), zs.size() * sizeof(float)) == 0);
      CHECK(is == iv);
    }
    // The 32-bit kernel on the same block, unscaled: every value fits (|E| < 6 * 2^16 + 14 * 3 * 2^16).
    const EdgeBlock32Fn edge32 = built_small_entry_kernels().edge32;
    if (edge32 && scale == 1) {
      const std::int32_t E32[3] = {static_cast<std::int32_t>(Ec[0]), static_cast<std::int32_t>(Ec[1]), static_cast<std::int32_t>(Ec[2])};
      const std::int32_t dx32[3] = {static_cast<std::int32_t>(dx_[0]), static_cast<std::int32_t>(dx_[1]), static_cast<std::int32_t>(dx_[2])};
      const std::int32_t dy32[3] = {static_cast<std::int32_t>(dy_[0]), static_cast<std::int32_t>(dy_[1]), static_cast<std::int32_t>(dy_[2])};
      std::vector<float> zv = z0;
      std::vector<int> iv = id0;
      const long nv = edge32(bw, bh, E32, dx32, dy32, 0.001f, 1.3e-5f, -0.7e-5f, 3, 5, zv.data() + stride + 2,
                             iv.data() + stride + 2, stride, 7);
      CAPTURE(tri);
      CHECK(ns == nv);
      CHECK(std::memcmp(zs.data(), zv.data(), zs.size() * sizeof(float)) == 0);
      CHECK(is == iv);
      ++compared32;
    }
  }
  CHECK(covered_total > 0);
  CHECK(blocks_partly > 20);  // edges cross many of the blocks (not all in or all out)
  CHECK(compared32 == (built_small_entry_kernels().edge32 ? 100 : 0));
}

TEST_CASE("the vertex stage agrees bit for bit on seeded random rows of posts (AVX2, AVX-512, NEON vs scalar)") {
  const auto builds = VECTOR_BUILDS(project_posts);
  if (builds.empty()) return;
  // A camera 300 m up looking 40 degrees from nadir over posts up to 3 km away: some behind
  // it, some beyond the guard band, some without a height (NaN, infinite).
  PostFrame f{};
  const Eigen::Matrix3f R = Eigen::AngleAxisf(2.4f, Eigen::Vector3f::UnitX()).toRotationMatrix() *
                            Eigen::AngleAxisf(0.3f, Eigen::Vector3f::UnitZ()).toRotationMatrix();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) f.R[3 * i + j] = R(i, j);
  f.t[0] = 12.5f;
  f.t[1] = -40.25f;
  f.t[2] = 300.0f;
  f.near = 0.5f;
  f.fx = 651.2;
  f.fy = 650.7;
  f.cx = 375.5;
  f.cy = 239.5;
  f.guard[0] = static_cast<float>((-2048 - f.cx) / f.fx);
  f.guard[1] = static_cast<float>((752 + 2048 - f.cx) / f.fx);
  f.guard[2] = static_cast<float>((-2048 - f.cy) / f.fy);
  f.guard[3] = static_cast<float>((480 + 2048 - f.cy) / f.fy);
  constexpr int kPosts = kMaxGridQuads + 1, kSlots = 2 * kPosts;  // a Wide chunk's row
  std::vector<float> cs(5 * kSlots), cv(5 * kSlots);
  std::vector<double> ps(5 * kSlots), pv(5 * kSlots);
  std::vector<std::int32_t> is(2 * kSlots), iv(2 * kSlots);
  auto clip_grid = [&](std::vector<float>& a) { return ClipGrid{a.data(), a.data() + kSlots, a.data() + 2 * kSlots, a.data() + 3 * kSlots, a.data() + 4 * kSlots}; };
  auto proj_grid = [&](std::vector<double>& a, std::vector<std::int32_t>& b) {
    return ProjGrid{a.data(), a.data() + kSlots, a.data() + 2 * kSlots, a.data() + 3 * kSlots, a.data() + 4 * kSlots, b.data(), b.data() + kSlots};
  };
  std::mt19937 rng(4242);
  std::uniform_real_distribution<float> u(0, 1);
  int inside = 0, outside = 0, whole_rows = 0;
  for (int round = 0; round < 300; ++round) {
    const float spread = round % 2 == 0 ? 6000.0f : 300.0f;
    const float x0 = (u(rng) - 0.5f) * spread, y0 = (u(rng) - 0.3f) * spread, step = round % 2 == 0 ? 60.0f : 2.0f * u(rng);
    float x[kPosts], y[kPosts], z[kPosts];
    for (int a = 0; a < kPosts; ++a) {
      x[a] = x0 + step * static_cast<float>(a);
      y[a] = y0 + 0.3f * step * u(rng);
      z[a] = 50.0f * u(rng);
      if (rng() % 23 == 0) z[a] = NAN;
      if (rng() % 41 == 0) z[a] = INFINITY;
    }
    const int n = round % 5 == 4 ? 1 + static_cast<int>(rng() % kPosts) : kPosts;
    const int k0 = static_cast<int>(rng() % (kPosts + 1));
    std::uint8_t os[kSlots] = {};
    bool hs[kSlots] = {};
    const bool all_s = project_posts_scalar(f, x, y, z, n, k0, clip_grid(cs), proj_grid(ps, is), os, hs);
    whole_rows += all_s;
    for (int k = k0; k < k0 + n; ++k) (os[k] != 0 ? outside : inside) += 1;
    for (const auto& [kernel, project] : builds) {
      const std::string name(kernel);  // CAPTURE may not capture a structured binding (C++17)
      CAPTURE(name);
      CAPTURE(round);
      std::uint8_t ov[kSlots] = {};
      bool hv[kSlots] = {};
      CHECK(all_s == project(f, x, y, z, n, k0, clip_grid(cv), proj_grid(pv, iv), ov, hv));
      for (int k = k0; k < k0 + n; ++k) {
        CAPTURE(k);
        const ClipVert a = clip_grid(cs).at(k), b = clip_grid(cv).at(k);
        CHECK(std::memcmp(&a, &b, sizeof a) == 0);
        CHECK(os[k] == ov[k]);
        CHECK(hs[k] == hv[k]);
        if (os[k] != 0) continue;
        const ProjVert p = proj_grid(ps, is).at(k), q = proj_grid(pv, iv).at(k);
        CHECK(std::memcmp(&p, &q, offsetof(ProjVert, Y) + sizeof p.Y) == 0);
      }
    }
  }
  MESSAGE(inside << " posts inside the clip volume, " << outside << " outside, " << whole_rows << " rows wholly inside");
  CHECK(inside > 1000);
  CHECK(outside > 300);
  CHECK(whole_rows > 10);
}

TEST_CASE("the triangle set-up kernel agrees bit for bit on seeded random rows of quads (AVX2, AVX-512, NEON vs scalar)") {
  const auto builds = VECTOR_BUILDS(emit_quad_row);
  if (builds.empty()) return;
  // Two rows of 33 vertices a grid (a Wide chunk's; rows of 16 quads, 32 and fewer): screen
  // positions over and around a 200 x 120 view, some rows coarse (triangles of tens of
  // pixels), some fine (most triangles cover no pixel centre), corners repeated (no area),
  // rows crossed (triangles turned either way) and quads split along either diagonal.
  constexpr int kRow = kMaxGridQuads + 1, kVerts = 2 * kRow;
  std::vector<double> f(5 * kVerts);
  std::vector<std::int32_t> i32(2 * kVerts);
  const ProjGrid g{f.data(), f.data() + kVerts, f.data() + 2 * kVerts, f.data() + 3 * kVerts, f.data() + 4 * kVerts,
                   i32.data(), i32.data() + kVerts};
  std::mt19937 rng(777);
  std::uniform_real_distribution<double> u(0, 1);
  int kept_total = 0, rejected_total = 0;
  for (int round = 0; round < 400; ++round) {
    const double spacing = round % 3 == 0 ? 12.0 : round % 3 == 1 ? 1.3 : 0.4;
    const double x0 = -30 + 250 * u(rng), y0 = -20 + 150 * u(rng), jitter = round % 5 == 0 ? 3.0 * spacing : 0.3 * spacing;
    for (int k = 0; k < kVerts; ++k) {
      const int col = k % kRow, row = k / kRow;
      ProjVert v;
      v.sx = x0 + spacing * col + jitter * (u(rng) - 0.5);
      v.sy = y0 + spacing * row + jitter * (u(rng) - 0.5);
      v.iz = 1e-3 * (1 + u(rng));
      v.qx = v.iz * (500 * u(rng) - 250);
      v.qy = v.iz * (500 * u(rng) - 250);
      v.X = static_cast<std::int32_t>(std::lround(v.sx * 256));
      v.Y = static_cast<std::int32_t>(std::lround(v.sy * 256));
      if (k > 0 && rng() % 9 == 0) {  // the corner before, again
        const ProjVert before = g.at(k - 1);
        v.X = before.X;
        v.Y = before.Y;
        v.sx = before.sx;
        v.sy = before.sy;
      }
      g.set(k, v);
    }
    const int n = round % 7 == 6 ? 1 + static_cast<int>(rng() % kMaxGridQuads) : round % 7 < 3 ? kChunkQuads : kMaxGridQuads;
    Tri ts[2 * kMaxGridQuads], tv[2 * kMaxGridQuads];
    PixelBox bs[2 * kMaxGridQuads], bv[2 * kMaxGridQuads];
    const bool anti = round % 2 == 1;  // and quads split along either diagonal
    const int cs = emit_quad_row_scalar(g, 0, kRow, n, anti, 200, 120, ts, bs);
    for (const auto& [kernel, emit] : builds) {
      const std::string name(kernel);  // CAPTURE may not capture a structured binding (C++17)
      CAPTURE(name);
      CAPTURE(round);
      const int cv = emit(g, 0, kRow, n, anti, 200, 120, tv, bv);
      REQUIRE(cs == cv);
      for (int k = 0; k < cs; ++k) {
        CAPTURE(k);
        CHECK(std::memcmp(&ts[k], &tv[k], offsetof(Tri, C) + sizeof(ts[k].C)) == 0);
        CHECK((bs[k].x0 == bv[k].x0 && bs[k].y0 == bv[k].y0 && bs[k].x1 == bv[k].x1 && bs[k].y1 == bv[k].y1));
        CHECK(bs[k].x0 <= bs[k].x1);
      }
    }
    kept_total += cs;
    rejected_total += 2 * n - cs;
  }
  MESSAGE("kept " << kept_total << ", rejected " << rejected_total);
  CHECK(kept_total > 2000);     // real triangles compared ...
  CHECK(rejected_total > 2000);  // ... and the rejections (no area, no pixel centre, off the view) too
}

TEST_CASE("the bin entries' set-up and the drawing of small entries agree bit for bit on seeded random triangles (AVX2, AVX-512, NEON vs scalar)") {
  const auto builds = VECTOR_BUILDS(setup_entries);
  if (builds.empty()) return;
  const DrawSmallEntriesFn draw_small = built_small_entry_kernels().draw;
  REQUIRE((draw_small != nullptr));  // (doubled: doctest cannot print a function pointer)
  // Triangles of under a pixel to hundreds of pixels over and around a 300 x 200 view, seen
  // from the tile at pixels 128 .. 255, 24 .. 47: small ones inside it, across its edges,
  // outside it, and large ones.
  const int vw = 300, vh = 200, x0 = 128, y0 = 24, x1 = 255, y1 = 47;
  std::vector<Tri> tris(64);
  std::mt19937 rng(99);
  std::uniform_real_distribution<float> u(0, 1);
  int small_total = 0, other_total = 0;
  long drawn_pixels = 0;
  for (int round = 0; round < 300; ++round) {
    for (Tri& t : tris) {
      const float size = round % 3 == 0 ? 300.0f * u(rng) : 9.0f * u(rng);
      const float cx = 100 + 200 * u(rng), cy = 10 + 50 * u(rng);
      for (int k = 0; k < 3; ++k) {
        t.X[k] = static_cast<std::int32_t>((cx + size * (u(rng) - 0.5f)) * 256);
        t.Y[k] = static_cast<std::int32_t>((cy + size * (u(rng) - 0.5f)) * 256);
        t.A[k] = (u(rng) - 0.5f) * 1e-3f;
        t.B[k] = (u(rng) - 0.5f) * 1e-3f;
        t.C[k] = u(rng) * (k == 0 ? 1e-2f : 3.0f);
        if (round % 5 == 1) {  // on a grid of half pixels: spans of exactly 8 pixels, edges along rows
          t.X[k] &= ~127;
          t.Y[k] &= ~127;
        }
      }
      if (rng() % 6 == 0) {  // two corners the same: an edge of no length
        t.X[1] = t.X[0];
        t.Y[1] = t.Y[0];
      }
      // Clockwise on screen, as set-up makes every triangle.
      if ((std::int64_t{t.X[1]} - t.X[0]) * (t.Y[2] - t.Y[0]) - (std::int64_t{t.Y[1]} - t.Y[0]) * (t.X[2] - t.X[0]) < 0) {
        std::swap(t.X[1], t.X[2]);
        std::swap(t.Y[1], t.Y[2]);
      }
    }
    int ids[EntrySetup::kMax];
    const int n = round % 4 == 3 ? 1 + static_cast<int>(rng() % EntrySetup::kMax) : EntrySetup::kMax;
    for (int i = 0; i < n; ++i) ids[i] = static_cast<int>(rng() % tris.size());
    EntrySetup a;
    std::vector<float> ca(kPlaneFloats * EntrySetup::kMax + 1, -1.0f);
    setup_entries_scalar(tris.data(), ids, n, x0, y0, x1, y1, vw, vh, a, ca.data());
    for (const auto& [kernel, setup] : builds) {
      const std::string name(kernel);  // CAPTURE may not capture a structured binding (C++17)
      CAPTURE(name);
      CAPTURE(round);
      EntrySetup b;
      std::vector<float> cb(ca.size(), -1.0f);
      setup(tris.data(), ids, n, x0, y0, x1, y1, vw, vh, b, cb.data());
      CHECK(std::memcmp(ca.data(), cb.data(), ca.size() * sizeof(float)) == 0);  // and nothing past n entries
      REQUIRE(a.small == b.small);
      for (int i = 0; i < n; ++i) {
        if (!(a.small >> i & 1)) continue;
        CAPTURE(i);
        CHECK((a.x0[i] == b.x0[i] && a.y0[i] == b.y0[i] && a.w[i] == b.w[i] && a.h[i] == b.h[i]));
        CHECK((a.base[i] == b.base[i] && a.A[i] == b.A[i] && a.B[i] == b.B[i]));
        for (int k = 0; k < 3; ++k) CHECK((a.E[k][i] == b.E[k][i] && a.dEx[k][i] == b.dEx[k][i] && a.dEy[k][i] == b.dEy[k][i]));
      }
      // The small entries drawn into a tile's visibility buffers, by this ISA's run of them
      // (AVX2's, which the AVX-512 renderer uses too) from this build's set-up and by the
      // scalar edge kernel one by one from the scalar set-up: the same depths, entries and counts.
      const std::ptrdiff_t stride = (x1 - x0 + 1) + 8;
      std::vector<float> za(static_cast<std::size_t>(stride * (y1 - y0 + 1)), 0.0f), zb = za;
      std::vector<int> ia(za.size(), -1), ib = ia;
      int cov_a[EntrySetup::kMax] = {}, cov_b[EntrySetup::kMax] = {};
      int at = 0;
      while (at < n) {
        if (!(a.small >> at & 1)) {
          ++at;
          continue;
        }
        const int end = draw_small(b, at, n, x0, y0, zb.data(), ib.data(), stride, 1000, cov_b);
        for (; at < n && (a.small >> at & 1); ++at) {
          const std::ptrdiff_t o = (a.y0[at] - y0) * stride + (a.x0[at] - x0);
          const std::int64_t E[3] = {a.E[0][at], a.E[1][at], a.E[2][at]}, dx[3] = {a.dEx[0][at], a.dEx[1][at], a.dEx[2][at]},
                             dy[3] = {a.dEy[0][at], a.dEy[1][at], a.dEy[2][at]};
          cov_a[at] = static_cast<int>(edge_block_scalar(a.w[at], a.h[at], E, dx, dy, a.base[at], a.A[at], a.B[at], 0, 0,
                                                         za.data() + o, ia.data() + o, stride, 1000 + at));
        }
        CHECK(end == at);
      }
      CHECK(std::memcmp(za.data(), zb.data(), za.size() * sizeof(float)) == 0);
      CHECK(ia == ib);
      CHECK(std::memcmp(cov_a, cov_b, sizeof cov_a) == 0);
      if (name == builds.front().first)
        for (int i = 0; i < n; ++i) drawn_pixels += cov_a[i];
    }
    for (int i = 0; i < n; ++i) {
      CAPTURE(i);
      CHECK(ca[static_cast<std::size_t>(kPlaneFloats * i + 9)] == INFINITY);
      if (!(a.small >> i & 1)) {
        ++other_total;
        continue;
      }
      ++small_total;
      CHECK((a.w[i] >= 1 && a.w[i] <= 8 && a.h[i] >= 1 && a.h[i] <= 8));
      CHECK((a.x0[i] >= x0 && a.x0[i] + a.w[i] - 1 <= x1 && a.y0[i] >= y0 && a.y0[i] + a.h[i] - 1 <= y1));
    }
  }
  MESSAGE(small_total << " small entries, " << other_total << " others, " << drawn_pixels << " pixels drawn");
  CHECK(small_total > 500);
  CHECK(drawn_pixels > small_total);  // more than a pixel each, on average
  CHECK(other_total > 500);
}

TEST_CASE("a view needing more than max_triangles fails with a clear error, the same on 1 and 2 threads") {
  const geo::Map map = test::dem_map(257, 257, 0, 2000, 7.8125, [](double x, double y) {
    return 100 + 30 * std::sin(x * 0.04) * std::cos(y * 0.06);
  }, smooth_layer());
  const geo::CameraModel cam = camera(333, 211, 280);
  std::string errors[2];
  for (int threads = 1; threads <= 2; ++threads) {
    RenderOptions o;
    o.threads = threads;
    o.max_triangles = 1024;
    auto r = make(map, cam, o);
    auto out = r->make_output({"all"});
    REQUIRE(out.ok());
    const Status st = r->render(look_down(1000, 1000, 400, 50, 30), out.value());
    REQUIRE_FALSE(st.ok());
    errors[threads - 1] = st.error().message;
    CHECK(std::all_of(out->valid[0].pixels().begin(), out->valid[0].pixels().end(), [](std::uint8_t v) { return v == 0; }));
  }
  CHECK(errors[0].find("more than 1024 triangles") != std::string::npos);
  CHECK(errors[0] == errors[1]);
}

TEST_CASE("a frame allocates nothing after set-up") {
  const geo::Map map = test::dem_map(129, 129, 0, 2000, 15.625, [](double x, double y) {
    return 50 + 20 * std::sin(x * 0.01 + y * 0.003);
  }, smooth_layer());
  auto r = make(map, camera());
  auto out = r->make_output({"all"});
  REQUIRE(out.ok());
  REQUIRE(r->render(look_down(1000, 1000, 700, 20), out.value()).ok());  // warm-up
  test::AllocationCounter count;
  auto st = r->render(look_down(1010, 990, 690, 25, 10), out.value());
  const long n = count.allocations();
  REQUIRE(st.ok());
  CHECK(n == 0);
}

TEST_CASE("bad poses: below the terrain, NaN, off the map, at the sky: an error and an all-invalid frame") {
  const geo::Map map = test::flat_map(100.0, smooth_layer());
  auto r = make(map, camera());
  auto out = r->make_output({"all"});
  REQUIRE(out.ok());
  auto all_invalid = [&] {
    for (auto v : out->valid[0].pixels())
      if (v) return false;
    for (float z : out->depth.pixels())
      if (z == z) return false;
    return true;
  };
  auto below = r->render(look_down(1000, 1000, 50), out.value());
  REQUIRE(!below.ok());
  // The numbers as they are, whatever the locale: not std::to_string's "50.000000".
  CHECK(below.error().message.find("camera at z 50 m is below the terrain (100 m) at (1000, 1000)") != std::string::npos);
  CHECK(all_invalid());
  geo::Pose nan = look_down(1000, 1000, 500);
  nan.t_W_C.x() = NAN;
  CHECK(!r->render(nan, out.value()).ok());
  CHECK(all_invalid());
  auto off = r->render(look_down(50000, 1000, 500), out.value());
  REQUIRE(!off.ok());
  CHECK(off.error().message.find("sees no terrain") != std::string::npos);
  CHECK(all_invalid());
  // Looking up at the sky.
  auto sky = r->render(geo::pose_from_ypr({1000, 1000, 500}, 0, 0, 0, geo::tilted_mount(180)), out.value());
  CHECK(!sky.ok());
  CHECK(all_invalid());
  // Towards the horizon: the sky part is invalid, the ground valid, the frame succeeds.
  REQUIRE(r->render(look_down(1000, 200, 300, 88), out.value()).ok());
  CHECK(std::isnan(out->depth.at(160, 0)));
  CHECK(std::isfinite(out->depth.at(160, 239)));
  CHECK(out->valid[0].at(160, 0) == 0);
}

TEST_CASE("an unknown layer name is refused with the names there are") {
  const geo::Map map = test::flat_map(0.0, smooth_layer());
  auto r = make(map, camera());
  auto out = r->make_output({"2030"});
  REQUIRE(!out.ok());
  CHECK(out.error().message.find("'2030'") != std::string::npos);
  CHECK(out.error().message.find("smooth") != std::string::npos);
}
