#include "importers/reference.h"

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "importers/euroc.h"
#include "importers/registry.h"
#include "importers/text_scan.h"
#include "util/file.h"
#include "util/str_util.h"

namespace imucal::importers {
namespace {

// A reference quaternion further than this from unit length is not an orientation (a column
// mix-up, a position read as a quaternion); closer ones are normalised.
constexpr double kUnitTolerance = 0.01;

std::vector<std::string_view> Split(std::string_view line, char separator) {
  std::vector<std::string_view> fields;
  if (separator == ' ') {
    size_t i = 0;
    while (i < line.size()) {
      while (i < line.size() && IsSpace(line[i])) ++i;
      const size_t start = i;
      while (i < line.size() && !IsSpace(line[i])) ++i;
      if (i > start) fields.push_back(line.substr(start, i - start));
    }
    return fields;
  }
  size_t start = 0;
  while (true) {
    const size_t end = std::min(line.find(separator, start), line.size());
    fields.push_back(TrimSpaces(line.substr(start, end - start)));
    if (end == line.size()) break;
    start = end + 1;
  }
  return fields;
}

// "1520530308.1819017" -> 1520530308181901700 exactly (digits past the ninth are dropped);
// exponent forms go through a double.
absl::Status ParseSecondsNs(std::string_view field, std::string_view source, int line,
                            std::string_view column, int64_t* ns) {
  const std::string_view text = TrimSpaces(field);
  const bool negative = !text.empty() && text[0] == '-';
  std::string_view digits = negative ? text.substr(1) : text;
  const size_t dot = digits.find('.');
  const std::string_view whole = digits.substr(0, dot);
  const std::string_view fraction =
      dot == std::string_view::npos ? std::string_view() : digits.substr(dot + 1);
  const auto all_digits = [](std::string_view s) {
    for (char c : s) {
      if (!IsDigit(c)) return false;
    }
    return true;
  };
  if (!whole.empty() && whole.size() <= 10 && all_digits(whole) && all_digits(fraction)) {
    int64_t value = 0;
    for (char c : whole) value = 10 * value + (c - '0');
    int64_t sub = 0;
    for (size_t i = 0; i < 9; ++i) sub = 10 * sub + (i < fraction.size() ? fraction[i] - '0' : 0);
    *ns = (negative ? -1 : 1) * (value * 1000000000 + sub);
    return absl::OkStatus();
  }
  double seconds = 0.0;
  if (absl::Status s = ParseNumberField(text, source, line, column, &seconds); !s.ok()) return s;
  if (std::abs(seconds) > 9e9) {
    return LineError(source, line,
                     Cat("column '", column, "': ", Quoted(text),
                         " is not a time in seconds (beyond year 2255)"));
  }
  *ns = std::llround(seconds * 1e9);
  return absl::OkStatus();
}

absl::Status ParseNsField(std::string_view field, std::string_view source, int line,
                          std::string_view column, int64_t* ns) {
  const std::string_view text = TrimSpaces(field);
  const auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), *ns);
  if (text.empty() || ec != std::errc() || ptr != text.data() + text.size()) {
    return LineError(
        source, line,
        Cat("column '", column, "': ", Quoted(text), " is not an integer number of nanoseconds"));
  }
  return absl::OkStatus();
}

// A header's field name without a bracketed unit and a leading '#'.
std::string_view BareName(std::string_view field) {
  field = TrimSpaces(field);
  field = TrimSpaces(field.substr(0, field.find('[')));
  if (field.starts_with('#')) field.remove_prefix(1);
  return TrimSpaces(field);
}

// The index of the header field equal to, or ending in, one of `names`.
std::optional<size_t> FindColumn(const std::vector<std::string_view>& header,
                                 std::initializer_list<std::string_view> names, bool suffix) {
  for (size_t i = 0; i < header.size(); ++i) {
    const std::string_view h = BareName(header[i]);
    for (std::string_view n : names) {
      if (h == n || (suffix && h.ends_with(Cat(".", n)))) return i;
    }
  }
  return std::nullopt;
}

// The columns of a delimited file with a header: time first (seconds or nanoseconds), then the
// value columns in the order asked.
struct ReferenceLayout {
  bool time_in_ns = false;
  size_t time = 0;
  std::vector<size_t> values;
  std::vector<std::string> value_names;  // for messages
  size_t field_count = 0;
};

absl::StatusOr<ReferenceLayout> FindLayout(const std::vector<std::string_view>& header,
                                           std::string_view source,
                                           const std::vector<std::vector<std::string_view>>& wanted,
                                           bool suffix) {
  ReferenceLayout layout;
  layout.field_count = header.size();
  if (auto t = FindColumn(header, {"Time", "time"}, false)) {
    layout.time = *t;
  } else if (auto ns = FindColumn(header, {"timestamp", "%time"}, false)) {
    layout.time = *ns;
    layout.time_in_ns = true;
  } else {
    return LineError(source, 1, "no time column ('Time' in s, or '#timestamp' in ns)");
  }
  for (const std::vector<std::string_view>& names : wanted) {
    std::optional<size_t> found;
    for (std::string_view n : names) {
      if (!found) found = FindColumn(header, {n}, suffix);
    }
    if (!found) return LineError(source, 1, Cat("missing column '", names[0], "'"));
    layout.values.push_back(*found);
    layout.value_names.emplace_back(BareName(header[*found]));
  }
  return layout;
}

// Reads every data row of a delimited file: its time (ns) and the layout's values.
template <typename Row>
absl::Status ReadRows(LineCursor* lines, std::string_view source, const ReferenceLayout& layout,
                      char separator, const Row& row) {
  std::string_view line;
  std::vector<double> values(layout.values.size());
  int64_t previous_ns = 0;
  int previous_line = 0;
  while (lines->Next(&line)) {
    const int n = lines->line_number();
    if (IsBlank(line) || TrimSpaces(line).starts_with('#')) continue;
    const std::vector<std::string_view> f = Split(line, separator);
    if (f.size() != layout.field_count) {
      return LineError(source, n,
                       Cat("expected ", layout.field_count, " fields, found ", f.size()));
    }
    int64_t ns = 0;
    const std::string_view time_name = separator == ' ' ? "t" : "time";
    absl::Status s = layout.time_in_ns ? ParseNsField(f[layout.time], source, n, time_name, &ns)
                                       : ParseSecondsNs(f[layout.time], source, n, time_name, &ns);
    if (!s.ok()) return s;
    if (previous_line > 0 && ns <= previous_ns) {
      return LineError(source, n,
                       Cat("time ", ns, " ns does not increase (previous ", previous_ns,
                           " ns at line ", previous_line, ")"));
    }
    previous_ns = ns;
    previous_line = n;
    for (size_t k = 0; k < values.size(); ++k) {
      const size_t i = layout.values[k];
      if (s = ParseNumberField(f[i], source, n, layout.value_names[k], &values[k]); !s.ok()) {
        return s;
      }
    }
    if (s = row(ns, values, n); !s.ok()) return s;
  }
  if (previous_line == 0) return LineError(source, lines->line_number(), "no samples");
  return absl::OkStatus();
}

double Seconds(int64_t ns, int64_t origin_ns) { return static_cast<double>(ns - origin_ns) / 1e9; }

// q as read (x, y, z, w), normalised; an error when it is not near unit length.
absl::Status AddQuaternion(std::string_view source, int line, double x, double y, double z,
                           double w, ReferenceStream* out) {
  const double norm = std::sqrt(x * x + y * y + z * z + w * w);
  if (!(std::abs(norm - 1.0) <= kUnitTolerance)) {
    return LineError(source, line,
                     Cat("quaternion (x y z w) has norm ", norm,
                         ", not 1: not an orientation (columns mixed up?)"));
  }
  out->q_world_ref.emplace_back(w / norm, x / norm, y / norm, z / norm);
  out->line.push_back(line);
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<ImuStream> ParseImuStream(std::string_view text, std::string_view source) {
  text = WithoutBom(text);
  LineCursor lines(text);
  std::string_view first;
  if (!lines.Next(&first)) return LineError(source, 1, "empty file (no header)");
  ImuStream out;
  if (first.starts_with("#timestamp") || first.starts_with("timestamp")) {
    std::vector<std::string> notes;
    absl::StatusOr<core::Capture> c = ParseEurocCsv(text, source, ImportOptions(), &notes);
    if (!c.ok()) return c.status();
    for (const auto& [key, value] : c->extra_metadata) {
      if (key == kEurocOriginKey) out.origin_ns = std::stoll(value);
    }
    out.t_s = std::move(c->t_s);
    out.gyro_rad_s = std::move(c->gyro);
    out.accel_m_s2 = std::move(c->accel);
    return out;
  }
  const std::vector<std::string_view> header = Split(first, ',');
  absl::StatusOr<ReferenceLayout> layout = FindLayout(header, source,
                                                      {{"angular_velocity.x"},
                                                       {"angular_velocity.y"},
                                                       {"angular_velocity.z"},
                                                       {"linear_acceleration.x"},
                                                       {"linear_acceleration.y"},
                                                       {"linear_acceleration.z"}},
                                                      true);
  if (!layout.ok()) {
    return LineError(source, 1,
                     Cat("not an IMU file: ", layout.status().message(),
                         " (expected the TUM-VI/ROS CSV 'Time,angular_velocity.x,...' or "
                         "EuRoC '#timestamp [ns],w_RS_S_x [rad s^-1],...')"));
  }
  bool first_row = true;
  absl::Status s =
      ReadRows(&lines, source, *layout, ',', [&](int64_t ns, const std::vector<double>& v, int) {
        if (first_row) out.origin_ns = ns;
        first_row = false;
        out.t_s.push_back(Seconds(ns, out.origin_ns));
        out.gyro_rad_s.emplace_back(v[0], v[1], v[2]);
        out.accel_m_s2.emplace_back(v[3], v[4], v[5]);
        return absl::OkStatus();
      });
  if (!s.ok()) return s;
  return out;
}

absl::StatusOr<ReferenceStream> ParseReferenceStream(std::string_view text,
                                                     std::string_view source) {
  text = WithoutBom(text);
  LineCursor lines(text);
  std::string_view first;
  if (!lines.Next(&first)) return LineError(source, 1, "empty file (no reference)");
  ReferenceLayout layout;
  char separator = ',';
  const bool euroc = first.find("q_RS_w") != std::string_view::npos;
  const bool ros = first.find("rotation.x") != std::string_view::npos ||
                   first.find("orientation.x") != std::string_view::npos;
  if (euroc || ros) {
    const std::vector<std::string_view> header = Split(first, ',');
    absl::StatusOr<ReferenceLayout> found =
        euroc ? FindLayout(header, source, {{"q_RS_x"}, {"q_RS_y"}, {"q_RS_z"}, {"q_RS_w"}}, false)
              : FindLayout(header, source,
                           {{"rotation.x", "orientation.x"},
                            {"rotation.y", "orientation.y"},
                            {"rotation.z", "orientation.z"},
                            {"rotation.w", "orientation.w"}},
                           true);
    if (!found.ok()) return found.status();
    layout = *found;
  } else {
    // TUM trajectory: `t tx ty tz qx qy qz qw`; the first line is data unless a comment.
    separator = ' ';
    layout.field_count = 8;
    layout.time = 0;
    layout.values = {4, 5, 6, 7};
    layout.value_names = {"qx", "qy", "qz", "qw"};
    lines = LineCursor(text);
    if (!TrimSpaces(first).starts_with('#') && Split(first, ' ').size() != 8) {
      return LineError(source, 1,
                       "not a reference file: expected the TUM trajectory format "
                       "'t tx ty tz qx qy qz qw', a TUM-VI/ROS CSV with transform.rotation.x..w "
                       "or EuRoC with q_RS_w..q_RS_z");
    }
  }
  ReferenceStream out;
  bool first_row = true;
  absl::Status s = ReadRows(&lines, source, layout, separator,
                            [&](int64_t ns, const std::vector<double>& v, int line) {
                              if (first_row) out.origin_ns = ns;
                              first_row = false;
                              out.t_s.push_back(Seconds(ns, out.origin_ns));
                              return AddQuaternion(source, line, v[0], v[1], v[2], v[3], &out);
                            });
  if (!s.ok()) return s;
  return out;
}

core::motion::MotionRecording JoinStreams(const ImuStream& imu, const ReferenceStream& reference) {
  core::motion::MotionRecording r;
  r.t_s = imu.t_s;
  r.gyro_rad_s = imu.gyro_rad_s;
  r.accel_m_s2 = imu.accel_m_s2;
  const double shift_s = Seconds(reference.origin_ns, imu.origin_ns);
  r.ref_t_s.reserve(reference.t_s.size());
  for (double t : reference.t_s) r.ref_t_s.push_back(t + shift_s);
  r.q_world_ref = reference.q_world_ref;
  r.ref_line = reference.line;
  return r;
}

namespace {

// EuRoC/ASL: DIR/mav0/imu0/data.csv or DIR/imu0/data.csv, with mocap0 or the estimate.
absl::Status FindEurocFiles(const std::string& dir, std::string* imu, std::string* reference) {
  namespace fs = std::filesystem;
  for (const std::string base : {dir + "/mav0", dir}) {
    if (!fs::exists(base + "/imu0/data.csv")) continue;
    *imu = base + "/imu0/data.csv";
    for (const char* ref : {"/mocap0/data.csv", "/state_groundtruth_estimate0/data.csv",
                            "/vicon0/data.csv", "/leica0/data.csv"}) {
      if (fs::exists(base + ref)) {
        *reference = base + ref;
        return absl::OkStatus();
      }
    }
    return absl::InvalidArgumentError(Cat(dir,
                                          ": no reference orientation (mocap0/data.csv or "
                                          "state_groundtruth_estimate0/data.csv beside imu0)"));
  }
  return absl::InvalidArgumentError(
      Cat(dir, ": not an EuRoC/ASL directory (no mav0/imu0/data.csv or imu0/data.csv)"));
}

}  // namespace

absl::StatusOr<core::motion::MotionRecording> ReadMotionRecording(const std::string& spec) {
  namespace fs = std::filesystem;
  std::string imu_path, ref_path;
  std::error_code error;
  if (fs::is_directory(spec, error)) {
    if (absl::Status s = FindEurocFiles(spec, &imu_path, &ref_path); !s.ok()) return s;
  } else {
    // The first ':' whose both sides are files (a path may hold ':' itself).
    for (size_t colon = spec.find(':'); colon != std::string::npos;
         colon = spec.find(':', colon + 1)) {
      const std::string a = spec.substr(0, colon), b = spec.substr(colon + 1);
      if (fs::is_regular_file(a, error) && fs::is_regular_file(b, error)) {
        imu_path = a;
        ref_path = b;
        break;
      }
    }
    if (imu_path.empty()) {
      return absl::InvalidArgumentError(
          Cat("recording '", spec,
              "': neither an EuRoC/ASL directory nor IMU_FILE:REFERENCE_FILE naming two files "
              "that exist"));
    }
  }
  absl::StatusOr<std::string> imu_text = ReadFileBytes(imu_path);
  if (!imu_text.ok()) return imu_text.status();
  absl::StatusOr<ImuStream> imu = ParseImuStream(*imu_text, imu_path);
  if (!imu.ok()) return imu.status();
  absl::StatusOr<std::string> ref_text = ReadFileBytes(ref_path);
  if (!ref_text.ok()) return ref_text.status();
  absl::StatusOr<ReferenceStream> ref = ParseReferenceStream(*ref_text, ref_path);
  if (!ref.ok()) return ref.status();
  core::motion::MotionRecording r = JoinStreams(*imu, *ref);
  r.name = spec;
  r.imu_path = imu_path;
  r.reference_path = ref_path;
  return r;
}

}  // namespace imucal::importers
