// The scene the localizer's tests share (test_refine.cpp, test_layers.cpp): the sample camera
// 800 m over the NAIP sample's middle looking down, seen in 2016 and in 2017; the prior 1
// degree of pitch and 12 m east of the truth, as an IMU's tilt and a failing GPS give a first
// frame.
#pragma once

#include <doctest/doctest.h>

#include <Eigen/Geometry>

#include <terralign/geo/camera.hpp>
#include <terralign/geo/map.hpp>
#include <terralign/geo/pose.hpp>
#include <terralign/raster/renderer.hpp>

#include "support.hpp"

namespace terralign::test {

constexpr double kDeg = 3.14159265358979323846 / 180;

struct Scene {
  geo::Map map;
  geo::CameraModel cam;
  geo::Pose truth, prior;
  ImageU8 live;       // 2016 at the truth
  ImageU8 live_2017;  // 2017 at the truth
};

inline Scene scene() {
  auto map = geo::load_map(source_path("data/naip_west/map.json"));
  auto cam = geo::load_camera(source_path("data/cameras/uav_752x480.json"));
  REQUIRE(map.ok());
  REQUIRE(cam.ok());
  Scene s{std::move(map.value()), cam.value(), {}, {}, {}, {}};
  const geo::Extent e = s.map.common_extent();
  const double x = 0.5 * (e.min_x + e.max_x), y = 0.5 * (e.min_y + e.max_y);
  s.truth.t_W_C = Eigen::Vector3d(x, y, s.map.dem.height_at(x, y) + 800);
  s.truth.q_W_C = Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ())) * Eigen::Quaterniond(0, 1, 0, 0);
  s.prior = s.truth;
  s.prior.t_W_C.x() += 12;
  s.prior.q_W_C = (Eigen::Quaterniond(Eigen::AngleAxisd(1.0 * kDeg, Eigen::Vector3d::UnitX())) * s.truth.q_W_C).normalized();
  auto r = raster::Renderer::create(s.map, s.cam);
  REQUIRE(r.ok());
  auto out = r.value()->make_output({"2016", "2017"});
  REQUIRE(out.ok());
  REQUIRE(r.value()->render(s.truth, out.value()).ok());
  s.live = out->rgb[0];
  s.live_2017 = out->rgb[1];
  return s;
}

}  // namespace terralign::test
