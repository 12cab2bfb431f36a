// Closing the loop on simulated captures whose effect the solver is not told about: the search
// (core/effects.h) must name the right sensor, axis and regressor, estimate the coefficient
// within 3 standard errors of the truth, and bring the error of a fresh validation capture down
// to its noise floor; clean captures must stay clean.
#include "core/effects.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "client/sdk/corrector.h"
#include "core/calibrate.h"
#include "core/simulator.h"
#include "tests/core/effect_scenarios.h"

namespace imucal::core {
namespace {

SimResult MustSimulate(const SimOptions& o) {
  absl::StatusOr<SimResult> r = Simulate(o);
  EXPECT_TRUE(r.ok()) << r.status();
  return r.ok() ? *std::move(r) : SimResult();
}

CalibrationReport MustCalibrate(const Capture& cap, bool apply_time_effects = false) {
  CalibrateOptions opt;
  opt.use_bsas = false;
  opt.effects.apply_time_effects = apply_time_effects;
  absl::StatusOr<CalibrationReport> r = Calibrate(cap, opt);
  EXPECT_TRUE(r.ok()) << r.status();
  return r.ok() ? *std::move(r) : CalibrationReport();
}

const Effect* FindEffect(const ParamSet& p, const SimEffect& want) {
  for (const Effect& e : p.effects)
    if (e.sensor == want.sensor && e.axis == want.axis && e.regressor == want.regressor) return &e;
  return nullptr;
}

std::string List(const ParamSet& p) {
  std::string s;
  for (const Effect& e : p.effects)
    s += absl::StrFormat("[%s %c %s %.4g+-%.2g] ", e.sensor == Sensor::kAccel ? "accel" : "gyro",
                         "xyz"[e.axis], e.regressor, e.coefficient, e.std_error);
  return s.empty() ? "none" : s;
}

class UndeclaredEffect : public testing::TestWithParam<std::tuple<EffectCase, int>> {};

TEST_P(UndeclaredEffect, FoundWithinThreeSigmaAndValidationDropsToNoiseFloor) {
  const auto& [c, seed] = GetParam();
  const SimResult sim = MustSimulate(EffectScenario(static_cast<uint64_t>(seed), c.effects));
  // Time effects are applied only when the user opts in: opt in to validate them.
  bool time = false;
  for (const SimEffect& e : c.effects) time |= e.regressor.find("time") != std::string::npos;
  const CalibrationReport rep = MustCalibrate(sim.capture, time);
  std::string notes;
  for (const std::string& n : rep.effect_diagnostics.notes) notes += n + "\n";
  SCOPED_TRACE(List(rep.params) + "\n" + notes);
  if (!c.axis_identifiable) {
    ASSERT_FALSE(rep.params.effects.empty());
    for (const Effect& e : rep.params.effects) {
      EXPECT_EQ(e.sensor, Sensor::kAccel);
      EXPECT_EQ(ParseRegressor(e.regressor)->num_factors, 2) << e.regressor;
    }
    EXPECT_TRUE(FindEffect(rep.params, c.effects[0]) != nullptr ||
                notes.find("ambiguous") != std::string::npos);
  }
  // Exactly the simulated effects, each within 3 standard errors.
  if (c.axis_identifiable) {
    EXPECT_EQ(rep.params.effects.size(), c.effects.size());
  }
  for (const SimEffect& want : c.axis_identifiable ? c.effects : std::vector<SimEffect>{}) {
    const Effect* got = FindEffect(rep.params, want);
    ASSERT_NE(got, nullptr) << "missing " << want.regressor;
    EXPECT_LT(std::abs(got->coefficient - want.coefficient), 3 * got->std_error)
        << want.regressor << " truth " << want.coefficient;
    EXPECT_LT(got->error_after, got->error_before);
  }
  // A fresh capture of the same unit (new poses and noise, same warm-up).
  SimOptions v = EffectScenario(static_cast<uint64_t>(seed) + 500, c.effects);
  absl::StatusOr<SimResult> val_or = Simulate(v, sim.truth);
  ASSERT_TRUE(val_or.ok()) << val_or.status();
  const SimResult& val = *val_or;
  ParamSet without = rep.params;
  without.effects.clear();
  const HoldError before = ErrorOn(val, without);
  const HoldError after = ErrorOn(val, rep.params);
  const HoldError floor = ErrorOn(val, TruthParams(val));
  SCOPED_TRACE(absl::StrFormat("accel before %.3f after %.3f floor %.3f mg; gyro before %.4f after "
                               "%.4f floor %.4f deg/s",
                               before.accel_m_s2 / kMg, after.accel_m_s2 / kMg,
                               floor.accel_m_s2 / kMg, before.gyro_rad_s / kDegS,
                               after.gyro_rad_s / kDegS, floor.gyro_rad_s / kDegS));
  // Near the floor: within the floor plus the calibration's own parameter error (0.3 mg, 0.005
  // deg/s), and no worse than without the effects.
  EXPECT_LT(after.accel_m_s2, floor.accel_m_s2 + 0.3 * kMg);
  EXPECT_LT(after.gyro_rad_s, floor.gyro_rad_s + 0.005 * kDegS);
  EXPECT_LE(after.accel_m_s2, before.accel_m_s2 * 1.05);
  EXPECT_LE(after.gyro_rad_s, before.gyro_rad_s * 1.05);
}

INSTANTIATE_TEST_SUITE_P(Effects, UndeclaredEffect,
                         testing::Combine(testing::ValuesIn(kEffectCases), testing::Range(1, 4)),
                         [](const auto& param_info) {
                           return std::get<0>(param_info.param).name + "_seed" +
                                  std::to_string(std::get<1>(param_info.param));
                         });

// Clean captures, with and without a temperature channel: nothing added.
class CleanCapture : public testing::TestWithParam<std::tuple<bool, int>> {};

TEST_P(CleanCapture, AddsNoEffect) {
  const auto& [temperature, seed] = GetParam();
  const SimResult sim = MustSimulate(EffectScenario(static_cast<uint64_t>(seed), {}, temperature));
  const CalibrationReport rep = MustCalibrate(sim.capture);
  EXPECT_TRUE(rep.effect_diagnostics.ran);
  EXPECT_GT(rep.effect_diagnostics.candidates, temperature ? 100 : 50);
  EXPECT_TRUE(rep.params.effects.empty()) << List(rep.params);
}

INSTANTIATE_TEST_SUITE_P(Effects, CleanCapture,
                         testing::Combine(testing::Bool(), testing::Range(1, 6)),
                         [](const auto& param_info) {
                           return absl::StrFormat("%s_seed%d",
                                                  std::get<0>(param_info.param) ? "Temp" : "NoTemp",
                                                  std::get<1>(param_info.param));
                         });

TEST(HumanCoefficient, UsesEngineeringUnits) {
  Effect e;
  e.sensor = Sensor::kAccel;
  e.regressor = "temperature";
  e.coefficient = 0.5 * kMg;
  e.std_error = 0.01 * kMg;
  EXPECT_EQ(HumanCoefficient(e), "0.5 +- 0.01 mg/degC");
  e.regressor = "temperature*ay";
  e.coefficient = 2e-4;
  e.std_error = 1e-5;
  EXPECT_EQ(HumanCoefficient(e), "200 +- 10 ppm/degC");
  e.sensor = Sensor::kGyro;
  e.regressor = "ax";
  e.coefficient = 0.05 * kDegS / kStandardGravity;
  e.std_error = 0.002 * kDegS / kStandardGravity;
  EXPECT_EQ(HumanCoefficient(e), "0.05 +- 0.002 deg/s/g");
}

}  // namespace
}  // namespace imucal::core
