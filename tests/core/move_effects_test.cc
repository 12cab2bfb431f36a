// Rate-dependent gyroscope terms found on the rotations between static poses
// (core/move_effects.h): the joint fit recovers a term it is given, the search names a rate-
// dependent scale the simulator puts in (sensor, axis, regressor, within 3 standard errors), the
// parameter set it joins brings a fresh capture's moves down to the truth's floor through the
// SDK, and clean captures stay clean.
#include "core/move_effects.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "core/calibrate/calibrate.h"
#include "core/correction.h"
#include "core/effects/common.h"
#include "core/simulator.h"
#include "tests/core/effect_scenarios.h"

namespace imucal::core {
namespace {

// The bench's rate-dependent scale: gyro z reads 0.1 % more per 100 deg/s of rate.
constexpr double kRateScale = 0.001 / (100 * kDegS);  // per rad/s

// Moves at a hand's pace (1 s each, up to 340 deg/s).
SimOptions RateScenario(uint64_t seed, double coefficient, int axis = 2) {
  const char* names[] = {"gx*|gx|", "gy*|gy|", "gz*|gz|"};
  std::vector<SimEffect> effects;
  if (coefficient != 0) effects.push_back({Sensor::kGyro, axis, names[axis], coefficient});
  return EffectScenario(seed, effects, /*temperature=*/true, /*move_s=*/1.0);
}

CalibrationReport MustCalibrate(const Capture& cap) {
  CalibrateOptions opt;
  opt.use_bsas = false;
  absl::StatusOr<CalibrationReport> r = Calibrate(cap, opt);
  EXPECT_TRUE(r.ok()) << r.status();
  return r.ok() ? *std::move(r) : CalibrationReport();
}

std::string Notes(const CalibrationReport& rep) {
  std::string notes;
  for (const std::string& n : rep.effect_diagnostics.notes) notes += n + "\n";
  return notes;
}

// The dictionary: 12 forms per axis, no duplicates, every name parses back to itself.
TEST(MoveEffectsTest, DictionaryIsCanonical) {
  const std::vector<Regressor> d = MoveDictionary();
  EXPECT_EQ(d.size(), 12u);
  for (size_t i = 0; i < d.size(); ++i) {
    EXPECT_EQ(ParseRegressor(d[i].Name()), d[i]) << d[i].Name();
    for (size_t j = 0; j < i; ++j) EXPECT_NE(d[i], d[j]) << d[i].Name();
  }
}

// Noise-free: given the true form, the joint fit recovers the coefficient and the matrix, and
// the moves close. The simulator adds c |w| w to the TRUE rate and the SDK takes c |v| v off the
// MEASURED one, v = w + c |w| w: the two coefficients differ at second order, by 2 c |w| (0.7 %
// of c at 340 deg/s), hence 1.5 %.
TEST(MoveEffectsTest, JointFitRecoversAGivenTerm) {
  SimOptions o = RateScenario(3, kRateScale);
  o.accel_noise_m_s2 = 0;
  o.gyro_noise_rad_s = 0;
  o.temperature = false;
  const absl::StatusOr<SimResult> sim = Simulate(o);
  ASSERT_TRUE(sim.ok()) << sim.status();
  // Moves between consecutive holds with the true up directions.
  MoveSearchInput in;
  in.t_s = &sim->capture.t_s;
  in.gyro_raw = &sim->capture.gyro;
  in.bias = sim->truth.gyro.bias;
  in.interpolate_bias = false;
  in.matrix = Eigen::Matrix3d::Identity();
  const Capture& cap = sim->capture;
  for (size_t i = 0; i + 1 < sim->poses.size(); ++i) {
    GyroMove m;
    while (m.begin + 1 < cap.size() && cap.t_s[m.begin + 1] <= sim->poses[i].t_end_s) ++m.begin;
    m.end = m.begin;
    while (m.end + 1 < cap.size() && cap.t_s[m.end] < sim->poses[i + 1].t_start_s) ++m.end;
    m.up_before = sim->poses[i].R_world_body.transpose() * Eigen::Vector3d::UnitZ();
    m.up_after = sim->poses[i + 1].R_world_body.transpose() * Eigen::Vector3d::UnitZ();
    in.moves.push_back(m);
  }
  const absl::StatusOr<MoveModelFit> without = FitMoveModel(in, {});
  ASSERT_TRUE(without.ok()) << without.status();
  const absl::StatusOr<MoveModelFit> with =
      FitMoveModel(in, {{2, *ParseRegressor("gz*|gz|"), 0.0}});
  ASSERT_TRUE(with.ok()) << with.status();
  EXPECT_GT(without->RmsMoveError(), 20 * with->RmsMoveError());
  EXPECT_NEAR(with->terms[0].coefficient, kRateScale, 0.015 * kRateScale);
  EXPECT_LT((with->matrix - sim->truth.gyro.matrix).norm(), 1e-4);
  EXPECT_LT(with->RmsMoveError(), 1e-4);
}

// The search on the project's simulator: found as simulated, within 3 standard errors, and the
// fresh capture's moves through the SDK close to the truth's floor.
TEST(MoveEffectsTest, FindsARateDependentScale) {
  int found = 0, within = 0;
  for (uint64_t seed = 1; seed <= 4; ++seed) {
    const double truth = kRateScale;
    const absl::StatusOr<SimResult> sim = Simulate(RateScenario(seed, truth));
    ASSERT_TRUE(sim.ok()) << sim.status();
    const CalibrationReport rep = MustCalibrate(sim->capture);
    const Effect* got = nullptr;
    for (const Effect& e : rep.params.effects)
      if (e.sensor == Sensor::kGyro && e.axis == 2 && SameForm(e.regressor, "gz*|gz|")) got = &e;
    SCOPED_TRACE(absl::StrFormat("seed %d\n%s", seed, Notes(rep)));
    if (got == nullptr) continue;
    ++found;
    within += std::abs(got->coefficient - truth) < 3 * got->std_error;
    // Held out by move, the error falls to within 1.4x what the noise alone leaves.
    const MoveEffectDiagnostics& d = rep.effect_diagnostics.move_search;
    EXPECT_LT(d.heldout_after_rad, 0.8 * d.heldout_before_rad);
    EXPECT_LT(d.heldout_after_rad, 1.4 * d.noise_floor_rad);
    absl::StatusOr<SimResult> val = Simulate(RateScenario(seed + 500, truth), sim->truth);
    ASSERT_TRUE(val.ok());
    ParamSet without = rep.params;
    std::erase_if(without.effects, [](const Effect& e) { return e.regressor == "gz*|gz|"; });
    const double before = MoveErrorOn(*val, without), after = MoveErrorOn(*val, rep.params),
                 floor = MoveErrorOn(*val, TruthParams(*val));
    EXPECT_LT(after, 0.6 * before) << before << " -> " << after << " (floor " << floor << ")";
    EXPECT_LT(after, 1.5 * floor + 2e-4) << before << " -> " << after << " (floor " << floor << ")";
  }
  EXPECT_EQ(found, 4);
  EXPECT_GE(within, 3);
}

// A misalignment that grows with the rate (x reads 0.52 % of the z rate per 100 deg/s of it),
// with the scenarios' default 2.5 s moves: found on x as gz*|gz|, within 3 standard errors.
TEST(MoveEffectsTest, FindsAMisalignmentThatGrowsWithTheRate) {
  constexpr double kTruth = 0.003;  // per rad/s
  for (uint64_t seed = 1; seed <= 2; ++seed) {
    const absl::StatusOr<SimResult> sim =
        Simulate(EffectScenario(seed, {{Sensor::kGyro, 0, "gz*|gz|", kTruth}}));
    ASSERT_TRUE(sim.ok()) << sim.status();
    const CalibrationReport rep = MustCalibrate(sim->capture);
    SCOPED_TRACE(absl::StrFormat("seed %d\n%s", seed, Notes(rep)));
    const Effect* got = nullptr;
    int rate_terms = 0;
    for (const Effect& e : rep.params.effects) {
      if (e.sensor != Sensor::kGyro || e.regressor.find('g') == std::string::npos) continue;
      ++rate_terms;
      if (e.axis == 0 && e.regressor == "gz*|gz|") got = &e;
    }
    ASSERT_NE(got, nullptr);
    EXPECT_EQ(rate_terms, 1);
    EXPECT_LT(std::abs(got->coefficient - kTruth), 3 * got->std_error)
        << got->coefficient << " +- " << got->std_error;
  }
}

// Clean captures: nothing found on the moves.
TEST(MoveEffectsTest, CleanCapturesStayClean) {
  int alarms = 0;
  std::string which;
  for (uint64_t seed = 1; seed <= 6; ++seed) {
    const absl::StatusOr<SimResult> sim = Simulate(RateScenario(seed + 1000, 0));
    ASSERT_TRUE(sim.ok()) << sim.status();
    const CalibrationReport rep = MustCalibrate(sim->capture);
    EXPECT_TRUE(rep.effect_diagnostics.move_search.ran);
    for (const Effect& e : rep.params.effects)
      if (e.sensor == Sensor::kGyro && e.regressor.find('g') != std::string::npos)
        ++alarms, which += e.regressor + " ";
  }
  EXPECT_EQ(alarms, 0) << which;
}

// The detection thresholds take Boost.Math's distributions at the edges of their domains (a power
// of 1 or 0, a threshold no noncentrality reaches, a family alpha of 0): each gives infinity
// ("nothing is detectable") or a number, never an exception that would end a server's process.
TEST(MoveEffectsTest, DetectionThresholdsAtTheEdgesOfTheirDomainsAreNumbersNotExceptions) {
  for (double power : {0.0, 1.0, 0.9}) {
    for (double threshold : {1e-300, 3.84, 1e3}) {
      double lambda = 0;
      EXPECT_NO_THROW(lambda = DetectableNoncentrality(1, threshold, power))
          << "power " << power << " threshold " << threshold;
      EXPECT_FALSE(std::isnan(lambda)) << "power " << power << " threshold " << threshold;
    }
  }
  EXPECT_GT(DetectableNoncentrality(1, 3.84), 5.0);  // about 10.5 for 90% power at 5%
  double f = 0;
  EXPECT_NO_THROW(f = effects::FThreshold(0.0, 1, 10));
  EXPECT_FALSE(std::isnan(f));
  EXPECT_NO_THROW(f = effects::FThreshold(1e-320, 1000, 1));
  EXPECT_FALSE(std::isnan(f));
}

}  // namespace
}  // namespace imucal::core
