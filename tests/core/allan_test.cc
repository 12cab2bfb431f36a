// Allan deviation (core/allan.h): the figures recovered from simulated noise of known density.
//
// White noise: the simulator draws a per-sample std sigma, so the density is N = sigma /
// sqrt(rate). Random walk: generated here, b_{k+1} = b_k + K sqrt(dt) n_k, whose Allan
// deviation is K sqrt(tau / 3).
#include "core/allan.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <random>
#include <vector>

#include "Eigen/Core"
#include "client/sdk/params_json.h"
#include "core/calibrate.h"
#include "core/capture.h"
#include "core/simulator.h"

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

// The acceptance: white noise of known density recovered within 10% from the initial
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
      EXPECT_TRUE(f.accel.random_walk.array().isNaN().all()) << f.accel.random_walk.transpose();
      EXPECT_TRUE(f.gyro.random_walk.array().isNaN().all()) << f.gyro.random_walk.transpose();
      EXPECT_TRUE(f.accel.random_walk_bound.allFinite());
      EXPECT_FALSE(f.notes.empty());
      // The curve for the plot.
      EXPECT_EQ(na->curves.tau_s.size(), na->curves.accel_m_s2.size());
      EXPECT_EQ(na->curves.tau_s.size(), na->curves.gyro_rad_s.size());
      EXPECT_NEAR(na->curves.tau_s.front(), 1.0 / rate, 1e-9);
    }
  }
  std::printf("white-noise density, worst relative error over 3 rates x 3 seeds x 3 axes: "
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
  const std::string json = sdk::ParamSetToJson(p);
  EXPECT_NE(json.find("m/s^2/sqrt(Hz)"), std::string::npos);
  EXPECT_NE(json.find("noise_std_per_sample"), std::string::npos);
  absl::StatusOr<ParamSet> back = sdk::ParamSetFromJson(json);
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
  absl::StatusOr<ParamSet> old_back = sdk::ParamSetFromJson(sdk::ParamSetToJson(old));
  ASSERT_TRUE(old_back.ok()) << old_back.status();
  EXPECT_FALSE(old_back->noise.has_value());
  EXPECT_EQ(sdk::ParamSetToJson(old).find("\"noise\""), std::string::npos);
}

}  // namespace
}  // namespace imucal::core
