// The pipeline on a capture without a gyroscope (core::Capture::has_gyro false): the
// accelerometer model alone, no gyro part in the parameter set, and nothing checked with a
// gyroscope it does not have (a six-face pair's turn is "not checked", not failed).
#include <gtest/gtest.h>

#include <cstdint>

#include "Eigen/Core"
#include "core/calibrate/calibrate.h"
#include "core/capture.h"
#include "core/correction.h"
#include "core/params.h"
#include "core/simulator.h"

namespace imucal::core {
namespace {

constexpr double kMg = 1e-3 * kStandardGravity;  // m/s^2

SimResult SixFace(uint64_t seed) {
  SimOptions o;
  o.protocol = SimProtocol::kSixFace;
  o.seed = seed;
  o.extra_poses = 12;
  o.rate_hz = 200;
  o.accel_noise_m_s2 = 2 * kMg;
  absl::StatusOr<SimResult> r = Simulate(o);
  EXPECT_TRUE(r.ok()) << r.status();
  return r.ok() ? *std::move(r) : SimResult();
}

Capture WithoutGyro(Capture c) {
  c.has_gyro = false;
  c.gyro.clear();
  return c;
}

TEST(AccelOnlyCalibrateTest, FitsTheAccelerometerAloneAndHasNoGyroPart) {
  const uint64_t seed = 21;
  const SimResult sim = SixFace(seed);
  CalibrateOptions options;
  options.seed = seed;
  absl::StatusOr<CalibrationReport> rep = Calibrate(WithoutGyro(sim.capture), options);
  ASSERT_TRUE(rep.ok()) << rep.status() << " seed " << seed;
  ASSERT_NE(rep->verdict, Verdict::kRefused) << rep->verdict_reasons.front();
  EXPECT_NE(rep->verdict, Verdict::kFail);
  EXPECT_FALSE(rep->params.has_gyro);
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(rep->params.accel.bias(i), sim.truth.accel.bias(i), 1 * kMg) << "axis " << i;
    EXPECT_NEAR(rep->params.accel.scale(i), sim.truth.accel.scale(i), 5e-4) << "axis " << i;
  }
  EXPECT_TRUE(rep->moves.empty());  // gravity direction after the moves needs the gyroscope
  EXPECT_TRUE(rep->turns.empty());
  EXPECT_FALSE(rep->effect_diagnostics.ran);
}

TEST(AccelOnlyCalibrateTest, SixFacePairsAreNotCheckedNotFailed) {
  const SimResult sim = SixFace(22);
  absl::StatusOr<CalibrationReport> rep = Calibrate(WithoutGyro(sim.capture), CalibrateOptions());
  ASSERT_TRUE(rep.ok()) << rep.status();
  ASSERT_EQ(rep->protocol, ProtocolKind::kSixFace);
  ASSERT_FALSE(rep->pairs.empty());
  for (const PairCheck& pair : rep->pairs) {
    EXPECT_FALSE(pair.turn_checked) << pair.face;
    EXPECT_TRUE(pair.ok) << pair.face << ": " << pair.reason;
  }
}

// On stops reached by tilts (Tedaldi's free protocol: what an accelerometer alone can see; a
// turn about the vertical leaves it unchanged), the accelerometer comes out as it does with
// the gyroscope.
TEST(AccelOnlyCalibrateTest, AgreesWithTheCalibrationThatHadTheGyroscope) {
  SimOptions o;
  o.protocol = SimProtocol::kFree;
  o.free_poses = 30;
  o.seed = 23;
  o.rate_hz = 200;
  o.accel_noise_m_s2 = 2 * kMg;
  absl::StatusOr<SimResult> sim = Simulate(o);
  ASSERT_TRUE(sim.ok()) << sim.status();
  absl::StatusOr<CalibrationReport> with = Calibrate(sim->capture, CalibrateOptions());
  absl::StatusOr<CalibrationReport> without =
      Calibrate(WithoutGyro(sim->capture), CalibrateOptions());
  ASSERT_TRUE(with.ok() && without.ok());
  ASSERT_NE(without->verdict, Verdict::kRefused) << without->verdict_reasons.front();
  EXPECT_TRUE(with->params.has_gyro);
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(without->params.accel.bias(i), with->params.accel.bias(i), 0.5 * kMg);
    EXPECT_NEAR(without->params.accel.scale(i), with->params.accel.scale(i), 3e-4);
  }
}

TEST(AccelOnlyCorrectionTest, LeavesTheGyroAsRead) {
  ParamSet params;
  params.has_gyro = false;
  params.accel.scale = Eigen::Vector3d(2, 2, 2);
  params.gyro.matrix = 3 * Eigen::Matrix3d::Identity();  // present in memory, never applied
  params.gyro.bias = Eigen::Vector3d(1, 1, 1);
  Effect gyro_effect;
  gyro_effect.sensor = Sensor::kGyro;
  gyro_effect.regressor = "temperature";
  gyro_effect.coefficient = 1.0;
  params.effects = {gyro_effect};
  const SampleCorrection correction(params, 0.0);
  EXPECT_FALSE(correction.corrects_gyro());
  const CorrectedSample out =
      correction.Apply(Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(0.1, -0.2, 0.3), 25.0, 0.0);
  EXPECT_EQ(out.gyro_rad_s, Eigen::Vector3d(0.1, -0.2, 0.3));
  EXPECT_EQ(out.accel_m_s2, Eigen::Vector3d(2, 4, 6));
}

}  // namespace
}  // namespace imucal::core
