#include "core/crb.h"

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "Eigen/Core"
#include "core/accel_solver.h"
#include "core/model.h"
#include "gtest/gtest.h"

namespace imucal::core {
namespace {

constexpr double kG = 9.80665;
constexpr uint64_t kSeed = 20240611;

// A MEMS-like truth in m/s^2 input units (magnitudes as RandomTruth's one-sigma values).
AccelParams Truth() {
  AccelParams p;
  p.bias = Eigen::Vector3d(0.31, -0.22, 0.45);
  p.scale = Eigen::Vector3d(1.012, 0.991, 1.004);
  p.tri_angles = Eigen::Vector3d(2.5e-3, -3.1e-3, 1.7e-3);
  p.frame_angles = Eigen::Vector3d(0.01, -0.005, 0.008);
  p.quadratic = Eigen::Vector3d(3e-5, -2e-5, 4e-5);
  return p;
}

// `n` orientations uniform on the sphere (deterministic), read by `truth` without noise; each
// mean averages `samples` readings of per-axis std `noise_m_s2`.
std::vector<AccelPose> PosesAtTruth(const AccelParams& truth, int n, double samples,
                                    double noise_m_s2, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::vector<AccelPose> poses;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d up = Eigen::Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
    AccelPose pose;
    pose.mean = truth.Invert(kG * up);
    // Raw noise that gives about noise_m_s2 on the calibrated output (as the simulator draws it).
    pose.mean_std = (noise_m_s2 / std::sqrt(samples)) * truth.scale.cwiseInverse();
    poses.push_back(pose);
  }
  return poses;
}

AccelMask AllFree() {
  AccelMask m{};
  m.fill(true);
  return m;
}

// The acceptance property: over many noise draws the spread of the LM estimates is what the
// bound says. Noise is small (0.5 mg per pose mean), so the problem is linear to high accuracy and
// LM, the maximum-likelihood estimator here, is efficient: empirical std == CRB up to sampling
// error (1/sqrt(2 * 400) = 3.5 % for 400 draws), well inside the 20 % tolerance.
TEST(CrbTest, MatchesEmpiricalStdOfLmEstimates) {
  SCOPED_TRACE(testing::Message() << "seed " << kSeed);
  const AccelParams truth = Truth();
  const std::vector<AccelPose> poses = PosesAtTruth(truth, 36, 100.0, 0.05, kSeed);
  const AccelVector crb = AccelCramerRaoStd(truth, poses, kG, AllFree());

  constexpr int kDraws = 400;
  std::mt19937_64 rng(kSeed + 1);
  std::normal_distribution<double> normal(0.0, 1.0);
  AccelVector sum = AccelVector::Zero(), sum_sq = AccelVector::Zero();
  const AccelVector theta_true = PackAccel(truth);
  for (int draw = 0; draw < kDraws; ++draw) {
    std::vector<AccelPose> noisy = poses;
    for (AccelPose& pose : noisy) {
      for (int a = 0; a < 3; ++a) pose.mean(a) += pose.mean_std(a) * normal(rng);
    }
    const auto fit = RefineAccelLm(truth, noisy, kG, AllFree(), nullptr);
    ASSERT_TRUE(fit.ok()) << fit.status();
    const AccelVector e = PackAccel(fit->params) - theta_true;
    sum += e;
    sum_sq += e.cwiseAbs2();
  }
  const AccelVector mean = sum / kDraws;
  const AccelVector empirical = ((sum_sq - kDraws * mean.cwiseAbs2()) / (kDraws - 1)).cwiseSqrt();
  for (int c = 0; c < kAccelParams; ++c) {
    SCOPED_TRACE(AccelParamName(c));
    ASSERT_TRUE(std::isfinite(crb(c)) && crb(c) > 0);
    EXPECT_NEAR(empirical(c) / crb(c), 1.0, 0.2)
        << "empirical " << empirical(c) << " crb " << crb(c);
    // Unbiased to well within the spread (the bound is for unbiased estimators).
    EXPECT_LT(std::abs(mean(c)), 4 * crb(c) / std::sqrt(kDraws) + 1e-3 * crb(c));
  }
}

// sigma_i is proportional to mean_std, so four times the samples per pose halves every bound.
TEST(CrbTest, ShrinksAsOneOverSqrtSamplesPerPose) {
  const AccelParams truth = Truth();
  const AccelVector few =
      AccelCramerRaoStd(truth, PosesAtTruth(truth, 30, 200, 0.02, kSeed), kG, AllFree());
  const AccelVector many =
      AccelCramerRaoStd(truth, PosesAtTruth(truth, 30, 800, 0.02, kSeed), kG, AllFree());
  for (int c = 0; c < kAccelParams; ++c) {
    SCOPED_TRACE(AccelParamName(c));
    EXPECT_NEAR(few(c) / many(c), 2.0, 1e-9);
  }
}

// More poses never loosen the bound (information only adds).
TEST(CrbTest, MorePosesNeverLoosen) {
  const AccelParams truth = Truth();
  const std::vector<AccelPose> poses = PosesAtTruth(truth, 40, 400, 0.02, kSeed);
  const std::vector<AccelPose> first(poses.begin(), poses.begin() + 20);
  const AccelVector all = AccelCramerRaoStd(truth, poses, kG, AllFree());
  const AccelVector part = AccelCramerRaoStd(truth, first, kG, AllFree());
  for (int c = 0; c < kAccelParams; ++c) EXPECT_LE(all(c), part(c) * (1 + 1e-12)) << c;
}

TEST(CrbTest, FixedParametersAreNanAndFixingNeverLoosensTheRest) {
  const AccelParams truth = Truth();
  const std::vector<AccelPose> poses = PosesAtTruth(truth, 30, 400, 0.02, kSeed);
  AccelMask linear = AllFree();
  for (int c = 9; c < 12; ++c) linear[static_cast<size_t>(c)] = false;
  const AccelVector free_all = AccelCramerRaoStd(truth, poses, kG, AllFree());
  const AccelVector free_linear = AccelCramerRaoStd(truth, poses, kG, linear);
  for (int c = 0; c < kAccelParams; ++c) {
    SCOPED_TRACE(AccelParamName(c));
    if (c >= 9) {
      EXPECT_TRUE(std::isnan(free_linear(c)));
    } else {
      ASSERT_TRUE(std::isfinite(free_linear(c)));
      // Knowing the quadratic terms can only help the others.
      EXPECT_LE(free_linear(c), free_all(c) * (1 + 1e-12));
    }
  }
  AccelMask none{};
  const AccelVector nothing = AccelCramerRaoStd(truth, poses, kG, none);
  for (int c = 0; c < kAccelParams; ++c) EXPECT_TRUE(std::isnan(nothing(c))) << c;
}

// Pose mean noise only: a fitted model error on the poses does not change the bound.
TEST(CrbTest, IgnoresModelSigma) {
  const AccelParams truth = Truth();
  std::vector<AccelPose> poses = PosesAtTruth(truth, 30, 400, 0.02, kSeed);
  const AccelVector bare = AccelCramerRaoStd(truth, poses, kG, AllFree());
  for (AccelPose& pose : poses) pose.model_sigma_m_s2 = 0.01;
  const AccelVector with_tau = AccelCramerRaoStd(truth, poses, kG, AllFree());
  for (int c = 0; c < kAccelParams; ++c) EXPECT_EQ(bare(c), with_tau(c)) << c;
}

// Poses that all point the same way cannot separate bias from scale: no finite bound.
TEST(CrbTest, UndeterminedSetIsInfinite) {
  const AccelParams truth = Truth();
  std::vector<AccelPose> poses;
  for (int i = 0; i < 20; ++i) {
    AccelPose pose;
    pose.mean = truth.Invert(Eigen::Vector3d(0, 0, kG));
    pose.mean_std = Eigen::Vector3d::Constant(1e-3);
    poses.push_back(pose);
  }
  const AccelVector crb = AccelCramerRaoStd(truth, poses, kG, AllFree());
  for (int c = 0; c < kAccelParams; ++c) EXPECT_TRUE(std::isinf(crb(c))) << c;
}

}  // namespace
}  // namespace imucal::core
