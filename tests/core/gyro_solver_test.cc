#include "core/gyro_solver.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/status.h"
#include "core/model.h"
#include "gtest/gtest.h"

namespace imucal::core {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr uint64_t kSeed = 20140531;  // every test uses this seed (printed on failure)

// A true gyro matrix [rad/s per input unit]: `scale` times (per-axis scale errors of 1-3% and
// misalignment of a few mrad).
Eigen::Matrix3d TrueMatrix(double scale) {
  Eigen::Matrix3d m;
  m << 1.021, -0.0035, 0.0042,  //
      0.0028, 0.987, -0.0051,   //
      -0.0019, 0.0046, 1.013;
  return scale * m;
}

struct SyntheticConfig {
  Eigen::Matrix3d matrix = TrueMatrix(1.0);
  Eigen::Vector3d bias = Eigen::Vector3d(0.012, -0.021, 0.008);  // input unit
  Eigen::Vector3d bias_drift = Eigen::Vector3d::Zero();          // input unit per second
  double rate_hz = 200.0;
  int num_moves = 20;
  double static_s = 1.0;
  double gyro_noise = 0.0;     // per-sample standard deviation, input unit
  double up_noise_rad = 0.0;   // per-axis standard deviation of the measured up directions
  bool single_axis_z = false;  // every move rotates about body z
  uint64_t seed = kSeed;
};

struct Synthetic {
  std::vector<double> t_s;
  std::vector<Eigen::Vector3d> gyro_raw;
  std::vector<GyroMove> moves;
};

Eigen::Vector3d RandomUnit(std::mt19937_64& rng) {
  std::normal_distribution<double> normal;
  return Eigen::Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
}

Eigen::Vector3d Perturbed(const Eigen::Vector3d& up, double sigma, std::mt19937_64& rng) {
  if (sigma == 0.0) return up;
  std::normal_distribution<double> normal(0.0, sigma);
  return ExpSo3<double>(Eigen::Vector3d(normal(rng), normal(rng), normal(rng))) * up;
}

// A capture of static poses joined by constant-axis rotations: each move turns by theta about a
// body axis with the raised-cosine rate theta / T (1 - cos(2 pi t / T)), zero at both static
// ends. Raw samples u = M^-1 w + b(t) + noise; up directions from the true orientations.
Synthetic MakeCapture(const SyntheticConfig& config) {
  std::mt19937_64 rng(config.seed);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, config.gyro_noise);
  const Eigen::Matrix3d m_inverse = config.matrix.inverse();
  const double dt = 1.0 / config.rate_hz;
  const int static_samples = static_cast<int>(std::lround(config.static_s * config.rate_hz));
  const Eigen::Vector3d up_world = Eigen::Vector3d::UnitZ();

  Synthetic out;
  auto push = [&](const Eigen::Vector3d& rate_rad_s) {
    const double t = static_cast<double>(out.t_s.size()) * dt;
    Eigen::Vector3d u = m_inverse * rate_rad_s + config.bias + config.bias_drift * t;
    if (config.gyro_noise > 0.0) u += Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
    out.t_s.push_back(t);
    out.gyro_raw.push_back(u);
  };
  // Body z tilted by ~55 degrees from up, so that rotations about it change `up`.
  Eigen::Matrix3d r_world_body = ExpSo3<double>(Eigen::Vector3d(0.8, 0.5, 0.1));
  if (!config.single_axis_z) r_world_body = ExpSo3<double>(2.0 * RandomUnit(rng)) * r_world_body;
  Eigen::Vector3d previous_static_mean = Eigen::Vector3d::Zero();
  for (int pose = 0; pose <= config.num_moves; ++pose) {
    const size_t first = out.gyro_raw.size();
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (int i = 0; i < static_samples; ++i) {
      push(Eigen::Vector3d::Zero());
      sum += out.gyro_raw.back();
    }
    const Eigen::Vector3d static_mean = sum / static_samples;
    const Eigen::Vector3d up_body =
        Perturbed(r_world_body.transpose() * up_world, config.up_noise_rad, rng);
    if (pose > 0) {  // close the move that led here
      GyroMove& move = out.moves.back();
      move.end = first;
      move.up_after = up_body;
      move.bias_before = previous_static_mean;
      move.bias_after = static_mean;
    }
    if (pose == config.num_moves) break;
    GyroMove move;
    move.begin = out.gyro_raw.size() - 1;
    move.up_before = up_body;
    out.moves.push_back(move);
    previous_static_mean = static_mean;

    const Eigen::Vector3d axis = config.single_axis_z ? Eigen::Vector3d::UnitZ() : RandomUnit(rng);
    const double sign = (config.single_axis_z && uniform(rng) < 0.5) ? -1.0 : 1.0;
    const double theta = sign * (kPi / 3.0 + uniform(rng) * 2.0 * kPi / 3.0);
    const int n = static_cast<int>(std::lround((1.5 + 1.5 * uniform(rng)) * config.rate_hz));
    const double duration = n * dt;
    for (int j = 1; j < n; ++j) {
      const double rate = theta / duration * (1.0 - std::cos(2.0 * kPi * j / n));
      push(rate * axis);
    }
    r_world_body = r_world_body * ExpSo3<double>(theta * axis);
  }
  return out;
}

double RelativeError(const Eigen::Matrix3d& estimate, const Eigen::Matrix3d& truth) {
  return (estimate - truth).norm() / truth.norm();
}

double Mean(const std::vector<double>& v) {
  return std::accumulate(v.begin(), v.end(), 0.0) / static_cast<double>(v.size());
}

GyroSolveOptions OptionsFor(const SyntheticConfig& config, double nominal_scale) {
  GyroSolveOptions options;
  options.initial_matrix = nominal_scale * Eigen::Matrix3d::Identity();
  options.bias = config.bias;
  return options;
}

TEST(GyroSolverTest, NoiseFreeRecoveryIsExact) {
  SCOPED_TRACE(testing::Message() << "seed " << kSeed);
  const SyntheticConfig config;
  const Synthetic data = MakeCapture(config);
  const absl::StatusOr<GyroSolveResult> result =
      SolveGyroFromMoves(data.t_s, data.gyro_raw, data.moves, OptionsFor(config, 1.0));
  ASSERT_TRUE(result.ok()) << result.status();
  EXPECT_LT(RelativeError(result->matrix, config.matrix), 1e-6) << result->matrix;
  EXPECT_FALSE(result->rank_deficient);
  EXPECT_TRUE(result->undetermined.empty());
  EXPECT_TRUE(result->converged);
  ASSERT_EQ(result->move_error_rad.size(), data.moves.size());
  for (double e : result->move_error_rad) EXPECT_LT(e, 1e-8);
  // A fixed model evaluated on a move: the true matrix predicts the measured up.
  for (const GyroMove& move : data.moves) {
    const Eigen::Vector3d up = PredictUpAfterMove(data.t_s, data.gyro_raw, move, config.matrix,
                                                  config.bias, /*interpolate_bias=*/false);
    EXPECT_LT((up - move.up_after).norm(), 1e-10);
  }
}

TEST(GyroSolverTest, AnalyticJacobianMatchesCentralDifferences) {
  SCOPED_TRACE(testing::Message() << "seed " << kSeed);
  SyntheticConfig config;
  config.num_moves = 4;
  config.bias_drift = Eigen::Vector3d(1e-3, -2e-3, 5e-4);
  const Synthetic data = MakeCapture(config);
  // Away from the solution (residuals of ~0.1 rad), where a wrong Jacobian cannot hide.
  const Eigen::Matrix3d m =
      config.matrix * ExpSo3<double>(Eigen::Vector3d(0.05, -0.03, 0.04)) * 1.06;
  for (bool interpolate : {false, true}) {
    for (const GyroMove& move : data.moves) {
      Eigen::Matrix<double, 3, 9> analytic;
      const Eigen::Vector3d r0 =
          GyroMoveResidual(data.t_s, data.gyro_raw, move, m, config.bias, interpolate, &analytic);
      EXPECT_GT(r0.norm(), 1e-2);
      Eigen::Matrix<double, 3, 9> numeric;
      const double h = 1e-6;
      for (int i = 0; i < 9; ++i) {
        Eigen::Matrix3d plus = m, minus = m;
        plus.data()[i] += h;
        minus.data()[i] -= h;
        numeric.col(i) = (GyroMoveResidual(data.t_s, data.gyro_raw, move, plus, config.bias,
                                           interpolate, nullptr) -
                          GyroMoveResidual(data.t_s, data.gyro_raw, move, minus, config.bias,
                                           interpolate, nullptr)) /
                         (2.0 * h);
      }
      EXPECT_LT((analytic - numeric).norm(), 1e-7 * analytic.norm()) << "analytic\n"
                                                                     << analytic << "\nnumeric\n"
                                                                     << numeric;
    }
  }
}

TEST(GyroSolverTest, NoisyRecoveryIsConsistentWithCovariance) {
  SCOPED_TRACE(testing::Message() << "seed " << kSeed);
  SyntheticConfig config;
  config.num_moves = 37;
  config.gyro_noise = 0.005;  // rad/s per sample at 200 Hz (input unit = rad/s here)
  config.up_noise_rad = 3e-4;
  const Synthetic data = MakeCapture(config);
  const absl::StatusOr<GyroSolveResult> result =
      SolveGyroFromMoves(data.t_s, data.gyro_raw, data.moves, OptionsFor(config, 1.0));
  ASSERT_TRUE(result.ok()) << result.status();
  EXPECT_FALSE(result->rank_deficient);
  const Eigen::Matrix3d error = result->matrix - config.matrix;
  for (int i = 0; i < 9; ++i) {
    const double sigma = std::sqrt(result->covariance(i, i));
    ASSERT_TRUE(std::isfinite(sigma));
    EXPECT_GT(sigma, 0.0);
    EXPECT_LT(sigma, 5e-3);  // noise this small determines M to well below 1%
    EXPECT_LT(std::abs(error.data()[i]), 4.0 * sigma) << "entry " << i;
  }
  // The covariance is symmetric positive definite.
  EXPECT_LT((result->covariance - result->covariance.transpose()).norm(),
            1e-12 * result->covariance.norm());
  EXPECT_GT(result->covariance.selfadjointView<Eigen::Lower>().ldlt().vectorD().minCoeff(), 0.0);
}

TEST(GyroSolverTest, HeldOutErrorsExceedInSampleAndMatchExactLeaveOneOut) {
  SCOPED_TRACE(testing::Message() << "seed " << kSeed);
  SyntheticConfig config;
  config.num_moves = 15;
  config.gyro_noise = 0.005;
  config.up_noise_rad = 3e-4;
  const Synthetic data = MakeCapture(config);
  const GyroSolveOptions options = OptionsFor(config, 1.0);
  const absl::StatusOr<GyroSolveResult> result =
      SolveGyroFromMoves(data.t_s, data.gyro_raw, data.moves, options);
  ASSERT_TRUE(result.ok()) << result.status();
  ASSERT_EQ(result->heldout_error_rad.size(), data.moves.size());
  EXPECT_GT(Mean(result->heldout_error_rad), Mean(result->move_error_rad));
  // The first-order LOO against full re-solves without the move, for a few moves.
  for (size_t i = 0; i < 3; ++i) {
    std::vector<GyroMove> others = data.moves;
    others.erase(others.begin() + static_cast<std::ptrdiff_t>(i));
    const absl::StatusOr<GyroSolveResult> without =
        SolveGyroFromMoves(data.t_s, data.gyro_raw, others, options);
    ASSERT_TRUE(without.ok()) << without.status();
    const Eigen::Vector3d up = PredictUpAfterMove(data.t_s, data.gyro_raw, data.moves[i],
                                                  without->matrix, config.bias, false);
    const double exact =
        std::atan2(up.cross(data.moves[i].up_after).norm(), up.dot(data.moves[i].up_after));
    EXPECT_NEAR(result->heldout_error_rad[i], exact, 0.01 * exact) << "move " << i;
  }
}

TEST(GyroSolverTest, FindsCountsScaleWithoutAHint) {
  SCOPED_TRACE(testing::Message() << "seed " << kSeed);
  SyntheticConfig config;
  constexpr double kCountsPerRadS = 938.7;
  config.matrix = TrueMatrix(1.0 / kCountsPerRadS);
  config.bias = Eigen::Vector3d(32768.0 + 14.0, 32768.0 - 37.0, 32768.0 + 5.0);
  const Synthetic data = MakeCapture(config);
  GyroSolveOptions options;
  options.bias = config.bias;
  options.scale_unknown = true;  // initial_matrix (identity: 938.7x too large) is ignored

  const double scale = EstimateIsotropicScale(data.t_s, data.gyro_raw, data.moves, options);
  EXPECT_NEAR(scale * kCountsPerRadS, 1.0, 0.05);

  const absl::StatusOr<GyroSolveResult> result =
      SolveGyroFromMoves(data.t_s, data.gyro_raw, data.moves, options);
  ASSERT_TRUE(result.ok()) << result.status();
  EXPECT_DOUBLE_EQ(result->initial_scale, scale);
  EXPECT_LT(RelativeError(result->matrix, config.matrix), 1e-6) << result->matrix;
}

TEST(GyroSolverTest, InterpolatedBiasFollowsALinearDrift) {
  SCOPED_TRACE(testing::Message() << "seed " << kSeed);
  SyntheticConfig config;
  // 0.02 rad/s of drift over the ~80 s capture: far beyond what a constant bias absorbs.
  config.bias_drift = Eigen::Vector3d(2.5e-4, -1.5e-4, 2e-4);
  const Synthetic data = MakeCapture(config);
  GyroSolveOptions options = OptionsFor(config, 1.0);
  options.bias = data.moves.front().bias_before;  // the first static mean

  const absl::StatusOr<GyroSolveResult> constant =
      SolveGyroFromMoves(data.t_s, data.gyro_raw, data.moves, options);
  options.interpolate_bias = true;
  const absl::StatusOr<GyroSolveResult> interpolated =
      SolveGyroFromMoves(data.t_s, data.gyro_raw, data.moves, options);
  ASSERT_TRUE(constant.ok()) << constant.status();
  ASSERT_TRUE(interpolated.ok()) << interpolated.status();
  // The static means sit at the middle of each pose, not at the move's ends, but the resulting
  // rate error is antisymmetric over the move and nearly cancels.
  const double interpolated_error = RelativeError(interpolated->matrix, config.matrix);
  const double constant_error = RelativeError(constant->matrix, config.matrix);
  EXPECT_LT(interpolated_error, 1e-4);
  EXPECT_GT(constant_error, 30.0 * interpolated_error);
  EXPECT_GT(Mean(constant->move_error_rad), 30.0 * Mean(interpolated->move_error_rad));
}

TEST(GyroSolverTest, RotationsAboutOneAxisAreFlaggedRankDeficient) {
  for (double noise : {0.0, 0.005}) {
    SCOPED_TRACE(testing::Message() << "seed " << kSeed << " noise " << noise);
    SyntheticConfig config;
    config.single_axis_z = true;
    config.gyro_noise = noise;
    const Synthetic data = MakeCapture(config);
    const absl::StatusOr<GyroSolveResult> result =
        SolveGyroFromMoves(data.t_s, data.gyro_raw, data.moves, OptionsFor(config, 1.0));
    ASSERT_TRUE(result.ok()) << result.status();
    EXPECT_TRUE(result->rank_deficient);
    EXPECT_EQ(result->undetermined,
              (std::vector<std::string>{"gyro matrix column x (rotations about x)",
                                        "gyro matrix column y (rotations about y)"}));
    // What the moves do determine: the calibrated rate for the excited raw direction.
    const Eigen::Vector3d excited = config.matrix.inverse() * Eigen::Vector3d::UnitZ();
    EXPECT_LT((result->matrix * excited - Eigen::Vector3d::UnitZ()).norm(),
              noise == 0.0 ? 1e-6 : 5e-3);
    for (int i = 0; i < 6; ++i) EXPECT_TRUE(std::isnan(result->covariance(i, i)));
    for (int i = 6; i < 9; ++i) EXPECT_TRUE(std::isfinite(result->covariance(i, i)));
  }
}

TEST(GyroSolverTest, BadInputsGiveTheRightCodes) {
  SyntheticConfig config;
  config.num_moves = 4;
  const Synthetic data = MakeCapture(config);
  const GyroSolveOptions options = OptionsFor(config, 1.0);
  auto code = [&](const std::vector<double>& t, const std::vector<Eigen::Vector3d>& u,
                  const std::vector<GyroMove>& moves, const GyroSolveOptions& o) {
    return SolveGyroFromMoves(t, u, moves, o).status().code();
  };
  EXPECT_EQ(code(data.t_s, data.gyro_raw, data.moves, options), absl::StatusCode::kOk);

  const std::vector<GyroMove> two(data.moves.begin(), data.moves.begin() + 2);
  EXPECT_EQ(code(data.t_s, data.gyro_raw, two, options), absl::StatusCode::kFailedPrecondition);

  std::vector<GyroMove> moves = data.moves;
  moves[1].end = data.gyro_raw.size();
  EXPECT_EQ(code(data.t_s, data.gyro_raw, moves, options), absl::StatusCode::kInvalidArgument);
  moves = data.moves;
  moves[2].begin = moves[2].end;
  EXPECT_EQ(code(data.t_s, data.gyro_raw, moves, options), absl::StatusCode::kInvalidArgument);
  moves = data.moves;
  moves[0].up_after = Eigen::Vector3d::Zero();
  EXPECT_EQ(code(data.t_s, data.gyro_raw, moves, options), absl::StatusCode::kInvalidArgument);

  std::vector<double> t = data.t_s;
  t[t.size() / 2] = t[t.size() / 2 - 1];
  EXPECT_EQ(code(t, data.gyro_raw, data.moves, options), absl::StatusCode::kInvalidArgument);
  t.pop_back();
  EXPECT_EQ(code(t, data.gyro_raw, data.moves, options), absl::StatusCode::kInvalidArgument);

  std::vector<Eigen::Vector3d> u = data.gyro_raw;
  u[data.moves[3].begin + 1].x() = std::nan("");
  EXPECT_EQ(code(data.t_s, u, data.moves, options), absl::StatusCode::kInvalidArgument);

  GyroSolveOptions bad = options;
  bad.max_iterations = 0;
  EXPECT_EQ(code(data.t_s, data.gyro_raw, data.moves, bad), absl::StatusCode::kInvalidArgument);
  bad = options;
  bad.initial_matrix.col(2).setZero();
  EXPECT_EQ(code(data.t_s, data.gyro_raw, data.moves, bad), absl::StatusCode::kInvalidArgument);

  // The Ceres-free helpers do not fail: NaN for a move they cannot integrate.
  EXPECT_TRUE(
      PredictUpAfterMove(data.t_s, data.gyro_raw, moves[2], config.matrix, config.bias, false)
          .allFinite());
  moves[2].end = data.gyro_raw.size() + 5;
  EXPECT_TRUE(
      PredictUpAfterMove(data.t_s, data.gyro_raw, moves[2], config.matrix, config.bias, false)
          .hasNaN());
  EXPECT_TRUE(std::isnan(EstimateIsotropicScale(data.t_s, data.gyro_raw, moves, options)));
}

}  // namespace
}  // namespace imucal::core
