#include "core/bsas.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "Eigen/Core"
#include "gtest/gtest.h"

namespace imucal::core {
namespace {

Eigen::VectorXd Filled(int n, double v) { return Eigen::VectorXd::Constant(n, v); }

// Bitwise equality: the reproducibility guarantee is bit-identical, not approximately equal.
bool SameBits(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return a.size() == b.size() &&
         std::memcmp(a.data(), b.data(), sizeof(double) * static_cast<size_t>(a.size())) == 0;
}

// An ill-conditioned but well-scaled convex quadratic with its minimum at `center`.
struct Quadratic {
  Eigen::VectorXd center;
  Eigen::VectorXd weights;
  double operator()(const Eigen::VectorXd& x) const {
    return (x - center).cwiseAbs2().dot(weights);
  }
};

Quadratic MakeQuadratic(int n) {
  Quadratic q;
  q.center = Eigen::VectorXd::LinSpaced(n, -0.5, 0.7);
  q.weights = Eigen::VectorXd::LinSpaced(n, 0.5, 2.0);
  return q;
}

// Starting point 5 units (Euclidean) from the minimum.
Eigen::VectorXd StartFiveAway(const Quadratic& q) {
  Eigen::VectorXd offset = Eigen::VectorXd::LinSpaced(q.center.size(), 1.0, -1.0);
  offset(0) = 0.3;  // avoid a symmetric start
  return q.center + 5.0 * offset.normalized();
}

TEST(BsasTest, SameSeedIsBitIdenticalDifferentSeedTakesADifferentPath) {
  const Quadratic q = MakeQuadratic(6);
  const Eigen::VectorXd x0 = StartFiveAway(q);
  std::vector<Eigen::VectorXd> trace_a, trace_b, trace_c;
  const auto traced = [&q](std::vector<Eigen::VectorXd>* trace) {
    return [&q, trace](const Eigen::VectorXd& x) {
      trace->push_back(x);
      return q(x);
    };
  };
  BsasOptions options;
  options.seed = 42;
  const BsasResult a = MinimizeBsas(traced(&trace_a), x0, Filled(6, -10), Filled(6, 10), options);
  const BsasResult b = MinimizeBsas(traced(&trace_b), x0, Filled(6, -10), Filled(6, 10), options);
  options.seed = 43;
  const BsasResult c = MinimizeBsas(traced(&trace_c), x0, Filled(6, -10), Filled(6, 10), options);

  EXPECT_TRUE(SameBits(a.x, b.x));
  EXPECT_EQ(std::memcmp(&a.cost, &b.cost, sizeof(double)), 0);
  EXPECT_EQ(a.iterations, b.iterations);
  EXPECT_EQ(a.evaluations, b.evaluations);
  ASSERT_EQ(trace_a.size(), trace_b.size());
  for (size_t i = 0; i < trace_a.size(); ++i) {
    ASSERT_TRUE(SameBits(trace_a[i], trace_b[i])) << "evaluation " << i;
  }
  // Same start, so the first evaluation agrees; the second (a random antenna) must not.
  ASSERT_GE(trace_c.size(), 2u);
  EXPECT_TRUE(SameBits(trace_a[0], trace_c[0]));
  EXPECT_FALSE(SameBits(trace_a[1], trace_c[1]));
  EXPECT_FALSE(SameBits(a.x, c.x));
}

TEST(BsasTest, ConvergesOnConvexQuadraticInNormalisedUnits) {
  const Quadratic q = MakeQuadratic(12);
  const Eigen::VectorXd x0 = StartFiveAway(q);
  const double start_cost = q(x0);
  for (uint64_t seed = 1; seed <= 5; ++seed) {
    BsasOptions options;
    options.seed = seed;
    const BsasResult r = MinimizeBsas(q, x0, Filled(12, -10), Filled(12, 10), options);
    EXPECT_LT(r.cost, 1e-3 * start_cost) << "seed " << seed << " iterations " << r.iterations;
    EXPECT_DOUBLE_EQ(r.cost, q(r.x)) << "seed " << seed;
  }
}

TEST(BsasTest, NeverEvaluatesOutsideTheBounds) {
  // The unconstrained minimum lies outside the box, so the search presses against the bounds
  // and d = 3 antennae reach far past them.
  Quadratic q = MakeQuadratic(4);
  q.center = Eigen::Vector4d(3.0, -3.0, 0.5, 2.5);
  const Eigen::VectorXd lower = Eigen::Vector4d(-1.0, -2.0, -1.0, 0.0);
  const Eigen::VectorXd upper = Eigen::Vector4d(1.0, 0.0, 1.0, 2.0);
  const Eigen::VectorXd x0 = Eigen::Vector4d(0.0, -1.0, 0.0, 1.0);
  int outside = 0;
  const auto checked = [&](const Eigen::VectorXd& x) {
    for (int i = 0; i < 4; ++i) outside += (x(i) < lower(i) || x(i) > upper(i)) ? 1 : 0;
    return q(x);
  };
  BsasOptions options;
  options.seed = 7;
  const BsasResult r = MinimizeBsas(checked, x0, lower, upper, options);
  EXPECT_EQ(outside, 0);
  // The constrained minimum is the projection of the centre onto the box.
  EXPECT_NEAR(r.x(0), 1.0, 1e-9);
  EXPECT_NEAR(r.x(1), -2.0, 1e-9);
  EXPECT_NEAR(r.x(3), 2.0, 1e-9);
}

TEST(BsasTest, CountsEveryEvaluation) {
  const Quadratic q = MakeQuadratic(3);
  for (int k : {1, 3, 5}) {
    for (int max_iterations : {0, 1, 10, 200}) {
      int calls = 0;
      const auto counted = [&](const Eigen::VectorXd& x) {
        ++calls;
        return q(x);
      };
      BsasOptions options;
      options.k = k;
      options.max_iterations = max_iterations;
      const BsasResult r =
          MinimizeBsas(counted, Filled(3, 2.0), Filled(3, -5), Filled(3, 5), options);
      EXPECT_EQ(r.evaluations, calls) << "k " << k << " n " << max_iterations;
      EXPECT_EQ(r.evaluations, 1 + 3 * k * r.iterations);
      EXPECT_LE(r.iterations, max_iterations);
    }
  }
}

TEST(BsasTest, StopsWhenTheStepFallsBelowTolerance) {
  // A constant cost never improves, so every iteration fails and shrinks the step (at most
  // n_flag = 2 kept steps in a row): 0.8 * 0.95^m < 0.01 needs m = 86 shrinks, reached
  // within 86..258 iterations.
  int calls = 0;
  const auto flat = [&calls](const Eigen::VectorXd&) {
    ++calls;
    return 1.0;
  };
  BsasOptions options;
  options.max_iterations = 100000;
  const BsasResult r = MinimizeBsas(flat, Filled(2, 0.0), Filled(2, -1), Filled(2, 1), options);
  EXPECT_GE(r.iterations, 86);
  EXPECT_LE(r.iterations, 3 * 86);
  EXPECT_EQ(r.evaluations, calls);
  EXPECT_TRUE(SameBits(r.x, Filled(2, 0.0)));
}

TEST(BsasTest, NeverReturnsWorseThanTheStart) {
  // A rugged function (Rastrigin-like) started exactly at its global minimum: nothing improves
  // on x0, so x0 must come back with its cost.
  const auto rugged = [](const Eigen::VectorXd& x) {
    double s = 0.0;
    for (Eigen::Index i = 0; i < x.size(); ++i) {
      s += x(i) * x(i) + 3.0 * (1.0 - std::cos(6.0 * x(i)));
    }
    return s;
  };
  for (uint64_t seed = 1; seed <= 3; ++seed) {
    BsasOptions options;
    options.seed = seed;
    const BsasResult at_min =
        MinimizeBsas(rugged, Filled(5, 0.0), Filled(5, -4), Filled(5, 4), options);
    EXPECT_TRUE(SameBits(at_min.x, Filled(5, 0.0)));
    EXPECT_EQ(at_min.cost, 0.0);
    const Eigen::VectorXd x0 = Eigen::VectorXd::LinSpaced(5, -2.0, 2.5);
    const BsasResult r = MinimizeBsas(rugged, x0, Filled(5, -4), Filled(5, 4), options);
    EXPECT_LE(r.cost, rugged(x0));
    EXPECT_EQ(r.cost, rugged(r.x));
  }
}

TEST(BsasTest, NanCostsNeverWin) {
  // NaN on half the space: the search must neither move onto it nor report it.
  const auto half_nan = [](const Eigen::VectorXd& x) {
    return x(0) > 0.5 ? std::nan("") : (x(0) - 2.0) * (x(0) - 2.0) + x(1) * x(1);
  };
  BsasOptions options;
  const BsasResult r =
      MinimizeBsas(half_nan, Eigen::Vector2d(-1.0, 1.0), Filled(2, -3), Filled(2, 3), options);
  EXPECT_FALSE(std::isnan(r.cost));
  EXPECT_LE(r.x(0), 0.5);
  EXPECT_LT(r.cost, half_nan(Eigen::Vector2d(-1.0, 1.0)));
}

// A coupled problem: coordinate blocks of very different sensitivity (as scale, bias, angles
// and K2 are) with cross terms between blocks, so optimising one block with the others fixed
// leaves the cost above the joint minimum until the blocks are revisited.
struct Coupled {
  Eigen::MatrixXd a;
  Eigen::VectorXd center;
  double operator()(const Eigen::VectorXd& x) const {
    const Eigen::VectorXd e = x - center;
    return e.dot(a * e);
  }
};

Coupled MakeCoupled() {
  Coupled c;
  const int n = 8;
  Eigen::MatrixXd b(n, n);
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) b(i, j) = std::sin(1.0 + 3.0 * i + 7.0 * j);
  }
  c.a = 0.25 * b.transpose() * b + 0.5 * Eigen::MatrixXd::Identity(n, n);
  c.center = Eigen::VectorXd::LinSpaced(n, -1.0, 1.0);
  return c;
}

TEST(BsasTest, StagedImprovesOnACoupledProblem) {
  const Coupled c = MakeCoupled();
  const Eigen::VectorXd x0 = Filled(8, 2.0);
  const double start = c(x0);
  const std::vector<std::vector<int>> groups = {{0, 1}, {2, 3, 4}, {5}, {6, 7}};
  BsasOptions options;
  options.seed = 11;
  int calls = 0;
  const auto counted = [&](const Eigen::VectorXd& x) {
    ++calls;
    return c(x);
  };
  const BsasResult one_round =
      MinimizeBsasStaged(c, x0, Filled(8, -5), Filled(8, 5), groups, 1, 1e-6, options);
  const BsasResult staged =
      MinimizeBsasStaged(counted, x0, Filled(8, -5), Filled(8, 5), groups, 30, 1e-6, options);

  EXPECT_LT(one_round.cost, start);
  EXPECT_LT(staged.cost, one_round.cost);
  EXPECT_LT(staged.cost, 1e-3 * start);
  EXPECT_EQ(staged.cost, c(staged.x));
  EXPECT_EQ(staged.evaluations, calls);

  // Reproducible from the one seed; a different seed gives a different path.
  const BsasResult again =
      MinimizeBsasStaged(c, x0, Filled(8, -5), Filled(8, 5), groups, 30, 1e-6, options);
  EXPECT_TRUE(SameBits(staged.x, again.x));
  EXPECT_EQ(staged.evaluations, again.evaluations);
  options.seed = 12;
  const BsasResult other =
      MinimizeBsasStaged(c, x0, Filled(8, -5), Filled(8, 5), groups, 30, 1e-6, options);
  EXPECT_FALSE(SameBits(staged.x, other.x));
}

TEST(BsasTest, StagedLeavesUngroupedCoordinatesAndStopsOnSmallImprovement) {
  const Coupled c = MakeCoupled();
  const Eigen::VectorXd x0 = Filled(8, 2.0);
  // Coordinate 7 is in no group: it must stay at x0.
  const std::vector<std::vector<int>> groups = {{0, 1, 2, 3}, {4, 5, 6}};
  const BsasResult r =
      MinimizeBsasStaged(c, x0, Filled(8, -5), Filled(8, 5), groups, 50, 0.5, BsasOptions());
  EXPECT_EQ(r.x(7), 2.0);
  EXPECT_LT(r.cost, c(x0));
  // rel_tol = 0.5 stops as soon as a round fails to halve the cost: far fewer than 50 rounds
  // (each stage runs at most 200 iterations).
  EXPECT_LT(r.iterations, 50 * 2 * 200);
}

TEST(BsasTest, DerivedSeedsAreDistinct) {
  std::vector<uint64_t> seen;
  for (uint64_t stage = 0; stage < 64; ++stage) {
    const uint64_t s = DeriveBsasSeed(1, stage);
    for (uint64_t other : seen) ASSERT_NE(s, other) << "stage " << stage;
    seen.push_back(s);
  }
  EXPECT_NE(DeriveBsasSeed(1, 0), DeriveBsasSeed(2, 0));
}

}  // namespace
}  // namespace imucal::core
