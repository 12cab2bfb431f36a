// Text-reading helpers of capture_io.cc shared with the other importers in core
// (import_columns.cc, import_euroc.cc), so that every reader splits lines, parses numbers and
// words its errors the same way ("SOURCE:LINE: column 'ax': 'abc' is not a number").
// Not a public API: for importers only (core, and storage/rosbag2_import.cc); everything else
// uses capture_io.h.
#ifndef IMUCAL_IMPORTERS_CAPTURE_IO_INTERNAL_H_
#define IMUCAL_IMPORTERS_CAPTURE_IO_INTERNAL_H_

#include <cstddef>
#include <cstring>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/capture.h"
#include "importers/capture_io.h"

namespace imucal::importers::io_internal {

inline constexpr std::string_view kUtf8Bom = "\xEF\xBB\xBF";

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

// The whole file, or at most `max_bytes` of it; errors name the path and keep errno's code.
absl::StatusOr<std::string> ReadFileText(const std::string& path,
                                         std::optional<size_t> max_bytes = std::nullopt);

// Upper bound on the lines in `text` (to reserve sample vectors once).
size_t CountTextLines(std::string_view text);

// Spaces and tabs.
std::string_view TrimText(std::string_view s);
bool IsBlankText(std::string_view line);
// 'text', cut to 40 characters.
std::string QuoteText(std::string_view text);
// Shortest round-trip form.
std::string DoubleText(double value);

// "SOURCE:LINE: message" as InvalidArgument.
absl::Status LineErrorAt(std::string_view source, int line_number, std::string_view message);

// A whole field as a finite double, as the imucal CSV reader accepts it (surrounding spaces, a
// leading '+'). On failure returns "SOURCE:LINE: column 'COLUMN': 'x' is not a number" (or
// empty field / out of range / not finite).
absl::Status ParseNumberField(std::string_view field, std::string_view source, int line_number,
                              std::string_view column, double* value);

// Applies the device/unit/gravity overrides of `options` to a capture whose file stated its own
// values, noting every value that changes.
void ApplyImportOverrides(const ImportOptions& options, core::Capture* capture,
                          std::vector<std::string>* notes);

}  // namespace imucal::importers::io_internal

#endif  // IMUCAL_IMPORTERS_CAPTURE_IO_INTERNAL_H_
