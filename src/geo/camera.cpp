// The camera model's mathematics (dependency-free: part of terralign::geo_core); reading
// and writing camera files is camera_io.cpp.
#include <terralign/geo/camera.hpp>

#include <algorithm>
#include <cmath>

#include <Eigen/LU>

#include <terralign/geo/number_text.hpp>

namespace terralign::geo {

const char* to_string(DistortionModel m) {
  switch (m) {
    case DistortionModel::None: return "none";
    case DistortionModel::RadTan: return "radtan";
    case DistortionModel::Equidistant: return "equidistant";
  }
  return "?";
}

bool CameraModel::unproject(const Eigen::Vector2d& pixel, Eigen::Vector3d& ray) const {
  if (!pixel.allFinite()) return false;
  const Eigen::Vector2d xd((pixel.x() - cx) / fx, (pixel.y() - cy) / fy);
  Eigen::Vector2d x = xd;
  if (model != DistortionModel::None) {
    bool converged = false;
    for (int it = 0; it < 30; ++it) {
      Eigen::Matrix2d J = Eigen::Matrix2d::Identity();
      const Eigen::Vector2d r = distort<double>(x, &J) - xd;
      const double det = J.determinant();
      if (!(std::abs(det) > 1e-12)) return false;
      const Eigen::Vector2d step = J.inverse() * r;
      x -= step;
      if (!x.allFinite()) return false;
      if (step.norm() < 1e-12) {
        converged = true;
        break;
      }
    }
    if (!converged) return false;
    // Newton may land on another branch of a non-monotonic polynomial: check the residual.
    if ((distort<double>(x) - xd).norm() > 1e-9) return false;
  }
  ray = Eigen::Vector3d(x.x(), x.y(), 1.0);
  return true;
}

CameraModel CameraModel::scaled(double s, int new_width, int new_height) const {
  CameraModel c = *this;
  c.width = new_width;
  c.height = new_height;
  c.fx = fx * s;
  c.fy = fy * s;
  c.cx = s * (cx + 0.5) - 0.5;
  c.cy = s * (cy + 0.5) - 0.5;
  return c;
}

Status CameraModel::validate(const std::string& where) const {
  if (width <= 0 || height <= 0 || width > 32768 || height > 32768)
    return Error{where + ": image size " + std::to_string(width) + " x " + std::to_string(height) +
                 " is outside 1..32768"};
  const double vals[] = {fx, fy, cx, cy, k[0], k[1], k[2], k[3], k[4]};
  for (double v : vals)
    if (!std::isfinite(v)) return Error{where + ": camera parameter is " + format_double(v) + ", not finite"};
  if (!(fx > 0) || !(fy > 0))
    return Error{where + ": focal length fx = " + format_double(fx) + ", fy = " + format_double(fy) +
                 " must be > 0 pixels"};
  if (model != DistortionModel::None) {
    // A distortion that cannot be inverted even beside the principal point (where every
    // usable model is nearly the identity) describes no camera: say so here, with the file,
    // rather than as a renderer's "nowhere in the image".
    const double u = std::min(std::max(std::round(cx), 0.0), static_cast<double>(width - 1));
    const double v = std::min(std::max(std::round(cy), 0.0), static_cast<double>(height - 1));
    Eigen::Vector3d ray;
    if (!unproject(Eigen::Vector2d(u, v), ray)) {
      std::string ks;
      for (double kk : k) ks += (ks.empty() ? "" : ", ") + format_double(kk);
      return Error{where + ": the distortion (coefficients " + ks + ") cannot be inverted at pixel (" +
                   std::to_string(static_cast<long>(u)) + ", " + std::to_string(static_cast<long>(v)) +
                   "), the nearest the principal point"};
    }
  }
  return Ok{};
}

}  // namespace terralign::geo
