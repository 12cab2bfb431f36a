// The drift test on synthetic sequences of check rows (made here, not by the fleet simulator):
// a clean sequence raises no more false alarms than its stated rate allows, a step is flagged
// within 3 checks and called a step, a ramp is called a drift, and a change the temperature
// explains is not flagged.
#include "core/health/drift.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "util/units.h"

namespace imucal::core::health {
namespace {

constexpr double kDay = 86400;

struct Sequence {
  int checks = 300;
  double per_day = 1.5;
  double gyro_spread_rad_s = 0.04 * kDegToRad;  // the unit's own power-up spread
  double accel_spread_m_s2 = 2e-3;
  double tilt_spread_rad = 0.01 * kDegToRad;
  // Changes: from check `at` on.
  int at = -1;
  Eigen::Vector3d gyro_step_rad_s = Eigen::Vector3d::Zero();
  double along_ramp_m_s2_per_day = 0;
  // Temperature: uniform in [t_lo, t_hi]; from `at` on in [t_lo + shift, t_hi + shift];
  // the gyro x reads gyro_x_per_c (T - 20).
  double t_lo = 15, t_hi = 25, temp_shift_c = 0, gyro_x_per_c = 0;
};

std::vector<HealthCheck> Make(const Sequence& s, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> n(0, 1);
  std::uniform_real_distribution<double> u(0, 1);
  const Eigen::Vector3d up = Eigen::Vector3d(0.02, -0.01, 1).normalized();
  const Eigen::Vector3d offset = s.gyro_spread_rad_s * Eigen::Vector3d(n(rng), n(rng), n(rng));
  std::vector<HealthCheck> out;
  for (int i = 0; i < s.checks; ++i) {
    HealthCheck h;
    h.t_start_s = 1e9 + i / s.per_day * kDay;
    h.duration_s = 20;
    h.samples = 2000;
    const bool changed = s.at >= 0 && i >= s.at;
    h.temp_mean_c = s.t_lo + (s.t_hi - s.t_lo) * u(rng) + (changed ? s.temp_shift_c : 0);
    double along = s.accel_spread_m_s2 * n(rng);
    if (changed) along += s.along_ramp_m_s2_per_day * (i - s.at + 1) / s.per_day;
    Eigen::Vector3d dir =
        (up + s.tilt_spread_rad * Eigen::Vector3d(n(rng), n(rng), 0)).normalized();
    h.specific_force_m_s2 = dir * (h.gravity_m_s2 + along);
    h.specific_force_se_m_s2 = Eigen::Vector3d::Constant(3e-4);
    h.gravity_dir_body = dir;
    h.gravity_dir_se_rad = 3e-5;
    h.norm_minus_g_m_s2 = along;
    h.gyro_bias_rad_s = offset + s.gyro_spread_rad_s * Eigen::Vector3d(n(rng), n(rng), n(rng));
    h.gyro_bias_rad_s.x() += s.gyro_x_per_c * (h.temp_mean_c - 20);
    if (changed) h.gyro_bias_rad_s += s.gyro_step_rad_s;
    h.gyro_bias_se_rad_s = Eigen::Vector3d::Constant(5e-5);
    out.push_back(h);
  }
  return out;
}

// The drift test after every check as a server runs it; a recalibrate starts a new version.
// Returns the checks that raised an alarm.
std::vector<int> Alarms(const std::vector<HealthCheck>& c, const DriftOptions& o = {}) {
  std::vector<int> alarms;
  DriftReference ref;
  size_t start = 0;
  for (size_t k = 0; k < c.size(); ++k) {
    const std::vector<HealthCheck> rows(c.begin() + static_cast<long>(start),
                                        c.begin() + static_cast<long>(k) + 1);
    if (AssessDrift(rows, ref, o).state != HealthState::kRecalibrate) continue;
    alarms.push_back(static_cast<int>(k));
    start = k + 1;
    if (start < c.size()) ref.activated_s = c[start].t_start_s;
  }
  return alarms;
}

TEST(DriftTest, TheThresholdGivesItsRunLength) {
  const double h = CusumThreshold(1.5, 1e5);
  EXPECT_NEAR(CusumArl0(1.5, h), 1e5, 10.0);
  EXPECT_GT(CusumThreshold(1.5, 1e6), h);
  // Siegmund's approximation overstates the run length at this k (hence the chain).
  EXPECT_GT(SiegmundArl0(1.5, h), 1.05e5);
  // The chain against a direct simulation of N(0,1) increments at a short run length.
  std::mt19937_64 rng(1);
  std::normal_distribution<double> n(0, 1);
  const double h100 = CusumThreshold(1.5, 100);
  double total = 0;
  for (int run = 0; run < 4000; ++run) {
    double s = 0;
    int t = 0;
    do s = std::max(0.0, s + n(rng) - 1.5), ++t;
    while (s < h100);
    total += t;
  }
  EXPECT_NEAR(total / 4000, 100, 6);  // the mean of 4000 run lengths: SE about 1.6
}

TEST(DriftTest, ACleanSequenceRaisesFewFalseAlarms) {
  // 12 units x 300 checks at 1.5 a day = 80 device-months; at the stated 1% per device-month
  // that is 0.8 false alarms expected. More than 4 would be a rate five times the stated one.
  int alarms = 0;
  for (uint64_t seed = 1; seed <= 12; ++seed) {
    const std::vector<int> a = Alarms(Make(Sequence(), seed));
    alarms += static_cast<int>(a.size());
    for (int k : a)
      std::printf("seed %llu: false alarm at check %d\n", (unsigned long long)seed, k);
  }
  EXPECT_LE(alarms, 4);
}

TEST(DriftTest, AGyroStepOfFiveSpreadsIsFlaggedWithinThreeChecksAsAStep) {
  int within3 = 0;
  for (uint64_t seed = 1; seed <= 20; ++seed) {
    Sequence s;
    s.checks = 60;
    s.at = 40;
    s.gyro_step_rad_s = Eigen::Vector3d(0, 0, 5 * s.gyro_spread_rad_s);
    const std::vector<HealthCheck> c = Make(s, seed);
    for (int k = s.at; k < s.at + 3; ++k) {
      const DriftAssessment a = AssessDrift({c.begin(), c.begin() + k + 1}, {});
      if (a.state != HealthState::kRecalibrate) continue;
      ++within3;
      EXPECT_EQ(a.quantities[a.worst].quantity, Quantity::kGyroZ) << a.summary;
      EXPECT_EQ(a.quantities[a.worst].kind, ChangeKind::kStep) << a.summary;
      EXPECT_GE(a.quantities[a.worst].onset_check, s.at - 2) << a.summary;
      EXPECT_NE(a.summary.find("gyro bias z"), std::string::npos) << a.summary;
      break;
    }
  }
  EXPECT_GE(within3, 18);  // 95% of 20 is 19; one more miss allowed for the small sample
}

TEST(DriftTest, ARampIsCalledADrift) {
  Sequence s;
  s.checks = 120;
  s.at = 30;
  s.along_ramp_m_s2_per_day = 2e-4;  // 0.02 mg a day
  const std::vector<HealthCheck> c = Make(s, 5);
  const DriftAssessment a = AssessDrift(c, {});
  ASSERT_EQ(a.state, HealthState::kRecalibrate) << a.summary;
  const QuantityEvidence& e = a.quantities[a.worst];
  EXPECT_EQ(e.quantity, Quantity::kAlongGravity) << a.summary;
  EXPECT_EQ(e.kind, ChangeKind::kDrift) << a.summary;
  EXPECT_NEAR(e.drift_per_day, 2e-4, 1e-4) << a.summary;
  EXPECT_NE(a.summary.find("drifts"), std::string::npos) << a.summary;
}

TEST(DriftTest, AChangeTheTemperatureExplainsIsNotFlagged) {
  Sequence s;
  s.checks = 120;
  s.at = 60;
  s.t_lo = 18;
  s.t_hi = 22;
  s.temp_shift_c = 15;           // a warm season: the checks now span 18-37 degC
  s.gyro_x_per_c = 0.02 * kDegToRad;  // 0.02 deg/s per degC that the stored effect misses
  const std::vector<HealthCheck> c = Make(s, 9);
  const DriftAssessment a = AssessDrift(c, {});
  EXPECT_NE(a.state, HealthState::kRecalibrate) << a.summary;
  EXPECT_EQ(a.quantities[static_cast<int>(Quantity::kGyroX)].kind, ChangeKind::kTemperature)
      << a.summary;
  EXPECT_NEAR(a.quantities[static_cast<int>(Quantity::kGyroX)].temp_coefficient_per_c,
              0.02 * kDegToRad, 0.005 * kDegToRad);
  // A step of that size without the warm season (nor a temperature dependence) is flagged.
  // (A step that comes exactly with a change of season is what the data cannot tell apart.)
  s.gyro_x_per_c = 0;
  s.temp_shift_c = 0;
  s.t_lo = 10;
  s.t_hi = 30;
  s.gyro_step_rad_s = Eigen::Vector3d(0.3 * kDegToRad, 0, 0);
  EXPECT_EQ(AssessDrift(Make(s, 9), {}).state, HealthState::kRecalibrate);
}

TEST(DriftTest, LearningAndDeterminism) {
  const std::vector<HealthCheck> c = Make(Sequence(), 3);
  const DriftAssessment few = AssessDrift({c.begin(), c.begin() + 4}, {});
  EXPECT_EQ(few.state, HealthState::kOk);
  EXPECT_NE(few.summary.find("learning"), std::string::npos) << few.summary;
  // A pure function of the rows, in any order.
  std::vector<HealthCheck> shuffled(c.begin(), c.begin() + 50);
  std::reverse(shuffled.begin(), shuffled.end());
  const DriftAssessment a = AssessDrift({c.begin(), c.begin() + 50}, {});
  const DriftAssessment b = AssessDrift(shuffled, {});
  EXPECT_EQ(a.summary, b.summary);
  EXPECT_EQ(a.quantities[3].cusum, b.quantities[3].cusum);
}

TEST(DriftTest, TheVersionsOwnFiguresAreChecked) {
  std::vector<HealthCheck> c = Make(Sequence(), 4);
  for (HealthCheck& h : c) h.gyro_bias_rad_s.y() += 0.5 * kDegToRad;  // the calibration was off
  DriftReference ref;
  ref.gyro_bias_se_rad_s = Eigen::Vector3d::Constant(0.005 * kDegToRad);
  const DriftAssessment a = AssessDrift({c.begin(), c.begin() + 20}, ref);
  EXPECT_EQ(a.state, HealthState::kWatch) << a.summary;
  EXPECT_TRUE(a.quantities[static_cast<int>(Quantity::kGyroY)].version_disagrees);
}

}  // namespace
}  // namespace imucal::core::health
