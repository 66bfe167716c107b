#include <cmath>
#include <random>

#include <doctest/doctest.h>

#include <terralign/geo/camera.hpp>

using namespace terralign;
using namespace terralign::geo;

namespace {

CameraModel make_camera(DistortionModel m) {
  CameraModel c;
  c.width = 752;
  c.height = 480;
  c.fx = 651.2;
  c.fy = 650.1;
  c.cx = 375.5;
  c.cy = 239.5;
  c.model = m;
  if (m == DistortionModel::RadTan) c.k = {-0.2641, 0.1019, 7.3e-4, 2.6e-4, -0.0258};  // Tuniu's
  if (m == DistortionModel::Equidistant) c.k = {0.02, -0.01, 0.003, -0.0005, 0};
  return c;
}

}  // namespace

TEST_CASE("unproject inverts project to 1e-6 px over the whole image, every model") {
  for (auto m : {DistortionModel::None, DistortionModel::RadTan, DistortionModel::Equidistant}) {
    CAPTURE(to_string(m));
    const CameraModel cam = make_camera(m);
    for (int v = 0; v < cam.height; v += 31)
      for (int u = 0; u < cam.width; u += 37) {
        Eigen::Vector3d ray;
        REQUIRE(cam.unproject(Eigen::Vector2d(u, v), ray));
        Eigen::Vector2d px = Eigen::Vector2d::Zero();
        REQUIRE(cam.project<double>(ray * 7.0, px));
        CHECK(std::abs(px.x() - u) < 1e-6);
        CHECK(std::abs(px.y() - v) < 1e-6);
      }
  }
}

TEST_CASE_TEMPLATE("d_pixel_d_point matches central differences", S, float, double) {
  // Step and bound per scalar: double h = 1e-4 m gives an O(h^2) truncation error far below
  // 1e-5 px/m; float needs a larger step (1e-2 m at 10 m depth) and a bound set by its
  // 1e-7 relative rounding of pixel coordinates near 1e3 (about 1e-4 px / 2h).
  const S h = std::is_same<S, double>::value ? S(1e-4) : S(1e-2);
  const double tol = std::is_same<S, double>::value ? 1e-5 : 2e-2;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> xy(-4.0, 4.0), depth(5.0, 15.0);
  for (auto m : {DistortionModel::None, DistortionModel::RadTan, DistortionModel::Equidistant}) {
    CAPTURE(to_string(m));
    const CameraModel cam = make_camera(m);
    for (int i = 0; i < 50; ++i) {
      const Eigen::Matrix<S, 3, 1> p(S(xy(rng)), S(xy(rng)), S(depth(rng)));
      Eigen::Matrix<S, 2, 1> px = Eigen::Matrix<S, 2, 1>::Zero();
      Eigen::Matrix<S, 2, 3> J;
      REQUIRE(cam.project<S>(p, px, &J));
      for (int k = 0; k < 3; ++k) {
        Eigen::Matrix<S, 3, 1> a = p, b = p;
        a[k] += h;
        b[k] -= h;
        Eigen::Matrix<S, 2, 1> pa = Eigen::Matrix<S, 2, 1>::Zero(), pb = Eigen::Matrix<S, 2, 1>::Zero();
        REQUIRE(cam.project<S>(a, pa));
        REQUIRE(cam.project<S>(b, pb));
        const Eigen::Matrix<S, 2, 1> num = (pa - pb) / (S(2) * h);
        CHECK(std::abs(double(num.x() - J(0, k))) < tol);
        CHECK(std::abs(double(num.y() - J(1, k))) < tol);
      }
    }
  }
}

TEST_CASE("project refuses points behind the camera and NaN") {
  const CameraModel cam = make_camera(DistortionModel::None);
  Eigen::Vector2d px(-1, -1);
  CHECK(!cam.project<double>(Eigen::Vector3d(0, 0, -1), px));
  CHECK(!cam.project<double>(Eigen::Vector3d(0, 0, 0), px));
  CHECK(!cam.project<double>(Eigen::Vector3d(NAN, 0, 1), px));
  CHECK(px.x() == -1);
  Eigen::Vector3d ray;
  CHECK(!cam.unproject(Eigen::Vector2d(NAN, 3), ray));
}

TEST_CASE("scaled intrinsics keep pixel centres at integers") {
  const CameraModel cam = make_camera(DistortionModel::None);
  const CameraModel half = cam.scaled(0.5, 376, 240);
  // A point seen at full-resolution pixel u lands at (u + 0.5) / 2 - 0.5 at half resolution.
  const Eigen::Vector3d p(1.3, -0.7, 9.0);
  Eigen::Vector2d full = Eigen::Vector2d::Zero(), small = Eigen::Vector2d::Zero();
  REQUIRE(cam.project<double>(p, full));
  REQUIRE(half.project<double>(p, small));
  CHECK(small.x() == doctest::Approx((full.x() + 0.5) / 2 - 0.5));
  CHECK(small.y() == doctest::Approx((full.y() + 0.5) / 2 - 0.5));
}

TEST_CASE("camera JSON: reads every model, refuses bad values with the value") {
  auto ok = parse_camera(R"({"width": 752, "height": 480, "fx": 651.2, "fy": 651.2, "cx": 375.5,
      "cy": 239.5, "distortion": {"model": "radtan", "k1": -0.1, "p2": 0.001}})", "cam.json");
  REQUIRE(ok.ok());
  CHECK(ok->model == DistortionModel::RadTan);
  CHECK(ok->k[0] == -0.1);
  CHECK(ok->k[3] == 0.001);
  auto round = parse_camera(camera_to_json(ok.value()), "again.json");
  REQUIRE(round.ok());
  CHECK(round->k == ok->k);

  const std::string base = R"("width": 752, "height": 480, "cx": 375.5, "cy": 239.5)";
  auto fx0 = parse_camera("{" + base + R"(, "fx": 0, "fy": 651})", "cam.json");
  REQUIRE(!fx0.ok());
  CHECK(fx0.error().message.find("fx = 0") != std::string::npos);
  auto size0 = parse_camera(R"({"width": 0, "height": 480, "fx": 1, "fy": 1, "cx": 0, "cy": 0})", "cam.json");
  REQUIRE(!size0.ok());
  CHECK(size0.error().message.find("0 x 480") != std::string::npos);
  auto inf = parse_camera("{" + base + R"(, "fx": 1e400, "fy": 651})", "cam.json");
  REQUIRE(!inf.ok());
  CHECK(inf.error().message.find("1e400") != std::string::npos);
  auto model = parse_camera("{" + base + R"(, "fx": 1, "fy": 1, "distortion": {"model": "fisheye624"}})", "cam.json");
  REQUIRE(!model.ok());
  CHECK(model.error().message.find("unknown model 'fisheye624'") != std::string::npos);
  // k1 = 1e308 is finite but turns the pixel beside the principal point (r^2 of about 6e-7)
  // to infinity: no camera. The model of the same file with k1 = -0.1 passes above.
  auto wild = parse_camera("{" + base + R"(, "fx": 651.2, "fy": 651.2, "distortion": {"model": "radtan", "k1": 1e308}})",
                           "wild.json");
  REQUIRE(!wild.ok());
  CHECK(wild.error().message.find("wild.json: the distortion (coefficients 1e+308, 0, 0, 0, 0) cannot be inverted at pixel (376, 240)") !=
        std::string::npos);
  auto key = parse_camera("{" + base + R"(, "fx": 1, "fy": 1, "focal": 3})", "cam.json");
  REQUIRE(!key.ok());
  CHECK(key.error().message.find("unknown key 'focal'") != std::string::npos);
  auto syntax = parse_camera("{\n  \"width\": 752,\n  \"height\" 480\n}", "cam.json");
  REQUIRE(!syntax.ok());
  CHECK(syntax.error().message.find("cam.json:3:") != std::string::npos);
  auto missing = load_camera("/nonexistent/cam.json");
  REQUIRE(!missing.ok());
  CHECK(missing.error().message.find("/nonexistent/cam.json") != std::string::npos);
}
