#include "importers/registry.h"

#include <sys/stat.h>

#include <algorithm>
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
#include "importers/mcap.h"
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

// One capture read by `importer`, its files recorded (core::Capture::files).
absl::StatusOr<core::Capture> ImportOne(const CaptureImporter& importer,
                                        const std::vector<std::string>& paths,
                                        const ImportOptions& options,
                                        std::vector<std::string>* used_paths,
                                        std::vector<std::string>* notes) {
  absl::StatusOr<core::Capture> capture = importer.Import(paths, options, used_paths, notes);
  if (capture.ok() && capture->files.empty() && !used_paths->empty())
    capture->files.push_back({(*used_paths)[0], 0});
  return capture;
}

// `paths` as one capture, or as several of the importer's size joined in order.
absl::StatusOr<core::Capture> ImportParts(const CaptureImporter& importer,
                                          const std::vector<std::string>& paths,
                                          const ImportOptions& options,
                                          std::vector<std::string>* used_paths,
                                          std::vector<std::string>* notes) {
  const size_t per = importer.paths_per_capture();
  if (paths.size() <= per) return ImportOne(importer, paths, options, used_paths, notes);
  if (paths.size() % per != 0) {
    return absl::InvalidArgumentError(Cat("the ", importer.name(), " format reads its files in ",
                                          per, "s, got ", paths.size(), ": ", Join(paths, ", ")));
  }
  std::vector<core::Capture> parts;
  for (size_t k = 0; k < paths.size(); k += per) {
    const std::vector<std::string> part(paths.begin() + static_cast<long>(k),
                                        paths.begin() + static_cast<long>(k + per));
    std::vector<std::string> part_used, part_notes;
    absl::StatusOr<core::Capture> capture =
        ImportOne(importer, part, options, &part_used, &part_notes);
    if (!capture.ok()) return capture.status();
    // A note that every file repeats (the same columns, units) is said once.
    for (std::string& n : part_notes) {
      const bool said = std::find(notes->begin(), notes->end(), n) != notes->end();
      if (!said) notes->push_back(k == 0 ? n : Cat(Join(part_used, ", "), ": ", n));
    }
    used_paths->insert(used_paths->end(), part_used.begin(), part_used.end());
    parts.push_back(*std::move(capture));
  }
  return JoinCaptures(std::move(parts), notes);
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// The registry.

std::span<const CaptureImporter* const> CaptureImporters() {
  // Order is the auto-detection order: explicit markers (imucal, EuRoC's header) before content
  // heuristics; a bag is a directory, an SQLite or an MCAP file, which no text format accepts.
  static const std::array<const CaptureImporter*, 6> kImporters = {
      ImucalCsvImporter(), EurocCsvImporter(), ImuTkImporter(),
      ColumnCsvImporter(), Rosbag2Importer(),  McapImporter(),
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
    // Several captures of a one-file format: detected from the first.
    if (!detected.ok() && paths.size() > 1) {
      absl::StatusOr<const CaptureImporter*> first = DetectImporter({paths[0]});
      if (first.ok() && (*first)->paths_per_capture() == 1) detected = first;
    }
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
  absl::StatusOr<core::Capture> capture =
      ImportParts(*importer, paths, options, &used_paths, &notes);
  if (!capture.ok()) return capture.status();
  // How the units were decided: named by the user, else as the importer set it (inferred),
  // else the format's or the file's own.
  for (auto [declared, source] :
       {std::pair{options.accel_unit.has_value(), &capture->accel_unit_source},
        std::pair{options.gyro_unit.has_value(), &capture->gyro_unit_source}}) {
    if (declared) {
      *source = "declared";
    } else if (source->empty()) {
      *source = "file";
    }
  }
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

absl::StatusOr<core::Capture> JoinCaptures(std::vector<core::Capture> parts,
                                           std::vector<std::string>* notes) {
  if (parts.empty()) return absl::InvalidArgumentError("no captures to join");
  auto file_name = [](const core::Capture& c) {
    return c.files.empty() ? std::string("(in memory)") : c.files[0].path;
  };
  core::Capture out = std::move(parts[0]);
  bool temp = out.has_temp();
  bool extras = true;
  for (size_t k = 1; k < parts.size(); ++k) {
    const core::Capture& p = parts[k];
    if (p.has_gyro != out.has_gyro) {
      const core::Capture& without = p.has_gyro ? out : p;
      return absl::InvalidArgumentError(
          Cat("the files do not agree on the sensors: ", file_name(without),
              " has no gyroscope columns and ", file_name(p.has_gyro ? p : out),
              " has (calibrate accelerometer-only files on their own)"));
    }
    if (p.accel_unit != out.accel_unit || (out.has_gyro && p.gyro_unit != out.gyro_unit)) {
      return absl::InvalidArgumentError(
          Cat("the files do not agree on units: ", file_name(out), " has accel ",
              core::AccelUnitName(out.accel_unit), ", gyro ", core::GyroUnitName(out.gyro_unit),
              "; ", file_name(p), " has accel ", core::AccelUnitName(p.accel_unit), ", gyro ",
              core::GyroUnitName(p.gyro_unit), " (give --accel-unit and --gyro-unit)"));
    }
    temp &= p.has_temp() && p.temp_unit == out.temp_unit;
    extras &= p.extra_column_names == out.extra_column_names;
  }
  if (!temp && out.has_temp()) notes->push_back("temperature left out: not every file has it");
  if (!extras && !out.extra_column_names.empty())
    notes->push_back("extra columns left out: the files name different ones");
  if (!temp) out.temp.clear();
  if (!extras) {
    out.extra_column_names.clear();
    out.extra_columns.clear();
  }
  int shifted = 0;
  for (size_t k = 1; k < parts.size(); ++k) {
    core::Capture& p = parts[k];
    const double dt = std::max(out.MedianDt(), p.MedianDt());
    const double gap = std::max(1.0, 10 * dt);
    const double start = out.t_s.back() + gap;
    if (p.t_s.front() < start) {
      const double shift = start - p.t_s.front();
      for (double& t : p.t_s) t += shift;
      ++shifted;
    }
    const size_t first = out.size();
    for (core::CaptureFile f : p.files) {
      f.first_sample += first;
      out.files.push_back(std::move(f));
    }
    if (p.files.empty()) out.files.push_back({"(in memory)", first});
    out.t_s.insert(out.t_s.end(), p.t_s.begin(), p.t_s.end());
    out.accel.insert(out.accel.end(), p.accel.begin(), p.accel.end());
    out.gyro.insert(out.gyro.end(), p.gyro.begin(), p.gyro.end());
    if (temp) out.temp.insert(out.temp.end(), p.temp.begin(), p.temp.end());
    if (extras)
      for (size_t c = 0; c < out.extra_columns.size(); ++c)
        out.extra_columns[c].insert(out.extra_columns[c].end(), p.extra_columns[c].begin(),
                                    p.extra_columns[c].end());
    if (out.line.size() + p.size() == out.size() && p.line.size() == p.size()) {
      out.line.insert(out.line.end(), p.line.begin(), p.line.end());
    } else {
      out.line.clear();
    }
  }
  notes->push_back(Cat("joined ", parts.size(),
                       " captures in the order given, with an unmeasured gap between each two",
                       shifted > 0
                           ? Cat(" (", shifted, " shifted in time to follow the one before)")
                           : std::string()));
  return out;
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
  if (capture->has_gyro && options.gyro_unit.has_value() &&
      *options.gyro_unit != capture->gyro_unit) {
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
