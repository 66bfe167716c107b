// Failure as data under abuse: 1000 random poses through the localisation pipeline (render the
// reference at the prior, align the camera image), inside, at the edge of and off the map,
// looking at the horizon or the sky, under the ground, with NaN in them; camera images that
// are renders of somewhere else, noise or flat grey. Every call gives a pose or a named
// failure: never a crash, a hang or a NaN.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>

#include <doctest/doctest.h>

#include <terralign/geo/map.hpp>

#include "localizer.hpp"
#include "support.hpp"

using namespace terralign;

namespace {

geo::Pose random_pose(std::mt19937_64& rng, const geo::Map& map) {
  std::uniform_real_distribution<double> u(0, 1);
  const geo::Extent e = map.common_extent();
  geo::Pose p;
  // Position: half the time inside, otherwise up to half the map's size beyond an edge.
  const double margin = u(rng) < 0.5 ? 0.0 : 0.5;
  const double x = e.min_x - margin * e.width() + u(rng) * (1 + 2 * margin) * e.width();
  const double y = e.min_y - margin * e.height() + u(rng) * (1 + 2 * margin) * e.height();
  // Height: mostly 50-2000 m above the ground, sometimes under it.
  const double ground = map.dem.height_at(std::clamp(x, e.min_x, e.max_x), std::clamp(y, e.min_y, e.max_y));
  const double agl = u(rng) < 0.1 ? -200 * u(rng) : 50 + 1950 * u(rng);
  p.t_W_C = Eigen::Vector3d(x, y, (std::isfinite(ground) ? ground : 0) + agl);
  // Orientation: nadir with a tilt, or any direction at all (horizon, sky).
  Eigen::Quaterniond q;
  if (u(rng) < 0.6) {
    const double tilt = u(rng) * 1.2, az = u(rng) * 6.283, yaw = u(rng) * 6.283;
    q = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
        Eigen::AngleAxisd(tilt, Eigen::Vector3d(std::cos(az), std::sin(az), 0)) *
        Eigen::Quaterniond(0, 1, 0, 0);  // camera z down
  } else {
    std::normal_distribution<double> n(0, 1);
    q = Eigen::Quaterniond(n(rng), n(rng), n(rng), n(rng));
  }
  p.q_W_C = q.normalized();
  return p;
}

}  // namespace

TEST_CASE("abuse: 1000 random poses through align give a pose or a named failure, never a NaN") {
  auto map = geo::load_map(test::source_path("data/naip_west/map.json"));
  REQUIRE(map.ok());
  geo::CameraModel cam;  // the sample camera at a quarter size, to keep the run short
  cam.width = 188;
  cam.height = 120;
  cam.fx = cam.fy = 162.8;
  cam.cx = 93.5;
  cam.cy = 59.5;
  iclk::TrackerOptions opt;
  opt.iterations = 10;
  opt.levels = 3;
  auto loc = cli::Localizer::create(map.value(), cam, "2016", opt, 2);
  REQUIRE(loc.ok());
  loc.value()->set_refinement(cli::kDefaultRefinePasses);  // as the command line runs it
  auto renderer = raster::Renderer::create(map.value(), cam);
  REQUIRE(renderer.ok());
  auto view = renderer.value()->make_output({"2017"});
  REQUIRE(view.ok());
  std::mt19937_64 rng(20261122);
  std::uniform_real_distribution<double> u(0, 1);
  ImageU8 noise(cam.width, cam.height, 3), grey(cam.width, cam.height, 3, 128);
  int converged = 0, failed = 0, errors = 0;
  for (int i = 0; i < 1000; ++i) {
    const geo::Pose truth = random_pose(rng, map.value());
    geo::Pose prior = truth;
    // The prior: near the truth (the localizer's use), somewhere else, or with a NaN in it.
    const double k = u(rng);
    if (k < 0.6) {
      prior.t_W_C += Eigen::Vector3d(u(rng) - 0.5, u(rng) - 0.5, u(rng) - 0.5) * 60.0;
      prior.q_W_C = (prior.q_W_C * Eigen::Quaterniond(Eigen::AngleAxisd(0.05 * u(rng), Eigen::Vector3d::UnitX()))).normalized();
    } else if (k < 0.9) {
      prior = random_pose(rng, map.value());
    } else {
      prior.t_W_C[static_cast<int>(u(rng) * 3)] = NAN;
    }
    // The camera image: a render at the truth (all-invalid off the map), noise, or grey.
    const ImageU8* live = &grey;
    const double c = u(rng);
    if (c < 0.7) {
      if (renderer.value()->render(truth, view.value()).ok()) live = &view->rgb[0];
    } else if (c < 0.9) {
      for (auto& v : noise.pixels()) v = static_cast<std::uint8_t>(rng() & 255);
      live = &noise;
    }
    auto out = loc.value()->localize(live->view(), prior);
    CAPTURE(i);
    if (!out.ok()) {
      ++errors;
      CHECK_FALSE(out.error().message.empty());
      if (errors <= 3) MESSAGE("refused: " << out.error().message);
      continue;
    }
    CHECK(std::strlen(out->reason) > 0);
    CHECK(out->T_W_C.t_W_C.allFinite());
    CHECK(out->T_W_C.q_W_C.coeffs().allFinite());
    CHECK(out->covariance.allFinite());
    if (out->converged) {
      ++converged;
    } else {
      ++failed;
    }
  }
  MESSAGE("1000 random poses: " << converged << " converged, " << failed << " failed with a reason, " << errors
                                << " refused with an error");
  CHECK(converged + failed + errors == 1000);
  CHECK(converged > 0);  // some of them are ordinary localisations, and those work
}
