#include "client/sdk/corrector.h"

#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <new>
#include <random>
#include <thread>
#include <vector>

#include "Eigen/Core"
#include "absl/strings/match.h"
#include "core/correction.h"
#include "core/model.h"
#include "core/params.h"
#include "gtest/gtest.h"
#include "tests/allocation_counter.h"

namespace imucal::sdk {
namespace {

constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
constexpr uint64_t kSeed = 20240611;

double Uniform(std::mt19937_64& rng, double lo, double hi) {
  return std::uniform_real_distribution<double>(lo, hi)(rng);
}

Eigen::Vector3d RandomVec(std::mt19937_64& rng, double lo, double hi) {
  return Eigen::Vector3d(Uniform(rng, lo, hi), Uniform(rng, lo, hi), Uniform(rng, lo, hi));
}

Eigen::Matrix3d RandomMat(std::mt19937_64& rng, double lo, double hi) {
  Eigen::Matrix3d m;
  for (int i = 0; i < 9; ++i) m(i) = Uniform(rng, lo, hi);
  return m;
}

// Realistic magnitudes (field notes section 7), raw input in counts-like units so that scale
// and bias matter; half of the sets have no quadratic term (the corrector's fused path).
core::ParamSet RandomParams(std::mt19937_64& rng, bool with_quadratic) {
  core::ParamSet p;
  p.accel.bias = RandomVec(rng, -50.0, 50.0);
  p.accel.scale = RandomVec(rng, 5.5e-3, 6.5e-3);
  p.accel.tri_angles = RandomVec(rng, -0.02, 0.02);
  p.accel.frame_angles = RandomVec(rng, -0.05, 0.05);
  p.accel.quadratic = with_quadratic ? RandomVec(rng, -2e-3, 2e-3) : Eigen::Vector3d::Zero();
  p.gyro.matrix = 1.3e-4 * (Eigen::Matrix3d::Identity() + RandomMat(rng, -0.03, 0.03));
  p.gyro.bias = RandomVec(rng, -40.0, 40.0);
  p.gyro.accel_coupling = RandomMat(rng, -2e-4, 2e-4);
  p.accel_unit = core::AccelUnit::kCounts;
  p.gyro_unit = core::GyroUnit::kCounts;
  return p;
}

RawSample MakeSample(double t_s, const Eigen::Vector3d& accel, const Eigen::Vector3d& gyro,
                     double temp_c) {
  RawSample s;
  s.t_s = t_s;
  for (int i = 0; i < 3; ++i) {
    s.accel[i] = accel(i);
    s.gyro[i] = gyro(i);
  }
  s.temp_c = temp_c;
  return s;
}

// Bitwise equality of the values (memcmp on the struct would also compare its padding).
bool SameBits(const CalibratedSample& a, const CalibratedSample& b) {
  return std::memcmp(a.accel_m_s2, b.accel_m_s2, sizeof(a.accel_m_s2)) == 0 &&
         std::memcmp(a.gyro_rad_s, b.gyro_rad_s, sizeof(a.gyro_rad_s)) == 0 &&
         a.effects_skipped == b.effects_skipped;
}

void ExpectClose(double actual, double expected, double rel, const char* what, int i) {
  EXPECT_NEAR(actual, expected, rel * std::max(1.0, std::abs(expected))) << what << "[" << i << "]";
}

TEST(CorrectorTest, AgreesWithTheModelOnRandomParams) {
  std::mt19937_64 rng(kSeed);
  for (int set = 0; set < 200; ++set) {
    SCOPED_TRACE(testing::Message() << "seed " << kSeed << " set " << set);
    const core::ParamSet p = RandomParams(rng, set % 2 == 1);
    const absl::StatusOr<Corrector> c = Corrector::Create(p);
    ASSERT_TRUE(c.ok()) << c.status();
    for (int n = 0; n < 20; ++n) {
      const Eigen::Vector3d u_a = RandomVec(rng, -2500.0, 2500.0);
      const Eigen::Vector3d u_g = RandomVec(rng, -30000.0, 30000.0);
      CalibratedSample out;
      c->Apply(MakeSample(0.1 * n, u_a, u_g, 25.0), &out);
      const Eigen::Vector3d a = p.accel.Apply(u_a);
      const Eigen::Vector3d w = p.gyro.Apply(u_g, a);
      for (int i = 0; i < 3; ++i) {
        ExpectClose(out.accel_m_s2[i], a(i), 1e-12, "accel", i);
        ExpectClose(out.gyro_rad_s[i], w(i), 1e-12, "gyro", i);
      }
      EXPECT_EQ(out.effects_skipped, 0);
    }
  }
}

TEST(CorrectorTest, UndoesTheModelInverse) {
  // Simulated truth -> raw through the model's exact inverse -> corrector == truth.
  std::mt19937_64 rng(kSeed + 1);
  for (int set = 0; set < 100; ++set) {
    SCOPED_TRACE(testing::Message() << "seed " << kSeed + 1 << " set " << set);
    const core::ParamSet p = RandomParams(rng, set % 2 == 0);
    const absl::StatusOr<Corrector> c = Corrector::Create(p);
    ASSERT_TRUE(c.ok()) << c.status();
    for (int n = 0; n < 20; ++n) {
      const Eigen::Vector3d a_true = RandomVec(rng, -1.0, 1.0).normalized() * 9.81;
      const Eigen::Vector3d w_true = RandomVec(rng, -4.0, 4.0);
      const Eigen::Vector3d u_a = p.accel.Invert(a_true);
      const Eigen::Vector3d u_g = p.gyro.Invert(w_true, a_true);
      CalibratedSample out;
      c->Apply(MakeSample(0.0, u_a, u_g, kNan), &out);
      for (int i = 0; i < 3; ++i) {
        ExpectClose(out.accel_m_s2[i], a_true(i), 1e-11, "accel", i);
        ExpectClose(out.gyro_rad_s[i], w_true(i), 1e-11, "gyro", i);
      }
    }
  }
}

core::Effect MakeEffect(core::Sensor sensor, int axis, const char* regressor, double coefficient,
                        bool applied = true) {
  core::Effect e;
  e.sensor = sensor;
  e.axis = axis;
  e.regressor = regressor;
  e.coefficient = coefficient;
  e.applied = applied;
  return e;
}

// Identity model (m/s^2 and rad/s in, the same out) with the effects under test.
core::ParamSet IdentityWithEffects(std::vector<core::Effect> effects) {
  core::ParamSet p;
  p.effects = std::move(effects);
  return p;
}

TEST(CorrectorTest, AppliesEffectsWithTheRightSignAndRegressor) {
  const core::ParamSet p = IdentityWithEffects({
      MakeEffect(core::Sensor::kAccel, 0, "temperature", 0.01),
      MakeEffect(core::Sensor::kGyro, 2, "ax*az", 1e-3),
      MakeEffect(core::Sensor::kAccel, 1, "temperature^2", -2e-5),
      MakeEffect(core::Sensor::kGyro, 0, "time", 3e-4),
      MakeEffect(core::Sensor::kGyro, 1, "gz", 0.5, /*applied=*/false),
      MakeEffect(core::Sensor::kAccel, 2, "gx", 0.02),
  });
  const absl::StatusOr<Corrector> c = Corrector::Create(p, /*time_origin_s=*/100.0);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->num_applied_effects(), 5);
  EXPECT_TRUE(c->NeedsTemperature());
  EXPECT_TRUE(c->NeedsTime());

  const double temp = 31.5, t = 112.0;
  const Eigen::Vector3d a(1.5, -0.25, 9.7), w(0.02, -0.3, 0.7);
  CalibratedSample out;
  c->Apply(MakeSample(t, a, w, temp), &out);
  // Every regressor reads the model output before any effect (ax, az, gx as given).
  EXPECT_DOUBLE_EQ(out.accel_m_s2[0], a(0) - 0.01 * temp);
  EXPECT_DOUBLE_EQ(out.accel_m_s2[1], a(1) - (-2e-5) * temp * temp);
  EXPECT_DOUBLE_EQ(out.accel_m_s2[2], a(2) - 0.02 * w(0));
  EXPECT_DOUBLE_EQ(out.gyro_rad_s[0], w(0) - 3e-4 * (t - 100.0));
  EXPECT_DOUBLE_EQ(out.gyro_rad_s[1], w(1));  // not applied
  EXPECT_DOUBLE_EQ(out.gyro_rad_s[2], w(2) - 1e-3 * a(0) * a(2));
  EXPECT_EQ(out.effects_skipped, 0);
}

void ExpectRejected(const core::ParamSet& p, const std::string& path_prefix);

// A quadratic written about the parameter set's reference temperature, as the search writes it:
// the SDK evaluates exactly the centred polynomial, (T - 31.2) and (T - 31.2)^2, not T and T^2.
TEST(CorrectorTest, AppliesCentredQuadraticAboutTheStatedReference) {
  core::ParamSet p = IdentityWithEffects({
      MakeEffect(core::Sensor::kGyro, 0, "(temperature-31.2)", 2e-4),
      MakeEffect(core::Sensor::kGyro, 0, "(temperature-31.2)^2", 3.5e-5),
      MakeEffect(core::Sensor::kAccel, 2, "(temperature-31.2)*az", 1e-4),
      MakeEffect(core::Sensor::kAccel, 1, "(time-120)", 1e-5, /*applied=*/false),
  });
  p.effect_reference.temperature_c = 31.2;
  p.effect_reference.time_s = 120;
  const absl::StatusOr<Corrector> c = Corrector::Create(p);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->num_applied_effects(), 3);
  EXPECT_FALSE(c->NeedsTime());
  const Eigen::Vector3d a(0.1, -0.2, 9.8), w(0.01, 0.02, -0.03);
  for (double temp : {22.0, 31.2, 42.0}) {
    CalibratedSample out;
    c->Apply(MakeSample(5.0, a, w, temp), &out);
    const double d = temp - 31.2;
    EXPECT_DOUBLE_EQ(out.gyro_rad_s[0], w(0) - 2e-4 * d - 3.5e-5 * d * d) << temp;
    EXPECT_DOUBLE_EQ(out.accel_m_s2[2], a(2) - 1e-4 * d * a(2)) << temp;
    EXPECT_DOUBLE_EQ(out.accel_m_s2[1], a(1)) << temp;  // not applied
  }
  // A centred name the reference does not state is refused where it is: the SDK would otherwise
  // evaluate a polynomial other than the one fitted. Old parameter sets state none (0) and use
  // uncentred names, which still load; a plain name means what it says whatever the reference.
  p.effect_reference.temperature_c = 30;
  ExpectRejected(p,
                 "effects[0].regressor: written (temperature-31.2) but "
                 "effect_reference.temperature makes it (temperature-30)");
  p.effect_reference = core::EffectReference();
  p.effects = {MakeEffect(core::Sensor::kGyro, 0, "temperature^2", 3.5e-5)};
  EXPECT_TRUE(Corrector::Create(p).ok());
}

TEST(CorrectorTest, EffectsReadCalibratedSignals) {
  // A non-trivial model: the `ax` an effect reads is the calibrated accel, not the raw one.
  std::mt19937_64 rng(kSeed + 2);
  core::ParamSet p = RandomParams(rng, true);
  const core::ParamSet plain = p;
  p.effects = {MakeEffect(core::Sensor::kGyro, 1, "ax", 2e-3),
               MakeEffect(core::Sensor::kAccel, 0, "gy^2", 0.1)};
  const absl::StatusOr<Corrector> with = Corrector::Create(p);
  const absl::StatusOr<Corrector> without = Corrector::Create(plain);
  ASSERT_TRUE(with.ok() && without.ok());
  const RawSample s = MakeSample(0.0, Eigen::Vector3d(1200.0, -300.0, 800.0),
                                 Eigen::Vector3d(500.0, -2000.0, 100.0), kNan);
  CalibratedSample a, b;
  with->Apply(s, &a);
  without->Apply(s, &b);
  EXPECT_NEAR(a.gyro_rad_s[1], b.gyro_rad_s[1] - 2e-3 * b.accel_m_s2[0], 1e-15);
  EXPECT_NEAR(a.accel_m_s2[0], b.accel_m_s2[0] - 0.1 * b.gyro_rad_s[1] * b.gyro_rad_s[1], 1e-15);
  EXPECT_FALSE(with->NeedsTemperature());
}

TEST(CorrectorTest, SkipsAndCountsTemperatureEffectsWithoutTemperature) {
  const core::ParamSet p = IdentityWithEffects({
      MakeEffect(core::Sensor::kAccel, 0, "temperature", 0.01),
      MakeEffect(core::Sensor::kGyro, 2, "temperature*gz", 1e-3),
      MakeEffect(core::Sensor::kAccel, 1, "ay", 0.1),
  });
  const absl::StatusOr<Corrector> c = Corrector::Create(p);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_TRUE(c->NeedsTemperature());
  const Eigen::Vector3d a(0.5, 2.0, 9.8), w(0.1, 0.2, 0.3);
  CalibratedSample out;
  c->Apply(MakeSample(0.0, a, w, kNan), &out);
  EXPECT_EQ(out.effects_skipped, 2);
  EXPECT_DOUBLE_EQ(out.accel_m_s2[0], a(0));
  EXPECT_DOUBLE_EQ(out.gyro_rad_s[2], w(2));
  EXPECT_DOUBLE_EQ(out.accel_m_s2[1], a(1) - 0.1 * a(1));  // not a temperature effect
  for (int i = 0; i < 3; ++i) {
    EXPECT_FALSE(std::isnan(out.accel_m_s2[i]));
    EXPECT_FALSE(std::isnan(out.gyro_rad_s[i]));
  }
  c->Apply(MakeSample(0.0, a, w, 20.0), &out);
  EXPECT_EQ(out.effects_skipped, 0);
  EXPECT_DOUBLE_EQ(out.accel_m_s2[0], a(0) - 0.2);

  // A temperature effect that is not applied does not make temperature necessary.
  const absl::StatusOr<Corrector> off = Corrector::Create(IdentityWithEffects(
      {MakeEffect(core::Sensor::kAccel, 0, "temperature", 0.01, /*applied=*/false)}));
  ASSERT_TRUE(off.ok());
  EXPECT_FALSE(off->NeedsTemperature());
  off->Apply(MakeSample(0.0, a, w, kNan), &out);
  EXPECT_EQ(out.effects_skipped, 0);
}

TEST(CorrectorTest, TimeEffectsNeedAnExplicitOrigin) {
  const core::ParamSet p = IdentityWithEffects({MakeEffect(core::Sensor::kGyro, 0, "time", 1e-4)});
  const absl::StatusOr<Corrector> no_origin = Corrector::Create(p);
  ASSERT_FALSE(no_origin.ok());
  EXPECT_EQ(no_origin.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(absl::StartsWith(no_origin.status().message(), "effects[0]:")) << no_origin.status();

  // Not applied: no origin needed, and time is not read.
  core::ParamSet reported = p;
  reported.effects[0].applied = false;
  ASSERT_TRUE(Corrector::Create(reported).ok());

  const absl::StatusOr<Corrector> c = Corrector::Create(p, 50.0);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->time_origin_s(), 50.0);
  CalibratedSample out;
  c->Apply(MakeSample(60.0, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), kNan), &out);
  EXPECT_DOUBLE_EQ(out.gyro_rad_s[0], -1e-4 * 10.0);

  // A copy with another origin (e.g. the first sample of a stream); the original is unchanged.
  const absl::StatusOr<Corrector> later = c->WithTimeOrigin(58.0);
  ASSERT_TRUE(later.ok());
  later->Apply(MakeSample(60.0, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), kNan), &out);
  EXPECT_DOUBLE_EQ(out.gyro_rad_s[0], -1e-4 * 2.0);
  EXPECT_EQ(c->time_origin_s(), 50.0);
  EXPECT_FALSE(c->WithTimeOrigin(kNan).ok());
  EXPECT_FALSE(Corrector::Create(p, std::numeric_limits<double>::infinity()).ok());
}

void ExpectRejected(const core::ParamSet& p, const std::string& path_prefix) {
  const absl::StatusOr<Corrector> c = Corrector::Create(p);
  ASSERT_FALSE(c.ok()) << "expected " << path_prefix;
  EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(absl::StartsWith(c.status().message(), path_prefix)) << c.status();
}

TEST(CorrectorTest, CreateRejectsInvalidParameters) {
  core::ParamSet p;
  p.accel.scale(1) = kNan;
  ExpectRejected(p, "accel.scale[1]: not finite");
  p = core::ParamSet();
  p.accel.scale(2) = 0.0;
  ExpectRejected(p, "accel.scale[2]: zero");
  p = core::ParamSet();
  p.accel.tri_angles(0) = std::numeric_limits<double>::infinity();
  ExpectRejected(p, "accel.tri_angles[0]: not finite");
  p = core::ParamSet();
  p.gyro.matrix(2, 1) = kNan;
  ExpectRejected(p, "gyro.matrix[2][1]: not finite");
  p = core::ParamSet();
  p.gyro.matrix.row(2) = p.gyro.matrix.row(0);  // singular
  ExpectRejected(p, "gyro.matrix: not invertible");
  p = core::ParamSet();
  p.gyro.matrix(2, 2) = 1e-14;  // condition number 1e14
  ExpectRejected(p, "gyro.matrix: not invertible");
  p = core::ParamSet();
  p.gyro.accel_coupling(0, 0) = kNan;
  ExpectRejected(p, "gyro.accel_coupling[0][0]: not finite");
  p = IdentityWithEffects({MakeEffect(core::Sensor::kAccel, 0, "ax", 1.0),
                           MakeEffect(core::Sensor::kAccel, 0, "ax*bz", 1.0, false)});
  ExpectRejected(p, "effects[1].regressor: unknown regressor \"ax*bz\"");
  p = IdentityWithEffects({MakeEffect(core::Sensor::kGyro, 3, "ax", 1.0)});
  ExpectRejected(p, "effects[0].axis");
  p = IdentityWithEffects({MakeEffect(core::Sensor::kGyro, 1, "ax", kNan)});
  ExpectRejected(p, "effects[0].coefficient: not finite");
}

// The Corrector applies core::SampleCorrection (core/correction.h, the code the report's
// figures are computed with), which precomputes its matrices. Checked here against the model
// written out term by term: core/model.h's own Apply for the accelerometer and gyroscope, then
// each applied effect's regressor evaluated by hand on those outputs, for every kind of effect,
// with and without a temperature, with and without the quadratic term.
TEST(CorrectorTest, AgreesWithTheModelWrittenOut) {
  std::mt19937_64 rng(kSeed + 1);
  for (int set = 0; set < 100; ++set) {
    SCOPED_TRACE(testing::Message() << "seed " << kSeed + 1 << " set " << set);
    core::ParamSet p = RandomParams(rng, set % 2 == 1);
    const double c_temp = Uniform(rng, -1e-3, 1e-3), c_axaz = Uniform(rng, -1e-4, 1e-4);
    const double c_az = Uniform(rng, -1e-4, 1e-4), c_temp2 = Uniform(rng, -1e-6, 1e-6);
    const double c_time = Uniform(rng, -1e-6, 1e-6), c_gxgz = Uniform(rng, -1e-3, 1e-3);
    p.effects = {MakeEffect(core::Sensor::kAccel, 0, "temperature", c_temp),
                 MakeEffect(core::Sensor::kAccel, 2, "ax*az", c_axaz),
                 MakeEffect(core::Sensor::kGyro, 1, "az", c_az),
                 MakeEffect(core::Sensor::kGyro, 2, "temperature^2", c_temp2),
                 MakeEffect(core::Sensor::kGyro, 0, "time", c_time),
                 MakeEffect(core::Sensor::kGyro, 0, "gx*gz", c_gxgz),
                 MakeEffect(core::Sensor::kAccel, 1, "time^2", 1.0, /*applied=*/false)};
    const double origin_s = Uniform(rng, 0.0, 100.0);
    const absl::StatusOr<Corrector> c = Corrector::Create(p, origin_s);
    ASSERT_TRUE(c.ok()) << c.status();
    for (int n = 0; n < 20; ++n) {
      const Eigen::Vector3d u_a = RandomVec(rng, -2500.0, 2500.0);
      const Eigen::Vector3d u_g = RandomVec(rng, -30000.0, 30000.0);
      const double t_s = origin_s + Uniform(rng, 0.0, 600.0);
      const double temp_c = n % 4 == 3 ? kNan : Uniform(rng, -10.0, 50.0);
      CalibratedSample out;
      c->Apply(MakeSample(t_s, u_a, u_g, temp_c), &out);
      const Eigen::Vector3d a = p.accel.Apply(u_a);
      const Eigen::Vector3d w = p.gyro.Apply(u_g, a);
      Eigen::Vector3d want_a = a, want_w = w;
      int skipped = 0;
      if (std::isnan(temp_c)) {
        skipped = 2;
      } else {
        want_a(0) -= c_temp * temp_c;
        want_w(2) -= c_temp2 * temp_c * temp_c;
      }
      want_a(2) -= c_axaz * a(0) * a(2);
      want_w(1) -= c_az * a(2);
      want_w(0) -= c_time * (t_s - origin_s) + c_gxgz * w(0) * w(2);
      for (int i = 0; i < 3; ++i) {
        ExpectClose(out.accel_m_s2[i], want_a(i), 1e-12, "accel", i);
        ExpectClose(out.gyro_rad_s[i], want_w(i), 1e-12, "gyro", i);
      }
      EXPECT_EQ(out.effects_skipped, skipped);
    }
  }
}

TEST(CorrectorTest, ApplyBatchMatchesApply) {
  std::mt19937_64 rng(kSeed + 3);
  core::ParamSet p = RandomParams(rng, true);
  p.effects = {MakeEffect(core::Sensor::kAccel, 2, "temperature", 1e-3)};
  const absl::StatusOr<Corrector> c = Corrector::Create(p);
  ASSERT_TRUE(c.ok());
  std::vector<RawSample> in;
  for (int i = 0; i < 100; ++i) {
    in.push_back(MakeSample(0.01 * i, RandomVec(rng, -2000, 2000), RandomVec(rng, -9000, 9000),
                            i % 3 == 0 ? kNan : 20.0 + 0.1 * i));
  }
  std::vector<CalibratedSample> out(in.size());
  ASSERT_TRUE(c->ApplyBatch(in, out).ok());
  for (size_t i = 0; i < in.size(); ++i) {
    CalibratedSample one;
    c->Apply(in[i], &one);
    EXPECT_TRUE(SameBits(one, out[i])) << "sample " << i;
    EXPECT_EQ(out[i].effects_skipped, i % 3 == 0 ? 1 : 0);
  }
  std::vector<CalibratedSample> short_out(in.size() - 1);
  EXPECT_EQ(c->ApplyBatch(in, short_out).code(), absl::StatusCode::kInvalidArgument);
}

TEST(CorrectorTest, ApplyDoesNotAllocate) {
  std::mt19937_64 rng(kSeed + 4);
  core::ParamSet p = RandomParams(rng, true);
  p.effects = {MakeEffect(core::Sensor::kAccel, 2, "temperature^2*ax", 1e-6),
               MakeEffect(core::Sensor::kGyro, 0, "time", 1e-6),
               MakeEffect(core::Sensor::kGyro, 1, "gx*gy", 1e-3)};
  const absl::StatusOr<Corrector> c = Corrector::Create(p, 0.0);
  ASSERT_TRUE(c.ok());
  std::vector<RawSample> in(1000);
  for (size_t i = 0; i < in.size(); ++i) {
    in[i] = MakeSample(0.01 * static_cast<double>(i), RandomVec(rng, -2000, 2000),
                       RandomVec(rng, -9000, 9000), i % 2 ? kNan : 25.0);
  }
  std::vector<CalibratedSample> out(in.size());
  // The counter sees ordinary allocations (the replacement is in effect).
  const int64_t probe = imucal::test_support::AllocationCount();
  auto heap = std::make_unique<std::vector<double>>(16);
  ASSERT_GT(imucal::test_support::AllocationCount(), probe);
  const int64_t before = imucal::test_support::AllocationCount();
  for (size_t i = 0; i < in.size(); ++i) c->Apply(in[i], &out[i]);
  const absl::Status batch = c->ApplyBatch(in, out);
  const int64_t after = imucal::test_support::AllocationCount();
  EXPECT_TRUE(batch.ok());
  EXPECT_EQ(after - before, 0);
}

TEST(CorrectorTest, ThreadsSharingOneCorrectorGetIdenticalResults) {
  std::mt19937_64 rng(kSeed + 5);
  core::ParamSet p = RandomParams(rng, true);
  p.effects = {MakeEffect(core::Sensor::kAccel, 0, "temperature", 1e-3),
               MakeEffect(core::Sensor::kGyro, 2, "ax*az", 1e-5)};
  const absl::StatusOr<Corrector> c = Corrector::Create(p);
  ASSERT_TRUE(c.ok());
  std::vector<RawSample> in(20000);
  for (size_t i = 0; i < in.size(); ++i) {
    in[i] = MakeSample(0.005 * static_cast<double>(i), RandomVec(rng, -2000, 2000),
                       RandomVec(rng, -9000, 9000), i % 5 ? 22.0 : kNan);
  }
  std::vector<CalibratedSample> reference(in.size());
  ASSERT_TRUE(c->ApplyBatch(in, reference).ok());

  constexpr int kThreads = 4;
  std::vector<std::vector<CalibratedSample>> results(kThreads,
                                                     std::vector<CalibratedSample>(in.size()));
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      // Each thread walks the samples in its own order so that the calls interleave.
      // Strides coprime with the sample count make each order a permutation.
      constexpr size_t kStrides[kThreads] = {1, 3, 7, 11};
      for (size_t k = 0; k < in.size(); ++k) {
        const size_t i = (k * kStrides[t] + static_cast<size_t>(t)) % in.size();
        c->Apply(in[i], &results[t][i]);
      }
    });
  }
  for (std::thread& th : threads) th.join();
  for (int t = 0; t < kThreads; ++t) {
    int differing = 0;
    for (size_t i = 0; i < reference.size(); ++i) {
      differing += SameBits(results[t][i], reference[i]) ? 0 : 1;
    }
    EXPECT_EQ(differing, 0) << "thread " << t;
  }
}

TEST(CorrectorTest, ChecksInputUnits) {
  core::ParamSet p;
  p.accel_unit = core::AccelUnit::kG;
  p.gyro_unit = core::GyroUnit::kDegPerSecond;
  const absl::StatusOr<Corrector> c = Corrector::Create(p);
  ASSERT_TRUE(c.ok());
  EXPECT_TRUE(c->CheckInputUnits(core::AccelUnit::kG, core::GyroUnit::kDegPerSecond).ok());
  const absl::Status accel =
      c->CheckInputUnits(core::AccelUnit::kMetersPerSecond2, core::GyroUnit::kDegPerSecond);
  EXPECT_EQ(accel.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(accel.message(), "accel unit m/s^2 but the parameters expect g");
  const absl::Status gyro = c->CheckInputUnits(core::AccelUnit::kG, core::GyroUnit::kCounts);
  EXPECT_EQ(gyro.message(), "gyro unit counts but the parameters expect deg/s");
}

// A parameter set without a gyroscope: the gyro passes through bit for bit, any gyro unit is
// accepted, and a gyro effect is a malformed parameter set.
TEST(CorrectorTest, WithoutGyroLeavesTheGyroAsRead) {
  std::mt19937_64 rng(kSeed);
  core::ParamSet p = RandomParams(rng, false);
  p.has_gyro = false;
  p.gyro.matrix.setZero();  // singular: never checked nor applied without a gyroscope
  const absl::StatusOr<Corrector> c = Corrector::Create(p);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_FALSE(c->has_gyro());
  EXPECT_TRUE(c->CheckInputUnits(p.accel_unit, core::GyroUnit::kCounts).ok());
  const Eigen::Vector3d u_a = RandomVec(rng, -2500.0, 2500.0);
  const Eigen::Vector3d u_g(0.1234567, -31.5, 1e-9);
  CalibratedSample out;
  c->Apply(MakeSample(0.0, u_a, u_g, 25.0), &out);
  const Eigen::Vector3d a = p.accel.Apply(u_a);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(out.gyro_rad_s[i], u_g(i)) << i;
    ExpectClose(out.accel_m_s2[i], a(i), 1e-12, "accel", i);
  }
  core::Effect e;
  e.sensor = core::Sensor::kGyro;
  e.regressor = "temperature";
  p.effects = {e};
  const absl::StatusOr<Corrector> bad = Corrector::Create(p);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("effects[0].sensor"), std::string::npos);
}

}  // namespace
}  // namespace imucal::sdk
