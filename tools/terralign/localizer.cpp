#include "localizer.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>

#include <terralign/geo/float_environment.hpp>
#include <terralign/geo/number_text.hpp>
#include <terralign/geo/numeric.hpp>

namespace terralign::cli {

Result<std::unique_ptr<Localizer>> Localizer::create(const geo::Map& map, const geo::CameraModel& camera,
                                                     const std::string& layer, const iclk::TrackerOptions& options,
                                                     int threads, const nn::WeightFile* weights,
                                                     const LocalizerSizes& sizes) {
  return create(map, camera, std::vector<std::string>{layer}, options, threads, weights, sizes);
}

Result<std::unique_ptr<Localizer>> Localizer::create(const geo::Map& map, const geo::CameraModel& camera,
                                                     const std::vector<std::string>& layers,
                                                     const iclk::TrackerOptions& options, int threads,
                                                     const nn::WeightFile* weights, const LocalizerSizes& sizes) {
  const FloatEnvironmentScope float_environment;
  if (camera.model != geo::DistortionModel::None)
    return Error{"Localizer: the camera must be a pinhole (undistort the live image first)"};
  if (layers.empty()) return Error{"Localizer: no reference layer given (layers: " + map.layer_names() + ")"};
  std::unique_ptr<Localizer> L(new Localizer);
  for (std::size_t i = 0; i < layers.size(); ++i) {
    const geo::Layer* ref_layer = map.find_layer(layers[i]);
    if (!ref_layer) return Error{"Localizer: no layer named '" + layers[i] + "' (layers: " + map.layer_names() + ")"};
    if (std::find(layers.begin(), layers.begin() + static_cast<std::ptrdiff_t>(i), layers[i]) !=
        layers.begin() + static_cast<std::ptrdiff_t>(i))
      return Error{"Localizer: layer '" + layers[i] + "' is given twice"};
    // The reference layer's own error on the ground joins any the caller's options count.
    L->ground_floor_m_.push_back(hypot_exact(options.ground_floor_m, ref_layer->registration_sigma_m));
  }
  L->attempts_.resize(layers.size());
  L->camera_ = camera;
  L->work_ = camera;
  iclk::TrackerOptions with_map = options;
  with_map.ground_floor_m = L->ground_floor_m_[0];
  L->dem_variance_ = map.dem.vertical_sigma_m * map.dem.vertical_sigma_m;
  if (weights) {
    // The learned tracker renders and aligns at the size its network was trained at.
    TERRALIGN_TRY_ASSIGN(double s, iclk::DeepAligner::input_scale(*weights));
    if (sizes.input_scale != 0) s = sizes.input_scale;
    if (!(s > 0 && s <= 1)) return Error{"Localizer: the learned tracker's input scale must be in (0, 1]"};
    const int w = static_cast<int>(std::lround(camera.width * s)), h = static_cast<int>(std::lround(camera.height * s));
    if (w < 1 || h < 1 || camera.width % w || camera.height % h || camera.width / w != camera.height / h)
      return Error{weights->name + ": input scale " + geo::format_double(s) + " is not 1/n of the camera's " +
                   std::to_string(camera.width) + " x " + std::to_string(camera.height)};
    L->work_ = camera.scaled(s, w, h);
    iclk::TrackerOptions dopt = with_map;
    dopt.registration_floor_px *= s;  // camera pixels -> working pixels
    dopt.registration_floor_per_residual_px *= s;
    L->pool_ = std::make_unique<ThreadPool>(std::max(1, threads));
    TERRALIGN_TRY_ASSIGN(L->deep_, iclk::DeepAligner::create(*weights, w, h, dopt, threads, sizes.levels, L->pool_.get()));
    L->set_refinement_scope(kDeepRefineLevels, kDeepRefineMaxResidual);
    L->ref_rgb_.resize(w, h, 3);
    L->live_rgb_.resize(w, h, 3);
    L->sum_row_.resize(static_cast<std::size_t>(3 * w));
  }
  raster::RenderOptions ro;
  ro.threads = threads;
  if (sizes.max_triangles > 0) ro.max_triangles = sizes.max_triangles;
  TERRALIGN_TRY_ASSIGN(L->renderer_, raster::Renderer::create(map, L->work_, ro, L->pool_.get()));
  for (const std::string& layer : layers) {
    TERRALIGN_TRY_ASSIGN(auto ref, L->renderer_->make_output({layer}));
    L->refs_.push_back(std::move(ref));
  }
  L->depth_.resize(L->work_.width, L->work_.height, 1);
  if (L->deep_) return L;
  L->ref_grey_.resize(camera.width, camera.height, 1);
  L->live_grey_.resize(camera.width, camera.height, 1);
  // The renderer takes the threads; the sparse classical alignment stays on one (measured:
  // 22.5 ms on one thread, 30 ms on two: its work per iteration is too small to repay the
  // hand-off; bench_align).
  iclk::TrackerOptions topt = with_map;
  topt.threads = 1;
  if (topt.coarse_search_px == 0) topt.coarse_search_px = kClassicCoarseSearchPx;
  if (topt.coarse_search_px < 0) topt.coarse_search_px = 0;
  if (topt.agree_px == 0) topt.agree_px = kClassicAgreePx;
  if (topt.max_disagreement_px == 0) topt.max_disagreement_px = kClassicMaxDisagreementPx;
  L->tracker_ = std::make_unique<iclk::Tracker<float, iclk::SE3DepthWarp<float>, 1>>(camera.width, camera.height, topt);
  return L;
}

void Localizer::set_iterations(int n) {
  if (deep_) return deep_->set_iterations(n);
  auto o = tracker_->options();
  o.iterations = n;
  tracker_->set_options(o);
}

Eigen::Matrix<double, 6, 6> covariance_in_world(const Eigen::Matrix<double, 6, 6>& cov_ref,
                                                const geo::Pose& T_W_ref, const iclk::SE3<double>& T_ref_live) {
  // T_ref_live' = exp(d) T_ref_live, d = [w; v] in the reference camera: the live centre
  // p = t_ref_live moves by w x p + v and the rotation by exp(w). In world axes:
  // dtheta = R_W_ref w, dp = R_W_ref (-[p]x w + v).
  const Eigen::Matrix3d R = T_W_ref.R();
  const Eigen::Vector3d p = T_ref_live.t;
  Eigen::Matrix<double, 6, 6> J = Eigen::Matrix<double, 6, 6>::Zero();
  J.topLeftCorner<3, 3>() = R;
  J.bottomLeftCorner<3, 3>() = -R * iclk::hat<double>(p);
  J.bottomRightCorner<3, 3>() = R;
  return J * cov_ref * J.transpose();
}

Eigen::Matrix<double, 6, 1> pose_error(const geo::Pose& estimate, const geo::Pose& truth) {
  Eigen::Matrix<double, 6, 1> e;
  e << geo::rotation_vector(truth.q_W_C * estimate.q_W_C.conjugate()), truth.t_W_C - estimate.t_W_C;
  return e;
}

double nees_of(const geo::Pose& estimate, const geo::Pose& truth, const Eigen::Matrix<double, 6, 6>& P) {
  const Eigen::Matrix<double, 6, 1> e = pose_error(estimate, truth);
  const auto ldlt = P.ldlt();
  return ldlt.info() == Eigen::Success && ldlt.isPositive() ? e.dot(ldlt.solve(e)) : NAN;
}

void Localizer::use_layer(std::size_t i) {
  // The options hold the current layer's floor (the first's from create()): a localizer of one
  // layer never changes them.
  if (i == current_) return;
  current_ = i;
  if (deep_) return deep_->set_ground_floor_m(ground_floor_m_[i]);
  auto o = tracker_->options();
  o.ground_floor_m = ground_floor_m_[i];
  tracker_->set_options(o);
}

Status Localizer::render_reference(const geo::Pose& at, LocalizeOutput& out) {
  raster::RenderOutput& ref = refs_[current_];
  const auto t0 = std::chrono::steady_clock::now();
  auto st = renderer_->render(at, ref);
  if (!st.ok()) return st.error();
  out.ms_render += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  // Depth where the reference layer has colour; NaN elsewhere (sky, off the layer).
  for (std::size_t k = 0; k < depth_.size(); ++k)
    depth_.data()[k] = ref.valid[0].data()[k] ? ref.depth.data()[k] : NAN;
  if (deep_)
    for (std::size_t k = 0; k < ref_rgb_.size(); ++k) ref_rgb_.data()[k] = ref.rgb[0].data()[k];
  else
    iclk::rgb_to_grey(ref.rgb[0].view(), ref_grey_);
  return Ok{};
}

const iclk::TrackResult<iclk::SE3DepthWarp<float>>& Localizer::align_once(ImageView<const std::uint8_t> live,
                                                                          const geo::Pose& ref_pose,
                                                                          const geo::Pose& prior,
                                                                          const Eigen::Quaterniond* attitude,
                                                                          bool first, bool learned_weights,
                                                                          bool agreement) {
  const iclk::Pinhole<float> K{static_cast<float>(work_.fx), static_cast<float>(work_.fy), static_cast<float>(work_.cx),
                               static_cast<float>(work_.cy)};
  // The reference camera is ref_pose's: the world's up seen from it (the tilt prior's axis),
  // and the attitude's rotation of the live camera relative to it, log(R_live^T R_ref), the
  // rotation of T_live_ref that the prior holds (the tracker starts from the identity).
  // Without an attitude reference the prior's own tilt is held, also in a refinement pass,
  // whose reference is rendered at the last answer: the prior stays the prior's.
  const Eigen::Vector3d up = ref_pose.R().transpose() * Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d tilt = geo::rotation_vector((attitude ? *attitude : prior.q_W_C).conjugate() * ref_pose.q_W_C);
  // The altimeter's height above the camera the reference is rendered from.
  const double height = altitude_ - ref_pose.t_W_C.z();
  if (!deep_) {
    tracker_->set_up(up, tilt);
    tracker_->set_height(height);
    // The live image's pyramid is built once a frame, by the first layer's alignment; a later
    // layer and a refinement pass align their reference to it.
    if (first && !live_kept_) {
      iclk::rgb_to_grey(live, live_grey_);
      live_kept_ = true;
      return tracker_->align(ref_grey_.view(), depth_.view(), live_grey_.view(), K, iclk::SE3<float>::identity());
    }
    if (first) return tracker_->align_to(ref_grey_.view(), depth_.view(), K, iclk::SE3<float>::identity());
    const iclk::TrackerOptions keep = tracker_->options();
    tracker_->set_options(iclk::refinement_options(keep, refine_levels_));
    const auto& r = tracker_->align_to(ref_grey_.view(), depth_.view(), K, iclk::SE3<float>::identity());
    tracker_->set_options(keep);
    return r;
  }
  deep_->set_up(up, tilt);
  deep_->set_height(height);
  if (!first) return deep_->refine(ref_rgb_.view(), depth_.view(), K, refine_levels_, learned_weights, agreement);
  // A later layer: the live image's features are those the first layer's alignment encoded.
  if (live_kept_) return deep_->align_to(ref_rgb_.view(), depth_.view(), K, iclk::SE3<float>::identity());
  live_kept_ = true;
  // The live image box-averaged down to the working size.
  const int f = camera_.width / work_.width;
  const float inv = 1.0f / static_cast<float>(f * f);
  for (int y = 0; y < work_.height; ++y) {
    float* out_row = &live_rgb_.at(0, y, 0);
    for (int k = 0; k < 3 * work_.width; ++k) sum_row_[static_cast<std::size_t>(k)] = 0;
    for (int dy = 0; dy < f; ++dy) {
      const std::uint8_t* in = live.row(y * f + dy);
      for (int x = 0; x < work_.width; ++x, in += 3 * f)
        for (int dx = 0; dx < f; ++dx)
          for (int c = 0; c < 3; ++c) sum_row_[static_cast<std::size_t>(3 * x + c)] += in[3 * dx + c];
    }
    for (int k = 0; k < 3 * work_.width; ++k) out_row[k] = static_cast<float>(sum_row_[static_cast<std::size_t>(k)]) * inv;
  }
  return deep_->align(ref_rgb_.view(), depth_.view(), live_rgb_.view(), K, iclk::SE3<float>::identity());
}

Result<LocalizeOutput> Localizer::localize(ImageView<const std::uint8_t> live, const geo::Pose& prior,
                                           const Eigen::Quaterniond* attitude, double altitude) {
  const FloatEnvironmentScope float_environment;
  if (live.width != camera_.width || live.height != camera_.height || live.channels != 3)
    return Error{"live image is " + std::to_string(live.width) + " x " + std::to_string(live.height) + " x " +
                 std::to_string(live.channels) + ", the camera is " + std::to_string(camera_.width) + " x " +
                 std::to_string(camera_.height) + " x 3"};
  // One output over the layers: each layer's passes add their time and iterations to it. Where
  // none converges, the last layer's failure is reported (its measures and reason).
  LocalizeOutput out;
  live_kept_ = false;
  altitude_ = std::isfinite(altitude) ? altitude : prior.t_W_C.z();
  for (std::size_t i = 0; i < refs_.size(); ++i) {
    use_layer(i);
    out.T_live_ref = iclk::SE3<double>::identity();
    out.covariance.setZero();
    out.uniform_refinements = 0;
    out.second_look = false;
    out.second_look_disagreement_px = NAN;
    const int iterations_before = out.iterations;
    // Every layer sees the same ground from the same prior: one that cannot be rendered
    // there is an error of the first (the pose off the map, say).
    if (auto st = localize_layer(live, prior, attitude, out); !st.ok()) return st.error();
    out.layer = static_cast<int>(i);
    out.layers_tried = static_cast<int>(i + 1);
    attempts_[i] = {out.converged,      out.reason,          out.iterations - iterations_before,
                    out.residual_final, out.disagreement_px, out.sharpness};
    if (out.converged) break;
  }
  if (out.converged) out.unconfirmed = false;  // an earlier layer's is no answer here
  return out;
}

Status Localizer::localize_layer(ImageView<const std::uint8_t> live, const geo::Pose& prior,
                                 const Eigen::Quaterniond* attitude, LocalizeOutput& out) {
  out.T_W_C = prior;
  out.converged = false;
  geo::Pose ref_pose = prior;                                      // where the reference is rendered
  iclk::SE3<double> T_ref_prior = iclk::SE3<double>::identity();  // and its place against the prior
  bool second_look = false;  // this pass looks again at the first pass's unconfirmed answer
  for (int pass = 0; pass <= refine_passes_; ++pass) {
    // A refinement pass that cannot render or does not converge leaves the previous pass's
    // answer: of the converged answers such passes failed on seed 7, 16 of 17 were right (the
    // learned tracker's 2009 -> 2020 with the agreement test in the pass, 11 of 12; the
    // classical tracker's 2016 -> 2017, 5 of 5).
    if (auto st = render_reference(ref_pose, out); !st.ok()) {
      if (pass == 0) return st.error();
      break;
    }
    // Where asked (set_uniform_refinement), the learned tracker's refinement pass of an answer
    // whose image agrees with the map weighs every pixel alike.
    const bool uniform = deep_ && pass > 0 && out.residual_final <= refine_uniform_max_residual_;
    const auto& r = align_once(live, ref_pose, prior, attitude, pass == 0, !uniform, second_look);
    out.iterations += r.iterations;
    out.ms_pyramid += r.ms_pyramid;
    out.ms_jacobian += r.ms_jacobian;
    out.ms_iterations += r.ms_iterations;
    if (deep_) {
      out.ms_encoder += deep_->ms_encoder();
      out.ms_mestimator += deep_->ms_mestimator();
    }
    if (second_look) out.second_look_disagreement_px = r.disagreement_px;
    if (pass > 0 && !r.converged) break;
    if (second_look && !(r.disagreement_px <= second_look_max_disagreement_px_)) break;  // the first pass's failure
    if (second_look) out.second_look = true;
    second_look = false;
    if (pass == 0) {  // the start, and the tests' measures (a refinement pass has none)
      out.cost_init = r.cost_init;
      out.residual_init = r.residual_init;
      out.sharpness = r.sharpness;
      out.disagreement_px = r.disagreement_px;
    }
    out.converged = r.converged;
    out.reason = r.reason;
    out.cost_final = r.cost_final;
    out.residual_final = r.residual_final;
    out.residual_correlation = r.residual_correlation;
    out.covariance_inflation = r.covariance_inflation;
    out.refinements = pass;
    if (uniform) ++out.uniform_refinements;
    // A map pose and its world covariance from the tracker's relative pose and covariance.
    const auto in_world = [&](const iclk::SE3<float>& params, const Eigen::Matrix<double, 6, 6>& cov_ref,
                              geo::Pose& T_W_C, Eigen::Matrix<double, 6, 6>& cov) {
      const iclk::SE3<double> T_ref_live = params.cast<double>().inverse();
      geo::Pose rel;
      rel.q_W_C = Eigen::Quaterniond(T_ref_live.R).normalized();
      rel.t_W_C = T_ref_live.t;
      T_W_C = ref_pose * rel;
      cov = covariance_in_world(cov_ref, ref_pose, T_ref_live);
      cov(5, 5) += dem_variance_;
    };
    if (!r.converged) {  // failure as data: the prior (T_W_C), no covariance
      if (pass == 0 && r.unconfirmed) {
        geo::Pose at;
        Eigen::Matrix<double, 6, 6> cov;
        in_world(r.unconfirmed_params, r.unconfirmed_covariance, at, cov);
        if (!out.unconfirmed) {
          out.unconfirmed = true;
          out.T_W_C_unconfirmed = at;
          out.covariance_unconfirmed = cov;
          out.unconfirmed_scale = r.unconfirmed_scale;
        }
        if (deep_ && second_look_ && pass < refine_passes_) {  // set_second_look
          ref_pose = at;
          T_ref_prior = r.unconfirmed_params.cast<double>();
          second_look = true;
          continue;
        }
      }
      return Ok{};
    }
    // T_live_prior = T_live_ref T_ref_prior: the relative pose to the prior's reference.
    const iclk::SE3<double> T_live_ref = r.params.cast<double>();
    out.T_live_ref = T_live_ref * T_ref_prior;
    in_world(r.params, r.covariance, out.T_W_C, out.covariance);
    // Again while the answer turned by more than kRefineMinDeg from where the reference was
    // rendered, and its final residual is within the bound (set_refinement_scope).
    if (!(geo::rotation_angle(Eigen::Quaterniond(T_live_ref.R)) * (180.0 / 3.14159265358979323846) > kRefineMinDeg)) break;
    if (!(r.residual_final <= refine_max_residual_)) break;
    ref_pose = out.T_W_C;
    T_ref_prior = out.T_live_ref;
  }
  if (out.second_look) out.reason = "converged at a second look (a reference rendered at the first answer)";
  return Ok{};
}

geo::CameraModel pinhole_of(const geo::CameraModel& camera) {
  geo::CameraModel c = camera;
  c.model = geo::DistortionModel::None;
  c.k = {};
  return c;
}

ImageU8 undistort(ImageView<const std::uint8_t> image, const geo::CameraModel& camera) {
  ImageU8 out(image.width, image.height, image.channels, 0);
  for (int v = 0; v < image.height; ++v)
    for (int u = 0; u < image.width; ++u) {
      // The pinhole pixel (u, v) sees the ray (x, y, 1); find where the real camera saw it.
      const Eigen::Vector3d ray((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0);
      Eigen::Vector2d px;
      if (!camera.project<double>(ray, px)) continue;
      const double x = px.x(), y = px.y();
      if (!(x >= 0 && y >= 0 && x <= image.width - 1 && y <= image.height - 1)) continue;
      const int x0 = std::min(static_cast<int>(x), image.width - 2), y0 = std::min(static_cast<int>(y), image.height - 2);
      const double fx = x - x0, fy = y - y0;
      for (int c = 0; c < image.channels; ++c) {
        const double a = image.at(x0, y0, c), b = image.at(x0 + 1, y0, c);
        const double d = image.at(x0, y0 + 1, c), e = image.at(x0 + 1, y0 + 1, c);
        out.at(u, v, c) = static_cast<std::uint8_t>(std::lround((1 - fy) * ((1 - fx) * a + fx * b) + fy * ((1 - fx) * d + fx * e)));
      }
    }
  return out;
}

}  // namespace terralign::cli
