#include "importers/euroc.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cstdint>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "importers/registry.h"
#include "importers/text_scan.h"
#include "util/str_util.h"

namespace imucal::importers {
namespace {

// The columns, in the dataset's order, with the unit each must state (if it states one).
struct EurocColumn {
  std::string_view name;
  std::string_view unit;
};
constexpr std::array<EurocColumn, 7> kEurocColumns = {{
    {"#timestamp", "ns"},
    {"w_RS_S_x", "rad s^-1"},
    {"w_RS_S_y", "rad s^-1"},
    {"w_RS_S_z", "rad s^-1"},
    {"a_RS_S_x", "m s^-2"},
    {"a_RS_S_y", "m s^-2"},
    {"a_RS_S_z", "m s^-2"},
}};

constexpr std::string_view kTimestampPrefix = "#timestamp";

// "w_RS_S_x [rad s^-1]" -> name "w_RS_S_x", unit "rad s^-1" (empty when not bracketed).
void SplitNameUnit(std::string_view header_field, std::string_view* name, std::string_view* unit) {
  header_field = TrimSpaces(header_field);
  const size_t open = header_field.find('[');
  const size_t close = header_field.rfind(']');
  if (open == std::string_view::npos || close == std::string_view::npos || close < open) {
    *name = header_field;
    *unit = std::string_view();
    return;
  }
  *name = TrimSpaces(header_field.substr(0, open));
  *unit = TrimSpaces(header_field.substr(open + 1, close - open - 1));
}

std::vector<std::string_view> SplitCommas(std::string_view line) {
  std::vector<std::string_view> fields;
  size_t start = 0;
  while (true) {
    const size_t comma = std::min(line.find(',', start), line.size());
    fields.push_back(line.substr(start, comma - start));
    if (comma == line.size()) break;
    start = comma + 1;
  }
  return fields;
}

struct EurocHeader {
  std::array<size_t, kEurocColumns.size()> index{};  // field index of each column
  std::vector<std::string> names;                    // every header field, for messages
  std::vector<std::string> ignored;
};

absl::StatusOr<EurocHeader> ParseHeader(std::string_view line, std::string_view source) {
  EurocHeader header;
  std::array<bool, kEurocColumns.size()> seen{};
  const std::vector<std::string_view> fields = SplitCommas(line);
  for (size_t i = 0; i < fields.size(); ++i) {
    std::string_view name, unit;
    SplitNameUnit(fields[i], &name, &unit);
    header.names.emplace_back(TrimSpaces(fields[i]));
    // "#timestamp" may also be written "timestamp" by tools that strip the comment sign.
    const std::string_view lookup = (name == "timestamp") ? kTimestampPrefix : name;
    const auto known = std::find_if(kEurocColumns.begin(), kEurocColumns.end(),
                                    [&](const EurocColumn& c) { return c.name == lookup; });
    if (known == kEurocColumns.end()) {
      header.ignored.push_back(Cat("'", header.names.back(), "'"));
      continue;
    }
    const size_t k = static_cast<size_t>(known - kEurocColumns.begin());
    if (seen[k]) return LineError(source, 1, Cat("duplicate column '", known->name, "'"));
    if (!unit.empty() && unit != known->unit) {
      return LineError(source, 1,
                       Cat("column '", header.names.back(), "': unit ", Quoted(unit),
                           " is not the EuRoC unit '", known->unit, "'"));
    }
    seen[k] = true;
    header.index[k] = i;
  }
  for (size_t k = 0; k < kEurocColumns.size(); ++k) {
    if (!seen[k]) {
      return LineError(
          source, 1,
          Cat("missing column '", kEurocColumns[k].name, " [", kEurocColumns[k].unit, "]'"));
    }
  }
  return header;
}

absl::Status ParseTimestamp(std::string_view field, std::string_view source, int line_number,
                            std::string_view column, int64_t* ns) {
  const std::string_view text = TrimSpaces(field);
  const auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), *ns);
  if (text.empty() || ec != std::errc() || ptr != text.data() + text.size()) {
    return LineError(source, line_number,
                     Cat("column '", column, "': ", text.empty() ? "empty field" : Quoted(text),
                         text.empty() ? "" : " is not an integer number of nanoseconds"));
  }
  return absl::OkStatus();
}

class EurocImporter final : public CaptureImporter {
 public:
  std::string_view name() const override { return "euroc"; }
  std::string_view description() const override {
    return "EuRoC/ASL imu0/data.csv ('#timestamp [ns],w_RS_S_x [rad s^-1],...')";
  }
  absl::Status Sniff(std::span<const std::string> /*paths*/,
                     std::span<const std::string> heads) const override {
    std::string_view head = heads[0];
    head = WithoutBom(head);
    const std::string_view first_line = head.substr(0, head.find('\n'));
    if (first_line.starts_with(kTimestampPrefix) &&
        first_line.find("w_RS_S_x") != std::string_view::npos &&
        first_line.find("a_RS_S_x") != std::string_view::npos) {
      return absl::OkStatus();
    }
    return absl::InvalidArgumentError(
        "first line is not '#timestamp [ns],w_RS_S_x [rad s^-1],...,a_RS_S_z [m s^-2]'");
  }
  absl::StatusOr<core::Capture> Import(const std::vector<std::string>& paths,
                                       const ImportOptions& options,
                                       std::vector<std::string>* used_paths,
                                       std::vector<std::string>* notes) const override {
    if (absl::Status s = CheckOnePath("euroc", "file", paths); !s.ok()) return s;
    absl::StatusOr<std::string> text = ReadFileBytes(paths[0]);
    if (!text.ok()) return text.status();
    *used_paths = paths;
    return ParseEurocCsv(*text, paths[0], options, notes);
  }
};

}  // namespace

absl::StatusOr<core::Capture> ParseEurocCsv(std::string_view text, std::string_view source_name,
                                            const ImportOptions& options,
                                            std::vector<std::string>* notes) {
  LineCursor lines(text);
  std::string_view line;
  if (!lines.Next(&line)) return LineError(source_name, 1, "empty file (no EuRoC header)");
  line = WithoutBom(line);
  absl::StatusOr<EurocHeader> header = ParseHeader(line, source_name);
  if (!header.ok()) return header.status();

  core::Capture capture;
  capture.gravity_m_s2 = core::kStandardGravity;
  capture.accel_unit = core::AccelUnit::kMetersPerSecond2;
  capture.gyro_unit = core::GyroUnit::kRadPerSecond;
  const size_t rows = CountLines(lines.rest());
  capture.t_s.reserve(rows);
  capture.accel.reserve(rows);
  capture.gyro.reserve(rows);

  const size_t field_count = header->names.size();
  int64_t t0_ns = 0;
  int64_t previous_ns = 0;
  int previous_line = 0;
  std::array<double, kEurocColumns.size()> values{};
  while (lines.Next(&line)) {
    if (IsBlank(line)) continue;
    const int line_number = lines.line_number();
    const std::vector<std::string_view> fields = SplitCommas(line);
    if (fields.size() != field_count) {
      return LineError(source_name, line_number,
                       Cat("expected ", field_count, " fields, found ", fields.size()));
    }
    int64_t ns = 0;
    if (absl::Status s = ParseTimestamp(fields[header->index[0]], source_name, line_number,
                                        header->names[header->index[0]], &ns);
        !s.ok()) {
      return s;
    }
    for (size_t k = 1; k < kEurocColumns.size(); ++k) {
      const size_t i = header->index[k];
      if (absl::Status s =
              ParseNumberField(fields[i], source_name, line_number, header->names[i], &values[k]);
          !s.ok()) {
        return s;
      }
    }
    if (previous_line == 0) {
      t0_ns = ns;
    } else if (ns <= previous_ns) {
      return LineError(source_name, line_number,
                       Cat("timestamp ", ns, " ns does not increase (previous ", previous_ns,
                           " ns at line ", previous_line, ")"));
    }
    previous_ns = ns;
    previous_line = line_number;
    // Integer difference first: a 1.4e18 ns origin would cost double precision (256 ns steps);
    // the division rounds once, correctly.
    capture.line.push_back(static_cast<uint32_t>(line_number));
    capture.t_s.push_back(static_cast<double>(ns - t0_ns) / 1e9);
    capture.gyro.emplace_back(values[1], values[2], values[3]);
    capture.accel.emplace_back(values[4], values[5], values[6]);
  }
  if (capture.t_s.empty()) {
    return LineError(source_name, std::max(lines.line_number(), 1), "no samples after the header");
  }
  capture.extra_metadata.emplace_back(std::string(kEurocOriginKey), Cat(t0_ns));
  notes->push_back(
      Cat("time counts from the first timestamp, ", t0_ns, " ns (kept as ", kEurocOriginKey, ")"));
  if (!header->ignored.empty()) {
    notes->push_back(Cat("ignored columns: ", Join(header->ignored, ", ")));
  }
  ApplyImportOverrides(options, &capture, notes);
  NoteTimeGaps(capture, notes);
  return capture;
}

const CaptureImporter* EurocCsvImporter() {
  static const auto* const kImporter = new EurocImporter();
  return kImporter;
}

}  // namespace imucal::importers
