#include "importers/capture_io.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <cfloat>
#include <charconv>
#include <cmath>
#include <concepts>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_format.h"
#include "absl/strings/string_view.h"
#include "importers/capture_io_internal.h"
#include "importers/columns.h"
#include "importers/euroc.h"
#include "util/str_util.h"

namespace imucal::importers {
namespace {

// ---------------------------------------------------------------------------------------------
// Text helpers shared by the readers. They work on string_views into the file buffer, so a
// 50,000-line capture costs no allocation per line or per value.

using io_internal::kUtf8Bom;

// Longest bad text quoted in full in an error message; a binary file fed to the reader must not
// produce a megabyte-long status.
constexpr size_t kMaxQuotedChars = 40;

bool IsSpace(char c) { return c == ' ' || c == '\t'; }

std::string_view TrimSpaces(std::string_view s) {
  while (!s.empty() && IsSpace(s.front())) s.remove_prefix(1);
  while (!s.empty() && IsSpace(s.back())) s.remove_suffix(1);
  return s;
}

bool IsBlank(std::string_view line) { return std::all_of(line.begin(), line.end(), IsSpace); }

std::string Quoted(std::string_view text) {
  if (text.size() <= kMaxQuotedChars) return Cat("'", text, "'");
  return Cat("'", text.substr(0, kMaxQuotedChars), "...'");
}

// Shortest text that parses back to exactly `value` (the round-trip guarantee of to_chars).
std::string_view FormatDouble(double value, std::array<char, 32>& buffer) {
  const auto result = std::to_chars(buffer.data(), buffer.data() + buffer.size(), value);
  return std::string_view(buffer.data(), static_cast<size_t>(result.ptr - buffer.data()));
}

std::string FormatDouble(double value) {
  std::array<char, 32> buffer;
  return std::string(FormatDouble(value, buffer));
}

absl::Status LineError(std::string_view source, int line_number, std::string_view message) {
  return absl::InvalidArgumentError(Cat(source, ":", line_number, ": ", message));
}

using io_internal::LineCursor;

// Upper bound on the rows left, to reserve the sample vectors once.
// memchr rather than std::count: glibc's is vectorised, GCC -O2 does not vectorise the count.
size_t CountLines(std::string_view text) {
  size_t lines = 1;
  const char* p = text.data();
  const char* const end = p + text.size();
  while (const void* newline = std::memchr(p, '\n', static_cast<size_t>(end - p))) {
    ++lines;
    p = static_cast<const char*>(newline) + 1;
  }
  return lines;
}

// Number parsing. std::from_chars is exact for every input; this puts Clinger's fast path in
// front of it for the plain decimals that loggers write ("-0.0203", "3.2786000e+04"). It halves
// the cost per number (about 18 -> 9 ns) and cuts the parse of a 50,000-line capture by about a
// quarter (bench/parse_bench.cc). When the significant digits form an integer m <= 2^53 and the
// decimal exponent e satisfies |e| <= 22, both m and 10^|e| are exact doubles, so the one IEEE
// multiplication or division rounds correctly and gives the same bits as from_chars
// (W. D. Clinger, "How to read floating point numbers accurately", PLDI 1990; also the first
// path of fast_float). Everything else (more digits, larger exponents, inf, nan, malformed text)
// goes to std::from_chars unchanged. The tests compare the two bit for bit.
static_assert(FLT_EVAL_METHOD == 0,
              "the fast path needs double arithmetic without excess precision");

constexpr std::array<double, 23> kExactPowersOf10 = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,
                                                     1e8,  1e9,  1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
                                                     1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};

bool IsDigit(char c) { return c >= '0' && c <= '9'; }

// Same contract as std::from_chars(first, last, value) with chars_format::general.
std::from_chars_result FromChars(const char* first, const char* last, double& value) {
  constexpr int kMaxDigits = 19;  // 10^19 - 1 < 2^64: the mantissa cannot overflow
  constexpr int kMaxExponentDigits = 4;
  constexpr uint64_t kMaxExactMantissa = uint64_t{1} << 53;
  const char* p = first;
  const bool negative = p != last && *p == '-';
  if (negative) ++p;
  uint64_t mantissa = 0;
  int significant_digits = 0;
  int exponent = 0;
  const char* const integer_start = p;
  for (; p != last && IsDigit(*p); ++p) {
    mantissa = 10 * mantissa + static_cast<uint64_t>(*p - '0');
    significant_digits += mantissa != 0;
  }
  bool any_digit = p != integer_start;
  if (p != last && *p == '.') {
    const char* const fraction_start = ++p;
    for (; p != last && IsDigit(*p); ++p) {
      mantissa = 10 * mantissa + static_cast<uint64_t>(*p - '0');
      significant_digits += mantissa != 0;
      --exponent;
    }
    any_digit = any_digit || p != fraction_start;
  }
  if (!any_digit || significant_digits > kMaxDigits) return std::from_chars(first, last, value);
  if (p != last && (*p == 'e' || *p == 'E')) {
    const char* q = p + 1;
    const bool exponent_negative = q != last && *q == '-';
    if (q != last && (*q == '-' || *q == '+')) ++q;
    const char* const exponent_start = q;
    int written_exponent = 0;
    for (; q != last && IsDigit(*q); ++q) {
      if (q - exponent_start == kMaxExponentDigits) return std::from_chars(first, last, value);
      written_exponent = 10 * written_exponent + (*q - '0');
    }
    // "1e" or "1e+": from_chars decides how much of it is the number.
    if (q == exponent_start) return std::from_chars(first, last, value);
    exponent += exponent_negative ? -written_exponent : written_exponent;
    p = q;
  }
  if (mantissa > kMaxExactMantissa || exponent < -22 || exponent > 22) {
    return std::from_chars(first, last, value);
  }
  double result = static_cast<double>(mantissa);
  if (exponent < 0) {
    result /= kExactPowersOf10[static_cast<size_t>(-exponent)];
  } else {
    result *= kExactPowersOf10[static_cast<size_t>(exponent)];
  }
  value = negative ? -result : result;
  return {p, std::errc()};
}

enum class NumberError { kNone, kEmpty, kNotNumber, kOutOfRange, kNotFinite };

// Parses a whole field as a finite double. Surrounding spaces and a leading '+' (which
// from_chars rejects but spreadsheets write) are accepted; nothing else may follow the number.
NumberError ParseNumber(std::string_view field, double* value) {
  field = TrimSpaces(field);
  if (field.empty()) return NumberError::kEmpty;
  const char* first = field.data();
  const char* last = first + field.size();
  if (*first == '+') {
    ++first;
    if (first == last || *first == '+' || *first == '-') return NumberError::kNotNumber;
  }
  const auto [ptr, ec] = FromChars(first, last, *value);
  if (ec == std::errc::result_out_of_range) return NumberError::kOutOfRange;
  if (ec != std::errc() || ptr != last) return NumberError::kNotNumber;
  if (!std::isfinite(*value)) return NumberError::kNotFinite;
  return NumberError::kNone;
}

absl::Status NumberFieldError(std::string_view source, int line_number, std::string_view column,
                              std::string_view field, NumberError error) {
  const std::string text = Quoted(TrimSpaces(field));
  std::string problem;
  switch (error) {
    case NumberError::kEmpty:
      problem = "empty field";
      break;
    case NumberError::kOutOfRange:
      problem = Cat(text, " is out of range");
      break;
    case NumberError::kNotFinite:
      problem = Cat(text, " is not finite");
      break;
    case NumberError::kNotNumber:
    case NumberError::kNone:
      problem = Cat(text, " is not a number");
      break;
  }
  return LineError(source, line_number, Cat("column '", column, "': ", problem));
}

absl::Status TimeNotIncreasingError(std::string_view source, int line_number, double t_s,
                                    double previous_t_s, int previous_line_number) {
  return LineError(source, line_number,
                   Cat("t=", FormatDouble(t_s), " does not increase (previous ",
                       FormatDouble(previous_t_s), " at line ", previous_line_number, ")"));
}

// ---------------------------------------------------------------------------------------------
// Files. One read of the whole file: the parsers then work on one contiguous buffer.

class ScopedFd {
 public:
  explicit ScopedFd(int fd) : fd_(fd) {}
  ScopedFd(const ScopedFd&) = delete;
  ScopedFd& operator=(const ScopedFd&) = delete;
  ~ScopedFd() {
    if (fd_ >= 0) ::close(fd_);
  }
  int get() const { return fd_; }
  // Closes now and reports the error that close() can carry for written files (e.g. NFS, quota).
  int Close() {
    const int result = ::close(fd_);
    fd_ = -1;
    return result;
  }

 private:
  int fd_;
};

// Reads at most `max_bytes` of `path` (all of it when max_bytes is nullopt).
absl::StatusOr<std::string> ReadFileBytes(const std::string& path,
                                          std::optional<size_t> max_bytes) {
  ScopedFd fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC));
  if (fd.get() < 0) return absl::ErrnoToStatus(errno, Cat(path, ": cannot open"));
  struct stat info;
  if (::fstat(fd.get(), &info) != 0) {
    return absl::ErrnoToStatus(errno, Cat(path, ": cannot stat"));
  }
  if (S_ISDIR(info.st_mode)) {
    return absl::InvalidArgumentError(Cat(path, ": is a directory, not a file"));
  }
  // st_size is exact for regular files; pipes and /proc files report 0 and are read in chunks.
  size_t capacity = info.st_size > 0 ? static_cast<size_t>(info.st_size) + 1 : 64 * 1024;
  if (max_bytes.has_value()) capacity = std::min(capacity, *max_bytes);
  std::string data(capacity, '\0');
  size_t size = 0;
  while (true) {
    if (size == data.size()) {
      if (max_bytes.has_value() && size >= *max_bytes) break;
      data.resize(max_bytes.has_value() ? std::min(2 * size, *max_bytes) : 2 * size);
    }
    const ssize_t n = ::read(fd.get(), data.data() + size, data.size() - size);
    if (n < 0) {
      if (errno == EINTR) continue;
      return absl::ErrnoToStatus(errno, Cat(path, ": cannot read"));
    }
    if (n == 0) break;
    size += static_cast<size_t>(n);
  }
  data.resize(size);
  return data;
}

absl::Status WriteFileBytes(const std::string& path, std::string_view data) {
  ScopedFd fd(::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644));
  if (fd.get() < 0) return absl::ErrnoToStatus(errno, Cat(path, ": cannot create"));
  while (!data.empty()) {
    const ssize_t n = ::write(fd.get(), data.data(), data.size());
    if (n < 0) {
      if (errno == EINTR) continue;
      return absl::ErrnoToStatus(errno, Cat(path, ": cannot write"));
    }
    data.remove_prefix(static_cast<size_t>(n));
  }
  // Flush to disk before the rename: otherwise a crash can leave the new name on empty content.
  if (::fsync(fd.get()) != 0) {
    return absl::ErrnoToStatus(errno, Cat(path, ": cannot sync"));
  }
  if (fd.Close() != 0) return absl::ErrnoToStatus(errno, Cat(path, ": cannot close"));
  return absl::OkStatus();
}

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

// The required columns in canonical (written) order; `temp` is optional.
constexpr std::array<std::string_view, 7> kRequiredColumns = {"t",  "ax", "ay", "az",
                                                              "gx", "gy", "gz"};
constexpr std::string_view kTempColumn = "temp";

// Where each known header key was first seen (0 = not seen), to reject duplicates and report
// missing required keys.
struct HeaderSeen {
  std::array<int, kKnownKeys.size()> line_of_key{};
};

absl::Status CheckMarkerLine(std::string_view line, std::string_view source) {
  if (line.starts_with(kUtf8Bom)) line.remove_prefix(kUtf8Bom.size());
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

absl::Status CheckRequiredHeaders(const HeaderSeen& seen, std::string_view source,
                                  int line_number) {
  for (const std::string_view key : {kKeyAccelUnit, kKeyGyroUnit}) {
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
};

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
  for (size_t i = 0; i < kRequiredColumns.size(); ++i) {
    if (layout.required[i] < 0) {
      return LineError(source, line_number,
                       Cat("missing required column '", kRequiredColumns[i], "'"));
    }
  }
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

// The hot loops' number reader: skips spaces and a leading '+', parses a finite number at `p` and
// returns where it ends, or nullptr. Accepts exactly what ParseNumber accepts, but lets
// from_chars find the end of the number instead of searching for the separator first.
const char* ScanNumber(const char* p, const char* end, double* value) {
  while (p != end && IsSpace(*p)) ++p;
  if (p != end && *p == '+') {
    ++p;
    if (p != end && (*p == '+' || *p == '-')) return nullptr;
  }
  const auto [next, ec] = FromChars(p, end, *value);
  if (ec != std::errc() || !std::isfinite(*value)) return nullptr;
  return next;
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
  capture->accel.reserve(rows);
  capture->gyro.reserve(rows);
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
    capture->t_s.push_back(t_s);
    auto at = [&](size_t k) { return row[static_cast<size_t>(col[k])]; };
    capture->accel.emplace_back(at(1), at(2), at(3));
    capture->gyro.emplace_back(at(4), at(5), at(6));
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
// Unit inference helpers.

// Element at quantile q in [0, 1] (nearest rank); `values` is reordered. NaN when empty.
double QuantileInPlace(std::vector<double>& values, double q) {
  if (values.empty()) return std::numeric_limits<double>::quiet_NaN();
  const size_t rank = static_cast<size_t>(std::ceil(q * static_cast<double>(values.size())));
  const size_t index = std::clamp<size_t>(rank, 1, values.size()) - 1;
  const auto it = values.begin() + static_cast<std::ptrdiff_t>(index);
  std::nth_element(values.begin(), it, values.end());
  return *it;
}

// Bands of the accelerometer rule (see InferAccelUnit in the header).
constexpr double kAccelBandFraction = 0.3;
// Gyro rule thresholds (see InferGyroUnit in the header).
constexpr double kGyroCountsMedianAbs = 50.0;
constexpr double kGyroDegPerSecondP99 = 20.0;
constexpr double kGyroRateQuantile = 0.99;

// ---------------------------------------------------------------------------------------------
// imu_tk ASCII.

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
    if (line_number == 1 && line.starts_with(kUtf8Bom)) line.remove_prefix(kUtf8Bom.size());
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

absl::Status CheckImportOptions(const ImportOptions& options) {
  if (options.gravity_m_s2.has_value() &&
      !(std::isfinite(*options.gravity_m_s2) && *options.gravity_m_s2 > 0.0)) {
    return absl::InvalidArgumentError(Cat("gravity override must be a positive number, got ",
                                          FormatDouble(*options.gravity_m_s2)));
  }
  return absl::OkStatus();
}

// Applies the ImportOptions overrides to a capture read from a file that states its own
// header values, noting every value that changes.
void ApplyOverrides(const ImportOptions& options, core::Capture* capture,
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
// Importers.

class ImucalImporter final : public CaptureImporter {
 public:
  std::string_view name() const override { return "imucal"; }
  std::string_view description() const override {
    return "imucal capture CSV (one file starting '# imucal-capture v1')";
  }

  absl::Status Sniff(std::span<const std::string> /*paths*/,
                     std::span<const std::string> heads) const override {
    std::string_view head = heads[0];
    if (head.starts_with(kUtf8Bom)) head.remove_prefix(kUtf8Bom.size());
    if (head.starts_with(kMarkerPrefix)) return absl::OkStatus();
    return absl::InvalidArgumentError(Cat("first line does not start with '", kMarkerPrefix, "'"));
  }

  absl::StatusOr<core::Capture> Import(const std::vector<std::string>& paths,
                                       const ImportOptions& options,
                                       std::vector<std::string>* used_paths,
                                       std::vector<std::string>* notes) const override {
    if (paths.size() != 1) {
      return absl::InvalidArgumentError(
          Cat("the imucal format reads one file, got ", paths.size(), ": ", Join(paths, ", ")));
    }
    absl::StatusOr<core::Capture> capture = ReadImucalCsvFile(paths[0]);
    if (!capture.ok()) return capture.status();
    ApplyOverrides(options, &*capture, notes);
    *used_paths = paths;
    return capture;
  }
};

class ImuTkImporter final : public CaptureImporter {
 public:
  std::string_view name() const override { return "imutk"; }
  std::string_view description() const override {
    return "imu_tk ASCII pair of 't x y z' files: accelerometer, then gyroscope";
  }

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
      if (lines.line_number() == 1 && line.starts_with(kUtf8Bom)) {
        line.remove_prefix(kUtf8Bom.size());
      }
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
// imucal CSV.

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
    if (absl::Status s = CheckRequiredHeaders(seen, source_name, line_number); !s.ok()) return s;
    absl::StatusOr<ColumnLayout> layout = ParseColumnLine(line, source_name, line_number);
    if (!layout.ok()) return layout.status();
    if (absl::Status s = ParseCsvRows(&lines, *layout, source_name, &capture); !s.ok()) return s;
    return capture;
  }
  const int last_line = lines.line_number();
  if (absl::Status s = CheckRequiredHeaders(seen, source_name, last_line); !s.ok()) return s;
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
  size_t rows = std::min({capture.t_s.size(), capture.accel.size(), capture.gyro.size()});
  const bool has_temp = capture.has_temp();
  if (has_temp) rows = std::min(rows, capture.temp.size());
  const size_t extra = std::min(capture.extra_column_names.size(), capture.extra_columns.size());
  for (size_t k = 0; k < extra; ++k) rows = std::min(rows, capture.extra_columns[k].size());

  std::string out;
  const size_t columns = 7 + (has_temp ? 1 : 0) + extra;
  // About 12 characters per value is typical; the string grows if the guess is short.
  out.reserve(512 + rows * columns * 12);
  AppendTo(&out, kImucalCaptureMarker, "\n");
  if (!capture.device.empty()) AppendTo(&out, "# ", kKeyDevice, "=", capture.device, "\n");
  AppendTo(&out, "# ", kKeyAccelUnit, "=", core::AccelUnitName(capture.accel_unit), "\n");
  AppendTo(&out, "# ", kKeyGyroUnit, "=", core::GyroUnitName(capture.gyro_unit), "\n");
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

  out.append(Join(kRequiredColumns, ","));
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
    for (int axis = 0; axis < 3; ++axis) writer.Add(capture.gyro[i][axis]);
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
  const std::string text = FormatImucalCsv(capture);
  const std::string temp_path = path + ".tmp";
  absl::Status written = WriteFileBytes(temp_path, text);
  if (written.ok() && std::rename(temp_path.c_str(), path.c_str()) != 0) {
    written = absl::ErrnoToStatus(errno, Cat(path, ": cannot rename ", temp_path));
  }
  if (!written.ok()) std::remove(temp_path.c_str());
  return written;
}

// ---------------------------------------------------------------------------------------------
// Unit inference.

core::AccelUnit InferAccelUnit(std::span<const Eigen::Vector3d> accel, double gravity_m_s2,
                               std::string* reason) {
  std::vector<double> magnitudes(accel.size());
  for (size_t i = 0; i < accel.size(); ++i) magnitudes[i] = accel[i].norm();
  const double median = QuantileInPlace(magnitudes, 0.5);
  core::AccelUnit unit = core::AccelUnit::kCounts;
  std::string why;
  if (accel.empty()) {
    unit = core::AccelUnit::kMetersPerSecond2;
    why = "no samples to go by";
  } else if (std::abs(median - gravity_m_s2) <= kAccelBandFraction * gravity_m_s2) {
    unit = core::AccelUnit::kMetersPerSecond2;
    why = absl::StrFormat("median |a| %.6g is near gravity %.6g", median, gravity_m_s2);
  } else if (std::abs(median - 1.0) <= kAccelBandFraction) {
    unit = core::AccelUnit::kG;
    why = absl::StrFormat("median |a| %.6g is near 1", median);
  } else {
    why = absl::StrFormat("median |a| %.6g is near neither %.6g (m/s^2) nor 1 (g)", median,
                          gravity_m_s2);
  }
  if (reason != nullptr) {
    *reason = Cat("accel unit inferred as ", core::AccelUnitName(unit), ": ", why);
  }
  return unit;
}

core::GyroUnit InferGyroUnit(std::span<const Eigen::Vector3d> gyro, core::AccelUnit accel_unit,
                             std::string* reason) {
  bool all_integers = true;
  std::vector<double> values;
  values.reserve(3 * gyro.size());
  for (const Eigen::Vector3d& w : gyro) {
    for (int axis = 0; axis < 3; ++axis) {
      all_integers = all_integers && std::floor(w[axis]) == w[axis];
      values.push_back(std::abs(w[axis]));
    }
  }
  const double median_abs = QuantileInPlace(values, 0.5);
  values.resize(gyro.size());
  for (size_t i = 0; i < gyro.size(); ++i) values[i] = gyro[i].norm();
  const double p99_rate = QuantileInPlace(values, kGyroRateQuantile);

  core::GyroUnit unit = core::GyroUnit::kRadPerSecond;
  std::string why;
  if (gyro.empty()) {
    why = "no samples to go by";
  } else if (accel_unit == core::AccelUnit::kCounts &&
             (all_integers || median_abs > kGyroCountsMedianAbs)) {
    unit = core::GyroUnit::kCounts;
    why = all_integers
              ? "the accelerometer is counts and every gyro value is an integer"
              : absl::StrFormat("the accelerometer is counts and the median |gyro value| %.6g > %g",
                                median_abs, kGyroCountsMedianAbs);
  } else if (p99_rate > kGyroDegPerSecondP99) {
    unit = core::GyroUnit::kDegPerSecond;
    why = absl::StrFormat("99th-percentile |rate| %.6g > %g", p99_rate, kGyroDegPerSecondP99);
  } else {
    why = absl::StrFormat(
        "99th-percentile |rate| %.6g <= %g (a capture with little rotation cannot tell deg/s "
        "from rad/s: give the unit if this is wrong)",
        p99_rate, kGyroDegPerSecondP99);
  }
  if (reason != nullptr) {
    *reason = Cat("gyro unit inferred as ", core::GyroUnitName(unit), ": ", why);
  }
  return unit;
}

// ---------------------------------------------------------------------------------------------
// imu_tk pair.

absl::StatusOr<core::Capture> ParseImuTkPair(std::string_view accel_text,
                                             std::string_view accel_name,
                                             std::string_view gyro_text, std::string_view gyro_name,
                                             const ImportOptions& options,
                                             std::vector<std::string>* notes) {
  if (absl::Status s = CheckImportOptions(options); !s.ok()) return s;
  absl::StatusOr<ImuTkSeries> accel = ParseImuTkText(accel_text, accel_name);
  if (!accel.ok()) return accel.status();
  absl::StatusOr<ImuTkSeries> gyro = ParseImuTkText(gyro_text, gyro_name);
  if (!gyro.ok()) return gyro.status();
  if (absl::Status s = CheckImuTkPairAligned(*accel, accel_name, *gyro, gyro_name); !s.ok()) {
    return s;
  }

  core::Capture capture;
  capture.device = options.device.value_or("");
  capture.gravity_m_s2 = options.gravity_m_s2.value_or(core::kStandardGravity);
  capture.t_s = std::move(accel->t_s);
  capture.accel = std::move(accel->xyz);
  capture.gyro = std::move(gyro->xyz);
  std::string reason;
  if (options.accel_unit.has_value()) {
    capture.accel_unit = *options.accel_unit;
  } else {
    capture.accel_unit = InferAccelUnit(capture.accel, capture.gravity_m_s2, &reason);
    if (notes != nullptr) notes->push_back(reason);
  }
  if (options.gyro_unit.has_value()) {
    capture.gyro_unit = *options.gyro_unit;
  } else {
    capture.gyro_unit = InferGyroUnit(capture.gyro, capture.accel_unit, &reason);
    if (notes != nullptr) notes->push_back(reason);
  }
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

// ---------------------------------------------------------------------------------------------
// Registry.

namespace {

// Order is the auto-detection order: explicit markers (imucal, EuRoC's header) before content
// heuristics. Leaked on purpose (no destructors at exit for function-local statics).
std::vector<const CaptureImporter*>& MutableImporters() {
  static auto* const importers = new std::vector<const CaptureImporter*>{
      new ImucalImporter(),
      EurocCsvImporter(),
      new ImuTkImporter(),
      ColumnCsvImporter(),
  };
  return *importers;
}

std::mutex& RegistryMutex() {
  static auto* const mutex = new std::mutex();
  return *mutex;
}

}  // namespace

std::span<const CaptureImporter* const> CaptureImporters() {
  std::lock_guard<std::mutex> lock(RegistryMutex());
  return MutableImporters();
}

void RegisterCaptureImporter(const CaptureImporter* importer) {
  std::lock_guard<std::mutex> lock(RegistryMutex());
  std::vector<const CaptureImporter*>& importers = MutableImporters();
  for (const CaptureImporter* known : importers) {
    if (known->name() == importer->name()) return;
  }
  importers.push_back(importer);
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
// Helpers shared with the other importers in core (capture_io_internal.h).

namespace io_internal {

absl::StatusOr<std::string> ReadFileText(const std::string& path, std::optional<size_t> max_bytes) {
  return ReadFileBytes(path, max_bytes);
}

size_t CountTextLines(std::string_view text) { return CountLines(text); }
std::string_view TrimText(std::string_view s) { return TrimSpaces(s); }
bool IsBlankText(std::string_view line) { return IsBlank(line); }
std::string QuoteText(std::string_view text) { return Quoted(text); }
std::string DoubleText(double value) { return FormatDouble(value); }

absl::Status LineErrorAt(std::string_view source, int line_number, std::string_view message) {
  return LineError(source, line_number, message);
}

absl::Status ParseNumberField(std::string_view field, std::string_view source, int line_number,
                              std::string_view column, double* value) {
  const NumberError error = ParseNumber(field, value);
  if (error == NumberError::kNone) return absl::OkStatus();
  return NumberFieldError(source, line_number, column, field, error);
}

void ApplyImportOverrides(const ImportOptions& options, core::Capture* capture,
                          std::vector<std::string>* notes) {
  ApplyOverrides(options, capture, notes);
}

}  // namespace io_internal

}  // namespace imucal::importers
