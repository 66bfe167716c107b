#include "sampling.hpp"

#include <algorithm>
#include <cmath>

#include <terralign/geo/number_text.hpp>
#include <terralign/geo/numeric.hpp>

namespace terralign::cli {

namespace {
constexpr double kPi = 3.14159265358979323846;
}  // namespace

std::uint64_t Rng::next() {
  std::uint64_t z = (s += 0x9e3779b97f4a7c15ull);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

double Rng::uniform() { return static_cast<double>(next() >> 11) * 0x1.0p-53; }

double Rng::normal() {
  const double u = std::max(uniform(), 1e-300), v = uniform();
  double sin_v, cos_v;
  sin_cos(2 * kPi * v, sin_v, cos_v);
  return std::sqrt(-2 * log_portable(u)) * cos_v;
}

Eigen::Vector3d Rng::unit() {
  const double z = uniform(-1, 1), phi = uniform(0, 2 * kPi), r = std::sqrt(1 - z * z);
  double sin_phi, cos_phi;
  sin_cos(phi, sin_phi, cos_phi);
  return {r * cos_phi, r * sin_phi, z};
}

namespace {

// The ground point seen along the camera ray through pixel (u, v), on the plane z = h.
bool ground_hit(const geo::Pose& T, const geo::CameraModel& cam, double u, double v, double h, Eigen::Vector3d& p) {
  const Eigen::Vector3d d = T.R() * Eigen::Vector3d((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0);
  if (!(d.z() < -1e-6)) return false;
  const double t = (h - T.t_W_C.z()) / d.z();
  p = T.t_W_C + t * d;
  return true;
}

}  // namespace

Result<std::vector<Sample>> sample_poses(const geo::Map& map, const geo::CameraModel& cam, const geo::Extent& e, int count,
                                         std::uint64_t seed, double lo, double hi, double tilt_deg,
                                         double imu_tilt_deg, double prior_scale, double altimeter_m) {
  Rng rng{seed};
  Rng imu{seed ^ 0x1e5a7c3b9d2f4601ULL};
  Rng baro{seed ^ 0x7b3d9e1f05a2c468ULL};
  std::vector<Sample> out;
  for (int i = 0; i < count; ++i) {
    bool placed = false;
    for (int attempt = 0; attempt < 2000 && !placed; ++attempt) {
      const double alt = rng.uniform(lo, hi), heading = rng.uniform(0, 360);
      const double tilt = rng.uniform(0, tilt_deg), tilt_dir = rng.uniform(0, 2 * kPi);
      const double x = rng.uniform(e.min_x, e.max_x), y = rng.uniform(e.min_y, e.max_y);
      const double ground = map.dem.height_at(x, y);
      if (!std::isfinite(ground)) continue;
      geo::Pose T = geo::pose_from_ypr({x, y, ground + alt}, heading, 0, 0);
      // Tilt off nadir by `tilt` about a horizontal axis at a random azimuth.
      double dir_sin, dir_cos;
      sin_cos(tilt_dir, dir_sin, dir_cos);
      T.q_W_C = geo::rotation_quaternion(Eigen::Vector3d(dir_cos, dir_sin, 0), tilt * kPi / 180) * T.q_W_C;
      bool inside = true;
      for (int k = 0; k < 5 && inside; ++k) {
        const double u = k == 4 ? cam.cx : (k & 1) * (cam.width - 1.0), v = k == 4 ? cam.cy : (k >> 1) * (cam.height - 1.0);
        Eigen::Vector3d p;
        inside = ground_hit(T, cam, u, v, ground, p) && e.contains(p.x(), p.y());
        if (inside) {
          const double hp = map.dem.height_at(p.x(), p.y());
          inside = std::isfinite(hp) && ground_hit(T, cam, u, v, hp, p) && e.contains(p.x(), p.y());
        }
      }
      if (!inside) continue;
      Sample s;
      s.truth = T;
      s.altitude = alt;
      // The prior: rotated about a random axis by U[0, 6] deg (in the camera frame), moved by
      // U[0, 0.13 alt] m in a random direction; both times prior_scale.
      const double angle = prior_scale * rng.uniform(0, 6) * kPi / 180;
      const Eigen::Vector3d raxis = rng.unit();
      const double len = prior_scale * rng.uniform(0, 0.13 * alt);
      const Eigen::Vector3d dir = rng.unit();
      s.prior.q_W_C = (T.q_W_C * geo::rotation_quaternion(raxis, angle)).normalized();
      s.prior.t_W_C = T.t_W_C + len * dir;
      if (imu_tilt_deg > 0) {
        // The error as a rotation vector in world axes: keep its vertical part (heading),
        // draw the horizontal ones (tilt) as the IMU's.
        Eigen::Vector3d phi = T.R() * (angle * raxis);
        phi.x() = imu.normal() * imu_tilt_deg * kPi / 180;
        phi.y() = imu.normal() * imu_tilt_deg * kPi / 180;
        s.prior.q_W_C = (geo::rotation_from_vector(phi) * T.q_W_C).normalized();
      }
      if (altimeter_m > 0) s.prior.t_W_C.z() = T.t_W_C.z() + baro.normal() * altimeter_m;
      out.push_back(s);
      placed = true;
    }
    if (!placed)
      return Error{"cannot place pose " + std::to_string(i) + ": no position in 2000 tries shows only the map at altitude " +
                   geo::format_double(lo) + ".." + geo::format_double(hi) + " m (map too small for the altitude?)"};
  }
  return out;
}

Eigen::Quaterniond attitude_reading(const Eigen::Quaterniond& q_W_C, Rng& rng, double sigma_deg) {
  const double sx = rng.normal() * sigma_deg * kPi / 180, sy = rng.normal() * sigma_deg * kPi / 180;
  return (geo::rotation_from_vector({sx, sy, 0}) * q_W_C).normalized();
}

Eigen::Quaterniond with_tilt_of(const Eigen::Quaterniond& q, const Eigen::Quaterniond& attitude) {
  const Eigen::Vector3d err = geo::rotation_vector(q * attitude.conjugate());  // world axes: attitude -> q
  return (geo::rotation_from_vector({0, 0, err.z()}) * attitude).normalized();
}

void box_blur(ImageU8& img, int r) {
  if (r <= 0) return;
  const ImageU8 src = img;
  for (int y = 0; y < img.height(); ++y)
    for (int x = 0; x < img.width(); ++x)
      for (int c = 0; c < img.channels(); ++c) {
        int s = 0, n = 0;
        for (int dy = -r; dy <= r; ++dy)
          for (int dx = -r; dx <= r; ++dx) {
            const int xx = std::clamp(x + dx, 0, img.width() - 1), yy = std::clamp(y + dy, 0, img.height() - 1);
            s += src.at(xx, yy, c);
            ++n;
          }
        img.at(x, y, c) = static_cast<std::uint8_t>((s + n / 2) / n);
      }
}

void degrade(ImageU8& img, const Degradation& d, Rng& rng) {
  box_blur(img, d.blur);
  const double gain = 1.0 + d.exposure * (2 * rng.uniform() - 1);
  for (auto& v : img.pixels())
    v = static_cast<std::uint8_t>(std::clamp(std::lround(v * gain + d.noise * rng.normal()), 0L, 255L));
}

}  // namespace terralign::cli
