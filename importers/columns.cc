#include "importers/columns.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <numeric>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "importers/csv_fields.h"
#include "importers/registry.h"
#include "importers/text_scan.h"
#include "importers/unit_inference.h"
#include "util/str_util.h"

namespace imucal::importers {
namespace {

// The capture fields a map can name, in the order of kFieldNames.
enum Field : size_t { kT, kAx, kAy, kAz, kGx, kGy, kGz, kTemp, kFieldCount };
constexpr std::array<std::string_view, kFieldCount> kFieldNames = {"t",  "ax", "ay", "az",
                                                                   "gx", "gy", "gz", "temp"};

// How far the header search looks (a preamble is a few lines; a data file is not all preamble).
constexpr int kMaxHeaderSearchLines = 1000;

// One side of "ax=acc_x": a header name, or a 1-based column number.
struct ColumnRef {
  std::string name;
  int number = 0;  // > 0: by number
};

struct ColumnMap {
  std::array<std::optional<ColumnRef>, kFieldCount> refs;
};

bool AllDigits(std::string_view s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

absl::Status MapError(std::string_view message) {
  return absl::InvalidArgumentError(Cat("--columns: ", message));
}

// The gyroscope is mapped whole or not at all: without gx, gy and gz the capture is
// accelerometer-only (core::Capture::has_gyro), but one axis missing is a typo, not a sensor.
absl::StatusOr<ColumnMap> CheckGyroMapped(const ColumnMap& map) {
  std::vector<std::string_view> mapped, missing;
  for (size_t f = kGx; f <= kGz; ++f) {
    (map.refs[f].has_value() ? mapped : missing).push_back(kFieldNames[f]);
  }
  if (mapped.empty() || missing.empty()) return map;
  return MapError(Cat("field '", missing.front(), "' is missing (", Join(mapped, ", "),
                      " are mapped: map all of gx, gy, gz, or none for an accelerometer-only "
                      "capture)"));
}

absl::StatusOr<ColumnMap> ParseColumnMap(std::string_view spec) {
  ColumnMap map;
  if (TrimSpaces(spec).empty()) {
    return MapError("empty (expected ax=NAME,ay=NAME,az=NAME[,gx=NAME,gy=NAME,gz=NAME][,t=NAME])");
  }
  size_t start = 0;
  while (start <= spec.size()) {
    const size_t comma = std::min(spec.find(',', start), spec.size());
    const std::string_view entry = TrimSpaces(spec.substr(start, comma - start));
    start = comma + 1;
    const size_t equals = entry.find('=');
    if (equals == std::string_view::npos) {
      return MapError(Cat(Quoted(entry), " is not FIELD=COLUMN"));
    }
    const std::string_view key = TrimSpaces(entry.substr(0, equals));
    const std::string_view value = TrimSpaces(entry.substr(equals + 1));
    const auto known = std::find(kFieldNames.begin(), kFieldNames.end(), key);
    if (known == kFieldNames.end()) {
      return MapError(
          Cat("unknown field ", Quoted(key), " (known: ", Join(kFieldNames, ", "), ")"));
    }
    const size_t field = static_cast<size_t>(known - kFieldNames.begin());
    if (map.refs[field].has_value()) return MapError(Cat("field '", key, "' given twice"));
    if (value.empty()) return MapError(Cat("field '", key, "' names no column"));
    ColumnRef ref;
    if (AllDigits(value)) {
      if (value.size() > 6 || std::stoi(std::string(value)) < 1) {
        return MapError(Cat("field '", key, "': column number ", Quoted(value),
                            " is out of range (columns count from 1)"));
      }
      ref.number = std::stoi(std::string(value));
    } else {
      ref.name = std::string(value);
    }
    map.refs[field] = std::move(ref);
  }
  for (size_t f = kAx; f <= kAz; ++f) {
    if (!map.refs[f].has_value()) return MapError(Cat("field '", kFieldNames[f], "' is missing"));
  }
  return CheckGyroMapped(map);
}

std::string RefText(const ColumnRef& ref) {
  return ref.number > 0 ? Cat("column ", ref.number) : Cat("'", ref.name, "'");
}

// ---------------------------------------------------------------------------------------------
// Splitting (importers/csv_fields.h: quotes as RFC 4180 reads them).

constexpr char kWhitespace = kWhitespaceDelimiter;

absl::StatusOr<std::optional<char>> ParseDelimiter(std::string_view name) {
  if (name.empty()) return std::optional<char>();
  if (name == "," || name == "comma") return std::optional<char>(',');
  if (name == ";" || name == "semicolon") return std::optional<char>(';');
  if (name == "tab" || name == "\t") return std::optional<char>('\t');
  if (name == "space" || name == " ") return std::optional<char>(kWhitespace);
  return absl::InvalidArgumentError(
      Cat("--delimiter: ", Quoted(name), " is not one of , ; tab space"));
}

// The delimiter a line uses: the most frequent of ',', ';', tab; else runs of spaces if the
// line has any; else ',' (a one-column line).
char DetectDelimiter(std::string_view line) {
  char best = 0;
  ptrdiff_t best_count = 0;
  for (const char c : {',', ';', '\t'}) {
    const ptrdiff_t count = std::count(line.begin(), line.end(), c);
    if (count > best_count) best = c, best_count = count;
  }
  if (best != 0) return best;
  return TrimSpaces(line).find(' ') != std::string_view::npos ? kWhitespace : ',';
}

// Splits the record that starts with `*record` (a line just read), joining the next lines while
// a quoted field holds a line break; the record then spans them (the text is one buffer).
absl::Status SplitRecord(LineCursor* lines, std::string_view source, char delimiter,
                         std::string_view* record, CsvFields* fields) {
  const int first_line = lines->line_number();
  while (SplitCsvRecord(*record, delimiter, fields) == CsvSplit::kOpenQuote) {
    std::string_view more;
    if (!lines->Next(&more)) {
      return LineError(source, first_line,
                       "a quoted field opened on this line is never closed (no closing '\"')");
    }
    *record = std::string_view(record->data(),
                               static_cast<size_t>(more.data() + more.size() - record->data()));
  }
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------------------------
// Layout: where the header is, and which field each capture field comes from.

struct Layout {
  char delimiter = ',';
  int header_line = 0;  // 0: no header
  std::vector<std::string> header;
  std::vector<std::string_view>
      preamble;                        // lines before the header (or the first row), from line 1
  std::array<int, kFieldCount> index;  // 0-based field index, -1 when not mapped
  std::vector<std::string> labels;     // per capture field, for error messages
  size_t max_index = 0;
};

bool HeaderHasNames(const std::vector<std::string_view>& fields, const ColumnMap& map) {
  for (const auto& ref : map.refs) {
    if (!ref.has_value() || ref->number > 0) continue;
    if (std::find(fields.begin(), fields.end(), ref->name) == fields.end()) return false;
  }
  return true;
}

// Finds the header line (or, without one, the first row) and the preamble before it. On return
// `lines` is positioned after the header (or before the first row).
absl::Status FindHeader(std::string_view source, const ColumnCsvOptions& options,
                        const ColumnMap& map, std::optional<char> delimiter, Layout* layout,
                        LineCursor* lines) {
  CsvFields split;
  const std::vector<std::string_view>& fields = split.fields;
  std::string_view line;
  const int skip = options.skip_lines.value_or(0);
  for (int i = 0; i < skip; ++i) {
    if (!lines->Next(&line)) {
      return LineError(source, lines->line_number(),
                       Cat("the file ends within the ", skip, " lines to skip"));
    }
    layout->preamble.push_back(line);
  }
  // Without --skip-lines, the header is the first line that names every mapped column; if none
  // does, the first non-blank line is taken as the header, so that the error lists its columns.
  std::optional<LineCursor> first_after;
  std::vector<std::string> first_fields;
  int first_line = 0;
  size_t first_preamble = 0;
  char first_delimiter = ',';
  auto use_first = [&]() {
    *lines = *first_after;
    layout->delimiter = first_delimiter;
    layout->header_line = first_line;
    layout->header = first_fields;
    layout->preamble.resize(first_preamble);
    return absl::OkStatus();
  };
  while (true) {
    LineCursor before = *lines;
    if (!lines->Next(&line)) {
      if (first_after.has_value()) return use_first();
      return LineError(source, std::max(lines->line_number(), 1),
                       options.no_header ? "no rows" : "no header line");
    }
    if (lines->line_number() == 1) line = WithoutBom(line);
    if (IsBlank(line)) {
      layout->preamble.push_back(line);
      continue;
    }
    if (options.no_header) {
      layout->delimiter = delimiter.value_or(DetectDelimiter(line));
      *lines = before;  // this line is the first row
      return absl::OkStatus();
    }
    // A commented header ("# time ax ay az ..."): the names after the comment marker.
    std::string_view named = TrimSpaces(line);
    if (named.starts_with('#')) {
      const size_t text = named.find_first_not_of('#');
      named = text == std::string_view::npos ? std::string_view() : TrimSpaces(named.substr(text));
    } else {
      named = line;
    }
    // Detected per line: a preamble may be prose, or use another delimiter than the table.
    layout->delimiter = delimiter.value_or(DetectDelimiter(named));
    // One line: a quote left open is not followed onto the next line here (a preamble's prose
    // may hold a lone '"').
    SplitCsvRecord(named, layout->delimiter, &split);
    if (options.skip_lines.has_value() || HeaderHasNames(fields, map)) {
      layout->header_line = lines->line_number();
      layout->header.assign(fields.begin(), fields.end());
      return absl::OkStatus();
    }

    if (!first_after.has_value()) {
      first_after = *lines;
      first_fields.assign(fields.begin(), fields.end());
      first_line = lines->line_number();
      first_preamble = layout->preamble.size();
      first_delimiter = layout->delimiter;
    }
    if (lines->line_number() >= kMaxHeaderSearchLines) return use_first();
    layout->preamble.push_back(line);
  }
}

absl::Status ResolveColumns(std::string_view source, const ColumnMap& map, Layout* layout) {
  layout->index.fill(-1);
  layout->labels.assign(kFieldCount, std::string());
  const std::vector<std::string>& header = layout->header;
  for (size_t f = 0; f < kFieldCount; ++f) {
    if (!map.refs[f].has_value()) continue;
    const ColumnRef& ref = *map.refs[f];
    int index = ref.number - 1;
    if (ref.number == 0) {
      const auto first = std::find(header.begin(), header.end(), ref.name);
      if (first == header.end()) {
        return LineError(source, layout->header_line,
                         Cat("no column '", ref.name, "' (mapped to ", kFieldNames[f],
                             ") in the header; it has: ", Join(header, ", "),
                             " (a preamble before the header: --skip-lines N)"));
      }
      if (std::find(first + 1, header.end(), ref.name) != header.end()) {
        return LineError(source, layout->header_line,
                         Cat("column '", ref.name, "' (mapped to ", kFieldNames[f],
                             ") appears more than once in the header: map it by number"));
      }
      index = static_cast<int>(first - header.begin());
    } else if (layout->header_line > 0 && static_cast<size_t>(index) >= header.size()) {
      return LineError(source, layout->header_line,
                       Cat(kFieldNames[f], "=", ref.number, ": the header has only ", header.size(),
                           " columns"));
    }
    for (size_t g = 0; g < f; ++g) {
      if (layout->index[g] == index) {
        return absl::InvalidArgumentError(Cat("--columns: ", kFieldNames[g], " and ",
                                              kFieldNames[f], " name the same column ",
                                              RefText(ref)));
      }
    }
    layout->index[f] = index;
    layout->max_index = std::max(layout->max_index, static_cast<size_t>(index));
    // Errors then read "column 'acc_x': ..." (or "column 'ax = column 3': ..." without a header).
    layout->labels[f] = layout->header_line > 0 ? header[static_cast<size_t>(index)]
                                                : Cat(kFieldNames[f], " = column ", index + 1);
  }
  return absl::OkStatus();
}

// The rate in Hz from a preamble line "KEY,VALUE" (or KEY=VALUE, KEY: VALUE).
absl::StatusOr<double> RateFromPreamble(std::string_view source, const Layout& layout,
                                        std::string_view key) {
  for (size_t i = 0; i < layout.preamble.size(); ++i) {
    const std::string_view line = TrimSpaces(layout.preamble[i]);
    const size_t split = line.find_first_of(",;=:\t");
    if (split == std::string_view::npos || TrimSpaces(line.substr(0, split)) != key) continue;
    const int line_number = static_cast<int>(i) + 1;  // the preamble starts the file
    std::string_view value = TrimSpaces(line.substr(split + 1));
    value = value.substr(0, std::min(value.find_first_of(",;\t"), value.size()));
    double rate = 0.0;
    if (absl::Status s = ParseNumberField(value, source, line_number, key, &rate); !s.ok()) {
      return s;
    }
    if (!(rate > 0.0)) {
      return LineError(source, line_number, Cat("rate '", key, "' must be positive"));
    }
    return rate;
  }
  return absl::InvalidArgumentError(Cat(source, ": no preamble line starts with '", key, "' (",
                                        layout.preamble.size(),
                                        " preamble lines) to read the rate from"));
}

double TimeScale(ColumnTimeUnit unit) {
  switch (unit) {
    case ColumnTimeUnit::kSeconds:
      return 1.0;
    case ColumnTimeUnit::kMilliseconds:
      return 1e-3;
    case ColumnTimeUnit::kMicroseconds:
      return 1e-6;
    case ColumnTimeUnit::kNanoseconds:
      return 1e-9;
    case ColumnTimeUnit::kSampleIndex:
      return 1.0;
  }
  return 1.0;
}

// One parsed row before the time check (kept so that rows can be sorted).
struct Row {
  double t_s;
  Eigen::Vector3d accel;
  Eigen::Vector3d gyro;
  double temp;
  int line_number;
};

// Rows left out by --skip-incomplete-rows: how many, and the first one's line.
struct SkippedRows {
  size_t count = 0;
  int first_line = 0;
};

// The first mapped capture field that `fields` leaves empty (or lacks: a short row), or -1.
// An interleaved log fills only its own sensor's columns on each row.
int FirstEmptyMappedField(const Layout& layout, const std::vector<std::string_view>& fields) {
  for (size_t f = 0; f < kFieldCount; ++f) {
    const int index = layout.index[f];
    if (index < 0) continue;
    if (static_cast<size_t>(index) >= fields.size() || fields[static_cast<size_t>(index)].empty()) {
      return static_cast<int>(f);
    }
  }
  return -1;
}

constexpr std::string_view kSkipHint =
    " (rows with empty fields, as an interleaved log of several sensors writes them, are skipped "
    "with --skip-incomplete-rows)";

absl::Status CheckRowShape(std::string_view source, int line_number, const Layout& layout,
                           size_t expected_fields, const std::vector<std::string_view>& fields) {
  const std::string_view hint = FirstEmptyMappedField(layout, fields) >= 0 ? kSkipHint : "";
  if (fields.size() != expected_fields) {
    return LineError(source, line_number,
                     Cat("expected ", expected_fields, " fields, found ", fields.size(), hint));
  }
  if (layout.max_index >= fields.size()) {
    return LineError(source, line_number,
                     Cat("has ", fields.size(), " fields, but the map uses column ",
                         layout.max_index + 1, hint));
  }
  return absl::OkStatus();
}

absl::Status ParseRowValues(std::string_view source, int line_number, const Layout& layout,
                            const std::vector<std::string_view>& fields,
                            std::array<double, kFieldCount>* values) {
  for (size_t f = 0; f < kFieldCount; ++f) {
    if (layout.index[f] < 0) continue;
    const std::string_view field = fields[static_cast<size_t>(layout.index[f])];
    if (absl::Status s =
            ParseNumberField(field, source, line_number, layout.labels[f], &(*values)[f]);
        !s.ok()) {
      if (field.empty()) return absl::InvalidArgumentError(Cat(s.message(), kSkipHint));
      return s;
    }
  }
  return absl::OkStatus();
}

absl::Status ParseRows(LineCursor* lines, std::string_view source, const Layout& layout,
                       const ColumnCsvOptions& options, std::optional<double> rate_hz,
                       std::vector<Row>* rows, SkippedRows* skipped) {
  rows->reserve(CountLines(lines->rest()));
  size_t expected_fields = layout.header_line > 0 ? layout.header.size() : 0;
  CsvFields split;
  std::string_view line;
  std::array<double, kFieldCount> values{};
  const bool index_time = options.time_unit == ColumnTimeUnit::kSampleIndex;
  const double scale = TimeScale(options.time_unit);
  while (lines->Next(&line)) {
    if (IsBlank(line)) continue;
    const int line_number = lines->line_number();
    if (absl::Status s = SplitRecord(lines, source, layout.delimiter, &line, &split); !s.ok()) {
      return s;
    }
    if (options.skip_incomplete_rows && FirstEmptyMappedField(layout, split.fields) >= 0) {
      if (skipped->count++ == 0) skipped->first_line = line_number;
      continue;
    }
    if (expected_fields == 0) expected_fields = split.fields.size();  // no header: the first row
    if (absl::Status s = CheckRowShape(source, line_number, layout, expected_fields, split.fields);
        !s.ok()) {
      return s;
    }
    if (absl::Status s = ParseRowValues(source, line_number, layout, split.fields, &values);
        !s.ok()) {
      return s;
    }
    double t_s = 0.0;
    if (layout.index[kT] < 0) {
      t_s = static_cast<double>(rows->size()) / *rate_hz;
    } else if (index_time) {
      t_s = values[kT] / *rate_hz;
    } else {
      t_s = values[kT] * scale;
    }
    rows->push_back(Row{t_s, Eigen::Vector3d(values[kAx], values[kAy], values[kAz]),
                        Eigen::Vector3d(values[kGx], values[kGy], values[kGz]), values[kTemp],
                        line_number});
  }
  return absl::OkStatus();
}

absl::Status TimeError(std::string_view source, const Row& row, const Row& previous) {
  return LineError(source, row.line_number,
                   Cat("t=", FormatDouble(row.t_s), " s does not increase (previous ",
                       FormatDouble(previous.t_s), " s at line ", previous.line_number, ")"));
}

// Checks that time increases (or sorts the rows, with a note), as the options say.
absl::Status OrderRows(std::string_view source, const ColumnCsvOptions& options,
                       std::vector<Row>* rows, std::vector<std::string>* notes) {
  if (!options.sort_by_time) {
    for (size_t i = 1; i < rows->size(); ++i) {
      if (!((*rows)[i].t_s > (*rows)[i - 1].t_s)) {
        absl::Status error = TimeError(source, (*rows)[i], (*rows)[i - 1]);
        return absl::InvalidArgumentError(
            Cat(error.message(), "; --sort-time puts the rows in time order"));
      }
    }
    return absl::OkStatus();
  }
  size_t out_of_order = 0;
  for (size_t i = 1; i < rows->size(); ++i) out_of_order += !((*rows)[i].t_s > (*rows)[i - 1].t_s);
  std::stable_sort(rows->begin(), rows->end(),
                   [](const Row& a, const Row& b) { return a.t_s < b.t_s; });
  for (size_t i = 1; i < rows->size(); ++i) {
    if ((*rows)[i].t_s == (*rows)[i - 1].t_s) {
      return LineError(source, (*rows)[i].line_number,
                       Cat("t=", FormatDouble((*rows)[i].t_s), " s repeats the time of line ",
                           (*rows)[i - 1].line_number));
    }
  }
  if (out_of_order > 0) {
    notes->push_back(Cat("sorted the rows by time: ", out_of_order,
                         " rows came before an earlier time in the file"));
  }
  return absl::OkStatus();
}

std::string DescribeTimeBase(const Layout& layout, const ColumnCsvOptions& options,
                             std::optional<double> rate_hz) {
  if (layout.index[kT] < 0) {
    return Cat("time = row / ", FormatDouble(*rate_hz), " Hz (no time column)");
  }
  const std::string column = Cat("'", layout.labels[kT], "'");
  if (options.time_unit == ColumnTimeUnit::kSampleIndex) {
    return Cat("time = ", column, " (sample index) / ", FormatDouble(*rate_hz),
               " Hz; a jump in the index stays a gap");
  }
  return Cat("time = ", column, " in ", ColumnTimeUnitName(options.time_unit));
}

core::Capture CaptureOfRows(const std::vector<Row>& rows, const Layout& layout,
                            const ImportOptions& options, std::optional<double> rate_hz) {
  core::Capture capture;
  capture.device = options.device.value_or("");
  capture.gravity_m_s2 = options.gravity_m_s2.value_or(core::kStandardGravity);
  capture.rate_hz = rate_hz.value_or(0.0);
  capture.temp_unit = options.columns.temp_unit.value_or(core::TempUnit::kCelsius);
  const bool has_temp = layout.index[kTemp] >= 0;
  capture.has_gyro = layout.index[kGx] >= 0;
  capture.t_s.reserve(rows.size());
  capture.accel.reserve(rows.size());
  if (capture.has_gyro) capture.gyro.reserve(rows.size());
  if (has_temp) capture.temp.reserve(rows.size());
  capture.line.reserve(rows.size());
  for (const Row& row : rows) {
    capture.line.push_back(static_cast<uint32_t>(row.line_number));
    capture.t_s.push_back(row.t_s);
    capture.accel.push_back(row.accel);
    if (capture.has_gyro) capture.gyro.push_back(row.gyro);
    if (has_temp) capture.temp.push_back(row.temp);
  }
  return capture;
}

void AddLayoutNotes(const Layout& layout, const ColumnCsvOptions& columns,
                    std::optional<double> rate_hz, std::vector<std::string>* notes) {
  std::vector<std::string> mapped;
  for (size_t f = 0; f < kFieldCount; ++f) {
    if (layout.index[f] >= 0) mapped.push_back(Cat(kFieldNames[f], "='", layout.labels[f], "'"));
  }
  notes->push_back(Cat("columns: ", Join(mapped, ", ")));
  if (layout.index[kGx] < 0) {
    notes->push_back("no gyroscope columns: an accelerometer-only capture");
  }
  notes->push_back(DescribeTimeBase(layout, columns, rate_hz));
  if (layout.header_line > 0) {
    std::vector<std::string> ignored;
    for (size_t i = 0; i < layout.header.size(); ++i) {
      if (std::find(layout.index.begin(), layout.index.end(), static_cast<int>(i)) ==
          layout.index.end()) {
        ignored.push_back(Cat("'", layout.header[i], "'"));
      }
    }
    if (!ignored.empty()) notes->push_back(Cat("ignored columns: ", Join(ignored, ", ")));
  }
}

// ApplyOrInferUnits, except that a capture without a gyroscope has no gyro unit to infer or
// note: it is left at its default, which nothing reads.
void InferUnits(const ImportOptions& options, core::Capture* capture,
                std::vector<std::string>* notes) {
  if (capture->has_gyro) return ApplyOrInferUnits(options, capture, notes);
  ImportOptions accel_only = options;
  accel_only.gyro_unit = capture->gyro_unit;
  ApplyOrInferUnits(accel_only, capture, notes);
}

class ColumnCsvImporterImpl final : public CaptureImporter {
 public:
  std::string_view name() const override { return "columns"; }
  std::string_view description() const override {
    return "delimited text with the columns named by --columns (vendor CSV)";
  }
  absl::Status Sniff(std::span<const std::string> /*paths*/,
                     std::span<const std::string> /*heads*/) const override {
    return absl::InvalidArgumentError("used only when --columns names the columns");
  }
  absl::StatusOr<core::Capture> Import(const std::vector<std::string>& paths,
                                       const ImportOptions& options,
                                       std::vector<std::string>* used_paths,
                                       std::vector<std::string>* notes) const override {
    if (absl::Status s = CheckOnePath("columns", "file", paths); !s.ok()) return s;
    absl::StatusOr<std::string> text = ReadFileBytes(paths[0]);
    if (!text.ok()) return text.status();
    *used_paths = paths;
    return ParseColumnCsv(*text, paths[0], options, notes);
  }
};

}  // namespace

absl::StatusOr<ColumnTimeUnit> ParseColumnTimeUnit(std::string_view name) {
  if (name == "s") return ColumnTimeUnit::kSeconds;
  if (name == "ms") return ColumnTimeUnit::kMilliseconds;
  if (name == "us") return ColumnTimeUnit::kMicroseconds;
  if (name == "ns") return ColumnTimeUnit::kNanoseconds;
  if (name == "index") return ColumnTimeUnit::kSampleIndex;
  return absl::InvalidArgumentError(
      Cat("unknown time unit ", Quoted(name), " (expected s, ms, us, ns or index)"));
}

std::string_view ColumnTimeUnitName(ColumnTimeUnit unit) {
  switch (unit) {
    case ColumnTimeUnit::kSeconds:
      return "s";
    case ColumnTimeUnit::kMilliseconds:
      return "ms";
    case ColumnTimeUnit::kMicroseconds:
      return "us";
    case ColumnTimeUnit::kNanoseconds:
      return "ns";
    case ColumnTimeUnit::kSampleIndex:
      return "index";
  }
  return "?";
}

absl::Status CheckColumnCsvOptions(const ColumnCsvOptions& options) {
  absl::StatusOr<ColumnMap> map = ParseColumnMap(options.map);
  if (!map.ok()) return map.status();
  if (absl::StatusOr<std::optional<char>> d = ParseDelimiter(options.delimiter); !d.ok()) {
    return d.status();
  }
  if (options.rate_hz.has_value() && !(std::isfinite(*options.rate_hz) && *options.rate_hz > 0)) {
    return absl::InvalidArgumentError("--rate: must be a positive number of Hz");
  }
  if (options.rate_hz.has_value() && !options.rate_from_preamble.empty()) {
    return absl::InvalidArgumentError("give --rate or --rate-from-preamble, not both");
  }
  if (options.skip_lines.has_value() && *options.skip_lines < 0) {
    return absl::InvalidArgumentError("--skip-lines: must not be negative");
  }
  const bool has_rate = options.rate_hz.has_value() || !options.rate_from_preamble.empty();
  const bool has_t = map->refs[kT].has_value();
  if (!has_t && !has_rate) {
    return absl::InvalidArgumentError(
        "--columns maps no time column (t=...): give the sample rate (--rate HZ or "
        "--rate-from-preamble KEY)");
  }
  if (has_t && options.time_unit == ColumnTimeUnit::kSampleIndex && !has_rate) {
    return absl::InvalidArgumentError(
        "--time-unit index: give the sample rate (--rate HZ or --rate-from-preamble KEY)");
  }
  if (options.no_header) {
    for (size_t f = 0; f < kFieldCount; ++f) {
      if (map->refs[f].has_value() && map->refs[f]->number == 0) {
        return absl::InvalidArgumentError(
            Cat("--no-header: map ", kFieldNames[f], " by column number, not by name"));
      }
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<core::Capture> ParseColumnCsv(std::string_view text, std::string_view source_name,
                                             const ImportOptions& options,
                                             std::vector<std::string>* notes) {
  const ColumnCsvOptions& columns = options.columns;
  if (absl::Status s = CheckColumnCsvOptions(columns); !s.ok()) return s;
  absl::StatusOr<ColumnMap> map = ParseColumnMap(columns.map);
  if (!map.ok()) return map.status();
  absl::StatusOr<std::optional<char>> delimiter = ParseDelimiter(columns.delimiter);
  if (!delimiter.ok()) return delimiter.status();

  Layout layout;
  LineCursor lines(text);
  if (absl::Status s = FindHeader(source_name, columns, *map, *delimiter, &layout, &lines);
      !s.ok()) {
    return s;
  }
  if (absl::Status s = ResolveColumns(source_name, *map, &layout); !s.ok()) return s;
  std::optional<double> rate_hz = columns.rate_hz;
  if (!columns.rate_from_preamble.empty()) {
    absl::StatusOr<double> rate = RateFromPreamble(source_name, layout, columns.rate_from_preamble);
    if (!rate.ok()) return rate.status();
    rate_hz = *rate;
  }

  std::vector<Row> rows;
  SkippedRows skipped;
  if (absl::Status s = ParseRows(&lines, source_name, layout, columns, rate_hz, &rows, &skipped);
      !s.ok()) {
    return s;
  }
  if (rows.empty() && skipped.count > 0) {
    return LineError(source_name, skipped.first_line,
                     Cat("every row (", skipped.count, ") leaves a mapped column empty"));
  }
  if (rows.empty()) {
    return LineError(source_name, std::max(lines.line_number(), 1), "no rows after the header");
  }
  if (absl::Status s = OrderRows(source_name, columns, &rows, notes); !s.ok()) return s;

  core::Capture capture = CaptureOfRows(rows, layout, options, rate_hz);
  AddLayoutNotes(layout, columns, rate_hz, notes);
  if (skipped.count > 0) {
    notes->push_back(Cat("skipped ", skipped.count, " rows with empty fields (first at ",
                         source_name, ":", skipped.first_line, ")"));
  }
  InferUnits(options, &capture, notes);
  NoteTimeGaps(capture, notes);
  return capture;
}

const CaptureImporter* ColumnCsvImporter() {
  static const auto* const kImporter = new ColumnCsvImporterImpl();
  return kImporter;
}

}  // namespace imucal::importers
