// EuRoC / ASL IMU CSV (imu0/data.csv of the EuRoC MAV datasets and of Kalibr/ASL tools):
//
//   #timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],
//       a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]
//   1403636579758555392,-0.099134701513277898,0.14730578886832138,0.02722713633111154,...
//
// Columns are found by name (any order; a bracketed unit must be the one above, and extra
// columns are ignored with a note). Timestamps are integer nanoseconds: t_s counts from the first
// one, computed in integers so that no precision is lost to a 1.4e18 origin, and the origin is
// kept in the metadata as `t0_ns`. Units are rad/s and m/s^2 (ImportOptions may override).
// Auto-detected by a first line that starts "#timestamp" and names w_RS_S_x and a_RS_S_x.
#ifndef IMUCAL_IMPORTERS_EUROC_H_
#define IMUCAL_IMPORTERS_EUROC_H_

#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "core/capture.h"
#include "importers/registry.h"

namespace imucal::importers {

// The metadata key that keeps the first timestamp (the origin of t_s), in nanoseconds.
inline constexpr std::string_view kEurocOriginKey = "t0_ns";

absl::StatusOr<core::Capture> ParseEurocCsv(std::string_view text, std::string_view source_name,
                                            const ImportOptions& options,
                                            std::vector<std::string>* notes);

// The "euroc" importer for the registry.
const CaptureImporter* EurocCsvImporter();

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_EUROC_H_
