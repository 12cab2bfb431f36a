#include "importers/imucal_csv.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cstddef>
#include <cstdio>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/capture.h"
#include "importers/registry.h"
#include "importers/text_scan.h"
#include "util/str_util.h"

namespace imucal::importers {
namespace {

// ---------------------------------------------------------------------------------------------
// imucal CSV header.

constexpr std::string_view kMarkerPrefix = "# imucal-capture";

constexpr std::string_view kKeyDevice = "device";
constexpr std::string_view kKeyAccelUnit = "accel_unit";
constexpr std::string_view kKeyGyroUnit = "gyro_unit";
constexpr std::string_view kKeyGravity = "gravity";
constexpr std::string_view kKeyRateHz = "rate_hz";
constexpr std::string_view kKeyTempUnit = "temp_unit";
constexpr std::array<std::string_view, 6> kKnownKeys = {kKeyDevice,  kKeyAccelUnit, kKeyGyroUnit,
                                                        kKeyGravity, kKeyRateHz,    kKeyTempUnit};

// The required columns in canonical (written) order; `temp` is optional. The three gyro
// columns (kGyroColumns on) are required together or absent together: a capture without them is
// accelerometer-only (core::Capture::has_gyro), and its `gyro_unit` header is optional.
constexpr std::array<std::string_view, 7> kRequiredColumns = {"t",  "ax", "ay", "az",
                                                              "gx", "gy", "gz"};
constexpr size_t kGyroColumns = 4;
constexpr std::string_view kTempColumn = "temp";

// Where each known header key was first seen (0 = not seen), to reject duplicates and report
// missing required keys.
struct HeaderSeen {
  std::array<int, kKnownKeys.size()> line_of_key{};
};

absl::Status CheckMarkerLine(std::string_view line, std::string_view source) {
  line = WithoutBom(line);
  line = TrimSpaces(line);
  if (line == kImucalCaptureMarker) return absl::OkStatus();
  if (line.starts_with(kMarkerPrefix)) {
    return LineError(source, 1,
                     Cat("unsupported capture version ", Quoted(line), " (this reader knows '",
                         kImucalCaptureMarker, "')"));
  }
  return LineError(source, 1,
                   Cat("missing header marker '", kImucalCaptureMarker,
                       "' on the first line (found ", Quoted(line), ")"));
}

absl::Status ParsePositiveHeaderNumber(std::string_view key, std::string_view value,
                                       bool allow_zero, std::string_view source, int line_number,
                                       double* out) {
  const NumberError error = ParseNumber(value, out);
  if (error == NumberError::kNone && (*out > 0.0 || (allow_zero && *out == 0.0))) {
    return absl::OkStatus();
  }
  return LineError(source, line_number,
                   Cat(key, ": ", Quoted(value), " is not a ",
                       allow_zero ? "non-negative" : "positive", " number"));
}

// Applies one known `key=value` to the capture.
absl::Status ApplyKnownHeader(size_t key_index, std::string_view value, std::string_view source,
                              int line_number, core::Capture* capture) {
  const std::string_view key = kKnownKeys[key_index];
  auto unit_error = [&](const absl::Status& status) {
    return LineError(source, line_number, Cat(key, ": ", status.message()));
  };
  if (key == kKeyDevice) {
    capture->device = std::string(value);
  } else if (key == kKeyAccelUnit) {
    absl::StatusOr<core::AccelUnit> unit = core::ParseAccelUnit(value);
    if (!unit.ok()) return unit_error(unit.status());
    capture->accel_unit = *unit;
  } else if (key == kKeyGyroUnit) {
    absl::StatusOr<core::GyroUnit> unit = core::ParseGyroUnit(value);
    if (!unit.ok()) return unit_error(unit.status());
    capture->gyro_unit = *unit;
  } else if (key == kKeyTempUnit) {
    absl::StatusOr<core::TempUnit> unit = core::ParseTempUnit(value);
    if (!unit.ok()) return unit_error(unit.status());
    capture->temp_unit = *unit;
  } else if (key == kKeyGravity) {
    return ParsePositiveHeaderNumber(key, value, /*allow_zero=*/false, source, line_number,
                                     &capture->gravity_m_s2);
  } else if (key == kKeyRateHz) {
    return ParsePositiveHeaderNumber(key, value, /*allow_zero=*/true, source, line_number,
                                     &capture->rate_hz);
  }
  return absl::OkStatus();
}

// One "# key=value" line. Keys and values are trimmed of surrounding spaces; a bare "#" is
// treated as a blank line.
absl::Status ParseHeaderLine(std::string_view line, std::string_view source, int line_number,
                             HeaderSeen* seen, core::Capture* capture) {
  const std::string_view body = TrimSpaces(line.substr(1));
  if (body.empty()) return absl::OkStatus();
  const size_t equals = body.find('=');
  if (equals == std::string_view::npos) {
    return LineError(source, line_number, Cat("header line is not key=value: ", Quoted(line)));
  }
  const std::string_view key = TrimSpaces(body.substr(0, equals));
  const std::string_view value = TrimSpaces(body.substr(equals + 1));
  if (key.empty()) {
    return LineError(source, line_number, Cat("header line has no key: ", Quoted(line)));
  }
  const auto known = std::find(kKnownKeys.begin(), kKnownKeys.end(), key);
  if (known == kKnownKeys.end()) {
    capture->extra_metadata.emplace_back(std::string(key), std::string(value));
    return absl::OkStatus();
  }
  const size_t key_index = static_cast<size_t>(known - kKnownKeys.begin());
  if (seen->line_of_key[key_index] != 0) {
    return LineError(
        source, line_number,
        Cat("duplicate header '", key, "' (first at line ", seen->line_of_key[key_index], ")"));
  }
  seen->line_of_key[key_index] = line_number;
  return ApplyKnownHeader(key_index, value, source, line_number, capture);
}

absl::Status CheckRequiredHeaders(const HeaderSeen& seen, std::string_view source, int line_number,
                                  bool has_gyro) {
  for (const std::string_view key : {kKeyAccelUnit, kKeyGyroUnit}) {
    if (key == kKeyGyroUnit && !has_gyro) continue;
    const size_t index = static_cast<size_t>(std::find(kKnownKeys.begin(), kKnownKeys.end(), key) -
                                             kKnownKeys.begin());
    if (seen.line_of_key[index] == 0) {
      return LineError(source, line_number, Cat("missing required header '", key, "'"));
    }
  }
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------------------------
// imucal CSV columns and rows.

// Where each field of a row goes: indices into the row for the known columns, and the names of
// every field for error messages.
struct ColumnLayout {
  std::vector<std::string_view> names;                  // views into the text being parsed
  std::array<int, kRequiredColumns.size()> required{};  // t, ax, ay, az, gx, gy, gz
  int temp = -1;
  std::vector<int> extra;  // field index of each extra column, in file order
  bool has_gyro() const { return required[kGyroColumns] >= 0; }
};

// All of t..az, and the gyro columns all or none.
absl::Status CheckRequiredColumns(const ColumnLayout& layout, std::string_view source,
                                  int line_number) {
  size_t gyro_present = 0;
  for (size_t i = kGyroColumns; i < kRequiredColumns.size(); ++i) {
    gyro_present += layout.required[i] >= 0;
  }
  for (size_t i = 0; i < kRequiredColumns.size(); ++i) {
    if (layout.required[i] >= 0 || (i >= kGyroColumns && gyro_present == 0)) continue;
    return LineError(source, line_number,
                     Cat("missing required column '", kRequiredColumns[i], "'",
                         i >= kGyroColumns ? " (give all of gx, gy, gz, or none for an "
                                             "accelerometer-only capture)"
                                           : ""));
  }
  return absl::OkStatus();
}

absl::StatusOr<ColumnLayout> ParseColumnLine(std::string_view line, std::string_view source,
                                             int line_number) {
  ColumnLayout layout;
  layout.required.fill(-1);
  size_t start = 0;
  while (true) {
    const size_t comma = line.find(',', start);
    const std::string_view name =
        TrimSpaces(line.substr(start, comma == std::string_view::npos ? line.npos : comma - start));
    const int index = static_cast<int>(layout.names.size());
    if (name.empty()) {
      return LineError(source, line_number, Cat("column ", index + 1, " has no name"));
    }
    if (std::find(layout.names.begin(), layout.names.end(), name) != layout.names.end()) {
      return LineError(source, line_number, Cat("duplicate column '", name, "'"));
    }
    layout.names.push_back(name);
    const auto known = std::find(kRequiredColumns.begin(), kRequiredColumns.end(), name);
    if (known != kRequiredColumns.end()) {
      layout.required[static_cast<size_t>(known - kRequiredColumns.begin())] = index;
    } else if (name == kTempColumn) {
      layout.temp = index;
    } else {
      layout.extra.push_back(index);
    }
    if (comma == std::string_view::npos) break;
    start = comma + 1;
  }
  if (absl::Status s = CheckRequiredColumns(layout, source, line_number); !s.ok()) return s;
  return layout;
}

// Describes what is wrong with a row that TryParseCsvRow rejected. The field count is checked
// first, so that a short row is reported as such rather than as a bad number in some column.
absl::Status DiagnoseCsvRow(std::string_view line, const ColumnLayout& layout,
                            std::string_view source, int line_number) {
  const size_t field_count = layout.names.size();
  const size_t found = static_cast<size_t>(std::count(line.begin(), line.end(), ',')) + 1;
  if (found != field_count) {
    return LineError(source, line_number, Cat("expected ", field_count, " fields, found ", found));
  }
  size_t start = 0;
  for (size_t c = 0; c < field_count; ++c) {
    const size_t comma = std::min(line.find(',', start), line.size());
    const std::string_view field = line.substr(start, comma - start);
    double value;
    const NumberError error = ParseNumber(field, &value);
    if (error != NumberError::kNone) {
      return NumberFieldError(source, line_number, layout.names[c], field, error);
    }
    start = comma + 1;
  }
  // Unreachable while TryParseCsvRow accepts exactly what ParseNumber accepts.
  return LineError(source, line_number, "malformed row");
}

// Parses the fields of one row into `row` (field_count values) in one scan. Returns false on
// anything irregular (wrong field count, bad or non-finite number); DiagnoseCsvRow then says what.
bool TryParseCsvRow(std::string_view line, size_t field_count, double* row) {
  const char* p = line.data();
  const char* const end = p + line.size();
  for (size_t c = 0; c < field_count; ++c) {
    p = ScanNumber(p, end, &row[c]);
    if (p == nullptr) return false;
    while (p != end && IsSpace(*p)) ++p;
    if (c + 1 < field_count) {
      if (p == end || *p != ',') return false;
      ++p;
    } else if (p != end) {
      return false;
    }
  }
  return true;
}

void ReserveSamples(size_t rows, const ColumnLayout& layout, core::Capture* capture) {
  capture->t_s.reserve(rows);
  capture->line.reserve(rows);
  capture->accel.reserve(rows);
  if (layout.has_gyro()) capture->gyro.reserve(rows);
  if (layout.temp >= 0) capture->temp.reserve(rows);
  capture->extra_column_names.reserve(layout.extra.size());
  capture->extra_columns.resize(layout.extra.size());
  for (size_t k = 0; k < layout.extra.size(); ++k) {
    capture->extra_column_names.emplace_back(layout.names[static_cast<size_t>(layout.extra[k])]);
    capture->extra_columns[k].reserve(rows);
  }
}

absl::Status ParseCsvRows(LineCursor* lines, const ColumnLayout& layout, std::string_view source,
                          core::Capture* capture) {
  ReserveSamples(CountLines(lines->rest()), layout, capture);
  std::vector<double> row(layout.names.size());
  const auto& col = layout.required;
  int previous_line = 0;
  std::string_view line;
  while (lines->Next(&line)) {
    if (line.empty() || (IsSpace(line.front()) && IsBlank(line))) continue;
    const int line_number = lines->line_number();
    if (!TryParseCsvRow(line, row.size(), row.data())) {
      return DiagnoseCsvRow(line, layout, source, line_number);
    }
    const double t_s = row[static_cast<size_t>(col[0])];
    if (previous_line != 0 && !(t_s > capture->t_s.back())) {
      return TimeNotIncreasingError(source, line_number, t_s, capture->t_s.back(), previous_line);
    }
    previous_line = line_number;
    capture->line.push_back(static_cast<uint32_t>(line_number));
    capture->t_s.push_back(t_s);
    auto at = [&](size_t k) { return row[static_cast<size_t>(col[k])]; };
    capture->accel.emplace_back(at(1), at(2), at(3));
    if (layout.has_gyro()) capture->gyro.emplace_back(at(4), at(5), at(6));
    if (layout.temp >= 0) capture->temp.push_back(row[static_cast<size_t>(layout.temp)]);
    for (size_t k = 0; k < layout.extra.size(); ++k) {
      capture->extra_columns[k].push_back(row[static_cast<size_t>(layout.extra[k])]);
    }
  }
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------------------------
// imucal CSV writing.

absl::Status CheckTextSafe(std::string_view text, std::string_view what) {
  if (text.find_first_of("\r\n") != std::string_view::npos) {
    return absl::InvalidArgumentError(Cat(what, " ", Quoted(text), " contains a line break"));
  }
  if (TrimSpaces(text) != text) {
    return absl::InvalidArgumentError(
        Cat(what, " ", Quoted(text), " has leading or trailing spaces, which a reader trims"));
  }
  return absl::OkStatus();
}

absl::Status CheckMetadataWritable(const core::Capture& capture) {
  if (absl::Status s = CheckTextSafe(capture.device, "device"); !s.ok()) return s;
  for (const auto& [key, value] : capture.extra_metadata) {
    if (key.empty() || key.find('=') != std::string::npos) {
      return absl::InvalidArgumentError(
          Cat("metadata key ", Quoted(key), " is empty or contains '='"));
    }
    if (std::find(kKnownKeys.begin(), kKnownKeys.end(), key) != kKnownKeys.end()) {
      return absl::InvalidArgumentError(
          Cat("metadata key '", key, "' is a field of Capture; set the field instead"));
    }
    if (absl::Status s = CheckTextSafe(key, "metadata key"); !s.ok()) return s;
    if (absl::Status s = CheckTextSafe(value, "metadata value"); !s.ok()) return s;
  }
  return absl::OkStatus();
}

absl::Status CheckColumnNamesWritable(const core::Capture& capture) {
  const auto& names = capture.extra_column_names;
  for (size_t i = 0; i < names.size(); ++i) {
    const std::string& name = names[i];
    if (name.empty() || name.find(',') != std::string::npos) {
      return absl::InvalidArgumentError(
          Cat("extra column name ", Quoted(name), " is empty or contains ','"));
    }
    if (absl::Status s = CheckTextSafe(name, "extra column name"); !s.ok()) return s;
    if (std::find(kRequiredColumns.begin(), kRequiredColumns.end(), name) !=
            kRequiredColumns.end() ||
        name == kTempColumn) {
      return absl::InvalidArgumentError(
          Cat("extra column name '", name, "' is reserved for a known column"));
    }
    if (std::find(names.begin(), names.begin() + static_cast<std::ptrdiff_t>(i), name) !=
        names.begin() + static_cast<std::ptrdiff_t>(i)) {
      return absl::InvalidArgumentError(Cat("duplicate extra column '", name, "'"));
    }
  }
  return absl::OkStatus();
}

// Longest shortest-form double: "-2.2250738585072014e-308".
constexpr size_t kMaxDoubleChars = 24;

// Writes one CSV row of doubles into a buffer sized by the caller.
class RowWriter {
 public:
  RowWriter(char* begin, char* limit) : cursor_(begin), limit_(limit) {}
  void Add(double value) {
    if (!first_) *cursor_++ = ',';
    first_ = false;
    cursor_ = std::to_chars(cursor_, limit_, value).ptr;
  }
  void EndRow() { *cursor_++ = '\n'; }
  const char* end() const { return cursor_; }

 private:
  char* cursor_;
  char* const limit_;
  bool first_ = true;
};

// ---------------------------------------------------------------------------------------------
// The importer.

class ImucalCsvImporterImpl final : public CaptureImporter {
 public:
  std::string_view name() const override { return "imucal"; }
  std::string_view description() const override {
    return "imucal capture CSV (one file starting '# imucal-capture v1')";
  }

  absl::Status Sniff(std::span<const std::string> /*paths*/,
                     std::span<const std::string> heads) const override {
    std::string_view head = heads[0];
    head = WithoutBom(head);
    if (head.starts_with(kMarkerPrefix)) return absl::OkStatus();
    return absl::InvalidArgumentError(Cat("first line does not start with '", kMarkerPrefix, "'"));
  }

  absl::StatusOr<core::Capture> Import(const std::vector<std::string>& paths,
                                       const ImportOptions& options,
                                       std::vector<std::string>* used_paths,
                                       std::vector<std::string>* notes) const override {
    if (absl::Status s = CheckOnePath("imucal", "file", paths); !s.ok()) return s;
    absl::StatusOr<core::Capture> capture = ReadImucalCsvFile(paths[0]);
    if (!capture.ok()) return capture.status();
    ApplyImportOverrides(options, &*capture, notes);
    *used_paths = paths;
    return capture;
  }
};

}  // namespace

absl::StatusOr<core::Capture> ParseImucalCsv(std::string_view text, std::string_view source_name) {
  LineCursor lines(text);
  std::string_view line;
  if (!lines.Next(&line)) {
    return LineError(source_name, 1,
                     Cat("empty file (missing header marker '", kImucalCaptureMarker, "')"));
  }
  if (absl::Status s = CheckMarkerLine(line, source_name); !s.ok()) return s;

  core::Capture capture;
  HeaderSeen seen;
  while (lines.Next(&line)) {
    if (IsBlank(line)) continue;
    const int line_number = lines.line_number();
    if (line.front() == '#') {
      if (absl::Status s = ParseHeaderLine(line, source_name, line_number, &seen, &capture);
          !s.ok()) {
        return s;
      }
      continue;
    }
    // The first line that is neither blank nor metadata names the columns.
    absl::StatusOr<ColumnLayout> layout = ParseColumnLine(line, source_name, line_number);
    if (!layout.ok()) return layout.status();
    capture.has_gyro = layout->has_gyro();
    if (absl::Status s = CheckRequiredHeaders(seen, source_name, line_number, capture.has_gyro);
        !s.ok()) {
      return s;
    }
    if (absl::Status s = ParseCsvRows(&lines, *layout, source_name, &capture); !s.ok()) return s;
    return capture;
  }
  const int last_line = lines.line_number();
  if (absl::Status s = CheckRequiredHeaders(seen, source_name, last_line, /*has_gyro=*/false);
      !s.ok()) {
    return s;
  }
  return LineError(source_name, last_line, "missing column line (t,ax,ay,az,gx,gy,gz)");
}

absl::StatusOr<core::Capture> ReadImucalCsvFile(const std::string& path) {
  absl::StatusOr<std::string> text = ReadFileBytes(path, std::nullopt);
  if (!text.ok()) return text.status();
  return ParseImucalCsv(*text, path);
}

absl::Status CheckCaptureWritable(const core::Capture& capture) {
  if (absl::Status s = core::ValidateCapture(capture); !s.ok()) return s;
  if (absl::Status s = CheckMetadataWritable(capture); !s.ok()) return s;
  return CheckColumnNamesWritable(capture);
}

std::string FormatImucalCsv(const core::Capture& capture) {
  // Rows are written up to the shortest sample vector, so a capture that breaks the
  // precondition cannot make this read out of bounds.
  const bool has_gyro = capture.has_gyro;
  size_t rows = std::min(capture.t_s.size(), capture.accel.size());
  if (has_gyro) rows = std::min(rows, capture.gyro.size());
  const bool has_temp = capture.has_temp();
  if (has_temp) rows = std::min(rows, capture.temp.size());
  const size_t extra = std::min(capture.extra_column_names.size(), capture.extra_columns.size());
  for (size_t k = 0; k < extra; ++k) rows = std::min(rows, capture.extra_columns[k].size());

  std::string out;
  const size_t columns = (has_gyro ? 7 : 4) + (has_temp ? 1 : 0) + extra;
  // About 12 characters per value is typical; the string grows if the guess is short.
  out.reserve(512 + rows * columns * 12);
  AppendTo(&out, kImucalCaptureMarker, "\n");
  if (!capture.device.empty()) AppendTo(&out, "# ", kKeyDevice, "=", capture.device, "\n");
  AppendTo(&out, "# ", kKeyAccelUnit, "=", core::AccelUnitName(capture.accel_unit), "\n");
  if (has_gyro) {
    AppendTo(&out, "# ", kKeyGyroUnit, "=", core::GyroUnitName(capture.gyro_unit), "\n");
  }
  AppendTo(&out, "# ", kKeyGravity, "=", FormatDouble(capture.gravity_m_s2), "\n");
  if (capture.rate_hz > 0.0) {
    AppendTo(&out, "# ", kKeyRateHz, "=", FormatDouble(capture.rate_hz), "\n");
  }
  if (has_temp || capture.temp_unit != core::TempUnit::kCelsius) {
    AppendTo(&out, "# ", kKeyTempUnit, "=", core::TempUnitName(capture.temp_unit), "\n");
  }
  for (const auto& [key, value] : capture.extra_metadata) {
    AppendTo(&out, "# ", key, "=", value, "\n");
  }

  out.append(Join(
      std::span(kRequiredColumns).first(has_gyro ? kRequiredColumns.size() : kGyroColumns), ","));
  if (has_temp) AppendTo(&out, ",", kTempColumn);
  for (size_t k = 0; k < extra; ++k) AppendTo(&out, ",", capture.extra_column_names[k]);
  out.push_back('\n');

  // Each row is formatted into a scratch buffer and appended once; a value takes at most
  // kMaxDoubleChars plus one separator (',' or the final '\n'), so the buffer cannot overflow.
  std::vector<char> row(columns * (kMaxDoubleChars + 1));
  for (size_t i = 0; i < rows; ++i) {
    RowWriter writer(row.data(), row.data() + row.size());
    writer.Add(capture.t_s[i]);
    for (int axis = 0; axis < 3; ++axis) writer.Add(capture.accel[i][axis]);
    if (has_gyro) {
      for (int axis = 0; axis < 3; ++axis) writer.Add(capture.gyro[i][axis]);
    }
    if (has_temp) writer.Add(capture.temp[i]);
    for (size_t k = 0; k < extra; ++k) writer.Add(capture.extra_columns[k][i]);
    writer.EndRow();
    out.append(row.data(), static_cast<size_t>(writer.end() - row.data()));
  }
  return out;
}

absl::Status WriteImucalCsvFile(const core::Capture& capture, const std::string& path) {
  if (absl::Status s = CheckCaptureWritable(capture); !s.ok()) {
    return absl::InvalidArgumentError(Cat(path, ": not written: ", s.message()));
  }
  return WriteFileDurably(path, FormatImucalCsv(capture));
}

const CaptureImporter* ImucalCsvImporter() {
  static const auto* const kImporter = new ImucalCsvImporterImpl();
  return kImporter;
}

}  // namespace imucal::importers
