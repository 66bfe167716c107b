// Poses: text, rotations from angles and mounts (dependency-free: part of
// terralign::geo_core); geodetic frames and OpenSfM files are pose_io.cpp.
#include <terralign/geo/pose.hpp>

#include <cmath>
#include <sstream>
#include <vector>

#include <terralign/geo/number_text.hpp>
#include <terralign/geo/numeric.hpp>

namespace terralign::geo {
namespace {
constexpr double kDeg = 3.14159265358979323846 / 180.0;

Eigen::Matrix3d rot_x(double a) { return rotation_matrix(Eigen::Vector3d::UnitX(), a); }
Eigen::Matrix3d rot_y(double a) { return rotation_matrix(Eigen::Vector3d::UnitY(), a); }
Eigen::Matrix3d rot_z(double a) { return rotation_matrix(Eigen::Vector3d::UnitZ(), a); }
}  // namespace

Eigen::Matrix3d rotation_matrix(const Eigen::Vector3d& axis, double angle) {
  double s, c;
  sin_cos(angle, s, c);
  const Eigen::Vector3d sin_axis = s * axis, cos1_axis = (1.0 - c) * axis;
  Eigen::Matrix3d R;
  double t = cos1_axis.x() * axis.y();
  R(0, 1) = t - sin_axis.z();
  R(1, 0) = t + sin_axis.z();
  t = cos1_axis.x() * axis.z();
  R(0, 2) = t + sin_axis.y();
  R(2, 0) = t - sin_axis.y();
  t = cos1_axis.y() * axis.z();
  R(1, 2) = t - sin_axis.x();
  R(2, 1) = t + sin_axis.x();
  for (int k = 0; k < 3; ++k) R(k, k) = cos1_axis[k] * axis[k] + c;
  return R;
}

Eigen::Quaterniond rotation_quaternion(const Eigen::Vector3d& axis, double angle) {
  double s, c;
  sin_cos(0.5 * angle, s, c);
  const Eigen::Vector3d v = s * axis;
  return Eigen::Quaterniond(c, v.x(), v.y(), v.z());
}

void angle_axis(const Eigen::Quaterniond& q, double& angle, Eigen::Vector3d& axis) {
  double n = q.vec().norm();
  if (n == 0) {
    angle = 0;
    axis = Eigen::Vector3d::UnitX();
    return;
  }
  angle = 2.0 * atan2_portable(n, std::abs(q.w()));
  if (q.w() < 0) n = -n;
  axis = q.vec() / n;
}

double rotation_angle(const Eigen::Quaterniond& q) {
  double angle;
  Eigen::Vector3d axis;
  angle_axis(q, angle, axis);
  return angle;
}

Eigen::Vector3d rotation_vector(const Eigen::Quaterniond& q) {
  double angle;
  Eigen::Vector3d axis;
  angle_axis(q, angle, axis);
  return angle * axis;
}

Eigen::Quaterniond rotation_from_vector(const Eigen::Vector3d& v) {
  const double a = v.norm();
  return a > 0 ? rotation_quaternion(v / a, a) : Eigen::Quaterniond::Identity();
}

Pose pose_from_rotation(const Eigen::Vector3d& t, const Eigen::Matrix3d& R) {
  Pose p;
  p.q_W_C = Eigen::Quaterniond(R).normalized();
  p.t_W_C = t;
  return p;
}

Result<Pose> parse_pose(const std::string& text) {
  std::istringstream in(text);
  double v[7];
  std::string tok;
  for (int i = 0; i < 7; ++i) {
    if (!(in >> tok))
      return Error{"pose '" + text + "' has " + std::to_string(i) + " numbers, needs 7 (x y z qw qx qy qz)"};
    auto num = parse_double(tok);
    if (!num.ok()) return Error{"pose '" + text + "': " + num.error().message};
    if (!std::isfinite(num.value()))
      return Error{"pose '" + text + "': value " + std::to_string(i + 1) + " is " + tok + ", not finite"};
    v[i] = num.value();
  }
  if (in >> tok) return Error{"pose '" + text + "' has more than 7 numbers ('" + tok + "')"};
  Eigen::Quaterniond q(v[3], v[4], v[5], v[6]);
  const double n = q.norm();
  if (std::abs(n - 1.0) > 1e-3)
    return Error{"pose '" + text + "': quaternion norm is " + format_double(n) +
                 ", must be 1 (within 1e-3); order is qw qx qy qz"};
  Pose p;
  p.q_W_C = q.normalized();
  p.t_W_C = Eigen::Vector3d(v[0], v[1], v[2]);
  return p;
}

std::string format_pose(const Pose& p) {
  const double v[7] = {p.t_W_C.x(), p.t_W_C.y(), p.t_W_C.z(), p.q_W_C.w(),
                       p.q_W_C.x(), p.q_W_C.y(), p.q_W_C.z()};
  std::string s;
  for (int i = 0; i < 7; ++i) s += (i ? " " : "") + format_double(v[i]);
  return s;
}

Eigen::Matrix3d nadir_mount() { return tilted_mount(0.0); }

Eigen::Matrix3d tilted_mount(double tilt_deg) {
  // Nadir: camera x = body y (right), camera y = -body x (image down = backwards),
  // camera z = body z (down). Tilting forward rotates the camera about its own x axis.
  Eigen::Matrix3d nadir;
  nadir << 0, -1, 0,
           1, 0, 0,
           0, 0, 1;
  return nadir * rot_x(tilt_deg * kDeg);
}

Pose pose_from_ypr(const Eigen::Vector3d& position, double yaw_deg, double pitch_deg,
                   double roll_deg, const Eigen::Matrix3d& R_B_C) {
  // Columns: NED axes expressed in the map frame (x east, y north, z up).
  Eigen::Matrix3d R_W_NED;
  R_W_NED << 0, 1, 0,
             1, 0, 0,
             0, 0, -1;
  const Eigen::Matrix3d R_NED_B = rot_z(yaw_deg * kDeg) * rot_y(pitch_deg * kDeg) * rot_x(roll_deg * kDeg);
  return pose_from_rotation(position, R_W_NED * R_NED_B * R_B_C);
}

Pose pose_from_opk(const Eigen::Vector3d& position, double omega_deg, double phi_deg, double kappa_deg) {
  const Eigen::Matrix3d R_W_Cpatb = rot_x(omega_deg * kDeg) * rot_y(phi_deg * kDeg) * rot_z(kappa_deg * kDeg);
  // PATB camera: x right, y up, z back. Ours: x right, y down, z forward.
  const Eigen::Matrix3d flip = Eigen::Vector3d(1, -1, -1).asDiagonal();
  return pose_from_rotation(position, R_W_Cpatb * flip);
}

}  // namespace terralign::geo
