#include "core/accel_solver.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/capture.h"
#include "core/model.h"

namespace imucal::core {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kG = kStandardGravity;
constexpr uint64_t kSeeds[] = {1, 2, 3, 4, 5, 6, 7, 8, 9, 10};

// Our own uniform and Box-Muller draws: the same numbers with any standard library.
class Rng {
 public:
  explicit Rng(uint64_t seed) : engine_(seed) {}
  double Uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }
  double Uniform(double lo, double hi) { return lo + (hi - lo) * Uniform(); }
  double Normal() {
    const double u1 = 1.0 - Uniform(), u2 = Uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
  }
  Eigen::Vector3d Normal3(double sigma) {
    const double x = Normal(), y = Normal();
    return sigma * Eigen::Vector3d(x, y, Normal());
  }
  Eigen::Vector3d UnitVector() { return Normal3(1.0).normalized(); }

 private:
  std::mt19937_64 engine_;
};

// A MEMS-like truth in m/s^2 input units (or counts with `counts`): bias tenths of m/s^2,
// scale errors of a percent, non-orthogonality of mrad; quadratic and frame angles optional.
AccelParams RandomTruth(uint64_t seed, bool quadratic, bool frame, bool counts = false) {
  Rng rng(seed * 7919 + 17);
  AccelParams p;
  const double nominal = counts ? kG / 2048.0 : 1.0;
  for (int i = 0; i < 3; ++i) {
    p.bias(i) = counts ? 32768 + rng.Uniform(-200, 200) : rng.Uniform(-0.5, 0.5);
    p.scale(i) = nominal * (1 + rng.Uniform(-0.02, 0.02));
    p.tri_angles(i) = rng.Uniform(-0.005, 0.005);
    if (quadratic) p.quadratic(i) = rng.Uniform(-3e-4, 3e-4);
    if (frame) p.frame_angles(i) = rng.Uniform(-0.02, 0.02);
  }
  return p;
}

// Pose means that read exactly g along `directions` (body frame), through the truth.
std::vector<AccelPose> PosesFor(const AccelParams& truth, const std::vector<Eigen::Vector3d>& dirs,
                                double mean_std = 1e-3) {
  std::vector<AccelPose> poses;
  for (const Eigen::Vector3d& d : dirs) {
    AccelPose p;
    p.mean = truth.Invert(kG * d.normalized());
    p.mean_std = Eigen::Vector3d::Constant(mean_std);
    poses.push_back(p);
  }
  return poses;
}

std::vector<Eigen::Vector3d> RandomDirections(uint64_t seed, int n) {
  Rng rng(seed * 104729 + 3);
  std::vector<Eigen::Vector3d> dirs;
  for (int i = 0; i < n; ++i) dirs.push_back(rng.UnitVector());
  return dirs;
}

// Each axis up and down twice: the six-face protocol without the floor tilt.
std::vector<Eigen::Vector3d> SixFaceDirections() {
  std::vector<Eigen::Vector3d> dirs;
  for (int axis = 0; axis < 3; ++axis) {
    for (int sign : {1, -1}) {
      Eigen::Vector3d d = Eigen::Vector3d::Zero();
      d(axis) = sign;
      dirs.push_back(d);
      dirs.push_back(d);
    }
  }
  return dirs;
}

AccelMask AllFree() {
  AccelMask m;
  m.fill(true);
  return m;
}

AccelMask LinearFree() {
  AccelMask m = AllFree();
  for (int c = 9; c < 12; ++c) m[c] = false;
  return m;
}

// Asserts every magnitude parameter within `tol` relative to its natural size.
void ExpectMagnitudeParamsNear(const AccelParams& got, const AccelParams& want, double tol) {
  const AccelVector g = PackAccel(got), w = PackAccel(want);
  for (int c = 0; c < kAccelParams; ++c) {
    // Natural sizes: bias ~ |scale|^-1 m/s^2, scale ~ |scale|, angles 1 rad, quadratic 1e-3.
    const double size = c < 3   ? 1.0 / std::abs(want.scale(c))
                        : c < 6 ? std::abs(w(c))
                        : c < 9 ? 1.0
                                : 1e-3;
    EXPECT_NEAR(g(c), w(c), tol * size) << AccelParamName(c);
  }
}

double WeightedCost(const AccelParams& p, const std::vector<AccelPose>& poses,
                    const std::vector<double>& sigma) {
  const std::vector<double> r = MagnitudeResiduals(p, poses, kG);
  double s = 0;
  for (size_t i = 0; i < r.size(); ++i) s += (r[i] / sigma[i]) * (r[i] / sigma[i]);
  return s;
}

// ---------------------------------------------------------------------------------------------

TEST(AccelSolverTest, PackUnpackRoundTripAndNames) {
  const AccelParams p = RandomTruth(3, true, true);
  const AccelParams q = UnpackAccel(PackAccel(p), p.frame_angles);
  EXPECT_EQ(PackAccel(q), PackAccel(p));
  EXPECT_EQ(q.frame_angles, p.frame_angles);
  EXPECT_EQ(AccelParamName(0), "bias_x");
  EXPECT_EQ(AccelParamName(4), "scale_y");
  EXPECT_EQ(AccelParamName(6), "t_yx");
  EXPECT_EQ(AccelParamName(8), "t_zy");
  EXPECT_EQ(AccelParamName(11), "quadratic_z");
}

TEST(AccelSolverTest, MagnitudeResidualsAreZeroAtTruth) {
  for (const uint64_t seed : kSeeds) {
    SCOPED_TRACE(absl::StrFormat("seed %d", seed));
    const AccelParams truth = RandomTruth(seed, true, true);
    const std::vector<AccelPose> poses = PosesFor(truth, RandomDirections(seed, 20));
    for (double r : MagnitudeResiduals(truth, poses, kG)) EXPECT_NEAR(r, 0.0, 1e-12);
  }
}

TEST(AccelSolverTest, FitEllipsoidRecoversLinearTruthExactly) {
  for (const uint64_t seed : kSeeds) {
    for (const bool counts : {false, true}) {
      SCOPED_TRACE(absl::StrFormat("seed %d counts %d", seed, counts));
      // frame_angles leave |a| unchanged: the fit must return the same bias, scale and tri.
      const AccelParams truth = RandomTruth(seed, /*quadratic=*/false, /*frame=*/true, counts);
      const absl::StatusOr<AccelParams> fit =
          FitEllipsoid(PosesFor(truth, RandomDirections(seed, 30)), kG);
      ASSERT_TRUE(fit.ok()) << fit.status();
      ExpectMagnitudeParamsNear(*fit, truth, 1e-9);
      EXPECT_EQ(fit->quadratic, Eigen::Vector3d::Zero());
      EXPECT_EQ(fit->frame_angles, Eigen::Vector3d::Zero());
    }
  }
}

TEST(AccelSolverTest, FitEllipsoidOnSixFacePosesToo) {
  // Twelve axis-aligned poses plus a few diagonals determine the 9 parameters as well.
  const AccelParams truth = RandomTruth(11, false, false);
  std::vector<Eigen::Vector3d> dirs = SixFaceDirections();
  dirs.push_back(Eigen::Vector3d(1, 1, 0));
  dirs.push_back(Eigen::Vector3d(1, 0, 1));
  dirs.push_back(Eigen::Vector3d(0, 1, -1));
  const absl::StatusOr<AccelParams> fit = FitEllipsoid(PosesFor(truth, dirs), kG);
  ASSERT_TRUE(fit.ok()) << fit.status();
  ExpectMagnitudeParamsNear(*fit, truth, 1e-9);
}

TEST(AccelSolverTest, FitKnownReferencesRecoversFullMatrix) {
  for (const uint64_t seed : kSeeds) {
    SCOPED_TRACE(absl::StrFormat("seed %d", seed));
    const AccelParams truth = RandomTruth(seed, /*quadratic=*/false, /*frame=*/true);
    std::vector<Eigen::Vector3d> means, refs;
    for (const Eigen::Vector3d& d : SixFaceDirections()) {
      refs.push_back(kG * d);
      means.push_back(truth.Invert(kG * d));
    }
    const absl::StatusOr<AccelParams> fit = FitKnownReferences(means, refs);
    ASSERT_TRUE(fit.ok()) << fit.status();
    ExpectMagnitudeParamsNear(*fit, truth, 1e-9);
    for (int i = 0; i < 3; ++i) EXPECT_NEAR(fit->frame_angles(i), truth.frame_angles(i), 1e-9);
    // And the whole model maps each mean onto its reference.
    for (size_t k = 0; k < means.size(); ++k)
      EXPECT_LT((fit->Apply(means[k]) - refs[k]).norm(), 1e-9);
  }
}

TEST(AccelSolverTest, FitKnownReferencesRejectsMirroredAxis) {
  const AccelParams truth = RandomTruth(2, false, false);
  std::vector<Eigen::Vector3d> means, refs;
  for (const Eigen::Vector3d& d : SixFaceDirections()) {
    Eigen::Vector3d mirrored = kG * d;
    mirrored.y() = -mirrored.y();
    refs.push_back(kG * d);
    means.push_back(truth.Invert(mirrored));
  }
  const absl::StatusOr<AccelParams> fit = FitKnownReferences(means, refs);
  ASSERT_FALSE(fit.ok());
  EXPECT_EQ(fit.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(fit.status().message().find("mirrored"), std::string::npos) << fit.status();
}

TEST(AccelSolverTest, RefineLmConvergesToTruthFromPerturbedStart) {
  for (const uint64_t seed : kSeeds) {
    SCOPED_TRACE(absl::StrFormat("seed %d", seed));
    const AccelParams truth = RandomTruth(seed, /*quadratic=*/true, /*frame=*/false);
    const std::vector<AccelPose> poses = PosesFor(truth, RandomDirections(seed, 24));
    AccelParams start = truth;
    start.bias += Eigen::Vector3d(0.05, -0.04, 0.03);
    start.scale = start.scale.cwiseProduct(Eigen::Vector3d(1.005, 0.996, 1.003));
    start.tri_angles += Eigen::Vector3d(0.002, -0.002, 0.001);
    start.quadratic.setZero();
    StageReport report;
    const absl::StatusOr<LmResult> lm = RefineAccelLm(start, poses, kG, AllFree(), &report);
    ASSERT_TRUE(lm.ok()) << lm.status();
    ExpectMagnitudeParamsNear(lm->params, truth, 1e-7);
    EXPECT_EQ(report.name, "lm");
    EXPECT_LT(report.accel_rms_m_s2, 1e-9);
    EXPECT_GT(report.iterations, 0);
    // A free parameter has a (finite, non-negative) variance; the covariance is symmetric.
    for (int c = 0; c < kAccelParams; ++c) EXPECT_GE(lm->covariance(c, c), 0.0);
    EXPECT_LT((lm->covariance - lm->covariance.transpose()).norm(), 1e-9 * lm->covariance.norm());
  }
}

TEST(AccelSolverTest, RefineLmHoldsFixedParameters) {
  const AccelParams truth = RandomTruth(4, /*quadratic=*/false, /*frame=*/false);
  const std::vector<AccelPose> poses = PosesFor(truth, RandomDirections(4, 20));
  AccelParams start = truth;
  start.bias += Eigen::Vector3d(0.02, 0.02, -0.02);
  start.quadratic = Eigen::Vector3d(1e-5, -2e-5, 3e-5);  // held at these values
  const absl::StatusOr<LmResult> lm = RefineAccelLm(start, poses, kG, LinearFree(), nullptr);
  ASSERT_TRUE(lm.ok()) << lm.status();
  EXPECT_EQ(lm->params.quadratic, start.quadratic);
  for (int c = 9; c < 12; ++c) {
    EXPECT_EQ(lm->covariance.row(c).norm(), 0.0);
    EXPECT_EQ(lm->covariance.col(c).norm(), 0.0);
  }
}

TEST(AccelSolverTest, MagnitudeJacobianMatchesCentralDifferences) {
  for (const uint64_t seed : kSeeds) {
    SCOPED_TRACE(absl::StrFormat("seed %d", seed));
    const AccelParams p = RandomTruth(seed, /*quadratic=*/true, /*frame=*/true);
    // Evaluate away from the truth so that the residuals are not zero.
    std::vector<AccelPose> poses =
        PosesFor(RandomTruth(seed + 100, true, false), RandomDirections(seed, 15));
    const Eigen::MatrixXd j = MagnitudeJacobian(p, poses);
    ASSERT_EQ(j.rows(), 15);
    ASSERT_EQ(j.cols(), kAccelParams);
    const AccelVector theta = PackAccel(p);
    for (int c = 0; c < kAccelParams; ++c) {
      const double h = 1e-6 * std::max(1.0, std::abs(theta(c)));
      AccelVector plus = theta, minus = theta;
      plus(c) += h;
      minus(c) -= h;
      const std::vector<double> rp =
          MagnitudeResiduals(UnpackAccel(plus, p.frame_angles), poses, kG);
      const std::vector<double> rm =
          MagnitudeResiduals(UnpackAccel(minus, p.frame_angles), poses, kG);
      for (int i = 0; i < 15; ++i) {
        const double numeric = (rp[i] - rm[i]) / (2 * h);
        EXPECT_NEAR(j(i, c), numeric, 1e-6 * std::max(1.0, std::abs(numeric)))
            << AccelParamName(c) << " pose " << i;
      }
    }
  }
}

TEST(AccelSolverTest, ObservabilityFlagsQuadraticButNotBiasOnSixFacePoses) {
  // On +-g per axis the quadratic term shifts |a| by +q g^2 up and -q g^2 down: exactly what a
  // bias does. Quadratic terms (higher order) are released, the bias stays determined.
  for (const uint64_t seed : kSeeds) {
    SCOPED_TRACE(absl::StrFormat("seed %d", seed));
    const AccelParams truth = RandomTruth(seed, false, false);
    const std::vector<AccelPose> poses =
        PosesFor(truth, SixFaceDirections(), 0.02 / std::sqrt(800.0));
    const AccelObservability obs = AnalyseAccelObservability(truth, poses, kG, AllFree());
    for (int c = 0; c < 3; ++c) EXPECT_TRUE(obs.determined[c]) << AccelParamName(c);
    for (int c = 3; c < 6; ++c) EXPECT_TRUE(obs.determined[c]) << AccelParamName(c);
    for (int c = 9; c < 12; ++c) {
      EXPECT_FALSE(obs.determined[c]) << AccelParamName(c);
      bool warned = false;
      for (const std::string& w : obs.warnings)
        warned |= w.find(AccelParamName(c)) != std::string::npos;
      EXPECT_TRUE(warned) << AccelParamName(c) << " has no warning";
    }
    for (const std::string& w : obs.warnings) {
      EXPECT_EQ(w.find("bias_"), std::string::npos) << w;
      EXPECT_NE(w.find("add poses"), std::string::npos) << "a warning must say what to add: " << w;
    }
  }
}

TEST(AccelSolverTest, ObservabilityFlagsNothingWithWellSpreadPoses) {
  for (const uint64_t seed : kSeeds) {
    SCOPED_TRACE(absl::StrFormat("seed %d", seed));
    const AccelParams truth = RandomTruth(seed, true, false);
    const std::vector<AccelPose> poses =
        PosesFor(truth, RandomDirections(seed, 30), 0.02 / std::sqrt(800.0));
    const AccelObservability obs = AnalyseAccelObservability(truth, poses, kG, AllFree());
    for (int c = 0; c < kAccelParams; ++c) EXPECT_TRUE(obs.determined[c]) << AccelParamName(c);
    EXPECT_TRUE(obs.warnings.empty()) << obs.warnings.front();
  }
}

TEST(AccelSolverTest, ObservabilityKeepsNonCandidatesOut) {
  const AccelParams truth = RandomTruth(1, false, false);
  const std::vector<AccelPose> poses = PosesFor(truth, RandomDirections(1, 30), 1e-3);
  const AccelObservability obs = AnalyseAccelObservability(truth, poses, kG, LinearFree());
  for (int c = 0; c < 9; ++c) EXPECT_TRUE(obs.determined[c]) << AccelParamName(c);
  for (int c = 9; c < 12; ++c) EXPECT_FALSE(obs.determined[c]) << AccelParamName(c);
}

TEST(AccelSolverTest, TooFewPosesIsFailedPrecondition) {
  const AccelParams truth = RandomTruth(1, false, false);
  const std::vector<AccelPose> eight = PosesFor(truth, RandomDirections(1, 8));
  const absl::StatusOr<AccelParams> ellipsoid = FitEllipsoid(eight, kG);
  ASSERT_FALSE(ellipsoid.ok());
  EXPECT_EQ(ellipsoid.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(ellipsoid.status().message().find("at least 9"), std::string::npos)
      << ellipsoid.status();

  const std::vector<AccelPose> twelve = PosesFor(truth, RandomDirections(1, 12));
  const absl::StatusOr<LmResult> lm = RefineAccelLm(truth, twelve, kG, AllFree(), nullptr);
  ASSERT_FALSE(lm.ok());
  EXPECT_EQ(lm.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(lm.status().message().find("add poses"), std::string::npos) << lm.status();

  const std::vector<Eigen::Vector3d> three_means = {truth.Invert(Eigen::Vector3d(kG, 0, 0)),
                                                    truth.Invert(Eigen::Vector3d(0, kG, 0)),
                                                    truth.Invert(Eigen::Vector3d(0, 0, kG))};
  const std::vector<Eigen::Vector3d> three_refs = {
      Eigen::Vector3d(kG, 0, 0), Eigen::Vector3d(0, kG, 0), Eigen::Vector3d(0, 0, kG)};
  const absl::StatusOr<AccelParams> known = FitKnownReferences(three_means, three_refs);
  ASSERT_FALSE(known.ok());
  EXPECT_EQ(known.status().code(), absl::StatusCode::kFailedPrecondition);
}

TEST(AccelSolverTest, EllipsoidOfPosesInOnePlaneIsFailedPrecondition) {
  // Twenty poses with gravity in the x-y plane only: z is not determined.
  const AccelParams truth = RandomTruth(5, false, false);
  std::vector<Eigen::Vector3d> dirs;
  for (int k = 0; k < 20; ++k)
    dirs.push_back(Eigen::Vector3d(std::cos(0.3 * k), std::sin(0.3 * k), 0));
  const absl::StatusOr<AccelParams> fit = FitEllipsoid(PosesFor(truth, dirs), kG);
  ASSERT_FALSE(fit.ok()) << "bias " << fit->bias.transpose();
  EXPECT_EQ(fit.status().code(), absl::StatusCode::kFailedPrecondition);
}

// Poses with white noise on the means and, optionally, an extra scatter of |a| that the model
// does not explain (`tau` m/s^2, along the gravity direction).
std::vector<AccelPose> NoisyPoses(const AccelParams& truth, uint64_t seed, int n, double mean_std,
                                  double tau) {
  Rng rng(seed * 31 + 5);
  std::vector<AccelPose> poses;
  for (const Eigen::Vector3d& d : RandomDirections(seed, n)) {
    AccelPose p;
    const double extra = tau * rng.Normal();
    // Raw noise of mean_std per axis, scaled so that the calibrated noise is mean_std m/s^2.
    p.mean = truth.Invert((kG + extra) * d) + rng.Normal3(mean_std).cwiseQuotient(truth.scale);
    p.mean_std = Eigen::Vector3d::Constant(mean_std).cwiseQuotient(truth.scale);
    poses.push_back(p);
  }
  return poses;
}

TEST(AccelSolverTest, ModelSigmaIsNearZeroForPureNoise) {
  constexpr double kSigma = 1e-3;
  for (const uint64_t seed : kSeeds) {
    SCOPED_TRACE(absl::StrFormat("seed %d", seed));
    const AccelParams truth = RandomTruth(seed, false, false);
    const std::vector<AccelPose> poses = NoisyPoses(truth, seed, 400, kSigma, 0.0);
    const double tau = EstimateModelSigma(truth, poses, kG, 0);
    // chi^2 of 400 residuals fluctuates by sqrt(2/400) = 7%: tau stays under half the noise
    // (0.5 sigma would need a 25% excess, 3.5 standard deviations).
    EXPECT_GE(tau, 0.0);
    EXPECT_LT(tau, 0.5 * kSigma);
  }
}

TEST(AccelSolverTest, ModelSigmaRecoversInjectedScatter) {
  constexpr double kSigma = 1e-3, kTau = 5e-3;
  for (const uint64_t seed : kSeeds) {
    SCOPED_TRACE(absl::StrFormat("seed %d", seed));
    const AccelParams truth = RandomTruth(seed, false, false);
    const std::vector<AccelPose> poses = NoisyPoses(truth, seed, 400, kSigma, kTau);
    EXPECT_NEAR(EstimateModelSigma(truth, poses, kG, 0), kTau, 0.15 * kTau);
    // From a fit of the 9 linear parameters (n_free = 9), as the accel stage
    // (core/calibrate/accel_stage.cc) uses it.
    const absl::StatusOr<AccelParams> fit = FitEllipsoid(poses, kG);
    ASSERT_TRUE(fit.ok()) << fit.status();
    const absl::StatusOr<LmResult> lm = RefineAccelLm(*fit, poses, kG, LinearFree(), nullptr);
    ASSERT_TRUE(lm.ok()) << lm.status();
    EXPECT_NEAR(EstimateModelSigma(lm->params, poses, kG, 9), kTau, 0.15 * kTau);
  }
}

TEST(AccelSolverTest, ModelSigmaWidensMagnitudeSigmas) {
  const AccelParams truth = RandomTruth(1, false, false);
  std::vector<AccelPose> poses = NoisyPoses(truth, 1, 10, 1e-3, 0.0);
  const std::vector<double> bare = MagnitudeSigmas(truth, poses);
  for (auto& p : poses) p.model_sigma_m_s2 = 4e-3;
  const std::vector<double> wide = MagnitudeSigmas(truth, poses);
  for (size_t i = 0; i < poses.size(); ++i) {
    EXPECT_NEAR(bare[i], 1e-3, 0.1e-3);  // isotropic 1e-3 m/s^2 per axis -> 1e-3 on |a|
    EXPECT_NEAR(wide[i], std::hypot(bare[i], 4e-3), 1e-12);
  }
}

TEST(AccelSolverTest, BsasIsDeterministicAndNeverWorseThanItsStart) {
  for (const uint64_t seed : {1, 2, 3, 4, 5}) {
    SCOPED_TRACE(absl::StrFormat("seed %d", seed));
    const AccelParams truth = RandomTruth(seed, true, false);
    const std::vector<AccelPose> poses = NoisyPoses(truth, seed, 30, 1e-3, 0.0);
    const absl::StatusOr<AccelParams> start = FitEllipsoid(poses, kG);
    ASSERT_TRUE(start.ok()) << start.status();
    AccelVector unit;
    unit << Eigen::Vector3d::Constant(1e-3), Eigen::Vector3d::Constant(1e-4),
        Eigen::Vector3d::Constant(1e-4), Eigen::Vector3d::Constant(1e-5);
    BsasStageOptions options;
    options.seed = seed;
    StageReport r1, r2;
    const AccelParams a = RefineAccelBsas(*start, poses, kG, AllFree(), unit, options, &r1);
    const AccelParams b = RefineAccelBsas(*start, poses, kG, AllFree(), unit, options, &r2);
    const AccelVector va = PackAccel(a), vb = PackAccel(b);
    for (int c = 0; c < kAccelParams; ++c) EXPECT_EQ(va(c), vb(c)) << AccelParamName(c);
    EXPECT_EQ(a.frame_angles, start->frame_angles);
    EXPECT_EQ(r1.name, "bsas");
    EXPECT_EQ(r1.iterations, r2.iterations);
    EXPECT_EQ(r1.evaluations, r2.evaluations);
    EXPECT_EQ(r1.accel_rms_m_s2, r2.accel_rms_m_s2);
    // The cost BSAS minimises (weights from the start) never increases.
    const std::vector<double> sigma = MagnitudeSigmas(*start, poses);
    EXPECT_LE(WeightedCost(a, poses, sigma), WeightedCost(*start, poses, sigma));
    // Parameters held fixed stay exactly at the start.
    AccelMask linear = LinearFree();
    const AccelParams c = RefineAccelBsas(*start, poses, kG, linear, unit, options, nullptr);
    EXPECT_EQ(c.quadratic, start->quadratic);
    EXPECT_LE(WeightedCost(c, poses, sigma), WeightedCost(*start, poses, sigma));
  }
}

TEST(AccelSolverTest, HeldOutResidualsExceedInSampleOnNoisyPoses) {
  const AccelParams truth = RandomTruth(6, false, false);
  const std::vector<AccelPose> poses = NoisyPoses(truth, 6, 20, 2e-3, 0.0);
  const absl::StatusOr<AccelParams> start = FitEllipsoid(poses, kG);
  ASSERT_TRUE(start.ok()) << start.status();
  const absl::StatusOr<LmResult> lm = RefineAccelLm(*start, poses, kG, LinearFree(), nullptr);
  ASSERT_TRUE(lm.ok()) << lm.status();
  const double in_sample = Rms(MagnitudeResiduals(lm->params, poses, kG));
  const std::vector<double> held = HeldOutMagnitudeResiduals(lm->params, poses, kG, LinearFree());
  ASSERT_EQ(held.size(), poses.size());
  for (double h : held) EXPECT_TRUE(std::isfinite(h));
  const double held_rms = Rms(held);
  EXPECT_GT(held_rms, in_sample);
  // PRESS is the first-order version of the same figure.
  EXPECT_NEAR(PressRms(lm->params, poses, kG, LinearFree()), held_rms, 0.1 * held_rms);
}

}  // namespace
}  // namespace imucal::core
