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
// needs no solver; DynamicGyroState is the one applier, used offline and by the SDK alike.
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

// The per-stream state of a DynamicGyro: a fixed ring buffer sized once at construction, so
// Step allocates nothing. One per sample stream (not thread-safe; the block itself is shared).
class DynamicGyroState {
 public:
  explicit DynamicGyroState(const DynamicGyro& block)
      : block_(&block), capacity_(block.WindowSamples()), ring_(6 * capacity_, 0.0) {}

  // Restarts the stream (a gap in time, a new power-up): the window is empty again.
  void Reset() { count_ = 0; }

  // One sample in (static output w_s [rad/s], calibrated accel a [m/s^2]), the dynamic output
  // out. Returns false when the sample lies outside the training envelope (the output is still
  // computed). Allocation-free.
  bool Step(const Eigen::Vector3d& w_s, const Eigen::Vector3d& a, Eigen::Vector3d* out) noexcept {
    head_ = (count_ == 0) ? 0 : (head_ + 1) % capacity_;
    double* slot = &ring_[6 * head_];
    for (int c = 0; c < 3; ++c) {
      slot[c] = w_s(c);
      slot[3 + c] = a(c);
    }
    if (count_ < capacity_) ++count_;
    const DynamicGyro& b = *block_;
    const double* prev = Lag(1);
    Eigen::Vector3d v;
    for (int i = 0; i < 3; ++i) {
      v(i) = w_s(i) + b.delay_s * b.rate_hz * (w_s(i) - prev[i]);
      v(i) += b.odd_rate(i) * v(i) * std::abs(v(i));
    }
    for (int l = 0; l < b.taps; ++l) {
      const double* x = Lag(l * b.dilation);
      for (int i = 0; i < 3; ++i) {
        const double* row = &b.weights[static_cast<size_t>(i) * 6 * b.taps + 6 * l];
        double sum = 0.0;
        for (int c = 0; c < 6; ++c) sum += row[c] * x[c];
        v(i) += sum;
      }
    }
    *out = v;
    bool inside = true;
    for (int i = 0; i < 3; ++i) {
      inside &= std::abs(w_s(i)) <= b.envelope.max_abs_rate_rad_s(i);
      inside &= std::abs(a(i)) <= b.envelope.max_abs_accel_m_s2(i);
    }
    return inside;
  }

 private:
  // The sample `lag` steps back, or the oldest held when the window is not yet full.
  const double* Lag(int lag) const {
    const int back = lag < count_ ? lag : count_ - 1;
    return &ring_[6 * ((head_ - back + capacity_) % capacity_)];
  }

  const DynamicGyro* block_;
  int capacity_;
  std::vector<double> ring_;
  int head_ = 0;
  int count_ = 0;
};

}  // namespace imucal::core

#endif  // IMUCAL_CORE_DYNAMIC_GYRO_H_
