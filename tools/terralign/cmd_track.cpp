// terralign track: localise every frame of a flight, each from the previous result.
#include <algorithm>
#include <array>
#include <chrono>
#include <numeric>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <optional>
#include <sstream>

#include <nlohmann/json.hpp>

#include <terralign/geo/file.hpp>
#include <terralign/geo/number_text.hpp>

#include "args.hpp"
#include "commands.hpp"
#include "common.hpp"
#include "localizer.hpp"
#include "sampling.hpp"

namespace terralign::cli {

Result<ImageU8> load_rgb(const std::string& path);

namespace {

constexpr double kPi = 3.14159265358979323846;

struct Frame {
  double t;
  std::string path;
  int line;
};

Result<std::vector<Frame>> read_list(const std::string& list) {
  std::ifstream in(list);
  if (!in) return Error{list + ": cannot open the image list"};
  const auto slash = list.find_last_of('/');
  const std::string dir = slash == std::string::npos ? "" : list.substr(0, slash + 1);
  std::vector<Frame> frames;
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    if (line.find_first_not_of(" \t\r") == std::string::npos || line[0] == '#') continue;
    std::istringstream s(line);
    std::string time, rest;
    Frame f{0, "", n};
    const bool two = (s >> time >> f.path) && !(s >> rest);
    const auto t = geo::parse_double(time);
    if (!two || !t.ok() || !std::isfinite(t.value()))
      return Error{list + ":" + std::to_string(n) + ": expected 'timestamp image-path', got '" + line + "'"};
    f.t = t.value();
    if (f.path[0] != '/') f.path = dir + f.path;
    frames.push_back(f);
  }
  if (frames.empty()) return Error{list + ": no frames"};
  return frames;
}

// A sensor's reading: up to four values, and "path:line: " for errors about them.
struct Reading {
  std::array<double, 4> v{};
  std::string where;
};

// A sensor's readings, one `timestamp v1 .. vn` a line (n values, finite), one for each frame
// at the frame's time (within 1 microsecond), each passing `check` (a Status) as it is read;
// `what` names them in errors, `fields` is the line's form.
template <class Check>
Result<std::vector<Reading>> read_readings(const std::string& path, const std::vector<Frame>& frames, const std::string& what,
                                           const std::string& fields, int n, Check check) {
  std::ifstream in(path);
  if (!in) return Error{path + ": cannot open the " + what};
  std::vector<Reading> out;
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    if (line.find_first_not_of(" \t\r") == std::string::npos || line[0] == '#') continue;
    const std::string where = path + ":" + std::to_string(number) + ": ";
    const auto values = finite_numbers(line, ' ', static_cast<std::size_t>(n) + 1);
    if (!values)
      return Error{where + "expected '" + fields + "' (finite numbers), got '" + line + "'"};
    const double t = (*values)[0];
    Reading r{{}, where};
    std::copy(values->begin() + 1, values->end(), r.v.begin());
    if (auto st = check(r); !st.ok()) return st.error();
    if (out.size() >= frames.size())
      return Error{where + "more " + what + " than the " + std::to_string(frames.size()) + " frames"};
    const Frame& f = frames[out.size()];
    if (!(std::abs(t - f.t) <= 1e-6 * std::max(1.0, std::abs(f.t))))
      return Error{where + "timestamp " + geo::format_double(t) + " is not frame " + std::to_string(out.size()) + "'s (" +
                   geo::format_double(f.t) + ")"};
    out.push_back(r);
  }
  if (out.size() != frames.size())
    return Error{path + ": " + std::to_string(out.size()) + " " + what + " for " + std::to_string(frames.size()) + " frames"};
  return out;
}

// An attitude reference's rotations, one `timestamp qw qx qy qz` a line, one for each frame.
Result<std::vector<Eigen::Quaterniond>> read_attitude(const std::string& path, const std::vector<Frame>& frames) {
  auto quaternion = [](const Reading& r) { return Eigen::Quaterniond(r.v[0], r.v[1], r.v[2], r.v[3]); };
  TERRALIGN_TRY_ASSIGN(auto readings, read_readings(path, frames, "attitude readings", "timestamp qw qx qy qz", 4,
                                                    [&](const Reading& r) -> Status {
                                                      const double norm = quaternion(r).norm();
                                                      if (std::abs(norm - 1.0) <= 1e-3) return Ok{};
                                                      return Error{r.where + "quaternion norm " + geo::format_double(norm) +
                                                                   ", must be 1 (within 1e-3)"};
                                                    }));
  std::vector<Eigen::Quaterniond> out;
  for (const Reading& r : readings) out.push_back(quaternion(r).normalized());
  return out;
}

// An altimeter's readings, one `timestamp z` a line (the camera centre's map z, metres), one
// for each frame.
Result<std::vector<double>> read_altimeter(const std::string& path, const std::vector<Frame>& frames) {
  TERRALIGN_TRY_ASSIGN(auto readings, read_readings(path, frames, "altimeter readings", "timestamp z", 1,
                                                    [](const Reading&) -> Status { return Ok{}; }));
  std::vector<double> out;
  for (const Reading& r : readings) out.push_back(r.v[0]);
  return out;
}

// "vx vy vz" in metres a second along the map's axes, finite.
Result<Eigen::Vector3d> parse_velocity(const std::string& text) {
  const auto v = finite_numbers(text, ' ', 3);
  if (!v) return Error{"--init-velocity '" + text + "' must be three finite numbers 'vx vy vz' (m/s along the map's axes)"};
  return Eigen::Vector3d((*v)[0], (*v)[1], (*v)[2]);
}

// Constant velocity: extrapolate from the last two estimates by dt / dt_prev.
geo::Pose predict(const geo::Pose& prev, double t_prev, const geo::Pose& last, double t_last, double t) {
  const double s = (t - t_last) / std::max(t_last - t_prev, 1e-9);
  geo::Pose p;
  p.t_W_C = last.t_W_C + s * (last.t_W_C - prev.t_W_C);
  double angle;  // of the body-frame rotation per step
  Eigen::Vector3d axis;
  geo::angle_axis(prev.q_W_C.conjugate() * last.q_W_C, angle, axis);
  p.q_W_C = (last.q_W_C * geo::rotation_quaternion(axis, angle * s)).normalized();
  return p;
}

// ",x,y,z,qw,qx,qy,qz" of a pose: 0.1 mm and 1e-9 of the quaternion.
void append_pose_cells(std::string& csv, const geo::Pose& T) {
  char cells[160];
  std::snprintf(cells, sizeof cells, ",%.4f,%.4f,%.4f,%.9f,%.9f,%.9f,%.9f", T.t_W_C.x(), T.t_W_C.y(), T.t_W_C.z(),
                T.q_W_C.w(), T.q_W_C.x(), T.q_W_C.y(), T.q_W_C.z());
  csv += cells;
}

}  // namespace

int run_track(const std::vector<std::string>& argv) {
  auto args = Args::parse(argv, {"map", "camera", "layer", "images", "init", "method", "out", "truth", "json", "iterations",
                                 "threads", "weights", "attitude", "altimeter", "tilt-prior", "altitude-prior", "init-velocity", "registration-floor",
                                 "registration-floor-per-residual",
                                 "filter", "accel-sigma", "gate", "init-sigma", "min-sharpness", "max-disagreement", "agree-px", "coarse-search", "min-step", "nn-levels", "refine", "refine-levels", "refine-max-residual", "refine-uniform", "second-look", "second-look-max-disagreement", "acquire", "restart-after", "restart-max-ratio"}, {});
  if (!args.ok()) return usage_error("track", args.error());
  for (const char* k : {"map", "camera", "layer", "images", "init"})
    if (!args->has(k)) return usage_error("track", Error{std::string("missing required option --") + k});
  const std::string method = args->get("method", "classic");
  if (method != "classic" && method != "nn") return usage_error("track", Error{"--method '" + method + "' must be classic or nn"});
  LocalizerSizes sizes;  // the learned tracker's levels: 0, the weight file's
  auto nn_levels = args->get_int("nn-levels", 0, 0, 6);
  if (!nn_levels.ok()) return usage_error("track", nn_levels.error());
  if (nn_levels.value() > 0 && method != "nn")
    return usage_error("track", Error{"--nn-levels sets the learned tracker's levels: it needs --method nn"});
  sizes.levels = nn_levels.value();
  // --filter kalman (the default; auto, its earlier name, is the same): the filter, with or
  // without an attitude reference. Without one its velocity moves more slowly
  // (TrackFilterOptions::kAccelSigmaWithoutAttitude), since the answers across many years drift
  // together over frames. Against extrapolating the last two answers (--filter none, the
  // default without an IMU until session 62), without an IMU across 11 years: 36 random
  // flights rendered after the rule was written lost 9 -> 5, and the README's lawnmower holds
  // (38.3 -> 39.4 m RMSE; docs/history.md, session 62).
  std::string filter_mode = args->get("filter", "kalman");
  if (filter_mode != "auto" && filter_mode != "kalman" && filter_mode != "none")
    return usage_error("track", Error{"--filter '" + filter_mode + "' must be kalman or none (or auto: kalman)"});
  if (filter_mode == "auto") filter_mode = "kalman";
  auto filter_options = parse_track_filter(args.value());
  if (!filter_options.ok()) return usage_error("track", filter_options.error());
  TrackFilterOptions fopt = filter_options.value();
  if (!args->has("attitude") && !args->has("accel-sigma")) fopt.accel_sigma = TrackFilterOptions::kAccelSigmaWithoutAttitude;
  if (filter_mode == "none" && (args->has("accel-sigma") || args->has("gate") || args->has("init-sigma")))
    return usage_error("track", Error{"--accel-sigma, --gate and --init-sigma set the filter: they need --filter kalman"});
  // --acquire yes (the default): until the track has a velocity (none given, and fewer than two
  // converged answers taken), an answer the agreement test alone failed starts it, with its
  // covariance scaled by how far the second start settled (LocalizeOutput::unconfirmed). A
  // track whose first frames fail the test otherwise waits where it started while the aircraft
  // flies on: so were all 6 of 36 random flights across 11 years with the IMU lost (2 with
  // it); of 36 more, rendered after the rule was written, 3 -> 1 with the IMU, 11 -> 8
  // without (docs/history.md, session 61).
  const std::string acquire_arg = args->get("acquire", "yes");
  if (acquire_arg != "yes" && acquire_arg != "no")
    return usage_error("track", Error{"--acquire '" + acquire_arg + "' must be yes or no"});
  // --restart-after N (default 3; 0: never): a track that has taken no answer for N frames
  // in a row starts again as it started (TrackStart): --acquire takes an unconfirmed answer,
  // which the gate still tests, and --second-look start looks again; but only an answer whose
  // disagreement is within --restart-max-ratio R (default 1.3) times the agreement test's
  // threshold. Without that bound (session 71's restart) the answers it took lay a median 37 m
  // off where coasting was 21 m off, and it did not pay over random flights; on seeds 21-24,
  // the 24 of 57 within 1.3x lay 18.2 m off against coasting's 19.7 m, the rest 40 m and more.
  // With both, over 192 fresh random flights across 11 years (seeds 25-32), lost 8 -> 6
  // without the IMU and 0 -> 1 with it, medians and means within 0.35 m, and the README's
  // lawnmower across 11 years 45.3 -> 39.4 m RMSE without the IMU, 123.6 -> 29.9 m with it
  // (docs/history.md, session 73).
  auto restart_after = args->get_int("restart-after", kDefaultRestartAfter, 0, 1000);
  if (!restart_after.ok()) return usage_error("track", restart_after.error());
  auto restart_max_ratio = args->get_double_in("restart-max-ratio", kDefaultRestartMaxRatio, {1, 1000});
  if (!restart_max_ratio.ok()) return usage_error("track", restart_max_ratio.error());
  auto iters = args->get_int("iterations", 20, 1, 1000);
  auto threads = args->get_int("threads", 2, 1, 64);
  if (!iters.ok()) return usage_error("track", iters.error());
  if (!threads.ok()) return usage_error("track", threads.error());
  // The CSV and the JSON are written after the whole flight: a path they cannot take is
  // refused before it.
  for (const char* k : {"out", "json"})
    if (args->has(k))
      if (auto st = geo::check_writable(args->get(k)); !st.ok()) return fail(Error{std::string("--") + k + " " + st.error().message});
  auto init = geo::parse_pose(args->get("init"));
  if (!init.ok()) return fail(Error{"--init: " + init.error().message});
  auto frames = read_list(args->get("images"));
  if (!frames.ok()) return fail(frames.error());
  std::optional<Eigen::Vector3d> init_velocity;
  if (args->has("init-velocity")) {
    auto v = parse_velocity(args->get("init-velocity"));
    if (!v.ok()) return usage_error("track", v.error());
    init_velocity = v.value();
  }
  const bool acquire = acquire_arg == "yes" && !init_velocity;  // a velocity given: nothing to acquire
  auto map = geo::load_map(args->get("map"));
  if (!map.ok()) return fail(map.error());
  auto cam_in = geo::load_camera(args->get("camera"));
  if (!cam_in.ok()) return fail(cam_in.error());
  const geo::CameraModel cam = pinhole_of(cam_in.value());
  auto topt = parse_tracker_options(args.value());
  if (!topt.ok()) return usage_error("track", topt.error());
  auto refine = parse_refine(args.value(), true);
  if (!refine.ok()) return usage_error("track", refine.error());
  std::vector<Eigen::Quaterniond> attitude;
  if (args->has("attitude")) {
    auto a = read_attitude(args->get("attitude"), frames.value());
    if (!a.ok()) return fail(a.error());
    attitude = std::move(a.value());
  }
  std::vector<double> altimeter;
  if (args->has("altimeter")) {
    if (!args->has("altitude-prior"))
      return usage_error("track", Error{"--altimeter needs --altitude-prior M (the altimeter's sigma, metres)"});
    auto a = read_altimeter(args->get("altimeter"), frames.value());
    if (!a.ok()) return fail(a.error());
    altimeter = std::move(a.value());
  }
  iclk::TrackerOptions opt = topt.value();
  opt.iterations = iters.value();
  std::optional<nn::WeightFile> weights;
  if (method == "nn") {
    auto w = learned_weights(args.value());
    if (!w.ok()) return fail(w.error());
    weights = std::move(w.value());
  }
  const std::vector<std::string> layers = split_commas(args->get("layer"));
  auto loc = Localizer::create(map.value(), cam, layers, opt, threads.value(), weights ? &*weights : nullptr, sizes);
  if (!loc.ok()) return fail(loc.error());
  refine->apply(*loc.value());
  std::vector<geo::Pose> truth;
  if (args->has("truth")) {
    std::ifstream in(args->get("truth"));
    if (!in) return fail(Error{args->get("truth") + ": cannot open the true poses"});
    std::string line;
    int n = 0;
    while (std::getline(in, line)) {
      ++n;
      if (line.empty() || line[0] == '#') continue;
      const auto sp = line.find(' ');
      auto p = geo::parse_pose(sp == std::string::npos ? "" : line.substr(sp + 1));
      if (!p.ok()) return fail(Error{args->get("truth") + ":" + std::to_string(n) + ": " + p.error().message});
      truth.push_back(p.value());
    }
    if (truth.size() != frames->size())
      return fail(Error{args->get("truth") + ": " + std::to_string(truth.size()) + " poses for " + std::to_string(frames->size()) + " frames"});
  }

  std::string csv = "timestamp,x,y,z,qw,qx,qy,qz,converged,reason,iterations,ms,lat,lon,height";
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c) csv += ",cov" + std::to_string(r) + std::to_string(c);
  // The aligner's own answer (empty where it did not converge) and, with the filter, the
  // squared Mahalanobis distance of its innovation that the gate tested.
  // The layer it aligned to (--layer A,B,...: the first that converged).
  csv += ",answer_x,answer_y,answer_z,answer_qw,answer_qx,answer_qy,answer_qz,gate_d2,layer\n";
  // Without the filter, the last two converged estimates (`known` of them so far, at most 2):
  // the velocity. With --init-velocity (a GPS's last fix has one) the start is the newest, at
  // the first frame's time, and a point one second before it on that velocity the other.
  geo::Pose last = init.value(), prev = init.value();
  double t_last = frames->front().t, t_prev = t_last;
  int known = 0;
  TrackStart start(restart_after.value());
  if (init_velocity) {
    prev.t_W_C -= *init_velocity;
    t_prev = t_last - 1;
    known = 2;
  }
  // The filter (--filter kalman, the default) predicts each frame's prior from the
  // start and every answer it took; without it (--filter none) the prior extrapolates the
  // last two.
  std::optional<TrackFilter> filter;
  if (filter_mode == "kalman")
    filter.emplace(init.value(), frames->front().t, init_velocity ? &*init_velocity : nullptr, fopt);
  int refused = 0, resets = 0, acquired = 0, restarted = 0;
  std::vector<double> pos_err, ang_err, nees, ms_all;
  double last_t = -INFINITY;
  const auto t_start = std::chrono::steady_clock::now();
  for (std::size_t i = 0; i < frames->size(); ++i) {
    const Frame& f = frames.value()[i];
    const bool in_order = f.t > last_t;
    if (filter && in_order) filter->predict(f.t);
    // With an attitude reference the start keeps the prediction's tilt when two converged
    // frames made it (starting from the IMU's instead: same-year RMSE 0.16 -> 0.31 m, across
    // a year 7.5 -> 8.1 m, docs/history.md, session 29), else takes the IMU's; the tilt prior holds the answer to
    // the IMU's either way.
    const auto predicted = [&] {
      geo::Pose p = filter ? filter->pose() : known == 2 ? predict(prev, t_prev, last, t_last, f.t) : last;
      if (!attitude.empty() && (filter ? filter->updates() : known) < 2) p.q_W_C = with_tilt_of(p.q_W_C, attitude[i]);
      return p;
    };
    const geo::Pose prior = predicted();
    // A frame whose answer is not taken reports the prediction, with the filter's covariance
    // (without the filter, none).
    geo::Pose estimate = prior;
    Eigen::Matrix<double, 6, 6> cov =
        filter ? filter->pose_covariance() : Eigen::Matrix<double, 6, 6>::Zero().eval();
    std::optional<geo::Pose> answer;  // the aligner's, where it converged or --acquire took it
    const std::string* answer_layer = nullptr;  // and the layer it aligned to
    double gate_d2 = NAN;
    bool ok = false;     // a converged answer was taken
    bool taken = false;  // an answer was taken: a converged one, or an unconfirmed one to start
    std::string reason;
    int iterations = 0;
    double ms = 0;
    const auto t0 = std::chrono::steady_clock::now();
    if (!in_order) {
      reason = "timestamp " + geo::format_double(f.t) + " does not follow " + geo::format_double(last_t);
    } else {
      auto img = load_rgb(f.path);
      if (!img.ok()) {
        reason = img.error().message;
      } else if (img->width() != cam.width || img->height() != cam.height) {
        reason = f.path + ": image is " + std::to_string(img->width()) + " x " + std::to_string(img->height()) +
                 ", the camera " + std::to_string(cam.width) + " x " + std::to_string(cam.height);
      } else {
        ImageU8 live = cam_in->model == geo::DistortionModel::None ? std::move(img.value()) : undistort(img->view(), cam_in.value());
        if (refine->second_look_at_start) loc.value()->set_second_look(start.starting(), refine->second_look_max_disagreement);
        auto out = loc.value()->localize(live.view(), prior, attitude.empty() ? nullptr : &attitude[i],
                                         altimeter.empty() ? NAN : altimeter[i]);
        if (!out.ok()) {
          reason = out.error().message;
        } else {
          ok = out->converged;
          reason = out->reason;
          iterations = out->iterations;
          // Starting, or starting again, an unconfirmed answer stands in for a converged one;
          // the frame still reports itself not converged. Starting again, only one whose second
          // start settled near it (--restart-max-ratio).
          const bool near = !start.again() || out->unconfirmed_scale <= restart_max_ratio.value();
          const bool unconfirmed = !ok && acquire && start.starting() && out->unconfirmed && near;
          const bool again = unconfirmed && start.again();
          if (!ok && acquire && out->unconfirmed && !near) {
            char d[128];
            std::snprintf(d, sizeof d, "; not taken to start the track again: its disagreement is %.3g x the threshold (at most %.3g)",
                          out->unconfirmed_scale, restart_max_ratio.value());
            reason += d;
          }
          const geo::Pose& T = ok ? out->T_W_C : out->T_W_C_unconfirmed;
          const Eigen::Matrix<double, 6, 6>& P = ok ? out->covariance : out->covariance_unconfirmed;
          taken = ok || unconfirmed;
          if (taken) {
            answer = T;
            answer_layer = &layers[static_cast<std::size_t>(out->layer)];
          }
          // The filter takes an answer its gate accepts. The frame reports the answer as it is,
          // not the fused pose: consecutive frames see nearly the same ground, so their errors
          // across years are one error, not independent ones (lag-one correlation 0.84-0.98
          // without an IMU, README "Tracking a flight"), and fused as independent they claimed
          // twice the precision they have (NEES 8.1 -> 15.5 across a year).
          if (taken && filter) {
            const TrackFilter::Update u = filter->update(T, P);
            gate_d2 = u.d2;
            if (u.reset) {
              ++resets;
              reason += "; the track starts again here: " + std::to_string(fopt.reset_after_refusals) +
                       " answers in a row too far from the prediction";
            } else if (!u.accepted) {
              ok = taken = false;
              ++refused;
              char d2[96];
              std::snprintf(d2, sizeof d2, " (squared Mahalanobis distance %.4g; the gate %.4g)", u.d2, fopt.gate);
              reason = std::string(u.why) + d2;
            }
          }
          if (taken) {
            estimate = T;
            cov = P;
          }
          if (taken && unconfirmed) {
            ++acquired;
            if (again) ++restarted;
            const std::string after = again ? " again after " + std::to_string(start.coasted()) + " frames without one" : "";
            char d[96];
            std::snprintf(d, sizeof d, " (the second start %.3g px away)", out->disagreement_px);
            reason += "; its answer taken unconfirmed to start the track" + after + d;
          }
        }
      }
      // The filter takes the altimeter's reading on a frame whose answer it did not take (a
      // taken answer already holds it), so the track's height and climb do not drift while it
      // coasts; the frame reports that prediction.
      if (filter && !taken && !altimeter.empty() && filter->update_height(altimeter[i], opt.altitude_prior_m)) {
        estimate = predicted();
        cov = filter->pose_covariance();
      }
      last_t = f.t;
    }
    ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    ms_all.push_back(ms);
    if (!ok) std::fprintf(stderr, "terralign track: frame %zu (t %.3f): not converged: %s\n", i, f.t, reason.c_str());
    // Without the filter, a converged estimate becomes the newest of the two the next
    // prediction extrapolates from. A failed frame changes neither: the track coasts at the
    // last velocity (dead reckoning) until a frame converges again, instead of waiting where
    // the aircraft was.
    // An estimate at the newest one's time (the first frame's, over a start given with
    // --init-velocity) replaces it instead of making a velocity over no time with it.
    start.frame(ok, taken);
    if (taken && !filter) {
      if (known > 0 && f.t > t_last) {
        prev = last;
        t_prev = t_last;
        known = 2;
      } else if (known == 0) {
        known = 1;
      }
      last = estimate;
      t_last = f.t;
    }
    if (!truth.empty()) {
      const geo::Pose& T = truth[i];
      const Eigen::Matrix<double, 6, 1> e = pose_error(estimate, T);  // world-frame rotation, position
      pos_err.push_back(e.tail<3>().norm());
      ang_err.push_back(e.head<3>().norm() * 180 / kPi);
      if (taken || filter) {  // every estimate that has a covariance
        const double v = nees_of(estimate, T, cov);
        if (std::isfinite(v)) nees.push_back(v);
      }
    }
    char row[512];
    std::snprintf(row, sizeof row, "%.6f", f.t);
    csv += row;
    append_pose_cells(csv, estimate);
    std::snprintf(row, sizeof row, ",%d,\"%s\",%d,%.2f", ok ? 1 : 0, reason.substr(0, 200).c_str(), iterations, ms);
    csv += row;
    auto g = map->crs.to_geodetic(estimate.t_W_C.x(), estimate.t_W_C.y(), estimate.t_W_C.z());
    char geo_txt[128];
    if (g.ok()) std::snprintf(geo_txt, sizeof geo_txt, ",%.9f,%.9f,%.4f", g->lat_deg, g->lon_deg, g->height);
    else std::snprintf(geo_txt, sizeof geo_txt, ",,,");
    csv += geo_txt;
    for (int r = 0; r < 6; ++r)
      for (int c = 0; c < 6; ++c) {
        char v[32];
        std::snprintf(v, sizeof v, ",%.6g", cov(r, c));
        csv += v;
      }
    if (answer) append_pose_cells(csv, *answer);
    else csv += ",,,,,,,";
    if (std::isfinite(gate_d2)) {
      std::snprintf(row, sizeof row, ",%.6g", gate_d2);
      csv += row;
    } else {
      csv += ",";
    }
    csv += ",";
    if (answer_layer) csv += *answer_layer;
    csv += "\n";
  }
  const double total_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  if (args->has("out")) {
    if (auto s = geo::write_file_atomic(args->get("out"), csv.data(), csv.size()); !s.ok()) return fail(s.error());
  } else {
    std::printf("%s", csv.c_str());
  }
  const double n = static_cast<double>(frames->size());
  nlohmann::json j;
  j["frames"] = frames->size();
  j["converged_fraction"] = start.converged() / n;
  j["filter"] = filter_mode;
  j["acquired"] = acquired;  // unconfirmed answers taken to start the track (--acquire)
  j["restarted"] = restarted;  // of them, those that started it again (--restart-after)
  if (filter) {
    j["refused"] = refused;
    j["resets"] = resets;
  }
  j["fps"] = n / total_s;
  std::vector<double> sorted_ms = ms_all;
  std::sort(sorted_ms.begin(), sorted_ms.end());
  j["ms"] = {{"mean", std::accumulate(ms_all.begin(), ms_all.end(), 0.0) / n}, {"median", sorted_ms[sorted_ms.size() / 2]}};
  if (!truth.empty()) {
    auto rmse = [](const std::vector<double>& v) {
      double s = 0;
      for (double x : v) s += x * x;
      return std::sqrt(s / static_cast<double>(v.size()));
    };
    j["position_rmse_m"] = rmse(pos_err);
    j["angle_rmse_deg"] = rmse(ang_err);
    j["position_max_m"] = *std::max_element(pos_err.begin(), pos_err.end());
    j["angle_max_deg"] = *std::max_element(ang_err.begin(), ang_err.end());
    j["position_error_m"] = pos_err;
    j["angle_error_deg"] = ang_err;
    if (!nees.empty()) {
      std::vector<double> s = nees;
      std::sort(s.begin(), s.end());
      j["nees_mean"] = std::accumulate(nees.begin(), nees.end(), 0.0) / static_cast<double>(nees.size());
      j["nees_median"] = s[s.size() / 2];
    } else {
      j["nees_mean"] = nullptr;
    }
  }
  const std::string text = j.dump(2) + "\n";
  if (args->has("json")) {
    if (auto s = geo::write_file_atomic(args->get("json"), text.data(), text.size()); !s.ok()) return fail(s.error());
  }
  nlohmann::json brief = j;
  brief.erase("position_error_m");
  brief.erase("angle_error_deg");
  std::fprintf(stderr, "%s\n", brief.dump(2).c_str());
  return 0;
}

}  // namespace terralign::cli
