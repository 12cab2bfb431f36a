// String building that accepts std::string_view. The Debian absl build keeps its own
// absl::string_view (ABSL_OPTION_USE_STD_STRING_VIEW=0), so absl::StrCat and friends reject the
// std::string_view that imucal's APIs use; these small equivalents accept both. Integers print
// exactly, doubles in their shortest round-trip form (std::to_chars).
//
// In namespace imucal itself (as absl::StrCat is in absl), so that code in every imucal library
// (core, storage, server, ...) calls Cat and Join unqualified.
#ifndef IMUCAL_UTIL_STR_UTIL_H_
#define IMUCAL_UTIL_STR_UTIL_H_

#include <array>
#include <charconv>
#include <concepts>
#include <string>
#include <string_view>

#include "absl/strings/string_view.h"

namespace imucal {

inline void AppendPiece(std::string* out, std::string_view s) { out->append(s); }
inline void AppendPiece(std::string* out, absl::string_view s) { out->append(s.data(), s.size()); }
inline void AppendPiece(std::string* out, const std::string& s) { out->append(s); }
inline void AppendPiece(std::string* out, const char* s) { out->append(s); }

template <std::integral Int>
void AppendPiece(std::string* out, Int value) {
  static_assert(!std::same_as<Int, char> && !std::same_as<Int, bool>, "not a number to print");
  std::array<char, 24> buffer;
  const auto result = std::to_chars(buffer.data(), buffer.data() + buffer.size(), value);
  out->append(buffer.data(), result.ptr);
}

inline void AppendPiece(std::string* out, double value) {
  std::array<char, 32> buffer;
  const auto result = std::to_chars(buffer.data(), buffer.data() + buffer.size(), value);
  out->append(buffer.data(), result.ptr);
}

template <typename... Pieces>
void AppendTo(std::string* out, const Pieces&... pieces) {
  (AppendPiece(out, pieces), ...);
}

template <typename... Pieces>
std::string Cat(const Pieces&... pieces) {
  std::string out;
  AppendTo(&out, pieces...);
  return out;
}

template <typename Range>
std::string Join(const Range& pieces, std::string_view separator) {
  std::string out;
  bool first = true;
  for (const auto& piece : pieces) {
    if (!first) out.append(separator);
    AppendPiece(&out, piece);
    first = false;
  }
  return out;
}

}  // namespace imucal

#endif  // IMUCAL_UTIL_STR_UTIL_H_
