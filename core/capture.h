// The capture model: what every importer produces and every part of imucal consumes.
//
// A capture is a time series of static-and-moving IMU samples in the sensor's own units
// (see ../shared/spec/capture-format.md). Values are kept exactly as read: conversion to SI
// happens only through a calibration (raw counts have an unknown offset and scale).
#ifndef IMUCAL_CORE_CAPTURE_H_
#define IMUCAL_CORE_CAPTURE_H_

#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "util/units.h"

namespace imucal::core {

// Standard gravity, m/s^2 (util/units.h). The default when a capture does not state its local
// gravity.
using ::imucal::kStandardGravity;

enum class AccelUnit { kMetersPerSecond2, kG, kCounts };
enum class GyroUnit { kRadPerSecond, kDegPerSecond, kCounts };
enum class TempUnit { kCelsius, kCounts };

// Names as written in the capture header: "m/s^2", "g", "counts"; "rad/s", "deg/s", "counts".
std::string_view AccelUnitName(AccelUnit unit);
std::string_view GyroUnitName(GyroUnit unit);
std::string_view TempUnitName(TempUnit unit);
absl::StatusOr<AccelUnit> ParseAccelUnit(std::string_view name);
absl::StatusOr<GyroUnit> ParseGyroUnit(std::string_view name);
absl::StatusOr<TempUnit> ParseTempUnit(std::string_view name);

// Nominal factor from the input unit to SI (m/s^2 or rad/s). Counts have no nominal factor:
// the calibration finds it from the data, so these return NaN for kCounts.
double NominalAccelToSi(AccelUnit unit, double gravity_m_s2);
double NominalGyroToSi(GyroUnit unit);

// One file a capture was read from: its samples are [first_sample, the next file's).
struct CaptureFile {
  std::string path;
  size_t first_sample = 0;
};

struct Capture {
  std::string device;  // may be empty
  AccelUnit accel_unit = AccelUnit::kMetersPerSecond2;
  GyroUnit gyro_unit = GyroUnit::kRadPerSecond;
  TempUnit temp_unit = TempUnit::kCelsius;
  double gravity_m_s2 = kStandardGravity;  // local gravity magnitude
  double rate_hz = 0.0;                    // nominal rate from the header; 0 if not given
  // How the units were decided (the report's input_units records it): "declared" (the user
  // named them: --accel-unit / --gyro-unit), "file" (the format or the file's header states
  // them), "inferred" (importers/unit_inference.h); empty for a capture made in memory or a
  // device's registered units.
  std::string accel_unit_source;
  std::string gyro_unit_source;

  // Header keys that imucal does not interpret, in file order, kept for round trips.
  std::vector<std::pair<std::string, std::string>> extra_metadata;

  // One entry per sample, all the same length. `t_s` strictly increasing (seconds, any origin).
  std::vector<double> t_s;
  std::vector<Eigen::Vector3d> accel;  // in accel_unit
  std::vector<Eigen::Vector3d> gyro;   // in gyro_unit; empty when !has_gyro
  std::vector<double> temp;            // in temp_unit; empty when the capture has no temperature

  // Columns beyond t,ax..gz,temp, carried through unchanged: names, then values[column][sample].
  std::vector<std::string> extra_column_names;
  std::vector<std::vector<double>> extra_columns;

  // Where the samples came from (importers fill these; empty for a capture made in memory):
  // the files in order, and each sample's 1-based line in its file (for a bag, its message's
  // ordinal). A capture joined from several files has an unmeasured gap at each file's start:
  // nothing is integrated across it and no pose spans it (FileStarts).
  std::vector<CaptureFile> files;
  std::vector<uint32_t> line;

  // False for an accelerometer-only capture (a file with no gyroscope columns). `gyro` is then
  // empty, never zero-filled: zeros would read as a perfectly still gyroscope to any stage that
  // forgot to ask, and gyro_unit means nothing.
  bool has_gyro = true;

  size_t size() const { return t_s.size(); }
  // The first sample of every file after the first.
  std::vector<size_t> FileStarts() const;
  // The file sample `i` came from (an index into `files`), or -1 when unknown.
  int FileOf(size_t i) const;
  bool has_temp() const { return !temp.empty(); }
  // Median sample interval, seconds; 0 for fewer than two samples.
  double MedianDt() const;
};

// Checks the invariants an importer must guarantee (equal lengths, finite values, strictly
// increasing time). Returns InvalidArgument naming the first sample index at fault.
absl::Status ValidateCapture(const Capture& capture);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_CAPTURE_H_
