// Rotation-vector helpers shared by the gyroscope's fits (core/gyro_solver.cc on the turns,
// core/move_effects.cc on the moves between poses): the skew matrix, and the exponential map
// with its right Jacobian.
#ifndef IMUCAL_CORE_SO3_H_
#define IMUCAL_CORE_SO3_H_

#include <cmath>

#include "Eigen/Core"

namespace imucal::core {

// [v]x: Skew(v) * u == v.cross(u).
inline Eigen::Matrix3d Skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d k;
  k << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return k;
}

// Exp(phi) (phi in rad) and, when `jr` is not null, the right Jacobian
//   Jr(phi) = I - (1 - cos t)/t^2 [phi]x + (t - sin t)/t^3 [phi]x^2,   t = |phi|,
// sharing one sin/cos. Below t = 1e-2 the coefficients come from their Taylor series (the
// closed forms lose eps/t^2 to cancellation; the series' next terms are below 1e-13).
inline Eigen::Matrix3d ExpAndRightJacobian(const Eigen::Vector3d& phi, Eigen::Matrix3d* jr) {
  const double t2 = phi.squaredNorm();
  double a, b, c;  // sin t / t, (1 - cos t) / t^2, (t - sin t) / t^3
  if (t2 < 1e-4) {
    a = 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0);
    b = 0.5 - t2 / 24.0 * (1.0 - t2 / 30.0);
    c = 1.0 / 6.0 - t2 / 120.0 * (1.0 - t2 / 42.0);
  } else {
    const double t = std::sqrt(t2);
    const double s = std::sin(t);
    a = s / t;
    b = (1.0 - std::cos(t)) / t2;
    c = (t - s) / (t2 * t);
  }
  const Eigen::Matrix3d k = Skew(phi);
  const Eigen::Matrix3d k2 = phi * phi.transpose() - t2 * Eigen::Matrix3d::Identity();
  if (jr != nullptr) *jr = Eigen::Matrix3d::Identity() - b * k + c * k2;
  return Eigen::Matrix3d::Identity() + a * k + b * k2;
}

}  // namespace imucal::core

#endif  // IMUCAL_CORE_SO3_H_
