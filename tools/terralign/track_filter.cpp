#include "track_filter.hpp"

#include <cmath>

#include <Eigen/Cholesky>

namespace terralign::cli {
namespace {

constexpr double kDeg = 3.14159265358979323846 / 180.0;

Eigen::Vector3d log_so3(const Eigen::Quaterniond& q) { return geo::rotation_vector(q.normalized()); }

}  // namespace

TrackFilter::TrackFilter(const geo::Pose& init, double t0, const Eigen::Vector3d* velocity,
                         const TrackFilterOptions& options)
    : opt_(options), q_(init.q_W_C.normalized()), p_(init.t_W_C), t_(t0) {
  v_ = velocity ? *velocity : Eigen::Vector3d::Zero();
  w_.setZero();
  Mat6 pose = Mat6::Zero();
  pose.diagonal().head<3>().setConstant((opt_.init_rotation_sigma_deg * kDeg) * (opt_.init_rotation_sigma_deg * kDeg));
  pose.diagonal().tail<3>().setConstant(opt_.init_position_sigma * opt_.init_position_sigma);
  start_at(pose, velocity != nullptr);
}

void TrackFilter::start_at(const Mat6& pose_covariance, bool velocity_given) {
  P_.setZero();
  P_.topLeftCorner<6, 6>() = 0.5 * (pose_covariance + pose_covariance.transpose());
  const double sv = velocity_given ? opt_.given_velocity_sigma : opt_.init_velocity_sigma;
  P_.block<3, 3>(6, 6) = Eigen::Matrix3d::Identity() * sv * sv;
  if (!velocity_given) P_(8, 8) = opt_.init_climb_sigma * opt_.init_climb_sigma;
  P_.block<3, 3>(9, 9) = Eigen::Matrix3d::Identity() * (opt_.init_rate_sigma_deg * kDeg) * (opt_.init_rate_sigma_deg * kDeg);
  refused_in_row_ = 0;
}

void TrackFilter::predict(double t) {
  const double dt = t - t_;
  if (!(dt > 0)) return;
  // The error state moves with the nominal: R = Exp(w dt) R0 turns an error Exp(e) R0 into
  // Exp(Exp(w dt) e) R, and a rate error dw adds dw dt (first order).
  Mat12 F = Mat12::Identity();
  F.block<3, 3>(0, 0) = geo::rotation_from_vector(w_ * dt).toRotationMatrix();
  F.block<3, 3>(0, 9).diagonal().setConstant(dt);  // dtheta += dw dt
  F.block<3, 3>(3, 6).diagonal().setConstant(dt);  // dp += dv dt
  // Continuous white acceleration: the velocity is a random walk (variance sa2 t after t
  // seconds) and the position its integral (Bar-Shalom's continuous white noise acceleration
  // model); the same for the turn rate and the attitude. Its gains do not depend on the frame
  // rate, and on a straight line it predicts as well as extrapolating the last two answers
  // where they are precise (same year) and better where they are not (across years).
  Mat12 Q = Mat12::Zero();
  const double sa2 = opt_.accel_sigma * opt_.accel_sigma;
  const double sw2 = opt_.angular_accel_sigma_deg * kDeg * opt_.angular_accel_sigma_deg * kDeg;
  const double q00 = dt * dt * dt / 3, q01 = dt * dt / 2, q11 = dt;
  for (int k = 0; k < 3; ++k) {
    Q(k, k) = sw2 * q00;
    Q(k, 9 + k) = Q(9 + k, k) = sw2 * q01;
    Q(9 + k, 9 + k) = sw2 * q11;
    Q(3 + k, 3 + k) = sa2 * q00;
    Q(3 + k, 6 + k) = Q(6 + k, 3 + k) = sa2 * q01;
    Q(6 + k, 6 + k) = sa2 * q11;
  }
  q_ = (geo::rotation_from_vector(w_ * dt) * q_).normalized();
  p_ += v_ * dt;
  P_ = F * P_ * F.transpose() + Q;
  P_ = 0.5 * (P_ + P_.transpose()).eval();
  t_ = t;
}

TrackFilter::Update TrackFilter::update(const geo::Pose& measured, const Mat6& covariance) {
  Update u;
  if (!covariance.allFinite() || !measured.t_W_C.allFinite() || !measured.q_W_C.coeffs().allFinite()) {
    u.why = "the answer or its covariance is not finite";
    return u;
  }
  Eigen::Matrix<double, 6, 1> y;
  y.head<3>() = log_so3(measured.q_W_C * q_.conjugate());
  y.tail<3>() = measured.t_W_C - p_;
  if (const Eigen::LDLT<Mat6> r(covariance); r.info() != Eigen::Success || !r.isPositive()) {
    u.why = "the answer's covariance is not positive semi-definite";
    return u;
  }
  const Mat6 S = P_.topLeftCorner<6, 6>() + covariance;
  const Eigen::LDLT<Mat6> ldlt(S);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive() || !(ldlt.vectorD().minCoeff() > 0)) {
    u.why = "the innovation's covariance is not positive definite";
    return u;
  }
  u.d2 = y.dot(ldlt.solve(y));
  if (!std::isfinite(u.d2)) {
    u.why = "the innovation is not finite";
    return u;
  }
  if (opt_.gate >= 0 && u.d2 > opt_.gate) {
    if (opt_.reset_after_refusals > 0 && ++refused_in_row_ >= opt_.reset_after_refusals) {
      reset(measured, covariance);
      u.accepted = u.reset = true;
      return u;
    }
    u.why = "refused: the answer is too far from the prediction for both covariances";
    return u;
  }
  refused_in_row_ = 0;
  // K = P H^T S^-1 with H = [I6 0]; Joseph's form keeps P symmetric and positive.
  const Eigen::Matrix<double, 12, 6> K = ldlt.solve(P_.leftCols<6>().transpose()).transpose();
  const Eigen::Matrix<double, 12, 1> dx = K * y;
  q_ = (geo::rotation_from_vector(dx.head<3>()) * q_).normalized();
  p_ += dx.segment<3>(3);
  v_ += dx.segment<3>(6);
  w_ += dx.segment<3>(9);
  Mat12 IKH = Mat12::Identity();
  IKH.leftCols<6>() -= K;
  P_ = IKH * P_ * IKH.transpose() + K * covariance * K.transpose();
  P_ = 0.5 * (P_ + P_.transpose()).eval();
  ++updates_;
  u.accepted = true;
  return u;
}

bool TrackFilter::update_height(double z, double sigma) {
  if (!std::isfinite(z) || !std::isfinite(sigma) || !(sigma > 0)) return false;
  // H = e_5 (the error state's dp_z); K = P H^T / (H P H^T + sigma^2); Joseph's form.
  const double r = sigma * sigma;
  const double s = P_(5, 5) + r;
  if (!(s > 0) || !std::isfinite(s)) return false;
  const Eigen::Matrix<double, 12, 1> K = P_.col(5) / s;
  const Eigen::Matrix<double, 12, 1> dx = K * (z - p_.z());
  q_ = (geo::rotation_from_vector(dx.head<3>()) * q_).normalized();
  p_ += dx.segment<3>(3);
  v_ += dx.segment<3>(6);
  w_ += dx.segment<3>(9);
  Mat12 IKH = Mat12::Identity();
  IKH.col(5) -= K;
  P_ = IKH * P_ * IKH.transpose() + r * K * K.transpose();
  P_ = 0.5 * (P_ + P_.transpose()).eval();
  return true;
}

void TrackFilter::reset(const geo::Pose& measured, const Mat6& covariance) {
  q_ = measured.q_W_C.normalized();
  p_ = measured.t_W_C;
  start_at(covariance, false);
  ++updates_;
}

geo::Pose TrackFilter::pose() const {
  geo::Pose p;
  p.q_W_C = q_;
  p.t_W_C = p_;
  return p;
}

}  // namespace terralign::cli
