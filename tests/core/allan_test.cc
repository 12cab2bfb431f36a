// Allan deviation (core/allan.h): the figures recovered from simulated noise of known density.
//
// White noise: the simulator draws a per-sample std sigma, so the density is N = sigma /
// sqrt(rate). Random walk: generated here, b_{k+1} = b_k + K sqrt(dt) n_k, whose Allan
// deviation is K sqrt(tau / 3). Bias instability: flicker built from a bank of Gauss-Markov
// processes (NoiseAxis below), whose Allan deviation is 0.664 B.
#include "core/allan.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <random>
#include <regex>
#include <vector>

#include "Eigen/Core"
#include "core/calibrate/calibrate.h"
#include "core/capture.h"
#include "core/noise_rest.h"
#include "core/simulator.h"
#include "formats/params_json.h"

namespace imucal::core {
namespace {

SimResult MustSimulate(const SimOptions& options) {
  absl::StatusOr<SimResult> r = Simulate(options);
  EXPECT_TRUE(r.ok()) << r.status();
  return r.ok() ? *std::move(r) : SimResult();
}

// Sample indices [begin, end) of the first static pose (the initial rest).
std::pair<size_t, size_t> RestRange(const SimResult& sim) {
  size_t begin = 0, end = 0;
  const SimPose& rest = sim.poses.front();
  while (begin < sim.capture.size() && sim.capture.t_s[begin] < rest.t_start_s) ++begin;
  end = begin;
  while (end < sim.capture.size() && sim.capture.t_s[end] <= rest.t_end_s) ++end;
  return {begin, end};
}

double MaxRelError(const Eigen::Vector3d& got, double want) {
  return ((got.array() - want).abs() / want).maxCoeff();
}

TEST(AllanTest, DiscreteStdIsDensityTimesSqrtRate) {
  // The first point (tau = one sample) of white noise is its per-sample std.
  std::mt19937_64 rng(7);
  std::normal_distribution<double> normal(0.0, 0.5);
  std::vector<double> x(200000);
  for (double& v : x) v = normal(rng);
  const std::vector<double> adev = OverlappingAllanDeviation(x, 400.0, {1, 4, 40});
  EXPECT_NEAR(adev[0], 0.5, 0.005);
  // N = sigma / sqrt(rate): adev(tau) = N / sqrt(tau) at every tau.
  const double density = 0.5 / std::sqrt(400.0);
  EXPECT_NEAR(adev[1], density / std::sqrt(4 / 400.0), 0.01);
  EXPECT_NEAR(adev[2], density / std::sqrt(40 / 400.0), 0.02);
}

TEST(AllanTest, LogSpacedClusterSizes) {
  const std::vector<size_t> m = LogSpacedClusterSizes(2001);
  ASSERT_FALSE(m.empty());
  EXPECT_EQ(m.front(), 1u);
  EXPECT_LE(m.back(), 1000u);
  EXPECT_GE(m.back(), 800u);
  EXPECT_TRUE(std::is_sorted(m.begin(), m.end()));
  EXPECT_TRUE(std::adjacent_find(m.begin(), m.end()) == m.end());
}

// Acceptance: white noise of known density recovered within 10% from the initial
// rest of a simulated capture, for several seeds and rates, calibrated with the true model.
TEST(AllanTest, WhiteNoiseDensityFromSimulatedRest) {
  double worst_accel = 0, worst_gyro = 0;
  for (double rate : {100.0, 200.0, 400.0}) {
    for (uint64_t seed : {1u, 2u, 3u}) {
      SimOptions o;
      o.seed = seed;
      o.rate_hz = rate;
      o.initial_rest_s = 30.0;
      o.accel_noise_m_s2 = 0.02;
      o.gyro_noise_rad_s = 0.002;
      o.temperature = false;
      const SimResult sim = MustSimulate(o);
      const auto [begin, end] = RestRange(sim);
      absl::StatusOr<NoiseAnalysis> na =
          ComputeNoise(sim.capture, begin, end, sim.truth.accel, sim.truth.gyro);
      ASSERT_TRUE(na.ok()) << na.status();
      const NoiseFigures& f = na->figures;
      EXPECT_NEAR(f.rate_hz, rate, 1e-6 * rate);
      const double accel_n = o.accel_noise_m_s2 / std::sqrt(rate);
      const double gyro_n = o.gyro_noise_rad_s / std::sqrt(rate);
      const double ea = MaxRelError(f.accel.noise_density, accel_n);
      const double eg = MaxRelError(f.gyro.noise_density, gyro_n);
      EXPECT_LT(ea, 0.10) << "seed " << seed << " rate " << rate;
      EXPECT_LT(eg, 0.10) << "seed " << seed << " rate " << rate;
      worst_accel = std::max(worst_accel, ea);
      worst_gyro = std::max(worst_gyro, eg);
      // A 30 s rest reaches neither the random walk nor the bias instability: said, not guessed.
      // (White noise has no flat floor: a B here would be a dip of the few-cluster tail.)
      EXPECT_TRUE(f.accel.bias_instability.array().isNaN().all())
          << "seed " << seed << " rate " << rate << ": " << f.accel.bias_instability.transpose();
      EXPECT_TRUE(f.gyro.bias_instability.array().isNaN().all())
          << "seed " << seed << " rate " << rate << ": " << f.gyro.bias_instability.transpose();
      EXPECT_TRUE(f.accel.random_walk.array().isNaN().all()) << f.accel.random_walk.transpose();
      EXPECT_TRUE(f.gyro.random_walk.array().isNaN().all()) << f.gyro.random_walk.transpose();
      EXPECT_TRUE(f.accel.random_walk_bound.allFinite());
      EXPECT_FALSE(f.notes.empty());
      // The notes give cluster times to 3 digits ("before 3.98 s"), not a double's 16.
      for (const std::string& note : f.notes) {
        EXPECT_TRUE(std::regex_search(note, std::regex("[ ~][0-9.]+ s[;)]"))) << note;
        EXPECT_FALSE(std::regex_search(note, std::regex("[0-9]\\.[0-9]{4,}"))) << note;
      }
      // The curve for the plot.
      EXPECT_EQ(na->curves.tau_s.size(), na->curves.accel_m_s2.size());
      EXPECT_EQ(na->curves.tau_s.size(), na->curves.gyro_rad_s.size());
      EXPECT_NEAR(na->curves.tau_s.front(), 1.0 / rate, 1e-9);
    }
  }
  std::printf(
      "white-noise density, worst relative error over 3 rates x 3 seeds x 3 axes: "
      "accel %.4f, gyro %.4f\n",
      worst_accel, worst_gyro);
}

// White plus bias random walk, generated here: N within 10%, K within 25% per axis and seed,
// and the mean K error over the 18 series within 10%.
// Why 25%: K is estimated from the cluster times past the curve's minimum (~3.5 s here) up to
// a sixth of the 30-minute record (300 s); each gives K^2 with a relative scatter of about
// sqrt(2 / edf), and the estimate is dominated by the 5-40 s points (45-360 clusters, but a
// random walk's Allan variance has only a fraction of that in equivalent degrees of freedom).
// Measured over 20 seeds x 6 series (120 estimates): mean error -0.8%, standard deviation
// 5.7%, worst 16.7%. 25% is ~4.4 standard deviations: a failure means a biased estimator, not
// an unlucky seed.
constexpr double kRandomWalkTolerance = 0.25;

TEST(AllanTest, RandomWalkRecovered) {
  const double rate = 100.0, duration = 1800.0;
  const double accel_n = 0.002, accel_k = 1e-3;  // m/s^2/sqrt(Hz), m/s^3/sqrt(Hz)
  const double gyro_n = 2e-4, gyro_k = 1e-4;     // rad/s/sqrt(Hz), rad/s^2/sqrt(Hz)
  const auto n = static_cast<size_t>(duration * rate);
  double worst_n = 0, worst_k = 0, sum_k = 0;
  int count = 0;
  for (uint64_t seed : {11u, 12u, 13u}) {
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> normal;
    Capture cap;
    cap.rate_hz = rate;
    Eigen::Vector3d ba = Eigen::Vector3d::Zero(), bg = Eigen::Vector3d::Zero();
    const double dt = 1.0 / rate;
    for (size_t i = 0; i < n; ++i) {
      Eigen::Vector3d a, g;
      for (int k = 0; k < 3; ++k) {
        a(k) = ba(k) + accel_n * std::sqrt(rate) * normal(rng);
        g(k) = bg(k) + gyro_n * std::sqrt(rate) * normal(rng);
        ba(k) += accel_k * std::sqrt(dt) * normal(rng);
        bg(k) += gyro_k * std::sqrt(dt) * normal(rng);
      }
      cap.t_s.push_back(static_cast<double>(i) * dt);
      cap.accel.push_back(a + Eigen::Vector3d(0, 0, kStandardGravity));
      cap.gyro.push_back(g);
    }
    absl::StatusOr<NoiseAnalysis> na = ComputeNoise(cap, 0, n, AccelParams(), GyroParams());
    ASSERT_TRUE(na.ok()) << na.status();
    const NoiseFigures& f = na->figures;
    for (int k = 0; k < 3; ++k) {
      const double en_a = std::abs(f.accel.noise_density(k) / accel_n - 1);
      const double en_g = std::abs(f.gyro.noise_density(k) / gyro_n - 1);
      const double ek_a = f.accel.random_walk(k) / accel_k - 1;
      const double ek_g = f.gyro.random_walk(k) / gyro_k - 1;
      EXPECT_LT(en_a, 0.10) << "seed " << seed << " axis " << k;
      EXPECT_LT(en_g, 0.10) << "seed " << seed << " axis " << k;
      EXPECT_LT(std::abs(ek_a), kRandomWalkTolerance) << "seed " << seed << " axis " << k;
      EXPECT_LT(std::abs(ek_g), kRandomWalkTolerance) << "seed " << seed << " axis " << k;
      worst_n = std::max({worst_n, en_a, en_g});
      worst_k = std::max({worst_k, std::abs(ek_a), std::abs(ek_g)});
      sum_k += ek_a + ek_g;
      count += 2;
    }
    EXPECT_TRUE(f.accel.random_walk_bound.array().isNaN().all());
  }
  const double mean_k = sum_k / count;
  EXPECT_LT(std::abs(mean_k), 0.10);
  std::printf("white + random walk: worst N error %.4f, worst K error %.4f, mean K error %+.4f\n",
              worst_n, worst_k, mean_k);
}

// ---------------------------------------------------------------------------------------------
// Bias instability and random walk within 10%. The noise is built here, one axis at a
// time, from the three IEEE Std 952 Annex C terms with their rate PSDs (two-sided, the
// standard's convention: avar(tau) = 4 int_0^inf S(f) sin^4(pi f tau) / (pi f tau)^2 df):
//   white            S(f) = N^2                   avar = N^2 / tau
//   flicker          S(f) = B^2 / (2 pi f)        avar = (2 ln 2 / pi) B^2, adev = 0.664 B
//   rate random walk S(f) = (K / 2 pi)^2 / f^2    avar = K^2 tau / 3
//
// Flicker is the sum of first-order Gauss-Markov processes (exact AR(1) steps) with time
// constants T_i = kFlickerT0 * r^i, r = 4, each of stationary variance q. One such process has
// S(f) = 2 q T / (1 + (2 pi f T)^2); summed over log-spaced T it is (1 / ln r) times the integral
// over ln T, q / (2 f ln r), for 1 / (2 pi T_max) << f << 1 / (2 pi T_min). (Poisson summation:
// the ripple about that is 2 sech(pi^2 / ln r) = 0.3% at r = 4.) Equal to B^2 / (2 pi f) when
//   q = B^2 ln r / pi.
// The exact Allan variance of one process, q (T/tau)^2 (2 tau/T - 3 + 4 e^(-tau/T) - e^(-2 tau/T))
// (IEEE Std 952 C.1.5), summed over the bank is checked below to be 0.664 B within 1% over the
// cluster times where B is read: the simulated noise has the bias instability it claims.
constexpr double kFlickerT0 = 0.01;    // s: the shortest time constant (one sample at 100 Hz)
constexpr double kFlickerRatio = 4.0;  // between neighbouring time constants
constexpr int kFlickerProcesses = 11;  // 0.01 s ... 1.0e4 s (the record is 3600 s)

class NoiseAxis {
 public:
  // n: white density, b: bias instability, k: rate random walk (continuous-time, any one unit).
  NoiseAxis(double n, double b, double k, double rate_hz, std::mt19937_64* rng)
      : rng_(rng), white_sd_(n * std::sqrt(rate_hz)), walk_sd_(k / std::sqrt(rate_hz)) {
    const double q = b * b * std::log(kFlickerRatio) / M_PI;
    double t = kFlickerT0;
    for (int i = 0; b > 0 && i < kFlickerProcesses; ++i, t *= kFlickerRatio) {
      const double phi = std::exp(-1.0 / (rate_hz * t));
      phi_.push_back(phi);
      drive_sd_.push_back(std::sqrt(q * (1 - phi * phi)));
      state_.push_back(std::sqrt(q) * normal_(*rng_));  // stationary from the start
    }
  }
  double Next() {
    double x = walk_ + white_sd_ * normal_(*rng_);
    for (size_t i = 0; i < state_.size(); ++i) {
      x += state_[i];
      state_[i] = phi_[i] * state_[i] + drive_sd_[i] * normal_(*rng_);
    }
    walk_ += walk_sd_ * normal_(*rng_);
    return x;
  }

 private:
  std::mt19937_64* rng_;
  std::normal_distribution<double> normal_;
  double white_sd_, walk_sd_, walk_ = 0;
  std::vector<double> phi_, drive_sd_, state_;
};

// The Allan variance the flicker bank has in expectation (the formula above).
double FlickerBankAvar(double b, double tau_s) {
  const double q = b * b * std::log(kFlickerRatio) / M_PI;
  double sum = 0, t = kFlickerT0;
  for (int i = 0; i < kFlickerProcesses; ++i, t *= kFlickerRatio) {
    const double x = tau_s / t;
    sum += q / (x * x) * (2 * x - 3 + 4 * std::exp(-x) - std::exp(-2 * x));
  }
  return sum;
}

struct AxisNoise {
  double n, b, k;
};

// A capture at rest (gravity on z) whose six axes carry independent noise of the given figures.
Capture SimulateRest(const AxisNoise& accel, const AxisNoise& gyro, double rate_hz,
                     double duration_s, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::vector<NoiseAxis> axes;
  for (int k = 0; k < 6; ++k) {
    const AxisNoise& f = k < 3 ? accel : gyro;
    axes.emplace_back(f.n, f.b, f.k, rate_hz, &rng);
  }
  const auto n = static_cast<size_t>(duration_s * rate_hz);
  Capture cap;
  cap.rate_hz = rate_hz;
  cap.t_s.reserve(n);
  cap.accel.reserve(n);
  cap.gyro.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    Eigen::Vector3d a, g;
    for (int k = 0; k < 3; ++k) a(k) = axes[k].Next(), g(k) = axes[3 + k].Next();
    cap.t_s.push_back(static_cast<double>(i) / rate_hz);
    cap.accel.push_back(a + Eigen::Vector3d(0, 0, kStandardGravity));
    cap.gyro.push_back(g);
  }
  return cap;
}

// White + flicker + rate random walk, a MEMS-like curve with a real minimum: B within 10% on
// every axis of every seed.
// The design (P = 0.664 B, the plateau): white meets the plateau at tau_w = N^2 / P^2 = 0.044 s
// (nine samples at 200 Hz: the curve visibly falls first, as the estimator requires), the random
// walk at tau_r = 3 P^2 / K^2 = 41 s. The true minimum lies above the plateau by
// sqrt(1 + 2 sqrt(tau_w / tau_r)) - 1 = +3.1% (computed exactly below, with the bank's own
// flicker), near tau* = sqrt(tau_w tau_r) = 1.3 s, where the 3600 s record has ~2700 clusters:
// flicker's overlapping estimate has edf ~ 1.25 x clusters (NIST SP 1065 Table 5), so the
// deviation scatters by 1 / sqrt(2 edf) = 1.2% there and by <= 2.1% over the bowl (0.45-4 s, the
// points within 10% of the floor); picking the lowest of those reads ~1% low. The estimator takes
// the curve's global minimum, so the bowl must end well before the few-cluster tail (6-30
// clusters, scatter 15-35%, where a dip would pass for the floor): the random walk has doubled
// the deviation by T / 30 = 120 s and quadrupled it by T / 6 = 600 s.
// Measured over 20 seeds x 6 axes (120 estimates): mean +2.5%, standard deviation 1.3%, range
// -1.0% ... +5.3%. 10% is 5.7 standard deviations from the mean.
TEST(AllanTest, BiasInstabilityRecovered) {
  const double rate = 200.0, duration = 3600.0;
  const AxisNoise accel{1.4e-4, 1e-3, 1.8e-4};  // m/s^2/sqrt(Hz), m/s^2, m/s^3/sqrt(Hz)
  const AxisNoise gyro{1.4e-5, 1e-4, 1.8e-5};   // rad/s/sqrt(Hz), rad/s, rad/s^2/sqrt(Hz)
  // The simulation is what it claims: the bank's flicker is 0.664 B within 0.75% from 1 s to the
  // longest usable cluster time (1.1% low at 0.3 s, where white noise still dominates).
  const double plateau = std::sqrt(2 * std::log(2.0) / M_PI);  // = 0.664
  for (double tau : {1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 600.0}) {
    EXPECT_NEAR(std::sqrt(FlickerBankAvar(1.0, tau)) / plateau, 1.0, 0.0075) << "tau " << tau;
  }
  EXPECT_NEAR(std::sqrt(FlickerBankAvar(1.0, 0.3)) / plateau, 1.0, 0.012);
  // The exact expected minimum of white + flicker + random walk, relative to 0.664 B: the bias
  // the estimator has even on infinitely long data.
  double expected_min = INFINITY;
  for (double tau = 0.01; tau < 600; tau *= 1.01) {
    const double avar =
        gyro.n * gyro.n / tau + FlickerBankAvar(gyro.b, tau) + gyro.k * gyro.k * tau / 3;
    expected_min = std::min(expected_min, std::sqrt(avar) / (plateau * gyro.b));
  }
  EXPECT_LT(expected_min, 1.05);  // the design's bias stays well inside the 10%
  double worst = 0, sum = 0;
  int count = 0;
  for (uint64_t seed : {101u, 102u, 103u}) {
    const Capture cap = SimulateRest(accel, gyro, rate, duration, seed);
    absl::StatusOr<NoiseAnalysis> na =
        ComputeNoise(cap, 0, cap.size(), AccelParams(), GyroParams());
    ASSERT_TRUE(na.ok()) << na.status();
    const NoiseFigures& f = na->figures;
    for (int k = 0; k < 3; ++k) {
      const double ea = f.accel.bias_instability(k) / accel.b - 1;
      const double eg = f.gyro.bias_instability(k) / gyro.b - 1;
      EXPECT_LT(std::abs(ea), 0.10) << "seed " << seed << " axis " << k;
      EXPECT_LT(std::abs(eg), 0.10) << "seed " << seed << " axis " << k;
      worst = std::max({worst, std::abs(ea), std::abs(eg)});
      sum += ea + eg;
      count += 2;
    }
  }
  std::printf(
      "bias instability: expected minimum %.4f x 0.664 B; worst B error %.4f, mean %+.4f "
      "over %d axes\n",
      expected_min, worst, sum / count, count);
}

// White + rate random walk: N and K within 10% on every axis of every seed.
// Why this design: K is read from the cluster times past the minimum, tau* = sqrt(3) N / K,
// and a record of T holds only ~T / tau* independent random-walk increments of that length, so
// no estimator knows K^2 better than sqrt(2 tau* / T) or K better than half that. The 30-minute
// record of RandomWalkRecovered (tau* = 3.5 s) bounds K at 3.1% and the Allan fit measures 5.7%
// (1.8x the bound): 10% there is only 1.75 standard deviations. Here tau* = 0.87 s over 3600 s:
// the bound is 1.1%, the expected scatter 1.8 x 1.1% = 2.0%, so 10% is ~5 standard deviations.
// Measured over 20 seeds x 6 axes (120 estimates): mean -0.2%, standard deviation 2.0%, worst
// 5.2%. (No flicker here: B is not checked, the minimum of a white + random-walk bowl is no
// floor.)
TEST(AllanTest, RandomWalkWithinTenPercent) {
  const double rate = 100.0, duration = 3600.0;
  const AxisNoise accel{5e-4, 0.0, 1e-3};  // m/s^2/sqrt(Hz), -, m/s^3/sqrt(Hz)
  const AxisNoise gyro{5e-5, 0.0, 1e-4};   // rad/s/sqrt(Hz), -, rad/s^2/sqrt(Hz)
  double worst_n = 0, worst_k = 0, sum_k = 0;
  int count = 0;
  for (uint64_t seed : {201u, 202u, 203u}) {
    const Capture cap = SimulateRest(accel, gyro, rate, duration, seed);
    absl::StatusOr<NoiseAnalysis> na =
        ComputeNoise(cap, 0, cap.size(), AccelParams(), GyroParams());
    ASSERT_TRUE(na.ok()) << na.status();
    const NoiseFigures& f = na->figures;
    for (int k = 0; k < 3; ++k) {
      const double en_a = f.accel.noise_density(k) / accel.n - 1;
      const double en_g = f.gyro.noise_density(k) / gyro.n - 1;
      const double ek_a = f.accel.random_walk(k) / accel.k - 1;
      const double ek_g = f.gyro.random_walk(k) / gyro.k - 1;
      EXPECT_LT(std::abs(en_a), 0.10) << "seed " << seed << " axis " << k;
      EXPECT_LT(std::abs(en_g), 0.10) << "seed " << seed << " axis " << k;
      EXPECT_LT(std::abs(ek_a), 0.10) << "seed " << seed << " axis " << k;
      EXPECT_LT(std::abs(ek_g), 0.10) << "seed " << seed << " axis " << k;
      worst_n = std::max({worst_n, std::abs(en_a), std::abs(en_g)});
      worst_k = std::max({worst_k, std::abs(ek_a), std::abs(ek_g)});
      sum_k += ek_a + ek_g;
      count += 2;
    }
    EXPECT_TRUE(f.accel.random_walk_bound.array().isNaN().all());
    EXPECT_TRUE(f.gyro.random_walk_bound.array().isNaN().all());
  }
  std::printf(
      "white + random walk (1 h): worst N error %.4f, worst K error %.4f, mean K error "
      "%+.4f over %d axes\n",
      worst_n, worst_k, sum_k / count, count);
}

// NIST SP 1065 Table 5 at hand-computed points (n = 1000 samples: N = 1001 phase points).
TEST(AllanTest, EquivalentDegreesOfFreedom) {
  // white FM, m = 1: (3 * 1000 / 2 - 2 * 999 / 1001) * 4 / 9
  EXPECT_NEAR(AllanEdf(AllanNoise::kWhite, 1000, 1), (1500 - 1998.0 / 1001) * 4 / 9, 1e-9);
  // flicker FM, m = 2: 5 N^2 / (4 m (N + 3 m))
  EXPECT_NEAR(AllanEdf(AllanNoise::kFlicker, 1000, 2), 5.0 * 1001 * 1001 / (8 * 1007), 1e-9);
  // random-walk FM, m = 10: (N - 2) / m ((N - 1)^2 - 3 m (N - 1) + 4 m^2) / (N - 3)^2
  EXPECT_NEAR(AllanEdf(AllanNoise::kRandomWalk, 1000, 10),
              99.9 * (1e6 - 3e4 + 400) / (998.0 * 998.0), 1e-9);
  // Fewer clusters, fewer degrees of freedom.
  EXPECT_GT(AllanEdf(AllanNoise::kWhite, 1000, 10), AllanEdf(AllanNoise::kWhite, 1000, 100));
}

// What `imucal noise` states, on one-hour rests of known figures: each within 10% of the truth,
// read at a cluster time where its term dominates, inside a 95% interval; N's interval (of one
// cluster time, for an estimate that averages many) holds the truth. N and K on the white +
// random walk design of RandomWalkWithinTenPercent, B on the white + flicker + random walk
// design of BiasInstabilityRecovered (where K, fitted with only the white part removed, reads
// high: flicker still lifts the curve past its minimum). On a 20 s rest of white noise alone,
// B and K are upper bounds and said to be; on 5 s of the white + random walk design, K is not
// reached and its bound lies above the truth.
TEST(AllanTest, ReadingsWithIntervalsAndBounds) {
  const AxisNoise walk_accel{5e-4, 0.0, 1e-3}, walk_gyro{5e-5, 0.0, 1e-4};
  const Capture walk = SimulateRest(walk_accel, walk_gyro, 100.0, 3600.0, 301);
  absl::StatusOr<NoiseAnalysis> na =
      ComputeNoise(walk, 0, walk.size(), AccelParams(), GyroParams());
  ASSERT_TRUE(na.ok()) << na.status();
  int n_covered = 0;
  for (size_t k = 0; k < 6; ++k) {
    SCOPED_TRACE(k);
    const AxisNoise& truth = k < 3 ? walk_accel : walk_gyro;
    const AxisReadings& r = na->readings[k];
    for (const AllanReading* f : {&r.noise_density, &r.random_walk}) {
      EXPECT_FALSE(f->upper_bound);
      EXPECT_LT(f->low, f->value);
      EXPECT_GT(f->high, f->value);
    }
    EXPECT_NEAR(r.noise_density.value / truth.n, 1.0, 0.10);
    EXPECT_NEAR(r.random_walk.value / truth.k, 1.0, 0.10);
    // The two meet at tau* = sqrt(3) N / K = 0.87 s: N is read below it, K above.
    EXPECT_LT(r.noise_density.tau_s, 0.87);
    EXPECT_GT(r.random_walk.tau_s, 0.87);
    n_covered += r.noise_density.low <= truth.n && truth.n <= r.noise_density.high;
    // The same figures as the noise block's.
    const SensorNoise& s = k < 3 ? na->figures.accel : na->figures.gyro;
    EXPECT_EQ(r.noise_density.value, s.noise_density(static_cast<int>(k % 3)));
    EXPECT_EQ(r.random_walk.value, s.random_walk(static_cast<int>(k % 3)));
  }
  EXPECT_GE(n_covered, 5);

  const AxisNoise flicker_accel{1.4e-4, 1e-3, 1.8e-4}, flicker_gyro{1.4e-5, 1e-4, 1.8e-5};
  const Capture flicker = SimulateRest(flicker_accel, flicker_gyro, 200.0, 3600.0, 302);
  na = ComputeNoise(flicker, 0, flicker.size(), AccelParams(), GyroParams());
  ASSERT_TRUE(na.ok()) << na.status();
  for (size_t k = 0; k < 6; ++k) {
    SCOPED_TRACE(k);
    const AllanReading& b = na->readings[k].bias_instability;
    EXPECT_FALSE(b.upper_bound);
    EXPECT_NEAR(b.value / (k < 3 ? flicker_accel : flicker_gyro).b, 1.0, 0.10);
    EXPECT_LT(b.low, b.value);
    EXPECT_GT(b.high, b.value);
    // The bowl of that design: white meets the plateau at 0.044 s, the random walk at 41 s.
    EXPECT_GT(b.tau_s, 0.044);
    EXPECT_LT(b.tau_s, 41.0);
  }

  const Capture white = SimulateRest({2e-3, 0, 0}, {2e-4, 0, 0}, 200.0, 20.0, 303);
  na = ComputeNoise(white, 0, white.size(), AccelParams(), GyroParams());
  ASSERT_TRUE(na.ok()) << na.status();
  for (size_t k = 0; k < 6; ++k) {
    SCOPED_TRACE(k);
    const AxisReadings& r = na->readings[k];
    EXPECT_FALSE(r.noise_density.upper_bound);
    EXPECT_NEAR(r.noise_density.value / (k < 3 ? 2e-3 : 2e-4), 1.0, 0.10);
    for (const AllanReading* f : {&r.bias_instability, &r.random_walk}) {
      EXPECT_TRUE(f->upper_bound);
      EXPECT_GT(f->value, 0);
      // Read at a cluster time the record holds at least kMinClustersForFit times.
      EXPECT_LE(f->tau_s, 20.0 / kMinClustersForFit);
      EXPECT_TRUE(std::isnan(f->low));
      EXPECT_EQ(f->high, f->value);
    }
  }
  const Capture short_walk = SimulateRest(walk_accel, walk_gyro, 100.0, 5.0, 304);
  na = ComputeNoise(short_walk, 0, short_walk.size(), AccelParams(), GyroParams());
  ASSERT_TRUE(na.ok()) << na.status();
  for (size_t k = 0; k < 6; ++k) {
    SCOPED_TRACE(k);
    const AllanReading& kr = na->readings[k].random_walk;
    EXPECT_TRUE(kr.upper_bound);
    EXPECT_GT(kr.value, (k < 3 ? walk_accel : walk_gyro).k);
  }
}

TEST(AllanTest, RejectsShortOrOutOfRangeIntervals) {
  Capture cap;
  for (int i = 0; i < 10; ++i) {
    cap.t_s.push_back(i * 0.01);
    cap.accel.push_back(Eigen::Vector3d::Zero());
    cap.gyro.push_back(Eigen::Vector3d::Zero());
  }
  EXPECT_EQ(ComputeNoise(cap, 0, 10, AccelParams(), GyroParams()).status().code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(ComputeNoise(cap, 0, 11, AccelParams(), GyroParams()).status().code(),
            absl::StatusCode::kInvalidArgument);
}

// The pipeline fills the parameter set's noise block from the longest used interval.
TEST(AllanTest, CalibrateFillsNoiseBlock) {
  SimOptions o;
  o.seed = 5;
  o.rate_hz = 200;
  o.initial_rest_s = 20.0;
  o.accel_noise_m_s2 = 0.02;
  o.gyro_noise_rad_s = 0.002;
  const SimResult sim = MustSimulate(o);
  CalibrateOptions co;
  co.effects.enabled = false;
  absl::StatusOr<CalibrationReport> rep = Calibrate(sim.capture, co);
  ASSERT_TRUE(rep.ok()) << rep.status();
  ASSERT_TRUE(rep->params.noise.has_value());
  const NoiseFigures& f = *rep->params.noise;
  EXPECT_GT(f.t_end_s - f.t_start_s, 15.0);  // the initial rest, trimmed
  EXPECT_LT(MaxRelError(f.accel.noise_density, 0.02 / std::sqrt(200.0)), 0.10);
  EXPECT_LT(MaxRelError(f.gyro.noise_density, 0.002 / std::sqrt(200.0)), 0.10);
  EXPECT_FALSE(rep->allan.tau_s.empty());
}

// The noise block survives the parameter set's JSON, NaN (not reached) included; a parameter
// set without one still loads.
TEST(ParamsJsonNoise, RoundTripAndOptional) {
  ParamSet p;
  NoiseFigures n;
  n.t_start_s = 0.1;
  n.t_end_s = 9.9;
  n.samples = 1961;
  n.rate_hz = 200;
  n.accel.noise_density = Eigen::Vector3d(1.4e-3, 1.5e-3, 1.6e-3);
  n.accel.random_walk_bound = Eigen::Vector3d(3e-3, 3.1e-3, 3.2e-3);
  n.gyro.noise_density = Eigen::Vector3d(1.4e-4, 1.5e-4, 1.6e-4);
  n.gyro.bias_instability = Eigen::Vector3d(1e-5, 2e-5, 3e-5);
  n.gyro.random_walk = Eigen::Vector3d(1e-6, 2e-6, 3e-6);
  n.notes = {"accel random walk not reached on x, y, z"};
  p.noise = n;
  const std::string json = formats::ParamSetToJson(p);
  EXPECT_NE(json.find("m/s^2/sqrt(Hz)"), std::string::npos);
  EXPECT_NE(json.find("noise_std_per_sample"), std::string::npos);
  absl::StatusOr<ParamSet> back = formats::ParamSetFromJson(json);
  ASSERT_TRUE(back.ok()) << back.status();
  ASSERT_TRUE(back->noise.has_value());
  const NoiseFigures& b = *back->noise;
  EXPECT_EQ(b.samples, n.samples);
  EXPECT_EQ(b.rate_hz, n.rate_hz);
  EXPECT_EQ(b.t_start_s, n.t_start_s);
  EXPECT_EQ(b.accel.noise_density, n.accel.noise_density);
  EXPECT_EQ(b.accel.random_walk_bound, n.accel.random_walk_bound);
  EXPECT_TRUE(b.accel.random_walk.array().isNaN().all());
  EXPECT_TRUE(b.accel.bias_instability.array().isNaN().all());
  EXPECT_EQ(b.gyro.bias_instability, n.gyro.bias_instability);
  EXPECT_EQ(b.gyro.random_walk, n.gyro.random_walk);
  EXPECT_EQ(b.notes, n.notes);

  ParamSet old;  // no noise block
  absl::StatusOr<ParamSet> old_back = formats::ParamSetFromJson(formats::ParamSetToJson(old));
  ASSERT_TRUE(old_back.ok()) << old_back.status();
  EXPECT_FALSE(old_back->noise.has_value());
  EXPECT_EQ(formats::ParamSetToJson(old).find("\"noise\""), std::string::npos);
}

// The rest with handling in it: the clean rest, then the same with 5 s of motion (a large
// swing on every axis) 40% in, after which the unit reads 0.2 m/s^2 and 5e-4 rad/s off on x
// (set down turned, a new bias): the step and the motion enter every Allan difference that
// straddles them.
Capture WithHandling(Capture cap, size_t at, size_t length) {
  for (size_t i = at; i < cap.size(); ++i) {
    if (i < at + length) {
      const double phase = 2 * M_PI * static_cast<double>(i - at) / 100.0;
      cap.accel[i] += Eigen::Vector3d::Constant(3.0 * std::sin(phase));
      cap.gyro[i] += Eigen::Vector3d::Constant(1.5 * std::cos(phase));
    } else {
      cap.accel[i].x() += 0.2;
      cap.gyro[i].x() += 5e-4;
    }
  }
  return cap;
}

// ComputeNoiseOfSegments: one segment is ComputeNoise exactly; the two still segments around
// the handling give the clean rest's figures (within 10%), where the whole record's are inflated.
TEST(AllanTest, SegmentsPoolTheirVariancesAndLeaveTheStepBetweenOut) {
  const AxisNoise accel{2e-3, 0.0, 3.5e-4}, gyro{2e-4, 0.0, 3.5e-5};
  const Capture clean = SimulateRest(accel, gyro, 100.0, 1200.0, 311);
  const size_t n = clean.size(), at = 480 * 100, length = 500;
  const Capture handled = WithHandling(clean, at, length);
  const SampleCorrection identity(AccelParams{}, GyroParams{}, {}, 0.0);
  auto whole = ComputeNoise(clean, 0, n, AccelParams{}, GyroParams{});
  auto one = ComputeNoiseOfSegments(clean, {SampleRange{0, n}}, identity);
  auto pooled = ComputeNoiseOfSegments(handled, {{0, at}, {at + length, n}}, identity);
  auto joined = ComputeNoise(handled, 0, n, AccelParams{}, GyroParams{});
  ASSERT_TRUE(whole.ok() && one.ok() && pooled.ok() && joined.ok());
  for (size_t k = 0; k < 6; ++k) {
    EXPECT_EQ(one->readings[k].noise_density.value, whole->readings[k].noise_density.value);
    EXPECT_EQ(one->readings[k].random_walk.value, whole->readings[k].random_walk.value);
    const double k_clean = whole->readings[k].random_walk.value;
    const double k_pooled = pooled->readings[k].random_walk.value;
    EXPECT_NEAR(k_pooled / k_clean, 1.0, 0.1) << "axis " << k;
    EXPECT_NEAR(pooled->readings[k].noise_density.value / whole->readings[k].noise_density.value,
                1.0, 0.05)
        << "axis " << k;
  }
  // Joined across the handling, accel x's random walk is several times the truth.
  EXPECT_GT(joined->readings[0].random_walk.value, 2 * whole->readings[0].random_walk.value);
  EXPECT_EQ(pooled->segments.size(), 2u);
  EXPECT_EQ(pooled->figures.samples, static_cast<int64_t>(n - length));
}

// FindNoiseRest: a rest stays whole; handling is cut out and said; a capture with moves and no
// 10 s rest is refused, the message's first words naming the problem.
TEST(NoiseRestTest, WholeRestHandlingCutMovingRefused) {
  const AxisNoise accel{2e-3, 0.0, 3.5e-4}, gyro{2e-4, 0.0, 3.5e-5};
  const Capture clean = SimulateRest(accel, gyro, 100.0, 600.0, 312);
  absl::StatusOr<NoiseRest> rest = FindNoiseRest(clean);
  ASSERT_TRUE(rest.ok()) << rest.status();
  EXPECT_TRUE(rest->whole);
  ASSERT_EQ(rest->segments.size(), 1u);
  EXPECT_EQ(rest->segments[0].begin, 0u);
  EXPECT_EQ(rest->segments[0].end, clean.size());

  const Capture handled = WithHandling(clean, 240 * 100, 500);
  rest = FindNoiseRest(handled);
  ASSERT_TRUE(rest.ok()) << rest.status();
  EXPECT_FALSE(rest->whole);
  EXPECT_EQ(rest->segments.size(), 2u);
  EXPECT_GT(rest->cut_s, 4.9);
  EXPECT_LT(rest->cut_s, 8.0);
  EXPECT_NE(rest->note.find("cut"), std::string::npos) << rest->note;

  SimOptions o;
  o.initial_rest_s = 5.0;
  const SimResult moving = MustSimulate(o);
  rest = FindNoiseRest(moving.capture);
  ASSERT_FALSE(rest.ok());
  EXPECT_TRUE(absl::IsFailedPrecondition(rest.status()));
  EXPECT_EQ(rest.status().message().rfind("the record is not at rest: ", 0), 0u)
      << rest.status().message();
}

}  // namespace
}  // namespace imucal::core
