// The fleet reference: siblings' spread, a far calibration's reason, units walking away; and the
// fleet simulator's rests pass the health check (the benchmark's premise).
#include "core/health/fleet.h"

#include <gtest/gtest.h>

#include <random>
#include <vector>

#include "core/health/drift.h"
#include "core/health/fleet_sim.h"
#include "util/units.h"

namespace imucal::core::health {
namespace {

std::vector<ParamSet> Siblings(int n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> z(0, 1);
  std::vector<ParamSet> out;
  for (int i = 0; i < n; ++i) {
    ParamSet p;
    p.device = "robot-" + std::to_string(i);
    for (int k = 0; k < 3; ++k) {
      p.accel.bias(k) = 0.05 * z(rng);
      p.accel.scale(k) = 1 + 4e-4 * z(rng);
      p.accel.tri_angles(k) = 1e-3 * z(rng);
      p.gyro.bias(k) = 0.01 * z(rng);
      p.gyro.matrix(k, k) = 1 + 1e-3 * z(rng);
    }
    p.stderrs.accel.scale = Eigen::Vector3d::Constant(5e-5);
    out.push_back(p);
  }
  return out;
}

TEST(FleetTest, AFarCalibrationGetsAReasonANormalOneDoesNot) {
  const std::vector<ParamSet> fleet = Siblings(48, 1);
  const absl::StatusOr<FleetReference> ref = BuildFleetReference("mpu6050", fleet);
  ASSERT_TRUE(ref.ok()) << ref.status();
  EXPECT_EQ(ref->siblings, 48);
  EXPECT_NEAR(ref->mad(3), 4e-4, 1.5e-4);  // accel scale x: the fleet's spread
  ParamSet normal = Siblings(1, 99).front();
  EXPECT_FALSE(DistanceToFleet(*ref, normal).far);
  ParamSet odd = normal;
  odd.accel.scale.x() = ref->median(3) + 7.2 * ref->mad(3);
  const FleetDistance d = DistanceToFleet(*ref, odd);
  EXPECT_TRUE(d.far);
  EXPECT_EQ(ref->names[d.worst], "accel scale x");
  EXPECT_NE(d.reason.find("accel scale x is 7.2 MADs from 48 siblings"), std::string::npos)
      << d.reason;
}

TEST(FleetTest, TooFewSiblingsOrMixedUnitsAreRefused) {
  EXPECT_EQ(BuildFleetReference("x", Siblings(3, 1)).status().code(),
            absl::StatusCode::kFailedPrecondition);
  std::vector<ParamSet> mixed = Siblings(10, 2);
  mixed[4].accel_unit = AccelUnit::kG;
  EXPECT_EQ(BuildFleetReference("x", mixed).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(FleetTest, AUnitWalkingAwayFromTheFleetIsFlagged) {
  std::mt19937_64 rng(3);
  std::normal_distribution<double> z(0, 1);
  std::vector<UnitChecks> units;
  for (int u = 0; u < 20; ++u) {
    UnitChecks uc;
    uc.device = "robot-" + std::to_string(u);
    for (int i = 0; i < 30; ++i) {
      HealthCheck h;
      h.norm_minus_g_m_s2 = 1e-3 * z(rng);
      h.gyro_bias_rad_s = 0.04 * kDegToRad * Eigen::Vector3d(z(rng), z(rng), z(rng));
      if (u == 7) h.gyro_bias_rad_s.y() += 0.02 * kDegToRad * i;  // walks 0.6 deg/s away
      uc.checks.push_back(h);
    }
    units.push_back(uc);
  }
  const std::vector<WalkingAway> w = UnitsWalkingAway(units);
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0].device, "robot-7");
  EXPECT_EQ(w[0].quantity, "gyro bias y");
  EXPECT_NEAR(FleetGyroSpread(units), 0.04 * kDegToRad, 0.01 * kDegToRad);
}

TEST(FleetSimTest, DockRestsPassTheHealthCheckAndAreDeterministic) {
  FleetSimOptions o;
  o.units = 3;
  o.days = 5;
  o.change = FleetChange::kGyroBiasStep;
  const std::vector<SimUnit> a = SimulateFleet(o), b = SimulateFleet(o);
  ASSERT_EQ(a.size(), 3u);
  EXPECT_EQ(a[1].plan.size(), b[1].plan.size());
  EXPECT_EQ(a[1].change_t_s, b[1].change_t_s);
  const Capture r1 = SimulateDockRest(a[1], 2, o), r2 = SimulateDockRest(b[1], 2, o);
  EXPECT_EQ(r1.accel, r2.accel);
  const absl::StatusOr<HealthCheck> h = ComputeHealthCheck(r1, a[1].params);
  ASSERT_TRUE(h.ok()) << h.status();
  // The dock's gravity is what the check sees, to the dock's jitter and the unit's residuals.
  EXPECT_LT(std::acos(h->gravity_dir_body.dot(a[1].dock_gravity_body.normalized())),
            0.05 * kDegToRad);
  EXPECT_LT(h->gyro_bias_rad_s.cwiseAbs().maxCoeff(), 0.3 * kDegToRad);
}

TEST(FleetSimTest, AMountingStepOfASimulatedUnitIsFlaggedWithinThreeChecks) {
  FleetSimOptions o;
  o.units = 2;
  o.days = 40;
  o.change = FleetChange::kMountingStep;
  o.change_start_min_d = o.change_start_max_d = 30;
  for (const SimUnit& u : SimulateFleet(o)) {
    std::vector<HealthCheck> checks;
    int flagged_at = -1;
    for (int c = 0; c < static_cast<int>(u.plan.size()) && flagged_at < 0; ++c) {
      const absl::StatusOr<HealthCheck> h = ComputeHealthCheck(SimulateDockRest(u, c, o), u.params);
      ASSERT_TRUE(h.ok()) << h.status();
      checks.push_back(*h);
      const DriftAssessment a = AssessDrift(checks, ReferenceFromParams(u.params, 0));
      if (a.state == HealthState::kRecalibrate) {
        flagged_at = c;
        EXPECT_NE(a.summary.find("gravity direction"), std::string::npos) << a.summary;
      }
    }
    ASSERT_GE(u.first_changed, 0);
    EXPECT_GE(flagged_at, u.first_changed) << u.device;
    EXPECT_LT(flagged_at, u.first_changed + 3) << u.device;
  }
}

TEST(FleetSimTest, AnAccelerometerOnlyRestIsChecked) {
  FleetSimOptions o;
  o.units = 1;
  o.days = 8;
  const std::vector<SimUnit> units = SimulateFleet(o);
  ParamSet p = units[0].params;
  p.has_gyro = false;
  std::vector<HealthCheck> checks;
  for (int c = 0; c < static_cast<int>(units[0].plan.size()); ++c) {
    Capture r = SimulateDockRest(units[0], c, o);
    r.has_gyro = false;
    r.gyro.clear();
    const absl::StatusOr<HealthCheck> h = ComputeHealthCheck(r, p);
    ASSERT_TRUE(h.ok()) << h.status();
    EXPECT_FALSE(h->has_gyro);
    checks.push_back(*h);
  }
  const DriftAssessment a = AssessDrift(checks, {});
  EXPECT_EQ(a.state, HealthState::kOk) << a.summary;
  EXPECT_FALSE(a.quantities[static_cast<int>(Quantity::kGyroX)].tested);
  EXPECT_TRUE(a.quantities[static_cast<int>(Quantity::kTiltA)].tested);
}

}  // namespace
}  // namespace imucal::core::health
