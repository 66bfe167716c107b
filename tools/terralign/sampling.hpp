// Pose sampling for eval and dataset: the paper's protocol (a true pose with the whole
// footprint inside an area, a prior perturbed from it), reproducible on every platform.
#pragma once

#include <cstdint>
#include <vector>

#include <terralign/geo/camera.hpp>
#include <terralign/geo/map.hpp>
#include <terralign/geo/pose.hpp>

namespace terralign::cli {

// SplitMix64: the same stream on every platform and standard library.
struct Rng {
  std::uint64_t s;
  std::uint64_t next();
  double uniform();  // [0, 1)
  double uniform(double a, double b) { return a + (b - a) * uniform(); }
  double normal();
  Eigen::Vector3d unit();  // uniform on the sphere
};

struct Sample {
  geo::Pose truth, prior;
  double altitude;  // above the terrain, metres
};

// `count` true poses whose whole footprint (corners and centre, on the terrain) lies in
// `area`: altitude above ground in [lo, hi], tilt off nadir up to tilt_deg in a random
// direction, any heading; each prior rotated about a random axis by U[0, 6] deg and moved by
// U[0, 0.13 x altitude] m in a random direction.
// imu_tilt_deg > 0 models an attitude reference that survives the GPS failure: the prior's
// rotation error about the world's two horizontal axes is replaced by N(0, imu_tilt_deg^2)
// each (its heading error, about the vertical, stays the protocol's). Those draws come from a
// second stream, so the true poses and the priors' positions are the protocol's.
// prior_scale shrinks (or widens) each prior's rotation angle and move by that factor, the
// same draws otherwise: the same true poses, priors on the same axes and directions (a
// tracking loop's prediction is far nearer than a failing GPS's); with imu_tilt_deg the tilt
// error stays the attitude reference's.
Result<std::vector<Sample>> sample_poses(const geo::Map& map, const geo::CameraModel& cam, const geo::Extent& area, int count,
                                         std::uint64_t seed, double lo, double hi, double tilt_deg,
                                         double imu_tilt_deg = 0, double prior_scale = 1);

// An attitude reference's reading of the camera's rotation q_W_C: rotated about the world's
// two horizontal axes by N(0, sigma_deg^2) each (its roll and pitch error), heading exact.
Eigen::Quaterniond attitude_reading(const Eigen::Quaterniond& q_W_C, Rng& rng, double sigma_deg);

// `q`'s heading with `attitude`'s tilt: q's rotation error against the attitude, as a
// rotation vector in world axes, keeps only its vertical part.
Eigen::Quaterniond with_tilt_of(const Eigen::Quaterniond& q, const Eigen::Quaterniond& attitude);

}  // namespace terralign::cli
