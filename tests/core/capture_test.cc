// Tests of core/capture.h: unit names and factors, the median interval, validation.
#include "core/capture.h"

#include <cmath>
#include <limits>
#include <numbers>
#include <string>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/core/test_captures.h"

namespace imucal::core {
namespace {

using core::test_captures::AwkwardCapture;
using ::testing::HasSubstr;

TEST(CaptureTest, UnitNamesRoundTrip) {
  for (core::AccelUnit u :
       {core::AccelUnit::kMetersPerSecond2, core::AccelUnit::kG, core::AccelUnit::kCounts}) {
    EXPECT_EQ(*core::ParseAccelUnit(core::AccelUnitName(u)), u);
  }
  for (core::GyroUnit u :
       {core::GyroUnit::kRadPerSecond, core::GyroUnit::kDegPerSecond, core::GyroUnit::kCounts}) {
    EXPECT_EQ(*core::ParseGyroUnit(core::GyroUnitName(u)), u);
  }
  for (core::TempUnit u : {core::TempUnit::kCelsius, core::TempUnit::kCounts}) {
    EXPECT_EQ(*core::ParseTempUnit(core::TempUnitName(u)), u);
  }
  EXPECT_EQ(core::AccelUnitName(core::AccelUnit::kMetersPerSecond2), "m/s^2");
  EXPECT_EQ(core::GyroUnitName(core::GyroUnit::kDegPerSecond), "deg/s");
  EXPECT_EQ(core::TempUnitName(core::TempUnit::kCelsius), "C");
  EXPECT_FALSE(core::ParseAccelUnit("m/s2").ok());
  EXPECT_FALSE(core::ParseGyroUnit("dps").ok());
  EXPECT_FALSE(core::ParseTempUnit("F").ok());
  EXPECT_THAT(std::string(core::ParseAccelUnit("G").status().message()), HasSubstr("'G'"));
}

TEST(CaptureTest, NominalFactors) {
  EXPECT_EQ(core::NominalAccelToSi(core::AccelUnit::kMetersPerSecond2, 9.81), 1.0);
  EXPECT_EQ(core::NominalAccelToSi(core::AccelUnit::kG, 9.81), 9.81);
  EXPECT_TRUE(std::isnan(core::NominalAccelToSi(core::AccelUnit::kCounts, 9.81)));
  EXPECT_EQ(core::NominalGyroToSi(core::GyroUnit::kRadPerSecond), 1.0);
  EXPECT_DOUBLE_EQ(core::NominalGyroToSi(core::GyroUnit::kDegPerSecond) * 180.0, std::numbers::pi);
  EXPECT_TRUE(std::isnan(core::NominalGyroToSi(core::GyroUnit::kCounts)));
}

TEST(CaptureTest, MedianDtIgnoresADroppedSample) {
  core::Capture c;
  EXPECT_EQ(c.MedianDt(), 0.0);
  c.t_s = {0.0};
  EXPECT_EQ(c.MedianDt(), 0.0);
  c.t_s = {0.0, 0.01, 0.02, 0.04, 0.05};
  EXPECT_DOUBLE_EQ(c.MedianDt(), 0.01);
}

TEST(CaptureTest, ValidateNamesTheSampleAtFault) {
  core::Capture c = AwkwardCapture();
  EXPECT_TRUE(core::ValidateCapture(c).ok());

  core::Capture shorter = c;
  shorter.gyro.pop_back();
  EXPECT_THAT(std::string(core::ValidateCapture(shorter).message()), HasSubstr("gyro"));

  core::Capture not_finite = c;
  not_finite.accel[3].y() = std::numeric_limits<double>::infinity();
  EXPECT_THAT(std::string(core::ValidateCapture(not_finite).message()), HasSubstr("sample 3"));

  core::Capture backwards = c;
  backwards.t_s[5] = backwards.t_s[4];
  EXPECT_EQ(core::ValidateCapture(backwards).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(core::ValidateCapture(backwards).message()), HasSubstr("sample 5"));

  core::Capture bad_extra = c;
  bad_extra.extra_columns[1].pop_back();
  EXPECT_THAT(std::string(core::ValidateCapture(bad_extra).message()), HasSubstr("pressure_pa"));

  core::Capture bad_gravity = c;
  bad_gravity.gravity_m_s2 = 0.0;
  EXPECT_FALSE(core::ValidateCapture(bad_gravity).ok());
}

}  // namespace
}  // namespace imucal::core
