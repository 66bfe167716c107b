// Poses in geodetic frames (GeographicLib) and OpenSfM reconstructions.
#include <terralign/geo/pose.hpp>

#include <cmath>
#include <vector>

#include <Eigen/SVD>
#include <GeographicLib/LocalCartesian.hpp>
#include <nlohmann/json.hpp>

#include <terralign/geo/file.hpp>
#include <terralign/geo/number_text.hpp>

#include "json_util.hpp"

namespace terralign::geo {

Result<Eigen::Matrix3d> grid_from_enu(const Crs& crs, const Geodetic& at) {
  const GeographicLib::LocalCartesian enu(at.lat_deg, at.lon_deg, at.height);
  double x0, y0, z0;
  TERRALIGN_TRY(crs.from_geodetic(at, x0, y0, z0));
  Eigen::Matrix3d J;
  for (int axis = 0; axis < 3; ++axis) {
    double e[3] = {0, 0, 0};
    e[axis] = 1.0;
    Geodetic g;
    enu.Reverse(e[0], e[1], e[2], g.lat_deg, g.lon_deg, g.height);
    double x, y, z;
    TERRALIGN_TRY(crs.from_geodetic(g, x, y, z));
    J.col(axis) = Eigen::Vector3d(x - x0, y - y0, z - z0);
  }
  // The nearest rotation (drops the projection's scale factor).
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(J, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d R = svd.matrixU() * svd.matrixV().transpose();
  if (R.determinant() < 0) return Error{"the CRS flips handedness at this point"};
  return R;
}

Result<Pose> pose_from_opensfm(const Eigen::Vector3d& rotation, const Eigen::Vector3d& translation,
                               const Geodetic& reference, const Crs& crs, OpenSfmFrame frame) {
  if (!rotation.allFinite() || !translation.allFinite())
    return Error{"OpenSfM shot has a non-finite rotation or translation"};
  const double angle = rotation.norm();
  const Eigen::Matrix3d R_C_ENU =
      angle > 0 ? rotation_matrix(rotation / angle, angle) : Eigen::Matrix3d::Identity();
  const Eigen::Vector3d centre_enu = -R_C_ENU.transpose() * translation;
  TERRALIGN_ASSERT(frame != OpenSfmFrame::Auto, "pose_from_opensfm: resolve Auto first");
  if (frame == OpenSfmFrame::ProjectedOffset) {
    Eigen::Vector3d offset;
    TERRALIGN_TRY(crs.from_geodetic(Geodetic{reference.lat_deg, reference.lon_deg, 0.0}, offset.x(),
                                    offset.y(), offset.z()));
    return pose_from_rotation(offset + centre_enu, R_C_ENU.transpose());
  }
  const GeographicLib::LocalCartesian topo(reference.lat_deg, reference.lon_deg, reference.height);
  Geodetic g;
  topo.Reverse(centre_enu.x(), centre_enu.y(), centre_enu.z(), g.lat_deg, g.lon_deg, g.height);
  Eigen::Vector3d t;
  TERRALIGN_TRY(crs.from_geodetic(g, t.x(), t.y(), t.z()));
  // The topocentric axes are ENU at the reference point; rotate them to ENU at the camera
  // (a few thousandths of a degree over 100 m), then to the grid.
  const GeographicLib::LocalCartesian at_cam(g.lat_deg, g.lon_deg, g.height);
  // R_ECEF_ENUref and R_ECEF_ENUcam from GeographicLib's rotation matrices.
  std::vector<double> Mref(9), Mcam(9);
  double x, y, z;
  topo.Forward(reference.lat_deg, reference.lon_deg, reference.height, x, y, z, Mref);
  at_cam.Forward(g.lat_deg, g.lon_deg, g.height, x, y, z, Mcam);
  const Eigen::Matrix3d R_ECEF_ENUref = Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(Mref.data());
  const Eigen::Matrix3d R_ECEF_ENUcam = Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(Mcam.data());
  TERRALIGN_TRY_ASSIGN(const Eigen::Matrix3d R_W_ENUcam, grid_from_enu(crs, g));
  const Eigen::Matrix3d R_W_C = R_W_ENUcam * R_ECEF_ENUcam.transpose() * R_ECEF_ENUref * R_C_ENU.transpose();
  return pose_from_rotation(t, R_W_C);
}

Result<OpenSfmShots> read_opensfm_shots(const std::string& path, const Crs& crs, OpenSfmFrame frame) {
  TERRALIGN_TRY_ASSIGN(const nlohmann::json doc, parse_json_file(path));
  const nlohmann::json* rec = &doc;
  if (doc.is_array()) {
    if (doc.empty()) return Error{path + ": reconstruction list is empty"};
    rec = &doc[0];
  }
  if (!rec->is_object() || !rec->contains("shots") || !rec->contains("reference_lla"))
    return Error{path + ": not an OpenSfM reconstruction (needs 'shots' and 'reference_lla')"};
  Geodetic ref;
  const auto& lla = (*rec)["reference_lla"];
  TERRALIGN_TRY_ASSIGN(ref.lat_deg, json_number(lla, "latitude", path + ": reference_lla"));
  TERRALIGN_TRY_ASSIGN(ref.lon_deg, json_number(lla, "longitude", path + ": reference_lla"));
  TERRALIGN_TRY_ASSIGN(ref.height, json_number(lla, "altitude", path + ": reference_lla"));
  OpenSfmShots out;
  if (frame == OpenSfmFrame::Auto) {
    double x, y, z;
    auto st = crs.from_geodetic(Geodetic{ref.lat_deg, ref.lon_deg, 0.0}, x, y, z);
    if (!st.ok()) return with_context(path + ": reference_lla", st.error());
    const bool whole = std::abs(x - std::round(x)) < 1e-3 && std::abs(y - std::round(y)) < 1e-3;
    frame = whole ? OpenSfmFrame::ProjectedOffset : OpenSfmFrame::Topocentric;
  }
  out.frame = frame;
  const auto& shots = (*rec)["shots"];
  if (!shots.is_object()) return Error{path + ": 'shots' must be an object"};
  for (const auto& [name, shot] : shots.items()) {
    const std::string where = path + ": shot " + name;
    TERRALIGN_TRY_ASSIGN(const Eigen::Vector3d r, json_vec3(shot, "rotation", where));
    TERRALIGN_TRY_ASSIGN(const Eigen::Vector3d t, json_vec3(shot, "translation", where));
    auto pose = pose_from_opensfm(r, t, ref, crs, frame);
    if (!pose.ok()) return with_context(where, pose.error());
    out.poses[name] = pose.value();
  }
  return out;
}

}  // namespace terralign::geo
