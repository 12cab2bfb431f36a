// The exponential map of SO(3), once, for every user: the accelerometer model's frame rotation
// (core/model.h, on Ceres's Jets too), the gyroscope's fits on the turns (core/gyro_solver.cc)
// and on the moves between poses (core/move_effects.cc), the simulators and the tests. Three
// forms of one map, sharing one set of coefficients: the rotation matrix (ExpSo3), the rotation
// matrix with its right Jacobian (ExpAndRightJacobian), and the unit quaternion (ExpQuaternion,
// about half the work when rotations are chained). Angles in rad.
#ifndef IMUCAL_CORE_SO3_H_
#define IMUCAL_CORE_SO3_H_

#include <cmath>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "util/units.h"

namespace imucal::core {

// [v]x: Skew(v) * u == v.cross(u).
inline Eigen::Matrix3d Skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d k;
  k << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return k;
}

// The coefficients of Exp([phi]x) = I + a K + b K^2 and of its right Jacobian
// Jr = I - b K + c K^2 (K = [phi]x, t = |phi|, t2 = t^2):
//   a = sin t / t,  b = (1 - cos t) / t^2,  c = (t - sin t) / t^3,
// sharing one sin/cos. Below t = 1e-2 they come from their Taylor series (the closed forms lose
// eps/t^2 to cancellation; the series' next terms are below 1e-13). Valid for any Scalar with
// sqrt/sin/cos (double, ceres::Jet).
template <typename Scalar>
void ExpCoefficients(const Scalar& t2, Scalar* a, Scalar* b, Scalar* c) {
  using std::cos;
  using std::sin;
  using std::sqrt;
  if (t2 < Scalar(1e-4)) {
    *a = Scalar(1) - t2 / Scalar(6) * (Scalar(1) - t2 / Scalar(20));
    *b = Scalar(0.5) - t2 / Scalar(24) * (Scalar(1) - t2 / Scalar(30));
    *c = Scalar(1.0 / 6.0) - t2 / Scalar(120) * (Scalar(1) - t2 / Scalar(42));
  } else {
    const Scalar t = sqrt(t2);
    const Scalar s = sin(t);
    *a = s / t;
    *b = (Scalar(1) - cos(t)) / t2;
    *c = (t - s) / (t2 * t);
  }
}

// Exp([v]x), the rotation matrix of rotation vector v.
template <typename Scalar>
Eigen::Matrix<Scalar, 3, 3> ExpSo3(const Eigen::Matrix<Scalar, 3, 1>& v) {
  using Mat3 = Eigen::Matrix<Scalar, 3, 3>;
  const Scalar t2 = v.squaredNorm();
  Scalar a, b, c;
  ExpCoefficients(t2, &a, &b, &c);
  Mat3 k;
  k << Scalar(0), -v.z(), v.y(), v.z(), Scalar(0), -v.x(), -v.y(), v.x(), Scalar(0);
  // K^2 = v v^T - t2 I
  const Mat3 k2 = v * v.transpose() - t2 * Mat3::Identity();
  return Mat3::Identity() + a * k + b * k2;
}

// Exp(phi) and, when `jr` is not null, the right Jacobian Jr(phi) (above).
inline Eigen::Matrix3d ExpAndRightJacobian(const Eigen::Vector3d& phi, Eigen::Matrix3d* jr) {
  const double t2 = phi.squaredNorm();
  double a, b, c;
  ExpCoefficients(t2, &a, &b, &c);
  const Eigen::Matrix3d k = Skew(phi);
  const Eigen::Matrix3d k2 = phi * phi.transpose() - t2 * Eigen::Matrix3d::Identity();
  if (jr != nullptr) *jr = Eigen::Matrix3d::Identity() - b * k + c * k2;
  return Eigen::Matrix3d::Identity() + a * k + b * k2;
}

// Exp(phi) as a unit quaternion (cos(t/2), sin(t/2)/t phi): the same rotation as ExpSo3.
inline Eigen::Quaterniond ExpQuaternion(const Eigen::Vector3d& phi) {
  const double t2 = phi.squaredNorm();
  double w, s;  // cos(t/2), sin(t/2)/t, with their Taylor series near zero
  if (t2 < 1e-8) {
    w = 1.0 - t2 / 8.0;
    s = 0.5 - t2 / 48.0;
  } else {
    const double t = std::sqrt(t2);
    w = std::cos(0.5 * t);
    s = std::sin(0.5 * t) / t;
  }
  return Eigen::Quaterniond(w, s * phi.x(), s * phi.y(), s * phi.z());
}

// The angle between two vectors, deg (0-180), accurate at every angle (atan2 of the cross and
// dot products, not acos).
inline double AngleBetweenDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return kRadToDeg * std::atan2(a.cross(b).norm(), a.dot(b));
}

}  // namespace imucal::core

#endif  // IMUCAL_CORE_SO3_H_
