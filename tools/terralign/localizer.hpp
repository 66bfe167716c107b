// The localisation pipeline shared by align, eval and track: render the reference at the
// prior, align the live image to it (classical: grey images; learned: DeepAligner at the
// weights' working scale), return the map pose with its covariance. Everything is sized at
// construction; localize() allocates nothing.
#pragma once

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include <terralign/geo/camera.hpp>
#include <terralign/geo/image.hpp>
#include <terralign/geo/map.hpp>
#include <terralign/geo/pose.hpp>
#include <terralign/iclk/tracker.hpp>
#include <terralign/nn/weights.hpp>
#include <terralign/raster/renderer.hpp>

#include <terralign/iclk/deep_aligner.hpp>

namespace terralign::cli {

struct LocalizeOutput {
  geo::Pose T_W_C;                      // the estimate (the prior when not converged)
  iclk::SE3<double> T_live_ref;         // the relative pose found, to the prior (identity when not converged)
  // Covariance of [dtheta; dp]: a rotation about the world axes applied on the left of
  // R_W_C (rad) and a shift of the camera centre (m, world axes), in that order.
  // The image's part, with the reference layer's registration_sigma_m in its floor
  // (iclk::TrackerOptions::ground_floor_m), and the DEM's vertical_sigma_m squared on the
  // height (a DEM too high by d puts the camera d higher).
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
  bool converged = false;
  const char* reason = "not run";  // the tracker's (a static string: no allocation per frame)
  // Where no layer converged and a layer's first pass failed the agreement test alone
  // (iclk::TrackResult::unconfirmed; the first such layer's): that answer, unconfirmed, as a
  // map pose with its covariance in LocalizeOutput::covariance's frame (the DEM's variance
  // included). terralign track may start a track with it; T_W_C stays the prior.
  bool unconfirmed = false;
  geo::Pose T_W_C_unconfirmed;
  Eigen::Matrix<double, 6, 6> covariance_unconfirmed = Eigen::Matrix<double, 6, 6>::Zero();
  // Its disagreement over the agreement test's threshold (above 1; the sigmas' factor).
  double unconfirmed_scale = 1;
  // The learned tracker's second look (Localizer::set_second_look) at the answer layer's
  // unconfirmed first answer: whether it confirmed the answer (then converged), and where it
  // ran, the disagreement its own agreement test measured (NaN where it did not run, INFINITY
  // where its second start failed).
  bool second_look = false;
  double second_look_disagreement_px = NAN;
  int iterations = 0;
  double cost_init = 0, cost_final = 0;  // mean squared residual of the normalised images
  double residual_init = 0, residual_final = 0;  // the same unweighted (iclk::TrackResult)
  double sharpness = 0;                          // iclk::TrackResult
  double disagreement_px = 0;                    // iclk::TrackResult
  double residual_correlation = 0, covariance_inflation = 1;  // see iclk::TrackResult
  // Which of the localizer's layers answered (the first whose alignment converged; where none
  // did, the last, whose failure and measures these are), and how many were tried; every
  // field of time and iterations sums them all.
  int layer = 0, layers_tried = 0;
  int refinements = 0;  // re-rendered passes after the first that converged (Localizer::set_refinement)
  int uniform_refinements = 0;  // of them, the learned tracker's without its M-estimator (set_uniform_refinement)
  double ms_render = 0, ms_pyramid = 0, ms_jacobian = 0, ms_iterations = 0;
  double ms_encoder = 0, ms_mestimator = 0;  // learned: both encoders; the M-estimator (inside ms_jacobian)
};

// One layer's alignment within a localize() call (Localizer::attempts): whether it converged,
// and where not, why (the tracker's reason and the converged tests' measures).
struct LayerAttempt {
  bool converged = false;
  const char* reason = "not run";  // a static string, as LocalizeOutput::reason
  int iterations = 0;              // this layer's, its refinement passes included
  double residual_final = 0, disagreement_px = 0, sharpness = 0;
};

// Sizes for a small target (the firmware: a 188 x 120 camera runs the network at full size
// on four levels, and the renderer needs room for few triangles); 0 keeps the default.
struct LocalizerSizes {
  double input_scale = 0;  // the learned tracker's; 0: the weights' `# input-scale`
  int levels = 0;          // the learned tracker's; 0: the weights' `# levels`
  int max_triangles = 0;   // the renderer's per-frame bound (RenderOptions::max_triangles)
};

// The classical tracker's coarse search (iclk::TrackerOptions::coarse_search_px) unless the
// options set one (negative: none), in coarsest-level pixels. On the calibration seed (11,
// 200 poses) it took same-year success within 1 px from 85 to 97.5 % and 2016 -> 2017 within
// 5 px from 24.5 to 31 % (2 px: 93.5 and 29.5 %), for about 1 ms (README). The learned
// tracker's is iclk::DeepAligner::kCoarseSearchPx.
constexpr int kClassicCoarseSearchPx = 4;

// The classical tracker's agreement test (iclk::TrackerOptions::agree_px and
// max_disagreement_px, camera pixels) unless the options set a threshold (negative: off, still
// measured): the learned tracker's start, 2 px in u and in v, and the threshold by its rule,
// the 97th percentile of the right converged answers' disagreement on 2016 -> 2017 (seed 11,
// 200 poses: 0.93 px), rounded up to 0.05. There it fails 9 of the 21 wrong converged answers
// and 1 of the 61 right ones; on Christchurch 000121, where 7 of the 185 converged answers are
// right, it fails all but one (README). Session 55 measured the rule again at 1.09 px (0.95
// keeps 67 of 71 right answers, fails 6 of 13 wrong) and a start 1 px away separating worse
// (AUC 0.778 against 0.805; README "The agreement test's start"); both constants stay.
constexpr double kClassicAgreePx = 2.0;
constexpr double kClassicMaxDisagreementPx = 0.95;

// The re-rendered refinement's defaults (Localizer::set_refinement, docs/history.md, "Session 29"): up
// to two passes (the command line's --refine), again while the last pass turned the answer by
// more than 0.05 degree from its reference (the learned tracker keeps an eighth to a fifth of
// that turn as a tilt error, 0.1 m at 800 m; 0.02 degree did no better on the tracks, 0.2 left
// the first frames of a track started from an IMU's tilt 0.6 m off).
constexpr int kDefaultRefinePasses = 2;
constexpr double kRefineMinDeg = 0.05;
// The learned tracker's second look at an answer that failed the agreement test alone
// (Localizer::set_second_look; the command line's --second-look, README "The second look",
// docs/history.md "Session 64"): 2009 -> 2020 on 200 poses, seeds 7 / 13, 67.0 / 63.5 -> 76.0
// / 76.5 % within 5 px (a failed answer at its prior), with 2 / 2 -> 5 / 4 wrong answers
// passed. Off by default: the rule written for it before the README's flights were tracked
// asked no row more than 1 m worse, and the lawnmower across 11 years with an IMU went 18.55
// -> 23.97 m RMSE, the wrong near misses it passes coming in runs on hard ground.
constexpr bool kDefaultSecondLook = false;
// The second look's own agreement threshold (Localizer::set_second_look's max_disagreement_px;
// --second-look-max-disagreement): its pass must also come within this of its second start.
// Infinity (the default) leaves the first pass's threshold alone. Session 65: 0.9 px, chosen
// on seed 7 as the largest that kept each cell's share of right converged answers within a
// point, passes fewer near misses (the strip 2012 -> 2020 seed 7: +45 right and 2 wrong
// answers where the first pass's threshold gives +59 and 14), but on the fresh seed 31 the
// strip's share still fell 96.1 -> 92.9 % (README "The second look").
constexpr double kSecondLookAnyDisagreement = INFINITY;
constexpr double kDefaultSecondLookMaxDisagreement = kSecondLookAnyDisagreement;
// The classical tracker's passes (Localizer::set_refinement_scope): the finest level alone (one,
// two or three levels gave the same answers on 200 same-year poses), and only where the image
// agrees with the map, a final residual (LocalizeOutput::residual_final, normalised images:
// about 2 (1 - NCC)) of at most 1.0, a correlation of 0.5 or more: same-year answers end at
// 0.01-0.08, 2016 -> 2017's at 0.8-1.5 and 2009 -> 2020's at 1.0-2.1.
constexpr int kRefineLevels = 1;
constexpr double kRefineMaxResidual = 1.0;
// The learned tracker's passes (session 58): its finest three levels, after every converged
// answer. Across many years a pass on the finest level alone moves the learned minimum with
// its reference instead of settling (every answer refined so: 2009 -> 2020 cost 1-4 points
// within 5 px, session 29; hence the residual bound above, under which no answer of 2009 ->
// 2020 was refined). Three levels from a reference rendered at the answer move it back to the
// ground instead: the six NAIP pairs with a 2017 or 2020 image, seeds 7 and 13, every answer
// counted, 1075.5 -> 1093.5 points within 5 px (2009 -> 2020 82.5 / 84.5 -> 88.0 / 87.5 %);
// with the agreement test (the first pass's, as before) 985.5 -> 993.5 points, and 60 -> 44
// wrong answers passed. Two levels lost points (1057.0 every answer counted), four and five
// gained as three on seed 11 (87.0 and 86.5 % of 2009 -> 2020 against three's 87.0 and the
// bound's 84.5). One pass of three levels gains 14 points, two 18 (README, "Refinement on three
// levels").
constexpr int kDeepRefineLevels = 3;
constexpr double kDeepRefineMaxResidual = INFINITY;
// Localizer::set_uniform_refinement's bound, opt-in since session 38 (the command line's
// --refine-uniform 0.5; off by default): the learned tracker's refinement pass weighs every
// pixel alike, without the M-estimator, where the answer it refines ended at a residual of at
// most 0.5: same-year answers end at
// 0.01-0.08 (0.05-0.27 for 199 of 200 poses with README's poor camera, noise 10 and blur 2),
// 2016 -> 2017's at 0.86 or more. Where image and map agree the finest level's M-estimator,
// about 5 of a pass's 14 ms, has little to weigh out (session 37, same year, seeds 7 / 13,
// median 3-D EPE with it -> without: clean 0.016 / 0.017 -> 0.015 / 0.017 m, the flights'
// camera 0.033 / 0.035 -> 0.035 / 0.036, the poor camera 0.095 / 0.098 -> 0.101 / 0.103;
// the same-year lawnmower with an IMU 0.21 -> 0.15 m RMSE, NEES 5.5 -> 3.6). Above the bound
// it still weighs out what changed between the years: those answers are as before. Real
// frames end below the bound too (the Baviaanskloof frames at 0.06 against their own flight's
// ortho, 0.38-0.56 against Sentinel-2) and wherever a pass ran without it the M-estimator's
// answers lie 0.6-1.6 m nearer the aero-triangulated pose (session 38, README "Real frames"):
// what a real camera and a 24 m DEM disagree on, a render does not show. Hence off by default.
constexpr double kRefineUniformMaxResidual = 0.5;
constexpr double kRefineUniformOff = -1.0;  // no residual is below it: every pass keeps the M-estimator

class Localizer {
 public:
  // `camera` must be a pinhole (undistort the live image first); `layer` is the reference.
  // With `weights` the learned tracker aligns (its size must halve exactly three times at
  // the weights' input scale), else the classical one. The answers' covariance counts what
  // the manifest says of the map's own error: the layer's registration_sigma_m and the DEM's
  // vertical_sigma_m (geo/map.hpp).
  static Result<std::unique_ptr<Localizer>> create(const geo::Map& map, const geo::CameraModel& camera,
                                                   const std::string& layer, const iclk::TrackerOptions& options,
                                                   int threads, const nn::WeightFile* weights = nullptr,
                                                   const LocalizerSizes& sizes = {});
  // Several layers of the map, in order of preference (the newest first, say): localize()
  // aligns to the first, and to the next only where the alignment before did not converge;
  // the first converged answer is the answer. A map of several years thus answers where its
  // newest year has changed too much, at the cost of an alignment more only there (NAIP's
  // 2020 images against 2016, then 2012, then 2009, seed 7: 86.5 -> 90.0 % within 5 px,
  // 97.7 -> 96.8 % of the converged answers right, 1.2 alignments an image; the README's
  // "A map of several years"). Each layer's covariance counts its own registration_sigma_m.
  // Refused: no layer, a name the map lacks, a name twice.
  static Result<std::unique_ptr<Localizer>> create(const geo::Map& map, const geo::CameraModel& camera,
                                                   const std::vector<std::string>& layers,
                                                   const iclk::TrackerOptions& options, int threads,
                                                   const nn::WeightFile* weights = nullptr,
                                                   const LocalizerSizes& sizes = {});
  // live: the camera image, 3-channel RGB of the camera's size. attitude: an attitude
  // reference's R_W_C for this image (an IMU's); with TrackerOptions::tilt_prior_rad the
  // answer's tilt is held to its roll and pitch (none: to the prior's). altitude: an
  // altimeter's reading of the camera centre's map z for this image (a barometer's, in the
  // map's vertical datum); with TrackerOptions::altitude_prior_m the answer's is held to it
  // (not finite: no altitude prior).
  Result<LocalizeOutput> localize(ImageView<const std::uint8_t> live, const geo::Pose& prior,
                                  const Eigen::Quaterniond* attitude = nullptr, double altitude = NAN);
  void set_iterations(int n);
  // Re-rendered refinement: after a converged alignment, up to `passes` times, render the
  // reference again at the answer and align again from it on its finest levels (the learned
  // tracker keeps the live image's features), while the last answer turned by more than
  // kRefineMinDeg from where its reference was rendered and its final residual is within the
  // bound (set_refinement_scope). The answer, its covariance and its converged flag are the
  // last converged pass's (a pass that fails leaves the one before it); the converged tests
  // are the first pass's. Default: none.
  void set_refinement(int passes) { refine_passes_ = std::max(passes, 0); }
  // A pass's levels (1 or more; at most the tracker's) and the final residual above which no
  // pass runs (INFINITY: none). create() sets the tracker's defaults: kDeepRefineLevels and
  // kDeepRefineMaxResidual learned, kRefineLevels and kRefineMaxResidual classical.
  void set_refinement_scope(int levels, double max_residual) {
    refine_levels_ = std::max(levels, 1);
    refine_max_residual_ = max_residual;
  }
  int refinement_levels() const { return refine_levels_; }
  double refinement_max_residual() const { return refine_max_residual_; }
  // The learned tracker's refinement passes without the M-estimator where the answer refined
  // ended at a final residual of at most `max_residual` (kRefineUniformMaxResidual: session
  // 37's rule); kRefineUniformOff (the default): every pass with it.
  void set_uniform_refinement(double max_residual) { refine_uniform_max_residual_ = max_residual; }
  // The learned tracker's second look: where a layer's first answer failed the agreement test
  // alone (iclk::TrackResult::unconfirmed), the reference is rendered again at that answer and
  // the first refinement pass aligns from it with the agreement test in it (the first pass's
  // threshold). If that pass converges the answer is confirmed: converged, its later passes
  // and covariance as any refined answer's. It is one of set_refinement's passes (none where
  // passes is 0). A first answer that failed it is a first pass's failure, as before. The
  // classical tracker has none. Default: off (kDefaultSecondLook is the command line's).
  // `max_disagreement_px` tightens the test for the second look alone: a second look whose
  // second start settled further than that from its answer fails, like one whose pass failed.
  void set_second_look(bool on, double max_disagreement_px = kSecondLookAnyDisagreement) {
    second_look_ = on;
    second_look_max_disagreement_px_ = max_disagreement_px;
  }
  bool second_look() const { return second_look_; }
  // The last localize()'s alignments, one a layer tried, in the order tried (its
  // LocalizeOutput::layers_tried of them; sized at create(): no allocation a frame).
  const LayerAttempt* attempts() const { return attempts_.data(); }
  // Renders the first layer's reference at `at` without aligning (the metrics' and figures'
  // reference).
  Status render_at(const geo::Pose& at) {
    LocalizeOutput unused;
    use_layer(0);
    return render_reference(at, unused);
  }
  // The reference of the last localize() (its last pass of the last layer tried) or render_at().
  const raster::RenderOutput& reference() const { return refs_[current_]; }
  std::size_t layer_count() const { return refs_.size(); }
  const ImageF& reference_depth() const { return depth_; }
  // The camera the reference is rendered with (the working size of the learned tracker).
  const geo::CameraModel& reference_camera() const { return work_; }
  bool learned() const { return deep_ != nullptr; }

 private:
  Localizer() = default;
  Status render_reference(const geo::Pose& at, LocalizeOutput& out);
  // The passes of one layer (localize()'s body for that layer).
  Status localize_layer(ImageView<const std::uint8_t> live, const geo::Pose& prior, const Eigen::Quaterniond* attitude,
                        LocalizeOutput& out);
  void use_layer(std::size_t i);  // the reference layer of the next render and alignment
  const iclk::TrackResult<iclk::SE3DepthWarp<float>>& align_once(ImageView<const std::uint8_t> live,
                                                                 const geo::Pose& ref_pose, const geo::Pose& prior,
                                                                 const Eigen::Quaterniond* attitude, bool first,
                                                                 bool learned_weights, bool agreement);
  double dem_variance_ = 0;  // the DEM's vertical_sigma_m squared (m^2)
  double altitude_ = NAN;    // the frame's altimeter reading (localize()), map z in metres
  int refine_passes_ = 0, refine_levels_ = kRefineLevels;
  double refine_max_residual_ = kRefineMaxResidual;
  double refine_uniform_max_residual_ = kRefineUniformOff;
  bool second_look_ = false;
  double second_look_max_disagreement_px_ = kSecondLookAnyDisagreement;
  geo::CameraModel camera_, work_;
  // Learned: one pool for the renderer and the aligner, which run one after the other
  // (declared before both: it outlives them). The classical tracker runs on the caller's thread.
  std::unique_ptr<ThreadPool> pool_;
  std::unique_ptr<iclk::DeepAligner> deep_;
  ImageF ref_rgb_, live_rgb_;  // learned: float RGB at the working size
  std::vector<int> sum_row_;   // learned: one row of the live image's box sums
  std::unique_ptr<raster::Renderer> renderer_;
  std::vector<raster::RenderOutput> refs_;  // one a layer, rendered where that layer is tried
  std::vector<double> ground_floor_m_;      // each layer's (TrackerOptions::ground_floor_m)
  std::size_t current_ = 0;
  // The live image of this localize() call is in the tracker already (converted, and for the
  // learned tracker encoded): a later layer's first pass aligns it to its own reference.
  bool live_kept_ = false;
  std::vector<LayerAttempt> attempts_;  // one a layer (attempts())
  ImageF ref_grey_, live_grey_, depth_;
  std::unique_ptr<iclk::Tracker<float, iclk::SE3DepthWarp<float>, 1>> tracker_;
};

// Maps the tracker's covariance (left perturbation of T_ref_live in the reference camera)
// to the world-frame [dtheta; dp] of LocalizeOutput::covariance.
Eigen::Matrix<double, 6, 6> covariance_in_world(const Eigen::Matrix<double, 6, 6>& cov_ref,
                                                const geo::Pose& T_W_ref, const iclk::SE3<double>& T_ref_live);
// A pose's error against the truth in the covariance's order (covariance_in_world's): the
// world-axis rotation truth * estimate^-1 as angle x axis (rad), then truth - estimate (m).
Eigen::Matrix<double, 6, 1> pose_error(const geo::Pose& estimate, const geo::Pose& truth);
// The normalised estimation error squared of a pose against the truth, e^T P^-1 e with e its
// pose_error and P the estimate's covariance; NaN where P is not positive definite. 6
// expected where P is honest (eval's and track's NEES).
double nees_of(const geo::Pose& estimate, const geo::Pose& truth, const Eigen::Matrix<double, 6, 6>& P);

// A pinhole copy of a camera, and the live image resampled to it (bilinear), for cameras
// with distortion. The pinhole keeps fx, fy, cx, cy.
geo::CameraModel pinhole_of(const geo::CameraModel& camera);
ImageU8 undistort(ImageView<const std::uint8_t> image, const geo::CameraModel& camera);

}  // namespace terralign::cli
