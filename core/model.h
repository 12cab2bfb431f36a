// The IMU error model that imucal estimates and the SDK applies. Header-only, Eigen only, so the
// robot SDK shares these exact equations without linking the solver.
//
// CONVENTION: imucal stores the INVERSE (correction) model: it maps a raw reading `u` (in the
// capture's input unit) to the calibrated value in SI units, in the body frame.
//
// Accelerometer (15 parameters; seeds/002's nonlinear model written in inverse form):
//   y   = diag(scale) (u - bias)          per-axis linear part           [m/s^2]
//   z_i = y_i + quadratic_i * y_i^2       per-axis second-order term     [m/s^2]
//   a   = misalignment * z                body-frame specific force      [m/s^2]
// with
//   bias          [input unit]            3
//   scale         [m/s^2 per input unit]  3
//   misalignment  = R(frame_angles) * L(tri_angles)                      6 angles [rad]
//       L = [[1, 0, 0], [t_yx, 1, 0], [t_zx, t_zy, 1]]  (unit lower-triangular; `tri_angles` =
//           (t_yx, t_zx, t_zy)): the non-orthogonality of the sensing axes. Body x is the sensing
//           x axis and body y lies in the sensing x-y plane.
//       R = exp([frame_angles]x): the rotation of the sensor in the case. It leaves |a| unchanged,
//           so only a protocol with known orientations (six-face) determines it; otherwise 0.
//   quadratic     [1/(m/s^2)]             3
//
// Gyroscope (12 parameters):
//   w = matrix * (u - bias) - accel_coupling * a                          [rad/s]
//   matrix         [rad/s per input unit] scale and misalignment in the accelerometer body frame;
//                  written scale_j = matrix(j,j) and misalignment = matrix * diag(1/scale)
//   bias           [input unit]
//   accel_coupling [(rad/s)/(m/s^2)]      g-sensitivity (zero unless a capture determines it)
#ifndef IMUCAL_CORE_MODEL_H_
#define IMUCAL_CORE_MODEL_H_

#include <cmath>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "core/so3.h"

namespace imucal::core {

template <typename Scalar>
using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
template <typename Scalar>
using Mat3 = Eigen::Matrix<Scalar, 3, 3>;

// Unit lower-triangular non-orthogonality matrix L from (t_yx, t_zx, t_zy).
template <typename Scalar>
Mat3<Scalar> LowerMisalignment(const Vec3<Scalar>& tri) {
  Mat3<Scalar> l = Mat3<Scalar>::Identity();
  l(1, 0) = tri(0);
  l(2, 0) = tri(1);
  l(2, 1) = tri(2);
  return l;
}

template <typename Scalar>
struct AccelModel {
  Vec3<Scalar> bias = Vec3<Scalar>::Zero();
  Vec3<Scalar> scale = Vec3<Scalar>::Ones();
  Vec3<Scalar> tri_angles = Vec3<Scalar>::Zero();
  Vec3<Scalar> frame_angles = Vec3<Scalar>::Zero();
  Vec3<Scalar> quadratic = Vec3<Scalar>::Zero();

  Mat3<Scalar> Misalignment() const {
    return ExpSo3<Scalar>(frame_angles) * LowerMisalignment<Scalar>(tri_angles);
  }
  // Raw reading (input unit) -> body-frame specific force (m/s^2).
  Vec3<Scalar> Apply(const Vec3<Scalar>& raw) const { return Misalignment() * PerAxis(raw); }
  // The per-axis part z (before misalignment). |a| does not depend on frame_angles.
  Vec3<Scalar> PerAxis(const Vec3<Scalar>& raw) const {
    Vec3<Scalar> y = scale.cwiseProduct(raw - bias);
    return y + quadratic.cwiseProduct(y.cwiseProduct(y));
  }
  // Exact inverse of Apply (used by the simulator): body specific force -> raw reading.
  Vec3<Scalar> Invert(const Vec3<Scalar>& accel) const {
    const Vec3<Scalar> z = Misalignment().inverse() * accel;
    Vec3<Scalar> raw;
    for (int i = 0; i < 3; ++i) {
      Scalar y = z(i);
      if (quadratic(i) != Scalar(0)) {  // root of q y^2 + y - z = 0 nearest to z
        using std::sqrt;
        y = Scalar(2) * z(i) / (Scalar(1) + sqrt(Scalar(1) + Scalar(4) * quadratic(i) * z(i)));
      }
      raw(i) = y / scale(i) + bias(i);
    }
    return raw;
  }
};

template <typename Scalar>
struct GyroModel {
  Mat3<Scalar> matrix = Mat3<Scalar>::Identity();
  Vec3<Scalar> bias = Vec3<Scalar>::Zero();
  Mat3<Scalar> accel_coupling = Mat3<Scalar>::Zero();

  // Raw reading (input unit) and body specific force (m/s^2) -> body rate (rad/s).
  Vec3<Scalar> Apply(const Vec3<Scalar>& raw, const Vec3<Scalar>& accel) const {
    return matrix * (raw - bias) - accel_coupling * accel;
  }
  Vec3<Scalar> Invert(const Vec3<Scalar>& rate, const Vec3<Scalar>& accel) const {
    return matrix.inverse() * (rate + accel_coupling * accel) + bias;
  }
};

using AccelParams = AccelModel<double>;
using GyroParams = GyroModel<double>;

}  // namespace imucal::core

#endif  // IMUCAL_CORE_MODEL_H_
