// The compact binary form of a batch of raw IMU samples, as stored in `sample_batches.payload`.
//
// Layout, all little-endian, no padding:
//   offset 0  u8   format version (kSampleCodecVersion = 1)
//   offset 1  u8   flags: bit 0 = each sample carries a temperature; other bits must be 0
//   offset 2  u32  count: number of samples
//   offset 6  count records of f64: t_s, ax, ay, az, gx, gy, gz [, temp]
// so a payload is exactly 6 + count * 8 * (7 or 8) bytes (56 or 64 bytes a sample). Values are in
// the device's own units (kept exactly as sent; conversion to SI happens only through a
// calibration). Every value is finite and `t_s` strictly increases within a batch, as in the
// capture format (../shared/spec/capture-format.md).
#ifndef IMUCAL_STORAGE_SAMPLE_CODEC_H_
#define IMUCAL_STORAGE_SAMPLE_CODEC_H_

#include <array>
#include <cstdint>
#include <limits>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace imucal::storage {

inline constexpr uint8_t kSampleCodecVersion = 1;
inline constexpr size_t kSampleHeaderBytes = 6;

struct ImuSample {
  double t_s = 0.0;                                        // seconds, any origin
  std::array<double, 3> accel{};                           // device accel unit
  std::array<double, 3> gyro{};                            // device gyro unit
  double temp = std::numeric_limits<double>::quiet_NaN();  // NaN = not measured
};

// What a payload holds, found without decoding it into samples.
struct EncodedBatchInfo {
  int64_t count = 0;
  bool has_temp = false;
  double first_t_s = std::numeric_limits<double>::quiet_NaN();  // NaN when count == 0
  double last_t_s = std::numeric_limits<double>::quiet_NaN();
};

// Encodes a batch. Temperature is stored when every sample has one and omitted when none has;
// a mix is InvalidArgument, as are non-finite values and a `t_s` that does not increase (the
// message names the sample index and field).
absl::StatusOr<std::string> EncodeSamples(std::span<const ImuSample> samples);

// Checks a payload completely (header, length, every value finite, `t_s` increasing) without
// allocating. DataLoss naming the byte offset on truncated or garbage input.
absl::StatusOr<EncodedBatchInfo> InspectSamples(std::string_view payload);

// Decodes a payload (same checks and errors as InspectSamples). The Into form appends to `out`
// so a session's batches concatenate without copies; on error `out` is left unchanged.
absl::StatusOr<std::vector<ImuSample>> DecodeSamples(std::string_view payload);
absl::Status DecodeSamplesInto(std::string_view payload, std::vector<ImuSample>* out);

}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_SAMPLE_CODEC_H_
