// Files and texts for the importer tests: a temp path, whole-file write and read, an import of a
// text written to a temp file, the capture-format spec's example, and a small imu_tk pair.
#ifndef IMUCAL_TESTS_IMPORTERS_TEST_FILES_H_
#define IMUCAL_TESTS_IMPORTERS_TEST_FILES_H_

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <string_view>
#include <utility>

#include "absl/status/statusor.h"
#include "core/capture.h"
#include "gtest/gtest.h"
#include "importers/registry.h"

namespace imucal::importers::test_files {

inline constexpr char kSpecExample[] =
    "# imucal-capture v1\n"
    "# device=robot-0042\n"
    "# accel_unit=m/s^2\n"
    "# gyro_unit=rad/s\n"
    "# gravity=9.80665\n"
    "# rate_hz=200\n"
    "t,ax,ay,az,gx,gy,gz,temp\n"
    "0.000000,0.0131,-0.0203,9.8152,0.00102,-0.00031,0.00207,24.81\n"
    "0.005000,0.0127,-0.0199,9.8149,0.00098,-0.00027,0.00211,24.81\n";

// A minimal valid header; tests append their own column line and rows.
inline constexpr char kHeader[] =
    "# imucal-capture v1\n"
    "# accel_unit=m/s^2\n"
    "# gyro_unit=rad/s\n";

inline std::string TempPath(std::string_view name) {
  return (std::filesystem::path(testing::TempDir()) / name).string();
}

inline void WriteText(const std::string& path, std::string_view text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(text.data(), static_cast<std::streamsize>(text.size()));
  ASSERT_TRUE(out.good()) << path;
}

inline std::string ReadText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// A small pair in deg/s and m/s^2: 50 static samples, a rotation, 50 static samples.
inline std::pair<std::string, std::string> ImuTkTexts() {
  std::string accel, gyro;
  for (int i = 0; i < 120; ++i) {
    const std::string t = std::to_string(0.01 * i);
    const bool turning = i >= 50 && i < 70;
    accel += "  " + t + "  0.01  -0.02  " + (i < 60 ? "9.81" : "-9.79") + "\n";
    gyro += t + "\t0.1\t" + (turning ? "90.0" : "-0.2") + "\t0.05\n";
  }
  return {accel, gyro};
}

// Writes `text` to the temp file `name` and imports it.
inline absl::StatusOr<core::Capture> ImportText(std::string_view name, std::string_view text,
                                                const ImportOptions& options,
                                                ImportReport* report = nullptr) {
  const std::string path = TempPath(name);
  WriteText(path, text);
  return ImportCapture({path}, options, report);
}

}  // namespace imucal::importers::test_files

#endif  // IMUCAL_TESTS_IMPORTERS_TEST_FILES_H_
