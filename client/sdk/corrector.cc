#include "client/sdk/corrector.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <optional>
#include <string>
#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/correction.h"
#include "core/model.h"
#include "core/regressor.h"
#include "formats/dynamic_gyro_json.h"
#include "formats/params_check.h"
#include "formats/params_json.h"

namespace imucal::sdk {
namespace {

absl::Status PathError(const std::string& path, const std::string& what) {
  return absl::InvalidArgumentError(path + ": " + what);
}

}  // namespace

absl::StatusOr<Corrector> Corrector::Create(const core::ParamSet& params,
                                            std::optional<double> time_origin_s) {
  if (absl::Status s = formats::ModelIsApplicable(params); !s.ok()) return s;
  if (time_origin_s.has_value() && !std::isfinite(*time_origin_s)) {
    return absl::InvalidArgumentError("time origin: not finite");
  }

  // Every effect is checked, applied or not: a malformed one means a malformed parameter set.
  int applied = 0;
  bool needs_temperature = false, needs_time = false;
  for (size_t i = 0; i < params.effects.size(); ++i) {
    const core::Effect& e = params.effects[i];
    const std::string path = "effects[" + std::to_string(i) + "]";
    if (e.axis < 0 || e.axis > 2) return PathError(path + ".axis", "not 0, 1 or 2 (x, y, z)");
    if (!std::isfinite(e.coefficient)) return PathError(path + ".coefficient", "not finite");
    const std::optional<core::Regressor> regressor = core::ParseRegressor(e.regressor);
    if (!regressor.has_value()) {
      return PathError(path + ".regressor", "unknown regressor \"" + e.regressor + "\"");
    }
    const std::string mismatch = core::CentreMismatch(*regressor, params.effect_reference);
    if (!mismatch.empty()) return PathError(path + ".regressor", mismatch);
    if (e.sensor == core::Sensor::kGyro && !params.has_gyro) {
      return PathError(path + ".sensor", "a gyro effect in a parameter set without a gyroscope");
    }
    if (!e.applied) continue;
    ++applied;
    needs_temperature |= core::SampleCorrection::Uses(*regressor, core::Signal::kTemperature);
    if (core::SampleCorrection::Uses(*regressor, core::Signal::kTime)) {
      if (!time_origin_s.has_value()) {
        return PathError(path, "applied effect on \"" + e.regressor +
                                   "\" needs a time origin (Create's time_origin_s, e.g. the "
                                   "first sample's t_s)");
      }
      needs_time = true;
    }
  }
  Corrector c(core::SampleCorrection(params, time_origin_s.value_or(0.0)));
  c.has_gyro_ = params.has_gyro;
  if (params.dynamic_gyro) {
    c.dynamic_gyro_ = std::make_shared<const core::DynamicGyro>(*params.dynamic_gyro);
  }
  c.num_applied_effects_ = applied;
  c.needs_temperature_ = needs_temperature;
  c.needs_time_ = needs_time;
  c.time_origin_s_ = time_origin_s;
  c.accel_unit_ = params.accel_unit;
  c.gyro_unit_ = params.gyro_unit;
  return c;
}

absl::StatusOr<Corrector> Corrector::WithTimeOrigin(double time_origin_s) const {
  if (!std::isfinite(time_origin_s)) return absl::InvalidArgumentError("time origin: not finite");
  Corrector c = *this;
  c.time_origin_s_ = time_origin_s;
  c.applier_.set_time_origin_s(time_origin_s);
  return c;
}

void Corrector::Apply(const RawSample& in, CalibratedSample* out) const noexcept {
  const core::CorrectedSample c =
      applier_.Apply(Eigen::Map<const Eigen::Vector3d>(in.accel),
                     Eigen::Map<const Eigen::Vector3d>(in.gyro), in.temp_c, in.t_s);
  for (int i = 0; i < 3; ++i) {
    out->accel_m_s2[i] = c.accel_m_s2(i);
    out->gyro_rad_s[i] = c.gyro_rad_s(i);
  }
  out->effects_skipped = c.effects_skipped;
}

absl::StatusOr<Stream> Corrector::NewStream(double stream_rate_hz) const {
  if (!(std::isfinite(stream_rate_hz) && stream_rate_hz > 0)) {
    return absl::InvalidArgumentError("stream rate: must be a finite number > 0 (Hz)");
  }
  if (dynamic_gyro_ != nullptr &&
      std::abs(stream_rate_hz / dynamic_gyro_->rate_hz - 1.0) > kStreamRateTolerance) {
    return absl::InvalidArgumentError(
        "stream rate " + std::to_string(stream_rate_hz) + " Hz but dynamic_gyro.rate_hz is " +
        std::to_string(dynamic_gyro_->rate_hz) +
        " Hz (within 2 %): the block's lags and delay are in samples of its rate");
  }
  return Stream(*this);
}

Stream::Stream(Corrector corrector) : corrector_(std::move(corrector)) {
  const core::DynamicGyro* block = corrector_.dynamic_gyro();
  if (block == nullptr) return;
  state_.emplace(*block);  // the ring buffer, allocated once
  period_s_ = 1.0 / block->rate_hz;
  // The window's span, and never less than the two samples the delay term reads.
  max_gap_s_ = std::max(block->WindowSamples(), 2) * period_s_;
}

void Stream::Reset() noexcept {
  if (state_) state_->Reset();
  prev_t_s_ = std::numeric_limits<double>::quiet_NaN();
}

void Stream::Apply(const RawSample& in, CalibratedSample* out) noexcept {
  corrector_.Apply(in, out);
  out->outside_envelope = false;
  out->interval_off_rate = false;
  if (!state_) return;
  ++counts_.samples;
  if (!std::isnan(prev_t_s_)) {
    const double dt_s = in.t_s - prev_t_s_;
    if (!(dt_s > 0) || dt_s > max_gap_s_) {  // time went back, or the window's past is gone
      state_->Reset();
      ++counts_.restarts;
    } else if (std::abs(dt_s / period_s_ - 1.0) > Corrector::kStreamRateTolerance) {
      out->interval_off_rate = true;
      ++counts_.interval_off_rate;
    }
  }
  prev_t_s_ = in.t_s;
  const Eigen::Vector3d w_s(out->gyro_rad_s[0], out->gyro_rad_s[1], out->gyro_rad_s[2]);
  const Eigen::Vector3d a(out->accel_m_s2[0], out->accel_m_s2[1], out->accel_m_s2[2]);
  Eigen::Vector3d w;
  if (!state_->Step(w_s, a, &w)) {
    out->outside_envelope = true;
    ++counts_.outside_envelope;
  }
  for (int i = 0; i < 3; ++i) out->gyro_rad_s[i] = w(i);
}

absl::Status Corrector::ApplyBatch(std::span<const RawSample> in,
                                   std::span<CalibratedSample> out) const {
  if (in.size() != out.size()) {
    return absl::InvalidArgumentError("ApplyBatch: " + std::to_string(in.size()) +
                                      " input samples but " + std::to_string(out.size()) +
                                      " output slots");
  }
  for (size_t i = 0; i < in.size(); ++i) Apply(in[i], &out[i]);
  return absl::OkStatus();
}

absl::Status Corrector::CheckInputUnits(core::AccelUnit accel, core::GyroUnit gyro) const {
  if (accel != accel_unit_) {
    return absl::InvalidArgumentError("accel unit " + std::string(formats::UnitName(accel)) +
                                      " but the parameters expect " +
                                      std::string(formats::UnitName(accel_unit_)));
  }
  if (has_gyro_ && gyro != gyro_unit_) {
    return absl::InvalidArgumentError("gyro unit " + std::string(formats::UnitName(gyro)) +
                                      " but the parameters expect " +
                                      std::string(formats::UnitName(gyro_unit_)));
  }
  return absl::OkStatus();
}

}  // namespace imucal::sdk
