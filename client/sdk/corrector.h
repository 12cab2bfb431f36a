// The robot SDK's per-sample correction: applies a calibration parameter set (core/params.h) to
// raw IMU samples. Links no solver: the equations are core/correction.h's, header-only, the very
// code the server's reports are computed with; the SDK adds the checks a received parameter set
// must pass before a robot applies it.
//
// The model (core/correction.h has it written out): a = R L (y + quadratic y^2), y = diag(scale)
// (u_a - bias) [m/s^2]; w = matrix (u_g - bias) - accel_coupling a [rad/s]; then every applied
// effect subtracted from its output, its regressor evaluated on (temperature, time since the
// time origin, a, w) before any effect. Effects with `applied == false` (time effects unless the
// user opts in) are not applied. An applied effect whose regressor uses temperature is skipped on
// a sample without temperature (temp_c NaN) and counted in CalibratedSample::effects_skipped.
//
// A parameter set without a gyroscope (core::ParamSet::has_gyro false, fitted on an
// accelerometer-only capture) corrects the accelerometer only: gyro_rad_s is then the gyro
// reading exactly as given (its own unit, not rad/s), and any gyro unit is accepted.
//
// A learnt dynamic gyro block (core::ParamSet::dynamic_gyro, core/dynamic_gyro.h; issue 27)
// depends on the samples before the current one, so it is applied by a Stream, one per sample
// stream (Corrector::NewStream): the static model above, then core::DynamicGyroState::Step on
// its output, in a fixed ring buffer sized once, allocation-free and O(window) per sample.
// Corrector::Apply, stateless, applies the static model only (as it did before blocks existed);
// has_dynamic_gyro() says whether a Stream would apply more. A Stream:
//   - is made for a stream of a stated nominal rate, refused (InvalidArgument) when that differs
//     from the block's rate_hz by more than 2 % (the filter's lags and the delay term are in
//     samples of that rate);
//   - flags each sample whose interval from the previous one differs from 1/rate_hz by more
//     than 2 % (CalibratedSample::interval_off_rate; the output is still computed);
//   - restarts the window (DynamicGyroState::Reset, counted) when t_s does not increase or a gap
//     longer than the window's span (at least 2 samples) separates two samples: the past it held
//     is gone;
//   - flags each sample outside the block's training envelope (outside_envelope).
//
// Thread safety: a Corrector is immutable after Create; Apply is const, allocation-free and
// noexcept, so any number of threads may share one Corrector. A Stream is one thread's.
#ifndef IMUCAL_CLIENT_SDK_CORRECTOR_H_
#define IMUCAL_CLIENT_SDK_CORRECTOR_H_

#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <span>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/capture.h"
#include "core/correction.h"
#include "core/dynamic_gyro.h"
#include "core/dynamic_gyro_state.h"
#include "core/params.h"
#include "core/regressor.h"

namespace imucal::sdk {

struct RawSample {
  double t_s = 0.0;      // seconds, any origin (see Corrector time origin)
  double accel[3] = {};  // in the parameter set's accel input unit
  double gyro[3] = {};   // in the parameter set's gyro input unit
  double temp_c = std::numeric_limits<double>::quiet_NaN();  // degC; NaN when not measured
};

struct CalibratedSample {
  double accel_m_s2[3] = {};
  double gyro_rad_s[3] = {};
  int effects_skipped = 0;  // applied temperature effects skipped: this sample had no temp_c
  // Stream::Apply with a dynamic gyro block only (false otherwise): the sample lay outside the
  // block's training envelope (its correction is an extrapolation) ...
  bool outside_envelope = false;
  // ... or came more than 2 % early or late for the block's rate_hz.
  bool interval_off_rate = false;
};

class Stream;

class Corrector {
 public:
  // Validates `params` and precomputes everything Apply needs. InvalidArgument naming the
  // parameter (JSON path spelling, e.g. `gyro.matrix: not invertible`, `effects[1].regressor:
  // unknown regressor "ax*bz"`) when a value is not finite, an accel scale is zero, the gyro
  // matrix is singular or ill-conditioned (condition number > 1e12), an effect has a bad axis or
  // regressor, or an applied effect uses `time` but no time origin is given.
  //
  // time_origin_s: the t_s from which the `time` signal counts (the capture start when the
  // effect was fitted; e.g. the first sample's t_s). Needed only by applied time effects.
  static absl::StatusOr<Corrector> Create(const core::ParamSet& params,
                                          std::optional<double> time_origin_s = std::nullopt);

  // The same corrector counting `time` from time_origin_s (must be finite).
  absl::StatusOr<Corrector> WithTimeOrigin(double time_origin_s) const;

  // Corrects one sample with the static model (a dynamic gyro block needs a Stream).
  // Allocation-free, noexcept, no shared mutable state.
  void Apply(const RawSample& in, CalibratedSample* out) const noexcept;

  // A stateful applier for one sample stream of nominal rate stream_rate_hz (finite, > 0):
  // the static model, then the dynamic gyro block when there is one. InvalidArgument when the
  // rate differs from the block's rate_hz by more than kStreamRateTolerance. Allocates its ring
  // buffer here, once.
  absl::StatusOr<Stream> NewStream(double stream_rate_hz) const;
  static constexpr double kStreamRateTolerance = 0.02;

  // True when the parameter set has a dynamic gyro block (applied by a Stream only).
  bool has_dynamic_gyro() const { return dynamic_gyro_ != nullptr; }
  const core::DynamicGyro* dynamic_gyro() const { return dynamic_gyro_.get(); }

  // Applies to in[i] -> out[i]. InvalidArgument (nothing written) if the sizes differ.
  absl::Status ApplyBatch(std::span<const RawSample> in, std::span<CalibratedSample> out) const;

  // True if some applied effect reads temperature: samples then need temp_c.
  bool NeedsTemperature() const { return needs_temperature_; }
  // True if some applied effect reads time (a time origin was then required by Create).
  bool NeedsTime() const { return needs_time_; }
  int num_applied_effects() const { return num_applied_effects_; }
  std::optional<double> time_origin_s() const { return time_origin_s_; }

  // The input units the parameters expect. Samples in any other unit must be refused:
  // CheckInputUnits says which one differs.
  core::AccelUnit accel_unit() const { return accel_unit_; }
  core::GyroUnit gyro_unit() const { return gyro_unit_; }
  // False: the parameter set has no gyroscope part; Apply leaves the gyro as read.
  bool has_gyro() const { return has_gyro_; }
  absl::Status CheckInputUnits(core::AccelUnit accel, core::GyroUnit gyro) const;

 private:
  explicit Corrector(core::SampleCorrection applier) : applier_(std::move(applier)) {}

  core::SampleCorrection applier_;
  // Shared by copies and their Streams: a DynamicGyroState points at it, so it must not move.
  std::shared_ptr<const core::DynamicGyro> dynamic_gyro_;
  bool has_gyro_ = true;
  int num_applied_effects_ = 0;
  bool needs_temperature_ = false;
  bool needs_time_ = false;
  std::optional<double> time_origin_s_;
  core::AccelUnit accel_unit_ = core::AccelUnit::kMetersPerSecond2;
  core::GyroUnit gyro_unit_ = core::GyroUnit::kRadPerSecond;
};

// One sample stream's applier (Corrector::NewStream): holds a copy of the Corrector and, with a
// dynamic gyro block, its core::DynamicGyroState. Not thread-safe: one per stream. Movable.
class Stream {
 public:
  // What the stream has seen (with a dynamic gyro block; all 0 without one).
  struct Counts {
    int64_t samples = 0;
    int64_t outside_envelope = 0;
    int64_t interval_off_rate = 0;
    int64_t restarts = 0;  // window restarts: t_s not increasing, or a gap longer than the window
  };

  // Corrects one sample: Corrector::Apply, then the dynamic gyro block on the gyro. Allocation-
  // free, noexcept, O(window) per sample.
  void Apply(const RawSample& in, CalibratedSample* out) noexcept;
  // Restarts the window (a new power-up, a known gap): the next sample is the first again.
  void Reset() noexcept;

  const Counts& counts() const { return counts_; }
  const Corrector& corrector() const { return corrector_; }

 private:
  friend class Corrector;
  explicit Stream(Corrector corrector);

  Corrector corrector_;
  std::optional<core::DynamicGyroState> state_;  // with a dynamic gyro block only
  double period_s_ = 0.0;                        // 1 / the block's rate_hz
  double max_gap_s_ = 0.0;                       // the window's span: beyond it, restart
  double prev_t_s_ = std::numeric_limits<double>::quiet_NaN();
  Counts counts_;
};

}  // namespace imucal::sdk

#endif  // IMUCAL_CLIENT_SDK_CORRECTOR_H_
