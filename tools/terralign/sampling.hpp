// Pose sampling for eval and dataset: the paper's protocol (a true pose with the whole
// footprint inside an area, a prior perturbed from it), reproducible on every platform.
#pragma once

#include <cstdint>
#include <vector>

#include <terralign/geo/camera.hpp>
#include <terralign/geo/image.hpp>
#include <terralign/geo/map.hpp>
#include <terralign/geo/pose.hpp>

namespace terralign::cli {

// SplitMix64: the same stream on every platform and standard library. Seeds one increment
// (0x9e37...) apart give the same stream shifted by one draw: derive a stream's seed with
// next() of another.
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
// altimeter_m > 0 models an altimeter (a barometer) that survives it too: the prior's map z is
// the truth's plus N(0, altimeter_m^2), from a third stream (its horizontal position and its
// rotation stay as above).
Result<std::vector<Sample>> sample_poses(const geo::Map& map, const geo::CameraModel& cam, const geo::Extent& area, int count,
                                         std::uint64_t seed, double lo, double hi, double tilt_deg,
                                         double imu_tilt_deg = 0, double prior_scale = 1, double altimeter_m = 0);

// An attitude reference's reading of the camera's rotation q_W_C: rotated about the world's
// two horizontal axes by N(0, sigma_deg^2) each (its roll and pitch error), heading exact.
Eigen::Quaterniond attitude_reading(const Eigen::Quaterniond& q_W_C, Rng& rng, double sigma_deg);

// `q`'s heading with `attitude`'s tilt: q's rotation error against the attitude, as a
// rotation vector in world axes, keeps only its vertical part.
Eigen::Quaterniond with_tilt_of(const Eigen::Quaterniond& q, const Eigen::Quaterniond& attitude);

// What a camera does to a frame that a render does not (flight's and eval's --blur, --noise,
// --exposure): a box blur of radius `blur` px (edges clamped), then a gain drawn from
// U[1 - exposure, 1 + exposure] for the frame, then N(0, noise^2) grey levels added to each
// channel value, rounded and clamped to 0..255. The draws come from `rng`, in that order.
struct Degradation {
  int blur = 0;          // px, 0..10
  double noise = 0;      // grey levels (of 255), >= 0
  double exposure = 0;   // [0, 1)
  bool any() const { return blur > 0 || noise > 0 || exposure > 0; }
};
void degrade(ImageU8& img, const Degradation& d, Rng& rng);

// A box blur of radius r px (the mean of the (2r+1)^2 pixels around, edges clamped, rounded);
// r <= 0 leaves the image as it is.
void box_blur(ImageU8& img, int r);

}  // namespace terralign::cli
