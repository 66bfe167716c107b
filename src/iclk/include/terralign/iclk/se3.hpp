// SE(3) with the exponential and logarithm maps, templated on the scalar.
//
// Tangent vectors are xi = [omega; v] (rotation first, as in Lv et al.): exp(xi) is the
// rigid motion whose rotation is exp([omega]x) and whose translation is V(omega) v.
// Both maps switch to Taylor series near zero rotation (Lv et al.'s code divides by the
// angle and returns NaN for a zero rotation) and log handles angles up to pi. Their sines,
// cosines and atan2 are terralign's (geo/numeric.hpp), in double, so that a pose's bits do
// not depend on the C library.
#pragma once

#include <cmath>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <terralign/geo/numeric.hpp>

namespace terralign::iclk {

// sin and cos of th in the scalar S (computed in double, rounded once to S).
template <class S>
void sin_cos_of(S th, S& s, S& c) {
  double sd, cd;
  sin_cos(static_cast<double>(th), sd, cd);
  s = static_cast<S>(sd);
  c = static_cast<S>(cd);
}

template <class S>
using Vec3 = Eigen::Matrix<S, 3, 1>;
template <class S>
using Vec6 = Eigen::Matrix<S, 6, 1>;
template <class S>
using Mat3 = Eigen::Matrix<S, 3, 3>;

template <class S>
Mat3<S> hat(const Vec3<S>& w) {
  Mat3<S> m;
  m << S(0), -w.z(), w.y(), w.z(), S(0), -w.x(), -w.y(), w.x(), S(0);
  return m;
}

template <class S>
struct SE3 {
  Mat3<S> R = Mat3<S>::Identity();
  Vec3<S> t = Vec3<S>::Zero();

  static SE3 identity() { return SE3{}; }

  Vec3<S> operator*(const Vec3<S>& p) const { return R * p + t; }
  SE3 operator*(const SE3& o) const { return SE3{R * o.R, R * o.t + t}; }
  SE3 inverse() const {
    const Mat3<S> Rt = R.transpose();
    return SE3{Rt, -(Rt * t)};
  }
  template <class T>
  SE3<T> cast() const {
    return SE3<T>{R.template cast<T>(), t.template cast<T>()};
  }

  // exp([omega; v]).
  static SE3 exp(const Vec6<S>& xi) {
    const Vec3<S> w = xi.template head<3>(), v = xi.template tail<3>();
    const S th2 = w.squaredNorm();
    const S th = std::sqrt(th2);
    const Mat3<S> W = hat(w), W2 = W * W;
    S A, B, C;  // sin(th)/th, (1 - cos th)/th^2, (th - sin th)/th^3
    if (th < S(1e-2)) {
      // Series (the closed forms cancel catastrophically here); the next terms are below
      // th^6 / 5040 < 2e-16 at th = 1e-2.
      const S th4 = th2 * th2;
      A = S(1) - th2 / S(6) + th4 / S(120);
      B = S(0.5) - th2 / S(24) + th4 / S(720);
      C = S(1) / S(6) - th2 / S(120) + th4 / S(5040);
    } else {
      S sn, cs;
      sin_cos_of(th, sn, cs);
      A = sn / th;
      B = (S(1) - cs) / th2;
      C = (th - sn) / (th2 * th);
    }
    SE3 T;
    T.R = Mat3<S>::Identity() + A * W + B * W2;
    T.t = (Mat3<S>::Identity() + B * W + C * W2) * v;
    return T;
  }

  // log: the [omega; v] with exp(log(T)) == T, |omega| in [0, pi].
  Vec6<S> log() const {
    const S c = std::max(S(-1), std::min(S(1), (R.trace() - S(1)) / S(2)));
    Vec3<S> w;
    const Vec3<S> axis_sin(R(2, 1) - R(1, 2), R(0, 2) - R(2, 0), R(1, 0) - R(0, 1));  // 2 sin(th) u
    // atan2 of sine and cosine is well conditioned at every angle (acos is not near 0 and pi).
    const S th = static_cast<S>(atan2_portable(static_cast<double>(axis_sin.norm() / S(2)), static_cast<double>(c)));
    if (th < S(1e-4)) {
      w = axis_sin / S(2) * (S(1) + th * th / S(6));  // th / sin(th) ~ 1 + th^2 / 6
    } else if (th > S(3.14159265358979323846) - S(1e-3)) {
      // Near pi, sin(th) -> 0: take the axis from the symmetric part, R + I = 2 u u^T (at pi).
      const Mat3<S> B = (R + R.transpose()) / S(2) - c * Mat3<S>::Identity();  // (1 - c) u u^T
      int k = 0;
      B.diagonal().maxCoeff(&k);
      Vec3<S> u = B.col(k) / std::sqrt(std::max(B(k, k), S(1e-300)));
      u.normalize();
      if (u.dot(axis_sin) < S(0)) u = -u;  // the sign from the antisymmetric part
      w = th * u;
    } else {
      S sn, cs;
      sin_cos_of(th, sn, cs);
      w = axis_sin * (th / (S(2) * sn));
    }
    // v = V^-1 t with V^-1 = I - W/2 + D W^2, D = (1 - A / (2 B)) / th^2.
    const Mat3<S> W = hat(w), W2 = W * W;
    const S th2 = th * th;
    S D;
    if (th < S(1e-2)) {  // series, as in exp: the closed form cancels
      D = S(1) / S(12) + th2 / S(720) + th2 * th2 / S(30240);
    } else {
      S sn, cs;
      sin_cos_of(th, sn, cs);
      const S A = sn / th, B = (S(1) - cs) / th2;
      D = (S(1) - A / (S(2) * B)) / th2;
    }
    const Vec3<S> v = (Mat3<S>::Identity() - W / S(2) + D * W2) * t;
    Vec6<S> xi;  // element-wise: GCC 12 misreads Eigen's packet copy of a Vec3 here
    for (int k = 0; k < 3; ++k) {
      xi[k] = w[k];
      xi[k + 3] = v[k];
    }
    return xi;
  }
};

// The adjoint of T for xi = [omega; v]: exp(Ad(T) xi) = T exp(xi) T^-1.
template <class S>
Eigen::Matrix<S, 6, 6> adjoint(const SE3<S>& T) {
  Eigen::Matrix<S, 6, 6> A = Eigen::Matrix<S, 6, 6>::Zero();
  A.template topLeftCorner<3, 3>() = T.R;
  A.template bottomRightCorner<3, 3>() = T.R;
  A.template bottomLeftCorner<3, 3>() = hat(T.t) * T.R;
  return A;
}

}  // namespace terralign::iclk
