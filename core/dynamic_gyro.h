// The gyroscope in motion (issue 27; seeds/003's learnt half, in a linear form): a dynamic block
// learnt from recordings with a reference orientation, carried by a parameter set
// (ParamSet::dynamic_gyro) and applied after the static model of core/correction.h.
//
// For sample k at the block's rate, with w_s(k) the static model's output (rad/s, body frame,
// every applied effect included) and a(k) the calibrated accelerometer (m/s^2, body frame):
//   v(k)   = w_s(k) + delay_s * rate_hz * (w_s(k) - w_s(k-1))     the gyro's delay compensated
//   v_i(k) += odd_rate_i * v_i(k) * |v_i(k)|                       odd rate non-linearity
//   w(k)   = v(k) + sum_{l=0}^{taps-1} W_l x(k - l*dilation)        the linear dilated filter
// with x(k) = [w_s(k); a(k)] (6 channels) and W_l the 3x6 block of `weights` at lag l*dilation
// samples. Before the window is full (the first (taps-1)*dilation samples of a stream) missing
// lags read the oldest sample held. Header-only (Eigen and the standard library) so the SDK
// needs no solver; DynamicGyroState (core/dynamic_gyro_state.h) is the one applier, used
// offline and by the SDK alike.
#ifndef IMUCAL_CORE_DYNAMIC_GYRO_H_
#define IMUCAL_CORE_DYNAMIC_GYRO_H_

#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "Eigen/Core"

namespace imucal::core {

// What the block saw in training: input outside it is flagged by the applier (the block was not
// shown such motion, so its correction is an extrapolation).
struct DynamicGyroEnvelope {
  Eigen::Vector3d max_abs_rate_rad_s = Eigen::Vector3d::Zero();  // |w_s| per axis
  Eigen::Vector3d max_abs_accel_m_s2 = Eigen::Vector3d::Zero();  // |a| per axis
};

// One recording the block was trained on, or held out in its gate.
struct DynamicGyroRecording {
  std::string name;    // as given on the command line (IMU_FILE:REFERENCE_FILE or a directory)
  std::string sha256;  // of the IMU file's bytes, then the reference file's
  double duration_s = 0.0;
  // Leave-one-recording-out: absolute orientation error (RMS over the recording, deg) of the
  // static model and of the learnt block fitted without this recording. NaN when not held out.
  double aoe_static_deg = std::nan("");
  double aoe_learnt_deg = std::nan("");
};

struct DynamicGyro {
  double rate_hz = 0.0;  // the sample rate it was learnt at; applied only within 2 % of it
  double delay_s = 0.0;  // the gyro's delay behind the true rate (s), compensated as above
  double delay_std_error_s = 0.0;
  Eigen::Vector3d odd_rate = Eigen::Vector3d::Zero();  // 1/(rad/s), per axis
  Eigen::Vector3d odd_rate_std_error = Eigen::Vector3d::Zero();
  int taps = 0;      // 0: no filter
  int dilation = 1;  // samples between taps
  // 3 rows (output axis x, y, z) by 6*taps columns, row-major: column l*6 + c is the weight of
  // channel c (0-2 w_s [rad/s per rad/s], 3-5 a [rad/s per m/s^2]) at lag l*dilation.
  std::vector<double> weights;
  double ridge_lambda = 0.0;  // the regularisation chosen by cross-validation
  DynamicGyroEnvelope envelope;
  // Provenance and the gate's figures.
  std::vector<DynamicGyroRecording> training;
  std::string gate_reason;  // why it passed (the figures) -- a refused block is never shipped

  int WindowSamples() const { return taps > 0 ? (taps - 1) * dilation + 1 : 2; }
};

}  // namespace imucal::core

#endif  // IMUCAL_CORE_DYNAMIC_GYRO_H_
