// The re-rendered refinement (cli::Localizer::set_refinement): after a converged alignment the
// reference is rendered again at the answer and the image aligned again from it. A nadir view
// barely tells a small tilt from a shift, and an alignment keeps a part of its reference's
// tilt error as a shift; a reference rendered at the answer takes it out. Also the
// registration floor that grows with the final residual (session 29, as refinement's bound).
#include <cmath>
#include <cstring>
#include <memory>
#include <string>

#include <doctest/doctest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include <terralign/geo/map.hpp>
#include <terralign/nn/weights.hpp>
#include <terralign/raster/renderer.hpp>

#include "alloc_counter.hpp"
#include "localizer.hpp"
#include "nadir_scene.hpp"
#include "support.hpp"

using namespace terralign;

namespace {

using test::kDeg;
using test::Scene;
using test::scene;

// The answer's position error (m) and its refinement passes, with `passes` passes allowed.
struct Answer {
  double error_m;
  int refinements;
  geo::Pose pose;
};
Answer localize(cli::Localizer& loc, const Scene& s, int passes) {
  loc.set_refinement(passes);
  auto out = loc.localize(s.live.view(), s.prior);
  REQUIRE(out.ok());
  REQUIRE(out->converged);
  return {(out->T_W_C.t_W_C - s.truth.t_W_C).norm(), out->refinements, out->T_W_C};
}

// A learned localizer on the scene's 2016 map with the default weights and passes.
std::unique_ptr<cli::Localizer> learned_localizer(const Scene& s, const nn::WeightFile& weights) {
  auto loc = cli::Localizer::create(s.map, s.cam, "2016", iclk::TrackerOptions{}, 2, &weights);
  REQUIRE(loc.ok());
  loc.value()->set_refinement(cli::kDefaultRefinePasses);
  return std::move(loc.value());
}

}  // namespace

TEST_CASE("refinement: a reference rendered at the answer takes out the tilt the first pass traded for a shift") {
  const Scene s = scene();
  auto weights = nn::read_weights(TERRALIGN_DEFAULT_WEIGHTS);
  REQUIRE(weights.ok());
  iclk::TrackerOptions opt;
  for (const bool learned : {true, false}) {
    CAPTURE(learned);
    auto loc = cli::Localizer::create(s.map, s.cam, "2016", opt, 2, learned ? &weights.value() : nullptr);
    REQUIRE(loc.ok());
    const Answer once = localize(*loc.value(), s, 0);
    const Answer refined = localize(*loc.value(), s, cli::kDefaultRefinePasses);
    MESSAGE((learned ? "learned" : "classic") << ": " << once.error_m << " m without refinement, " << refined.error_m
                                              << " m after " << refined.refinements << " passes");
    CHECK(once.refinements == 0);
    CHECK(refined.refinements >= 1);
    // Same-year renders: over 200 eval poses the learned tracker's median 3-D EPE went from
    // 0.16 to 0.016 m, the classical one's from 0.07 to 0.002 m (docs/history.md, session 29). Here the first
    // answers are 0.24 and 0.16 m off and the refined ones 4 and 1 mm (measured); a third of
    // the first error must go, and what is left must be under 0.1 m (the sample map's texel is 5 m).
    CHECK(refined.error_m < once.error_m / 3);
    CHECK(refined.error_m < 0.1);
    // An answer already at its reference is not refined: started at the refined answer, the
    // first pass turns it by less than the 0.05 degree that asks for another.
    Scene at = s;
    at.prior = refined.pose;
    CHECK(localize(*loc.value(), at, cli::kDefaultRefinePasses).refinements == 0);
  }
}

TEST_CASE("refinement: asked to, the learned tracker weighs every pixel alike where the image agrees with the map") {
  // Same-year answers end at a residual of 0.01-0.08, a year apart at 0.86 or more (400 eval
  // poses); with set_uniform_refinement(cli::kRefineUniformMaxResidual) (--refine-uniform 0.5)
  // a pass from an answer at 0.5 or less runs without the M-estimator, and is as precise: the
  // same-year answer must still end under 0.1 m, as in the first case. Across a year every
  // pass keeps the M-estimator. By default (since session 38) every pass keeps it.
  const Scene s = scene();
  auto weights = nn::read_weights(TERRALIGN_DEFAULT_WEIGHTS);
  REQUIRE(weights.ok());
  auto loc = learned_localizer(s, weights.value());
  {
    auto by_default = loc->localize(s.live.view(), s.prior);
    REQUIRE(by_default.ok());
    CHECK(by_default->refinements >= 1);
    CHECK(by_default->uniform_refinements == 0);
  }
  loc->set_uniform_refinement(cli::kRefineUniformMaxResidual);
  // Across a year: 2017's render, 7 parts to 3 of 2016's, ends between the bounds (0.72,
  // measured; 2017 alone ends at 1.3, where no pass runs at all, half and half at 0.35).
  ImageU8 blend = s.live_2017;
  for (std::size_t i = 0; i < static_cast<std::size_t>(3 * blend.width() * blend.height()); ++i)
    blend.data()[i] = static_cast<std::uint8_t>((7 * s.live_2017.data()[i] + 3 * s.live.data()[i] + 5) / 10);
  for (const bool same_year : {true, false}) {
    CAPTURE(same_year);
    auto out = loc->localize((same_year ? s.live : blend).view(), s.prior);
    REQUIRE(out.ok());
    REQUIRE(out->converged);
    const double error_m = (out->T_W_C.t_W_C - s.truth.t_W_C).norm();
    MESSAGE((same_year ? "2016" : "2017 blend") << ": " << out->refinements << " passes, " << out->uniform_refinements
                                                << " without the M-estimator, residual " << out->residual_final << ", "
                                                << error_m << " m");
    CHECK(out->refinements >= 1);
    if (same_year) {
      CHECK(out->uniform_refinements == out->refinements);
      CHECK(error_m < 0.1);
    } else {
      CHECK(out->residual_final > cli::kRefineUniformMaxResidual);
      CHECK(out->uniform_refinements == 0);
    }
  }
  // The classical tracker has no M-estimator to leave out.
  auto classic = cli::Localizer::create(s.map, s.cam, "2016", iclk::TrackerOptions{}, 2, nullptr);
  REQUIRE(classic.ok());
  classic.value()->set_refinement(cli::kDefaultRefinePasses);
  auto out = classic.value()->localize(s.live.view(), s.prior);
  REQUIRE(out.ok());
  CHECK(out->refinements >= 1);
  CHECK(out->uniform_refinements == 0);
}

TEST_CASE("refinement: without an attitude reference the tilt prior holds the prior's tilt in every pass") {
  // The prior is 1 degree of pitch off. A tilt prior of 0.02 degree, about what the image pins
  // a same-year tilt to, leaves a share of that degree in the first answer. A refinement pass
  // renders its reference at that answer. Holding the answer to the reference's tilt (as
  // before session 33) anchored the prior there and the passes walked the answer to the
  // image's tilt: 0.67 -> 0.07 degree (learned), 0.48 -> 0.001 (classic). Held to the prior's
  // tilt the passes still move it (each pass weighs the prior by the image noise measured at
  // its start, which a reference rendered near the answer makes smaller) but keep a part:
  // 0.67 -> 0.37 and 0.48 -> 0.13 degree (measured). A fifth separates the two. Measured with
  // weights/deep_iclk_s16.tlw, which the test keeps: session 38's wider default pins the tilt
  // harder from the image (0.59 -> 0.10 degree), too close to a fifth to tell the two apart.
  // The passes run on the finest level, as both trackers' did when this was measured: the
  // learned tracker's default three levels (session 58) pin the tilt from the image alone
  // (0.64 -> 0.008 degree, measured), as the prior weighs by each level's image noise and a
  // coarse level rendered at a same-year answer has next to none; the anchoring this case
  // guards is the same on any number of levels.
  const Scene s = scene();
  auto weights = nn::read_weights(test::source_path("weights/deep_iclk_s16.tlw"));
  REQUIRE(weights.ok());
  iclk::TrackerOptions opt;
  opt.tilt_prior_rad = 0.02 * kDeg;
  for (const bool learned : {true, false}) {
    CAPTURE(learned);
    auto loc = cli::Localizer::create(s.map, s.cam, "2016", opt, 2, learned ? &weights.value() : nullptr);
    REQUIRE(loc.ok());
    loc.value()->set_refinement_scope(cli::kRefineLevels, learned ? cli::kDeepRefineMaxResidual : cli::kRefineMaxResidual);
    auto angle_deg = [&](const Answer& a) {
      return Eigen::AngleAxisd(a.pose.q_W_C.conjugate() * s.truth.q_W_C).angle() / kDeg;
    };
    const Answer once = localize(*loc.value(), s, 0);
    const Answer refined = localize(*loc.value(), s, cli::kDefaultRefinePasses);
    MESSAGE((learned ? "learned" : "classic") << ": " << angle_deg(once) << " deg without refinement, "
                                              << angle_deg(refined) << " deg after " << refined.refinements << " passes");
    CHECK(refined.refinements >= 1);
    CHECK(angle_deg(once) > 0.1);
    CHECK(angle_deg(once) < 0.9);
    CHECK(angle_deg(refined) > 0.2 * angle_deg(once));
  }
}

TEST_CASE("refinement: same bytes on 1 and 2 threads, no heap allocation, and a flat grey image still fails") {
  const Scene s = scene();
  auto weights = nn::read_weights(TERRALIGN_DEFAULT_WEIGHTS);
  REQUIRE(weights.ok());
  iclk::TrackerOptions opt;
  auto one = cli::Localizer::create(s.map, s.cam, "2016", opt, 1, &weights.value());
  auto two = cli::Localizer::create(s.map, s.cam, "2016", opt, 2, &weights.value());
  REQUIRE(one.ok());
  REQUIRE(two.ok());
  one.value()->set_refinement(cli::kDefaultRefinePasses);
  two.value()->set_refinement(cli::kDefaultRefinePasses);
  auto a = one.value()->localize(s.live.view(), s.prior);
  auto warm = two.value()->localize(s.live.view(), s.prior);  // the first call may size lazily
  REQUIRE(a.ok());
  REQUIRE(warm.ok());
  long allocations = 0;
  geo::Pose b;
  int passes = 0;
  {
    test::AllocationCounter count;
    auto out = two.value()->localize(s.live.view(), s.prior);
    allocations = count.allocations();
    REQUIRE(out.ok());
    b = out->T_W_C;
    passes = out->refinements;
  }
  CHECK(allocations == 0);
  CHECK(passes >= 1);
  CHECK(a->refinements == passes);
  CHECK(std::memcmp(a->T_W_C.t_W_C.data(), b.t_W_C.data(), sizeof(double) * 3) == 0);
  CHECK(std::memcmp(a->T_W_C.q_W_C.coeffs().data(), b.q_W_C.coeffs().data(), sizeof(double) * 4) == 0);
  // Failure as data: an image of flat grey does not converge, refinement or not, and the
  // answer is the prior.
  ImageU8 grey(s.cam.width, s.cam.height, 3, 128);
  auto g = two.value()->localize(grey.view(), s.prior);
  REQUIRE(g.ok());
  CHECK_FALSE(g->converged);
  CHECK(g->refinements == 0);
  CHECK((g->T_W_C.t_W_C - s.prior.t_W_C).norm() == 0);
}

TEST_CASE("the registration floor grows with the final residual: a map of another year widens the covariance many times, its own does not") {
  const Scene s = scene();
  auto weights = nn::read_weights(TERRALIGN_DEFAULT_WEIGHTS);
  REQUIRE(weights.ok());
  for (const bool same_year : {true, false}) {
    CAPTURE(same_year);
    const ImageU8& live = same_year ? s.live : s.live_2017;
    double residual = 0, variance[2] = {0, 0};
    for (int k = 0; k < 2; ++k) {  // the fixed floor alone; 1 px per unit of residual (the default)
      iclk::TrackerOptions opt;
      opt.registration_floor_per_residual_px = k == 0 ? 0.0 : 1.0;
      auto loc = cli::Localizer::create(s.map, s.cam, "2016", opt, 2, &weights.value());
      REQUIRE(loc.ok());
      auto out = loc.value()->localize(live.view(), s.prior);
      REQUIRE(out.ok());
      REQUIRE(out->converged);
      residual = out->residual_final;
      variance[k] = out->covariance.bottomRightCorner<2, 2>().trace();  // east and north
    }
    MESSAGE((same_year ? "2016" : "2017") << ": residual " << residual << ", horizontal position variance "
                                          << variance[0] << " -> " << variance[1] << " m^2");
    if (same_year) {
      // Same-year answers end at a residual of 0.01-0.08 (200 eval poses), under the fixed
      // 0.1 px floor and under the 0.3 past which the keystones grow: nothing changes, to the bit.
      CHECK(residual < 0.1);
      CHECK(variance[1] == variance[0]);
    } else {
      // A year apart they end at 0.8-1.5: a floor of 8-15x the fixed one, whose shifts move
      // the camera sideways and whose keystones (1.0 px here, about a degree of tilt) move it
      // by 800 m x the tilt. The image noise's term alone is 21.7 m^2 here, with the floor
      // 271 (session 40; 40.6 with the whole-image motions alone, session 29): the floor must
      // add at least four times it.
      CHECK(residual > 0.5);
      CHECK(variance[1] > 5 * variance[0]);
    }
  }
}

TEST_CASE("the map's own error: a layer's registration sigma widens the answer's covariance as a whole-image motion, the DEM's its height, and the answer stays") {
  Scene s = scene();
  iclk::TrackerOptions opt;
  auto plain = cli::Localizer::create(s.map, s.cam, "2016", opt, 2);
  REQUIRE(plain.ok());
  auto a = plain.value()->localize(s.live.view(), s.prior);
  REQUIRE(a.ok());
  REQUIRE(a->converged);

  s.map.find_layer("2016")->registration_sigma_m = 2.0;
  s.map.dem.vertical_sigma_m = 3.0;
  auto stated = cli::Localizer::create(s.map, s.cam, "2016", opt, 2);
  REQUIRE(stated.ok());
  auto b = stated.value()->localize(s.live.view(), s.prior);
  REQUIRE(b.ok());
  REQUIRE(b->converged);
  // The answer is the image's alone; only its covariance counts the map's error.
  CHECK(b->T_W_C.t_W_C == a->T_W_C.t_W_C);
  CHECK(b->T_W_C.q_W_C.coeffs() == a->T_W_C.q_W_C.coeffs());
  const Eigen::Matrix<double, 6, 6> d = b->covariance - a->covariance;
  MESSAGE("horizontal position variance " << a->covariance(3, 3) + a->covariance(4, 4) << " -> "
                                          << b->covariance(3, 3) + b->covariance(4, 4) << " m^2, height "
                                          << a->covariance(5, 5) << " -> " << b->covariance(5, 5));
  // A whole-image shift of 2 m on the ground moves a nadir camera's centre by 2 m along each
  // horizontal axis: 4 m^2 each (measured 8.0 in all). The tilt prior (3 degrees, 42 m at 800
  // m) could let a part of it go to a tilt, so at least half; no more than the whole. The scale
  // mode, 2 m RMS at the view's edges, changes the height by about 2 m x 800 m / the view's RMS
  // radius (about 330 m): 23 m^2 (measured 25.6) on top of the DEM's 9.
  CHECK(d(3, 3) > 0.5 * 4.0);
  CHECK(d(4, 4) > 0.5 * 4.0);
  CHECK(d(3, 3) < 4.0 * 1.01);
  CHECK(d(4, 4) < 4.0 * 1.01);
  CHECK(d(5, 5) > 9.0 + 0.5 * 23);
  // What the map is off by is a covariance too: symmetric, positive semi-definite.
  CHECK((d - d.transpose()).cwiseAbs().maxCoeff() < 1e-9 * d.cwiseAbs().maxCoeff());
  CHECK(Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>>(0.5 * (d + d.transpose())).eigenvalues().minCoeff() >
        -1e-9 * d.cwiseAbs().maxCoeff());
}

TEST_CASE("refinement: the learned tracker refines on three levels whatever its residual") {
  // Across years a first answer ends above the classical bound (2017's render on the 2016 map:
  // a residual of 1.3), where no pass ran before session 58. The learned tracker's default
  // scope (kDeepRefineLevels, no bound) refines it; `--refine-levels 1 --refine-max-residual 1`
  // (the scope before) leaves it as the first pass gave it. (Here the passes move a first
  // answer 4.5 m off to 6.0 m, measured: one pose says nothing of the gain over 2400 eval
  // poses, README "Refinement on three levels", so that is not asserted.)
  const Scene s = scene();
  auto weights = nn::read_weights(TERRALIGN_DEFAULT_WEIGHTS);
  REQUIRE(weights.ok());
  auto loc = learned_localizer(s, weights.value());
  auto by_default = loc->localize(s.live_2017.view(), s.prior);
  REQUIRE(by_default.ok());
  REQUIRE(by_default->converged);
  loc->set_refinement_scope(cli::kRefineLevels, cli::kRefineMaxResidual);
  auto before = loc->localize(s.live_2017.view(), s.prior);
  REQUIRE(before.ok());
  REQUIRE(before->converged);
  loc->set_refinement(0);
  auto once = loc->localize(s.live_2017.view(), s.prior);
  REQUIRE(once.ok());
  const double e_default = (by_default->T_W_C.t_W_C - s.truth.t_W_C).norm();
  const double e_before = (before->T_W_C.t_W_C - s.truth.t_W_C).norm();
  MESSAGE("2017 on the 2016 map: first pass residual " << once->residual_final << ", " << e_before
                                                       << " m without a pass; " << by_default->refinements
                                                       << " passes on three levels: " << e_default << " m");
  CHECK(once->residual_final > cli::kRefineMaxResidual);
  CHECK(before->refinements == 0);
  CHECK(std::memcmp(before->T_W_C.t_W_C.data(), once->T_W_C.t_W_C.data(), sizeof(double) * 3) == 0);
  CHECK(by_default->refinements >= 1);
  // The converged tests are the first pass's: a pass changes the answer, not its measures.
  CHECK(by_default->disagreement_px == once->disagreement_px);
}

TEST_CASE("second look: an answer that failed the agreement test alone is confirmed from a reference rendered at it, or stays unconfirmed") {
  // Localizer::set_second_look. Where the first pass's answer fails the agreement test alone,
  // the reference is rendered at that answer and the first refinement pass aligns from it with
  // the same test. The scene's 2017 image against the 2016 map, across a year. First with a
  // threshold no second start meets (1e-6 px): both looks fail, the frame is a failure as
  // before (the prior, not converged) and its unconfirmed answer is the first pass's, bit for
  // bit; the second look's own disagreement is measured. Then with the threshold between the
  // two looks' disagreements: the second look confirms what the first could not, unless its
  // own threshold is below its disagreement.
  const Scene s = scene();
  auto weights = nn::read_weights(TERRALIGN_DEFAULT_WEIGHTS);
  REQUIRE(weights.ok());
  auto make = [&](double threshold_px, bool second_look, double second_threshold_px = cli::kSecondLookAnyDisagreement) {
    iclk::TrackerOptions opt;
    opt.max_disagreement_px = threshold_px;
    auto loc = cli::Localizer::create(s.map, s.cam, "2016", opt, 2, &weights.value());
    REQUIRE(loc.ok());
    loc.value()->set_refinement(cli::kDefaultRefinePasses);
    loc.value()->set_second_look(second_look, second_threshold_px);
    return std::move(loc.value());
  };
  auto run = [&](double threshold_px, bool second_look, double second_threshold_px = cli::kSecondLookAnyDisagreement) {
    auto out = make(threshold_px, second_look, second_threshold_px)->localize(s.live_2017.view(), s.prior);
    REQUIRE(out.ok());
    return out.value();
  };
  const cli::LocalizeOutput without = run(1e-6, false), strict = run(1e-6, true);
  for (const cli::LocalizeOutput* o : {&without, &strict}) {
    CHECK_FALSE(o->converged);
    CHECK(o->unconfirmed);
    CHECK_FALSE(o->second_look);
    CHECK(o->refinements == 0);
    CHECK((o->T_W_C.t_W_C - s.prior.t_W_C).norm() == 0);
  }
  CHECK(std::isnan(without.second_look_disagreement_px));
  CHECK(std::string(strict.reason) == without.reason);
  CHECK(strict.disagreement_px == without.disagreement_px);
  CHECK(std::memcmp(strict.T_W_C_unconfirmed.t_W_C.data(), without.T_W_C_unconfirmed.t_W_C.data(), sizeof(double) * 3) == 0);
  const double first = strict.disagreement_px, second = strict.second_look_disagreement_px;
  MESSAGE("disagreement: first look " << first << " px, second look " << second << " px; unconfirmed answer "
                                      << (strict.T_W_C_unconfirmed.t_W_C - s.truth.t_W_C).norm() << " m off");
  REQUIRE(std::isfinite(first));
  REQUIRE(std::isfinite(second));
  REQUIRE(second < first);
  const double between = std::sqrt(first * second);
  const cli::LocalizeOutput looked = run(between, true), once = run(between, false);
  CHECK_FALSE(once.converged);
  CHECK(once.unconfirmed);
  REQUIRE(looked.converged);
  CHECK(looked.second_look);
  CHECK_FALSE(looked.unconfirmed);
  CHECK(looked.second_look_disagreement_px == second);
  CHECK(looked.refinements >= 1);
  CHECK(std::string(looked.reason).find("second look") != std::string::npos);
  const double error_m = (looked.T_W_C.t_W_C - s.truth.t_W_C).norm();
  const double moved_m = (looked.T_W_C.t_W_C - strict.T_W_C_unconfirmed.t_W_C).norm();
  MESSAGE("confirmed at a second look: " << error_m << " m off after " << looked.refinements << " passes, "
                                         << moved_m << " m from the unconfirmed answer");
  // Measured 6.0 m off (the first answer 4.5 m; across a year the maps disagree by up to 3.5 m
  // and a nadir view trades a tilt for a shift, so the position alone moves either way) and
  // 2.8 m from the first answer: a second look confirms the basin the first pass found, it
  // does not search. Bounds: nearer than the prior (12 m) and within 5 m of the first answer.
  CHECK(error_m < (s.prior.t_W_C - s.truth.t_W_C).norm());
  CHECK(moved_m < 5.0);
  // The second look's own, tighter threshold (--second-look-max-disagreement): below its
  // measured disagreement it fails as if its pass had, and the first pass's failure stands bit
  // for bit; at it, it confirms as before.
  const cli::LocalizeOutput tight = run(between, true, 0.5 * second), at = run(between, true, second);
  CHECK_FALSE(tight.converged);
  CHECK(tight.unconfirmed);
  CHECK_FALSE(tight.second_look);
  CHECK(tight.second_look_disagreement_px == second);
  CHECK(std::string(tight.reason) == once.reason);
  CHECK((tight.T_W_C.t_W_C - s.prior.t_W_C).norm() == 0);
  CHECK(std::memcmp(tight.T_W_C_unconfirmed.t_W_C.data(), once.T_W_C_unconfirmed.t_W_C.data(), sizeof(double) * 3) == 0);
  CHECK(at.second_look);
  CHECK(std::memcmp(at.T_W_C.t_W_C.data(), looked.T_W_C.t_W_C.data(), sizeof(double) * 3) == 0);
  // No heap allocation a frame, the second look's render and pass included.
  {
    auto loc = make(between, true);
    REQUIRE(loc->localize(s.live_2017.view(), s.prior).ok());  // the first call may size lazily
    long allocations = 0;
    bool confirmed = false;
    {
      test::AllocationCounter count;
      auto again = loc->localize(s.live_2017.view(), s.prior);
      allocations = count.allocations();
      REQUIRE(again.ok());
      confirmed = again->second_look;
    }
    CHECK(confirmed);
    CHECK(allocations == 0);
  }
  // The classical tracker has no second look.
  iclk::TrackerOptions opt;
  opt.max_disagreement_px = 1e-6;
  auto classic = cli::Localizer::create(s.map, s.cam, "2016", opt, 2, nullptr);
  REQUIRE(classic.ok());
  classic.value()->set_refinement(cli::kDefaultRefinePasses);
  classic.value()->set_second_look(true);
  auto c = classic.value()->localize(s.live_2017.view(), s.prior);
  REQUIRE(c.ok());
  CHECK_FALSE(c->converged);
  CHECK(std::isnan(c->second_look_disagreement_px));
}
