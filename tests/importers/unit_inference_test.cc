// Tests of the unit inference (importers/unit_inference.h).
#include "importers/unit_inference.h"

#include <string>
#include <vector>

#include "Eigen/Core"
#include "core/capture.h"
#include "core/simulator.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace imucal::importers {
namespace {

using ::testing::HasSubstr;
using ::testing::StartsWith;

std::vector<Eigen::Vector3d> Poses(double magnitude) {
  // Several faces up, as in a calibration: the per-axis median would be near zero, the median
  // magnitude is not.
  std::vector<Eigen::Vector3d> out;
  for (int i = 0; i < 60; ++i) {
    Eigen::Vector3d axis = Eigen::Vector3d::Zero();
    axis[i % 3] = (i % 2 == 0 ? 1.0 : -1.0) * magnitude;
    out.push_back(axis + Eigen::Vector3d(0.01, -0.02, 0.015) * magnitude);
  }
  return out;
}

TEST(InferUnitTest, Accelerometer) {
  std::string reason;
  EXPECT_EQ(InferAccelUnit(Poses(9.81), core::kStandardGravity, &reason),
            core::AccelUnit::kMetersPerSecond2);
  EXPECT_THAT(reason, StartsWith("accel unit inferred as m/s^2: median |a| 9.7"));
  EXPECT_EQ(InferAccelUnit(Poses(1.02), core::kStandardGravity, &reason), core::AccelUnit::kG);
  EXPECT_THAT(reason, StartsWith("accel unit inferred as g"));
  EXPECT_EQ(InferAccelUnit(Poses(16384), core::kStandardGravity, &reason),
            core::AccelUnit::kCounts);
  EXPECT_THAT(reason, StartsWith("accel unit inferred as counts: median |a| 16"));
  std::vector<Eigen::Vector3d> unsigned_counts(10, Eigen::Vector3d(33108, 33329, 36429));
  EXPECT_EQ(InferAccelUnit(unsigned_counts, core::kStandardGravity, nullptr),
            core::AccelUnit::kCounts);
  // An uncalibrated sensor 8% off still reads as m/s^2.
  EXPECT_EQ(InferAccelUnit(Poses(10.6), core::kStandardGravity, nullptr),
            core::AccelUnit::kMetersPerSecond2);
}

TEST(InferUnitTest, Gyroscope) {
  std::vector<Eigen::Vector3d> still(100, Eigen::Vector3d(0.01, -0.02, 0.003));
  std::vector<Eigen::Vector3d> turning_deg = still;
  for (int i = 0; i < 10; ++i) turning_deg[static_cast<size_t>(i) * 10] = {0, 0, 90};
  std::vector<Eigen::Vector3d> turning_rad = still;
  for (int i = 0; i < 10; ++i) turning_rad[static_cast<size_t>(i) * 10] = {0, 0, 1.6};
  std::vector<Eigen::Vector3d> integers(100, Eigen::Vector3d(3, -2, 0));
  std::vector<Eigen::Vector3d> big(100, Eigen::Vector3d(32786.5, 32429, 32499));

  std::string reason;
  EXPECT_EQ(InferGyroUnit(turning_deg, core::AccelUnit::kMetersPerSecond2, &reason),
            core::GyroUnit::kDegPerSecond);
  EXPECT_THAT(reason, StartsWith("gyro unit inferred as deg/s: 99th-percentile |rate| 90"));
  EXPECT_EQ(InferGyroUnit(turning_rad, core::AccelUnit::kG, &reason),
            core::GyroUnit::kRadPerSecond);
  EXPECT_THAT(reason, HasSubstr("cannot tell deg/s from rad/s"));
  EXPECT_EQ(InferGyroUnit(integers, core::AccelUnit::kCounts, &reason), core::GyroUnit::kCounts);
  EXPECT_THAT(reason, HasSubstr("every gyro value is an integer"));
  EXPECT_EQ(InferGyroUnit(big, core::AccelUnit::kCounts, &reason), core::GyroUnit::kCounts);
  // Integer values alone do not make counts when the accelerometer is in physical units.
  EXPECT_EQ(InferGyroUnit(integers, core::AccelUnit::kMetersPerSecond2, nullptr),
            core::GyroUnit::kRadPerSecond);
}

// A capture in deg/s whose moves are under 1% of its samples (five-minute holds): the rates'
// 99th percentile is a rest's, which read it as rad/s. The moves against the accelerometer's
// turn of gravity say deg/s; the same capture in rad/s stays rad/s.
TEST(InferUnitTest, GyroUnitFromTheMovesWhenTheyAreRare) {
  core::SimOptions o;
  o.seed = 71;
  o.rate_hz = 50;
  o.hold_s = 300;
  o.initial_rest_s = 300;
  for (core::GyroUnit unit : {core::GyroUnit::kDegPerSecond, core::GyroUnit::kRadPerSecond}) {
    o.gyro_unit = unit;
    absl::StatusOr<core::SimResult> sim = core::Simulate(o);
    ASSERT_TRUE(sim.ok()) << sim.status();
    core::Capture c = sim->capture;
    std::string rare_rule;
    EXPECT_EQ(InferGyroUnit(c.gyro, core::AccelUnit::kMetersPerSecond2, &rare_rule),
              core::GyroUnit::kRadPerSecond)
        << "the rates' size alone should miss it here: " << rare_rule;
    std::vector<std::string> notes;
    ApplyOrInferUnits(ImportOptions{}, &c, &notes);
    EXPECT_EQ(c.gyro_unit, unit) << notes.back();
    EXPECT_EQ(c.gyro_unit_source, "inferred");
    EXPECT_EQ(c.accel_unit_source, "inferred");
    EXPECT_THAT(notes.back(), HasSubstr("moves between rests")) << notes.back();
  }
  // Declared units are kept, and said to be.
  core::Capture c = core::Simulate(o)->capture;
  ImportOptions declared;
  declared.gyro_unit = core::GyroUnit::kDegPerSecond;
  ApplyOrInferUnits(declared, &c, nullptr);
  EXPECT_EQ(c.gyro_unit, core::GyroUnit::kDegPerSecond);
  EXPECT_EQ(c.gyro_unit_source, "declared");
}

}  // namespace
}  // namespace imucal::importers
