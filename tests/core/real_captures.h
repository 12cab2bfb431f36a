// How the tests read the real captures under ../shared/data/real through the column-mapped
// importer (docs/formats.md, "Vendor CSV"): the same options a user passes to `imucal calibrate`.
// Shared by real_data_test (the calibration) and real_effects_test (the effect search).
#ifndef IMUCAL_TESTS_CORE_REAL_CAPTURES_H_
#define IMUCAL_TESTS_CORE_REAL_CAPTURES_H_

#include <filesystem>
#include <string>

#include "absl/status/statusor.h"
#include "importers/registry.h"

namespace imucal::core::real_captures {

inline const std::string kRealDir = IMUCAL_SHARED_DIR "/data/real";
inline const std::string kMpu6050 = kRealDir + "/mpu6050-tedaldi-raw/example_data_calibration.csv";
// The same MPU-6050 (same Arduino logger and format): one long rest (449 s), a short rest
// (100 s), and a rest, one turn of about 90 deg about x, and a rest (100 s).
inline const std::string kMpu6050LongRest =
    kRealDir + "/mpu6050-tedaldi-raw/example_data_tinit_calc.csv";
inline const std::string kMpu6050ShortRest = kRealDir + "/mpu6050-tedaldi-raw/imu_static_test.csv";
inline const std::string kMpu6050TurnX90 = kRealDir + "/mpu6050-tedaldi-raw/imu_90_x_rot.csv";
// The MPU-6050's datasheet sensitivities at the logger's ranges (+-2 g, +-250 deg/s; the
// source's README): counts per g and counts per deg/s. Nominal, not calibrated.
inline constexpr double kMpu6050CountsPerG = 16384.0;
inline constexpr double kMpu6050CountsPerDegS = 131.0;
inline const std::string kFerrarisExample =
    kRealDir + "/imucal-ferraris/example_ferraris_session.csv";
inline const std::string kFerrarisAnnotated = kRealDir + "/imucal-ferraris/annotated_session.csv";

// MPU-6050: raw counts, the rate in the preamble ("Fs"), no time column.
inline importers::ImportOptions Mpu6050Options() {
  importers::ImportOptions io;
  io.columns.map = "ax=ax,ay=ay,az=az,gx=gx,gy=gy,gz=gz";
  io.columns.rate_from_preamble = "Fs";
  io.accel_unit = AccelUnit::kCounts;
  io.gyro_unit = GyroUnit::kCounts;
  return io;
}

// mad-lab-fau/imucal's Ferraris example: m/s^2 and deg/s, a sample counter at 102.4 Hz.
inline importers::ImportOptions FerrarisExampleOptions() {
  importers::ImportOptions io;
  io.columns.map = "t=n_samples,ax=acc_x,ay=acc_y,az=acc_z,gx=gyr_x,gy=gyr_y,gz=gyr_z";
  io.columns.time_unit = importers::ColumnTimeUnit::kSampleIndex;
  io.columns.rate_hz = 102.4;
  io.accel_unit = AccelUnit::kMetersPerSecond2;
  io.gyro_unit = GyroUnit::kDegPerSecond;
  return io;
}

// The annotated session: raw counts at 204.8 Hz, saved part by part (rows out of time order).
inline importers::ImportOptions FerrarisAnnotatedOptions() {
  importers::ImportOptions io;
  io.columns.map = "t=samples,ax=acc_x,ay=acc_y,az=acc_z,gx=gyr_x,gy=gyr_y,gz=gyr_z";
  io.columns.time_unit = importers::ColumnTimeUnit::kSampleIndex;
  io.columns.rate_hz = 204.8;
  io.columns.sort_by_time = true;
  io.accel_unit = AccelUnit::kCounts;
  io.gyro_unit = GyroUnit::kCounts;
  return io;
}

// NotFound when the shared data is not beside the checkout (the caller skips).
inline absl::StatusOr<Capture> ImportColumns(const std::string& path,
                                             const importers::ImportOptions& io) {
  if (!std::filesystem::exists(path)) return absl::NotFoundError(path);
  return importers::ImportCapture({path}, io);
}

}  // namespace imucal::core::real_captures

#endif  // IMUCAL_TESTS_CORE_REAL_CAPTURES_H_
