// terralign eval: the paper's evaluation protocol on rendered pairs.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>

#include <nlohmann/json.hpp>

#include <terralign/geo/file.hpp>
#include <terralign/geo/image_io.hpp>
#include <terralign/geo/number_text.hpp>
#include <terralign/geo/numeric.hpp>

#include "args.hpp"
#include "commands.hpp"
#include "common.hpp"
#include "localizer.hpp"
#include "sampling.hpp"

namespace terralign::cli {

Result<iclk::Robust> parse_robust(const std::string& s);

namespace {

constexpr double kPi = 3.14159265358979323846;

struct Errors {
  double epe_m, angle_deg, trans_m, epe_px;
  double tilt_deg;  // the part of angle_deg an attitude reference sees: between the two cameras' views of the map's up
  iclk::Vec3<double> shift_C;  // mean of T_est X - T_gt X over the reference points, live camera axes
};

// est and gt are T_live_ref; up_ref is the map's up in the reference camera's axes.
Errors errors(const iclk::SE3<double>& est, const iclk::SE3<double>& gt, const iclk::Vec3<double>& up_ref, const ImageF& depth,
              const geo::CameraModel& cam) {
  const iclk::Pinhole<double> K{cam.fx, cam.fy, cam.cx, cam.cy};
  double s3 = 0, s2 = 0;
  iclk::Vec3<double> shift = iclk::Vec3<double>::Zero();
  long n3 = 0, n2 = 0;
  for (int y = 0; y < depth.height(); y += 2)
    for (int x = 0; x < depth.width(); x += 2) {
      const double d = depth.at(x, y);
      if (!std::isfinite(d)) continue;
      const iclk::Vec3<double> X(d * (x - cam.cx) / cam.fx, d * (y - cam.cy) / cam.fy, d);
      const iclk::Vec3<double> d3 = est * X - gt * X;
      s3 += d3.norm();
      shift += d3;
      ++n3;
      double u1, v1, u2, v2;
      if (iclk::SE3DepthWarp<double>::apply(est, X, x, y, K, u1, v1) && iclk::SE3DepthWarp<double>::apply(gt, X, x, y, K, u2, v2)) {
        s2 += hypot_exact(u1 - u2, v1 - v2);
        ++n2;
      }
    }
  const Eigen::Matrix3d dR = gt.R * est.R.transpose();
  Errors e;
  e.epe_m = n3 ? s3 / static_cast<double>(n3) : NAN;
  e.epe_px = n2 ? s2 / static_cast<double>(n2) : NAN;
  e.shift_C = n3 ? iclk::Vec3<double>(shift / static_cast<double>(n3)) : iclk::Vec3<double>::Constant(NAN);
  e.angle_deg = geo::rotation_angle(Eigen::Quaterniond(dR)) * 180 / kPi;
  const iclk::Vec3<double> up_est = est.R * up_ref, up_gt = gt.R * up_ref;
  e.tilt_deg = atan2_portable(up_est.cross(up_gt).norm(), up_est.dot(up_gt)) * 180 / kPi;
  e.trans_m = (gt.t - dR * est.t).norm();
  return e;
}

nlohmann::json stats(std::vector<double> v) {
  if (v.empty()) return nullptr;
  std::sort(v.begin(), v.end());
  double s = 0, s2 = 0;
  for (double x : v) {
    s += x;
    s2 += x * x;
  }
  const double n = static_cast<double>(v.size()), mean = s / n;
  const double median = v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
  return {{"mean", mean}, {"std", std::sqrt(std::max(0.0, s2 / n - mean * mean))}, {"median", median},
          {"min", v.front()}, {"max", v.back()}};
}

struct Method {
  std::string name;
  int iterations;  // 0: init
  bool learned = false;
  std::vector<double> epe_m, angle, tilt, trans, epe_px, ms;
  std::vector<Eigen::Vector3d> position_error;  // estimated camera centre - true one, map x y z (east north up)
  std::vector<Eigen::Vector3d> ground_shift;    // mean displacement of the seen ground, estimate - truth, map axes
  std::vector<Eigen::Vector3d> truth_position;  // the true camera centre, map x y z
  std::vector<char> ok;  // reported converged
  std::vector<double> cost_init, cost_final, residual_init, residual_final, sharpness, disagreement;
  std::vector<char> second_look;                  // the learned tracker's second look confirmed the answer
  std::vector<double> second_look_disagreement;  // that look's measure (NaN: it did not run)
  std::vector<double> sigma_position, sigma_angle, residual_correlation;  // the covariance's (m, deg: root of its trace)
  // The answer's 6-DoF error against that covariance, e^T P^-1 e (track's NEES: world-axis
  // rotation and position error); NaN where no covariance (not converged).
  std::vector<double> nees;
  std::vector<Eigen::Matrix<double, 6, 6>> covariance;  // that covariance (--json: converged answers)
  std::vector<Eigen::Vector3d> rotation_error;          // world-axis rotation, estimate -> truth (rad, angle x axis)
  std::vector<int> iterations_used;  // LM iterations over all levels
  std::vector<const char*> reason;
  std::vector<int> layer;  // which of --ref-layer's answered (Localizer: the first that converged)
  int converged = 0;
};

// Red: the reference; green and blue: the query seen through T_live_ref (pixels of the
// reference warped into the query). Aligned images look grey; misaligned ones show fringes.
ImageU8 overlay(const ImageF& ref_grey, const ImageF& depth, const ImageF& query_grey, const iclk::SE3<double>& T,
                const geo::CameraModel& cam) {
  const iclk::Pinhole<double> K{cam.fx, cam.fy, cam.cx, cam.cy};
  ImageU8 img(ref_grey.width(), ref_grey.height(), 3, 0);
  for (int y = 0; y < img.height(); ++y)
    for (int x = 0; x < img.width(); ++x) {
      const double d = depth.at(x, y);
      const auto r8 = static_cast<std::uint8_t>(std::clamp(ref_grey.at(x, y) * 255.0f, 0.0f, 255.0f));
      img.at(x, y, 0) = r8;
      if (!std::isfinite(d)) continue;
      const iclk::Vec3<double> X(d * (x - cam.cx) / cam.fx, d * (y - cam.cy) / cam.fy, d);
      double u, v;
      if (!iclk::SE3DepthWarp<double>::apply(T, X, x, y, K, u, v)) continue;
      if (!(u >= 0 && v >= 0 && u <= img.width() - 1 && v <= img.height() - 1)) continue;
      const int x0 = std::min(static_cast<int>(u), img.width() - 2), y0 = std::min(static_cast<int>(v), img.height() - 2);
      const double fx = u - x0, fy = v - y0;
      const double q = (1 - fy) * ((1 - fx) * query_grey.at(x0, y0) + fx * query_grey.at(x0 + 1, y0)) +
                       fy * ((1 - fx) * query_grey.at(x0, y0 + 1) + fx * query_grey.at(x0 + 1, y0 + 1));
      const auto q8 = static_cast<std::uint8_t>(std::clamp(q * 255.0, 0.0, 255.0));
      img.at(x, y, 1) = q8;
      img.at(x, y, 2) = q8;
    }
  return img;
}

}  // namespace

int run_eval(const std::vector<std::string>& argv) {
  auto args = Args::parse(argv, {"map", "camera", "ref-layer", "query-layer", "count", "seed", "altitude", "tilt", "methods",
                                 "json", "overlays", "threads", "robust", "levels", "weights", "area",
                                 "min-sharpness", "max-disagreement", "agree-px", "coarse-search", "min-step", "input-scale", "nn-levels", "imu-tilt", "altimeter", "tilt-prior", "altitude-prior",
                                 "prior-scale", "refine", "refine-levels", "refine-max-residual", "refine-uniform", "second-look", "second-look-max-disagreement", "blur", "noise", "exposure"}, {});
  if (!args.ok()) return usage_error("eval", args.error());
  for (const char* k : {"map", "camera", "ref-layer", "query-layer", "count", "seed", "altitude"})
    if (!args->has(k)) return usage_error("eval", Error{std::string("missing required option --") + k});
  auto count = args->get_int("count", 0, 1, 100000);
  if (!count.ok()) return usage_error("eval", count.error());
  const std::string seed_text = args->get("seed");
  const auto seed_value = geo::parse_integer(seed_text);
  if (!seed_value.ok() || seed_value.value() < 0)
    return usage_error("eval", Error{"--seed '" + seed_text + "' must be an integer in [0, " +
                                     std::to_string(std::numeric_limits<long long>::max()) + "]"});
  const auto seed = static_cast<unsigned long long>(seed_value.value());
  const auto altitude = altitude_range(args.value(), {0, 0});
  if (!altitude.ok()) return usage_error("eval", altitude.error());
  const auto [lo, hi] = altitude.value();
  auto tilt = args->get_double_in("tilt", 0.0, {0, 60}, "degrees");
  if (!tilt.ok()) return usage_error("eval", tilt.error());
  auto threads = args->get_int("threads", 2, 1, 64);
  if (!threads.ok()) return usage_error("eval", threads.error());
  auto robust = parse_robust(args->get("robust", "none"));
  if (!robust.ok()) return usage_error("eval", robust.error());
  auto levels = args->get_int("levels", 4, 1, 6);
  if (!levels.ok()) return usage_error("eval", levels.error());
  auto imu_tilt = args->get_double_in("imu-tilt", 0.0, {0, 10}, "degrees (0: the protocol's prior rotation)");
  auto altimeter = args->get_double_in("altimeter", 0.0, {0, 1000}, "m (0: the protocol's prior position)");
  auto prior_scale = args->get_double_in("prior-scale", 1.0, {0, 4, true}, "(1: the protocol's priors)");
  for (const auto* r : {&imu_tilt, &altimeter, &prior_scale})
    if (!r->ok()) return usage_error("eval", r->error());
  auto topt = parse_tracker_options(args.value());
  if (!topt.ok()) return usage_error("eval", topt.error());
  auto refine = parse_refine(args.value());
  if (!refine.ok()) return usage_error("eval", refine.error());
  auto degradation = parse_degradation(args.value());
  if (!degradation.ok()) return usage_error("eval", degradation.error());
  // The learned tracker's working size and levels (as the firmware sets them): 0 keeps the
  // weight file's.
  LocalizerSizes sizes;
  auto input_scale = args->get_double_in("input-scale", 0.0, {0, 1}, "(0: the weight file's)");
  if (!input_scale.ok()) return usage_error("eval", input_scale.error());
  sizes.input_scale = input_scale.value();
  auto nn_levels = args->get_int("nn-levels", 0, 0, 6);
  if (!nn_levels.ok()) return usage_error("eval", nn_levels.error());
  sizes.levels = nn_levels.value();
  std::vector<Method> methods;
  {
    for (const std::string& m : split_commas(args->get("methods", "init,classic:20,classic:50"))) {
      if (m == "init") {
        methods.emplace_back();
        methods.back().name = m;
        methods.back().iterations = 0;
      } else if (m.rfind("classic:", 0) == 0 || m.rfind("nn:", 0) == 0) {
        const auto n = geo::parse_integer(m.substr(m.find(':') + 1));
        if (!n.ok() || n.value() < 1 || n.value() > 1000)
          return usage_error("eval", Error{"method '" + m + "': iterations must be an integer in [1, 1000]"});
        methods.emplace_back();
        methods.back().name = m;
        methods.back().iterations = static_cast<int>(n.value());
        methods.back().learned = m[0] == 'n';
      } else {
        return usage_error("eval", Error{"unknown method '" + m + "' (init, classic:N, nn:N)"});
      }
      // The table would show it twice and the JSON, keyed by name, once.
      for (std::size_t i = 0; i + 1 < methods.size(); ++i)
        if (methods[i].name == m) return usage_error("eval", Error{"method '" + m + "' is given twice"});
    }
  }

  auto map = geo::load_map(args->get("map"));
  if (!map.ok()) return fail(map.error());
  auto cam_in = geo::load_camera(args->get("camera"));
  if (!cam_in.ok()) return fail(cam_in.error());
  const geo::CameraModel cam = pinhole_of(cam_in.value());
  // --ref-layer A[,B,...]: the reference layers in order of preference (Localizer::create).
  const std::vector<std::string> ref_layers = split_commas(args->get("ref-layer"));
  for (const std::string& name : ref_layers)
    if (!map->find_layer(name))
      return fail(Error{"--ref-layer: no layer named '" + name + "' (layers: " + map->layer_names() + ")"});
  if (!map->find_layer(args->get("query-layer")))
    return fail(Error{"--query-layer: no layer named '" + args->get("query-layer") + "' (layers: " + map->layer_names() + ")"});
  {
    // The truth is the query layer's, over the same DEM: the answers are off it by what the
    // reference layer's registration and the query's disagree on (none where they are one
    // layer), and not by the DEM's error. The covariance counts that.
    const std::string query = args->get("query-layer");
    const double query_sigma = map->find_layer(query)->registration_sigma_m;
    for (const std::string& name : ref_layers) {
      geo::Layer& ref = *map->find_layer(name);
      ref.registration_sigma_m = name == query ? 0.0 : hypot_exact(ref.registration_sigma_m, query_sigma);
    }
    map->dem.vertical_sigma_m = 0;
  }
  const std::string overlays = args->get("overlays");
  if (!overlays.empty())
    if (auto st = ensure_dir(overlays); !st.ok()) return fail(st.error());
  // The JSON is written after every pose: a path it cannot take is refused before the first.
  if (args->has("json"))
    if (auto st = geo::check_writable(args->get("json")); !st.ok()) return fail(Error{"--json " + st.error().message});
  geo::Extent area = map->common_extent();
  if (args->has("area")) {
    const auto v = finite_numbers(args->get("area"), ',', 4);
    const geo::Extent a = v ? geo::Extent{(*v)[0], (*v)[1], (*v)[2], (*v)[3]} : geo::Extent{};
    if (a.empty())
      return usage_error("eval", Error{"--area '" + args->get("area") + "' must be MINX,MINY,MAXX,MAXY in map coordinates"});
    area = area.intersect(a);
    if (area.empty()) return fail(Error{"--area '" + args->get("area") + "' does not overlap the map"});
  }
  auto samples =
      sample_poses(map.value(), cam, area, count.value(), seed, lo, hi, tilt.value(), imu_tilt.value(), prior_scale.value(),
                   altimeter.value());
  if (!samples.ok()) return fail(samples.error());

  iclk::TrackerOptions opt = topt.value();
  // The altimeter's sigma holds the answers' altitude unless --altitude-prior says otherwise.
  if (altimeter.value() > 0 && !args->has("altitude-prior")) opt.altitude_prior_m = altimeter.value();
  opt.robust = robust.value();
  opt.levels = levels.value();
  auto loc = Localizer::create(map.value(), cam, ref_layers, opt, threads.value());
  if (!loc.ok()) return fail(loc.error());
  refine->apply(*loc.value());
  std::unique_ptr<Localizer> learned;
  if (std::any_of(methods.begin(), methods.end(), [](const Method& m) { return m.learned; })) {
    auto w = learned_weights(args.value());
    if (!w.ok()) return fail(w.error());
    // eval reports each answer's sharpness (--json; training/calibrate_sharpness.py reads it),
    // so its probe runs here whether or not the test is on (align and track skip it then).
    iclk::TrackerOptions lopt = opt;
    lopt.probe_px = iclk::DeepAligner::kProbePx;
    auto l = Localizer::create(map.value(), cam, ref_layers, lopt, threads.value(), &w.value(), sizes);
    if (!l.ok()) return fail(l.error());
    learned = std::move(l.value());
    refine->apply(*learned);
  }
  raster::RenderOptions ro;
  ro.threads = threads.value();
  auto query_renderer = raster::Renderer::create(map.value(), cam, ro);
  if (!query_renderer.ok()) return fail(query_renderer.error());
  auto query = query_renderer.value()->make_output({args->get("query-layer")});
  if (!query.ok()) return fail(query.error());
  ImageF ref_grey, query_grey;
  ImageF ref_depth;  // the metrics' reference: the classical (full-size) one rendered at the prior
  ImageU8 degraded;  // the query as the camera gives it, with --blur, --noise or --exposure

  int skipped = 0;
  for (std::size_t i = 0; i < samples->size(); ++i) {
    const Sample& s = samples.value()[i];
    if (auto st = query_renderer.value()->render(s.truth, query.value()); !st.ok()) {
      ++skipped;
      continue;
    }
    const ImageU8* live = &query->rgb[0];
    if (degradation->any()) {
      // Each sample's own stream, so that a sample's image does not depend on the others.
      Rng rng{Rng{(seed ^ 0x243f6a8885a308d3ULL) + i}.next()};
      degraded = query->rgb[0];
      degrade(degraded, degradation.value(), rng);
      live = &degraded;
    }
    const geo::Pose rel = s.truth.inverse() * s.prior;  // T_C1_Cref
    iclk::SE3<double> gt;
    gt.R = rel.R();
    gt.t = rel.t_W_C;
    // The metrics and the figures take the reference at the prior, rendered once a sample
    // before any method. Until session 87 they took the one a classical localisation left
    // behind, which a refinement pass that did not converge had rendered at its answer.
    if (!loc.value()->render_at(s.prior).ok()) {
      ++skipped;
      continue;
    }
    ref_depth = loc.value()->reference_depth();
    const bool figures = !overlays.empty() && i < 20;
    if (figures) {
      iclk::rgb_to_grey(loc.value()->reference().rgb[0].view(), ref_grey);
      iclk::rgb_to_grey(live->view(), query_grey);
    }
    for (auto& m : methods) {
      iclk::SE3<double> est = iclk::SE3<double>::identity();
      double ms = 0;
      if (m.iterations > 0) {
        Localizer& L = m.learned ? *learned : *loc.value();
        L.set_iterations(m.iterations);
        auto out = L.localize(live->view(), s.prior);
        if (!out.ok()) {
          std::fprintf(stderr, "terralign eval: sample %zu: %s\n", i, out.error().message.c_str());
          break;
        }
        est = out->T_live_ref;
        ms = out->ms_encoder + out->ms_pyramid + out->ms_jacobian + out->ms_iterations;
        m.converged += out->converged;
        m.ok.push_back(out->converged);
        m.cost_init.push_back(out->cost_init);
        m.cost_final.push_back(out->cost_final);
        m.residual_init.push_back(out->residual_init);
        m.residual_final.push_back(out->residual_final);
        m.sharpness.push_back(out->sharpness);
        m.disagreement.push_back(out->disagreement_px);
        m.second_look.push_back(out->second_look);
        m.second_look_disagreement.push_back(out->second_look_disagreement_px);
        // (no covariance where not converged: NaN, left out of the JSON)
        const Eigen::Matrix<double, 6, 6>& P = out->covariance;
        m.sigma_angle.push_back(out->converged ? std::sqrt(P.topLeftCorner<3, 3>().trace()) * 180.0 / kPi : NAN);
        m.sigma_position.push_back(out->converged ? std::sqrt(P.bottomRightCorner<3, 3>().trace()) : NAN);
        m.nees.push_back(out->converged ? nees_of(out->T_W_C, s.truth, P) : NAN);
        m.covariance.push_back(P);
        m.rotation_error.push_back(pose_error(out->T_W_C, s.truth).head<3>());
        m.residual_correlation.push_back(out->residual_correlation);
        m.iterations_used.push_back(out->iterations);
        m.reason.push_back(out->reason);
        m.layer.push_back(out->layer);
      } else {
        m.converged += 1;
        m.ok.push_back(1);
      }
      const Errors e = errors(est, gt, s.prior.R().transpose() * Eigen::Vector3d::UnitZ(), ref_depth, cam);
      m.epe_m.push_back(e.epe_m);
      m.angle.push_back(e.angle_deg);
      m.tilt.push_back(e.tilt_deg);
      m.trans.push_back(e.trans_m);
      m.epe_px.push_back(e.epe_px);
      m.ms.push_back(ms);
      // The estimate as a camera pose in the map: T_W_live = T_W_ref T_ref_live.
      const geo::Pose T_live_ref{Eigen::Quaterniond(est.R), est.t};
      m.position_error.push_back((s.prior * T_live_ref.inverse()).t_W_C - s.truth.t_W_C);
      m.ground_shift.push_back(s.truth.R() * e.shift_C);
      m.truth_position.push_back(s.truth.t_W_C);
      if (figures) {
        const std::string base = overlays + "/" + std::to_string(i) + "_";
        std::string safe = m.name;
        std::replace(safe.begin(), safe.end(), ':', '_');
        auto img = overlay(ref_grey, ref_depth, query_grey, est, cam);
        if (auto st = geo::save_png(base + safe + ".png", img.view()); !st.ok()) return fail(st.error());
        if (&m == &methods.front()) {
          auto truth_img = overlay(ref_grey, ref_depth, query_grey, gt, cam);
          if (auto st = geo::save_png(base + "truth.png", truth_img.view()); !st.ok()) return fail(st.error());
        }
      }
    }
    std::fprintf(stderr, "\r%zu/%zu", i + 1, samples->size());
  }
  std::fprintf(stderr, "\n");

  nlohmann::json j;
  j["count"] = count.value();
  j["seed"] = seed;
  j["map"] = args->get("map");
  j["ref_layer"] = args->get("ref-layer");
  j["query_layer"] = args->get("query-layer");
  j["altitude"] = {lo, hi};
  j["tilt_deg"] = tilt.value();
  j["degradation"] = {{"blur_px", degradation->blur}, {"noise", degradation->noise}, {"exposure", degradation->exposure}};
  j["skipped"] = skipped;
  std::printf("%s vs %s, %d poses, seed %llu, altitude %g-%g m, tilt <= %g deg\n\n", args->get("ref-layer").c_str(),
              args->get("query-layer").c_str(), count.value(), seed, lo, hi, tilt.value());
  std::printf("| method | 3-D EPE m (mean / median) | angle deg (mean / median) | trans m (mean / median) | 2-D EPE px (mean / median) | < 1 px | < 5 px | converged | converged and < 5 px | ms (mean / median) | NEES (mean / median) |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|\n");
  for (const auto& m : methods) {
    const double n = static_cast<double>(m.epe_px.size());
    int ok1 = 0, ok5 = 0, conv5 = 0;
    for (std::size_t k = 0; k < m.epe_px.size(); ++k) {
      ok1 += m.epe_px[k] < 1.0;
      ok5 += m.epe_px[k] < 5.0;
      conv5 += m.ok[k] && m.epe_px[k] < 5.0;
    }
    nlohmann::json mj;
    mj["epe_m"] = stats(m.epe_m);
    mj["angle_deg"] = stats(m.angle);
    mj["tilt_deg"] = stats(m.tilt);  // of angle_deg, roll and pitch together (the rest is heading)
    mj["trans_m"] = stats(m.trans);
    mj["epe_px"] = stats(m.epe_px);
    mj["success_rate"] = n > 0 ? ok1 / n : 0.0;
    mj["success_rate_5px"] = n > 0 ? ok5 / n : 0.0;
    mj["converged_fraction"] = n > 0 ? m.converged / n : 0.0;
    // How far "converged" can be trusted: the fraction of converged answers within 5 px.
    mj["converged_within_5px"] = m.converged > 0 ? conv5 / static_cast<double>(m.converged) : 0.0;
    // How far the converged answers' covariances can be trusted: NEES, 6 expected.
    std::vector<double> nees;
    for (double v : m.nees)
      if (std::isfinite(v)) nees.push_back(v);
    mj["nees"] = stats(nees);
    // ... and how often an answer lies inside its own 95 % ellipsoid (NEES under chi-square's
    // 95th percentile for 6 degrees of freedom, 12.592): 95 % where the covariance is honest.
    const auto inside = std::count_if(nees.begin(), nees.end(), [](double v) { return v < 12.592; });
    mj["nees_within_95"] = nees.empty() ? nlohmann::json(nullptr)
                                        : nlohmann::json(static_cast<double>(inside) / static_cast<double>(nees.size()));
    const auto t = stats(m.ms);
    mj["ms"] = t.is_null() ? nlohmann::json(nullptr) : nlohmann::json{{"mean", t["mean"]}, {"median", t["median"]}};
    // Per pose, for analysis: 2-D EPE, converged, the camera centre's error (map axes), the
    // costs behind the decision and the reported uncertainty.
    for (std::size_t k = 0; k < m.epe_px.size(); ++k) {
      const Eigen::Vector3d& dp = m.position_error[k];
      nlohmann::json sj = {{"epe_px", m.epe_px[k]}, {"epe_m", m.epe_m[k]}, {"angle_deg", m.angle[k]}, {"tilt_deg", m.tilt[k]},
                           {"converged", m.ok[k] != 0},
                           {"position_error_m", {dp.x(), dp.y(), dp.z()}}};
      const Eigen::Vector3d &g = m.ground_shift[k], &tp = m.truth_position[k];
      if (g.allFinite()) sj["ground_shift_m"] = {g.x(), g.y(), g.z()};
      sj["truth_position_m"] = {tp.x(), tp.y(), tp.z()};
      if (k < m.cost_final.size()) {
        sj["cost_init"] = m.cost_init[k];
        sj["cost_final"] = m.cost_final[k];
        sj["residual_init"] = m.residual_init[k];
        sj["residual_final"] = m.residual_final[k];
        sj["sharpness"] = m.sharpness[k];
        if (std::isfinite(m.disagreement[k])) sj["disagreement_px"] = m.disagreement[k];  // else the second start failed
        if (!std::isnan(m.second_look_disagreement[k])) {  // a second look ran (null: its second start failed)
          sj["second_look"] = m.second_look[k] != 0;
          sj["second_look_disagreement_px"] =
              std::isfinite(m.second_look_disagreement[k]) ? nlohmann::json(m.second_look_disagreement[k]) : nlohmann::json(nullptr);
        }
        if (std::isfinite(m.sigma_position[k])) {
          sj["sigma_position_m"] = m.sigma_position[k];
          sj["sigma_angle_deg"] = m.sigma_angle[k];
        }
        if (std::isfinite(m.nees[k])) {  // and what it is made of, for analysis
          sj["nees"] = m.nees[k];
          const Eigen::Matrix<double, 6, 6>& P = m.covariance[k];
          nlohmann::json rows = nlohmann::json::array();
          for (int r = 0; r < 6; ++r) rows.push_back({P(r, 0), P(r, 1), P(r, 2), P(r, 3), P(r, 4), P(r, 5)});
          sj["covariance"] = rows;
          const Eigen::Vector3d& dr = m.rotation_error[k];
          sj["rotation_error_rad"] = {dr.x(), dr.y(), dr.z()};
        }
        sj["residual_correlation"] = m.residual_correlation[k];
        sj["iterations"] = m.iterations_used[k];
        sj["reason"] = m.reason[k];
        sj["layer"] = ref_layers[static_cast<std::size_t>(m.layer[k])];
      }
      mj["samples"].push_back(sj);
    }
    j["methods"][m.name] = mj;
    if (n == 0) continue;
    auto mm = [&](const char* key) {
      char buf[64];
      std::snprintf(buf, sizeof buf, "%.3f / %.3f", mj[key]["mean"].get<double>(), mj[key]["median"].get<double>());
      return std::string(buf);
    };
    char nees_cell[64] = "-";  // the init method, or no converged answer
    if (!mj["nees"].is_null())
      std::snprintf(nees_cell, sizeof nees_cell, "%.1f / %.1f", mj["nees"]["mean"].get<double>(),
                    mj["nees"]["median"].get<double>());
    std::printf("| %s | %s | %s | %s | %s | %.1f %% | %.1f %% | %.1f %% | %.1f %% | %.1f / %.1f | %s |\n", m.name.c_str(),
                mm("epe_m").c_str(), mm("angle_deg").c_str(), mm("trans_m").c_str(), mm("epe_px").c_str(), 100.0 * ok1 / n,
                100.0 * ok5 / n, 100.0 * m.converged / n, m.iterations ? 100.0 * conv5 / std::max(m.converged, 1) : 0.0,
                t["mean"].get<double>(), t["median"].get<double>(), nees_cell);
  }
  // With several reference layers: which answered each converged alignment.
  if (ref_layers.size() > 1) {
    std::printf("\n");
    for (const auto& m : methods) {
      if (m.iterations == 0) continue;
      std::vector<int> by(ref_layers.size(), 0);
      int none = 0;
      for (std::size_t k = 0; k < m.layer.size(); ++k) m.ok[k] ? ++by[static_cast<std::size_t>(m.layer[k])] : ++none;
      std::printf("%s, converged answers by layer:", m.name.c_str());
      for (std::size_t l = 0; l < by.size(); ++l) {
        std::printf(" %s %d,", ref_layers[l].c_str(), by[l]);
        j["methods"][m.name]["answered_by"][ref_layers[l]] = by[l];
      }
      std::printf(" none %d\n", none);
    }
  }
  if (args->has("json")) {
    const std::string text = j.dump(2) + "\n";
    if (auto st = geo::write_file_atomic(args->get("json"), text.data(), text.size()); !st.ok()) return fail(st.error());
  }
  return 0;
}

}  // namespace terralign::cli
