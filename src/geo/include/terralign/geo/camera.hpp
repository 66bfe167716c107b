// Camera models: pinhole intrinsics with radial-tangential (OpenCV / Brown: k1 k2 p1 p2 k3)
// or equidistant (Kannala-Brandt / OpenCV fisheye: k1..k4) distortion.
//
// Pixel centres are at integer coordinates; (cx, cy) is the principal point in that
// convention. A point p_C = (X, Y, Z) in the camera frame (x right, y down, z forward)
// projects to normalised (x, y) = (X/Z, Y/Z), is distorted to (xd, yd), and lands at
// (u, v) = (fx xd + cx, fy yd + cy).
#pragma once

#include <array>
#include <cmath>
#include <string>

#include <Eigen/Core>

#include <terralign/geo/numeric.hpp>
#include <terralign/geo/result.hpp>

namespace terralign::geo {

enum class DistortionModel { None, RadTan, Equidistant };
const char* to_string(DistortionModel m);

struct CameraModel {
  int width = 0, height = 0;     // pixels
  double fx = 0, fy = 0;         // focal lengths, pixels
  double cx = 0, cy = 0;         // principal point, pixels (pixel centres at integers)
  DistortionModel model = DistortionModel::None;
  std::array<double, 5> k{};     // radtan: k1 k2 p1 p2 k3; equidistant: k1 k2 k3 k4 (k[4] = 0)

  // The distortion in normalised coordinates, with its 2x2 Jacobian if J is non-null.
  template <class S>
  Eigen::Matrix<S, 2, 1> distort(const Eigen::Matrix<S, 2, 1>& xn,
                                 Eigen::Matrix<S, 2, 2>* J = nullptr) const;

  // Projects a camera-frame point. Returns false (pixel untouched) if Z <= 0 or not finite.
  // d_pixel_d_point, if non-null, receives d(u, v) / d(X, Y, Z).
  template <class S>
  bool project(const Eigen::Matrix<S, 3, 1>& p_C, Eigen::Matrix<S, 2, 1>& pixel,
               Eigen::Matrix<S, 2, 3>* d_pixel_d_point = nullptr) const;

  // The ray (x, y, 1) through a pixel: Newton iterations on the distortion until the step
  // is below 1e-12 in normalised units (1e-9 px at f = 1000 px), 30 at most. Returns false
  // where the distortion cannot be inverted (outside its monotonic domain).
  bool unproject(const Eigen::Vector2d& pixel, Eigen::Vector3d& ray) const;

  // The model for an image scaled by `s` (0.5 for each pyramid level down), keeping pixel
  // centres at integers: u' = s (u + 0.5) - 0.5, so cx' = s (cx + 0.5) - 0.5.
  CameraModel scaled(double s, int new_width, int new_height) const;

  // Checks sizes, focal lengths, finiteness; the message names the value and the range.
  Status validate(const std::string& where) const;
};

// Reads {"width","height","fx","fy","cx","cy","distortion": {"model": "none"} |
// {"model": "radtan", "k1","k2","p1","p2","k3"} | {"model": "equidistant", "k1".."k4"}}.
// "distortion" may be omitted (none); absent coefficients are zero.
Result<CameraModel> load_camera(const std::string& path);
Result<CameraModel> parse_camera(const std::string& json_text, const std::string& name);
std::string camera_to_json(const CameraModel& cam);

// ---- implementation of the templates ----

template <class S>
Eigen::Matrix<S, 2, 1> CameraModel::distort(const Eigen::Matrix<S, 2, 1>& xn,
                                            Eigen::Matrix<S, 2, 2>* J) const {
  const S x = xn.x(), y = xn.y();
  switch (model) {
    case DistortionModel::None:
      if (J) J->setIdentity();
      return xn;
    case DistortionModel::RadTan: {
      const S k1 = S(k[0]), k2 = S(k[1]), p1 = S(k[2]), p2 = S(k[3]), k3 = S(k[4]);
      const S r2 = x * x + y * y;
      const S rad = S(1) + r2 * (k1 + r2 * (k2 + r2 * k3));
      if (J) {
        const S drad = k1 + r2 * (S(2) * k2 + S(3) * k3 * r2);  // d rad / d r2
        (*J)(0, 0) = rad + S(2) * x * x * drad + S(2) * p1 * y + S(6) * p2 * x;
        (*J)(0, 1) = S(2) * x * y * drad + S(2) * p1 * x + S(2) * p2 * y;
        (*J)(1, 0) = (*J)(0, 1);
        (*J)(1, 1) = rad + S(2) * y * y * drad + S(6) * p1 * y + S(2) * p2 * x;
      }
      return {x * rad + S(2) * p1 * x * y + p2 * (r2 + S(2) * x * x),
              y * rad + p1 * (r2 + S(2) * y * y) + S(2) * p2 * x * y};
    }
    case DistortionModel::Equidistant: {
      const S k1 = S(k[0]), k2 = S(k[1]), k3 = S(k[2]), k4 = S(k[3]);
      const S r2 = x * x + y * y;
      const S r = std::sqrt(r2);
      if (r < S(1e-8)) {  // s = theta_d / r -> 1, its derivative -> 0
        if (J) J->setIdentity();
        return xn;
      }
      const S th = static_cast<S>(atan2_portable(static_cast<double>(r), 1.0)), th2 = th * th;  // atan(r)
      const S poly = S(1) + th2 * (k1 + th2 * (k2 + th2 * (k3 + th2 * k4)));
      const S thd = th * poly;
      const S s = thd / r;
      if (J) {
        const S dthd_dth = S(1) + th2 * (S(3) * k1 + th2 * (S(5) * k2 + th2 * (S(7) * k3 + th2 * S(9) * k4)));
        const S dth_dr = S(1) / (S(1) + r2);
        const S ds_dr = (dthd_dth * dth_dr * r - thd) / r2;
        (*J)(0, 0) = s + ds_dr * x * x / r;
        (*J)(0, 1) = ds_dr * x * y / r;
        (*J)(1, 0) = (*J)(0, 1);
        (*J)(1, 1) = s + ds_dr * y * y / r;
      }
      return {s * x, s * y};
    }
  }
  // No model of the enum's (a value cast from outside it): no distortion, as None.
  if (J) J->setIdentity();
  return xn;
}

template <class S>
bool CameraModel::project(const Eigen::Matrix<S, 3, 1>& p_C, Eigen::Matrix<S, 2, 1>& pixel,
                          Eigen::Matrix<S, 2, 3>* d_pixel_d_point) const {
  const S z = p_C.z();
  if (!(z > S(0)) || !std::isfinite(z) || !std::isfinite(p_C.x()) || !std::isfinite(p_C.y())) return false;
  const S iz = S(1) / z;
  const Eigen::Matrix<S, 2, 1> xn(p_C.x() * iz, p_C.y() * iz);
  Eigen::Matrix<S, 2, 2> Jd;
  const Eigen::Matrix<S, 2, 1> xd = distort(xn, d_pixel_d_point ? &Jd : nullptr);
  pixel = {S(fx) * xd.x() + S(cx), S(fy) * xd.y() + S(cy)};
  if (d_pixel_d_point) {
    Eigen::Matrix<S, 2, 3> dxn_dp;
    dxn_dp << iz, S(0), -xn.x() * iz, S(0), iz, -xn.y() * iz;
    Eigen::Matrix<S, 2, 2> F;
    F << S(fx), S(0), S(0), S(fy);
    *d_pixel_d_point = F * Jd * dxn_dp;
  }
  return true;
}

}  // namespace terralign::geo
