#include "core/robust_covariance.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Eigenvalues"
#include "Eigen/LU"
#include "gtest/gtest.h"

namespace imucal::core {
namespace {

constexpr uint64_t kSeed = 20261129;

double MinEigenvalue(const Eigen::MatrixXd& m) {
  return Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(0.5 * (m + m.transpose()))
      .eigenvalues()
      .minCoeff();
}

// A straight line y = a + b x fitted by ordinary least squares to n points, its errors drawn by
// `noise(i, x, rng)`. Returns (the slope's error, its textbook SE, its robust SE).
struct SlopeFit {
  double error, textbook_se, robust_se;
};

template <typename Noise>
SlopeFit FitLine(int n, Noise noise, std::mt19937_64* rng) {
  Eigen::MatrixXd j(n, 2);
  Eigen::VectorXd y(n);
  double previous = 0;
  for (int i = 0; i < n; ++i) {
    const double x = -1.0 + 2.0 * i / (n - 1);
    j(i, 0) = 1, j(i, 1) = x;
    previous = noise(x, previous, rng);
    y(i) = 0.5 + 2.0 * x + previous;  // truth: a = 0.5, b = 2
  }
  const Eigen::MatrixXd p = (j.transpose() * j).inverse();
  const Eigen::Vector2d theta = p * j.transpose() * y;
  const Eigen::VectorXd r = j * theta - y;
  const Eigen::MatrixXd model = p * r.squaredNorm() / (n - 2);
  std::vector<ObservationBlock> blocks;
  for (int i = 0; i < n; ++i) blocks.push_back({j.row(i), r.segment(i, 1)});
  const Eigen::MatrixXd robust = RobustCovariance(p, blocks, Eigen::MatrixXd::Zero(2, 2), model);
  return {theta(1) - 2.0, std::sqrt(model(1, 1)), std::sqrt(robust(1, 1))};
}

// Over many fits: the RMS of the slope's error over each SE (1 when the SE is honest).
template <typename Noise>
std::pair<double, double> ZRms(int n, Noise noise) {
  std::mt19937_64 rng(kSeed);
  double textbook = 0, robust = 0;
  constexpr int kTrials = 2000;
  for (int t = 0; t < kTrials; ++t) {
    const SlopeFit f = FitLine(n, noise, &rng);
    textbook += std::pow(f.error / f.textbook_se, 2);
    robust += std::pow(f.error / f.robust_se, 2);
  }
  return {std::sqrt(textbook / kTrials), std::sqrt(robust / kTrials)};
}

TEST(RobustCovarianceTest, ErrorsThatGrowWithTheLeverOverwhelmTheTextbookButNotTheSandwich) {
  // The error's sigma grows with |x|, as a move's error grows with its angle.
  const auto [textbook, robust] = ZRms(40, [](double x, double, std::mt19937_64* rng) {
    return std::normal_distribution<double>(0.0, 0.05 + std::abs(x))(*rng);
  });
  RecordProperty("textbook", std::to_string(textbook));
  RecordProperty("robust", std::to_string(robust));
  EXPECT_GT(textbook, 1.25);  // the textbook SE claims too much (1.36 with this seed)
  // A noisy SE leaves an RMS above 1 even when its variance is right (E[1/s^2] > 1/E[s^2]):
  // 1.17 with this seed.
  EXPECT_GT(robust, 0.9);
  EXPECT_LT(robust, 1.25);
  EXPECT_LT(robust, textbook - 0.1);
}

TEST(RobustCovarianceTest, NeighboursThatShareTheirErrorAreNotCountedTwice) {
  // AR(1) errors (rho 0.6) along x: each point's error carries on into the next, as poses share
  // a drift.
  const auto [textbook, robust] = ZRms(40, [](double, double previous, std::mt19937_64* rng) {
    return 0.6 * previous + std::normal_distribution<double>(0.0, 0.1)(*rng);
  });
  RecordProperty("textbook", std::to_string(textbook));
  RecordProperty("robust", std::to_string(robust));
  EXPECT_GT(textbook, 1.5);  // 2.0 with this seed
  EXPECT_LT(robust, textbook - 0.25);  // the lags take back part of it: 1.63
}

TEST(RobustCovarianceTest, IndependentEqualErrorsKeepTheTextbookFigure) {
  const auto [textbook, robust] = ZRms(40, [](double, double, std::mt19937_64* rng) {
    return std::normal_distribution<double>(0.0, 0.1)(*rng);
  });
  EXPECT_NEAR(textbook, 1.0, 0.06);
  // Never below the textbook SE, and not much above: the price of the floor is small.
  EXPECT_LE(robust, textbook + 1e-12);
  EXPECT_GT(robust, 0.8);
}

TEST(RobustCovarianceTest, TheUpperBoundIsAtLeastBothInEveryDirection) {
  std::mt19937_64 rng(kSeed);
  std::normal_distribution<double> n01;
  for (int trial = 0; trial < 50; ++trial) {
    Eigen::MatrixXd x(4, 4), y(4, 4);
    for (int i = 0; i < 16; ++i) x(i) = n01(rng), y(i) = n01(rng);
    const Eigen::MatrixXd a = x * x.transpose(), b = y * y.transpose();
    const Eigen::MatrixXd c = LoewnerUpperBound(a, b);
    EXPECT_GT(MinEigenvalue(c - a), -1e-9);
    EXPECT_GT(MinEigenvalue(c - b), -1e-9);
  }
}

TEST(RobustCovarianceTest, NeweyWestLagsGrowSlowly) {
  EXPECT_EQ(NeweyWestLags(5), 2u);
  EXPECT_EQ(NeweyWestLags(40), 3u);
  EXPECT_EQ(NeweyWestLags(100), 4u);
}

}  // namespace
}  // namespace imucal::core
