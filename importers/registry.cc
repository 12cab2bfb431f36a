#include "importers/registry.h"

#include <sys/stat.h>

#include <array>
#include <cmath>
#include <cstddef>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/capture.h"
#include "importers/columns.h"
#include "importers/euroc.h"
#include "importers/imucal_csv.h"
#include "importers/imutk.h"
#include "importers/rosbag2.h"
#include "importers/text_scan.h"
#include "util/str_util.h"

namespace imucal::importers {
namespace {

// A time interval above this multiple of the median is reported as a gap.
constexpr double kGapFactor = 3.0;

const CaptureImporter* FindImporter(std::string_view name) {
  for (const CaptureImporter* importer : CaptureImporters()) {
    if (importer->name() == name) return importer;
  }
  return nullptr;
}

absl::StatusOr<const CaptureImporter*> DetectImporter(const std::vector<std::string>& paths) {
  std::vector<std::string> heads;
  heads.reserve(paths.size());
  for (const std::string& path : paths) {
    struct stat info;
    if (::stat(path.c_str(), &info) == 0 && S_ISDIR(info.st_mode)) {
      heads.emplace_back();  // a directory (a ROS 2 bag): its importer looks at the path
      continue;
    }
    absl::StatusOr<std::string> head = ReadFileBytes(path, kSniffBytes);
    if (!head.ok()) return head.status();
    heads.push_back(*std::move(head));
  }
  std::vector<std::string> reasons;
  for (const CaptureImporter* importer : CaptureImporters()) {
    const absl::Status sniff = importer->Sniff(paths, heads);
    if (sniff.ok()) return importer;
    reasons.push_back(Cat(importer->name(), ": ", sniff.message()));
  }
  return absl::InvalidArgumentError(
      Cat(paths[0], ": unrecognised capture format (tried ", Join(reasons, "; "), ")"));
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// The registry.

std::span<const CaptureImporter* const> CaptureImporters() {
  // Order is the auto-detection order: explicit markers (imucal, EuRoC's header) before content
  // heuristics; a bag is a directory or an SQLite file, which no text format accepts.
  static const std::array<const CaptureImporter*, 5> kImporters = {
      ImucalCsvImporter(), EurocCsvImporter(), ImuTkImporter(),
      ColumnCsvImporter(), Rosbag2Importer(),
  };
  return kImporters;
}

absl::StatusOr<core::Capture> ImportCapture(const std::vector<std::string>& paths,
                                            const ImportOptions& options, ImportReport* report) {
  if (paths.empty()) return absl::InvalidArgumentError("no input files given");
  if (absl::Status s = CheckImportOptions(options); !s.ok()) return s;

  const CaptureImporter* importer = nullptr;
  if (options.format == "auto" && !options.columns.map.empty()) {
    importer = FindImporter("columns");
  } else if (options.format == "auto") {
    absl::StatusOr<const CaptureImporter*> detected = DetectImporter(paths);
    if (!detected.ok()) return detected.status();
    importer = *detected;
  } else {
    importer = FindImporter(options.format);
    if (importer == nullptr) {
      std::vector<std::string_view> names = {"auto"};
      for (const CaptureImporter* known : CaptureImporters()) names.push_back(known->name());
      return absl::InvalidArgumentError(
          Cat("unknown capture format '", options.format, "' (known: ", Join(names, ", "), ")"));
    }
  }

  std::vector<std::string> used_paths;
  std::vector<std::string> notes;
  absl::StatusOr<core::Capture> capture = importer->Import(paths, options, &used_paths, &notes);
  if (!capture.ok()) return capture.status();
  // Every importer promises this; checking here keeps a new importer's slip from reaching the
  // solvers as a confusing numerical failure.
  if (absl::Status s = core::ValidateCapture(*capture); !s.ok()) {
    return absl::InvalidArgumentError(Cat(Join(used_paths, ", "), ": ", s.message()));
  }
  if (report != nullptr) {
    report->format = std::string(importer->name());
    report->paths = std::move(used_paths);
    report->notes = std::move(notes);
  }
  return capture;
}

// ---------------------------------------------------------------------------------------------
// Shared by the importers.

absl::Status CheckOnePath(std::string_view format, std::string_view what,
                          const std::vector<std::string>& paths) {
  if (paths.size() == 1) return absl::OkStatus();
  return absl::InvalidArgumentError(Cat("the ", format, " format reads one ", what, ", got ",
                                        paths.size(), ": ", Join(paths, ", ")));
}

absl::Status CheckImportOptions(const ImportOptions& options) {
  if (options.gravity_m_s2.has_value() &&
      !(std::isfinite(*options.gravity_m_s2) && *options.gravity_m_s2 > 0.0)) {
    return absl::InvalidArgumentError(Cat("gravity override must be a positive number, got ",
                                          FormatDouble(*options.gravity_m_s2)));
  }
  return absl::OkStatus();
}

void ApplyImportOverrides(const ImportOptions& options, core::Capture* capture,
                          std::vector<std::string>* notes) {
  if (options.device.has_value() && *options.device != capture->device) {
    notes->push_back(capture->device.empty()
                         ? Cat("device '", *options.device, "' given (the file names none)")
                         : Cat("device '", *options.device, "' used instead of the file's '",
                               capture->device, "'"));
    capture->device = *options.device;
  }
  if (options.accel_unit.has_value() && *options.accel_unit != capture->accel_unit) {
    notes->push_back(Cat("accel unit ", core::AccelUnitName(*options.accel_unit),
                         " used instead of the file's ", core::AccelUnitName(capture->accel_unit)));
    capture->accel_unit = *options.accel_unit;
  }
  if (options.gyro_unit.has_value() && *options.gyro_unit != capture->gyro_unit) {
    notes->push_back(Cat("gyro unit ", core::GyroUnitName(*options.gyro_unit),
                         " used instead of the file's ", core::GyroUnitName(capture->gyro_unit)));
    capture->gyro_unit = *options.gyro_unit;
  }
  if (options.gravity_m_s2.has_value() && *options.gravity_m_s2 != capture->gravity_m_s2) {
    notes->push_back(Cat("gravity ", FormatDouble(*options.gravity_m_s2),
                         " m/s^2 used instead of the file's ",
                         FormatDouble(capture->gravity_m_s2)));
    capture->gravity_m_s2 = *options.gravity_m_s2;
  }
}

void NoteTimeGaps(const core::Capture& capture, std::vector<std::string>* notes) {
  const double median = capture.MedianDt();
  if (!(median > 0.0)) return;
  size_t gaps = 0;
  size_t largest = 0;
  for (size_t i = 1; i < capture.size(); ++i) {
    const double dt = capture.t_s[i] - capture.t_s[i - 1];
    if (dt > kGapFactor * median) {
      ++gaps;
      if (largest == 0 || dt > capture.t_s[largest] - capture.t_s[largest - 1]) largest = i;
    }
  }
  if (gaps == 0) return;
  notes->push_back(
      Cat("time has ", gaps, " gap", gaps == 1 ? "" : "s", " (an interval over ", kGapFactor,
          "x the median ", FormatDouble(median), " s; the largest ",
          FormatDouble(capture.t_s[largest] - capture.t_s[largest - 1]),
          " s after t=", FormatDouble(capture.t_s[largest - 1]),
          " s): nothing was recorded there, so a rotation inside a gap is not measured"));
}

}  // namespace imucal::importers
