// The one applier of a learnt dynamic gyro block (core/dynamic_gyro.h has its equations): the
// per-stream state, used by the offline evaluation (core/motion) and the SDK's Stream alike.
// Header-only; kept apart from dynamic_gyro.h so the parameter set's header (params.h) does not
// carry it.
#ifndef IMUCAL_CORE_DYNAMIC_GYRO_STATE_H_
#define IMUCAL_CORE_DYNAMIC_GYRO_STATE_H_

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

#include "Eigen/Core"
#include "core/dynamic_gyro.h"

namespace imucal::core {

// The per-stream state of a DynamicGyro: a fixed ring buffer sized once at construction, so
// Step allocates nothing. One per sample stream (not thread-safe; the block itself is shared).
class DynamicGyroState {
 public:
  explicit DynamicGyroState(const DynamicGyro& block)
      // At least 2 samples: the delay term reads the previous sample even for a one-tap filter.
      : block_(&block),
        capacity_(std::max(2, block.WindowSamples())),
        ring_(12 * static_cast<size_t>(capacity_), 0.0) {}

  // Restarts the stream (a gap in time, a new power-up): the window is empty again.
  void Reset() { count_ = 0; }

  // One sample in (static output w_s [rad/s], calibrated accel a [m/s^2]), the dynamic output
  // out. Returns false when the sample lies outside the training envelope (the output is still
  // computed). Allocation-free; O(taps).
  bool Step(const Eigen::Vector3d& w_s, const Eigen::Vector3d& a, Eigen::Vector3d* out) noexcept {
    head_ = (count_ == 0 || head_ + 1 == capacity_) ? 0 : head_ + 1;
    // Each sample is written twice, at head and head + capacity, so the window's samples from
    // head back are contiguous in memory: a lag is a subtraction, never a modulo.
    for (const int at : {head_, head_ + capacity_}) {
      double* slot = &ring_[6 * static_cast<size_t>(at)];
      for (int c = 0; c < 3; ++c) {
        slot[c] = w_s(c);
        slot[3 + c] = a(c);
      }
    }
    if (count_ < capacity_) ++count_;
    const DynamicGyro& b = *block_;
    const double* prev = Lag(1);
    Eigen::Vector3d v;
    for (int i = 0; i < 3; ++i) {
      v(i) = w_s(i) + b.delay_s * b.rate_hz * (w_s(i) - prev[i]);
      v(i) += b.odd_rate(i) * v(i) * std::abs(v(i));
    }
    const size_t row_stride = 6 * static_cast<size_t>(b.taps);
    for (int l = 0; l < b.taps; ++l) {
      const double* x = Lag(l * b.dilation);
      for (int i = 0; i < 3; ++i) {
        const double* row = &b.weights[static_cast<size_t>(i) * row_stride + 6 * l];
        v(i) += row[0] * x[0] + row[1] * x[1] + row[2] * x[2] + row[3] * x[3] + row[4] * x[4] +
                row[5] * x[5];
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
    return &ring_[6 * static_cast<size_t>(head_ + capacity_ - back)];
  }

  const DynamicGyro* block_;
  int capacity_;
  std::vector<double> ring_;  // 2 * capacity_ samples of 6 channels
  int head_ = 0;
  int count_ = 0;
};

}  // namespace imucal::core

#endif  // IMUCAL_CORE_DYNAMIC_GYRO_STATE_H_
