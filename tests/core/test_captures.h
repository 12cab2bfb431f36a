// Captures for tests: one whose values have awkward text forms, and a bit-exact comparison.
#ifndef IMUCAL_TESTS_CORE_TEST_CAPTURES_H_
#define IMUCAL_TESTS_CORE_TEST_CAPTURES_H_

#include <cmath>
#include <cstring>
#include <numbers>
#include <vector>

#include "core/capture.h"
#include "gtest/gtest.h"

namespace imucal::core::test_captures {

inline bool SameBits(double a, double b) { return std::memcmp(&a, &b, sizeof(double)) == 0; }

// Values whose text form is awkward: non-terminating binary fractions, extremes of the exponent
// range, subnormals, negative zero, integers above 2^53 precision.
inline core::Capture AwkwardCapture() {
  core::Capture c;
  c.device = "robot 0042 (bench)";
  c.accel_unit = core::AccelUnit::kG;
  c.gyro_unit = core::GyroUnit::kDegPerSecond;
  c.temp_unit = core::TempUnit::kCounts;
  c.gravity_m_s2 = 9.80743;
  c.rate_hz = 204.8;
  c.extra_metadata = {{"operator", "ada"}, {"zeta", "last=first"}, {"alpha", ""}};
  const std::vector<double> awkward = {0.1,
                                       1.0 / 3.0,
                                       -0.0,
                                       5e-324,
                                       1.7976931348623157e308,
                                       2e-308,
                                       -1e-300,
                                       1e22,
                                       123456789.123456789,
                                       9007199254740993.0,
                                       32768.0,
                                       -2.5e-7};
  for (size_t i = 0; i < awkward.size(); ++i) {
    c.t_s.push_back(1e9 + 0.001 * static_cast<double>(i) + 1.0 / 7.0);
    c.accel.emplace_back(awkward[i], -awkward[(i + 1) % awkward.size()], std::sqrt(2.0) * i);
    c.gyro.emplace_back(std::numbers::pi * i, -awkward[(i + 5) % awkward.size()], 1e-9 * i);
    c.temp.push_back(24.81 + 0.01 * static_cast<double>(i));
  }
  c.extra_column_names = {"seq", "pressure_pa"};
  c.extra_columns = {{}, {}};
  for (size_t i = 0; i < awkward.size(); ++i) {
    c.extra_columns[0].push_back(static_cast<double>(i));
    c.extra_columns[1].push_back(101325.0 + awkward[(i + 3) % awkward.size()]);
  }
  return c;
}

inline void ExpectSameCapture(const core::Capture& a, const core::Capture& b) {
  EXPECT_EQ(a.device, b.device);
  EXPECT_EQ(a.accel_unit, b.accel_unit);
  EXPECT_EQ(a.gyro_unit, b.gyro_unit);
  EXPECT_EQ(a.temp_unit, b.temp_unit);
  EXPECT_TRUE(SameBits(a.gravity_m_s2, b.gravity_m_s2));
  EXPECT_TRUE(SameBits(a.rate_hz, b.rate_hz));
  EXPECT_EQ(a.extra_metadata, b.extra_metadata);
  EXPECT_EQ(a.extra_column_names, b.extra_column_names);
  ASSERT_EQ(a.size(), b.size());
  ASSERT_EQ(a.temp.size(), b.temp.size());
  ASSERT_EQ(a.extra_columns.size(), b.extra_columns.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_TRUE(SameBits(a.t_s[i], b.t_s[i])) << "t at " << i;
    for (int k = 0; k < 3; ++k) {
      EXPECT_TRUE(SameBits(a.accel[i][k], b.accel[i][k])) << "accel at " << i << "," << k;
      EXPECT_TRUE(SameBits(a.gyro[i][k], b.gyro[i][k])) << "gyro at " << i << "," << k;
    }
    if (a.has_temp()) {
      EXPECT_TRUE(SameBits(a.temp[i], b.temp[i])) << "temp at " << i;
    }
    for (size_t c = 0; c < a.extra_columns.size(); ++c) {
      EXPECT_TRUE(SameBits(a.extra_columns[c][i], b.extra_columns[c][i])) << "extra " << c;
    }
  }
}

}  // namespace imucal::core::test_captures

#endif  // IMUCAL_TESTS_CORE_TEST_CAPTURES_H_
