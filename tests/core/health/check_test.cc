// Health checks on rests from a small generator of the test's own (not core/simulator.h nor
// core/health/fleet_sim.h): a known parameter set, a known residual the calibration misses, white
// noise from std::normal_distribution; the check must recover the residual within its SE.
#include "core/health/check.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "Eigen/Geometry"
#include "util/units.h"

namespace imucal::core::health {
namespace {

ParamSet Params() {
  ParamSet p;
  p.accel.bias = Eigen::Vector3d(0.12, -0.07, 0.2);
  p.accel.scale = Eigen::Vector3d(1.01, 0.995, 1.003);
  p.accel.tri_angles = Eigen::Vector3d(0.002, -0.001, 0.003);
  p.gyro.bias = Eigen::Vector3d(0.01, -0.02, 0.005);
  return p;
}

struct Truth {
  Eigen::Vector3d up_body = Eigen::Vector3d(0.1, -0.2, 1).normalized();
  Eigen::Vector3d accel_error_m_s2 = Eigen::Vector3d(0.02, -0.01, 0.03);  // what params miss
  Eigen::Vector3d gyro_error_rad_s = Eigen::Vector3d(1e-3, -2e-3, 5e-4);
  double accel_sigma = 0.02, gyro_sigma = 2e-3;  // per sample
  double rate_hz = 100, duration_s = 30;
  double wobble_deg = 0;  // a rocking motion's amplitude (not a rest)
};

Capture MakeRest(const ParamSet& p, const Truth& t, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> n(0, 1);
  Capture c;
  const int samples = static_cast<int>(t.duration_s * t.rate_hz);
  for (int i = 0; i < samples; ++i) {
    const double ts = 1000 + i / t.rate_hz;
    const double angle = t.wobble_deg * kDegToRad * std::sin(2 * M_PI * 0.5 * ts);
    const Eigen::Matrix3d r = Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitX()).toRotationMatrix();
    const Eigen::Vector3d f = r * t.up_body * p.gravity_m_s2 + t.accel_error_m_s2 +
                              t.accel_sigma * Eigen::Vector3d(n(rng), n(rng), n(rng));
    const double rate = t.wobble_deg * kDegToRad * 2 * M_PI * 0.5 * std::cos(2 * M_PI * 0.5 * ts);
    const Eigen::Vector3d w = t.gyro_error_rad_s + rate * Eigen::Vector3d::UnitX() +
                              t.gyro_sigma * Eigen::Vector3d(n(rng), n(rng), n(rng));
    c.t_s.push_back(ts);
    c.accel.push_back(p.accel.Invert(f));
    c.gyro.push_back(p.gyro.Invert(w, f));
    c.temp.push_back(25.0);
  }
  return c;
}

TEST(HealthCheckTest, RecoversTheResidualWithinItsStandardError) {
  const ParamSet p = Params();
  const Truth t;
  double sum_z2 = 0;
  int n = 0;
  for (uint64_t seed = 1; seed <= 40; ++seed) {
    const absl::StatusOr<HealthCheck> h = ComputeHealthCheck(MakeRest(p, t, seed), p);
    ASSERT_TRUE(h.ok()) << h.status() << " seed " << seed;
    const Eigen::Vector3d f_true = t.up_body * p.gravity_m_s2 + t.accel_error_m_s2;
    for (int k = 0; k < 3; ++k) {
      const double za = (h->specific_force_m_s2(k) - f_true(k)) / h->specific_force_se_m_s2(k);
      const double zg = (h->gyro_bias_rad_s(k) - t.gyro_error_rad_s(k)) / h->gyro_bias_se_rad_s(k);
      EXPECT_LT(std::abs(za), 5) << "seed " << seed;
      EXPECT_LT(std::abs(zg), 5) << "seed " << seed;
      sum_z2 += za * za + zg * zg;
      n += 2;
    }
    EXPECT_NEAR(h->norm_minus_g_m_s2, f_true.norm() - p.gravity_m_s2, 5 * h->norm_minus_g_se_m_s2);
    const double tilt = std::acos(std::min(1.0, h->gravity_dir_body.dot(f_true.normalized())));
    EXPECT_LT(tilt, 5 * h->gravity_dir_se_rad) << "seed " << seed;
    EXPECT_NEAR(h->duration_s, 30.0, 0.02);
    EXPECT_EQ(h->samples, 3000);
    EXPECT_DOUBLE_EQ(h->temp_mean_c, 25.0);
  }
  // The SEs are neither too small nor too large: the RMS z is about 1 (no noise block here,
  // so from the rest itself).
  EXPECT_NEAR(std::sqrt(sum_z2 / n), 1.0, 0.2);
}

TEST(HealthCheckTest, NoiseBlockGivesTheAllanStandardError) {
  ParamSet p = Params();
  const Truth t;
  NoiseFigures nf;
  nf.accel.noise_density = Eigen::Vector3d::Constant(t.accel_sigma / std::sqrt(t.rate_hz));
  nf.gyro.noise_density = Eigen::Vector3d::Constant(t.gyro_sigma / std::sqrt(t.rate_hz));
  p.noise = nf;
  const absl::StatusOr<HealthCheck> h = ComputeHealthCheck(MakeRest(p, t, 7), p);
  ASSERT_TRUE(h.ok()) << h.status();
  EXPECT_TRUE(h->se_from_noise_block);
  // Accel SE in calibrated units is sigma / sqrt(n) exactly for white noise.
  EXPECT_NEAR(h->gyro_bias_se_rad_s(0), t.gyro_sigma / std::sqrt(3000.0), 1e-9);
  EXPECT_NEAR(h->specific_force_se_m_s2(2), t.accel_sigma / std::sqrt(3000.0), 1e-9);
}

TEST(HealthCheckTest, AlongAReferenceDirectionSeesAMountingChange) {
  const ParamSet p = Params();
  Truth t;
  const Eigen::Vector3d dock = t.up_body;
  t.up_body = Eigen::AngleAxisd(0.3 * kDegToRad, Eigen::Vector3d::UnitY()) * dock;
  t.accel_error_m_s2.setZero();
  HealthCheckOptions o;
  o.reference_gravity_dir_body = dock;
  const absl::StatusOr<HealthCheck> h = ComputeHealthCheck(MakeRest(p, t, 3), p, o);
  ASSERT_TRUE(h.ok()) << h.status();
  const double angle = std::acos(h->gravity_dir_body.dot(dock));
  EXPECT_NEAR(angle, 0.3 * kDegToRad, 5 * h->gravity_dir_se_rad);
  EXPECT_NEAR(h->along_gravity_m_s2, p.gravity_m_s2 * (std::cos(0.3 * kDegToRad) - 1),
              5 * h->along_gravity_se_m_s2);
}

TEST(HealthCheckTest, ANonRestIsRefusedWithTheReason) {
  const ParamSet p = Params();
  Truth t;
  t.wobble_deg = 5;  // rocked by hand, +-5 degrees at 0.5 Hz
  const absl::StatusOr<HealthCheck> h = ComputeHealthCheck(MakeRest(p, t, 1), p);
  ASSERT_FALSE(h.ok());
  EXPECT_EQ(h.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(h.status().message().find("not a rest"), std::string::npos) << h.status();
  // Without a gyroscope (the still detector is not used there) the variance test refuses it.
  Capture accel_only = MakeRest(p, t, 1);
  accel_only.has_gyro = false;
  accel_only.gyro.clear();
  ParamSet pa = p;
  pa.has_gyro = false;
  const absl::StatusOr<HealthCheck> ha = ComputeHealthCheck(accel_only, pa);
  ASSERT_FALSE(ha.ok());
  EXPECT_NE(ha.status().message().find("moved or vibrated"), std::string::npos) << ha.status();
}

TEST(HealthCheckTest, ASteadyTurnIsRefused) {
  const ParamSet p = Params();
  Truth t;
  t.gyro_error_rad_s = Eigen::Vector3d(0, 0, 20 * kDegToRad);  // turning at 20 deg/s about up
  // The still detector finds no still stretch (the turn has no variance, but the gyroscope
  // turns more than a rest can); without it, the rate test refuses it.
  absl::StatusOr<HealthCheck> h = ComputeHealthCheck(MakeRest(p, t, 1), p);
  ASSERT_FALSE(h.ok());
  EXPECT_NE(h.status().message().find("not a rest"), std::string::npos) << h.status();
  HealthCheckOptions o;
  o.use_still_detector = false;
  h = ComputeHealthCheck(MakeRest(p, t, 1), p, o);
  ASSERT_FALSE(h.ok());
  EXPECT_NE(h.status().message().find("turns at 20.00 deg/s"), std::string::npos) << h.status();
}

TEST(HealthCheckTest, TooShortOrTooFewSamplesIsRefused) {
  const ParamSet p = Params();
  Truth t;
  t.duration_s = 5;
  absl::StatusOr<HealthCheck> h = ComputeHealthCheck(MakeRest(p, t, 1), p);
  ASSERT_FALSE(h.ok());
  EXPECT_NE(h.status().message().find("too short"), std::string::npos) << h.status();
  t.duration_s = 15;
  t.rate_hz = 10;  // 150 samples
  h = ComputeHealthCheck(MakeRest(p, t, 1), p);
  ASSERT_FALSE(h.ok());
  EXPECT_NE(h.status().message().find("too few samples"), std::string::npos) << h.status();
}

TEST(HealthCheckTest, OtherUnitsAreInvalid) {
  const ParamSet p = Params();
  Capture c = MakeRest(p, Truth(), 1);
  c.accel_unit = AccelUnit::kG;
  const absl::StatusOr<HealthCheck> h = ComputeHealthCheck(c, p);
  EXPECT_EQ(h.status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace imucal::core::health
