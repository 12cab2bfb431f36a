// Tests of the imu_tk ASCII pair (importers/imutk.h).
#include "importers/imutk.h"

#include <string>
#include <vector>

#include "Eigen/Core"
#include "core/capture.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "importers/registry.h"
#include "tests/importers/test_files.h"

namespace imucal::importers {
namespace {

using test_files::ImuTkTexts;
using ::testing::StartsWith;

TEST(ImuTkTest, ParsesAndInfersPhysicalUnits) {
  const auto [accel, gyro] = ImuTkTexts();
  std::vector<std::string> notes;
  absl::StatusOr<core::Capture> c = ParseImuTkPair(accel, "acc.txt", gyro, "gyr.txt", {}, &notes);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->size(), 120u);
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kMetersPerSecond2);
  EXPECT_EQ(c->gyro_unit, core::GyroUnit::kDegPerSecond);
  EXPECT_EQ(c->gravity_m_s2, core::kStandardGravity);
  EXPECT_EQ(c->accel[70], Eigen::Vector3d(0.01, -0.02, -9.79));
  EXPECT_EQ(c->gyro[55], Eigen::Vector3d(0.1, 90.0, 0.05));
  ASSERT_EQ(notes.size(), 2u);
  EXPECT_THAT(notes[0], StartsWith("accel unit inferred as m/s^2"));
  EXPECT_THAT(notes[1], StartsWith("gyro unit inferred as deg/s"));
  EXPECT_TRUE(core::ValidateCapture(*c).ok());
}

TEST(ImuTkTest, OptionsOverrideInference) {
  const auto [accel, gyro] = ImuTkTexts();
  ImportOptions options;
  options.accel_unit = core::AccelUnit::kCounts;
  options.gyro_unit = core::GyroUnit::kRadPerSecond;
  options.gravity_m_s2 = 9.81744;
  options.device = "xsens";
  std::vector<std::string> notes;
  absl::StatusOr<core::Capture> c = ParseImuTkPair(accel, "a", gyro, "g", options, &notes);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kCounts);
  EXPECT_EQ(c->gyro_unit, core::GyroUnit::kRadPerSecond);
  EXPECT_EQ(c->gravity_m_s2, 9.81744);
  EXPECT_EQ(c->device, "xsens");
  EXPECT_TRUE(notes.empty());
}

TEST(ImuTkTest, MismatchedRowCount) {
  auto [accel, gyro] = ImuTkTexts();
  gyro.resize(gyro.rfind('\n', gyro.size() - 2) + 1);  // drop the last gyro line
  absl::StatusOr<core::Capture> c = ParseImuTkPair(accel, "acc.txt", gyro, "gyr.txt", {});
  EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(c.status().message(),
            "gyr.txt:119: ends after 119 samples, but acc.txt has 120 (sample 120 at "
            "acc.txt:120, t=1.19)");
}

TEST(ImuTkTest, MismatchedTimestamp) {
  auto [accel, gyro] = ImuTkTexts();
  const size_t at = gyro.find("0.300000");  // sample 31, line 31
  ASSERT_NE(at, std::string::npos);
  gyro.replace(at, 8, "0.300500");
  absl::StatusOr<core::Capture> c = ParseImuTkPair(accel, "acc.txt", gyro, "gyr.txt", {});
  EXPECT_EQ(c.status().message(), "gyr.txt:31: t=0.3005 does not match acc.txt:31 (t=0.3)");
}

TEST(ImuTkTest, LineErrors) {
  const std::string good = "0 1 2 3\n0.01 1 2 3\n";
  auto error = [&](const std::string& accel) {
    return std::string(ParseImuTkPair(accel, "acc.txt", good, "gyr.txt", {}).status().message());
  };
  EXPECT_EQ(error("0 1 2 3\n\n0.01 1 2 3 4\n"), "acc.txt:3: expected 4 fields (t x y z), found 5");
  EXPECT_EQ(error("0 1 2 3\n0.01 1 y 3\n"), "acc.txt:2: column 'y': 'y' is not a number");
  EXPECT_EQ(error("0 1 2 3\n0.01 1 2 nan\n"), "acc.txt:2: column 'z': 'nan' is not finite");
  EXPECT_EQ(error("0 1 2 3\n0 1 2 3\n"), "acc.txt:2: t=0 does not increase (previous 0 at line 1)");
  EXPECT_EQ(error("\n\n"), "acc.txt:2: no samples (expected lines of 't x y z')");
}

TEST(ImuTkTest, CrlfAndBlankLines) {
  absl::StatusOr<core::Capture> c =
      ParseImuTkPair("0 0 0 9.8\r\n\r\n0.01 0 0 9.8\r\n", "a", "0 0 0 0\n0.01 0 0 0", "g", {});
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->size(), 2u);
}

}  // namespace
}  // namespace imucal::importers
