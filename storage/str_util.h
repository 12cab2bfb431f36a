// String building for storage/*.cc (not part of the public API).
//
// The Debian absl build keeps its own absl::string_view (ABSL_OPTION_USE_STD_STRING_VIEW=0), so
// absl::StrCat rejects the std::string_view this library's API uses; Cat accepts both (as
// core/capture_io.cc does). Doubles print in their shortest round-trip form.
#ifndef IMUCAL_STORAGE_STR_UTIL_H_
#define IMUCAL_STORAGE_STR_UTIL_H_

#include <array>
#include <charconv>
#include <concepts>
#include <string>
#include <string_view>

#include "absl/strings/string_view.h"

namespace imucal::storage {

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

}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_STR_UTIL_H_
