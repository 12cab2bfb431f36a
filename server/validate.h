// What a robot may send, checked at the boundary before anything is converted or stored.
//
// Every refusal names the batch (its seq), the sample, the field and the problem, e.g.
//   batch 17, sample 3: accel.y (accel[10]) is NaN
//   batch 17, sample 0: t_s (t_s[0]) = 1.5 s is not after the session's last stored sample (2 s)
// INVALID_ARGUMENT for malformed content, RESOURCE_EXHAUSTED for a configured limit.
//
// Physical bounds, from the unit the device declared (Device.accel_unit / gyro_unit). They sit
// beyond every MEMS full-scale range, so that only corrupt or mis-scaled data is refused:
//   accelerometer  |a| <= 100 g      (980.665 m/s^2; MEMS parts reach +-32 g, high-g +-64 g)
//   gyroscope      |w| <= 100 rad/s  (5730 deg/s; the widest MEMS range is +-4000 deg/s)
//   counts         |x| <= 2^31       (the device declares no register width: a signed 32-bit
//                                      register is the widest an IMU reports)
//   temp_c         -60 .. 150 degC   (IMU operating ranges are -40 .. 105 degC)
//   t_s            finite, |t| <= 1e12 s, strictly increasing within and across batches
#ifndef IMUCAL_SERVER_VALIDATE_H_
#define IMUCAL_SERVER_VALIDATE_H_

#include <cstdint>
#include <string_view>

#include "absl/status/status.h"
#include "imucal/v1/imucal.pb.h"

namespace imucal::server {

// Operator-facing ingest limits (SessionServiceOptions carries them).
struct IngestLimits {
  // Samples in one SampleBatch (RESOURCE_EXHAUSTED above). 20,000 samples with temperature are
  // 1.1 MB on the wire, a quarter of the default 4 MiB receive limit.
  int64_t max_batch_samples = 20000;
  // Samples one session may hold (RESOURCE_EXHAUSTED above): 200 Hz for 13.9 h, 1 kHz for
  // 2.8 h. A solve holds its session's samples in memory (about 130 bytes each).
  int64_t max_session_samples = 10'000'000;
};

inline constexpr double kMaxAccelG = 100;
inline constexpr double kMaxGyroRadS = 100;
inline constexpr double kMaxCounts = 2147483648.0;  // 2^31
inline constexpr double kMinTempC = -60, kMaxTempC = 150;
inline constexpr double kMaxAbsTimeS = 1e12;

// The largest magnitude a reading in `unit` may have ("m/s^2", "g", "counts"; "rad/s",
// "deg/s", "counts"). An unknown unit gets the counts bound (the device's unit was checked at
// registration).
double AccelLimit(std::string_view unit);
double GyroLimit(std::string_view unit);

// Column sizes, finiteness and magnitudes, independent of the session's history; the batch's
// size against `limits.max_batch_samples`.
absl::Status ValidateBatchColumns(const v1::SampleBatch& batch, std::string_view accel_unit,
                                  std::string_view gyro_unit, const IngestLimits& limits = {});
// The batch's times against the session's last stored sample time (NaN: none yet).
absl::Status ValidateBatchTimes(const v1::SampleBatch& batch, double last_t_s);
// Room for the batch in a session that holds `stored_samples`.
absl::Status ValidateSessionRoom(const v1::SampleBatch& batch, std::string_view session_id,
                                 int64_t stored_samples, const IngestLimits& limits);

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_VALIDATE_H_
