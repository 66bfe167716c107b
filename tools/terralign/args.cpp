#include "args.hpp"

#include "localizer.hpp"

#include <algorithm>
#include <cmath>
#include <sys/stat.h>

#include <terralign/geo/number_text.hpp>
#include <terralign/iclk/tracker.hpp>

namespace terralign::cli {

Result<Args> Args::parse(const std::vector<std::string>& argv, const std::set<std::string>& options,
                         const std::set<std::string>& flags) {
  Args a;
  for (std::size_t i = 0; i < argv.size(); ++i) {
    const std::string& tok = argv[i];
    if (tok.rfind("--", 0) != 0) return Error{"unexpected argument '" + tok + "'"};
    const std::string key = tok.substr(2);
    if (flags.count(key)) {
      a.values_[key] = "1";
    } else if (options.count(key)) {
      if (i + 1 >= argv.size()) return Error{"option --" + key + " needs a value"};
      a.values_[key] = argv[++i];
    } else {
      return Error{"unknown option --" + key};
    }
  }
  return a;
}

std::string Args::get(const std::string& key, const std::string& def) const {
  auto it = values_.find(key);
  return it == values_.end() ? def : it->second;
}

Result<std::string> Args::required(const std::string& key) const {
  auto it = values_.find(key);
  if (it == values_.end()) return Error{"missing required option --" + key};
  return it->second;
}

Result<int> Args::get_int(const std::string& key, int def, int lo, int hi) const {
  if (!has(key)) return def;
  const std::string s = get(key);
  const auto v = geo::parse_integer(s);
  if (!v.ok() || v.value() < lo || v.value() > hi)
    return Error{"--" + key + " '" + s + "' must be an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]"};
  return static_cast<int>(v.value());
}

Result<double> Args::get_double(const std::string& key, double def) const {
  if (!has(key)) return def;
  const std::string s = get(key);
  const auto v = geo::parse_double(s);
  if (!v.ok() || !std::isfinite(v.value())) return Error{"--" + key + " '" + s + "' must be a finite number"};
  return v.value();
}

std::optional<std::vector<double>> finite_numbers(const std::string& text, char separator, std::size_t count) {
  auto v = geo::parse_numbers(text, separator);
  if (!v.ok() || v->size() != count || !std::all_of(v->begin(), v->end(), [](double x) { return std::isfinite(x); }))
    return std::nullopt;
  return std::move(v.value());
}

Result<std::array<double, 2>> altitude_range(const Args& args, std::array<double, 2> def) {
  if (!args.has("altitude")) return def;
  const std::string text = args.get("altitude");
  const auto v = finite_numbers(text, ':', 2);
  if (!v || !((*v)[0] > 0) || !((*v)[1] >= (*v)[0]))
    return Error{"--altitude '" + text + "' must be LO:HI metres with 0 < LO <= HI"};
  return std::array<double, 2>{(*v)[0], (*v)[1]};
}

std::vector<std::string> split_commas(const std::string& s) {
  std::vector<std::string> out;
  std::size_t a = 0;
  while (a <= s.size()) {
    const std::size_t b = s.find(',', a);
    out.push_back(s.substr(a, b == std::string::npos ? std::string::npos : b - a));
    if (b == std::string::npos) break;
    a = b + 1;
  }
  return out;
}

Status ensure_dir(const std::string& dir) {
  struct stat st {};
  if (::stat(dir.c_str(), &st) == 0) {
    if (!S_ISDIR(st.st_mode)) return Error{dir + ": exists and is not a folder"};
    return Ok{};
  }
  if (::mkdir(dir.c_str(), 0755) != 0) return Error{dir + ": cannot create the output folder"};
  return Ok{};
}

Result<nn::WeightFile> learned_weights(const Args& args) {
  const std::string path = args.get("weights", TERRALIGN_DEFAULT_WEIGHTS);
  auto w = nn::read_weights(path);
  if (!w.ok()) return Error{"the learned tracker's weights: " + w.error().message};
  return w;
}

Result<iclk::TrackerOptions> parse_tracker_options(const Args& args) {
  iclk::TrackerOptions opt;
  auto tilt = args.get_double("tilt-prior", kDefaultTiltPriorDeg);
  if (!tilt.ok() || !(tilt.value() >= 0 && tilt.value() <= 10))
    return Error{"--tilt-prior '" + args.get("tilt-prior") + "' must be in [0, 10] degrees (0: no tilt prior)"};
  opt.tilt_prior_rad = tilt.value() * 3.14159265358979323846 / 180;
  auto altitude = args.get_double("altitude-prior", 0.0);
  if (!altitude.ok() || !(altitude.value() >= 0 && altitude.value() <= 1000))
    return Error{"--altitude-prior '" + args.get("altitude-prior") + "' must be in [0, 1000] m (0: no altitude prior)"};
  opt.altitude_prior_m = altitude.value();
  auto floor_px = args.get_double("registration-floor", opt.registration_floor_px);
  if (!floor_px.ok() || !(floor_px.value() >= 0 && floor_px.value() <= 100))
    return Error{"--registration-floor '" + args.get("registration-floor") + "' must be in [0, 100] camera pixels"};
  opt.registration_floor_px = floor_px.value();
  auto per_residual = args.get_double("registration-floor-per-residual", opt.registration_floor_per_residual_px);
  if (!per_residual.ok() || !(per_residual.value() >= 0 && per_residual.value() <= 100))
    return Error{"--registration-floor-per-residual '" + args.get("registration-floor-per-residual") +
                 "' must be in [0, 100] camera pixels"};
  opt.registration_floor_per_residual_px = per_residual.value();
  auto sharp = args.get_double("min-sharpness", 0.0);
  if (!sharp.ok() || !(std::abs(sharp.value()) <= 1000))
    return Error{"--min-sharpness '" + args.get("min-sharpness") + "' must be in [-1000, 1000] (negative: no sharpness test)"};
  opt.min_sharpness = sharp.value();
  auto agree = args.get_double("max-disagreement", 0.0);
  if (!agree.ok() || !(std::abs(agree.value()) <= 1000))
    return Error{"--max-disagreement '" + args.get("max-disagreement") +
                 "' must be in [-1000, 1000] working pixels (negative: no agreement test)"};
  opt.max_disagreement_px = agree.value();
  auto agree_px = args.get_double("agree-px", 0.0);
  if (!agree_px.ok() || !(agree_px.value() >= 0 && agree_px.value() <= 10))
    return Error{"--agree-px '" + args.get("agree-px") + "' must be in [0, 10] working pixels (0: each tracker's own)"};
  opt.agree_px = agree_px.value();
  TERRALIGN_TRY_ASSIGN(opt.coarse_search_px, args.get_int("coarse-search", 0, -1, 16));
  auto min_step = args.get_double("min-step", 0.0);
  if (!min_step.ok() || !(min_step.value() >= -1 && min_step.value() <= 10))
    return Error{"--min-step '" + args.get("min-step") + "' must be in [-1, 10] working pixels (negative: none)"};
  opt.min_step_px = min_step.value();
  return opt;
}

Result<Degradation> parse_degradation(const Args& args) {
  Degradation d;
  TERRALIGN_TRY_ASSIGN(d.blur, args.get_int("blur", 0, 0, 10));
  auto noise = args.get_double("noise", 0.0);
  if (!noise.ok() || !(noise.value() >= 0 && noise.value() <= 100))
    return Error{"--noise '" + args.get("noise") + "' must be in [0, 100] grey levels"};
  d.noise = noise.value();
  auto exposure = args.get_double("exposure", 0.0);
  if (!exposure.ok() || !(exposure.value() >= 0 && exposure.value() < 1))
    return Error{"--exposure '" + args.get("exposure") + "' must be in [0, 1)"};
  d.exposure = exposure.value();
  return d;
}

Result<TrackFilterOptions> parse_track_filter(const Args& args) {
  TrackFilterOptions opt;
  auto accel = args.get_double("accel-sigma", opt.accel_sigma);
  if (!accel.ok()) return accel.error();
  if (!(accel.value() > 0 && accel.value() <= 100))
    return Error{"--accel-sigma " + args.get("accel-sigma") + " must be in (0, 100] m/s per root second"};
  opt.accel_sigma = accel.value();
  auto gate = args.get_double("gate", opt.gate);
  if (!gate.ok()) return gate.error();
  if (!(gate.value() <= 1e6)) return Error{"--gate " + args.get("gate") + " must be at most 1e6 (negative: none)"};
  opt.gate = gate.value();
  auto init_sigma = args.get_double("init-sigma", opt.init_position_sigma);
  if (!init_sigma.ok()) return init_sigma.error();
  if (!(init_sigma.value() > 0 && init_sigma.value() <= 1e5))
    return Error{"--init-sigma " + args.get("init-sigma") + " must be in (0, 1e5] m"};
  opt.init_position_sigma = init_sigma.value();
  return opt;
}

Result<Refinement> parse_refine(const Args& args, bool tracking) {
  Refinement r;
  auto n = args.get_int("refine", kDefaultRefinePasses, 0, 5);
  if (!n.ok()) return Error{"--refine '" + args.get("refine") + "' must be 0 to 5 re-rendered passes"};
  r.passes = n.value();
  if (args.has("refine-levels")) {
    auto l = args.get_int("refine-levels", 0, 1, 6);
    if (!l.ok()) return Error{"--refine-levels '" + args.get("refine-levels") + "' must be 1 to 6 levels"};
    r.levels = l.value();
  }
  if (args.has("refine-max-residual")) {
    auto m = args.get_double("refine-max-residual", 0.0);
    if (!m.ok() || !(m.value() > 0 && m.value() <= 100))
      return Error{"--refine-max-residual '" + args.get("refine-max-residual") + "' must be a final residual in (0, 100]"};
    r.max_residual = m.value();
  }
  if (args.has("refine-uniform")) {
    auto u = args.get_double("refine-uniform", 0.0);
    if (!u.ok() || !(u.value() >= 0 && u.value() <= 2))
      return Error{"--refine-uniform '" + args.get("refine-uniform") + "' must be a final residual in [0, 2]"};
    r.uniform_max_residual = u.value();
  }
  if (args.has("second-look-max-disagreement")) {
    auto m = args.get_double("second-look-max-disagreement", 0.0);
    if (!m.ok() || !(m.value() > 0 && m.value() <= 1000))
      return Error{"--second-look-max-disagreement '" + args.get("second-look-max-disagreement") +
                   "' must be in (0, 1000] px"};
    r.second_look_max_disagreement = m.value();
  }
  const std::string look = args.get("second-look", kDefaultSecondLook ? "yes" : "no");
  const bool at_start = tracking && look == "start";  // off until the track's first frame turns it on
  if (!at_start && look != "yes" && look != "no")
    return Error{"--second-look '" + look + "' must be yes or no" + (tracking ? " (or start)" : "")};
  r.second_look = look == "yes";
  r.second_look_at_start = at_start;
  return r;
}

}  // namespace terralign::cli
