// Property tests of the whole pipeline on simulated captures with known truth: calibrate, then
// apply the result to a fresh noise-free capture of the same unit (the acceptance
// figures: accel within 0.3 mg RMS after the best-fit rotation, static rate under 0.02 deg/s).
#include "core/calibrate/calibrate.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "core/accel_solver.h"
#include "core/calibrate/static_poses.h"
#include "core/capture.h"
#include "core/protocol.h"
#include "core/quantisation.h"
#include "core/simulator.h"
#include "core/validation.h"

namespace imucal::core {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kRadToDeg = 180.0 / kPi;
constexpr double kMg = 1e-3 * kStandardGravity;  // m/s^2
constexpr double kAccelTolerance = 0.3 * kMg;    // the figure
constexpr double kStaticRateToleranceDegS = 0.02;

// The scenario: six-face + 24 extra poses at 200 Hz, 2 mg accel noise.
SimOptions Scenario(uint64_t seed) {
  SimOptions o;
  o.protocol = SimProtocol::kSixFace;
  o.seed = seed;
  o.extra_poses = 24;
  o.rate_hz = 200;
  o.accel_noise_m_s2 = 2 * kMg;
  return o;
}

SimResult MustSimulate(const SimOptions& options) {
  absl::StatusOr<SimResult> r = Simulate(options);
  EXPECT_TRUE(r.ok()) << r.status();
  return r.ok() ? *std::move(r) : SimResult();
}

// A fresh noise-free capture of the same unit: same truth, new random poses.
SimResult ValidationCapture(const SimOptions& options, const SimTruth& truth) {
  SimOptions v = options;
  v.seed = options.seed + 1000;
  v.protocol = SimProtocol::kFree;
  v.free_poses = 20;
  v.extra_poses = 0;
  v.accel_noise_m_s2 = 0;
  v.gyro_noise_rad_s = 0;
  absl::StatusOr<SimResult> r = Simulate(v, truth);
  EXPECT_TRUE(r.ok()) << r.status();
  return r.ok() ? *std::move(r) : SimResult();
}

struct Errors {
  double accel_rms_m_s2 = 0;         // after the best-fit rotation
  double static_rate_max_deg_s = 0;  // largest |calibrated rate| over the static samples
};

// Applies `params` to the validation capture's raw readings. For counts, the raw readings are
// recomputed from the truth without the rounding to integers: a noise-free capture rounded to
// whole counts carries up to half a count of error per sample (0.24 mg, 0.03 deg/s here) that
// no calibration can remove and that is not calibration error.
Errors Validate(const ParamSet& params, const SimResult& val) {
  std::vector<Eigen::Vector3d> raw_accel = val.capture.accel, raw_gyro = val.capture.gyro;
  for (size_t k = 0; k < val.capture.size(); ++k) {
    if (val.capture.accel_unit == AccelUnit::kCounts)
      raw_accel[k] = val.truth.accel.Invert(val.true_accel_m_s2[k]);
    if (val.capture.gyro_unit == GyroUnit::kCounts)
      raw_gyro[k] = val.truth.gyro.Invert(val.true_gyro_rad_s[k], val.true_accel_m_s2[k]);
  }
  Errors e;
  std::vector<Eigen::Vector3d> accel;
  for (const Eigen::Vector3d& u : raw_accel) accel.push_back(params.accel.Apply(u));
  e.accel_rms_m_s2 = VectorRmsError(accel, val.true_accel_m_s2, /*align=*/true);
  for (const SimPose& pose : val.poses) {
    for (size_t k = 0; k < val.capture.size(); ++k) {
      const double t = val.capture.t_s[k];
      if (t < pose.t_start_s || t > pose.t_end_s) continue;
      const Eigen::Vector3d w = params.gyro.Apply(raw_gyro[k], accel[k]);
      e.static_rate_max_deg_s = std::max(e.static_rate_max_deg_s, w.norm() * kRadToDeg);
    }
  }
  return e;
}

CalibrationReport MustCalibrate(const Capture& capture, const CalibrateOptions& options = {}) {
  absl::StatusOr<CalibrationReport> r = Calibrate(capture, options);
  EXPECT_TRUE(r.ok()) << r.status();
  return r.ok() ? *std::move(r) : CalibrationReport();
}

std::string Summary(const CalibrationReport& r) {
  std::string out = absl::StrFormat(
      "protocol %s (detected %d), multiplier %g, verdict %s, accel rms %.3g max %.3g heldout %.3g "
      "m/s^2, move rms %.3g deg\n",
      ProtocolKindName(r.protocol), r.protocol_detected, r.threshold_multiplier,
      VerdictName(r.verdict), r.residual.accel_rms_m_s2, r.residual.accel_max_m_s2,
      r.residual.accel_heldout_rms_m_s2, r.residual.move_rms_deg);
  for (const StageReport& s : r.stages)
    out += absl::StrFormat("  stage %s rms %.3g\n", s.name, s.accel_rms_m_s2);
  for (const PairCheck& p : r.pairs)
    out += absl::StrFormat("  pair %d-%d %s ok=%d rot %.1f: %s\n", p.pose_a, p.pose_b, p.face, p.ok,
                           p.rotation_deg, p.reason);
  for (const std::string& w : r.warnings) out += "  warning: " + w + "\n";
  return out;
}

int UsedPoses(const CalibrationReport& r) {
  int n = 0;
  for (const PoseReport& p : r.poses) n += p.interval.used;
  return n;
}

void ExpectSixOkPairsOnePerFace(const CalibrationReport& r) {
  int ok_pairs = 0;
  std::vector<std::string> faces;
  for (const PairCheck& p : r.pairs) {
    if (!p.ok) continue;
    ++ok_pairs;
    faces.push_back(p.face);
  }
  EXPECT_EQ(ok_pairs, 6);
  std::sort(faces.begin(), faces.end());
  EXPECT_EQ(absl::StrJoin(faces, " "), "X+ X- Y+ Y- Z+ Z-");
}

// ---------------------------------------------------------------------------------------------
// The acceptance property, one ctest entry per seed (ctest -j2 spreads them over both cores).

class CalibrateSeedTest : public testing::TestWithParam<uint64_t> {};

TEST_P(CalibrateSeedTest, SixFacePlusExtraMeetsTheAccuracyFigures) {
  const uint64_t seed = GetParam();
  SCOPED_TRACE(absl::StrFormat("simulation seed %d", seed));
  const SimOptions options = Scenario(seed);
  const SimResult sim = MustSimulate(options);
  const CalibrationReport report = MustCalibrate(sim.capture);
  SCOPED_TRACE(Summary(report));

  const Errors e = Validate(report.params, ValidationCapture(options, sim.truth));
  std::printf("seed %llu: accel %.4f mg after best-fit rotation, static rate %.5f deg/s\n",
              static_cast<unsigned long long>(seed), e.accel_rms_m_s2 / kMg,
              e.static_rate_max_deg_s);
  EXPECT_LT(e.accel_rms_m_s2, kAccelTolerance) << e.accel_rms_m_s2 / kMg << " mg";
  EXPECT_LT(e.static_rate_max_deg_s, kStaticRateToleranceDegS);

  // Protocol: detected as six-face, with its 6 pairs verified (one per face).
  EXPECT_EQ(ProtocolKindName(report.protocol), "six-face");
  EXPECT_TRUE(report.protocol_detected);
  ExpectSixOkPairsOnePerFace(report);

  // Every simulated hold is found and used; the stages ran in order.
  EXPECT_EQ(UsedPoses(report), static_cast<int>(sim.poses.size()));
  ASSERT_EQ(report.stages.size(), 3u);
  EXPECT_EQ(report.stages[0].name, "ls");
  EXPECT_EQ(report.stages[1].name, "bsas");
  EXPECT_EQ(report.stages[2].name, "lm");
  EXPECT_LE(report.stages[2].accel_rms_m_s2, report.stages[0].accel_rms_m_s2 * (1 + 1e-9));
  EXPECT_TRUE(report.params.gyro_calibrated);
  EXPECT_NE(report.verdict,
            Verdict::kFail);  // "pass" expected: see ExtraPosesAreNotRejectedAsPairs
  EXPECT_EQ(report.params.accel_unit, AccelUnit::kMetersPerSecond2);
  EXPECT_EQ(report.params.gyro_unit, GyroUnit::kRadPerSecond);
}

INSTANTIATE_TEST_SUITE_P(Seeds, CalibrateSeedTest, testing::Values(1, 2, 3, 4, 5, 6, 7, 8, 9, 10),
                         [](const testing::TestParamInfo<uint64_t>& param_info) {
                           return absl::StrFormat("seed%d", param_info.param);
                         });

// A plain six-face capture (12 poses): |a| = g sees the non-orthogonality angles only through
// the floor's tilt, so its "determination" of them is ~100 times weaker than the face
// references' and refining on it alone wandered (an independent writer's capture came out with
// a 1.1 degree angle, 5-10 mg across the axis, verdict pass). The faces' angles enter as priors
// (said in a warning) and dominate, the angles stay within their standard errors of the truth,
// and the calibrated accelerometer is right to the second-order terms that six faces cannot see
// (held at 0; the truth has them).
TEST(CalibrateTest, PlainSixFaceKeepsTheAnglesOfTheFaceReferences) {
  for (uint64_t seed = 1; seed <= 5; ++seed) {
    SCOPED_TRACE(absl::StrFormat("simulation seed %d", seed));
    SimOptions options = Scenario(seed);
    options.extra_poses = 0;
    const SimResult sim = MustSimulate(options);
    const CalibrationReport report = MustCalibrate(sim.capture);
    SCOPED_TRACE(Summary(report));
    int faces = 0;
    for (const std::string& w : report.warnings)
      faces += w.find("the face references measure them") != std::string::npos;
    EXPECT_EQ(faces, 1);
    for (int j = 0; j < 3; ++j) {
      const double se = report.params.stderrs.accel.tri_angles(j);
      ASSERT_TRUE(std::isfinite(se) && se > 0) << se;
      EXPECT_LT(std::abs(report.params.accel.tri_angles(j) - sim.truth.accel.tri_angles(j)),
                4 * se + 1e-4)
          << j;
    }
    const Errors e = Validate(report.params, ValidationCapture(options, sim.truth));
    std::printf("plain six-face seed %llu: accel %.4f mg after best-fit rotation\n",
                static_cast<unsigned long long>(seed), e.accel_rms_m_s2 / kMg);
    EXPECT_LT(e.accel_rms_m_s2, 1.0 * kMg) << e.accel_rms_m_s2 / kMg << " mg";
  }
}

// Regression: CheckSixFacePairs once paired ANY two consecutive placements with the same face
// up, including the random extra poses after the protocol. Two extra poses that happened to
// share a face were "rejected" ("turned 68 degrees instead of 180; place it again"), telling the
// technician to redo a placement that was never meant as a pair, and the rejection degraded a
// perfect calibration's verdict from pass to warn (7 of these 10 seeds at commit 90c36ed).
// Only the protocol's placements are pair candidates, and the verdict stays "pass".
TEST(CalibrateTest, ExtraPosesAreNotRejectedAsPairs) {
  for (uint64_t seed = 1; seed <= 10; ++seed) {
    SCOPED_TRACE(absl::StrFormat("simulation seed %d", seed));
    const SimResult sim = MustSimulate(Scenario(seed));
    CalibrateOptions co;
    co.heldout = false;
    const CalibrationReport r = MustCalibrate(sim.capture, co);
    for (const PairCheck& p : r.pairs) {
      EXPECT_TRUE(p.ok) << "pair " << p.pose_a << "-" << p.pose_b << " (" << p.face
                        << ", extra poses) rejected: " << p.reason;
    }
    EXPECT_EQ(r.verdict, Verdict::kPass) << Summary(r);
  }
}

// ---------------------------------------------------------------------------------------------
// Determinism.

void ExpectIdentical(const ParamSet& a, const ParamSet& b) {
  const AccelVector va = PackAccel(a.accel), vb = PackAccel(b.accel);
  for (int c = 0; c < kAccelParams; ++c) EXPECT_EQ(va(c), vb(c)) << AccelParamName(c);
  EXPECT_EQ(a.accel.frame_angles, b.accel.frame_angles);
  EXPECT_EQ(a.gyro.matrix, b.gyro.matrix);
  EXPECT_EQ(a.gyro.bias, b.gyro.bias);
  EXPECT_EQ(a.gyro.accel_coupling, b.gyro.accel_coupling);
}

TEST(CalibrateTest, SameSeedGivesBitIdenticalParameters) {
  const SimResult sim = MustSimulate(Scenario(21));
  CalibrateOptions options;
  options.heldout = false;  // not part of the parameters; saves time
  const CalibrationReport a = MustCalibrate(sim.capture, options);
  const CalibrationReport b = MustCalibrate(sim.capture, options);
  ExpectIdentical(a.params, b.params);
  EXPECT_EQ(a.residual.accel_rms_m_s2, b.residual.accel_rms_m_s2);
  EXPECT_EQ(a.threshold_multiplier, b.threshold_multiplier);
}

// The threshold sweep's multipliers are scored on several threads and judged in order: the
// result is the one thread's, bit for bit, whatever the count.
TEST(CalibrateTest, ThreadsGiveBitIdenticalResults) {
  const SimResult sim = MustSimulate(Scenario(23));
  CalibrateOptions options;
  options.heldout = false;
  const CalibrationReport one = MustCalibrate(sim.capture, options);
  for (int threads : {2, 3, 16}) {
    options.threads = threads;
    const CalibrationReport many = MustCalibrate(sim.capture, options);
    ExpectIdentical(one.params, many.params);
    EXPECT_EQ(one.threshold_multiplier, many.threshold_multiplier) << threads << " threads";
    ASSERT_EQ(one.poses.size(), many.poses.size()) << threads << " threads";
    for (size_t i = 0; i < one.poses.size(); ++i) {
      EXPECT_EQ(one.poses[i].interval.begin, many.poses[i].interval.begin) << "pose " << i;
      EXPECT_EQ(one.poses[i].interval.end, many.poses[i].interval.end) << "pose " << i;
    }
  }
}

TEST(CalibrateTest, OtherBsasSeedsStayWithinTolerance) {
  const SimOptions scenario = Scenario(22);
  const SimResult sim = MustSimulate(scenario);
  const SimResult val = ValidationCapture(scenario, sim.truth);
  for (const uint64_t bsas_seed : {2, 3, 99}) {
    SCOPED_TRACE(absl::StrFormat("BSAS seed %d", bsas_seed));
    CalibrateOptions options;
    options.seed = bsas_seed;
    options.heldout = false;
    const CalibrationReport r = MustCalibrate(sim.capture, options);
    SCOPED_TRACE(Summary(r));
    const Errors e = Validate(r.params, val);
    EXPECT_LT(e.accel_rms_m_s2, kAccelTolerance) << e.accel_rms_m_s2 / kMg << " mg";
    EXPECT_LT(e.static_rate_max_deg_s, kStaticRateToleranceDegS);
  }
}

TEST(CalibrateTest, WithoutBsasStillWithinTolerance) {
  const SimOptions scenario = Scenario(23);
  const SimResult sim = MustSimulate(scenario);
  CalibrateOptions options;
  options.use_bsas = false;
  options.heldout = false;
  const CalibrationReport r = MustCalibrate(sim.capture, options);
  SCOPED_TRACE(Summary(r));
  ASSERT_EQ(r.stages.size(), 2u);
  EXPECT_EQ(r.stages[0].name, "ls");
  EXPECT_EQ(r.stages[1].name, "lm");
  const Errors e = Validate(r.params, ValidationCapture(scenario, sim.truth));
  EXPECT_LT(e.accel_rms_m_s2, kAccelTolerance) << e.accel_rms_m_s2 / kMg << " mg";
}

// ---------------------------------------------------------------------------------------------
// Six-face pairs in the pipeline.

TEST(CalibrateTest, ExactHalfTurnsGiveSixOkPairsNearOneEighty) {
  SimOptions options = Scenario(31);
  options.turn_error_deg = 0;
  const SimResult sim = MustSimulate(options);
  CalibrateOptions co;
  co.heldout = false;
  const CalibrationReport r = MustCalibrate(sim.capture, co);
  SCOPED_TRACE(Summary(r));
  ExpectSixOkPairsOnePerFace(r);
  for (const PairCheck& p : r.pairs) {
    if (!p.ok) continue;  // rejected "pairs" of extra poses: see ExtraPosesAreNotRejectedAsPairs
    EXPECT_LT(p.pose_b, 12);
    EXPECT_NEAR(p.rotation_deg, 180, 1.0);
    EXPECT_NEAR(p.tilt_deg, options.floor_tilt_deg, 0.1);
  }
}

// A pair's mean cancels the floor's tilt only for an exact half turn: 180 + e degrees on a floor
// tilted by t leaves t * e / 2 (2 degrees and turn errors of 5 degrees standard deviation: about
// 1.5 mrad) in the face direction, hence in the case frame and in the gyroscope matrix fitted in
// it, many times their standard errors. The calibrated gyroscope measures each turn and the
// frame is taken from the turn axes: frame and gyroscope matrix then agree with the truth to
// their noise, and so do the faces' residuals.
TEST(CalibrateTest, TurnErrorsOnATiltedFloorDoNotTurnTheFrame) {
  for (uint64_t seed = 1; seed <= 4; ++seed) {
    SCOPED_TRACE(absl::StrFormat("simulation seed %d", seed));
    SimOptions options = Scenario(seed);
    options.floor_tilt_deg = 2.0;
    options.turn_error_deg = 5.0;
    const SimResult sim = MustSimulate(options);
    const CalibrationReport r = MustCalibrate(sim.capture);
    SCOPED_TRACE(Summary(r));
    ExpectSixOkPairsOnePerFace(r);
    // The faces' per-axis residuals (effects report), taken along the turn axes with the mean
    // of the two poses' sizes, are at the noise: the pair's mean vector, cos(2 degrees) short,
    // read -0.6 mg on every face's own axis.
    ASSERT_EQ(r.effect_diagnostics.faces.size(), 6u);
    for (const FaceResidual& f : r.effect_diagnostics.faces)
      EXPECT_LT(f.residual_m_s2.cwiseAbs().maxCoeff(), 0.4 * kMg)
          << f.face << ": " << f.residual_m_s2.transpose() / kMg << " mg";
    const Eigen::Vector3d frame_error = r.params.accel.frame_angles - sim.truth.accel.frame_angles;
    EXPECT_LT(frame_error.cwiseAbs().maxCoeff(), 0.25e-3) << frame_error.transpose() << " rad";
    for (int c = 0; c < 9; ++c) {
      const double error = r.params.gyro.matrix(c % 3, c / 3) - sim.truth.gyro.matrix(c % 3, c / 3);
      EXPECT_LT(std::abs(error), 4 * r.params.stderrs.gyro_matrix(c % 3, c / 3))
          << "gyro matrix (" << c % 3 << "," << c / 3 << ") off by " << error;
    }
  }
}

TEST(CalibrateTest, DeclaredProtocolIsNotDetected) {
  const SimResult sim = MustSimulate(Scenario(32));
  CalibrateOptions co;
  co.protocol = ProtocolKind::kFree;
  co.heldout = false;
  const CalibrationReport r = MustCalibrate(sim.capture, co);
  EXPECT_EQ(ProtocolKindName(r.protocol), "free");
  EXPECT_FALSE(r.protocol_detected);
  EXPECT_TRUE(r.pairs.empty());  // free has no pairs to check
}

// ---------------------------------------------------------------------------------------------
// Captures that cannot determine the model.

// A refusal is a report: the verdict refused, why, and every pose found with why it is or is
// not usable.
TEST(CalibrateTest, TooFewPosesIsRefusedSayingWhatToAdd) {
  SimOptions options;
  options.protocol = SimProtocol::kFree;
  options.free_poses = 5;
  options.seed = 41;
  const SimResult sim = MustSimulate(options);
  const CalibrationReport r = MustCalibrate(sim.capture);
  ASSERT_EQ(r.verdict, Verdict::kRefused) << Summary(r);
  ASSERT_TRUE(r.refusal.has_value());
  EXPECT_EQ(r.refusal->reason, RefusalReason::kTooFewOrientations);
  const std::string& message = r.refusal->message;
  EXPECT_NE(message.find("Found at most 5 usable"), std::string::npos) << message;
  EXPECT_NE(message.find("in 5 distinct orientations"), std::string::npos) << message;
  // The minimum counts come from the one table.
  EXPECT_NE(message.find(absl::StrFormat("%d distinct orientations spread over the sphere",
                                         static_cast<int>(pipeline::kFullModelNeeds.count))),
            std::string::npos)
      << message;
  EXPECT_EQ(r.verdict_reasons, std::vector<std::string>{message});
  EXPECT_EQ(UsedPoses(r), 5);
  EXPECT_TRUE(r.stages.empty());
}

// A capture of the given orientations (R_world_body) through `truth`: the first held for
// `rest_s`, each later one for `hold_s`, minimum-jerk moves of `move_s` about a fixed body axis
// between them (the simulator's model), white noise from our own Box-Muller draws.
Capture CaptureOfOrientations(const std::vector<Eigen::Matrix3d>& orientations,
                              const SimTruth& truth, uint64_t seed, double rest_s = 10,
                              double hold_s = 4, double move_s = 2.5) {
  constexpr double kRate = 200, kAccelNoise = 0.02, kGyroNoise = 0.002;
  std::mt19937_64 rng(seed);
  auto normal = [&rng]() {
    const double u1 = 1.0 - static_cast<double>(rng() >> 11) * 0x1.0p-53;
    const double u2 = static_cast<double>(rng() >> 11) * 0x1.0p-53;
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
  };
  Capture c;
  c.rate_hz = kRate;
  const Eigen::Vector3d up_world(0, 0, c.gravity_m_s2);
  auto push = [&](const Eigen::Matrix3d& r, const Eigen::Vector3d& w) {
    const Eigen::Vector3d f = r.transpose() * up_world;
    Eigen::Vector3d na, ng;
    for (int i = 0; i < 3; ++i) na(i) = kAccelNoise * normal() / truth.accel.scale(i);
    for (int i = 0; i < 3; ++i) ng(i) = kGyroNoise * normal() / truth.gyro.matrix(i, i);
    c.t_s.push_back(static_cast<double>(c.t_s.size()) / kRate);
    c.accel.push_back(truth.accel.Invert(f) + na);
    c.gyro.push_back(truth.gyro.Invert(w, f) + ng);
  };
  for (size_t p = 0; p < orientations.size(); ++p) {
    if (p > 0) {
      const Eigen::AngleAxisd aa(orientations[p - 1].transpose() * orientations[p]);
      const Eigen::Vector3d phi = aa.angle() * aa.axis();
      const int n = static_cast<int>(std::lround(move_s * kRate));
      for (int k = 1; k < n; ++k) {
        const double tau = static_cast<double>(k) / n;
        const double s = tau * tau * tau * (10 - 15 * tau + 6 * tau * tau);
        const double ds = 30 * tau * tau * (1 - tau) * (1 - tau) / move_s;
        push(orientations[p - 1] * ExpSo3<double>(Eigen::Vector3d(s * phi)), ds * phi);
      }
    }
    const int n = static_cast<int>(std::lround((p == 0 ? rest_s : hold_s) * kRate));
    for (int k = 0; k < n; ++k) push(orientations[p], Eigen::Vector3d::Zero());
  }
  return c;
}

TEST(CalibrateTest, RestWithTinyMovesIsRefused) {
  // The initial rest, then 14 placements that differ from it by under a degree of tilt: static
  // intervals exist, but they cannot determine the accelerometer (nor the gyroscope).
  SimOptions options;
  const SimTruth truth =
      RandomTruth(44, AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond, options);
  std::vector<Eigen::Matrix3d> orientations;
  for (int k = 0; k < 15; ++k) {
    const double a = 0.7 * k;
    orientations.push_back(
        ExpSo3<double>(Eigen::Vector3d(std::cos(a), std::sin(a), 0) * (k == 0 ? 0.0 : 0.012)));
  }
  const Capture c = CaptureOfOrientations(orientations, truth, 44);
  const CalibrationReport r = MustCalibrate(c);
  ASSERT_EQ(r.verdict, Verdict::kRefused) << Summary(r);
  std::printf("tiny moves: %s\n", r.refusal->message.c_str());
  // Counted from its stops, the capture holds one orientation (within 5 degrees): a rest.
  EXPECT_EQ(r.refusal->reason, RefusalReason::kRestOnly) << r.refusal->message;
}

TEST(CalibrateTest, HandBuiltCaptureOfSpreadOrientationsCalibrates) {
  // The control for the test above: the same builder with orientations spread over the sphere
  // calibrates to the accuracy figure, so the failure above is about the poses, not the builder.
  SimOptions options;
  SimTruth truth = RandomTruth(45, AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond, options);
  truth.accel.quadratic.setZero();
  std::vector<Eigen::Matrix3d> orientations = {Eigen::Matrix3d::Identity()};
  std::mt19937_64 rng(45);
  for (int k = 0; k < 29; ++k) {
    Eigen::Vector4d q;
    for (int i = 0; i < 4; ++i) q(i) = static_cast<double>(rng() >> 11) * 0x1.0p-53 - 0.5;
    orientations.push_back(
        Eigen::Quaterniond(q(0), q(1), q(2), q(3)).normalized().toRotationMatrix());
  }
  const Capture c = CaptureOfOrientations(orientations, truth, 45);
  CalibrateOptions co;
  co.heldout = false;
  const CalibrationReport r = MustCalibrate(c, co);
  SCOPED_TRACE(Summary(r));
  EXPECT_EQ(UsedPoses(r), 30);
  const Errors e = Validate(r.params, ValidationCapture(options, truth));
  EXPECT_LT(e.accel_rms_m_s2, kAccelTolerance) << e.accel_rms_m_s2 / kMg << " mg";
}

TEST(CalibrateTest, GyroThatSawNoRotationIsReportedNotCalibrated) {
  // A gyroscope that recorded no motion (its rate replaced by its static bias and noise): the
  // accelerometer still calibrates; the report says the gyroscope is not calibrated.
  const SimOptions options = Scenario(43);
  const SimResult sim = MustSimulate(options);
  Capture c = sim.capture;
  for (size_t k = 0; k < c.size(); ++k) {
    c.gyro[k] -= sim.truth.gyro.Invert(sim.true_gyro_rad_s[k], sim.true_accel_m_s2[k]) -
                 sim.truth.gyro.Invert(Eigen::Vector3d::Zero(), sim.true_accel_m_s2[k]);
  }
  CalibrateOptions co;
  co.heldout = false;
  const absl::StatusOr<CalibrationReport> r = Calibrate(c, co);
  ASSERT_TRUE(r.ok()) << r.status();
  SCOPED_TRACE(Summary(*r));
  EXPECT_FALSE(r->params.gyro_calibrated);
  bool warned = false;
  for (const std::string& w : r->warnings)
    warned |= w.rfind("gyroscope:", 0) == 0 && w.find("only the bias") != std::string::npos;
  EXPECT_TRUE(warned) << "no warning that the gyroscope kept only its bias";
  EXPECT_NE(r->verdict, Verdict::kPass);
  // The bias is still measured.
  EXPECT_LT((r->params.gyro.bias - sim.truth.gyro.bias).norm() *
                std::abs(sim.truth.gyro.matrix(0, 0)) * kRadToDeg,
            0.02);
  // params.h: gyro_calibrated == false means "only the gyro bias was determined (matrix
  // nominal)", and the CLI summary prints "NOT calibrated: nominal". (Regression: at commit
  // 90c36ed the rank-deficient solver's matrix was stored instead, entries of several thousand
  // rad/s per rad/s against a truth of ~1.0, and the SDK applied it.)
  const Eigen::Matrix3d nominal = Eigen::Matrix3d::Identity() * NominalGyroToSi(c.gyro_unit);
  EXPECT_TRUE(r->params.gyro.matrix.isApprox(nominal, 1e-9)) << "stored gyro matrix\n"
                                                             << r->params.gyro.matrix;
}

// ---------------------------------------------------------------------------------------------
// Raw counts, without unit hints: the calibration finds offset and scale from the data.

class CalibrateCountsTest : public testing::TestWithParam<uint64_t> {};

TEST_P(CalibrateCountsTest, CountsCalibrateToTheSameAccuracy) {
  const uint64_t seed = GetParam();
  SCOPED_TRACE(absl::StrFormat("simulation seed %d", seed));
  SimOptions options = Scenario(seed);
  options.accel_unit = AccelUnit::kCounts;
  options.accel_offset_counts = 32768;
  options.gyro_unit = GyroUnit::kCounts;
  const SimResult sim = MustSimulate(options);
  CalibrateOptions co;
  co.heldout = false;
  const CalibrationReport r = MustCalibrate(sim.capture, co);
  SCOPED_TRACE(Summary(r));
  EXPECT_EQ(r.params.accel_unit, AccelUnit::kCounts);
  EXPECT_EQ(r.params.gyro_unit, GyroUnit::kCounts);
  const Errors e = Validate(r.params, ValidationCapture(options, sim.truth));
  std::printf("counts seed %llu: accel %.4f mg after best-fit rotation, static rate %.5f deg/s\n",
              static_cast<unsigned long long>(seed), e.accel_rms_m_s2 / kMg,
              e.static_rate_max_deg_s);
  EXPECT_LT(e.accel_rms_m_s2, kAccelTolerance) << e.accel_rms_m_s2 / kMg << " mg";
  EXPECT_LT(e.static_rate_max_deg_s, kStaticRateToleranceDegS);
  EXPECT_TRUE(r.params.gyro_calibrated);
  ExpectSixOkPairsOnePerFace(r);
}

INSTANTIATE_TEST_SUITE_P(Seeds, CalibrateCountsTest, testing::Values(51, 52, 53),
                         [](const testing::TestParamInfo<uint64_t>& param_info) {
                           return absl::StrFormat("seed%d", param_info.param);
                         });

// ---------------------------------------------------------------------------------------------
// Time gaps (the importers keep a jump in a sample counter as a gap in time).

// The scenario capture with `cut_s` of samples removed from the middle of the move after the
// first extra pose: the gyroscope misses part of that rotation. Returns the gap's start time.
double CutMove(const SimResult& sim, double cut_s, Capture* out) {
  const SimPose* from = nullptr;
  const SimPose* to = nullptr;
  for (size_t i = 0; i + 1 < sim.poses.size(); ++i) {
    if (sim.poses[i].label.rfind("extra", 0) == 0) {
      from = &sim.poses[i];
      to = &sim.poses[i + 1];
      break;
    }
  }
  EXPECT_NE(from, nullptr);
  if (from == nullptr) return 0;
  const double mid = 0.5 * (from->t_end_s + to->t_start_s);
  const double lo = mid - cut_s / 2, hi = mid + cut_s / 2;
  *out = sim.capture;
  out->t_s.clear();
  out->accel.clear();
  out->gyro.clear();
  out->temp.clear();
  double gap_start = 0;
  for (size_t k = 0; k < sim.capture.size(); ++k) {
    const double t = sim.capture.t_s[k];
    if (t > lo && t < hi) continue;
    if (t <= lo) gap_start = t;
    out->t_s.push_back(t);
    out->accel.push_back(sim.capture.accel[k]);
    out->gyro.push_back(sim.capture.gyro[k]);
    if (sim.capture.has_temp()) out->temp.push_back(sim.capture.temp[k]);
  }
  return gap_start;
}

TEST(CalibrateTest, MoveAcrossATimeGapIsLeftOutOfTheGyroFitWithAWarning) {
  const SimOptions options = Scenario(7);
  const SimResult sim = MustSimulate(options);
  Capture cut;
  const double gap_start = CutMove(sim, 0.5, &cut);
  ASSERT_LT(cut.size(), sim.capture.size());
  CalibrateOptions co;
  co.heldout = false;
  const CalibrationReport intact = MustCalibrate(sim.capture, co);
  const CalibrationReport gapped = MustCalibrate(cut, co);
  SCOPED_TRACE(Summary(gapped));
  EXPECT_EQ(gapped.verdict, intact.verdict);
  ASSERT_TRUE(gapped.params.gyro_calibrated);
  // One move fewer in the gyro fit: the matrix may move by its standard error, not more.
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      const double se = gapped.params.stderrs.gyro_matrix(i, j);
      ASSERT_TRUE(std::isfinite(se));
      EXPECT_NEAR(gapped.params.gyro.matrix(i, j), intact.params.gyro.matrix(i, j), 3 * se)
          << "gyro matrix (" << i << "," << j << ")";
    }
  }
  EXPECT_EQ(gapped.moves.size() + 1, intact.moves.size());
  const Errors e = Validate(gapped.params, ValidationCapture(options, sim.truth));
  EXPECT_LT(e.static_rate_max_deg_s, kStaticRateToleranceDegS);
  EXPECT_LT(e.accel_rms_m_s2, kAccelTolerance);
  bool warned = false;
  const std::string where = absl::StrFormat("at %.3f s", gap_start);
  for (const std::string& w : gapped.warnings)
    warned |= w.find("time gap") != std::string::npos && w.find(where) != std::string::npos &&
              w.find("left out of the gyroscope fit") != std::string::npos;
  EXPECT_TRUE(warned) << "no warning naming the gap " << where;
}

// ---------------------------------------------------------------------------------------------
// Fewer poses than the full model needs: the largest model they determine, with a warning.

TEST(CalibrateTest, EightPosesGiveBiasAndScaleWithAWarnVerdict) {
  SimOptions options;
  options.protocol = SimProtocol::kFree;
  options.free_poses = 8;
  options.seed = 43;
  const SimResult sim = MustSimulate(options);
  const CalibrationReport r = MustCalibrate(sim.capture);
  SCOPED_TRACE(Summary(r));
  EXPECT_EQ(r.verdict, Verdict::kWarn);
  bool warned = false;
  for (const std::string& w : r.warnings)
    warned |= w.find("only bias and scale were calibrated") != std::string::npos;
  EXPECT_TRUE(warned);
  EXPECT_EQ(r.params.accel.tri_angles, Eigen::Vector3d::Zero());
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(r.params.accel.bias(i), sim.truth.accel.bias(i),
                4 * r.params.stderrs.accel.bias(i) + 1e-3);
    EXPECT_NEAR(r.params.accel.scale(i), sim.truth.accel.scale(i),
                4 * r.params.stderrs.accel.scale(i) + 5e-3);
  }
}

}  // namespace

// A unit that does not fit the data is refused after the fit, naming the likely unit: data in
// m/s^2 declared in g (before: passed, with a scale of 1/9.8 of g's, an OpenVINS Ta of 9.7), and
// a gyroscope in deg/s declared rad/s (the fit can settle on an aliased scale near 1; the moves
// against gravity's turn tell).
TEST(CalibrateTest, WrongDeclaredUnitIsRefusedNamingTheLikelyUnit) {
  SimOptions options;
  options.seed = 61;
  options.extra_poses = 4;
  SimResult sim = *Simulate(options);
  Capture c = sim.capture;
  c.accel_unit = AccelUnit::kG;
  c.accel_unit_source = "declared";
  CalibrationReport r = MustCalibrate(c);
  ASSERT_EQ(r.verdict, Verdict::kRefused) << Summary(r);
  EXPECT_EQ(r.refusal->reason, RefusalReason::kUnitMismatch);
  EXPECT_EQ(r.refusal->message.rfind("the accelerometer reads about 9.", 0), 0u)
      << r.refusal->message;
  EXPECT_NE(r.refusal->message.find("what --accel-unit g implies: the data look like m/s^2; "
                                    "give --accel-unit m/s^2"),
            std::string::npos)
      << r.refusal->message;

  options.gyro_unit = GyroUnit::kDegPerSecond;
  sim = *Simulate(options);
  c = sim.capture;
  c.gyro_unit = GyroUnit::kRadPerSecond;
  c.gyro_unit_source = "inferred";
  r = MustCalibrate(c);
  ASSERT_EQ(r.verdict, Verdict::kRefused) << Summary(r);
  EXPECT_EQ(r.refusal->reason, RefusalReason::kUnitMismatch);
  EXPECT_EQ(r.refusal->message.rfind("the gyroscope reads about 57.3 times what the inferred "
                                     "unit rad/s implies: the data look like deg/s",
                                     0),
            0u)
      << r.refusal->message;
  // In its own unit the same capture calibrates.
  sim.capture.gyro_unit_source = "declared";
  EXPECT_NE(MustCalibrate(sim.capture).verdict, Verdict::kRefused);
}

// core/quantisation.h at its limits: a stuck channel's mean is known to q / sqrt(12); noise of
// one step dithers the rounding away.
TEST(QuantisationTest, RoundingErrorOfAMean) {
  EXPECT_DOUBLE_EQ(RoundingBiasStd(0.01, 0.0), 0.01 / std::sqrt(12.0));
  EXPECT_LT(RoundingBiasStd(0.01, 0.01), 1e-8 * 0.01);
  EXPECT_EQ(RoundingBiasStd(0.0, 0.0), 0.0);
  EXPECT_DOUBLE_EQ(WithRoundingError(3e-6, 0.0, 0.0), 3e-6);
  EXPECT_NEAR(WithRoundingError(3e-6, 0.01, 0.0), 0.01 / std::sqrt(12.0), 1e-8);
}

// A gyroscope quantised to 0.01 rad/s whose noise (2e-4 rad/s) is far below the step: an axis
// whose rests all read one value. Its bias standard error was the pose means' scatter, ~0; it
// must not sit below the grid's rounding, q / sqrt(12).
TEST(CalibrateTest, StuckGyroChannelBiasStdErrorRespectsTheGrid) {
  SimOptions options;
  options.seed = 62;
  options.extra_poses = 4;
  options.gyro_step = 0.01;
  options.gyro_noise_rad_s = 2e-4;
  const SimResult sim = *Simulate(options);
  const CalibrationReport r = MustCalibrate(sim.capture);
  ASSERT_NE(r.verdict, Verdict::kRefused) << Summary(r);
  int stuck = 0;
  for (int j = 0; j < 3; ++j) {
    // Stuck: every used pose reads one value on this axis.
    bool constant = true;
    for (const PoseReport& p : r.poses)
      if (p.interval.used) constant &= p.interval.gyro_std(j) == 0.0;
    if (!constant) continue;
    ++stuck;
    EXPECT_GE(r.params.stderrs.gyro_bias(j), 0.9 * 0.01 / std::sqrt(12.0)) << "axis " << j;
  }
  EXPECT_GT(stuck, 0) << "no axis is stuck: the test checks nothing (seed 62)";
}

}  // namespace imucal::core
