// The tracking filter (cli::TrackFilter, `terralign track --filter kalman`): its prediction
// against extrapolating the last two answers, its covariance's honesty where the motion is
// the model's, the gate and the new start after refused answers, coasting, bad input; and
// when a track starts and starts again (cli::TrackStart).
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include <doctest/doctest.h>

#include <Eigen/Cholesky>
#include <Eigen/Geometry>

#include "track_filter.hpp"

using namespace terralign;
using cli::TrackFilter;
using cli::TrackFilterOptions;
using cli::TrackStart;

namespace {

constexpr double kDeg = 3.14159265358979323846 / 180;

// A normal deviate from a fixed 64-bit LCG and Box-Muller: the same numbers on every platform
// (std::normal_distribution's are the library's choice).
struct Normal {
  std::uint64_t s;
  double uniform() {
    s = s * 6364136223846793005ULL + 1442695040888963407ULL;
    return (static_cast<double>(s >> 11) + 0.5) / 9007199254740992.0;
  }
  double operator()() {
    const double u = uniform(), v = uniform();
    return std::sqrt(-2 * std::log(u)) * std::cos(2 * 3.14159265358979323846 * v);
  }
  Eigen::Vector3d vec(double sigma) { return {sigma * (*this)(), sigma * (*this)(), sigma * (*this)()}; }
};

geo::Pose pose_at(const Eigen::Vector3d& p, const Eigen::Quaterniond& q) {
  geo::Pose T;
  T.t_W_C = p;
  T.q_W_C = q;
  return T;
}

Eigen::Quaterniond exp_so3(const Eigen::Vector3d& w) {
  return w.norm() > 0 ? Eigen::Quaterniond(Eigen::AngleAxisd(w.norm(), w.normalized())) : Eigen::Quaterniond::Identity();
}

// A measured pose about `truth`: rotation and position errors with the given sigmas.
geo::Pose measure(const geo::Pose& truth, double rot_sigma, double pos_sigma, Normal& n) {
  return pose_at(truth.t_W_C + n.vec(pos_sigma), (exp_so3(n.vec(rot_sigma)) * truth.q_W_C).normalized());
}

TrackFilter::Mat6 covariance_of(double rot_sigma, double pos_sigma) {
  TrackFilter::Mat6 R = TrackFilter::Mat6::Zero();
  R.diagonal() << rot_sigma * rot_sigma, rot_sigma * rot_sigma, rot_sigma * rot_sigma, pos_sigma * pos_sigma,
      pos_sigma * pos_sigma, pos_sigma * pos_sigma;
  return R;
}

// The 6-D error of `estimate` against `truth`, [dtheta (world); dp], as track's NEES.
Eigen::Matrix<double, 6, 1> error_of(const geo::Pose& truth, const geo::Pose& estimate) {
  const Eigen::AngleAxisd dr(truth.q_W_C * estimate.q_W_C.conjugate());
  Eigen::Matrix<double, 6, 1> e;
  e << dr.angle() * dr.axis(), truth.t_W_C - estimate.t_W_C;
  return e;
}

}  // namespace

TEST_CASE("the tracking filter predicts a straight flight no worse than extrapolating two answers, and much better when they are poor") {
  // 25 m/s east at 1 Hz, 200 frames; the answers' position noise as the learned tracker's on a
  // same-year map (0.15 m) and across years (10 m), white here. Straight lines are what the
  // simulation (and the constant-velocity model) favours; the README's flights measure the
  // real case, where the errors are not white.
  const Eigen::Quaterniond q0(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()));
  for (const double sigma : {0.15, 10.0}) {
    CAPTURE(sigma);
    Normal n{42};
    auto truth = [&](int k) { return pose_at(Eigen::Vector3d(25.0 * k, 0, 800), q0); };
    TrackFilter f(truth(0), 0.0, nullptr, TrackFilterOptions{});
    std::vector<geo::Pose> answers;
    double se_filter = 0, se_extrap = 0;
    int count = 0;
    for (int k = 0; k < 200; ++k) {
      f.predict(k);
      if (k >= 10) {
        const Eigen::Vector3d ex = 2 * answers[static_cast<std::size_t>(k - 1)].t_W_C - answers[static_cast<std::size_t>(k - 2)].t_W_C;
        se_filter += (f.pose().t_W_C - truth(k).t_W_C).squaredNorm();
        se_extrap += (ex - truth(k).t_W_C).squaredNorm();
        ++count;
      }
      answers.push_back(measure(truth(k), 0.01 * kDeg, sigma, n));
      REQUIRE(f.update(answers.back(), covariance_of(0.01 * kDeg, sigma)).accepted);
    }
    const double rms_filter = std::sqrt(se_filter / count), rms_extrap = std::sqrt(se_extrap / count);
    CAPTURE(rms_filter);
    CAPTURE(rms_extrap);
    // Extrapolation's error is sqrt(5) sigma per axis (3-D: 0.71 m and 39.6 m here); the
    // filter's, with its 1 m/s per root second of velocity noise, 0.64 m where the answers
    // are precise (its velocity noise outweighs them: about extrapolation) and 10.8 m where
    // they are poor (it averages them). The bounds leave 10-50 % for another platform's
    // rounding; they fail if the filter only extrapolated or followed the answers.
    if (sigma < 1) CHECK(rms_filter < 1.2 * rms_extrap);
    else CHECK(rms_filter < 0.5 * rms_extrap);
  }
}

TEST_CASE("the tracking filter's covariance is honest where the motion is its model's: NEES about 6") {
  // The truth flies the model: its velocity and turn rate random walks at the filter's own
  // sigmas (integrated in 20 substeps a second), measured at 1 Hz with white noise of the
  // stated covariance. The mean NEES of the pose after each update (6 degrees of freedom)
  // over 600 frames has a standard error of about sqrt(12 / 600) = 0.14 where the filter is
  // consistent; [5, 7] allows for the substeps' discretisation and the rotation's first
  // order.
  TrackFilterOptions opt;
  opt.gate = -1;  // consistent, it would still refuse one answer in a thousand
  // A turn rate that walks at the default 5 degrees/s per root second reaches 100 degrees/s
  // in 600 s, where a step's first-order rotation error model no longer holds (an aircraft
  // does not spin so); 0.5 keeps it to about 12.
  opt.angular_accel_sigma_deg = 0.5;
  Normal n{7};
  Eigen::Vector3d p(0, 0, 800), v(25, 0, 0), w(0, 0, 0);
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
  TrackFilter f(pose_at(p, q), 0.0, &v, opt);
  const double rot_sigma = 0.2 * kDeg, pos_sigma = 2.0;
  double nees = 0, d2 = 0;
  int count = 0;
  for (int k = 1; k <= 600; ++k) {
    const int sub = 20;
    const double h = 1.0 / sub;
    for (int s = 0; s < sub; ++s) {
      p += v * h;
      q = (exp_so3(w * h) * q).normalized();
      v += n.vec(opt.accel_sigma * std::sqrt(h));
      w += n.vec(opt.angular_accel_sigma_deg * kDeg * std::sqrt(h));
    }
    f.predict(k);
    const geo::Pose truth = pose_at(p, q);
    const auto u = f.update(measure(truth, rot_sigma, pos_sigma, n), covariance_of(rot_sigma, pos_sigma));
    REQUIRE(u.accepted);
    if (k > 20) {
      d2 += u.d2;
      const auto e = error_of(truth, f.pose());
      nees += e.dot(f.pose_covariance().ldlt().solve(e));
      ++count;
    }
  }
  nees /= count;
  d2 /= count;
  CAPTURE(nees);
  CAPTURE(d2);
  CHECK(nees > 5.0);
  CHECK(nees < 7.0);
  // The innovations' squared Mahalanobis distance, what the gate tests, likewise.
  CHECK(d2 > 5.0);
  CHECK(d2 < 7.0);
}

TEST_CASE("the tracking filter refuses an answer far from its prediction, and starts again at the second in a row") {
  const Eigen::Vector3d v(25, 0, 0);
  const geo::Pose start = pose_at(Eigen::Vector3d(0, 0, 800), Eigen::Quaterniond::Identity());
  TrackFilterOptions opt;
  TrackFilter f(start, 0.0, &v, opt);
  const auto R = covariance_of(0.05 * kDeg, 1.0);
  for (int k = 1; k <= 5; ++k) {
    f.predict(k);
    REQUIRE(f.update(pose_at(Eigen::Vector3d(25.0 * k, 0, 800), Eigen::Quaterniond::Identity()), R).accepted);
  }
  f.predict(6);
  const geo::Pose before = f.pose();
  // 100 m north of the prediction, far beyond both covariances (a few metres).
  const geo::Pose far = pose_at(Eigen::Vector3d(150, 100, 800), Eigen::Quaterniond::Identity());
  const auto u = f.update(far, R);
  CHECK_FALSE(u.accepted);
  CHECK_FALSE(u.reset);
  CHECK(u.d2 > opt.gate);
  CHECK(std::string(u.why).find("refused") != std::string::npos);
  CHECK((f.pose().t_W_C - before.t_W_C).norm() == 0.0);  // a refused answer changes nothing
  // A second far answer in a row: the prediction, not the answers, is what went wrong.
  f.predict(7);
  const geo::Pose far2 = pose_at(Eigen::Vector3d(175, 100, 800), Eigen::Quaterniond::Identity());
  const auto u2 = f.update(far2, R);
  CHECK(u2.accepted);
  CHECK(u2.reset);
  CHECK((f.pose().t_W_C - far2.t_W_C).norm() < 1e-9);
  CHECK(f.pose_covariance().isApprox(R));
  // With reset_after_refusals 0 the gate never gives way.
  opt.reset_after_refusals = 0;
  TrackFilter g(start, 0.0, &v, opt);
  for (int k = 1; k <= 4; ++k) {
    g.predict(k);
    CHECK_FALSE(g.update(pose_at(Eigen::Vector3d(25.0 * k, 300, 800), Eigen::Quaterniond::Identity()), R).accepted);
  }
  // A negative gate takes every answer.
  opt.gate = -1;
  TrackFilter h(start, 0.0, &v, opt);
  h.predict(1);
  CHECK(h.update(far, R).accepted);
}

TEST_CASE("the tracking filter coasts with a growing covariance, and turns bad answers away by name") {
  const geo::Pose start = pose_at(Eigen::Vector3d(10, 20, 800), Eigen::Quaterniond::Identity());
  const Eigen::Vector3d v(25, 0, 0);
  TrackFilter f(start, 100.0, &v, TrackFilterOptions{});
  double last = f.pose_covariance()(3, 3);
  for (int k = 1; k <= 5; ++k) {
    f.predict(100.0 + k);
    CHECK(f.pose_covariance()(3, 3) > last);  // east: the velocity's uncertainty grows into it
    last = f.pose_covariance()(3, 3);
    CHECK(f.pose().t_W_C.x() == doctest::Approx(10 + 25.0 * k));
  }
  f.predict(100.0);  // not later than now: nothing
  CHECK(f.time() == 105.0);
  CHECK(f.pose().t_W_C.x() == doctest::Approx(135.0));
  // Without a velocity the start's 30 m/s horizontal and 5 m/s vertical sigmas.
  TrackFilter g(start, 0.0, nullptr, TrackFilterOptions{});
  g.predict(1.0);
  CHECK(g.pose_covariance()(3, 3) > 30.0 * 30.0);
  CHECK(g.pose_covariance()(5, 5) < g.pose_covariance()(3, 3));
  // A NaN answer, a NaN covariance, a covariance that is not positive definite: refused, the
  // state as it was.
  TrackFilter::Mat6 bad = covariance_of(0.01, 1.0);
  const geo::Pose at = f.pose();
  auto u = f.update(pose_at(Eigen::Vector3d(NAN, 0, 0), Eigen::Quaterniond::Identity()), bad);
  CHECK_FALSE(u.accepted);
  CHECK(std::string(u.why).find("not finite") != std::string::npos);
  bad(3, 3) = NAN;
  CHECK_FALSE(f.update(at, bad).accepted);
  bad = -1e6 * TrackFilter::Mat6::Identity();
  u = f.update(at, bad);
  CHECK_FALSE(u.accepted);
  CHECK(std::string(u.why).find("positive semi-definite") != std::string::npos);
  CHECK((f.pose().t_W_C - at.t_W_C).norm() == 0.0);
  CHECK(f.pose().t_W_C.allFinite());
}

TEST_CASE("the tracking filter takes an altimeter's reading: the scalar update, its honesty, and bad readings refused") {
  const geo::Pose start = pose_at(Eigen::Vector3d(10, 20, 800), Eigen::Quaterniond::Identity());
  // One reading, by hand: z moves by P_zz / (P_zz + r) of the innovation, its variance becomes
  // P_zz r / (P_zz + r), and x and y stay where the start's diagonal covariance put them.
  TrackFilter f(start, 0.0, nullptr, TrackFilterOptions{});
  const double pzz = f.pose_covariance()(5, 5), r = 2.0 * 2.0;
  REQUIRE(f.update_height(810.0, 2.0));
  CHECK(f.pose().t_W_C.z() == doctest::Approx(800 + 10 * pzz / (pzz + r)).epsilon(1e-12));
  CHECK(f.pose_covariance()(5, 5) == doctest::Approx(pzz * r / (pzz + r)).epsilon(1e-12));
  CHECK(f.pose().t_W_C.head<2>() == start.t_W_C.head<2>());
  CHECK(f.updates() == 0);  // no pose answer: a start still needs two
  // A reading or sigma that is not finite, or a sigma not above 0: refused, the state as it was.
  const TrackFilter::Mat12 P = f.covariance();
  const geo::Pose at = f.pose();
  CHECK_FALSE(f.update_height(NAN, 2.0));
  CHECK_FALSE(f.update_height(800.0, NAN));
  CHECK_FALSE(f.update_height(800.0, 0.0));
  CHECK_FALSE(f.update_height(800.0, -1.0));
  CHECK_FALSE(f.update_height(INFINITY, 2.0));
  CHECK(f.covariance() == P);
  CHECK(f.pose().t_W_C == at.t_W_C);

  // Coasting with readings only. The truths start off the filter's start by its own sigmas
  // (50 m in z, a 5 m/s climb) and follow the model exactly (no process noise here, nor in the
  // filter: then its covariance is the exact posterior), the readings their z plus N(0, 2 m).
  // Over 400 flights of 20 frames the final z error's squared, normalised by the filter's
  // variance, has mean 1 (chi-square, one degree of freedom; the mean of 400 has sigma
  // sqrt(2 / 400) = 0.071): asked within [0.75, 1.25], 3.5 sigma. The climb is learnt from
  // the readings alone: its RMS error under 0.4 m/s (the posterior's sigma after 20 readings
  // a second apart at 2 m is 0.16 m/s), where the start's was 5.
  TrackFilterOptions opt;
  opt.accel_sigma = 1e-9;
  opt.angular_accel_sigma_deg = 1e-9;
  Normal n{12345};
  double nees = 0, climb2 = 0;
  const int runs = 400;
  for (int k = 0; k < runs; ++k) {
    const double z0 = 800 + opt.init_position_sigma * n(), climb = opt.init_climb_sigma * n();
    TrackFilter g(start, 0.0, nullptr, opt);
    for (int t = 1; t <= 20; ++t) {
      g.predict(t);
      REQUIRE(g.update_height(z0 + climb * t + 2.0 * n(), 2.0));
    }
    const double e = g.pose().t_W_C.z() - (z0 + climb * 20);
    nees += e * e / g.pose_covariance()(5, 5);
    climb2 += std::pow(g.velocity().z() - climb, 2);
  }
  CHECK(nees / runs > 0.75);
  CHECK(nees / runs < 1.25);
  CHECK(std::sqrt(climb2 / runs) < 0.4);
}

TEST_CASE("a track starts until two answers converge, and starts again after N frames in a row without an answer") {
  TrackStart s(3);
  CHECK(s.starting());
  CHECK_FALSE(s.again());
  // An unconfirmed answer taken to start is no converged one: still starting.
  s.frame(false, true);
  CHECK(s.starting());
  s.frame(true, true);
  CHECK(s.starting());
  s.frame(true, true);
  CHECK_FALSE(s.starting());
  CHECK(s.converged() == 2);
  // Frames without an answer (failed, refused, unreadable): two are coasted through, the third
  // in a row makes the next frame a start again, and it stays one until an answer is taken.
  s.frame(false, false);
  s.frame(false, false);
  CHECK(s.coasted() == 2);
  CHECK_FALSE(s.starting());
  s.frame(false, false);
  CHECK(s.starting());
  CHECK(s.again());
  s.frame(false, false);
  CHECK(s.again());
  CHECK(s.coasted() == 4);
  // Taken (converged, or unconfirmed as the new start): tracking again.
  s.frame(false, true);
  CHECK_FALSE(s.starting());
  CHECK(s.coasted() == 0);
  CHECK(s.converged() == 2);
  // A taken answer between failures resets the count.
  s.frame(false, false);
  s.frame(false, false);
  s.frame(true, true);
  s.frame(false, false);
  s.frame(false, false);
  CHECK_FALSE(s.starting());
  // Before two have converged, a start is the first one, not a start again, however long it
  // has gone without an answer.
  TrackStart first(3);
  for (int k = 0; k < 5; ++k) first.frame(false, false);
  CHECK(first.starting());
  CHECK_FALSE(first.again());
  // 0: never again.
  TrackStart never(0);
  never.frame(true, true);
  never.frame(true, true);
  for (int k = 0; k < 100; ++k) never.frame(false, false);
  CHECK_FALSE(never.starting());
  CHECK(never.coasted() == 100);
}
