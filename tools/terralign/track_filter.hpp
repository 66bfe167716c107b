// The tracking filter of `terralign track`: an error-state Kalman filter on the camera's pose,
// its velocity and its turn rate, which the aligner's answers update.
//
// Each frame the aligner starts from the filter's prediction and its answer, with the
// aligner's covariance, is a measurement of the pose. The filter weighs it against the
// prediction and gates it: an answer farther from the prediction than both their covariances
// allow (a chi-square test on the innovation) is refused and the track coasts on the motion
// model, as it does through a frame that did not converge. The estimate is then the fused
// pose and its covariance the filter's, which also covers the frames in between. An
// altimeter's reading (track --altimeter) updates its height on the frames whose answer it
// does not take (update_height).
//
// State: R_W_C, p (camera centre, map frame), v (m/s) and w (rad/s about the map's axes),
// constant velocity and constant turn rate between frames, white acceleration and angular
// acceleration as the process noise. The error state is [dtheta; dp; dv; dw], dtheta about
// the map's axes (R_true = Exp(dtheta) R), the order of the aligner's covariance
// (Localizer::covariance_in_world) and of track's NEES.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <terralign/geo/pose.hpp>

namespace terralign::cli {

struct TrackFilterOptions {
  // Process noise, continuous white acceleration: the velocity's random walk, m/s per
  // square root of a second (1: it drifts by 1 m/s in a second, 3 m/s in nine), and the turn
  // rate's, degrees/s per square root of a second.
  double accel_sigma = 1.0;
  double angular_accel_sigma_deg = 5.0;
  // `track`'s velocity random walk where no attitude reference comes with the frames (and no
  // --accel-sigma): across many years the answers drift together over frames, and a filter
  // whose velocity may move 1 m/s in a second takes that drift for motion (the README's
  // lawnmower across 11 years lost, 118.7 m RMSE); at 0.3 it holds it (39.4 m), and of 36
  // random straight flights it loses 3 where extrapolation loses 8 (docs/history.md, session 62).
  static constexpr double kAccelSigmaWithoutAttitude = 0.3;
  // The gate on the innovation's squared Mahalanobis distance: the chi-square quantile of 6
  // degrees of freedom at p = 0.999 (22.46): one right answer in a thousand refused where
  // both covariances are honest. Negative: no gate.
  double gate = 22.46;
  // The answer that would be the N-th refused in a row is taken as a new start instead
  // (reset()): a gate refuses the right answers of a track whose prediction took wrong ones,
  // and they agree with each other, not with it. 0: never.
  int reset_after_refusals = 2;
  // The start's uncertainty, per axis: a failing GPS's last fix (position, m), a rough
  // attitude (degrees), the horizontal and the vertical velocity (m/s; a given velocity has
  // `given_velocity_sigma`) and the turn rate (degrees/s).
  double init_position_sigma = 50.0;
  double init_rotation_sigma_deg = 5.0;
  double init_velocity_sigma = 30.0;
  double init_climb_sigma = 5.0;  // the vertical velocity: an aircraft's climb rate
  double given_velocity_sigma = 2.0;
  double init_rate_sigma_deg = 5.0;
};

class TrackFilter {
 public:
  using Mat6 = Eigen::Matrix<double, 6, 6>;
  using Mat12 = Eigen::Matrix<double, 12, 12>;

  // At `init` at time t0, with a velocity where one is known (else zero and
  // init_velocity_sigma).
  TrackFilter(const geo::Pose& init, double t0, const Eigen::Vector3d* velocity, const TrackFilterOptions& options);

  // Moves the state and covariance on to time t (nothing if t is not later than now).
  void predict(double t);

  struct Update {
    bool accepted = false;
    bool reset = false;  // taken as a new start (TrackFilterOptions::reset_after_refusals)
    double d2 = 0;  // the innovation's squared Mahalanobis distance
    const char* why = "";  // why refused
  };
  // Fuses a measured pose with its covariance ([dtheta; dp] in the map's axes) at the current
  // time, unless its covariance is not positive definite or the gate refuses it (or, the
  // N-th refused in a row, starts again at it).
  Update update(const geo::Pose& measured, const Mat6& covariance);

  // Fuses an altimeter's reading of the camera centre's map z with its sigma (m): a scalar
  // update, ungated (an altimeter does not fail with the GPS, and a track whose height has
  // drifted is what it corrects). Through the state's correlations it also corrects the climb
  // rate. `track` gives it the frames whose answer it does not take: a taken answer was
  // already held to the reading (the altitude prior), and fused twice it would claim twice the
  // precision. False, the state as it was, for a reading or sigma that is not finite or a
  // sigma not above 0.
  bool update_height(double z, double sigma);

  // Starts again at a measured pose with its covariance, the velocity and turn rate kept
  // with the start's uncertainty: where the prediction, not the answers, went wrong.
  void reset(const geo::Pose& measured, const Mat6& covariance);

  geo::Pose pose() const;
  Mat6 pose_covariance() const { return P_.topLeftCorner<6, 6>(); }
  const Eigen::Vector3d& velocity() const { return v_; }
  const Mat12& covariance() const { return P_; }
  int updates() const { return updates_; }
  double time() const { return t_; }

 private:
  // P: the pose's covariance, the velocity's and turn rate's of the start (TrackFilterOptions).
  void start_at(const Mat6& pose_covariance, bool velocity_given);

  TrackFilterOptions opt_;
  Eigen::Quaterniond q_;  // R_W_C
  Eigen::Vector3d p_, v_, w_;
  Mat12 P_;
  double t_;
  int updates_ = 0;
  int refused_in_row_ = 0;
};

// Whether a track is starting (`terralign track --acquire`, `--second-look start`): until two
// answers have converged, and again once `restart_after` frames in a row have taken no answer
// (0: never again). While it starts, an answer the agreement test alone failed may stand in
// for a converged one; started again, the filter's gate still tests it, and two refused in a
// row start the filter again (TrackFilterOptions::reset_after_refusals). A track whose
// prediction took one wrong answer otherwise coasts away on it while every later answer fails
// the agreement test (the README's lawnmower across 11 years with the IMU, session 70: 123.6 m
// RMSE, lost). Over random flights most answers a restart takes are wrong, but not those whose
// second start settled within 1.3x the agreement test's threshold, and `track` starts again
// after 3 frames only with one of those (docs/history.md, sessions 71 and 73).
constexpr int kDefaultRestartAfter = 3;         // track --restart-after
constexpr double kDefaultRestartMaxRatio = 1.3;  // track --restart-max-ratio
class TrackStart {
 public:
  explicit TrackStart(int restart_after) : restart_after_(restart_after) {}
  // Before a frame: whether it may start the track, and whether that is a start again.
  bool starting() const { return converged_ < 2 || again(); }
  bool again() const { return converged_ >= 2 && restart_after_ > 0 && coasted_ >= restart_after_; }
  // After it: whether its answer converged (and was taken), and whether any answer was taken.
  void frame(bool converged, bool taken) {
    if (converged) ++converged_;
    coasted_ = taken ? 0 : coasted_ + 1;
  }
  int converged() const { return converged_; }
  int coasted() const { return coasted_; }  // frames in a row without an answer taken

 private:
  int restart_after_;
  int converged_ = 0, coasted_ = 0;
};

}  // namespace terralign::cli
