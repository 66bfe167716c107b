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

std::string Interval::text() const {
  if (std::isinf(hi)) return (lo_open ? "> " : ">= ") + geo::format_double(lo);
  if (std::isinf(lo)) return (hi_open ? "< " : "<= ") + geo::format_double(hi);
  return std::string("in ") + (lo_open ? "(" : "[") + geo::format_double(lo) + ", " + geo::format_double(hi) + (hi_open ? ")" : "]");
}

Result<double> Args::get_double_in(const std::string& key, double def, const Interval& in, const std::string& unit) const {
  const auto v = get_double(key, def);
  if (!has(key) || (v.ok() && in.contains(v.value()))) return v;
  return Error{"--" + key + " '" + get(key) + "' must be " + in.text() + (unit.empty() ? "" : " " + unit)};
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
  double tilt_deg = 0;
  TERRALIGN_TRY_ASSIGN(tilt_deg, args.get_double_in("tilt-prior", kDefaultTiltPriorDeg, {0, 10}, "degrees (0: no tilt prior)"));
  opt.tilt_prior_rad = tilt_deg * 3.14159265358979323846 / 180;
  TERRALIGN_TRY_ASSIGN(opt.altitude_prior_m, args.get_double_in("altitude-prior", 0.0, {0, 1000}, "m (0: no altitude prior)"));
  TERRALIGN_TRY_ASSIGN(opt.registration_floor_px,
                       args.get_double_in("registration-floor", opt.registration_floor_px, {0, 100}, "camera pixels"));
  TERRALIGN_TRY_ASSIGN(opt.registration_floor_per_residual_px,
                       args.get_double_in("registration-floor-per-residual", opt.registration_floor_per_residual_px, {0, 100},
                                          "camera pixels"));
  TERRALIGN_TRY_ASSIGN(opt.min_sharpness,
                       args.get_double_in("min-sharpness", 0.0, {-1000, 1000}, "(negative: no sharpness test)"));
  TERRALIGN_TRY_ASSIGN(opt.max_disagreement_px,
                       args.get_double_in("max-disagreement", 0.0, {-1000, 1000}, "working pixels (negative: no agreement test)"));
  TERRALIGN_TRY_ASSIGN(opt.agree_px, args.get_double_in("agree-px", 0.0, {0, 10}, "working pixels (0: each tracker's own)"));
  TERRALIGN_TRY_ASSIGN(opt.coarse_search_px, args.get_int("coarse-search", 0, -1, 16));
  TERRALIGN_TRY_ASSIGN(opt.min_step_px, args.get_double_in("min-step", 0.0, {-1, 10}, "working pixels (negative: none)"));
  return opt;
}

Result<Degradation> parse_degradation(const Args& args) {
  Degradation d;
  TERRALIGN_TRY_ASSIGN(d.blur, args.get_int("blur", 0, 0, 10));
  TERRALIGN_TRY_ASSIGN(d.noise, args.get_double_in("noise", 0.0, {0, 100}, "grey levels"));
  TERRALIGN_TRY_ASSIGN(d.exposure, args.get_double_in("exposure", 0.0, {0, 1, false, true}));
  return d;
}

Result<TrackFilterOptions> parse_track_filter(const Args& args) {
  TrackFilterOptions opt;
  TERRALIGN_TRY_ASSIGN(opt.accel_sigma, args.get_double_in("accel-sigma", opt.accel_sigma, {0, 100, true}, "m/s per root second"));
  TERRALIGN_TRY_ASSIGN(opt.gate, args.get_double_in("gate", opt.gate, {-INFINITY, 1e6}, "(negative: none)"));
  TERRALIGN_TRY_ASSIGN(opt.init_position_sigma, args.get_double_in("init-sigma", opt.init_position_sigma, {0, 1e5, true}, "m"));
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
  TERRALIGN_TRY_ASSIGN(r.max_residual, args.get_double_in("refine-max-residual", r.max_residual, {0, 100, true}, "(a final residual)"));
  TERRALIGN_TRY_ASSIGN(r.uniform_max_residual,
                       args.get_double_in("refine-uniform", r.uniform_max_residual, {0, 2}, "(a final residual)"));
  TERRALIGN_TRY_ASSIGN(r.second_look_max_disagreement,
                       args.get_double_in("second-look-max-disagreement", r.second_look_max_disagreement, {0, 1000, true}, "px"));
  const std::string look = args.get("second-look", kDefaultSecondLook ? "yes" : "no");
  const bool at_start = tracking && look == "start";  // off until the track's first frame turns it on
  if (!at_start && look != "yes" && look != "no")
    return Error{"--second-look '" + look + "' must be yes or no" + (tracking ? " (or start)" : "")};
  r.second_look = look == "yes";
  r.second_look_at_start = at_start;
  return r;
}

}  // namespace terralign::cli
