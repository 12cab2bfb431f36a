#include "core/capture.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <limits>
#include <numbers>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"

namespace imucal::core {
namespace {

// The unit names are the exact spellings of the capture header (capture-format.md); they are
// case-sensitive so that a file written by one tool reads the same in every other.
constexpr std::string_view kAccelMetersPerSecond2Name = "m/s^2";
constexpr std::string_view kAccelGName = "g";
constexpr std::string_view kGyroRadPerSecondName = "rad/s";
constexpr std::string_view kGyroDegPerSecondName = "deg/s";
constexpr std::string_view kTempCelsiusName = "C";
constexpr std::string_view kCountsName = "counts";

// Shortest round-trip text, so that two timestamps that differ print differently.
std::string FormatDouble(double value) {
  std::array<char, 32> buffer;
  const auto result = std::to_chars(buffer.data(), buffer.data() + buffer.size(), value);
  return std::string(buffer.data(), result.ptr);
}

bool AllFinite(const Eigen::Vector3d& v) { return v.allFinite(); }
bool AllFinite(double v) { return std::isfinite(v); }

absl::Status CheckLengths(const Capture& capture) {
  const size_t n = capture.t_s.size();
  if (capture.accel.size() != n) {
    return absl::InvalidArgumentError(absl::StrCat("capture has ", n, " timestamps but ",
                                                   capture.accel.size(), " accel samples"));
  }
  if (capture.has_gyro && capture.gyro.size() != n) {
    return absl::InvalidArgumentError(
        absl::StrCat("capture has ", n, " timestamps but ", capture.gyro.size(), " gyro samples"));
  }
  if (!capture.has_gyro && !capture.gyro.empty()) {
    return absl::InvalidArgumentError(absl::StrCat("capture says it has no gyroscope but holds ",
                                                   capture.gyro.size(), " gyro samples"));
  }
  if (!capture.temp.empty() && capture.temp.size() != n) {
    return absl::InvalidArgumentError(absl::StrCat("capture has ", n, " timestamps but ",
                                                   capture.temp.size(), " temperature samples"));
  }
  if (capture.extra_columns.size() != capture.extra_column_names.size()) {
    return absl::InvalidArgumentError(
        absl::StrCat("capture has ", capture.extra_column_names.size(), " extra column names but ",
                     capture.extra_columns.size(), " extra columns"));
  }
  if (!capture.line.empty() && capture.line.size() != n) {
    return absl::InvalidArgumentError(
        absl::StrCat("capture has ", n, " timestamps but ", capture.line.size(), " line numbers"));
  }
  for (size_t k = 0; k < capture.files.size(); ++k) {
    if ((k == 0 && capture.files[k].first_sample != 0) ||
        (k > 0 && capture.files[k].first_sample <= capture.files[k - 1].first_sample) ||
        capture.files[k].first_sample >= std::max<size_t>(n, 1)) {
      return absl::InvalidArgumentError(
          absl::StrCat("capture file ", k, " ('", capture.files[k].path, "') starts at sample ",
                       capture.files[k].first_sample, ", not after the previous file within the ",
                       n, " samples"));
    }
  }
  for (size_t c = 0; c < capture.extra_columns.size(); ++c) {
    if (capture.extra_columns[c].size() != n) {
      return absl::InvalidArgumentError(absl::StrCat(
          "capture has ", n, " timestamps but extra column '", capture.extra_column_names[c],
          "' has ", capture.extra_columns[c].size(), " values"));
    }
  }
  return absl::OkStatus();
}

template <typename T>
absl::Status CheckFinite(const std::vector<T>& values, const std::string& what) {
  for (size_t i = 0; i < values.size(); ++i) {
    if (!AllFinite(values[i])) {
      return absl::InvalidArgumentError(absl::StrCat("sample ", i, ": ", what, " is not finite"));
    }
  }
  return absl::OkStatus();
}

absl::Status CheckAllFinite(const Capture& capture) {
  if (absl::Status s = CheckFinite(capture.t_s, "t"); !s.ok()) return s;
  if (absl::Status s = CheckFinite(capture.accel, "accel"); !s.ok()) return s;
  if (absl::Status s = CheckFinite(capture.gyro, "gyro"); !s.ok()) return s;
  if (absl::Status s = CheckFinite(capture.temp, "temp"); !s.ok()) return s;
  for (size_t c = 0; c < capture.extra_columns.size(); ++c) {
    const std::string what = absl::StrCat("column '", capture.extra_column_names[c], "'");
    if (absl::Status s = CheckFinite(capture.extra_columns[c], what); !s.ok()) return s;
  }
  return absl::OkStatus();
}

absl::Status CheckTimeIncreasing(const Capture& capture) {
  for (size_t i = 1; i < capture.t_s.size(); ++i) {
    if (!(capture.t_s[i] > capture.t_s[i - 1])) {
      return absl::InvalidArgumentError(
          absl::StrCat("sample ", i, ": t=", FormatDouble(capture.t_s[i]),
                       " does not increase (previous ", FormatDouble(capture.t_s[i - 1]), ")"));
    }
  }
  return absl::OkStatus();
}

absl::Status CheckHeaderValues(const Capture& capture) {
  if (!std::isfinite(capture.gravity_m_s2) || capture.gravity_m_s2 <= 0.0) {
    return absl::InvalidArgumentError(absl::StrCat("gravity must be finite and positive, got ",
                                                   FormatDouble(capture.gravity_m_s2)));
  }
  if (!std::isfinite(capture.rate_hz) || capture.rate_hz < 0.0) {
    return absl::InvalidArgumentError(absl::StrCat("rate_hz must be finite and not negative, got ",
                                                   FormatDouble(capture.rate_hz)));
  }
  return absl::OkStatus();
}

}  // namespace

std::string_view AccelUnitName(AccelUnit unit) {
  switch (unit) {
    case AccelUnit::kMetersPerSecond2:
      return kAccelMetersPerSecond2Name;
    case AccelUnit::kG:
      return kAccelGName;
    case AccelUnit::kCounts:
      return kCountsName;
  }
  return "unknown";
}

std::string_view GyroUnitName(GyroUnit unit) {
  switch (unit) {
    case GyroUnit::kRadPerSecond:
      return kGyroRadPerSecondName;
    case GyroUnit::kDegPerSecond:
      return kGyroDegPerSecondName;
    case GyroUnit::kCounts:
      return kCountsName;
  }
  return "unknown";
}

std::string_view TempUnitName(TempUnit unit) {
  switch (unit) {
    case TempUnit::kCelsius:
      return kTempCelsiusName;
    case TempUnit::kCounts:
      return kCountsName;
  }
  return "unknown";
}

absl::StatusOr<AccelUnit> ParseAccelUnit(std::string_view name) {
  if (name == kAccelMetersPerSecond2Name) return AccelUnit::kMetersPerSecond2;
  if (name == kAccelGName) return AccelUnit::kG;
  if (name == kCountsName) return AccelUnit::kCounts;
  return absl::InvalidArgumentError(
      absl::StrCat("unknown accel unit '", std::string(name), "' (expected m/s^2, g or counts)"));
}

absl::StatusOr<GyroUnit> ParseGyroUnit(std::string_view name) {
  if (name == kGyroRadPerSecondName) return GyroUnit::kRadPerSecond;
  if (name == kGyroDegPerSecondName) return GyroUnit::kDegPerSecond;
  if (name == kCountsName) return GyroUnit::kCounts;
  return absl::InvalidArgumentError(absl::StrCat("unknown gyro unit '", std::string(name),
                                                 "' (expected rad/s, deg/s or counts)"));
}

absl::StatusOr<TempUnit> ParseTempUnit(std::string_view name) {
  if (name == kTempCelsiusName) return TempUnit::kCelsius;
  if (name == kCountsName) return TempUnit::kCounts;
  return absl::InvalidArgumentError(
      absl::StrCat("unknown temp unit '", std::string(name), "' (expected C or counts)"));
}

double NominalAccelToSi(AccelUnit unit, double gravity_m_s2) {
  switch (unit) {
    case AccelUnit::kMetersPerSecond2:
      return 1.0;
    case AccelUnit::kG:
      return gravity_m_s2;
    case AccelUnit::kCounts:
      break;
  }
  return std::numeric_limits<double>::quiet_NaN();
}

double NominalGyroToSi(GyroUnit unit) {
  switch (unit) {
    case GyroUnit::kRadPerSecond:
      return 1.0;
    case GyroUnit::kDegPerSecond:
      return std::numbers::pi / 180.0;
    case GyroUnit::kCounts:
      break;
  }
  return std::numeric_limits<double>::quiet_NaN();
}

double Capture::MedianDt() const {
  if (t_s.size() < 2) return 0.0;
  std::vector<double> dt_s(t_s.size() - 1);
  for (size_t i = 1; i < t_s.size(); ++i) dt_s[i - 1] = t_s[i] - t_s[i - 1];
  // Upper median for an even count: a sample interval that occurs in the data, not an average
  // of two, so a capture with a few dropped samples still reports its true interval.
  const auto mid = dt_s.begin() + static_cast<std::ptrdiff_t>(dt_s.size() / 2);
  std::nth_element(dt_s.begin(), mid, dt_s.end());
  return *mid;
}

std::vector<size_t> Capture::FileStarts() const {
  std::vector<size_t> out;
  for (size_t k = 1; k < files.size(); ++k) out.push_back(files[k].first_sample);
  return out;
}

int Capture::FileOf(size_t i) const {
  int out = -1;
  for (size_t k = 0; k < files.size() && files[k].first_sample <= i; ++k) out = static_cast<int>(k);
  return out;
}

absl::Status ValidateCapture(const Capture& capture) {
  if (absl::Status s = CheckLengths(capture); !s.ok()) return s;
  if (absl::Status s = CheckHeaderValues(capture); !s.ok()) return s;
  if (absl::Status s = CheckAllFinite(capture); !s.ok()) return s;
  return CheckTimeIncreasing(capture);
}

}  // namespace imucal::core
