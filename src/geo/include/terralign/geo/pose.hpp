// Camera poses in the map frame and conversions from other encodings.
//
// Frames (see DESIGN.md): the world W is the map's projected CRS with x east, y north,
// z up (metres). The camera C has x right, y down, z forward (OpenCV). A pose is T_W_C: it
// maps a point from C to W, p_W = R_W_C p_C + t_W_C, so t_W_C is the camera centre.
// Its text form is "x y z qw qx qy qz" (Hamilton quaternion of R_W_C).
#pragma once

#include <map>
#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <terralign/geo/crs.hpp>
#include <terralign/geo/result.hpp>

namespace terralign::geo {

struct Pose {
  Eigen::Quaterniond q_W_C = Eigen::Quaterniond::Identity();
  Eigen::Vector3d t_W_C = Eigen::Vector3d::Zero();

  Eigen::Matrix3d R() const { return q_W_C.toRotationMatrix(); }
  Eigen::Vector3d operator*(const Eigen::Vector3d& p_C) const { return q_W_C * p_C + t_W_C; }
  Pose operator*(const Pose& o) const { return Pose{q_W_C * o.q_W_C, q_W_C * o.t_W_C + t_W_C}; }
  Pose inverse() const {
    const Eigen::Quaterniond qi = q_W_C.conjugate();
    return Pose{qi, -(qi * t_W_C)};
  }
};

// Rotations from axes and angles, and back, in terralign's sine, cosine and atan2
// (geo/numeric.hpp) where Eigen::AngleAxis calls the C library's: the same bits on every
// machine and C library. Each computes what Eigen's does, in its order:
// rotation_matrix(axis, angle) = AngleAxisd(angle, axis).toRotationMatrix(),
// rotation_quaternion(axis, angle) = Quaterniond(AngleAxisd(angle, axis)) (axis of unit
// length); angle_axis(q, angle, axis) = AngleAxisd(q)'s angle (in [0, pi]) and unit axis
// ((1, 0, 0) for the identity); rotation_angle(q) its angle (angularDistance(a, b) is
// rotation_angle(a * b.conjugate())), rotation_vector(q) angle times axis, and
// rotation_from_vector(v) its inverse (the identity where |v| is not above 0).
Eigen::Matrix3d rotation_matrix(const Eigen::Vector3d& axis, double angle);
Eigen::Quaterniond rotation_quaternion(const Eigen::Vector3d& axis, double angle);
void angle_axis(const Eigen::Quaterniond& q, double& angle, Eigen::Vector3d& axis);
double rotation_angle(const Eigen::Quaterniond& q);
Eigen::Vector3d rotation_vector(const Eigen::Quaterniond& q);
Eigen::Quaterniond rotation_from_vector(const Eigen::Vector3d& v);

// From a camera-to-world rotation (orthonormalised through the quaternion) and position.
Pose pose_from_rotation(const Eigen::Vector3d& t_W_C, const Eigen::Matrix3d& R_W_C);

// Parses "x y z qw qx qy qz". The quaternion must be finite with a norm within 1e-3 of 1
// (it is then normalised): a zero or far-from-unit norm usually means swapped fields.
Result<Pose> parse_pose(const std::string& text);
// Shortest text that reads back to the same doubles.
std::string format_pose(const Pose& pose);

// Camera mount R_B_C: camera axes in the body frame FRD (x forward, y right, z down).
// nadir_mount(): optical axis straight down, image top towards the nose.
Eigen::Matrix3d nadir_mount();
// A camera tilted forward from nadir by `tilt_deg` (0: nadir, 90: looking ahead).
Eigen::Matrix3d tilted_mount(double tilt_deg);

// From an aircraft attitude. yaw: heading in degrees clockwise from grid north (the map's
// +y); pitch: nose up, degrees; roll: right wing down, degrees; applied as
// R_NED_B = Rz(yaw) Ry(pitch) Rx(roll) (aerospace Z-Y-X), with NED taken from the map frame
// (north = +y, east = +x, down = -z). The camera sits in the body with R_B_C = mount.
Pose pose_from_ypr(const Eigen::Vector3d& position, double yaw_deg, double pitch_deg,
                   double roll_deg, const Eigen::Matrix3d& R_B_C = nadir_mount());

// From photogrammetric omega/phi/kappa (PATB / Pix4D / orthority convention): angles in
// degrees, R(camera -> world) = Rx(omega) Ry(phi) Rz(kappa), with that camera's axes x right,
// y up, z backwards. The world is the map frame.
Pose pose_from_opk(const Eigen::Vector3d& position, double omega_deg, double phi_deg,
                   double kappa_deg);

// The rotation R_W_ENU from the local east-north-up frame at `at` to the map grid: the
// meridian convergence (and any tilt of the grid) as a proper rotation, computed from the
// CRS's own forward projection by differences over 1 m.
Result<Eigen::Matrix3d> grid_from_enu(const Crs& crs, const Geodetic& at);

// How an OpenSfM reconstruction.json's frame relates to the map.
//  - Topocentric: OpenSfM's own frame, east-north-up at `reference_lla` (height 0 on the
//    ellipsoid there); converted through geodetic coordinates, with the meridian convergence.
//  - ProjectedOffset: what OpenDroneMap writes after `export_geocoords`: axes parallel to the
//    projected grid, origin at a whole-metre offset, and `reference_lla` set to that offset's
//    latitude / longitude. (The Tuniu reconstruction is of this kind: its reference_lla
//    projects to (292632.0000, 2731169.0000) in EPSG:32651.)
//  - Auto: ProjectedOffset when reference_lla projects to whole metres within 1 mm in the
//    map CRS (a chance of about 1e-6 for a true topocentric origin), else Topocentric.
enum class OpenSfmFrame { Auto, Topocentric, ProjectedOffset };

// One shot: `rotation` is the axis-angle of R_C_F (frame F -> camera, OpenCV camera axes)
// and `translation` is t with p_C = R p_F + t. The height is passed through (see crs.hpp).
Result<Pose> pose_from_opensfm(const Eigen::Vector3d& rotation, const Eigen::Vector3d& translation,
                               const Geodetic& reference, const Crs& crs, OpenSfmFrame frame);

struct OpenSfmShots {
  OpenSfmFrame frame = OpenSfmFrame::Topocentric;  // the frame used (Auto resolved)
  std::map<std::string, Pose> poses;               // map poses in `crs`, by shot name
};

// Reads every shot of an OpenSfM reconstruction.json (the first reconstruction).
Result<OpenSfmShots> read_opensfm_shots(const std::string& path, const Crs& crs,
                                        OpenSfmFrame frame = OpenSfmFrame::Auto);

}  // namespace terralign::geo
