// Fields of a server's JSON document (a report, a parameter set) as text, for the summaries of
// `imucal report` and `imucal params get`: a missing or mistyped field prints as missing, it
// does not stop the summary.
#ifndef IMUCAL_CLIENT_CLI_JSON_TEXT_H_
#define IMUCAL_CLIENT_CLI_JSON_TEXT_H_

#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "nlohmann/json.hpp"

namespace imucal::cli {

// "[+0.00100, -0.00200, null]" (each number with `fmt`), "-" when `v` is not an array.
inline std::string JsonVector(const nlohmann::json& v, const char* fmt = "%+.5f") {
  if (!v.is_array()) return "-";
  std::vector<std::string> parts;
  for (const auto& x : v)
    parts.push_back(x.is_number() ? absl::StrFormat(fmt, x.get<double>()) : std::string("null"));
  return absl::StrCat("[", absl::StrJoin(parts, ", "), "]");
}

// j[key] when it is a number, else NaN.
inline double JsonNumber(const nlohmann::json& j, const char* key) {
  return j.contains(key) && j[key].is_number() ? j[key].get<double>() : std::nan("");
}

// j[key] when it is a string, else "".
inline std::string JsonString(const nlohmann::json& j, const char* key) {
  return j.contains(key) && j[key].is_string() ? j[key].get<std::string>() : "";
}

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_JSON_TEXT_H_
