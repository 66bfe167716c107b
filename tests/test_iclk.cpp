#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>
#include <utility>
#include <vector>

#include <doctest/doctest.h>

#include <terralign/geo/cpu.hpp>
#include <terralign/iclk/tracker.hpp>
#include <terralign/raster/renderer.hpp>

#include "../src/iclk/evaluate_kernels.hpp"

#include "alloc_counter.hpp"
#include "same_answer.hpp"
#include "support.hpp"
#include "synthetic.hpp"

using namespace terralign;
using namespace terralign::iclk;

TEST_CASE_TEMPLATE("SE(3) exp and log round-trip, small and near-pi angles included", S, float, double) {
  // Bounds: double 1e-9; float 2e-4 (acos and the near-pi branch lose ~sqrt(eps) there).
  const double tol = std::is_same<S, double>::value ? 1e-9 : 2e-4;
  std::mt19937 rng(3);
  std::normal_distribution<double> n01(0, 1);
  for (double angle : {0.0, 1e-9, 1e-6, 1e-4, 0.3, 1.0, 2.5, M_PI - 1e-3, M_PI - 1e-6}) {
    for (int trial = 0; trial < 5; ++trial) {
      CAPTURE(angle);
      Eigen::Vector3d axis(n01(rng), n01(rng), n01(rng));
      axis.normalize();
      Vec6<S> xi;
      xi << (axis * angle).cast<S>(), Vec3<S>(S(n01(rng)), S(n01(rng)), S(n01(rng)));
      const SE3<S> T = SE3<S>::exp(xi);
      CHECK(T.R.allFinite());
      CHECK(((T.R.transpose() * T.R) - Mat3<S>::Identity()).norm() < tol);
      const Vec6<S> back = T.log();
      REQUIRE(back.allFinite());
      // exp(log(T)) == T, compared as transforms (near pi the axis sign is ambiguous).
      const SE3<S> T2 = SE3<S>::exp(back);
      CHECK((T2.R - T.R).norm() < tol);
      CHECK((T2.t - T.t).norm() < tol * 10);
      if (angle < 3.0) CHECK((back - xi).norm() < tol * 10);
    }
  }
  // The identity: exactly zero, no NaN (Lv et al.'s exp divides by the angle).
  const SE3<S> I = SE3<S>::exp(Vec6<S>::Zero());
  CHECK(I.R == Mat3<S>::Identity());
  CHECK(I.t == Vec3<S>::Zero());
  CHECK(I.log() == Vec6<S>::Zero());
}

TEST_CASE_TEMPLATE("warp Jacobians match central differences on an analytic image", S, float, double) {
  const Pinhole<S> K{S(300), S(310), S(160.3), S(119.7)};
  // A smooth analytic texture and its exact gradient.
  auto f = [](S u, S v) { return std::sin(u * S(0.11)) * std::cos(v * S(0.07)) + S(0.3) * std::sin(u * S(0.05) + v * S(0.09)); };
  auto grad = [](S u, S v) {
    return Eigen::Matrix<S, 1, 2>(S(0.11) * std::cos(u * S(0.11)) * std::cos(v * S(0.07)) + S(0.015) * std::cos(u * S(0.05) + v * S(0.09)),
                                  -S(0.07) * std::sin(u * S(0.11)) * std::sin(v * S(0.07)) + S(0.027) * std::cos(u * S(0.05) + v * S(0.09)));
  };
  // Steps and bounds: double h = 1e-6 (truncation ~1e-12); float h = 1e-3 with float
  // rounding of pixel coordinates near 300 (~3e-5 px / 2e-3) dominating.
  const S h = std::is_same<S, double>::value ? S(1e-6) : S(1e-3);
  const double tol = std::is_same<S, double>::value ? 1e-6 : 3e-2;
  for (int i = 0; i < 20; ++i) {
    const S u = S(20 + 13 * i), v = S(15 + 9 * i);
    const S d = S(80 + 3 * i);
    const Vec3<S> X(d * (u - K.cx) / K.fx, d * (v - K.cy) / K.fy, d);
    SUBCASE("SE(3) with depth") {
      const auto J = SE3DepthWarp<S>::d_warp_d_xi(X, u, v, K);
      const Eigen::Matrix<S, 1, 6> JI = grad(u, v) * J;
      for (int k = 0; k < 6; ++k) {
        Vec6<S> e = Vec6<S>::Zero();
        e[k] = h;
        S up = 0, vp = 0, um = 0, vm = 0;
        REQUIRE(SE3DepthWarp<S>::apply(SE3<S>::exp(e), X, u, v, K, up, vp));
        REQUIRE(SE3DepthWarp<S>::apply(SE3<S>::exp(-e), X, u, v, K, um, vm));
        CHECK(std::abs(double((up - um) / (S(2) * h) - J(0, k))) < tol * (1 + std::abs(double(J(0, k)))));
        CHECK(std::abs(double((vp - vm) / (S(2) * h) - J(1, k))) < tol * (1 + std::abs(double(J(1, k)))));
        const S dI = (f(up, vp) - f(um, vm)) / (S(2) * h);
        CHECK(std::abs(double(dI - JI(k))) < tol * (1 + std::abs(double(JI(k)))));
      }
    }
    SUBCASE("homography") {
      const auto J = HomographyWarp<S>::d_warp_d_xi(X, u, v, K);
      for (int k = 0; k < 8; ++k) {
        Eigen::Matrix<S, 8, 1> e = Eigen::Matrix<S, 8, 1>::Zero();
        e[k] = h;
        Mat3<S> Hp, Hm;
        Hp << S(1) + e[0], e[1], e[2], e[3], S(1) + e[4], e[5], e[6], e[7], S(1);
        Hm << S(1) - e[0], -e[1], -e[2], -e[3], S(1) - e[4], -e[5], -e[6], -e[7], S(1);
        S up = 0, vp = 0, um = 0, vm = 0;
        REQUIRE(HomographyWarp<S>::apply(Hp, X, u, v, K, up, vp));
        REQUIRE(HomographyWarp<S>::apply(Hm, X, u, v, K, um, vm));
        CHECK(std::abs(double((up - um) / (S(2) * h) - J(0, k))) < tol * 10 * (1 + std::abs(double(J(0, k)))));
        CHECK(std::abs(double((vp - vm) / (S(2) * h) - J(1, k))) < tol * 10 * (1 + std::abs(double(J(1, k)))));
      }
    }
  }
}

namespace {

struct Pair {
  ImageF ref_grey, live_grey, depth;
  SE3<double> T_live_ref_true;
  Pinhole<double> K;
};

// Renders the reference at `prior` and the live image at `truth` from one layer.
Pair render_pair(const geo::Map& map, const geo::CameraModel& cam, const geo::Pose& prior, const geo::Pose& truth,
                 const std::string& ref_layer, const std::string& live_layer) {
  auto r = raster::Renderer::create(map, cam);
  REQUIRE(r.ok());
  auto a = r.value()->make_output({ref_layer});
  auto b = r.value()->make_output({live_layer});
  REQUIRE((a.ok() && b.ok()));
  REQUIRE(r.value()->render(prior, a.value()).ok());
  REQUIRE(r.value()->render(truth, b.value()).ok());
  Pair p;
  rgb_to_grey(a->rgb[0].view(), p.ref_grey);
  rgb_to_grey(b->rgb[0].view(), p.live_grey);
  p.depth = a->depth;
  for (std::size_t k = 0; k < p.depth.size(); ++k)
    if (!a->valid[0].data()[k]) p.depth.data()[k] = NAN;
  // T_live_ref = T_C1_W T_W_Cref.
  const geo::Pose rel = truth.inverse() * prior;
  p.T_live_ref_true.R = rel.R();
  p.T_live_ref_true.t = rel.t_W_C;
  p.K = {cam.fx, cam.fy, cam.cx, cam.cy};
  return p;
}

// The bit-for-bit tests' pair: NAIP 2012 against itself, 10 m and a degree or so apart, at
// the paper's camera.
Pair naip_2012_pair() {
  auto map = geo::load_map(test::source_path("data/naip_west/map.json"));
  REQUIRE(map.ok());
  return render_pair(map.value(), test::paper_camera(), geo::pose_from_ypr({487450, 5207437, 1370}, 10, 1, 0),
                     geo::pose_from_ypr({487458, 5207431, 1374}, 11, 0, 1), "2012", "2012");
}

// The pair of several tests: the paper's camera 800 m over the NAIP ground, its prior 15 m
// aside, 6 m higher, 1.5 degrees of heading and a degree of roll and pitch off.
Pair offset_pair(const geo::Map& map, const std::string& ref_layer, const std::string& live_layer) {
  return render_pair(map, test::paper_camera(), geo::pose_from_ypr({487450 + 12, 5207437 - 9, 570 + 806}, 31.5, 1, -2),
                     geo::pose_from_ypr({487450, 5207437, 570 + 800}, 30, 2, -3), ref_layer, live_layer);
}

// Mean 2-D end-point error between two relative poses over the reference points.
double epe_px(const Pair& p, const SE3<double>& est) {
  double sum = 0;
  long n = 0;
  for (int y = 0; y < p.depth.height(); y += 4)
    for (int x = 0; x < p.depth.width(); x += 4) {
      const double d = p.depth.at(x, y);
      if (!std::isfinite(d)) continue;
      const Vec3<double> X(d * (x - p.K.cx) / p.K.fx, d * (y - p.K.cy) / p.K.fy, d);
      double u1, v1, u2, v2;
      if (!SE3DepthWarp<double>::apply(est, X, x, y, p.K, u1, v1)) continue;
      if (!SE3DepthWarp<double>::apply(p.T_live_ref_true, X, x, y, p.K, u2, v2)) continue;
      sum += std::hypot(u1 - u2, v1 - v2);
      ++n;
    }
  return n ? sum / static_cast<double>(n) : INFINITY;
}


}  // namespace

namespace {

// Aligns a same-layer pair rendered at a known small offset; returns the final 2-D EPE.
double converge_same_layer(const geo::Map& map, const std::string& layer) {
  const geo::CameraModel cam = test::paper_camera();
  const Pair p = offset_pair(map, layer, layer);
  CHECK(epe_px(p, SE3<double>::identity()) > 10);  // a real offset to recover
  TrackerOptions opt;
  opt.iterations = 50;
  opt.step_tol = 1e-10;
  Tracker<double, SE3DepthWarp<double>, 1> tracker(cam.width, cam.height, opt);
  const auto& res = tracker.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), p.K, SE3<double>::identity());
  CHECK(res.converged);
  const double epe = epe_px(p, res.params);
  MESSAGE(layer << ": " << std::string(res.reason) << ", iterations " << res.iterations << ", EPE " << epe << " px");
  // The covariance is a covariance: symmetric positive definite.
  CHECK((res.covariance - res.covariance.transpose()).norm() < 1e-12 * res.covariance.norm());
  CHECK(res.covariance.llt().info() == Eigen::Success);

  // The float solver and the homography baseline converge on the same pair.
  Tracker<float, SE3DepthWarp<float>, 1> tf(cam.width, cam.height, opt);
  const Pinhole<float> Kf{float(p.K.fx), float(p.K.fy), float(p.K.cx), float(p.K.cy)};
  const auto& rf = tf.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), Kf, SE3<float>::identity());
  CHECK(rf.converged);
  CHECK(epe_px(p, rf.params.cast<double>()) < 2 * epe + 0.01);
  Tracker<double, HomographyWarp<double>, 1> th(cam.width, cam.height, opt);
  CHECK(th.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), p.K, Mat3<double>::Identity()).converged);
  return epe;
}

}  // namespace

TEST_CASE("a rendered same-layer pair with a known small relative pose converges below 0.01 px") {
  // A smooth texture over the NAIP tile's ground: the solver's own accuracy.
  const geo::Map smooth = test::flat_map(570.0, test::make_layer("s", 700, 800, 485900, 5209250, 5.0, [](int x, int y, std::uint8_t* p) {
    p[0] = static_cast<std::uint8_t>(128 + 90 * std::sin(x * 0.21) * std::cos(y * 0.13));
    p[1] = static_cast<std::uint8_t>(128 + 80 * std::sin(x * 0.07 + y * 0.17));
    p[2] = static_cast<std::uint8_t>(128 + 60 * std::cos(y * 0.11 - x * 0.05));
  }));
  CHECK(converge_same_layer(smooth, "s") < 0.01);
  // The real NAIP 2016 layer, 5 m texels magnified 4x: bilinear texture interpolation is not
  // shift-invariant (the two views sample the texels at different phases), which leaves
  // 0.025 px here; 0.05 px bounds it.
  auto naip = geo::load_map(test::source_path("data/naip_west/map.json"));
  REQUIRE(naip.ok());
  CHECK(converge_same_layer(naip.value(), "2016") < 0.05);
}

TEST_CASE("min_step_px stops the finest level once a step moves the image by less, and the answer stays within it") {
  auto naip = geo::load_map(test::source_path("data/naip_west/map.json"));
  REQUIRE(naip.ok());
  const geo::CameraModel cam = test::paper_camera();
  const Pair p = offset_pair(naip.value(), "2016", "2016");
  const Pinhole<float> Kf{float(p.K.fx), float(p.K.fy), float(p.K.cx), float(p.K.cy)};
  TrackerOptions opt;
  opt.iterations = 50;
  opt.step_tol = 0;  // never: every level runs its 50 steps unless the motion stop ends it
  SE3<double> answer[2];
  int iterations[2] = {0, 0};
  for (int k = 0; k < 2; ++k) {
    opt.min_step_px = k ? 0.01 : 0.0;
    Tracker<float, SE3DepthWarp<float>, 1> tracker(cam.width, cam.height, opt);
    const auto& res = tracker.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), Kf, SE3<float>::identity());
    REQUIRE(res.converged);
    answer[k] = res.params.cast<double>();
    iterations[k] = res.iterations;
  }
  const double e0 = epe_px(p, answer[0]), e1 = epe_px(p, answer[1]);
  MESSAGE("every step: " << iterations[0] << " iterations, EPE " << e0 << " px; min_step_px 0.01: " << iterations[1]
                         << ", EPE " << e1 << " px");
  CHECK(iterations[0] == 4 * 50);
  // The coarse levels run all their steps; the finest stops early.
  CHECK(iterations[1] > 3 * 50);
  CHECK(iterations[1] < 4 * 50);
  // Steps under 0.01 px that shrink as LM converges add up to a few hundredths: the answers
  // differ by far less than the 0.05 px this same-layer pair is registered to (test above).
  CHECK(std::abs(e1 - e0) < 0.02);
  CHECK(e1 < 0.05);
}

TEST_CASE("the coarse search starts the coarsest level nearer a prior that is a few coarse pixels off") {
  auto naip = geo::load_map(test::source_path("data/naip_west/map.json"));
  REQUIRE(naip.ok());
  const geo::CameraModel cam = test::paper_camera();
  // The prior looks 2 degrees away: about 23 pixels at 752 x 480, 2.9 at the coarsest of 4 levels.
  const geo::Pose truth = geo::pose_from_ypr({487450, 5207437, 570 + 800}, 30, 2, -3);
  const geo::Pose prior = geo::pose_from_ypr({487450, 5207437, 570 + 800}, 30, 4, -3);
  const Pair p = render_pair(naip.value(), cam, prior, truth, "2016", "2016");
  const double e0 = epe_px(p, SE3<double>::identity());
  CHECK(e0 > 15);
  TrackerOptions opt;
  for (int k : {0, 3}) {
    opt.coarse_search_px = k;
    Tracker<double, SE3DepthWarp<double>, 1> tracker(cam.width, cam.height, opt);
    const auto& res = tracker.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), p.K, SE3<double>::identity());
    const double e_start = epe_px(p, res.coarse_start);
    MESSAGE("coarse search " << k << " px: the coarsest level starts " << e_start << " px off (prior " << e0 << ")");
    if (k == 0) {
      CHECK(e_start == doctest::Approx(e0));  // no search: the prior itself
    } else {
      CHECK(e_start < 0.5 * e0);  // 2.9 coarse pixels off: the search's grid has a point within 0.7 of the truth
      CHECK(res.converged);
      CHECK(epe_px(p, res.params) < 0.1);
    }
  }
  // A prior turned 4 degrees about the optical axis (heading 34 against 30): the turns of the
  // search (2-degree steps) find it, the shifts alone cannot.
  const geo::Pose turned = geo::pose_from_ypr({487450, 5207437, 570 + 800}, 34, 2, -3);
  const Pair q = render_pair(naip.value(), cam, turned, truth, "2016", "2016");
  const double t0 = epe_px(q, SE3<double>::identity());
  double start[2] = {0, 0};
  for (int with_turns = 0; with_turns < 2; ++with_turns) {
    opt.coarse_search_px = 1;
    opt.coarse_search_yaw_deg = with_turns ? 4.0 : 0.0;
    Tracker<double, SE3DepthWarp<double>, 1> tracker(cam.width, cam.height, opt);
    const auto& res = tracker.align(q.ref_grey.view(), q.depth.view(), q.live_grey.view(), q.K, SE3<double>::identity());
    start[with_turns] = epe_px(q, res.coarse_start);
  }
  MESSAGE("turned prior " << t0 << " px off: the coarsest level starts " << start[0] << " px off without turns, "
                          << start[1] << " with");
  CHECK(start[1] < 0.25 * t0);
  CHECK(start[1] < 0.5 * start[0]);
}

TEST_CASE("set_options: fewer levels run only the finest, and the levels built come back (a refinement pass)") {
  auto naip = geo::load_map(test::source_path("data/naip_west/map.json"));
  REQUIRE(naip.ok());
  const geo::CameraModel cam = test::paper_camera();
  const geo::Pose truth = geo::pose_from_ypr({487450, 5207437, 570 + 800}, 30, 2, -3);
  const geo::Pose prior = geo::pose_from_ypr({487452, 5207437, 570 + 800}, 30, 2.2, -3);
  const Pair p = render_pair(naip.value(), cam, prior, truth, "2016", "2016");
  TrackerOptions opt;
  opt.iterations = 3;
  Tracker<double, SE3DepthWarp<double>, 1> tracker(cam.width, cam.height, opt);
  auto steps = [&] {
    return tracker.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), p.K, SE3<double>::identity()).iterations;
  };
  CHECK(steps() > 3);  // four levels of up to 3 steps
  tracker.set_options(refinement_options(tracker.options(), 1));
  CHECK(tracker.options().levels == 1);
  CHECK(tracker.options().coarse_search_px == 0);
  CHECK(tracker.options().agree_px == 0);
  CHECK(steps() <= 3);  // the finest alone
  opt.levels = 9;       // more than built: the four built
  tracker.set_options(opt);
  CHECK(tracker.options().levels == 4);
  CHECK(steps() > 3);
}

TEST_CASE("the tilt prior holds the answer's roll and pitch to the prior's and leaves heading and position free") {
  auto naip = geo::load_map(test::source_path("data/naip_west/map.json"));
  REQUIRE(naip.ok());
  const geo::CameraModel cam = test::paper_camera();
  const geo::Pose truth = geo::pose_from_ypr({487450, 5207437, 570 + 800}, 30, 2, -3);
  constexpr double kDeg = 3.14159265358979323846 / 180;
  // The tilt of `prior` relative to it: the rotation log(R_init^T R) of T_live_ref about the
  // axes orthogonal to the world's up in the reference camera, in degrees.
  auto tilt_deg = [](const geo::Pose& prior, const SE3<double>& T_live_ref) {
    const Vec3<double> u = prior.R().transpose() * Vec3<double>::UnitZ();
    const Vec3<double> e = SE3<double>{T_live_ref.R, Vec3<double>::Zero()}.log().head<3>();
    return (e - u * u.dot(e)).norm() / kDeg;
  };
  TrackerOptions opt;
  opt.iterations = 50;
  opt.coarse_search_px = 3;
  // 1. The prior's roll and pitch are the truth's; heading 1.5 degrees and the position 16 m
  //    off. A tight prior (0.05 deg) still finds heading and position: the EPE the solver
  //    reaches without it (below 0.1 px, the coarse-search test's bound).
  const geo::Pose level = geo::pose_from_ypr({487450 + 12, 5207437 - 9, 570 + 806}, 31.5, 2, -3);
  const Pair p = render_pair(naip.value(), cam, level, truth, "2016", "2016");
  CHECK(epe_px(p, SE3<double>::identity()) > 10);
  opt.tilt_prior_rad = 0.05 * kDeg;
  {
    Tracker<double, SE3DepthWarp<double>, 1> tracker(cam.width, cam.height, opt);
    tracker.set_up(level.R().transpose() * Vec3<double>::UnitZ());
    const auto& res = tracker.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), p.K, SE3<double>::identity());
    REQUIRE(res.converged);
    MESSAGE("right tilt, 0.05 deg prior: EPE " << epe_px(p, res.params) << " px, tilt moved " << tilt_deg(level, res.params)
                                               << " deg");
    CHECK(epe_px(p, res.params) < 0.1);
    CHECK(tilt_deg(level, res.params) < 0.05);
  }
  // 2. The prior's pitch 1 degree off the truth's. Without the prior (or without an up
  //    vector) the answer's tilt moves the whole degree to the truth's. With a prior it is
  //    the weighted mean of the two (MAP): this same-year pair alone pins the tilt to about
  //    0.02 degree (its covariance), so a 0.001-degree prior keeps it within 0.05 degree of
  //    the prior's, the image shift made up by the position.
  const geo::Pose pitched = geo::pose_from_ypr({487450 + 12, 5207437 - 9, 570 + 806}, 31.5, 3, -3);
  const Pair q = render_pair(naip.value(), cam, pitched, truth, "2016", "2016");
  const double want = tilt_deg(pitched, q.T_live_ref_true);
  CHECK(want == doctest::Approx(1.0).epsilon(0.02));
  double moved[3] = {0, 0, 0};
  Eigen::Matrix3d cov_rot = Eigen::Matrix3d::Zero();
  for (int k = 0; k < 3; ++k) {  // no prior; a prior without an up vector; the prior
    opt.tilt_prior_rad = k == 0 ? 0.0 : 0.001 * kDeg;
    opt.registration_floor_px = 0;  // the covariance of the image term and the prior alone
    opt.registration_floor_per_residual_px = 0;
    Tracker<double, SE3DepthWarp<double>, 1> tracker(cam.width, cam.height, opt);
    if (k == 2) tracker.set_up(pitched.R().transpose() * Vec3<double>::UnitZ());
    const auto& res = tracker.align(q.ref_grey.view(), q.depth.view(), q.live_grey.view(), q.K, SE3<double>::identity());
    REQUIRE(res.converged);
    moved[k] = tilt_deg(pitched, res.params);
    if (k == 2) cov_rot = res.covariance.topLeftCorner<3, 3>();
  }
  MESSAGE("pitch 1 deg off (truth " << want << "): tilt moved " << moved[0] << " deg without the prior, " << moved[1]
                                    << " without an up vector, " << moved[2] << " with a 0.001 deg prior");
  CHECK(moved[0] == doctest::Approx(want).epsilon(0.02));
  CHECK(moved[1] == moved[0]);
  CHECK(moved[2] < 0.05);
  // 3. The same prior held to another tilt than the start's (Tracker::set_up's `tilt`, as
  //    track's --attitude gives when the start keeps the prediction's): the truth's. The answer
  //    goes there, with the start 1 degree away: within 0.05 degree as in 2.
  {
    opt.tilt_prior_rad = 0.001 * kDeg;
    Tracker<double, SE3DepthWarp<double>, 1> tracker(cam.width, cam.height, opt);
    tracker.set_up(pitched.R().transpose() * Vec3<double>::UnitZ(),
                   SE3<double>{q.T_live_ref_true.R, Vec3<double>::Zero()}.log().head<3>());
    const auto& res = tracker.align(q.ref_grey.view(), q.depth.view(), q.live_grey.view(), q.K, SE3<double>::identity());
    REQUIRE(res.converged);
    const Vec3<double> u = pitched.R().transpose() * Vec3<double>::UnitZ();
    auto horizontal = [&](const SE3<double>& T) {
      const Vec3<double> e = SE3<double>{T.R, Vec3<double>::Zero()}.log().head<3>();
      return Vec3<double>(e - u * u.dot(e));
    };
    const double off = (horizontal(res.params) - horizontal(q.T_live_ref_true)).norm() / kDeg;
    MESSAGE("held to the truth's tilt: " << off << " deg from it, EPE " << epe_px(q, res.params) << " px");
    CHECK(off < 0.05);
  }
  // The posterior's tilt variance is at most the prior's (about each horizontal axis).
  const Vec3<double> u = pitched.R().transpose() * Vec3<double>::UnitZ();
  const Vec3<double> a = u.unitOrthogonal(), b = u.cross(a);
  const double s2 = std::pow(0.001 * kDeg, 2);
  CHECK(a.dot(cov_rot * a) <= s2 * (1 + 1e-9));
  CHECK(b.dot(cov_rot * b) <= s2 * (1 + 1e-9));
}

TEST_CASE("the altitude prior holds the answer's height to an altimeter's and leaves the rest free") {
  auto naip = geo::load_map(test::source_path("data/naip_west/map.json"));
  REQUIRE(naip.ok());
  const geo::CameraModel cam = test::paper_camera();
  const geo::Pose truth = geo::pose_from_ypr({487450, 5207437, 570 + 800}, 30, 2, -3);
  // The live camera's height above the reference camera along the world's up, in metres.
  auto height = [](const geo::Pose& prior, const SE3<double>& T_live_ref) {
    return (prior.R().transpose() * Vec3<double>::UnitZ()).dot(T_live_ref.inverse().t);
  };
  TrackerOptions opt;
  opt.iterations = 50;
  opt.coarse_search_px = 3;
  // 1. The prior at the truth's height, heading 1.5 degrees and 15 m horizontally off: a
  //    tight prior (0.05 m) still finds the rest, to the EPE the solver reaches without it
  //    (below 0.1 px, as the tilt prior's test), and keeps the height within 0.05 m.
  const geo::Pose level = geo::pose_from_ypr({487450 + 12, 5207437 - 9, 570 + 800}, 31.5, 2, -3);
  const Pair p = render_pair(naip.value(), cam, level, truth, "2016", "2016");
  CHECK(epe_px(p, SE3<double>::identity()) > 10);
  opt.altitude_prior_m = 0.05;
  {
    Tracker<double, SE3DepthWarp<double>, 1> tracker(cam.width, cam.height, opt);
    tracker.set_up(level.R().transpose() * Vec3<double>::UnitZ());
    tracker.set_height(0);
    const auto& res = tracker.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), p.K, SE3<double>::identity());
    REQUIRE(res.converged);
    MESSAGE("right height, 0.05 m prior: EPE " << epe_px(p, res.params) << " px, height moved " << height(level, res.params)
                                               << " m");
    CHECK(epe_px(p, res.params) < 0.1);
    CHECK(std::abs(height(level, res.params)) < 0.05);
  }
  // 2. The prior 8 m above the truth. Without the prior, or without an up vector or a height,
  //    the answer comes down the whole 8 m, the same bits each way. With a prior it is the
  //    weighted mean of the two (MAP): this same-year pair alone places the height to a few
  //    centimetres, so a 0.001 m prior keeps it within 0.05 m of the prior's.
  const geo::Pose high = geo::pose_from_ypr({487450 + 12, 5207437 - 9, 570 + 808}, 31.5, 2, -3);
  const Pair q = render_pair(naip.value(), cam, high, truth, "2016", "2016");
  const double want = height(high, q.T_live_ref_true);
  CHECK(want == doctest::Approx(-8.0).epsilon(0.05));
  SE3<double> answer[4];
  Eigen::Matrix<double, 6, 6> cov = Eigen::Matrix<double, 6, 6>::Zero();
  for (int k = 0; k < 4; ++k) {  // no prior; a prior without an up vector; without a height; the prior
    opt.altitude_prior_m = k == 0 ? 0.0 : 0.001;
    opt.registration_floor_px = 0;  // the covariance of the image term and the prior alone
    opt.registration_floor_per_residual_px = 0;
    Tracker<double, SE3DepthWarp<double>, 1> tracker(cam.width, cam.height, opt);
    if (k >= 2) tracker.set_up(high.R().transpose() * Vec3<double>::UnitZ());
    if (k == 3) tracker.set_height(0);
    const auto& res = tracker.align(q.ref_grey.view(), q.depth.view(), q.live_grey.view(), q.K, SE3<double>::identity());
    REQUIRE(res.converged);
    answer[k] = res.params;
    if (k == 3) cov = res.covariance;
  }
  MESSAGE("8 m high (truth " << want << " m): the answer moved " << height(high, answer[0]) << " m without the prior, "
                             << height(high, answer[3]) << " m with a 0.001 m prior");
  CHECK(height(high, answer[0]) == doctest::Approx(want).epsilon(0.01));
  CHECK(epe_px(q, answer[0]) < 0.1);
  for (int k = 1; k < 3; ++k) {
    CHECK(answer[k].R == answer[0].R);
    CHECK(answer[k].t == answer[0].t);
  }
  CHECK(std::abs(height(high, answer[3])) < 0.05);
  // 3. Held to the truth's height (an altimeter that reads it, the start 8 m away): the answer
  //    goes there, within 0.05 m, as in 2.
  {
    opt.altitude_prior_m = 0.001;
    Tracker<double, SE3DepthWarp<double>, 1> tracker(cam.width, cam.height, opt);
    tracker.set_up(high.R().transpose() * Vec3<double>::UnitZ());
    tracker.set_height(want);
    const auto& res = tracker.align(q.ref_grey.view(), q.depth.view(), q.live_grey.view(), q.K, SE3<double>::identity());
    REQUIRE(res.converged);
    MESSAGE("held to the truth's height: " << height(high, res.params) - want << " m from it, EPE " << epe_px(q, res.params)
                                           << " px");
    CHECK(std::abs(height(high, res.params) - want) < 0.05);
    CHECK(epe_px(q, res.params) < 0.1);
  }
  // The posterior's variance of the height is at most the prior's: J cov J^T for the height's
  // row J = [(c x u)^T, u^T] at the answer (the live centre c in the reference camera).
  const Vec3<double> u = high.R().transpose() * Vec3<double>::UnitZ();
  const Vec3<double> c = answer[3].inverse().t;
  Eigen::Matrix<double, 1, 6> J;
  J << c.cross(u).transpose(), u.transpose();
  const double var = (J * cov * J.transpose())(0, 0);
  MESSAGE("the height's posterior sigma " << std::sqrt(var) << " m against the prior's 0.001 m");
  CHECK(var > 0);
  CHECK(var <= 1e-6 * (1 + 1e-6));
}

TEST_CASE("the registration floor's keystones: a tilt traded for a shift, which a tilt prior narrows") {
  // A same-year pair, 800 m above flat ground, the floor made to dominate the covariance (1e4
  // px per unit of the final residual, all of it, the fixed floor off): its keystones admit a tilt
  // of the camera whose image shift a move of the camera takes back, the direction in which
  // maps of distant years mislead the learned tracker (README, "Why the tilt prior").
  auto naip = geo::load_map(test::source_path("data/naip_west/map.json"));
  REQUIRE(naip.ok());
  const geo::CameraModel cam = test::paper_camera();
  const geo::Pose truth = geo::pose_from_ypr({487450, 5207437, 570 + 800}, 30, 2, -3);
  const geo::Pose prior = geo::pose_from_ypr({487450 + 6, 5207437 - 4, 570 + 803}, 30.5, 2, -3);  // the truth's tilt
  const Pair p = render_pair(naip.value(), cam, prior, truth, "2016", "2016");
  constexpr double kDeg = 3.14159265358979323846 / 180;
  TrackerOptions opt;
  opt.iterations = 50;
  opt.registration_floor_px = 0;
  opt.keystone_free_residual = 0;  // the keystones from the first unit of residual on
  const Vec3<double> u = prior.R().transpose() * Vec3<double>::UnitZ();  // the world's up, reference camera
  const Vec3<double> a = u.unitOrthogonal(), b = u.cross(a);              // two horizontal axes
  struct Sigmas {
    double tilt_deg, horizontal_m, residual;
  };
  auto sigmas = [&](double per_residual, double tilt_prior_deg) {
    opt.registration_floor_per_residual_px = per_residual;
    opt.tilt_prior_rad = tilt_prior_deg * kDeg;
    Tracker<double, SE3DepthWarp<double>, 1> tracker(cam.width, cam.height, opt);
    tracker.set_up(u);
    const auto& res = tracker.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), p.K, SE3<double>::identity());
    REQUIRE(res.converged);
    CHECK(epe_px(p, res.params) < 0.1);
    const Eigen::Matrix3d R = res.covariance.topLeftCorner<3, 3>(), T = res.covariance.bottomRightCorner<3, 3>();
    return Sigmas{std::sqrt(a.dot(R * a) + b.dot(R * b)) / kDeg, std::sqrt(a.dot(T * a) + b.dot(T * b)), res.residual_final};
  };
  const Sigmas none = sigmas(0, 0), floor = sigmas(1e4, 0), held = sigmas(1e4, 0.01);
  const double keystone_px = 1e4 * floor.residual;
  MESSAGE("keystones of " << keystone_px << " px: tilt sigma " << none.tilt_deg << " -> " << floor.tilt_deg
                          << " deg, horizontal position " << none.horizontal_m << " -> " << floor.horizontal_m
                          << " m; with a 0.01 deg tilt prior " << held.tilt_deg << " deg, " << held.horizontal_m << " m");
  REQUIRE(keystone_px > 0.5);  // large enough to dominate the image term's few hundredths of a degree
  // A keystone of k px RMS is the perspective change of a tilt of about k / (f rms(x^2)) rad
  // (x the normalised image coordinate: rms 0.2-0.3 over this 60-degree view), a degree or
  // more a pixel: the floor's tilt sigma must reach at least half a degree per pixel of it.
  CHECK(floor.tilt_deg > 0.5 * keystone_px);
  // ... and the camera moves with it: 800 m x the tilt keeps the image in place, so the
  // horizontal position's sigma follows the tilt's (within 30 %: the shift and rotation modes
  // add their own).
  CHECK(floor.horizontal_m == doctest::Approx(800 * floor.tilt_deg * kDeg).epsilon(0.3));
  // A tilt prior (an attitude reference) is combined with the image term, floor included:
  // the tilt is held to it, and with the tilt the shift the keystones traded for it.
  CHECK(held.tilt_deg < 0.02);
  CHECK(held.horizontal_m < 0.2 * floor.horizontal_m);
}

TEST_CASE("the agreement test: a second start nearby returns to a basin and settles elsewhere on a lattice") {
  // Two textures seen from the truth itself (reference and live the same view, so every
  // level starts and stays at the answer): a smooth one, whose only minimum near the answer is
  // the answer, and a lattice of period 3 finest-level pixels (3.7 m at 800 m), a minimum
  // every period. The second start, 2 px away in u and in v (2.8 px), is nearer the lattice's
  // next minimum (3, 3) than the answer, so it settles there, about 4.2 px away.
  const geo::CameraModel cam = test::paper_camera();
  const geo::Pose truth = geo::pose_from_ypr({1000, 800, 800}, 0, 0, 0);
  const double period_m = 3.0 * 800 / cam.fx;
  constexpr double kPiD = 3.14159265358979323846;
  auto texture = [&](bool lattice) {
    return test::flat_map(0.0, test::make_layer("t", 2400, 1800, 400, 1250, 0.5, [&](int x, int y, std::uint8_t* p) {
      const double u = 2 * kPiD * x * 0.5 / period_m, v = 2 * kPiD * y * 0.5 / period_m;
      const double s = lattice ? 50 * (std::sin(u) + std::sin(v))
                               : 90 * std::sin(x * 0.021) * std::cos(y * 0.013) + 40 * std::sin(x * 0.007 + y * 0.017);
      // Clamped: the smooth texture's peaks reach 128 + 130 (a float-to-byte conversion out of
      // range is undefined; clang's UBSan stops on it).
      p[0] = p[1] = p[2] = static_cast<std::uint8_t>(std::clamp(128 + s, 0.0, 255.0));
    }));
  };
  TrackerOptions opt;
  opt.agree_px = 2;
  for (bool lattice : {false, true}) {
    CAPTURE(lattice);
    const Pair p = render_pair(texture(lattice), cam, truth, truth, "t", "t");
    Tracker<double, SE3DepthWarp<double>, 1> measured(cam.width, cam.height, opt);
    const auto& res = measured.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), p.K, SE3<double>::identity());
    REQUIRE(res.converged);  // no threshold: measured only
    CHECK(epe_px(p, res.params) < 0.01);
    MESSAGE(std::string(lattice ? "lattice" : "smooth") << ": the second start settles " << res.disagreement_px << " px away");
    if (lattice) CHECK(res.disagreement_px > 3);  // 4.2 px to the next minimum, at least most of it
    else CHECK(res.disagreement_px < 0.05);       // back to the answer, within the steps' tolerance
    // With a threshold of 1 px between the two, the lattice's answer is reported as failed,
    // the initial pose returned, and the smooth one stands.
    opt.max_disagreement_px = 1;
    Tracker<double, SE3DepthWarp<double>, 1> tested(cam.width, cam.height, opt);
    const auto& t = tested.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), p.K, SE3<double>::identity());
    CHECK(t.converged == !lattice);
    if (lattice) {
      CHECK(std::string(t.reason).rfind("ambiguous", 0) == 0);
      CHECK(t.params.t.norm() == 0.0);
    }
    opt.max_disagreement_px = 0;
  }
}

TEST_CASE("a pair with no texture reports failure instead of a pose") {
  const geo::Map map = test::flat_map(0.0, test::make_layer("grey", 400, 400, 0, 2000, 5.0, [](int, int, std::uint8_t* p) {
    p[0] = p[1] = p[2] = 120;
  }));
  const geo::CameraModel cam = test::paper_camera();
  const geo::Pose truth = geo::pose_from_ypr({1000, 1000, 800}, 0, 0, 0);
  const geo::Pose prior = geo::pose_from_ypr({1010, 1000, 800}, 1, 0, 0);
  const Pair p = render_pair(map, cam, prior, truth, "grey", "grey");
  Tracker<double, SE3DepthWarp<double>, 1> tracker(cam.width, cam.height, TrackerOptions{});
  const auto& res = tracker.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), p.K, SE3<double>::identity());
  CHECK(!res.converged);
  MESSAGE("reason: " << std::string(res.reason));
  CHECK(std::string(res.reason).find("texture") != std::string::npos);
  CHECK(res.params.R == Mat3<double>::Identity());  // the initial pose, never NaN
}

TEST_CASE("1, 2 and 3 threads, and the scalar and vector (AVX2, NEON) residual kernels, give the same pose, bit for bit") {
  const geo::CameraModel cam = test::paper_camera();
  const Pair p = naip_2012_pair();
  const Pinhole<float> K{float(p.K.fx), float(p.K.fy), float(p.K.cx), float(p.K.cy)};
  TrackerOptions o1, o2, o3, o4;
  o1.threads = 1;
  o2.threads = 2;
  o3.simd = false;
  o4.threads = 3;  // the pixel selection's bands and the sums' chunks do not follow the threads
  Tracker<float, SE3DepthWarp<float>, 1> t1(cam.width, cam.height, o1), t2(cam.width, cam.height, o2),
      t3(cam.width, cam.height, o3), t4(cam.width, cam.height, o4);
  const auto& r1 = t1.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), K, SE3<float>::identity());
  for (auto* t : {&t2, &t3, &t4}) {
    const auto& r2 = t->align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), K, SE3<float>::identity());
    CHECK(r1.converged);
    CHECK(r1.iterations == r2.iterations);
    CHECK(r1.params.R == r2.params.R);
    CHECK(r1.params.t == r2.params.t);
    CHECK(r1.covariance == r2.covariance);
  }
}

TEST_CASE("four feature channels: the same bits on any thread count and kernel, and four copies of one channel align as one") {
  const geo::CameraModel cam = test::paper_camera();
  const Pair p = naip_2012_pair();
  const Pinhole<float> K{float(p.K.fx), float(p.K.fy), float(p.K.cx), float(p.K.cy)};
  // Channels of one image: c = 0 the grey, 1 its square, 2 the grey shifted a pixel right, 3
  // its negative; `copies`: the grey four times.
  auto channels = [&](const ImageF& g, bool copies) {
    ImageF out(g.width(), g.height(), 4);
    for (int y = 0; y < g.height(); ++y)
      for (int x = 0; x < g.width(); ++x) {
        const float v = g.at(x, y);
        out.at(x, y, 0) = v;
        out.at(x, y, 1) = copies ? v : v * v;
        out.at(x, y, 2) = copies ? v : g.at(std::max(x - 1, 0), y);
        out.at(x, y, 3) = copies ? v : -v;
      }
    return out;
  };
  const ImageF ref4 = channels(p.ref_grey, false), live4 = channels(p.live_grey, false);
  TrackerOptions o1, o2, o3;
  o1.threads = 1;
  o2.threads = 2;
  o3.simd = false;
  Tracker<float, SE3DepthWarp<float>, 4> t1(cam.width, cam.height, o1), t2(cam.width, cam.height, o2),
      t3(cam.width, cam.height, o3);
  const auto& r1 = t1.align(ref4.view(), p.depth.view(), live4.view(), K, SE3<float>::identity());
  CHECK(r1.converged);
  for (auto* t : {&t2, &t3}) {
    const auto& r2 = t->align(ref4.view(), p.depth.view(), live4.view(), K, SE3<float>::identity());
    CHECK(r1.iterations == r2.iterations);
    CHECK(r1.params.R == r2.params.R);
    CHECK(r1.params.t == r2.params.t);
    CHECK(r1.covariance == r2.covariance);
  }
  // Four copies: H, g and the cost summed four times over, the step and the cost per residual
  // the same as one channel's up to float summation order (each lane's float sum takes a
  // pixel's four channels in turn): the translation agrees to 1e-4 of its size (measured
  // 2.2e-5: float sums of ~1000 terms a lane, through 80 solves), the rotation to 1e-5, the
  // cost per residual to 1e-4 relative. The covariance
  // too (to 1e-3): H is four times larger, but the channels' residuals correlate fully, so
  // the channel factor (1 + 3 x 1) gives it back; without that factor it came out 2-3x too
  // small.
  const ImageF refc = channels(p.ref_grey, true), livec = channels(p.live_grey, true);
  Tracker<float, SE3DepthWarp<float>, 1> one(cam.width, cam.height, o2);
  const auto r1c = one.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), K, SE3<float>::identity());
  const auto& r4c = t2.align(refc.view(), p.depth.view(), livec.view(), K, SE3<float>::identity());
  REQUIRE(r1c.converged);
  CHECK(r4c.converged);
  CHECK((r4c.params.t - r1c.params.t).norm() <= 1e-4f * std::max(1.0f, r1c.params.t.norm()));
  CHECK((r4c.params.R - r1c.params.R).norm() <= 1e-5f);
  CHECK(r4c.cost_final == doctest::Approx(r1c.cost_final).epsilon(1e-4));
  CHECK(r4c.residual_final == doctest::Approx(r1c.residual_final).epsilon(1e-4));
  for (int k = 0; k < 6; ++k) CHECK(r4c.covariance(k, k) == doctest::Approx(r1c.covariance(k, k)).epsilon(1e-3));
  MESSAGE("four copies against one channel: translation differs by " << (r4c.params.t - r1c.params.t).norm()
                                                                      << ", cost " << r4c.cost_final << " / " << r1c.cost_final);
}

#if defined(TERRALIGN_ICLK_AVX2) || defined(TERRALIGN_ICLK_NEON)
// The vector builds of the solver's kernels this machine runs (AVX2 where the CPU has it,
// NEON on aarch64), or nulls.
struct VectorKernels {
  detail::Se3EvalFn se3 = nullptr;
  detail::OuterSumsFn outer = nullptr;
  detail::OuterSumsAtFn outer_at = nullptr;
  detail::Se3JacobianFn jacobians = nullptr;
};
VectorKernels vector_kernels() {
#if defined(TERRALIGN_ICLK_AVX2)
  if (!cpu_features().avx2_fma) return {};
  return {detail::evaluate_se3_avx2, detail::outer_sums_avx2, detail::outer_sums_at_avx2, detail::se3_jacobians_avx2};
#else
  return {detail::evaluate_se3_neon, detail::outer_sums_neon, detail::outer_sums_at_neon, detail::se3_jacobians_neon};
#endif
}
// Every vector build of the residual kernel this machine runs: AVX2's and, where the CPU has
// AVX-512, its sixteen-pixel one; NEON's on aarch64.
std::vector<detail::Se3EvalFn> se3_vector_kernels() {
  std::vector<detail::Se3EvalFn> fns;
  if (vector_kernels().se3) fns.push_back(vector_kernels().se3);
#if defined(TERRALIGN_ICLK_AVX2)
  if (cpu_features().avx512f) fns.push_back(detail::evaluate_se3_avx512);
#endif
  return fns;
}

// The residual kernel's inputs: a W x H live image and n reference points, values, weights
// and Jacobians (the caller places the points and sets the weights), seen through K =
// (40, 40, 30, 18) and a pose set with pose().
struct KernelCase {
  int W, H, n;
  std::vector<float> px, py, pz, val, w, live, jac[6];
  detail::Se3EvalInput in{};
  // C channels: the values, Jacobians and live level hold one plane per channel.
  KernelCase(int width, int height, int count, std::mt19937& rng, float jac_scale, int C = 1)
      : W(width), H(height), n(count), px(n), py(n), pz(n), val(static_cast<std::size_t>(n) * C), w(n),
        live(static_cast<std::size_t>(W) * H * C) {
    std::uniform_real_distribution<float> U(-1, 1);
    for (auto& v : live) v = U(rng);
    for (auto& v : val) v = U(rng);
    for (auto& j : jac) {
      j.resize(static_cast<std::size_t>(n) * C);
      for (auto& v : j) v = jac_scale * U(rng);
    }
    in.channels = C;
    in.plane = in.jac_plane = n;
    in.live_plane = static_cast<std::ptrdiff_t>(W) * H;
    in.px = px.data();
    in.py = py.data();
    in.pz = pz.data();
    in.val = val.data();
    in.w = w.data();
    for (int k = 0; k < 6; ++k) in.jac[k] = jac[k].data();
    in.live = live.data();
    in.stride = W;
    in.width = W;
    in.height = H;
    in.fx = in.fy = 40.0f;
    in.cx = 30.0f;
    in.cy = 18.0f;
  }
  void pose(const SE3<float>& T) {
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) in.R[3 * a + b] = T.R(a, b);
      in.t[a] = T.t[a];
    }
  }
  // Both builds over [i0, i1), from outputs filled with markers (r 7, ok 9, out -1): every
  // output the same bits; the scalar build's returned.
  struct Run {
    std::vector<float> r;
    std::vector<unsigned char> ok;
    std::vector<int> out;
    detail::Se3EvalSums s{};
  };
  Run both(int i0, int i1) {
    const std::size_t values = static_cast<std::size_t>(n) * static_cast<std::size_t>(in.channels);
    Run a{std::vector<float>(values, 7.0f), std::vector<unsigned char>(n, 9), std::vector<int>(n, -1)};
    in.out = a.out.data();
    detail::evaluate_se3_scalar(in, i0, i1, a.r.data(), a.ok.data(), a.s);
    for (const detail::Se3EvalFn fn : se3_vector_kernels()) {
      Run b{std::vector<float>(values, 7.0f), std::vector<unsigned char>(n, 9), std::vector<int>(n, -1)};
      in.out = b.out.data();
      fn(in, i0, i1, b.r.data(), b.ok.data(), b.s);
      CHECK(std::memcmp(a.r.data(), b.r.data(), values * sizeof(float)) == 0);
      CHECK(a.ok == b.ok);
      CHECK(a.out == b.out);
      CHECK(std::memcmp(&a.s, &b.s, sizeof a.s) == 0);
    }
    return a;
  }
};
#endif

TEST_CASE("the residual kernel: its vector builds (AVX2, AVX-512, NEON) and the scalar one agree bit for bit, at the edges, behind the camera and on NaN, in 1, 2 and 5 channels") {
#if defined(TERRALIGN_ICLK_AVX2) || defined(TERRALIGN_ICLK_NEON)
  if (!vector_kernels().se3) {
    MESSAGE("this CPU has no AVX2: only the scalar kernel runs here");
    return;
  }
  // 2 channels: the learned tracker's levels; 5: more than the AVX-512 build keeps apart,
  // which hands them to the AVX2 one.
  for (const int C : {1, 2, 5}) {
  CAPTURE(C);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> U(-1, 1);
  KernelCase k(61, 37, 1000, rng, 10.0f, C);
  const int n = k.n;
  for (int i = 0; i < n; ++i) {
    // Depth 100; points spread over 1.4x the image so that some land outside; some behind the
    // camera, some NaN; weights include 0.
    const auto j = static_cast<std::size_t>(i);
    k.pz[j] = i % 97 == 0 ? -5.0f : 100.0f;
    k.px[j] = 70.0f * U(rng);
    k.py[j] = 45.0f * U(rng);
    if (i % 89 == 0) k.px[j] = NAN;
    k.w[j] = i % 7 == 0 ? 0.0f : 0.5f + 0.5f * U(rng);
  }
  k.pose(SE3<float>::exp((Vec6<float>() << 0.01f, -0.02f, 0.03f, 1.5f, -0.7f, 2.0f).finished()));
  // Ranges with a partial last group of eight or sixteen (more or fewer than eight left), and
  // ones shorter than a group.
  for (const auto& [i0, i1] : std::vector<std::pair<int, int>>{{0, n}, {3, 998}, {1, 990}, {500, 505}, {10, 23}}) {
    const KernelCase::Run run = k.both(i0, i1);
    int landed = 0;
    std::vector<int> left;
    for (int i = i0; i < i1; ++i) {
      landed += run.ok[static_cast<std::size_t>(i)];
      if (!run.ok[static_cast<std::size_t>(i)]) left.push_back(i);
    }
    CHECK(run.s.valid == landed);
    // The list names exactly the pixels that did not land, in order, and nothing more.
    REQUIRE(run.s.n_out == static_cast<int>(left.size()));
    CHECK(std::equal(left.begin(), left.end(), run.out.begin()));
    CHECK(run.out[left.size()] == -1);
    if (i1 - i0 > 100) {  // the case is not degenerate: some land, some do not
      CHECK(landed > (i1 - i0) / 4);
      CHECK(landed < i1 - i0);
    }
    for (const float g : run.s.g[0]) CHECK(std::isfinite(g));
    // Nothing written outside the range.
    if (i0 > 0) CHECK((run.r[static_cast<std::size_t>(i0 - 1)] == 7.0f && run.ok[static_cast<std::size_t>(i0 - 1)] == 9));
    if (i1 < n) CHECK((run.r[static_cast<std::size_t>(i1)] == 7.0f && run.ok[static_cast<std::size_t>(i1)] == 9));
  }
  }
#else
  MESSAGE("built without a vector kernel");
#endif
}

TEST_CASE("the residual kernel: its vector builds (AVX2, AVX-512, NEON) and the scalar one agree bit for bit where neighbouring pixels land side by side, in 1 and 2 channels") {
#if defined(TERRALIGN_ICLK_AVX2) || defined(TERRALIGN_ICLK_NEON)
  if (!vector_kernels().se3) {
    MESSAGE("this CPU has no AVX2: only the scalar kernel runs here");
    return;
  }
  // Every pixel of a 61 x 37 reference at depth 100, in row order (as the tracker lists
  // them): warped by the identity and by small motions, runs of eight land in one live row
  // within eight columns (the AVX2 kernel's row-window loads), others straddle two rows or
  // the image's edge (its gathers); so do runs of sixteen (the AVX-512 kernel's).
  for (const int C : {1, 2}) {
  CAPTURE(C);
  std::mt19937 rng(6);
  std::uniform_real_distribution<float> U(-1, 1);
  KernelCase k(61, 37, 61 * 37, rng, 1.0f, C);
  for (int i = 0; i < k.n; ++i) {
    const auto j = static_cast<std::size_t>(i);
    k.pz[j] = 100.0f;
    k.px[j] = 100.0f * (static_cast<float>(i % k.W) - k.in.cx) / k.in.fx;
    k.py[j] = 100.0f * (static_cast<float>(i / k.W) - k.in.cy) / k.in.fy;
    k.w[j] = 0.5f + 0.5f * U(rng);
  }
  for (const Vec6<float>& xi : {Vec6<float>::Zero().eval(), (Vec6<float>() << 0, 0, 0, 0.6f, 0.3f, 0).finished(),
                                (Vec6<float>() << 0.002f, -0.003f, 0.02f, 1.1f, -0.4f, 0.5f).finished()}) {
    k.pose(SE3<float>::exp(xi));
    CHECK(k.both(0, k.n).s.valid > k.n / 2);  // most land: the case is not degenerate
  }
  }
#else
  MESSAGE("built without a vector kernel");
#endif
}

TEST_CASE("the J^T W J kernels: their vector builds (AVX2, NEON) and the scalar ones agree bit for bit, and with a plain sum in double") {
  using namespace detail;
  const int n = 1003;
  std::vector<float> w(n), jac[6];
  std::mt19937 rng(8);
  std::uniform_real_distribution<float> U(-1, 1);
  for (int i = 0; i < n; ++i) w[static_cast<std::size_t>(i)] = i % 7 == 0 ? 0.0f : i % 11 == 0 ? -1.0f : 1.5f + U(rng);
  w[13] = NAN;
  for (auto& j : jac) {
    j.resize(n);
    for (auto& v : j) v = 10 * U(rng);
  }
  jac[2][21] = INFINITY;  // on a pixel of weight 0: it must add nothing, not NaN
  jac[4][22] = NAN;       // on a pixel of negative weight, likewise
  const float* J[6];
  for (int a = 0; a < 6; ++a) J[a] = jac[a].data();
  // Lists in any order with any gaps, and runs of consecutive pixels (of 1 to 9, which the
  // AVX2 kernel loads plainly where four are in a row).
  std::vector<int> down, runs;
  for (int i = n - 1; i >= 0; i -= 3) down.push_back(i);
  for (int i = 0, len = 1; i < n; i += len + 2, len = len % 9 + 1)
    for (int k = i; k < std::min(i + len, n); ++k) runs.push_back(k);
  // The reference: a plain sum over the pixels whose weight is > 0.
  auto plain = [&](auto pixels) {
    double h[21] = {};
    for (int i : pixels) {
      const double wd = static_cast<double>(w[static_cast<std::size_t>(i)]);
      if (!(wd > 0)) continue;
      int e = 0;
      for (int a = 0; a < 6; ++a)
        for (int b = 0; b <= a; ++b, ++e) h[e] += wd * static_cast<double>(jac[a][static_cast<std::size_t>(i)]) * static_cast<double>(jac[b][static_cast<std::size_t>(i)]);
    }
    return std::vector<double>(h, h + 21);
  };
  auto lanes = [](const OuterSums& s) {
    std::vector<double> h(21, 0.0);
    for (int e = 0; e < 21; ++e)
      for (double v : s.h[e]) h[static_cast<std::size_t>(e)] += v;
    return h;
  };
  // Sums of up to 1000 terms of size <= 300 in double, in another order: within 1e-12 of the
  // largest entry (the rounding of each order is about 1000 x 1.1e-16 of it).
  auto close = [](const std::vector<double>& a, const std::vector<double>& b) {
    double big = 0;
    for (double v : b) big = std::max(big, std::abs(v));
    for (std::size_t e = 0; e < a.size(); ++e)
      if (!(std::abs(a[e] - b[e]) <= 1e-12 * big)) return false;
    return big > 0;
  };
  for (const auto& [i0, i1] : std::vector<std::pair<int, int>>{{0, n}, {3, 998}, {500, 502}}) {
    std::vector<int> range;
    for (int i = i0; i < i1; ++i) range.push_back(i);
    OuterSums s1{};
    outer_sums_scalar(J, w.data(), i0, i1, s1);
    CHECK(close(lanes(s1), plain(range)));
#if defined(TERRALIGN_ICLK_AVX2) || defined(TERRALIGN_ICLK_NEON)
    if (vector_kernels().outer) {
      OuterSums s2{};
      vector_kernels().outer(J, w.data(), i0, i1, s2);
      CHECK(std::memcmp(&s1, &s2, sizeof s1) == 0);
    }
#endif
    for (const auto* index : {&down, &runs}) {
      const int count = static_cast<int>(std::min<std::size_t>(index->size(), static_cast<std::size_t>(i1 - i0)));
      OuterSums s3{};
      outer_sums_at_scalar(J, w.data(), index->data(), count, s3);
      CHECK(close(lanes(s3), plain(std::vector<int>(index->begin(), index->begin() + count))));
#if defined(TERRALIGN_ICLK_AVX2) || defined(TERRALIGN_ICLK_NEON)
      if (vector_kernels().outer_at) {
        OuterSums s4{};
        vector_kernels().outer_at(J, w.data(), index->data(), count, s4);
        CHECK(std::memcmp(&s3, &s4, sizeof s3) == 0);
      }
#endif
    }
  }
}

TEST_CASE("the Jacobian kernel: the warp's d_warp_d_xi with a Sobel / 8 gradient, and its vector build (AVX2, NEON) the same bits (runs of eight, gathered and partial groups, in 1, 2 and 4 channels)") {
  using namespace detail;
  const int W = 40, H = 23;
  const Pinhole<float> K{35.0f, 33.0f, 19.5f, 11.0f};
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> U(-1, 1);
  std::vector<float> depth(static_cast<std::size_t>(W) * H);
  for (auto& d : depth) d = 100.0f + 40.0f * U(rng);
  // Groups of pixels (x, y), each with a neighbour on every side: eight side by side on a row
  // (the vector builds' plain loads), eight side by side across a row's end, eight scattered,
  // three of a row and one alone (lanes past the count unwritten, adding +0 to the sums).
  std::vector<std::vector<std::pair<int, int>>> groups = {{}, {}, {}, {}, {{17, 9}}};
  for (int l = 0; l < 8; ++l) {
    groups[0].push_back({5 + l, 7});
    groups[1].push_back(l < 4 ? std::pair<int, int>{W - 5 + l, 3} : std::pair<int, int>{l - 3, 4});
    groups[2].push_back({1 + (l * 13) % (W - 2), 1 + (l * 7) % (H - 2)});
    if (l < 3) groups[3].push_back({W - 4 + l, H - 2});
  }
  for (const int C : {1, 2, 4}) {
    CAPTURE(C);
    std::vector<float> ref(static_cast<std::size_t>(W) * H * static_cast<std::size_t>(C));
    for (auto& v : ref) v = 3.0f * U(rng);
    Se3JacobianInput in;
    in.ref = ref.data();
    in.depth = depth.data();
    in.width = W;
    in.channels = C;
    in.fx = K.fx;
    in.fy = K.fy;
    in.cx = K.cx;
    in.cy = K.cy;
    // Outputs of 8 pixels, 8 floats a plane, filled with a marker.
    struct Out {
      std::vector<float> buf = std::vector<float>(8 * (5 + 4 + 6 * 4), 7.0f);
      Se3JacobianGroup g{};
      Se3FinestSums sums{};
      Out(int channels) {
        float* p = buf.data();
        g.pu = p;
        g.pv = p + 8;
        g.px = p + 16;
        g.py = p + 24;
        g.pz = p + 32;
        g.val = p + 40;
        g.plane = 8;
        for (int a = 0; a < 6; ++a) g.jac[a] = p + 40 + 8 * channels + 8 * a;
        g.jac_plane = 6 * 8;
        // Sums already under way: the kernel adds to them.
        for (auto& e : sums.motion)
          for (int l = 0; l < 8; ++l) e[l] = 0.25f * static_cast<float>(l + 1);
        for (auto& a : sums.floor)
          for (auto& m : a)
            for (int l = 0; l < 8; ++l) m[l] = -0.5f * static_cast<float>(l);
      }
    };
    for (const auto& group : groups) {
      const int count = static_cast<int>(group.size());
      int xs[8] = {}, ys[8] = {};
      for (int l = 0; l < count; ++l) {
        xs[l] = group[static_cast<std::size_t>(l)].first;
        ys[l] = group[static_cast<std::size_t>(l)].second;
      }
      Out a(C);
      const Out start(C);
      se3_jacobians_scalar(in, xs, ys, count, a.g, &a.sums);
      // Against the warp's own Jacobian and a Sobel / 8 of each channel, pixel by pixel: the
      // same bits, except where Eigen's vector products fuse a multiply and an add of their
      // own (NEON: EIGEN_HAS_SINGLE_INSTRUCTION_MADD), which moves a two-term entry of dW by
      // an ulp; there within 1e-6 of the terms' size (a few ulps; the kernel never fuses, so
      // its scalar build is bit for bit its vector ones', checked below, on every CPU).
#if defined(EIGEN_HAS_SINGLE_INSTRUCTION_MADD)
      auto same = [](float got, float want, float size) { return std::abs(got - want) <= 1e-6f * size; };
#else
      auto same = [](float got, float want, float) { return got == want; };
#endif
      auto I = [&](int x, int y, int c) { return ref[(static_cast<std::size_t>(y) * W + static_cast<std::size_t>(x)) * static_cast<std::size_t>(C) + static_cast<std::size_t>(c)]; };
      Se3FinestSums sums = start.sums;
      for (int l = 0; l < 8; ++l) {
        float wu[6] = {}, wv[6] = {}, mu = 0.0f, mv = 0.0f;
        if (l < count) {
          const int x = xs[l], y = ys[l];
          const float u = static_cast<float>(x), v = static_cast<float>(y), d = depth[static_cast<std::size_t>(y * W + x)];
          const Vec3<float> X(d * (u - K.cx) / K.fx, d * (v - K.cy) / K.fy, d);
          const auto dW = SE3DepthWarp<float>::d_warp_d_xi(X, u, v, K);
          CHECK((a.g.pu[l] == u && a.g.pv[l] == v && a.g.px[l] == X.x() && a.g.py[l] == X.y() && a.g.pz[l] == X.z()));
          for (int c = 0; c < C; ++c) {
            const float gx = (I(x + 1, y - 1, c) + 2.0f * I(x + 1, y, c) + I(x + 1, y + 1, c) - I(x - 1, y - 1, c) -
                              2.0f * I(x - 1, y, c) - I(x - 1, y + 1, c)) / 8.0f;
            const float gy = (I(x - 1, y + 1, c) + 2.0f * I(x, y + 1, c) + I(x + 1, y + 1, c) - I(x - 1, y - 1, c) -
                              2.0f * I(x, y - 1, c) - I(x + 1, y - 1, c)) / 8.0f;
            CHECK(a.g.val[c * 8 + l] == I(x, y, c));
            for (int k = 0; k < 6; ++k)
              CHECK(same(a.g.jac[k][c * a.g.jac_plane + l], gx * dW(0, k) + gy * dW(1, k),
                         std::abs(gx * dW(0, k)) + std::abs(gy * dW(1, k))));
          }
          for (int k = 0; k < 6; ++k) {
            wu[k] = dW(0, k);
            wv[k] = dW(1, k);
          }
          mu = u - K.cx;
          mv = v - K.cy;
        } else {  // not written
          CHECK((a.g.pu[l] == 7.0f && a.g.pz[l] == 7.0f && a.g.val[l] == 7.0f && a.g.jac[5][l] == 7.0f));
        }
        int e = 0;
        for (int p = 0; p < 6; ++p)
          for (int q = 0; q <= p; ++q, ++e) sums.motion[e][l] += wu[p] * wu[q] + wv[p] * wv[q];
        for (int p = 0; p < 6; ++p) {
          const float radial = wu[p] * mu + wv[p] * mv;
          const float modes[6] = {wu[p], wv[p], wv[p] * mu - wu[p] * mv, radial, radial * mu, radial * mv};
          for (int m = 0; m < 6; ++m) sums.floor[p][m][l] += modes[m];
        }
      }
      // The sums: within 1e-5 of each lane's size where dW may differ by an ulp.
      auto same_lanes = [&](const float* got, const float* want, std::size_t n) {
        bool all = true;
        for (std::size_t k = 0; k < n; ++k) all = all && same(got[k], want[k], 10.0f * (1.0f + std::abs(want[k])));
        return all;
      };
      CHECK(same_lanes(&a.sums.motion[0][0], &sums.motion[0][0], sizeof sums.motion / sizeof(float)));
      CHECK(same_lanes(&a.sums.floor[0][0][0], &sums.floor[0][0][0], sizeof sums.floor / sizeof(float)));
#if defined(TERRALIGN_ICLK_AVX2) || defined(TERRALIGN_ICLK_NEON)
      if (vector_kernels().jacobians) {
        Out b(C);
        vector_kernels().jacobians(in, xs, ys, count, b.g, &b.sums);
        CHECK(std::memcmp(a.buf.data(), b.buf.data(), a.buf.size() * sizeof(float)) == 0);
        CHECK(std::memcmp(&a.sums, &b.sums, sizeof a.sums) == 0);
        Out c(C);  // without the sums (the coarser levels)
        vector_kernels().jacobians(in, xs, ys, count, c.g, nullptr);
        CHECK(std::memcmp(a.buf.data(), c.buf.data(), a.buf.size() * sizeof(float)) == 0);
      }
#endif
    }
  }
}

TEST_CASE("align_to aligns the last live image to another reference as align() would, allocating nothing") {
  // What a map of several layers does (cli::Localizer): the live pyramid is built once, by the
  // first layer's alignment (here 2012's reference); a refinement pass on one level against it
  // (which must leave the coarser live levels alone), then 2016's reference aligned to it.
  auto map = geo::load_map(test::source_path("data/naip_west/map.json"));
  REQUIRE(map.ok());
  const geo::CameraModel cam = test::paper_camera();
  const Pair p = offset_pair(map.value(), "2016", "2016");
  const Pair other = offset_pair(map.value(), "2012", "2016");
  REQUIRE(std::memcmp(p.live_grey.data(), other.live_grey.data(), sizeof(float) * p.live_grey.size()) == 0);
  TrackerOptions opt;
  opt.threads = 2;
  const Pinhole<float> K{float(p.K.fx), float(p.K.fy), float(p.K.cx), float(p.K.cy)};
  Tracker<float, SE3DepthWarp<float>, 1> fresh(cam.width, cam.height, opt), kept(cam.width, cam.height, opt);
  const auto a = fresh.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), K, SE3<float>::identity());
  REQUIRE(a.converged);  // a comparison of answers, not of two failures
  kept.align(other.ref_grey.view(), other.depth.view(), other.live_grey.view(), K, SE3<float>::identity());
  kept.set_options(refinement_options(opt, 1));
  kept.align_to(other.ref_grey.view(), other.depth.view(), K, SE3<float>::identity());
  kept.set_options(opt);
  long allocations = 0;
  TrackResult<SE3DepthWarp<float>> b;
  {
    test::AllocationCounter count;
    b = kept.align_to(p.ref_grey.view(), p.depth.view(), K, SE3<float>::identity());
    allocations = count.allocations();
  }
  CHECK(allocations == 0);
  CHECK(b.converged);
  test::check_same_answer(a, b);
}

TEST_CASE("an alignment allocates nothing after set-up") {
  auto map = geo::load_map(test::source_path("data/naip_west/map.json"));
  REQUIRE(map.ok());
  const geo::CameraModel cam = test::paper_camera();
  const Pair p = render_pair(map.value(), cam, geo::pose_from_ypr({487450, 5207437, 1370}, 0, 0, 0),
                             geo::pose_from_ypr({487455, 5207437, 1370}, 0.5, 0, 0), "2009", "2009");
  TrackerOptions opt;
  opt.robust = Robust::Huber;
  opt.threads = 2;
  Tracker<float, SE3DepthWarp<float>, 1> tracker(cam.width, cam.height, opt);
  const Pinhole<float> K{float(p.K.fx), float(p.K.fy), float(p.K.cx), float(p.K.cy)};
  (void)tracker.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), K, SE3<float>::identity());
  test::AllocationCounter count;
  const auto& res = tracker.align(p.ref_grey.view(), p.depth.view(), p.live_grey.view(), K, SE3<float>::identity());
  CHECK(count.allocations() == 0);
  CHECK(res.converged);
}
