// Warps for the inverse-compositional solver. A warp maps a reference pixel into the live
// image given its parameters; its Jacobian is taken at the identity on the reference side.
//
// Both work in pinhole pixel coordinates (pixel centres at integers) of one pyramid level.
#pragma once

#include <Eigen/Core>
#include <Eigen/LU>

#include <terralign/iclk/se3.hpp>

namespace terralign::iclk {

template <class S>
struct Pinhole {
  S fx, fy, cx, cy;
  // One level down: half the resolution, pixel centres kept at integers:
  // u' = (u + 0.5) / 2 - 0.5.
  Pinhole half() const { return {fx / S(2), fy / S(2), (cx + S(0.5)) / S(2) - S(0.5), (cy + S(0.5)) / S(2) - S(0.5)}; }
};

// The 6-DoF warp of a reference pixel with known depth: X = d K^-1 (u, v, 1) in the
// reference camera, moved by T_live_ref and projected. Parameters: T_live_ref.
template <class S>
struct SE3DepthWarp {
  static constexpr int DoF = 6;
  static constexpr bool kNeedsDepth = true;
  using Params = SE3<S>;
  using Jac = Eigen::Matrix<S, 2, DoF>;

  static Params identity() { return Params::identity(); }

  // d(u, v)/d(xi) at xi = 0 for X' = exp(xi) X: d pi/dX * [-[X]x | I].
  static Jac d_warp_d_xi(const Vec3<S>& X, S, S, const Pinhole<S>& K) {
    const S iz = S(1) / X.z(), x = X.x() * iz, y = X.y() * iz;
    Eigen::Matrix<S, 2, 3> dpi;
    dpi << K.fx * iz, S(0), -K.fx * x * iz, S(0), K.fy * iz, -K.fy * y * iz;
    Eigen::Matrix<S, 3, 6> dX;
    dX << -hat(X), Mat3<S>::Identity();
    return dpi * dX;
  }

  static bool apply(const Params& T, const Vec3<S>& X, S, S, const Pinhole<S>& K, S& u, S& v) {
    const Vec3<S> Y = T * X;
    if (!(Y.z() > S(1e-6))) return false;
    u = K.fx * Y.x() / Y.z() + K.cx;
    v = K.fy * Y.y() / Y.z() + K.cy;
    return true;
  }

  // Inverse-compositional update: W(x; T) <- W(W(x; delta)^-1; T), i.e. T <- T exp(delta)^-1.
  static void update(Params& T, const Eigen::Matrix<S, DoF, 1>& delta) { T = T * Params::exp(delta).inverse(); }
};

// The 8-DoF homography baseline on normalised coordinates x_n = ((u - cx) / fx, (v - cy) / fy)
// (so its parameters do not depend on the pyramid level). Parameters: H mapping reference to
// live normalised coordinates, H(2, 2) = 1.
template <class S>
struct HomographyWarp {
  static constexpr int DoF = 8;
  static constexpr bool kNeedsDepth = false;
  using Params = Mat3<S>;
  using Jac = Eigen::Matrix<S, 2, DoF>;

  static Params identity() { return Params::Identity(); }

  static Jac d_warp_d_xi(const Vec3<S>&, S u, S v, const Pinhole<S>& K) {
    const S x = (u - K.cx) / K.fx, y = (v - K.cy) / K.fy;
    Eigen::Matrix<S, 2, DoF> Jn;
    Jn << x, y, S(1), S(0), S(0), S(0), -x * x, -x * y,
          S(0), S(0), S(0), x, y, S(1), -x * y, -y * y;
    Jn.row(0) *= K.fx;
    Jn.row(1) *= K.fy;
    return Jn;
  }

  static bool apply(const Params& H, const Vec3<S>&, S u, S v, const Pinhole<S>& K, S& uo, S& vo) {
    const Vec3<S> x((u - K.cx) / K.fx, (v - K.cy) / K.fy, S(1));
    const Vec3<S> y = H * x;
    if (!(std::abs(y.z()) > S(1e-9))) return false;
    uo = K.fx * y.x() / y.z() + K.cx;
    vo = K.fy * y.y() / y.z() + K.cy;
    return true;
  }

  static void update(Params& H, const Eigen::Matrix<S, DoF, 1>& p) {
    Mat3<S> D;
    D << S(1) + p[0], p[1], p[2], p[3], S(1) + p[4], p[5], p[6], p[7], S(1);
    H = H * D.inverse();
    H /= H(2, 2);
  }
};

}  // namespace terralign::iclk
