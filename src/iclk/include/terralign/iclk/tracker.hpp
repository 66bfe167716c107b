// The inverse-compositional Lucas-Kanade solver with Levenberg-Marquardt steps, coarse to
// fine, templated on the scalar (float, double), the warp (SE3DepthWarp, HomographyWarp) and
// the channel count of the feature images.
//
// For each pyramid level, from coarse to fine:
//  - reference pixels with valid depth (and a valid 3x3 neighbourhood) are selected (all, or
//    the strongest gradient in each block of TrackerOptions::block), and
//    their Jacobians J = dF_ref/du * dW/dxi are computed once, on the reference (inverse
//    compositional);
//  - per-pixel weights W come from outside (a learned M-estimator) or from a robust
//    function (none, Huber, Tukey) of the residuals at the pose the level starts from;
//    H = J^T W J is built once per level;
//  - each iteration warps the reference pixels into the live image (bilinear; pixels that
//    land outside are masked, and their share of H removed), forms r = F_live(W(x)) -
//    F_ref(x), and steps dxi = (H + lambda diag(H))^-1 J^T W r, p <- p o W(dxi)^-1.
// "N iterations" is N per level (Lv et al.'s max_iter_per_pyr): the paper's "no NN (20)".
// A level stops early when the step is below step_tol, and the finest level (6-DoF warp)
// also when a step moves its image by less than TrackerOptions::min_step_px.
//
// Intrinsics per level: K_{l+1} = K_l.half(), i.e. fx' = fx / 2, cx' = (cx + 0.5) / 2 - 0.5,
// with a level's pixel (i, j) the mean of level l's pixels 2i..2i+1, 2j..2j+1.
//
// Failure is data: converged = false with a reason (too few valid pixels, no texture, NaN,
// a step over the bound, a final cost above the cost at the initial parameters, a final
// pose implausibly far from the initial one); the parameters are then the initial ones,
// never NaN. All buffers are allocated in the constructor; align() allocates nothing.
#pragma once

#include <array>
#include <limits>
#include <memory>
#include <type_traits>
#include <vector>

#include <Eigen/Core>
#include <Eigen/StdVector>

#include <terralign/geo/image.hpp>
#include <terralign/geo/thread_pool.hpp>
#include <terralign/iclk/se3.hpp>
#include <terralign/iclk/warps.hpp>

namespace terralign::iclk {
namespace detail {
struct Se3EvalInput;
struct Se3EvalSums;
// The residual kernel of the 6-DoF warp on one float channel (src/iclk/evaluate_kernels.hpp):
// pixels [i0, i1), writes r and ok, fills the lane sums.
using Se3EvalFn = void (*)(const Se3EvalInput& in, int i0, int i1, float* r, unsigned char* ok, Se3EvalSums& sums);
// Its Jacobians at up to eight selected pixels, a level's set-up (evaluate_kernels.hpp).
struct Se3JacobianInput;
struct Se3JacobianGroup;
struct Se3FinestSums;
using Se3JacobianFn = void (*)(const Se3JacobianInput& in, const int* x, const int* y, int count, Se3JacobianGroup& out,
                               Se3FinestSums* sums);
// The lower half of a 6 x 6 J^T W J in lanes of double (evaluate_kernels.hpp).
constexpr int kOuterLanes = 4;
struct OuterSums {
  double h[21][kOuterLanes];
};
using OuterSumsFn = void (*)(const float* const* jac, const float* w, int i0, int i1, OuterSums& h);
using OuterSumsAtFn = void (*)(const float* const* jac, const float* w, const int* index, int count, OuterSums& h);
}  // namespace detail

enum class Robust { None, Huber, Tukey };

// The step of the coarse search's turns about the optical axis (TrackerOptions).
constexpr double kCoarseYawStepDeg = 2.0;

struct TrackerOptions {
  int levels = 4;                    // 1..6
  int iterations = 20;               // per level
  double lambda = 1e-6;              // LM damping, times diag(H)
  Robust robust = Robust::None;
  bool normalize = true;             // zero mean, unit variance per image, level and channel
  double step_tol = 1e-6;            // rad, and m per metre of median depth
  // The finest level (and the agreement test's second start) also stops once a step moves
  // the image by less than this, RMS over the used pixels (6-DoF warp; 0 or negative: never). The
  // parameters then lie well inside the registration floor (0.1 px and more), yet step_tol
  // rarely stops a level: across a year the learned tracker's finest level ran all 20
  // iterations on 76 of 80 solves, steps of thousandths of a pixel among them (session 42).
  double min_step_px = 0;
  int min_valid_pixels = 200;        // at the finest level
  double max_step_rotation = 0.35;   // rad in one iteration
  double max_step_translation = 0.35;  // times the median reference depth, in one iteration
  double max_cost_ratio = 1.0;       // final cost / cost at the initial parameters, finest level
  // ... unless the answer lies within still_px of the start (RMS finest-level image motion,
  // 6-DoF warp): a start already at the minimum, as a tracking loop's prediction often is,
  // ends a noise-sized step away at a cost equal to the start's within noise, which is the
  // start confirmed, not a divergence (a same-year learned track failed 35 % of its frames
  // so, each 0.1-0.4 m from the truth).
  double still_px = 0.5;
  // With normalised images (zero mean, unit variance) the mean squared residual is about
  // 2 (1 - NCC): 1.0 asks for a final correlation of at least 0.5. Measured on NAIP: aligned
  // same-year pairs end below 0.03, diverged ones mostly above 0.15 (README).
  double max_final_cost = 1.0;
  double max_rotation = 0.35;        // rad: a final rotation farther from the initial one fails
  double max_translation = 0.5;      // times the median reference depth, likewise
  double min_information = 1e-9;     // smallest eigenvalue of H / largest: below is no texture
  // The smallest registration error the covariance admits, in finest-level pixels: what no
  // pixel-noise model sees (a rendered reference resamples the map's texture at another
  // phase than the camera saw it; maps of different years disagree by a fraction of a
  // pixel). Added to the image term's covariance as that of the pose change that whole-image
  // motions cause: a shift in u, one in v, a rotation and a scale change about the principal
  // point, each of RMS size sigma_floor px over the used pixels and independent:
  // sigma_floor^2 M^-1 (sum_m b_m b_m^T) M^-1, M = sum dW^T dW, b_m = sum dW^T d_m.
  // 0.1 px: about the position RMSE of same-year rendered flights (README, tracking).
  double registration_floor_px = 0.1;
  // ... and at least this many pixels per unit of the final residual (TrackResult::
  // residual_final, about 2 (1 - NCC) with normalised images): a map that agrees with the
  // image less is registered to it less well. Same-year answers end at a residual of 0.01-0.08
  // (the fixed floor stays), a year apart at 0.8-1.5. 1 px took the learned tracker's NEES
  // across a year from 27.1 / 21.7 to 9.7 / 6.0 (the 40-frame lawnmower without / with an
  // IMU, where it was chosen) and from 12.7 / 11.4 to 5.5 / 3.7 on a circle (README).
  // 0: the fixed floor alone.
  double registration_floor_per_residual_px = 1.0;
  // The floor's two keystones, (du^2, du dv) and (du dv, dv^2) less their means, each of RMS
  // registration_floor_per_residual_px px per unit of the final residual past this one: the
  // perspective change of a tilt whose image shift a move of the camera takes back, which maps
  // of other years leave the learned tracker free to trade (README, "Why the tilt prior";
  // session 40). A camera's own noise is the image term's (sigma^2) and leaves same-year
  // answers at 0.01-0.08, 0.05-0.27 with README's poor camera (noise 10, blur 2): past 0.3 the
  // residual is what the map and the image disagree on (a year apart 0.8-1.5). Without the
  // keystones the learned tracker's converged answers across 1-9 years of the training map
  // claimed 2-5 times the precision they had (eval NEES mean 16-36 over six pairs, 8.7-13.6
  // with an IMU's tilt); with them 3.3-6.6 and 3.6-6.1. The tilt prior is combined with the
  // image term and its floor, so an attitude reference narrows what the keystones admit.
  double keystone_free_residual = 0.3;
  // What the map's placement of the ground is off by, metres per horizontal axis (a layer's
  // registration, geo::Layer::registration_sigma_m; 6-DoF warp only): the whole-image motions
  // of the floor gain (ground_floor_m f / median depth) px in variance. It is the image's
  // frame the map is off in, so the camera's answer is off as a whole motion of the image
  // would place it, tilt prior included (Christchurch's two surveys: session 41). 0: none.
  double ground_floor_m = 0;
  // The sharpness test (TrackResult::sharpness): the nudge in finest-level pixels (0: not
  // measured) and the least sharpness a converged answer must have. Off for the classical
  // tracker; the learned one sets them (DeepAligner).
  double probe_px = 0;
  double min_sharpness = 0;
  // The agreement test (TrackResult::disagreement_px, 6-DoF warp): a second start, the answer
  // moved by agree_px finest-level pixels in u and in v (0: not measured), takes up to
  // agree_iterations steps at the finest level with the same weights; a converged answer
  // whose second start settles more than max_disagreement_px away fails (0: no test).
  double agree_px = 0;
  int agree_iterations = 10;
  double max_disagreement_px = 0;
  // Before the coarsest level's first step (6-DoF warp): the start is moved to the best of
  // the rotations that shift the image by up to k coarsest-level pixels in u and v (whole
  // pixels), each also turned about the optical axis in steps of kCoarseYawStepDeg up to
  // coarse_search_yaw_deg each way, by the unweighted residual there (k = 0: no search).
  // Widens the basin for a prior a few coarsest pixels off, which the steps alone can miss.
  int coarse_search_px = 0;
  double coarse_search_yaw_deg = 0;
  // A tilt prior (6-DoF warp), from an attitude reference, as an aircraft's IMU still gives
  // while GPS fails, or from the prior pose's own roll and pitch (the command line's default,
  // 3 degrees): the answer's tilt, its rotation relative to the initial parameters about the two axes
  // orthogonal to the world's up (Tracker::set_up), is held to a Gaussian prior of this
  // standard deviation per axis, in rad (0: none). The heading and the position stay free.
  // Weighed against the image term at its noise (sigma^2 f, TrackResult::covariance, f
  // measured when each level starts) in every step, and part of the covariance. Images of
  // distant years agree on where things are better than on the perspective: without it the
  // learned tracker trades a tilt error for a shift (README).
  double tilt_prior_rad = 0;
  // An altitude prior (6-DoF warp), from an altimeter, as an aircraft's barometer still gives
  // while GPS fails: the answer's camera centre, its height along the world's up above the
  // reference camera's, is held to Tracker::set_height()'s with a Gaussian of this standard
  // deviation, in metres (0: none). Weighed against the image term as the tilt prior is, and
  // part of the covariance. Across many years the learned tracker's misses are mostly a
  // height off by 10-30 m, which the coarse levels' features place wrong (README).
  double altitude_prior_m = 0;
  int threads = 1;                   // residuals in fixed chunks: same result on any count
  // The vector (AVX2) residual kernel where the CPU has it; false: its scalar twin. Both give
  // the same bits (evaluate_kernels.hpp); tests compare them.
  bool simd = true;
  // Pixel selection per level (finest first): in each block x block cell the pixel with the
  // strongest gradient is used; 1 uses every pixel (as Lv et al. do). Sparse fine levels make
  // the classical solver about 10x faster for a small loss in precision (see bench_align).
  std::array<int, 6> block{{4, 2, 1, 1, 1, 1}};
};

// The options of a refinement pass, an alignment started from a reference rendered again at
// the last answer: the finest `levels` levels of o's, no coarse search, and neither the
// sharpness nor the agreement test (the first pass's answer passed them; a threshold
// calibrated on answers found from afar failed 11 right and 1 wrong of 2009 -> 2020's
// refined answers, seed 7).
inline TrackerOptions refinement_options(TrackerOptions o, int levels) {
  o.levels = std::max(1, std::min(levels, o.levels));
  o.coarse_search_px = 0;
  o.probe_px = 0;
  o.min_sharpness = 0;
  o.agree_px = 0;
  o.max_disagreement_px = 0;
  return o;
}

template <class Warp>
struct TrackResult {
  using Params = typename Warp::Params;
  static constexpr int DoF = Warp::DoF;
  Params params = Warp::identity();  // e.g. T_live_ref
  bool converged = false;
  const char* reason = "not run";
  int iterations = 0;                // over all levels
  int valid_pixels = 0;              // at the finest level, final iteration
  // Mean weighted squared residual (per channel) at the finest level: at the initial parameters, where
  // the finest level started (after the coarse levels), and at the end.
  double cost_init = 0, cost_start = 0, cost_final = 0;
  // The same without the weights: the mean squared residual per channel over the finest
  // level's pixels that land inside, at the initial parameters and at the end. With
  // normalised features about 2 (1 - NCC): how well the whole image agrees, not only the
  // pixels a (learned) M-estimator kept.
  double residual_init = 0, residual_final = 0;
  // How sharply the answer is a minimum (6-DoF warp with probe_px > 0; else 0): the residual
  // with the pose nudged by TrackerOptions::probe_px finest-level pixels left, right, up and
  // down (rotations about the camera's y and x axes), the smallest of the four, over
  // residual_final. A right answer sits in a narrow valley of the image agreement; a wrong
  // one, where the features do not agree anyway, in a flat one.
  double sharpness = 0;
  // Whether the answer is a basin (6-DoF warp with agree_px > 0; else 0): the RMS image motion,
  // finest-level pixels over the used pixels, between the answer and where a second start
  // TrackerOptions::agree_px away settles (infinite where that run fails). Across many years
  // a wrong answer is often as deep a minimum as a right one, but a shallower, wider one: a
  // start nearby returns to a right answer and drifts near a wrong one (README).
  double disagreement_px = 0;
  // Where the agreement test alone failed an answer (converged false, params the initial
  // ones): that answer, unconfirmed, and its covariance scaled by (disagreement_px /
  // max_disagreement_px)^2, as uncertain as its two starts are apart. Only where the second
  // start settled (a finite disagreement); elsewhere false, the identity and zero. A track that
  // has no velocity yet may take it to start (terralign track); nothing else uses it.
  bool unconfirmed = false;
  Params unconfirmed_params = Warp::identity();
  Eigen::Matrix<double, DoF, DoF> unconfirmed_covariance = Eigen::Matrix<double, DoF, DoF>::Zero();
  double unconfirmed_scale = 1;  // disagreement_px / max_disagreement_px, the sigmas' factor
  // The pose the coarsest level started from: the initial one, or the coarse search's pick
  // (TrackerOptions::coarse_search_px).
  Params coarse_start = Warp::identity();
  // Covariance of the last step's parameters dxi (the solver's tangent at the estimate,
  // reference side): f sigma^2 (J^T W J)^-1 at the finest level, sigma^2 = sum w r^2 /
  // (sum w - DoF). Neighbouring residuals are not independent (interpolation, blur, and the
  // texture-phase error of a rendered reference are smooth), so the least-squares covariance
  // is inflated by f = ((1 + rho) / (1 - rho))^2, the variance factor of a 2-D field whose
  // neighbours correlate by rho (first-order autoregressive in each axis); rho is measured on
  // horizontally adjacent used pixels at the end, clamped to [0, 0.9]; with C channels f is
  // also multiplied by 1 + (C - 1) rho_c, rho_c the channels' residuals' mean correlation in
  // [0, 1] (four copies of one channel: the one channel's covariance). To that the
  // registration floor (TrackerOptions::registration_floor_px) is added, and the sum is
  // combined with the tilt prior's information where there is one.
  Eigen::Matrix<double, DoF, DoF> covariance = Eigen::Matrix<double, DoF, DoF>::Zero();
  double residual_correlation = 0;   // rho
  double covariance_inflation = 1;   // f (with the channels' factor)
  double ms_pyramid = 0, ms_jacobian = 0, ms_iterations = 0;
};

// Per-pixel weights computed when a level starts (a learned M-estimator). The tracker hands
// over, on the level's reference grid: |r| at the pose the level starts from (the RMS over
// channels; 0 where a pixel is not used or lands outside the live image), the level's
// reference and live feature images (C channels, each normalised on its own when
// TrackerOptions::normalize), and an image to fill with
// weights (0 or NaN: the pixel is not used). Called from align(), on the caller's thread.
class LevelWeights {
 public:
  virtual ~LevelWeights() = default;
  virtual void weights(int level, ImageView<const float> abs_r, ImageView<const float> ref, ImageView<const float> live,
                       ImageView<float> out) = 0;
};

template <class S, class Warp, int C = 1>
class Tracker {
 public:
  using Params = typename Warp::Params;
  static constexpr int DoF = Warp::DoF;

  // Sizes every buffer for images of width x height at the finest level.
  // `pool`: the caller's pool to run on (shared with its other work, e.g. the learned
  // tracker's networks; it must outlive the tracker, and its thread count replaces
  // options.threads), else the tracker starts one of options.threads.
  Tracker(int width, int height, const TrackerOptions& options, ThreadPool* pool = nullptr);

  const TrackerOptions& options() const { return opt_; }
  void set_options(const TrackerOptions& o);  // same sizes; at most the levels it was built with

  // Full-resolution inputs: reference features (C channels), its depth (metres along the
  // axis, NaN: no data), live features (C channels), the level-0 pinhole intrinsics, the
  // initial parameters. Pyramids are built inside. `weights`, if given, is one view per
  // level of per-pixel weights on the reference grid (from a learned M-estimator).
  const TrackResult<Warp>& align(ImageView<const float> ref, ImageView<const float> ref_depth,
                                 ImageView<const float> live, const Pinhole<S>& K0,
                                 const Params& init, const ImageView<const float>* weights = nullptr);

  // Aligns the last align()'s live image to another reference (another layer of the map, or
  // a reference rendered again where an answer ended): as align(), but the live pyramid is
  // the last alignment's, not built again. The answer is align()'s with that live image, bit
  // for bit. The last alignment must have run at least as many levels as the options run now.
  const TrackResult<Warp>& align_to(ImageView<const float> ref, ImageView<const float> ref_depth, const Pinhole<S>& K0,
                                    const Params& init, const ImageView<const float>* weights = nullptr);

  // Pyramids from outside (learned features): ref_levels and live_levels hold
  // options().levels views each, finest first, level l of size (w >> l, h >> l) (floor);
  // the depth pyramid is built from the full-resolution ref_depth. `weights` (optional) is
  // asked for each level's weights when the level starts. live_levels null: the live levels
  // of the last alignment, which ran at least as many (a refinement pass against the same
  // image: they are not copied and normalised again).
  const TrackResult<Warp>& align_levels(const ImageView<const float>* ref_levels, ImageView<const float> ref_depth,
                                        const ImageView<const float>* live_levels, const Pinhole<S>& K0,
                                        const Params& init, LevelWeights* weights);

  const TrackResult<Warp>& result() const { return result_; }

  // The world's up direction in the reference camera's frame, for the tilt prior
  // (TrackerOptions::tilt_prior_rad); kept for the next align() calls. Zero, or not finite:
  // no prior. `tilt`: the attitude reference's rotation of the answer relative to the initial
  // parameters, log(R_init^T R) (rad, the rotation part of the parameters' log), where the
  // reference's tilt is not the initial parameters' (zero: it is); only its part about the
  // two axes orthogonal to up counts.
  void set_up(const Eigen::Vector3d& up_in_reference, const Eigen::Vector3d& tilt = Eigen::Vector3d::Zero()) {
    up_ = up_in_reference;
    tilt_ = tilt;
  }
  // For the altitude prior (TrackerOptions::altitude_prior_m): the altimeter's height of the
  // live camera above the reference camera, along set_up()'s up, in metres; kept for the next
  // align() calls. Not finite: no prior.
  void set_height(double height) { altimeter_height_ = height; }

 private:
  struct Level {
    int w = 0, h = 0;
    ImageF ref, live, depth;
    ImageF live_planes;    // several channels: live's, one plane after another (the kernel's)
    ImageF abs_r, weight;  // for LevelWeights
  };
  // The levels the options run (set_options may run fewer than were built: a refinement
  // pass); only these are built, copied and normalised for an alignment.
  std::size_t levels_in_use() const { return static_cast<std::size_t>(opt_.levels); }
  // align()'s and align_to()'s pyramids and solve; live null: the last alignment's live levels.
  const TrackResult<Warp>& build_and_solve(ImageView<const float> ref, ImageView<const float> ref_depth,
                                           const ImageView<const float>* live, const Pinhole<S>& K0,
                                           const Params& init, const ImageView<const float>* weights);
  // live null: the reference's and depth's pyramids alone (the live levels are kept).
  void build_pyramids(ImageView<const float> ref, ImageView<const float> depth, const ImageView<const float>* live);
  template <bool kLive>
  void downsample_levels();  // levels 1.. of the reference (and of the live image) from the finest
  void build_depth_pyramid();
  void normalize_levels(bool live = true);  // live: also the live levels (else they are kept)
  std::size_t live_ready_ = 0;  // levels whose live images the last alignment normalised
  const TrackResult<Warp>& solve(const Pinhole<S>& K0, const Params& init, const ImageView<const float>* weights,
                                 LevelWeights* level_weights);
  void learned_weights(int n, int level, const Params& p, const Pinhole<S>& K, LevelWeights& lw);
  double residual_correlation(int n) const;
  // Several channels: 1 + (C - 1) x their residuals' mean correlation, the covariance's factor
  // for channels that repeat each other (1 for one channel).
  double channel_factor(int n) const;
  double mean_square_residual(int n) const;  // unweighted, of the residuals of the last evaluate()
  // The RMS image motion over the finest level's n used pixels of a pose change d (6-DoF
  // warp; first order, sum dW^T dW): finest-level pixels.
  double rms_motion_px(const Vec6<double>& d, int n) const;
  Params coarse_search(int n, const Params& p, const Pinhole<S>& K);
  // p with the camera turned so the image moves by about (du, dv) pixels of K's level (6-DoF
  // warp): the sharpness probe's nudge, the agreement test's second start and the coarse
  // search's grid.
  static Params shifted(const Params& p, double du, double dv, const Pinhole<S>& K);
  // The reference pixels a level uses (every pixel with depth around it, or the strongest
  // gradient of each block), with their 3-D points, values and Jacobians; returns how many.
  // Runs on the pool in fixed bands of block rows, so the result does not depend on the
  // thread count: each band picks its pixels, then writes them after the earlier bands'.
  int select_pixels(int level, const Pinhole<S>& K);
  // The registration floor's image motions (TrackerOptions::registration_floor_px): shift in
  // u, in v, rotation and scale about the principal point, and the two keystones (du^2, du dv)
  // and (du dv, dv^2), du and dv from the principal point.
  static constexpr int kFloorModes = 6;
  // Sums over the used finest-level pixels of du^2, dv^2, du dv, du^2 (du^2 + dv^2) and
  // dv^2 (du^2 + dv^2): the modes' sizes and means.
  using Moments = std::array<double, 5>;
  // Bands and chunks are written by the thread that takes them, a line of their own each
  // (kUnsharedAlign).
  struct alignas(kUnsharedAlign) Band {
    int row0 = 0, row1 = 0;  // block rows [row0, row1)
    int count = 0, offset = 0;
    Eigen::Matrix<double, DoF, DoF> motion;  // the band's shares of motion0_, floor0_, moments0_
    Eigen::Matrix<double, DoF, kFloorModes> floor;
    Moments moments;
  };
  static constexpr int kBands = 16;
  void pick_band(int level, Band& b);
  void write_band(int level, const Pinhole<S>& K, Band& b);
  // H = J^T W J over the selected pixels, in chunks of kChunk pixels summed in chunk order.
  void hessian(int n, Eigen::Matrix<double, DoF, DoF>& H);
  void robust_weights(int n, const ImageView<const float>* weights, int level);
  // Residuals and J^T W r at `p`; returns the valid count, fills cost (sum w r^2 over pixels
  // and channels), wsum (sum of w, counted once per channel: cost / wsum is the mean per
  // residual, and sigma^2 its variance) and H_out (J^T W J over the pixels that left the image).
  int evaluate(int n, const Params& p, const Pinhole<S>& K, Eigen::Matrix<double, DoF, 1>& g,
               Eigen::Matrix<double, DoF, DoF>& H_out, double& cost, double& wsum);

  TrackerOptions opt_;
  int width_, height_;
  std::vector<Level> levels_;
  // Per selected reference pixel (structure of arrays, sized for the finest level).
  std::vector<S> pu_, pv_, px_, py_, pz_;   // pixel and 3-D point in the reference camera
  std::vector<S> val_;                      // reference feature values, one array per channel
  std::vector<S> jac_;                      // Jacobians, one array per channel and parameter
  std::size_t jac_stride_ = 0;
  S& jac(int i, int c, int a) {
    return jac_[(static_cast<std::size_t>(c) * DoF + static_cast<std::size_t>(a)) * jac_stride_ + static_cast<std::size_t>(i)];
  }
  // Pixel i's place in a per-channel array (val_, r_): channel c's array starts at c * stride.
  std::size_t at(std::size_t i, int c) const { return static_cast<std::size_t>(c) * jac_stride_ + i; }
  std::vector<S> w_;                        // weight
  std::vector<S> r_;                        // residuals, one array per channel
  std::vector<unsigned char> ok_;           // landed inside the live image
  std::vector<S> abs_;                      // scratch: absolute residuals
  Eigen::Matrix<double, DoF, DoF> motion0_;  // sum over used finest-level pixels of dW^T dW
  // Per finest-level pixel dW^T d for the image motions of the registration floor
  // (kFloorModes), summed; and the pixels' Moments.
  Eigen::Matrix<double, DoF, kFloorModes> floor0_;
  Moments moments0_{};
  const Level* cur_level_ = nullptr;
  Eigen::Vector3d up_ = Eigen::Vector3d::Zero(), tilt_ = Eigen::Vector3d::Zero();
  double altimeter_height_ = std::numeric_limits<double>::quiet_NaN();
  // Per chunk of kChunk pixels: partial sums, combined in chunk order.
  static constexpr int kChunk = 2048;
  struct alignas(kUnsharedAlign) Partial {
    Eigen::Matrix<double, DoF, 1> g;
    Eigen::Matrix<double, DoF, DoF> H_out;
    double cost, wsum;
    int valid;
  };
  std::vector<Partial> partials_;  // (C++17's allocator honours over-alignment)
  std::vector<Band> bands_;
  std::vector<int> pick_;  // per block of the level: its chosen pixel (y * w + x), or -1
  int pick_cols_ = 0, pick_block_ = 1;
  std::unique_ptr<ThreadPool> own_pool_;  // without a caller's pool
  ThreadPool* pool_ = nullptr;
  void evaluate_chunk(int chunk, int n, const Params& p, const Pinhole<S>& K);
  void add_outer(Partial& P, int i);  // pixel i's share of J^T W J into P.H_out (a pixel that left; hessian())
  // The 6-DoF float warp has a vector kernel (evaluate_kernels.hpp), run once per channel.
  static constexpr bool kSe3Kernel = std::is_same_v<S, float> && std::is_same_v<Warp, SE3DepthWarp<float>>;
  detail::Se3EvalFn se3_kernel_ = nullptr;
  detail::Se3JacobianFn jacobian_kernel_ = nullptr;
  // J^T W J of the 6-DoF float trackers has one too, whatever the warp and channels.
  static constexpr bool kOuterKernel = std::is_same_v<S, float> && DoF == 6;
  detail::OuterSumsFn outer_kernel_ = nullptr;
  detail::OuterSumsAtFn outer_at_kernel_ = nullptr;
  std::vector<int> out_index_;  // per chunk, kChunk entries: the pixels that left (evaluate_chunk())
  // J^T W J through the kernels into P.H_out: of pixels [i0, i1), or of index[0 .. count)
  // when index is set; the lanes combined in lane order, so every build gives the same bits.
  void outer_kernel_sum(Partial& P, int i0, int i1, const int* index, int count);
  void pick_kernel();
  TrackResult<Warp> result_;
};

// Grey level in [0, 1] from 8-bit RGB (Rec. 601 weights), for the classical method.
void rgb_to_grey(ImageView<const std::uint8_t> rgb, ImageF& grey);

}  // namespace terralign::iclk
