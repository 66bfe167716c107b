// Command-line arguments: "--key value" pairs and "--flag" switches after a command name.
#pragma once

#include <array>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <terralign/geo/result.hpp>
#include <terralign/iclk/tracker.hpp>
#include <terralign/nn/weights.hpp>

#include "localizer.hpp"
#include "sampling.hpp"
#include "track_filter.hpp"

namespace terralign::cli {

// Where a number option may lie: from lo to hi, each end closed unless said open; an infinite
// end is no bound.
struct Interval {
  double lo, hi;
  bool lo_open = false, hi_open = false;
  bool contains(double v) const { return (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi); }
  std::string text() const;  // "in [0, 60]", "in (0, 1)", "> 0", "<= 1000000"
};

class Args {
 public:
  // `flags` take no value; every other option takes one. Unknown options are errors.
  static Result<Args> parse(const std::vector<std::string>& argv, const std::set<std::string>& options,
                            const std::set<std::string>& flags);
  bool has(const std::string& key) const { return values_.count(key) != 0; }
  std::string get(const std::string& key, const std::string& def = "") const;
  Result<std::string> required(const std::string& key) const;
  Result<int> get_int(const std::string& key, int def, int lo, int hi) const;
  Result<double> get_double(const std::string& key, double def) const;
  // A number in `in`, `def` without the option; an error names the option, its text and the
  // interval, then `unit` ("--tilt '70' must be in [0, 60] degrees").
  Result<double> get_double_in(const std::string& key, double def, const Interval& in, const std::string& unit = "") const;

 private:
  std::map<std::string, std::string> values_;
};

// --altitude LO:HI, the sampled poses' heights above the ground in metres (eval, dataset):
// `def` without the option; an error names the text unless 0 < LO <= HI, both finite.
Result<std::array<double, 2>> altitude_range(const Args& args, std::array<double, 2> def);

// Exactly `count` finite numbers of `text` split at `separator` (geo::parse_numbers' rules), or
// none: the caller's error names its option or line and what it expects.
std::optional<std::vector<double>> finite_numbers(const std::string& text, char separator, std::size_t count);

// "a,b,c" -> {"a", "b", "c"} (empty fields kept, so callers can refuse them by name).
std::vector<std::string> split_commas(const std::string& s);

// Creates a folder if it is missing; an error names the path if it cannot, or if a file is
// in the way.
Status ensure_dir(const std::string& dir);

// The learned tracker's weights: --weights FILE, else the shipped file (CMake's
// TERRALIGN_SHIPPED_WEIGHTS, weights/deep_iclk_s16w64.tlw, in the source tree the program was
// built from).
Result<nn::WeightFile> learned_weights(const Args& args);

// The tracker's options that align, eval and track share, on iclk::TrackerOptions' defaults
// (a command that does not accept one keeps its default):
// --tilt-prior DEG: the standard deviation of the prior's tilt (roll and pitch: an attitude
//   reference's where there is one, else the prior pose's own), in [0, 10] degrees
//   (tilt_prior_rad, radians); default kDefaultTiltPriorDeg; 0: none.
// --altitude-prior M: the standard deviation of the prior's altitude (the camera centre's
//   map z: an altimeter's where there is one, else the prior pose's own), in [0, 1000] m
//   (altitude_prior_m); default 0: none.
// --registration-floor PX: the smallest registration error the covariance admits, in camera
//   pixels, [0, 100] (registration_floor_px). The default suits a map of the image's own
//   year; across years of change the error is larger (README, tracking a flight).
// --registration-floor-per-residual PX: the floor is at least PX camera pixels per unit of
//   the final residual, [0, 100] (registration_floor_per_residual_px; default 1; 0: none).
// --min-sharpness S: the learned tracker's sharpness test (min_sharpness), in [-1000, 1000];
//   0 (the default): the weight file's '# min-sharpness'; negative: no test.
// --max-disagreement PX: the agreement test (max_disagreement_px), in [-1000, 1000] of each
//   tracker's working pixels; 0 (the default): each tracker's own (kClassicMaxDisagreementPx,
//   the weight file's '# max-disagreement-px', or with an attitude reference's tilt prior its
//   '# max-disagreement-px-attitude': iclk::DeepAligner::max_disagreement); negative: no test.
// --agree-px PX: where that test's second start begins (agree_px), in [0, 10] working pixels
//   in u and v; 0 (the default): each tracker's own (kClassicAgreePx, the weight file's
//   '# agree-px'). A threshold holds only for the start it was calibrated with.
// --coarse-search PX: the search before the coarsest level (coarse_search_px), in [-1, 16]
//   coarsest-level pixels; 0 (the default): each tracker's own (kClassicCoarseSearchPx,
//   iclk::DeepAligner::kCoarseSearchPx); -1: none.
// --min-step PX: the finest level stops once a step moves the image by less (min_step_px),
//   in [-1, 10] working pixels; 0 (the default): each tracker's own (none for the classical,
//   iclk::DeepAligner::kMinStepPx for the learned); negative: none.
Result<iclk::TrackerOptions> parse_tracker_options(const Args& args);
// The tilt prior the commands assume when --tilt-prior is not given: a rough pose's roll and
// pitch are good to 3 degrees (1 sigma per axis). The evaluation protocol turns its priors by
// U[0, 6] degrees about a random axis, 2 degrees RMS about each horizontal one; across years
// the learned tracker otherwise trades a tilt error for a shift (2009 -> 2020, seed 11, every
// answer counted: 63.0 % within 5 px without, 75.0 / 76.5 / 76.5 / 73.5 % with 1.5 / 2 / 3 / 5
// degrees; docs/history.md, session 33).
constexpr double kDefaultTiltPriorDeg = 3.0;
// --blur R (px, 0..10), --noise SIGMA (grey levels, [0, 100]), --exposure E ([0, 1)): what a
// camera does to a rendered frame (Degradation); none by default.
Result<Degradation> parse_degradation(const Args& args);
// --refine N: the re-rendered refinement's passes (Localizer::set_refinement), 0..5;
// --refine-levels L (1..6) and --refine-max-residual R ((0, 100]): a pass's levels and the
// final residual above which none runs (Localizer::set_refinement_scope; default the
// tracker's: learned 3 and none, classical 1 and 1.0; `--refine-levels 1 --refine-max-residual
// 1` is the learned tracker's before session 58);
// --refine-uniform R: the learned tracker's passes without the M-estimator below a final
// residual of R (Localizer::set_uniform_refinement; 0..2, default off).
struct Refinement {
  int passes = kDefaultRefinePasses;
  int levels = 0;           // 0: the localizer's (its tracker's default)
  double max_residual = 0;  // 0: the localizer's
  double uniform_max_residual = kRefineUniformOff;
  bool second_look = kDefaultSecondLook;  // --second-look yes|no
  // --second-look start (track only): a second look only while the track starts, until two
  // answers have converged (cmd_track turns it on and off a frame).
  bool second_look_at_start = false;
  double second_look_max_disagreement = kDefaultSecondLookMaxDisagreement;  // --second-look-max-disagreement PX
  void apply(Localizer& loc) const {
    loc.set_refinement(passes);
    loc.set_second_look(second_look, second_look_max_disagreement);
    loc.set_refinement_scope(levels > 0 ? levels : loc.refinement_levels(),
                             max_residual > 0 ? max_residual : loc.refinement_max_residual());
    loc.set_uniform_refinement(uniform_max_residual);
  }
};
// `tracking`: track's, where --second-look may also be start.
Result<Refinement> parse_refine(const Args& args, bool tracking = false);

// The tracking filter's options (track): --accel-sigma A, the velocity's random walk in m/s per
// root second, (0, 100]; --gate D2, at most 1e6 (negative: none); --init-sigma M, the position
// sigma of --init, (0, 1e5] m; TrackFilterOptions' defaults otherwise.
Result<TrackFilterOptions> parse_track_filter(const Args& args);

}  // namespace terralign::cli
