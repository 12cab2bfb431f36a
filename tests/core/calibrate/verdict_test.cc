#include "core/calibrate/verdict.h"

#include <cmath>
#include <limits>

#include "gtest/gtest.h"

namespace imucal::core {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

VerdictInputs Figures(double accel_rms, double move_rms = kNaN) {
  VerdictInputs in;
  in.accel_rms_m_s2 = accel_rms;
  in.move_rms_deg = move_rms;
  return in;
}

TEST(VerdictTest, NamesRoundTripAndUnknownNamesAreRefused) {
  for (Verdict v : {Verdict::kPass, Verdict::kWarn, Verdict::kFail, Verdict::kRefused})
    EXPECT_EQ(ParseVerdict(VerdictName(v)), v);
  EXPECT_EQ(VerdictName(Verdict::kPass), "pass");
  EXPECT_EQ(VerdictName(Verdict::kRefused), "refused");
  EXPECT_FALSE(ParseVerdict("PASS").has_value());
  EXPECT_FALSE(ParseVerdict("").has_value());
}

TEST(VerdictTest, AccelerometerGates) {
  EXPECT_EQ(JudgeVerdict(Figures(0.019)).verdict, Verdict::kPass);
  EXPECT_EQ(JudgeVerdict(Figures(0.021)).verdict, Verdict::kWarn);
  EXPECT_EQ(JudgeVerdict(Figures(0.049)).verdict, Verdict::kWarn);
  const VerdictResult fail = JudgeVerdict(Figures(0.051));
  EXPECT_EQ(fail.verdict, Verdict::kFail);
  ASSERT_EQ(fail.reasons.size(), 1u);
  EXPECT_NE(fail.reasons[0].find("accelerometer residual"), std::string::npos) << fail.reasons[0];
}

TEST(VerdictTest, MoveGatesApplyOnlyWhenMovesWereFitted) {
  EXPECT_EQ(JudgeVerdict(Figures(0.001, 0.9)).verdict, Verdict::kPass);
  EXPECT_EQ(JudgeVerdict(Figures(0.001, 1.1)).verdict, Verdict::kWarn);
  EXPECT_EQ(JudgeVerdict(Figures(0.001, 5.1)).verdict, Verdict::kFail);
  EXPECT_EQ(JudgeVerdict(Figures(0.001, kNaN)).verdict, Verdict::kPass);
}

// A sound fit predicts held-out poses about as well as its own (1.2-2x); many times worse is a
// fit to its own poses only.
TEST(VerdictTest, HeldOutManyTimesTheInSampleOrFloorFails) {
  VerdictInputs in = Figures(0.35e-3 * 9.80665);  // 0.35 mg
  in.accel_noise_floor_m_s2 = 0.3e-3 * 9.80665;
  in.accel_heldout_rms_m_s2 = 2 * in.accel_rms_m_s2;
  EXPECT_EQ(JudgeVerdict(in).verdict, Verdict::kPass);
  in.accel_heldout_rms_m_s2 = 6 * in.accel_rms_m_s2;
  EXPECT_EQ(JudgeVerdict(in).verdict, Verdict::kFail);
  // The floor, not a lucky in-sample figure, is the scale when it is the larger.
  in.accel_rms_m_s2 = 0.05e-3 * 9.80665;
  in.accel_heldout_rms_m_s2 = 4 * in.accel_noise_floor_m_s2;
  EXPECT_EQ(JudgeVerdict(in).verdict, Verdict::kPass);
  // Above the absolute gate, whatever the ratio.
  in.accel_rms_m_s2 = 0.03;
  in.accel_heldout_rms_m_s2 = 0.06;
  EXPECT_EQ(JudgeVerdict(in).verdict, Verdict::kFail);
}

// Few poses for many parameters inflate every held-out residual by about N / (N - p): 8 poses
// for bias and scale (6) leave k = 4, and a held-out RMS 9 x the in-sample one is then sound.
TEST(VerdictTest, HeldOutGatesAllowForFewPosesPerParameter) {
  VerdictInputs in = Figures(0.74e-3 * 9.80665);
  in.accel_noise_floor_m_s2 = 0.7e-3 * 9.80665;
  in.accel_heldout_rms_m_s2 = 9 * in.accel_rms_m_s2;
  EXPECT_EQ(JudgeVerdict(in).verdict, Verdict::kFail);
  in.accel_heldout_inflation = 4;
  EXPECT_EQ(JudgeVerdict(in).verdict, Verdict::kPass);
  in.accel_heldout_rms_m_s2 = 25 * in.accel_rms_m_s2;
  EXPECT_EQ(JudgeVerdict(in).verdict, Verdict::kFail);
}

TEST(VerdictTest, MoveHeldOutFailsWhenManyTimesInSampleAndAboveADegree) {
  VerdictInputs in = Figures(0.001, 0.3);
  in.move_heldout_rms_deg = 0.9;  // 3x, under a degree
  EXPECT_EQ(JudgeVerdict(in).verdict, Verdict::kPass);
  in.move_heldout_rms_deg = 1.6;  // 5.3x and above a degree
  EXPECT_EQ(JudgeVerdict(in).verdict, Verdict::kFail);
}

TEST(VerdictTest, AParameterTheDataDidNotDetermineFails) {
  VerdictInputs in = Figures(0.001, 0.1);
  in.parameters.push_back({"gyro matrix (y,y)", 0.02, 0.05});
  EXPECT_EQ(JudgeVerdict(in).verdict, Verdict::kPass);
  in.parameters.push_back({"gyro matrix (x,y)", 0.06, 0.05});
  const VerdictResult r = JudgeVerdict(in);
  EXPECT_EQ(r.verdict, Verdict::kFail);
  ASSERT_EQ(r.reasons.size(), 1u);
  EXPECT_NE(r.reasons[0].find("gyro matrix (x,y)"), std::string::npos) << r.reasons[0];
}

TEST(VerdictTest, AnIncompleteModelIsAtBestWarnButCanStillFail) {
  VerdictInputs in = Figures(0.001, 0.1);
  in.incomplete = {"gyroscope: only the bias was calibrated"};
  const VerdictResult warn = JudgeVerdict(in);
  EXPECT_EQ(warn.verdict, Verdict::kWarn);
  EXPECT_EQ(warn.reasons, in.incomplete);
  in.accel_rms_m_s2 = 0.06;
  const VerdictResult fail = JudgeVerdict(in);
  EXPECT_EQ(fail.verdict, Verdict::kFail);
  EXPECT_EQ(fail.reasons.size(), 2u);  // the failed gate first, then what was incomplete
}

}  // namespace
}  // namespace imucal::core
