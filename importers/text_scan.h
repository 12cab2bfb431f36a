// Text scanning shared by the capture readers (imucal CSV, imu_tk, EuRoC, vendor CSV, a bag's
// metadata.yaml): lines, spaces and numbers read from string_views into one buffer that holds the
// whole file, so a 50,000-line capture costs no allocation per line or per value; and the wording
// of their errors, so that every reader names the source, the line, the column and the text the
// same way ("SOURCE:LINE: column 'ax': 'abc' is not a number").
#ifndef IMUCAL_IMPORTERS_TEXT_SCAN_H_
#define IMUCAL_IMPORTERS_TEXT_SCAN_H_

#include <array>
#include <cfloat>
#include <charconv>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "util/file.h"  // ReadFileBytes, for the parsers

namespace imucal::importers {

inline constexpr std::string_view kUtf8Bom = "\xEF\xBB\xBF";

// `text` without a leading UTF-8 byte-order mark (which editors on Windows write).
inline std::string_view WithoutBom(std::string_view text) {
  return text.starts_with(kUtf8Bom) ? text.substr(kUtf8Bom.size()) : text;
}

// ---------------------------------------------------------------------------------------------
// Lines and spaces.

// Splits text into lines without copying. Accepts LF and CRLF; a final line without a newline
// counts, an empty remainder after the last newline does not.
class LineCursor {
 public:
  explicit LineCursor(std::string_view text) : text_(text) {}

  bool Next(std::string_view* line) {
    if (pos_ >= text_.size()) return false;
    const char* begin = text_.data() + pos_;
    const size_t left = text_.size() - pos_;
    const void* newline = std::memchr(begin, '\n', left);
    size_t length = newline == nullptr ? left : static_cast<const char*>(newline) - begin;
    pos_ += newline == nullptr ? left : length + 1;
    if (length > 0 && begin[length - 1] == '\r') --length;
    *line = std::string_view(begin, length);
    ++line_number_;
    return true;
  }

  // 1-based number of the line last returned by Next (0 before the first).
  int line_number() const { return line_number_; }
  std::string_view rest() const { return text_.substr(pos_); }

 private:
  std::string_view text_;
  size_t pos_ = 0;
  int line_number_ = 0;
};

// Upper bound on the lines in `text` (to reserve sample vectors once).
size_t CountLines(std::string_view text);

// Spaces and tabs (the only white space inside a line).
inline bool IsSpace(char c) { return c == ' ' || c == '\t'; }
std::string_view TrimSpaces(std::string_view s);
bool IsBlank(std::string_view line);

// ---------------------------------------------------------------------------------------------
// Numbers. Inline: the readers' row loops call them once per value.

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

inline constexpr std::array<double, 23> kExactPowersOf10 = {
    1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,  1e8,  1e9,  1e10, 1e11,
    1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};

inline bool IsDigit(char c) { return c >= '0' && c <= '9'; }

// Same contract as std::from_chars(first, last, value) with chars_format::general.
inline std::from_chars_result FromChars(const char* first, const char* last, double& value) {
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

// The hot loops' number reader: skips spaces and a leading '+', parses a finite number at `p` and
// returns where it ends, or nullptr. Accepts exactly what ParseNumber accepts, but lets
// from_chars find the end of the number instead of searching for the separator first.
inline const char* ScanNumber(const char* p, const char* end, double* value) {
  while (p != end && IsSpace(*p)) ++p;
  if (p != end && *p == '+') {
    ++p;
    if (p != end && (*p == '+' || *p == '-')) return nullptr;
  }
  const auto [next, ec] = FromChars(p, end, *value);
  if (ec != std::errc() || !std::isfinite(*value)) return nullptr;
  return next;
}

// What ParseNumber found wrong with a field.
enum class NumberError { kNone, kEmpty, kNotNumber, kOutOfRange, kNotFinite };

// Parses a whole field as a finite double. Surrounding spaces and a leading '+' (which
// from_chars rejects but spreadsheets write) are accepted; nothing else may follow the number.
NumberError ParseNumber(std::string_view field, double* value);

// Shortest text that parses back to exactly `value` (the round-trip guarantee of to_chars).
std::string FormatDouble(double value);

// ---------------------------------------------------------------------------------------------
// Errors: InvalidArgument "SOURCE:LINE: message".

absl::Status LineError(std::string_view source, int line_number, std::string_view message);

// `text` with control bytes escaped (\0, \t, \r, \n, \xHH): a NUL in a message would cut it off.
std::string Escaped(std::string_view text);

// 'text', escaped, cut to 40 characters (a binary file fed to a reader must not produce a
// megabyte-long status).
std::string Quoted(std::string_view text);

// "SOURCE:LINE: column 'COLUMN': 'x' is not a number" (or empty field / is out of range / is not
// finite), for a field that ParseNumber rejected with `error`.
absl::Status NumberFieldError(std::string_view source, int line_number, std::string_view column,
                              std::string_view field, NumberError error);

// ParseNumber, with NumberFieldError on failure.
absl::Status ParseNumberField(std::string_view field, std::string_view source, int line_number,
                              std::string_view column, double* value);

// "SOURCE:LINE: t=T does not increase (previous P at line N)".
absl::Status TimeNotIncreasingError(std::string_view source, int line_number, double t_s,
                                    double previous_t_s, int previous_line_number);

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_TEXT_SCAN_H_
