// The imu_tk ASCII pair (the format of IMU-TK's sample data, e.g. the Xsens capture in
// ../shared/data/real/xsens-imutk).
#ifndef IMUCAL_IMPORTERS_IMUTK_H_
#define IMUCAL_IMPORTERS_IMUTK_H_

#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "core/capture.h"
#include "importers/registry.h"

namespace imucal::importers {

// imu_tk ASCII pair: two files of lines "t x y z" (whitespace separated, no header), the
// accelerometer and the gyroscope, with the same timestamps on the same rows (equal to within
// 1 microsecond, the precision of the text). Blank lines are skipped. Units come from `options`
// or are inferred (importers/unit_inference.h); what was inferred is appended to `notes` if
// non-null.
absl::StatusOr<core::Capture> ParseImuTkPair(std::string_view accel_text,
                                             std::string_view accel_name,
                                             std::string_view gyro_text, std::string_view gyro_name,
                                             const ImportOptions& options,
                                             std::vector<std::string>* notes = nullptr);
absl::StatusOr<core::Capture> ReadImuTkPair(const std::string& accel_path,
                                            const std::string& gyro_path,
                                            const ImportOptions& options,
                                            std::vector<std::string>* notes = nullptr);

// The "imutk" importer for the registry (two files; auto-detected when the first lines of each
// are four numbers). If the file names say "gyr" then "acc", they are swapped back with a note.
const CaptureImporter* ImuTkImporter();

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_IMUTK_H_
