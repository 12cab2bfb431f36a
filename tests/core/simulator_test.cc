#include "core/simulator.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <functional>
#include <numbers>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/status.h"
#include "core/capture.h"
#include "core/model.h"
#include "core/regressor.h"

namespace imucal::core {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kRadToDeg = 180.0 / kPi;

SimOptions MakeOptions(SimProtocol protocol, uint64_t seed) {
  SimOptions options;
  options.protocol = protocol;
  options.seed = seed;
  return options;
}

SimResult MustSimulate(const SimOptions& options) {
  absl::StatusOr<SimResult> result = Simulate(options);
  EXPECT_TRUE(result.ok()) << result.status();
  if (!result.ok()) return SimResult();
  return *std::move(result);
}

size_t SampleAt(const SimResult& result, double t_s) {
  return static_cast<size_t>(std::lround(t_s * result.capture.rate_hz));
}

// Samples of a hold, leaving 0.1 s at each end.
std::vector<size_t> HoldSamples(const SimResult& result, const SimPose& pose) {
  std::vector<size_t> samples;
  for (size_t k = SampleAt(result, pose.t_start_s + 0.1); k <= SampleAt(result, pose.t_end_s - 0.1);
       ++k) {
    samples.push_back(k);
  }
  return samples;
}

Eigen::Vector3d Mean(const std::vector<Eigen::Vector3d>& values,
                     const std::vector<size_t>& samples) {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (size_t k : samples) sum += values[k];
  return sum / static_cast<double>(samples.size());
}

// Integrates the true body rates from sample `from` to sample `to` (trapezoid steps): the
// rotation R(t_from)^T R(t_to).
Eigen::Matrix3d IntegrateRates(const SimResult& result, size_t from, size_t to) {
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  for (size_t k = from; k < to; ++k) {
    const double dt = result.capture.t_s[k + 1] - result.capture.t_s[k];
    const Eigen::Vector3d w = 0.5 * (result.true_gyro_rad_s[k] + result.true_gyro_rad_s[k + 1]);
    R = R * ExpSo3<double>(w * dt);
  }
  return R;
}

double AngleBetween(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return Eigen::AngleAxisd(a.transpose() * b).angle();
}

// --- Regressor -------------------------------------------------------------------------------

TEST(RegressorTest, ParsesAndGivesCanonicalName) {
  struct Case {
    const char* text;
    const char* name;
    int num_factors;
  };
  for (const Case& c :
       {Case{"ax*az", "ax*az", 2}, Case{"az*ax", "ax*az", 2},
        Case{"temperature^2", "temperature^2", 2},
        Case{"temperature*temperature", "temperature^2", 2}, Case{"time", "time", 1},
        Case{"gz", "gz", 1}, Case{"ax*temperature*ax", "temperature*ax^2", 3},
        Case{"ax^2*az^2", "ax^2*az^2", 4}, Case{" ax * az ", "ax*az", 2},
        Case{"gx*gy*gz", "gx*gy*gz", 3}, Case{"ax^2*ax", "ax^2*ax", 3}}) {
    SCOPED_TRACE(c.text);
    const std::optional<Regressor> regressor = ParseRegressor(c.text);
    ASSERT_TRUE(regressor.has_value());
    EXPECT_EQ(regressor->num_factors, c.num_factors);
    EXPECT_EQ(regressor->Name(), c.name);
    EXPECT_EQ(ParseRegressor(regressor->Name()), regressor);  // round trip
  }
  EXPECT_EQ(ParseRegressor("ax*az"), ParseRegressor("az*ax"));
  EXPECT_NE(ParseRegressor("ax*az"), ParseRegressor("ax*ay"));
}

TEST(RegressorTest, RejectsMalformedNames) {
  for (const char* text :
       {"foo", "ax**az", "", "*", "ax*", "*ax", "ax^3", "ax^2^2", "Ax", "ax^", "temperature2",
        "ax*ay*az*gx*gy", "ax^2*ay^2*az", "ax+az", "1",
        // Centred factors: temperature and time only, a finite number, one
        // reference per signal.
        "(ax-1)", "(temperature)", "(temperature-)", "(temperature-abc)", "(temperature-1x)",
        "temperature-30", "(temperature-nan)", "(temperature-inf)", "temperature*(temperature-30)",
        "(time-1)*(time-2)", "(temperature*30)"}) {
    SCOPED_TRACE(text);
    EXPECT_FALSE(ParseRegressor(text).has_value());
  }
}

TEST(RegressorTest, EvaluatesProductOfSignals) {
  SignalArray signals = {};
  signals[static_cast<int>(Signal::kTemperature)] = 30.0;
  signals[static_cast<int>(Signal::kTime)] = 2.0;
  signals[static_cast<int>(Signal::kAx)] = 1.5;
  signals[static_cast<int>(Signal::kAy)] = -2.0;
  signals[static_cast<int>(Signal::kAz)] = 3.0;
  signals[static_cast<int>(Signal::kGx)] = 4.0;
  signals[static_cast<int>(Signal::kGy)] = 5.0;
  signals[static_cast<int>(Signal::kGz)] = 6.0;
  EXPECT_DOUBLE_EQ(ParseRegressor("ax*az")->Evaluate(signals), 4.5);
  EXPECT_DOUBLE_EQ(ParseRegressor("temperature^2")->Evaluate(signals), 900.0);
  EXPECT_DOUBLE_EQ(ParseRegressor("time")->Evaluate(signals), 2.0);
  EXPECT_DOUBLE_EQ(ParseRegressor("ay")->Evaluate(signals), -2.0);
  EXPECT_DOUBLE_EQ(ParseRegressor("gx*gy*gz")->Evaluate(signals), 120.0);
  EXPECT_DOUBLE_EQ(ParseRegressor("ax^2*az^2")->Evaluate(signals), 20.25);
  EXPECT_DOUBLE_EQ(Regressor().Evaluate(signals), 1.0);
  // Centred factors read the signal minus the reference written in the name.
  EXPECT_DOUBLE_EQ(ParseRegressor("(temperature-31.5)^2")->Evaluate(signals), 2.25);
  EXPECT_DOUBLE_EQ(ParseRegressor("(temperature+5)")->Evaluate(signals), 35.0);
  EXPECT_DOUBLE_EQ(ParseRegressor("(time-0.5)*ax")->Evaluate(signals), 2.25);
  EXPECT_DOUBLE_EQ(ParseRegressor("(temperature-25)*(time-1)")->Evaluate(signals), 5.0);
}

// The magnitude of a sensor signal, `|gx|`: a rate-dependent gyroscope term's factor.
TEST(RegressorTest, AbsoluteValueOfASensorSignal) {
  for (const auto& [text, name] :
       {std::pair{"|gx|*gx", "gx*|gx|"}, std::pair{"gx*|gx|", "gx*|gx|"},
        std::pair{"|gz|", "|gz|"}, std::pair{"|gy|^2", "|gy|^2"},
        std::pair{"|ax|*temperature", "temperature*|ax|"}, std::pair{" |gz| * gx ", "gx*|gz|"}}) {
    SCOPED_TRACE(text);
    const std::optional<Regressor> r = ParseRegressor(text);
    ASSERT_TRUE(r.has_value());
    EXPECT_EQ(r->Name(), name);
    EXPECT_EQ(ParseRegressor(r->Name()), r);
    EXPECT_TRUE(r->HasAbsolute());
  }
  EXPECT_NE(ParseRegressor("gx*|gx|"), ParseRegressor("gx^2"));
  EXPECT_FALSE(ParseRegressor("gx^2")->HasAbsolute());
  for (const char* bad : {"|temperature|", "|time|", "|gx", "gx|", "||", "|gq|", "|(time-3)|"}) {
    SCOPED_TRACE(bad);
    EXPECT_FALSE(ParseRegressor(bad).has_value());
  }
  SignalArray s{};
  s[static_cast<size_t>(Signal::kGx)] = -2.0;
  s[static_cast<size_t>(Signal::kGz)] = 3.0;
  EXPECT_DOUBLE_EQ(ParseRegressor("gx*|gx|")->Evaluate(s), -4.0);
  EXPECT_DOUBLE_EQ(ParseRegressor("|gx|")->Evaluate(s), 2.0);
  EXPECT_DOUBLE_EQ(ParseRegressor("gz*|gx|")->Evaluate(s), 6.0);
}

TEST(RegressorTest, CentredNamesRoundTripExactly) {
  // The reference is written in the shortest form that reads back to the same double, so the
  // SDK evaluates exactly what the search fitted, whatever the reference.
  for (double centre : {31.2, 31.25, -4.0, 0.1 + 0.2, 1e-7, 123456.789, 29.999999999999996}) {
    Regressor r = *ParseRegressor("temperature^2*ax");
    SignalArray reference{};
    reference[static_cast<int>(Signal::kTemperature)] = centre;
    reference[static_cast<int>(Signal::kTime)] = 7;  // not a factor: not centred
    r = r.CentredOn(reference);
    SCOPED_TRACE(r.Name());
    const std::optional<Regressor> back = ParseRegressor(r.Name());
    ASSERT_TRUE(back.has_value());
    EXPECT_EQ(*back, r);
    EXPECT_EQ(r.centre[static_cast<int>(Signal::kTime)], 0.0);
    EXPECT_EQ(r.centre[static_cast<int>(Signal::kTemperature)], centre);
  }
  EXPECT_EQ(ParseRegressor("(temperature-31.2)^2")->Name(), "(temperature-31.2)^2");
  EXPECT_EQ(ParseRegressor("ax * (time+3)")->Name(), "(time+3)*ax");
  EXPECT_EQ(ParseRegressor("(temperature-0)")->Name(), "temperature");
  // The same form about different references is a different regressor.
  EXPECT_NE(*ParseRegressor("(temperature-30)"), *ParseRegressor("(temperature-31)"));
}

// --- Simulator -------------------------------------------------------------------------------

TEST(SimulatorTest, ProtocolNamesRoundTrip) {
  for (SimProtocol protocol : {SimProtocol::kSixFace, SimProtocol::kPositions24,
                               SimProtocol::kPositions36, SimProtocol::kFree}) {
    absl::StatusOr<SimProtocol> parsed = ParseSimProtocol(ProtocolName(protocol));
    ASSERT_TRUE(parsed.ok()) << parsed.status();
    EXPECT_EQ(*parsed, protocol);
  }
  EXPECT_EQ(ProtocolName(SimProtocol::kSixFace), "six-face");
  EXPECT_EQ(ParseSimProtocol("sixface").status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(SimulatorTest, SameSeedGivesIdenticalCapture) {
  for (bool tremor : {false, true}) {
    SimOptions options = MakeOptions(SimProtocol::kSixFace, 42);
    options.hand_tremor = tremor;
    options.extra_poses = 2;
    const SimResult a = MustSimulate(options);
    const SimResult b = MustSimulate(options);
    ASSERT_GT(a.capture.size(), 0u);
    EXPECT_EQ(a.capture.t_s, b.capture.t_s);
    EXPECT_EQ(a.capture.accel, b.capture.accel);
    EXPECT_EQ(a.capture.gyro, b.capture.gyro);
    EXPECT_EQ(a.capture.temp, b.capture.temp);
    EXPECT_EQ(a.truth.accel.bias, b.truth.accel.bias);
    EXPECT_EQ(a.truth.gyro.matrix, b.truth.gyro.matrix);
  }
}

TEST(SimulatorTest, DifferentSeedGivesDifferentCapture) {
  const SimResult a = MustSimulate(MakeOptions(SimProtocol::kFree, 1));
  const SimResult b = MustSimulate(MakeOptions(SimProtocol::kFree, 2));
  ASSERT_EQ(a.capture.size(), b.capture.size());  // same timing
  EXPECT_NE(a.capture.accel, b.capture.accel);
  EXPECT_NE(a.capture.gyro, b.capture.gyro);
  EXPECT_NE(a.truth.accel.bias, b.truth.accel.bias);
  EXPECT_GT(AngleBetween(a.poses[1].R_world_body, b.poses[1].R_world_body), 1e-3);
}

TEST(SimulatorTest, NoiseLevelDoesNotMovePoses) {
  SimOptions options = MakeOptions(SimProtocol::kPositions24, 7);
  const SimResult a = MustSimulate(options);
  options.accel_noise_m_s2 = 0.0;
  options.gyro_noise_rad_s = 0.0;
  const SimResult b = MustSimulate(options);
  ASSERT_EQ(a.poses.size(), b.poses.size());
  for (size_t i = 0; i < a.poses.size(); ++i) {
    EXPECT_EQ(a.poses[i].R_world_body, b.poses[i].R_world_body) << "pose " << i;
  }
}

TEST(SimulatorTest, PoseCountAndTimingPerProtocol) {
  struct Case {
    SimProtocol protocol;
    int extra;
    size_t poses;
    const char* first_label;
    const char* last_label;
  };
  for (const Case& c : {Case{SimProtocol::kSixFace, 0, 12, "Z+", "X- turned"},
                        Case{SimProtocol::kPositions24, 0, 24, "pos 1", "pos 24"},
                        Case{SimProtocol::kPositions36, 0, 36, "pos 1", "pos 36"},
                        Case{SimProtocol::kFree, 0, 20, "free 1", "free 20"},
                        Case{SimProtocol::kSixFace, 3, 15, "Z+", "extra 3"}}) {
    SimOptions options = MakeOptions(c.protocol, 3);
    options.free_poses = 20;
    options.extra_poses = c.extra;
    SCOPED_TRACE(ProtocolName(c.protocol) + " extra " + std::to_string(c.extra));
    const SimResult result = MustSimulate(options);
    ASSERT_EQ(result.poses.size(), c.poses);
    EXPECT_EQ(result.poses.front().label, c.first_label);
    EXPECT_EQ(result.poses.back().label, c.last_label);
    // The initial rest is the first pose; every later hold follows one move.
    EXPECT_DOUBLE_EQ(result.poses[0].t_start_s, 0.0);
    EXPECT_NEAR(result.poses[0].t_end_s, options.initial_rest_s, 1e-9);
    for (size_t i = 1; i < result.poses.size(); ++i) {
      EXPECT_NEAR(result.poses[i].t_start_s - result.poses[i - 1].t_end_s, options.move_s, 1e-9);
      EXPECT_NEAR(result.poses[i].t_end_s - result.poses[i].t_start_s, options.hold_s, 1e-9);
    }
    const Capture& capture = result.capture;
    EXPECT_TRUE(ValidateCapture(capture).ok()) << ValidateCapture(capture);
    EXPECT_NEAR(capture.t_s.back(), result.poses.back().t_end_s, 1e-6);
    EXPECT_NEAR(capture.MedianDt(), 1.0 / options.rate_hz, 1e-12);
    EXPECT_EQ(result.true_accel_m_s2.size(), capture.size());
    EXPECT_EQ(result.true_gyro_rad_s.size(), capture.size());
    EXPECT_EQ(capture.temp.size(), capture.size());
  }
}

// At every static pose the true specific force has norm g, and the raw readings calibrated
// through the truth give back the true values within the noise, in every unit.
TEST(SimulatorTest, StaticPosesCalibrateBackToTruth) {
  struct Case {
    AccelUnit accel_unit;
    GyroUnit gyro_unit;
    double accel_offset;
    double gyro_offset;
  };
  for (SimProtocol protocol :
       {SimProtocol::kSixFace, SimProtocol::kPositions24, SimProtocol::kFree}) {
    for (const Case& c : {Case{AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond, 0, 0},
                          Case{AccelUnit::kG, GyroUnit::kDegPerSecond, 0, 0},
                          Case{AccelUnit::kCounts, GyroUnit::kCounts, 32768, -100}}) {
      SimOptions options = MakeOptions(protocol, 11);
      options.accel_unit = c.accel_unit;
      options.gyro_unit = c.gyro_unit;
      options.accel_offset_counts = c.accel_offset;
      options.gyro_offset_counts = c.gyro_offset;
      SCOPED_TRACE(ProtocolName(protocol) + " " + std::string(AccelUnitName(c.accel_unit)) +
                   " seed 11");
      const SimResult result = MustSimulate(options);
      ASSERT_FALSE(result.poses.empty());
      Eigen::Vector3d accel_sq = Eigen::Vector3d::Zero();
      Eigen::Vector3d gyro_sq = Eigen::Vector3d::Zero();
      size_t count = 0;
      for (const SimPose& pose : result.poses) {
        SCOPED_TRACE(pose.label);
        const std::vector<size_t> samples = HoldSamples(result, pose);
        ASSERT_GT(samples.size(), 100u);
        const Eigen::Vector3d f_mean = Mean(result.true_accel_m_s2, samples);
        EXPECT_NEAR(f_mean.norm(), options.gravity_m_s2, 1e-9);
        EXPECT_LT(
            (f_mean - pose.R_world_body.transpose() * Eigen::Vector3d(0, 0, options.gravity_m_s2))
                .norm(),
            1e-9);
        Eigen::Vector3d accel_error = Eigen::Vector3d::Zero();
        Eigen::Vector3d gyro_error = Eigen::Vector3d::Zero();
        for (size_t k : samples) {
          const Eigen::Vector3d a = result.truth.accel.Apply(result.capture.accel[k]);
          const Eigen::Vector3d w = result.truth.gyro.Apply(result.capture.gyro[k], a);
          const Eigen::Vector3d da = a - result.true_accel_m_s2[k];
          const Eigen::Vector3d dw = w - result.true_gyro_rad_s[k];
          accel_error += da;
          gyro_error += dw;
          accel_sq += da.cwiseAbs2();
          gyro_sq += dw.cwiseAbs2();
          ++count;
        }
        // Mean over >700 samples of 0.02 m/s^2 (0.002 rad/s) noise: 1e-3 (1e-4) is > 10 sigma.
        EXPECT_LT((accel_error / samples.size()).norm(), 3e-3);
        EXPECT_LT((gyro_error / samples.size()).norm(), 3e-4);
      }
      // The per-axis calibrated noise is the requested one (counts add ~0.0014 m/s^2 of
      // quantisation, in quadrature).
      const Eigen::Vector3d accel_rms = (accel_sq / count).cwiseSqrt();
      const Eigen::Vector3d gyro_rms = (gyro_sq / count).cwiseSqrt();
      for (int i = 0; i < 3; ++i) {
        EXPECT_NEAR(accel_rms(i), options.accel_noise_m_s2, 0.1 * options.accel_noise_m_s2);
        EXPECT_NEAR(gyro_rms(i), options.gyro_noise_rad_s, 0.15 * options.gyro_noise_rad_s);
      }
    }
  }
}

// Integrating the true rates from the start reproduces every pose: the rates and the poses
// describe one motion (with and without hand tremor).
TEST(SimulatorTest, IntegratedRatesReachEveryPose) {
  for (SimProtocol protocol :
       {SimProtocol::kSixFace, SimProtocol::kPositions36, SimProtocol::kFree}) {
    for (bool tremor : {false, true}) {
      SimOptions options = MakeOptions(protocol, 5);
      options.extra_poses = 2;
      options.hand_tremor = tremor;
      SCOPED_TRACE(ProtocolName(protocol) + (tremor ? " tremor" : "") + " seed 5");
      const SimResult result = MustSimulate(options);
      Eigen::Matrix3d R = result.poses[0].R_world_body;
      size_t k = 0;
      for (const SimPose& pose : result.poses) {
        const size_t start = SampleAt(result, pose.t_start_s);
        R = R * IntegrateRates(result, k, start);
        k = start;
        EXPECT_LT(AngleBetween(R, pose.R_world_body), tremor ? 1e-6 : 1e-7) << pose.label;
      }
    }
  }
}

TEST(SimulatorTest, SixFaceFacesMatchLabels) {
  SimOptions options = MakeOptions(SimProtocol::kSixFace, 9);
  options.floor_tilt_deg = 2.0;
  const SimResult result = MustSimulate(options);
  ASSERT_EQ(result.poses.size(), 12u);
  const double g = options.gravity_m_s2;
  const double cos_tilt = std::cos(options.floor_tilt_deg * kPi / 180.0);
  for (size_t i = 0; i < result.poses.size(); ++i) {
    const SimPose& pose = result.poses[i];
    SCOPED_TRACE(pose.label);
    const Eigen::Vector3d f = Mean(result.true_accel_m_s2, HoldSamples(result, pose));
    Eigen::Index axis;
    f.cwiseAbs().maxCoeff(&axis);
    EXPECT_EQ(std::string(1, "XYZ"[axis]), pose.label.substr(0, 1));
    EXPECT_EQ(f(axis) > 0 ? "+" : "-", pose.label.substr(1, 1));
    EXPECT_EQ(pose.label.find("turned") != std::string::npos, i % 2 == 1);
    // The face axis lies along the tilted floor normal: it reads g cos(tilt) exactly.
    EXPECT_NEAR(std::abs(f(axis)), g * cos_tilt, 1e-9);
    if (i % 2 == 1) {  // the turn mirrors the horizontal part: same size, about opposite
      const Eigen::Vector3d before =
          Mean(result.true_accel_m_s2, HoldSamples(result, result.poses[i - 1]));
      Eigen::Vector3d h_before = before, h_after = f;
      h_before(axis) = 0;
      h_after(axis) = 0;
      EXPECT_NEAR(h_before.norm(), h_after.norm(), 1e-9);
      EXPECT_NEAR(h_before.norm(), g * std::sin(options.floor_tilt_deg * kPi / 180.0), 1e-9);
      EXPECT_LT((h_before + h_after).norm(), 0.3 * h_before.norm());  // turn error 3 deg
    }
  }
}

// The gyro integrated over a pair's turn gives 180 degrees plus the turn error, about the face
// axis (the floor normal).
TEST(SimulatorTest, SixFaceTurnIsHalfCircleAboutFloorNormal) {
  for (double turn_error_deg : {0.0, 3.0}) {
    SimOptions options = MakeOptions(SimProtocol::kSixFace, 21);
    options.turn_error_deg = turn_error_deg;
    SCOPED_TRACE("turn error " + std::to_string(turn_error_deg) + " seed 21");
    const SimResult result = MustSimulate(options);
    double largest_error_deg = 0.0;
    for (size_t i = 0; i + 1 < result.poses.size(); i += 2) {
      const SimPose& before = result.poses[i];
      const SimPose& after = result.poses[i + 1];
      SCOPED_TRACE(after.label);
      const size_t from = SampleAt(result, before.t_end_s);
      const size_t to = SampleAt(result, after.t_start_s);
      // Face axis in body coordinates = the floor normal.
      const Eigen::Vector3d axis_body =
          before.R_world_body.transpose() * result.R_world_floor.col(2);
      EXPECT_NEAR(axis_body.cwiseAbs().maxCoeff(), 1.0, 1e-9);
      double angle = 0.0;
      for (size_t k = from; k < to; ++k) {
        const Eigen::Vector3d w = 0.5 * (result.true_gyro_rad_s[k] + result.true_gyro_rad_s[k + 1]);
        angle += w.dot(axis_body) * (result.capture.t_s[k + 1] - result.capture.t_s[k]);
        // The turn is about the floor normal only.
        EXPECT_LT((w - w.dot(axis_body) * axis_body).norm(), 1e-9);
      }
      const double error_deg = angle * kRadToDeg - 180.0;
      EXPECT_LT(std::abs(error_deg), 4.0 * turn_error_deg + 1e-6);
      largest_error_deg = std::max(largest_error_deg, std::abs(error_deg));
      EXPECT_LT(
          AngleBetween(before.R_world_body * IntegrateRates(result, from, to), after.R_world_body),
          1e-7);
    }
    if (turn_error_deg > 0) {
      EXPECT_GT(largest_error_deg, 0.1);
    }
  }
}

TEST(SimulatorTest, PositionsTurnAboutHorizontalBodyAxis) {
  for (auto [protocol, steps] :
       {std::pair{SimProtocol::kPositions24, 8}, std::pair{SimProtocol::kPositions36, 12}}) {
    SimOptions options = MakeOptions(protocol, 13);
    SCOPED_TRACE(ProtocolName(protocol) + " seed 13");
    const SimResult result = MustSimulate(options);
    ASSERT_EQ(result.poses.size(), static_cast<size_t>(3 * steps));
    const double sin_tilt = std::sin(options.floor_tilt_deg * kPi / 180.0);
    for (int group = 0; group < 3; ++group) {
      for (int j = 0; j < steps; ++j) {
        const Eigen::Matrix3d& R = result.poses[group * steps + j].R_world_body;
        // The body axis of the group lies in the (tilted) floor plane.
        EXPECT_LE(std::abs(R.col(group).z()), sin_tilt + 1e-9);
        if (j == 0) continue;
        const Eigen::AngleAxisd step(result.poses[group * steps + j - 1].R_world_body.transpose() *
                                     R);
        EXPECT_NEAR(step.angle(), 2 * kPi / steps, 1e-9);
        EXPECT_NEAR(std::abs(step.axis()(group)), 1.0, 1e-9);
      }
    }
  }
}

TEST(SimulatorTest, CountsAreIntegers) {
  SimOptions options = MakeOptions(SimProtocol::kSixFace, 17);
  options.accel_unit = AccelUnit::kCounts;
  options.gyro_unit = GyroUnit::kCounts;
  options.accel_offset_counts = 32768;
  options.accel_counts_per_g = 4096;
  const SimResult result = MustSimulate(options);
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (size_t k = 0; k < result.capture.size(); ++k) {
    for (int i = 0; i < 3; ++i) {
      ASSERT_EQ(result.capture.accel[k](i), std::round(result.capture.accel[k](i))) << k;
      ASSERT_EQ(result.capture.gyro[k](i), std::round(result.capture.gyro[k](i))) << k;
    }
    sum += result.capture.accel[k];
  }
  // Offset register: readings sit around 32768, within the +-1 g span plus the bias.
  const Eigen::Vector3d mean = sum / result.capture.size();
  EXPECT_LT((mean.array() - 32768.0).abs().maxCoeff(), 4096.0);
  EXPECT_NEAR(result.truth.accel.scale.mean(), options.gravity_m_s2 / 4096.0,
              0.05 * options.gravity_m_s2 / 4096.0);
}

TEST(SimulatorTest, InvalidOptionsNameTheField) {
  struct Case {
    std::function<void(SimOptions&)> change;
    const char* field;
  };
  const std::vector<Case> cases = {
      {[](SimOptions& o) { o.rate_hz = 0; }, "rate_hz"},
      {[](SimOptions& o) { o.rate_hz = 1e9; }, "rate_hz"},
      {[](SimOptions& o) { o.hold_s = -1; }, "hold_s"},
      {[](SimOptions& o) { o.move_s = std::nan(""); }, "move_s"},
      {[](SimOptions& o) { o.initial_rest_s = 0; }, "initial_rest_s"},
      {[](SimOptions& o) { o.extra_poses = -1; }, "extra_poses"},
      {[](SimOptions& o) {
         o.protocol = SimProtocol::kFree;
         o.free_poses = 0;
       },
       "free_poses"},
      {[](SimOptions& o) { o.floor_tilt_deg = 90; }, "floor_tilt_deg"},
      {[](SimOptions& o) { o.turn_error_deg = -1; }, "turn_error_deg"},
      {[](SimOptions& o) { o.accel_noise_m_s2 = -0.1; }, "accel_noise_m_s2"},
      {[](SimOptions& o) { o.gyro_noise_rad_s = INFINITY; }, "gyro_noise_rad_s"},
      {[](SimOptions& o) {
         o.accel_unit = AccelUnit::kCounts;
         o.accel_counts_per_g = 0;
       },
       "accel_counts_per_g"},
      {[](SimOptions& o) {
         o.gyro_unit = GyroUnit::kCounts;
         o.gyro_counts_per_rad_s = -5;
       },
       "gyro_counts_per_rad_s"},
      {[](SimOptions& o) { o.gravity_m_s2 = 0; }, "gravity_m_s2"},
      {[](SimOptions& o) { o.temp_tau_s = 0; }, "temp_tau_s"},
      {[](SimOptions& o) {
         o.effects = {{Sensor::kAccel, 0, "foo", 1e-3}};
       },
       "effects[0].regressor"},
      {[](SimOptions& o) {
         o.effects = {{Sensor::kAccel, 0, "ax", 1e-3}, {Sensor::kGyro, 3, "ax", 1e-3}};
       },
       "effects[1].axis"},
      {[](SimOptions& o) {
         o.effects = {{Sensor::kGyro, 1, "time", NAN}};
       },
       "effects[0].coefficient"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.field);
    SimOptions options = MakeOptions(SimProtocol::kSixFace, 1);
    c.change(options);
    const absl::StatusOr<SimResult> result = Simulate(options);
    EXPECT_EQ(result.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_NE(result.status().message().find(c.field), std::string_view::npos) << result.status();
    EXPECT_EQ(Simulate(options, SimTruth()).status().code(), absl::StatusCode::kInvalidArgument);
  }
  // Counts fields are not checked for units that do not use them.
  SimOptions options = MakeOptions(SimProtocol::kSixFace, 1);
  options.accel_counts_per_g = 0;
  EXPECT_TRUE(Simulate(options).ok());
}

TEST(SimulatorTest, EffectsShowUpInCalibratedReadings) {
  SimOptions options = MakeOptions(SimProtocol::kSixFace, 23);
  options.accel_noise_m_s2 = 0;
  options.gyro_noise_rad_s = 0;
  options.effects = {{Sensor::kAccel, 1, "temperature", 1e-3},
                     {Sensor::kGyro, 2, "ax", 2e-3},
                     {Sensor::kAccel, 0, "az*ax", 1e-4}};
  const SimResult result = MustSimulate(options);
  ASSERT_EQ(result.effects.size(), 3u);
  EXPECT_EQ(result.effects[2].regressor, "ax*az");  // canonical
  double temp_min = 1e9, temp_max = -1e9;
  for (size_t k = 0; k < result.capture.size(); ++k) {
    const Eigen::Vector3d& f = result.true_accel_m_s2[k];
    const Eigen::Vector3d a = result.truth.accel.Apply(result.capture.accel[k]);
    const Eigen::Vector3d w = result.truth.gyro.Apply(result.capture.gyro[k], a);
    const Eigen::Vector3d da = a - f;
    const Eigen::Vector3d dw = w - result.true_gyro_rad_s[k];
    ASSERT_NEAR(da.y(), 1e-3 * result.true_temp_c[k], 1e-9) << k;
    ASSERT_NEAR(da.y(), 1e-3 * result.capture.temp[k], 1e-3 * 0.06) << k;  // 6 sigma of 0.01 C
    ASSERT_NEAR(da.x(), 1e-4 * f.x() * f.z(), 1e-9) << k;
    ASSERT_NEAR(da.z(), 0.0, 1e-9) << k;
    ASSERT_NEAR(dw.z(), 2e-3 * f.x(), 1e-9) << k;
    ASSERT_NEAR(dw.head<2>().norm(), 0.0, 1e-9) << k;
    temp_min = std::min(temp_min, result.true_temp_c[k]);
    temp_max = std::max(temp_max, result.true_temp_c[k]);
  }
  EXPECT_GT(temp_max - temp_min, 3.0);  // the warm-up makes the temperature effect visible
}

TEST(SimulatorTest, TemperatureWarmsUp) {
  SimOptions options = MakeOptions(SimProtocol::kPositions24, 29);
  const SimResult result = MustSimulate(options);
  const double t_end = result.capture.t_s.back();
  EXPECT_NEAR(result.capture.temp.front(), options.temp_start_c, 0.06);
  EXPECT_NEAR(
      result.capture.temp.back(),
      options.temp_start_c + options.temp_rise_c * (1.0 - std::exp(-t_end / options.temp_tau_s)),
      0.06);
  options.temperature = false;
  const SimResult no_temp = MustSimulate(options);
  EXPECT_FALSE(no_temp.capture.has_temp());
  EXPECT_EQ(no_temp.true_temp_c.back(), options.temp_start_c);
}

TEST(SimulatorTest, HandTremorShakesHoldsOnly) {
  SimOptions options = MakeOptions(SimProtocol::kSixFace, 31);
  options.hand_tremor = true;
  options.tremor_rms_deg = 0.2;
  const SimResult result = MustSimulate(options);
  for (const SimPose& pose : result.poses) {
    SCOPED_TRACE(pose.label);
    double rate_sq = 0;
    double max_deviation = 0;
    const std::vector<size_t> samples = HoldSamples(result, pose);
    for (size_t k : samples) {
      rate_sq += result.true_gyro_rad_s[k].squaredNorm();
      const Eigen::Vector3d up_body =
          pose.R_world_body.transpose() * Eigen::Vector3d::UnitZ() * options.gravity_m_s2;
      max_deviation = std::max(max_deviation, (result.true_accel_m_s2[k] - up_body).norm());
    }
    EXPECT_GT(std::sqrt(rate_sq / samples.size()), 1e-3);                  // visibly not still
    EXPECT_LT(max_deviation, options.gravity_m_s2 * 0.2 * 4 * kPi / 180);  // but small
  }
}

}  // namespace
}  // namespace imucal::core
