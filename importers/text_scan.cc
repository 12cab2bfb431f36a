#include "importers/text_scan.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_format.h"
#include "util/str_util.h"

namespace imucal::importers {
namespace {

// Longest bad text quoted in full in an error message.
constexpr size_t kMaxQuotedChars = 40;

}  // namespace

// ---------------------------------------------------------------------------------------------
// Lines and spaces.

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

std::string_view TrimSpaces(std::string_view s) {
  while (!s.empty() && IsSpace(s.front())) s.remove_prefix(1);
  while (!s.empty() && IsSpace(s.back())) s.remove_suffix(1);
  return s;
}

bool IsBlank(std::string_view line) { return std::all_of(line.begin(), line.end(), IsSpace); }

// ---------------------------------------------------------------------------------------------
// Numbers.

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

std::string FormatDouble(double value) {
  std::array<char, 32> buffer;
  const auto result = std::to_chars(buffer.data(), buffer.data() + buffer.size(), value);
  return std::string(buffer.data(), result.ptr);
}

// ---------------------------------------------------------------------------------------------
// Errors.

absl::Status LineError(std::string_view source, int line_number, std::string_view message) {
  return absl::InvalidArgumentError(Cat(source, ":", line_number, ": ", message));
}

std::string Escaped(std::string_view text) {
  std::string out;
  for (const char ch : text) {
    const auto c = static_cast<unsigned char>(ch);
    switch (c) {
      case '\0':
        out += "\\0";
        break;
      case '\t':
        out += "\\t";
        break;
      case '\r':
        out += "\\r";
        break;
      case '\n':
        out += "\\n";
        break;
      default:
        if (c < 0x20 || c == 0x7f) {
          absl::StrAppendFormat(&out, "\\x%02x", c);
        } else {
          out += ch;
        }
    }
  }
  return out;
}

std::string Quoted(std::string_view text) {
  if (text.size() <= kMaxQuotedChars) return Cat("'", Escaped(text), "'");
  return Cat("'", Escaped(text.substr(0, kMaxQuotedChars)), "...'");
}

// " (a control byte \0 at byte 3 of the field)" for the first control byte of `field`, else "".
std::string ControlByteNote(std::string_view field) {
  for (size_t i = 0; i < field.size(); ++i) {
    const auto c = static_cast<unsigned char>(field[i]);
    if (c < 0x20 || c == 0x7f) {
      return Cat(" (a control byte ", Escaped(field.substr(i, 1)), " at byte ", i + 1,
                 " of the field)");
    }
  }
  return "";
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
      problem = Cat(text, " is not a number", ControlByteNote(field));
      break;
  }
  return LineError(source, line_number, Cat("column '", column, "': ", problem));
}

absl::Status ParseNumberField(std::string_view field, std::string_view source, int line_number,
                              std::string_view column, double* value) {
  const NumberError error = ParseNumber(field, value);
  if (error == NumberError::kNone) return absl::OkStatus();
  return NumberFieldError(source, line_number, column, field, error);
}

absl::Status TimeNotIncreasingError(std::string_view source, int line_number, double t_s,
                                    double previous_t_s, int previous_line_number) {
  return LineError(source, line_number,
                   Cat("t=", FormatDouble(t_s), " does not increase (previous ",
                       FormatDouble(previous_t_s), " at line ", previous_line_number, ")"));
}

}  // namespace imucal::importers
