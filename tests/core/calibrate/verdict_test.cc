#include "core/calibrate/verdict.h"

#include <cmath>
#include <limits>

#include "gtest/gtest.h"

namespace imucal::core {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

TEST(VerdictTest, NamesRoundTripAndUnknownNamesAreRefused) {
  for (Verdict v : {Verdict::kPass, Verdict::kWarn, Verdict::kFail})
    EXPECT_EQ(ParseVerdict(VerdictName(v)), v);
  EXPECT_EQ(VerdictName(Verdict::kPass), "pass");
  EXPECT_FALSE(ParseVerdict("PASS").has_value());
  EXPECT_FALSE(ParseVerdict("").has_value());
}

TEST(VerdictTest, AccelerometerGates) {
  EXPECT_EQ(JudgeVerdict({.accel_rms_m_s2 = 0.019, .move_rms_deg = kNaN}), Verdict::kPass);
  EXPECT_EQ(JudgeVerdict({.accel_rms_m_s2 = 0.021, .move_rms_deg = kNaN}), Verdict::kWarn);
  EXPECT_EQ(JudgeVerdict({.accel_rms_m_s2 = 0.049, .move_rms_deg = kNaN}), Verdict::kWarn);
  EXPECT_EQ(JudgeVerdict({.accel_rms_m_s2 = 0.051, .move_rms_deg = kNaN}), Verdict::kFail);
}

TEST(VerdictTest, MoveGatesApplyOnlyWhenMovesWereFitted) {
  EXPECT_EQ(JudgeVerdict({.accel_rms_m_s2 = 0.001, .move_rms_deg = 0.9}), Verdict::kPass);
  EXPECT_EQ(JudgeVerdict({.accel_rms_m_s2 = 0.001, .move_rms_deg = 1.1}), Verdict::kWarn);
  EXPECT_EQ(JudgeVerdict({.accel_rms_m_s2 = 0.001, .move_rms_deg = 5.1}), Verdict::kFail);
  EXPECT_EQ(JudgeVerdict({.accel_rms_m_s2 = 0.001, .move_rms_deg = kNaN}), Verdict::kPass);
}

TEST(VerdictTest, AnIncompleteModelIsAtBestWarnButCanStillFail) {
  EXPECT_EQ(JudgeVerdict({.accel_rms_m_s2 = 0.001, .move_rms_deg = 0.1, .degraded = true}),
            Verdict::kWarn);
  EXPECT_EQ(JudgeVerdict({.accel_rms_m_s2 = 0.06, .move_rms_deg = 0.1, .degraded = true}),
            Verdict::kFail);
}

}  // namespace
}  // namespace imucal::core
