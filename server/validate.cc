#include "server/validate.h"

#include <cmath>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/capture.h"
#include "util/units.h"

namespace imucal::server {
namespace {

constexpr char kAxes[] = "xyz";

// "batch 17, sample 3: accel.y (accel[10])"
std::string Where(const v1::SampleBatch& batch, int sample, std::string_view column, int per_sample,
                  int index) {
  if (per_sample == 1) {
    return absl::StrFormat("batch %d, sample %d: %s (%s[%d])", batch.seq(), sample, column, column,
                           index);
  }
  return absl::StrFormat("batch %d, sample %d: %s.%c (%s[%d])", batch.seq(), sample, column,
                         kAxes[index % per_sample], column, index);
}

std::string NonFinite(double v) {
  if (std::isnan(v)) return "NaN";
  return v > 0 ? "+infinity" : "-infinity";
}

// One packed column: its size (per_sample values per sample), then each value finite and
// within [-limit, limit] (or [min, max] when given).
absl::Status CheckColumn(const v1::SampleBatch& batch,
                         const google::protobuf::RepeatedField<double>& column,
                         std::string_view name, int per_sample, int samples, double min, double max,
                         std::string_view unit) {
  if (column.size() != per_sample * samples) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "batch %d: %s has %d values, expected %d (%d per sample for the %d samples in t_s)",
        batch.seq(), name, column.size(), per_sample * samples, per_sample, samples));
  }
  for (int i = 0; i < column.size(); ++i) {
    const double v = column[i];
    if (!std::isfinite(v)) {
      return absl::InvalidArgumentError(
          absl::StrCat(Where(batch, i / per_sample, name, per_sample, i), " is ", NonFinite(v)));
    }
    if (v < min || v > max) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s = %g %s is outside the physical range %g..%g %s",
          Where(batch, i / per_sample, name, per_sample, i), v, unit, min, max, unit));
    }
  }
  return absl::OkStatus();
}

}  // namespace

double AccelLimit(std::string_view unit) {
  if (unit == "m/s^2") return kMaxAccelG * core::kStandardGravity;
  if (unit == "g") return kMaxAccelG;
  return kMaxCounts;
}

double GyroLimit(std::string_view unit) {
  if (unit == "rad/s") return kMaxGyroRadS;
  if (unit == "deg/s") return kMaxGyroRadS * kRadToDeg;
  return kMaxCounts;
}

absl::Status ValidateBatchColumns(const v1::SampleBatch& batch, std::string_view accel_unit,
                                  std::string_view gyro_unit, const IngestLimits& limits) {
  if (batch.seq() < 1) {
    return absl::InvalidArgumentError(
        absl::StrFormat("batch %d: seq must be 1 or more (1, 2, 3, ... per session)", batch.seq()));
  }
  const int n = batch.t_s_size();
  if (n == 0) {
    return absl::InvalidArgumentError(
        absl::StrFormat("batch %d: t_s is empty; a batch carries 1 or more samples", batch.seq()));
  }
  if (n > limits.max_batch_samples) {
    return absl::ResourceExhaustedError(
        absl::StrFormat("batch %d: t_s has %d samples, at most %d per batch; send smaller batches",
                        batch.seq(), n, limits.max_batch_samples));
  }
  const double a = AccelLimit(accel_unit), g = GyroLimit(gyro_unit);
  if (absl::Status s = CheckColumn(batch, batch.accel(), "accel", 3, n, -a, a, accel_unit); !s.ok())
    return s;
  if (absl::Status s = CheckColumn(batch, batch.gyro(), "gyro", 3, n, -g, g, gyro_unit); !s.ok())
    return s;
  if (batch.temp_c_size() != 0) {
    if (absl::Status s =
            CheckColumn(batch, batch.temp_c(), "temp_c", 1, n, kMinTempC, kMaxTempC, "degC");
        !s.ok())
      return s;
  }
  return absl::OkStatus();
}

absl::Status ValidateBatchTimes(const v1::SampleBatch& batch, double last_t_s) {
  for (int i = 0; i < batch.t_s_size(); ++i) {
    const double t = batch.t_s(i);
    if (!std::isfinite(t)) {
      return absl::InvalidArgumentError(
          absl::StrCat(Where(batch, i, "t_s", 1, i), " is ", NonFinite(t)));
    }
    if (std::abs(t) > kMaxAbsTimeS) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s = %g s is beyond +-%g s", Where(batch, i, "t_s", 1, i), t, kMaxAbsTimeS));
    }
    const double previous = i > 0 ? batch.t_s(i - 1) : last_t_s;
    if (!std::isnan(previous) && !(t > previous)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s = %.9g s is not after %s (%.9g s); times must strictly increase",
          Where(batch, i, "t_s", 1, i), t,
          i > 0 ? "the previous sample" : "the session's last stored sample", previous));
    }
  }
  return absl::OkStatus();
}

absl::Status ValidateSessionRoom(const v1::SampleBatch& batch, std::string_view session_id,
                                 int64_t stored_samples, const IngestLimits& limits) {
  const int64_t after = stored_samples + batch.t_s_size();
  if (after > limits.max_session_samples) {
    return absl::ResourceExhaustedError(absl::StrFormat(
        "batch %d: session %s holds %d samples and may hold at most %d; solve it or start a new "
        "session",
        batch.seq(), session_id, stored_samples, limits.max_session_samples));
  }
  return absl::OkStatus();
}

}  // namespace imucal::server
