#include "importers/imutk.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstddef>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/capture.h"
#include "importers/registry.h"
#include "importers/text_scan.h"
#include "importers/unit_inference.h"
#include "util/parallel.h"
#include "util/str_util.h"

namespace imucal::importers {
namespace {

// One file of an imu_tk pair.
struct ImuTkSeries {
  std::vector<double> t_s;
  std::vector<Eigen::Vector3d> xyz;
  std::vector<int> line_numbers;  // of each sample, for pair-mismatch messages
  int last_line = 0;              // number of lines in the file
};

constexpr std::array<std::string_view, 4> kImuTkColumns = {"t", "x", "y", "z"};

// Splits a line on spaces and tabs into at most `fields.size()` fields; returns how many there
// are in total (which may exceed fields.size()).
size_t SplitWhitespace(std::string_view line, std::span<std::string_view> fields) {
  size_t count = 0;
  const char* p = line.data();
  const char* const end = p + line.size();
  while (true) {
    while (p != end && IsSpace(*p)) ++p;
    if (p == end) break;
    const char* start = p;
    while (p != end && !IsSpace(*p)) ++p;
    if (count < fields.size())
      fields[count] = std::string_view(start, static_cast<size_t>(p - start));
    ++count;
  }
  return count;
}

// Fast path for one imu_tk line: exactly four finite numbers separated by spaces or tabs.
// Returns false for anything else, blank lines included.
bool TryParseImuTkLine(std::string_view line, std::array<double, kImuTkColumns.size()>& values) {
  const char* p = line.data();
  const char* const end = p + line.size();
  for (double& value : values) {
    p = ScanNumber(p, end, &value);
    if (p == nullptr || (p != end && !IsSpace(*p))) return false;
  }
  while (p != end && IsSpace(*p)) ++p;
  return p == end;
}

// Describes what is wrong with a non-blank line that TryParseImuTkLine rejected.
absl::Status DiagnoseImuTkLine(std::string_view line, std::string_view source, int line_number) {
  std::array<std::string_view, kImuTkColumns.size()> fields;
  const size_t count = SplitWhitespace(line, fields);
  if (count != fields.size()) {
    return LineError(source, line_number, Cat("expected 4 fields (t x y z), found ", count));
  }
  for (size_t c = 0; c < fields.size(); ++c) {
    double value;
    const NumberError error = ParseNumber(fields[c], &value);
    if (error != NumberError::kNone) {
      return NumberFieldError(source, line_number, kImuTkColumns[c], fields[c], error);
    }
  }
  // Unreachable while TryParseImuTkLine accepts exactly what ParseNumber accepts.
  return LineError(source, line_number, "malformed line");
}

absl::StatusOr<ImuTkSeries> ParseImuTkText(std::string_view text, std::string_view source) {
  ImuTkSeries series;
  const size_t rows = CountLines(text);
  series.t_s.reserve(rows);
  series.xyz.reserve(rows);
  series.line_numbers.reserve(rows);
  LineCursor lines(text);
  std::string_view line;
  std::array<double, kImuTkColumns.size()> values;
  while (lines.Next(&line)) {
    const int line_number = lines.line_number();
    if (line_number == 1) line = WithoutBom(line);
    if (!TryParseImuTkLine(line, values)) {
      if (IsBlank(line)) continue;
      return DiagnoseImuTkLine(line, source, line_number);
    }
    if (!series.t_s.empty() && !(values[0] > series.t_s.back())) {
      return TimeNotIncreasingError(source, line_number, values[0], series.t_s.back(),
                                    series.line_numbers.back());
    }
    series.t_s.push_back(values[0]);
    series.xyz.emplace_back(values[1], values[2], values[3]);
    series.line_numbers.push_back(line_number);
  }
  series.last_line = std::max(lines.line_number(), 1);
  if (series.t_s.empty()) {
    return LineError(source, series.last_line, "no samples (expected lines of 't x y z')");
  }
  return series;
}

// Timestamps of the two files must agree to the precision of the text; 1 us is far below any
// IMU sample interval and far above double rounding of a decimal timestamp.
constexpr double kImuTkTimeToleranceS = 1e-6;

absl::Status CheckImuTkPairAligned(const ImuTkSeries& accel, std::string_view accel_name,
                                   const ImuTkSeries& gyro, std::string_view gyro_name) {
  const size_t common = std::min(accel.t_s.size(), gyro.t_s.size());
  for (size_t i = 0; i < common; ++i) {
    if (std::abs(accel.t_s[i] - gyro.t_s[i]) > kImuTkTimeToleranceS) {
      return LineError(gyro_name, gyro.line_numbers[i],
                       Cat("t=", FormatDouble(gyro.t_s[i]), " does not match ", accel_name, ":",
                           accel.line_numbers[i], " (t=", FormatDouble(accel.t_s[i]), ")"));
    }
  }
  if (accel.t_s.size() == gyro.t_s.size()) return absl::OkStatus();
  const bool gyro_short = gyro.t_s.size() < accel.t_s.size();
  const ImuTkSeries& shorter = gyro_short ? gyro : accel;
  const ImuTkSeries& longer = gyro_short ? accel : gyro;
  const std::string_view shorter_name = gyro_short ? gyro_name : accel_name;
  const std::string_view longer_name = gyro_short ? accel_name : gyro_name;
  return LineError(shorter_name, shorter.last_line,
                   Cat("ends after ", shorter.t_s.size(), " samples, but ", longer_name, " has ",
                       longer.t_s.size(), " (sample ", common + 1, " at ", longer_name, ":",
                       longer.line_numbers[common], ", t=", FormatDouble(longer.t_s[common]), ")"));
}

std::string_view Basename(std::string_view path) {
  const size_t slash = path.find_last_of('/');
  return slash == std::string_view::npos ? path : path.substr(slash + 1);
}

bool NameSays(std::string_view path, std::string_view word, std::string_view other) {
  std::string name(Basename(path));
  for (char& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return name.find(word) != std::string::npos && name.find(other) == std::string::npos;
}

// ---------------------------------------------------------------------------------------------
// The importer.

class ImuTkImporterImpl final : public CaptureImporter {
 public:
  std::string_view name() const override { return "imutk"; }
  std::string_view description() const override {
    return "imu_tk ASCII pair of 't x y z' files: accelerometer, then gyroscope";
  }

  size_t paths_per_capture() const override { return 2; }

  absl::Status Sniff(std::span<const std::string> paths,
                     std::span<const std::string> heads) const override {
    for (size_t i = 0; i < heads.size(); ++i) {
      const std::string label = heads.size() > 1 ? Cat(paths[i], ": ") : std::string();
      if (absl::Status s = SniffOne(label, heads[i]); !s.ok()) return s;
    }
    return absl::OkStatus();
  }

  absl::StatusOr<core::Capture> Import(const std::vector<std::string>& paths,
                                       const ImportOptions& options,
                                       std::vector<std::string>* used_paths,
                                       std::vector<std::string>* notes) const override {
    if (paths.size() != 2) {
      return absl::InvalidArgumentError(
          Cat("the imutk format reads two files (accelerometer, then gyroscope), got ",
              paths.size(), ": ", Join(paths, ", ")));
    }
    *used_paths = paths;
    // The order on the command line is the contract, but file names such as "xsens_gyro.mat
    // xsens_acc.mat" make a swapped order unambiguous, and reading a gyro as an accelerometer
    // would fail much later with a confusing calibration.
    if (NameSays(paths[0], "gyr", "acc") && NameSays(paths[1], "acc", "gyr")) {
      std::swap((*used_paths)[0], (*used_paths)[1]);
      notes->push_back(Cat("swapped the inputs by their names: accelerometer ", (*used_paths)[0],
                           ", gyroscope ", (*used_paths)[1]));
    }
    return ReadImuTkPair((*used_paths)[0], (*used_paths)[1], options, notes);
  }

 private:
  // Looks at the first few complete lines; each must be exactly four numbers, as the parser
  // reads them. `label` names the file in the reason when there are several.
  static absl::Status SniffOne(std::string_view label, std::string_view head) {
    constexpr int kLinesToCheck = 8;
    // A head cut at kSniffBytes may end inside a line; that line is not judged.
    if (head.size() >= kSniffBytes) {
      const size_t last_newline = head.rfind('\n');
      head = last_newline == std::string_view::npos ? std::string_view()
                                                    : head.substr(0, last_newline + 1);
    }
    LineCursor lines(head);
    std::string_view line;
    std::array<double, kImuTkColumns.size()> values;
    int checked = 0;
    while (checked < kLinesToCheck && lines.Next(&line)) {
      if (lines.line_number() == 1) line = WithoutBom(line);
      if (IsBlank(line)) continue;
      ++checked;
      if (!TryParseImuTkLine(line, values)) {
        return absl::InvalidArgumentError(Cat(label, "line ", lines.line_number(),
                                              " is not four numbers 't x y z' (",
                                              Quoted(TrimSpaces(line)), ")"));
      }
    }
    if (checked == 0) return absl::InvalidArgumentError(Cat(label, "no 't x y z' lines"));
    return absl::OkStatus();
  }
};

}  // namespace

absl::StatusOr<core::Capture> ParseImuTkPair(std::string_view accel_text,
                                             std::string_view accel_name,
                                             std::string_view gyro_text, std::string_view gyro_name,
                                             const ImportOptions& options,
                                             std::vector<std::string>* notes) {
  if (absl::Status s = CheckImportOptions(options); !s.ok()) return s;
  // The two files are parsed side by side (options.threads); the accelerometer's error first.
  absl::StatusOr<ImuTkSeries> accel, gyro;
  ParallelFor(2, options.threads, [&](size_t i) {
    if (i == 0) accel = ParseImuTkText(accel_text, accel_name);
    if (i == 1) gyro = ParseImuTkText(gyro_text, gyro_name);
  });
  if (!accel.ok()) return accel.status();
  if (!gyro.ok()) return gyro.status();
  if (absl::Status s = CheckImuTkPairAligned(*accel, accel_name, *gyro, gyro_name); !s.ok()) {
    return s;
  }

  core::Capture capture;
  capture.device = options.device.value_or("");
  capture.gravity_m_s2 = options.gravity_m_s2.value_or(core::kStandardGravity);
  // Lines are the accelerometer file's (the gyroscope's, row by row, are checked to match).
  capture.line.assign(accel->line_numbers.begin(), accel->line_numbers.end());
  capture.t_s = std::move(accel->t_s);
  capture.accel = std::move(accel->xyz);
  capture.gyro = std::move(gyro->xyz);
  ApplyOrInferUnits(options, &capture, notes);
  return capture;
}

absl::StatusOr<core::Capture> ReadImuTkPair(const std::string& accel_path,
                                            const std::string& gyro_path,
                                            const ImportOptions& options,
                                            std::vector<std::string>* notes) {
  absl::StatusOr<std::string> accel_text = ReadFileBytes(accel_path, std::nullopt);
  if (!accel_text.ok()) return accel_text.status();
  absl::StatusOr<std::string> gyro_text = ReadFileBytes(gyro_path, std::nullopt);
  if (!gyro_text.ok()) return gyro_text.status();
  return ParseImuTkPair(*accel_text, accel_path, *gyro_text, gyro_path, options, notes);
}

const CaptureImporter* ImuTkImporter() {
  static const auto* const kImporter = new ImuTkImporterImpl();
  return kImporter;
}

}  // namespace imucal::importers
