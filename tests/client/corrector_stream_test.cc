// sdk::Stream: the static model then the learnt dynamic gyro block (issue 27), equal to the
// offline application (core::SampleCorrection + core::DynamicGyroState) within 1e-12, with no
// heap allocation per sample (counted here), and its refusals and flags.
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <new>
#include <random>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "client/sdk/corrector.h"
#include "core/correction.h"
#include "core/dynamic_gyro.h"
#include "core/dynamic_gyro_state.h"
#include "core/params.h"
#include "gtest/gtest.h"
#include "tests/allocation_counter.h"

namespace imucal::sdk {
namespace {

constexpr uint64_t kSeed = 2027;
constexpr double kRateHz = 200.0;
constexpr int kSamples = 4000;

double Uniform(std::mt19937_64& rng, double lo, double hi) {
  return std::uniform_real_distribution<double>(lo, hi)(rng);
}

Eigen::Vector3d RandomVec(std::mt19937_64& rng, double lo, double hi) {
  return Eigen::Vector3d(Uniform(rng, lo, hi), Uniform(rng, lo, hi), Uniform(rng, lo, hi));
}

// A static set in SI input units with a gyro-to-accel coupling, and a block of random weights.
core::ParamSet RandomParams(std::mt19937_64& rng, int taps, int dilation) {
  core::ParamSet p;
  p.accel.bias = RandomVec(rng, -0.2, 0.2);
  p.accel.scale = RandomVec(rng, 0.98, 1.02);
  p.accel.tri_angles = RandomVec(rng, -0.01, 0.01);
  p.accel.frame_angles = RandomVec(rng, -0.02, 0.02);
  p.gyro.bias = RandomVec(rng, -0.02, 0.02);
  p.gyro.matrix = Eigen::Matrix3d::Identity();
  for (int i = 0; i < 9; ++i) p.gyro.matrix(i) += Uniform(rng, -0.01, 0.01);
  p.gyro.accel_coupling = Eigen::Matrix3d::Constant(1e-4);
  p.gyro_calibrated = true;
  core::DynamicGyro b;
  b.rate_hz = kRateHz;
  b.delay_s = 0.0026;
  b.odd_rate = RandomVec(rng, -1e-3, 1e-3);
  b.taps = taps;
  b.dilation = dilation;
  for (int i = 0; i < 18 * taps; ++i) b.weights.push_back(Uniform(rng, -0.02, 0.02));
  b.envelope.max_abs_rate_rad_s = Eigen::Vector3d::Constant(6.0);
  b.envelope.max_abs_accel_m_s2 = Eigen::Vector3d::Constant(30.0);
  p.dynamic_gyro = b;
  return p;
}

std::vector<RawSample> RandomStream(std::mt19937_64& rng, int n) {
  std::vector<RawSample> out(static_cast<size_t>(n));
  for (int k = 0; k < n; ++k) {
    RawSample& s = out[static_cast<size_t>(k)];
    s.t_s = 10.0 + k / kRateHz;
    const Eigen::Vector3d a = RandomVec(rng, -15.0, 15.0);
    const Eigen::Vector3d w = RandomVec(rng, -4.0, 4.0);
    for (int i = 0; i < 3; ++i) {
      s.accel[i] = a(i);
      s.gyro[i] = w(i);
    }
  }
  return out;
}

// The offline path: the two core appliers in a loop, nothing of the SDK's.
std::vector<Eigen::Vector3d> OfflineGyro(const core::ParamSet& p,
                                         const std::vector<RawSample>& in) {
  const core::SampleCorrection correction(p, 0.0);
  core::DynamicGyroState state(*p.dynamic_gyro);
  std::vector<Eigen::Vector3d> out;
  for (const RawSample& s : in) {
    const core::CorrectedSample c =
        correction.Apply(Eigen::Vector3d(s.accel[0], s.accel[1], s.accel[2]),
                         Eigen::Vector3d(s.gyro[0], s.gyro[1], s.gyro[2]), s.temp_c, s.t_s);
    Eigen::Vector3d w;
    state.Step(c.gyro_rad_s, c.accel_m_s2, &w);
    out.push_back(w);
  }
  return out;
}

TEST(StreamTest, EqualsTheOfflineApplicationWithin1e12) {
  for (const auto& [taps, dilation] :
       {std::pair{29, 16}, std::pair{8, 3}, std::pair{1, 1}, std::pair{0, 1}}) {
    std::mt19937_64 rng(kSeed + taps);
    const core::ParamSet p = RandomParams(rng, taps, dilation);
    const std::vector<RawSample> in = RandomStream(rng, kSamples);
    const std::vector<Eigen::Vector3d> expected = OfflineGyro(p, in);
    absl::StatusOr<Corrector> c = Corrector::Create(p);
    ASSERT_TRUE(c.ok()) << c.status();
    ASSERT_TRUE(c->has_dynamic_gyro());
    absl::StatusOr<Stream> stream = c->NewStream(kRateHz);
    ASSERT_TRUE(stream.ok()) << stream.status();
    double worst = 0.0, moved = 0.0;
    for (int k = 0; k < kSamples; ++k) {
      CalibratedSample out, static_out;
      stream->Apply(in[k], &out);
      c->Apply(in[k], &static_out);
      for (int i = 0; i < 3; ++i) {
        worst = std::max(worst, std::abs(out.gyro_rad_s[i] - expected[k](i)));
        moved = std::max(moved, std::abs(out.gyro_rad_s[i] - static_out.gyro_rad_s[i]));
        EXPECT_EQ(out.accel_m_s2[i], static_out.accel_m_s2[i]);
      }
      EXPECT_FALSE(out.interval_off_rate);
    }
    EXPECT_LE(worst, 1e-12) << "taps " << taps << " dilation " << dilation << " seed " << kSeed;
    EXPECT_GT(moved, 1e-3) << "the block must change the output for the test to mean anything";
    EXPECT_EQ(stream->counts().samples, kSamples);
    EXPECT_EQ(stream->counts().restarts, 0);
  }
}

TEST(StreamTest, ApplyAllocatesNothingPerSample) {
  std::mt19937_64 rng(kSeed);
  const core::ParamSet p = RandomParams(rng, 29, 16);
  const std::vector<RawSample> in = RandomStream(rng, kSamples);
  absl::StatusOr<Corrector> c = Corrector::Create(p);
  ASSERT_TRUE(c.ok()) << c.status();
  absl::StatusOr<Stream> stream = c->NewStream(kRateHz);
  ASSERT_TRUE(stream.ok()) << stream.status();
  CalibratedSample out;
  const int64_t before = imucal::test_support::AllocationCount();
  for (const RawSample& s : in) stream->Apply(s, &out);
  stream->Reset();
  for (const RawSample& s : in) stream->Apply(s, &out);
  const int64_t allocations = imucal::test_support::AllocationCount() - before;
  EXPECT_EQ(allocations, 0) << "over " << 2 * kSamples << " samples";
  // The counter counts: making a stream allocates its ring buffer.
  const int64_t at_new = imucal::test_support::AllocationCount();
  ASSERT_TRUE(c->NewStream(kRateHz).ok());
  EXPECT_GT(imucal::test_support::AllocationCount(), at_new);
}

TEST(StreamTest, AStreamOfAnotherRateIsRefused) {
  std::mt19937_64 rng(kSeed);
  absl::StatusOr<Corrector> c = Corrector::Create(RandomParams(rng, 2, 2));
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_TRUE(c->NewStream(kRateHz * 1.019).ok());
  EXPECT_TRUE(c->NewStream(kRateHz * 0.981).ok());
  absl::StatusOr<Stream> off = c->NewStream(kRateHz * 1.021);
  ASSERT_FALSE(off.ok());
  EXPECT_EQ(off.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(off.status().message().find("dynamic_gyro.rate_hz"), std::string::npos) << off.status();
  EXPECT_FALSE(c->NewStream(0.0).ok());
  EXPECT_FALSE(c->NewStream(std::numeric_limits<double>::quiet_NaN()).ok());
}

TEST(StreamTest, IntervalsOffRateAreFlaggedAndGapsRestartTheWindow) {
  std::mt19937_64 rng(kSeed);
  core::ParamSet p = RandomParams(rng, 4, 2);  // window 7 samples = 35 ms
  std::vector<RawSample> in = RandomStream(rng, 100);
  in[20].t_s += 0.1 / kRateHz;                               // 10 % late, then 10 % early
  for (size_t k = 60; k < in.size(); ++k) in[k].t_s += 1.0;  // a 1 s gap before sample 60
  absl::StatusOr<Corrector> c = Corrector::Create(p);
  ASSERT_TRUE(c.ok()) << c.status();
  absl::StatusOr<Stream> stream = c->NewStream(kRateHz);
  ASSERT_TRUE(stream.ok()) << stream.status();
  // Offline: the same window restarted at sample 60.
  const std::vector<RawSample> head(in.begin(), in.begin() + 60), tail(in.begin() + 60, in.end());
  std::vector<Eigen::Vector3d> expected = OfflineGyro(p, head);
  for (const Eigen::Vector3d& w : OfflineGyro(p, tail)) expected.push_back(w);
  for (size_t k = 0; k < in.size(); ++k) {
    CalibratedSample out;
    stream->Apply(in[k], &out);
    EXPECT_EQ(out.interval_off_rate, k == 20 || k == 21) << k;
    for (int i = 0; i < 3; ++i) EXPECT_NEAR(out.gyro_rad_s[i], expected[k](i), 1e-12) << k;
  }
  EXPECT_EQ(stream->counts().interval_off_rate, 2);
  EXPECT_EQ(stream->counts().restarts, 1);
}

TEST(StreamTest, SamplesOutsideTheTrainingEnvelopeAreFlagged) {
  std::mt19937_64 rng(kSeed);
  core::ParamSet p = RandomParams(rng, 2, 1);
  p.dynamic_gyro->envelope.max_abs_rate_rad_s = Eigen::Vector3d::Constant(1.0);
  absl::StatusOr<Corrector> c = Corrector::Create(p);
  ASSERT_TRUE(c.ok()) << c.status();
  absl::StatusOr<Stream> stream = c->NewStream(kRateHz);
  ASSERT_TRUE(stream.ok());
  RawSample slow, fast;
  slow.t_s = 0.0;
  fast.t_s = 1.0 / kRateHz;
  fast.gyro[2] = 3.0;  // rad/s, beyond the 1 rad/s it saw
  CalibratedSample out;
  stream->Apply(slow, &out);
  EXPECT_FALSE(out.outside_envelope);
  stream->Apply(fast, &out);
  EXPECT_TRUE(out.outside_envelope);
  EXPECT_EQ(stream->counts().outside_envelope, 1);
}

TEST(StreamTest, WithoutABlockAStreamIsTheStaticCorrector) {
  std::mt19937_64 rng(kSeed);
  core::ParamSet p = RandomParams(rng, 2, 1);
  p.dynamic_gyro.reset();
  absl::StatusOr<Corrector> c = Corrector::Create(p);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_FALSE(c->has_dynamic_gyro());
  absl::StatusOr<Stream> stream = c->NewStream(333.0);  // any rate: nothing depends on it
  ASSERT_TRUE(stream.ok()) << stream.status();
  for (const RawSample& s : RandomStream(rng, 50)) {
    CalibratedSample a, b;
    stream->Apply(s, &a);
    c->Apply(s, &b);
    for (int i = 0; i < 3; ++i) EXPECT_EQ(a.gyro_rad_s[i], b.gyro_rad_s[i]);
    EXPECT_FALSE(a.outside_envelope);
  }
  EXPECT_EQ(stream->counts().samples, 0);
}

TEST(StreamTest, CreateRefusesAMalformedBlockNamingItsField) {
  std::mt19937_64 rng(kSeed);
  const core::ParamSet good = RandomParams(rng, 2, 2);
  struct Case {
    void (*edit)(core::ParamSet&);
    const char* message;
  };
  const Case cases[] = {
      {[](core::ParamSet& p) { p.dynamic_gyro->weights.pop_back(); },
       "dynamic_gyro.weights: 35 values but taps*18 = 36 expected"},
      {[](core::ParamSet& p) { p.dynamic_gyro->weights[3] = std::nan(""); },
       "dynamic_gyro.weights[3]: not finite"},
      {[](core::ParamSet& p) { p.dynamic_gyro->taps = -1; }, "dynamic_gyro.taps: negative"},
      {[](core::ParamSet& p) { p.dynamic_gyro->dilation = 0; },
       "dynamic_gyro.dilation: must be 1 or more"},
      {[](core::ParamSet& p) { p.dynamic_gyro->rate_hz = 0; },
       "dynamic_gyro.rate_hz: must be a finite number > 0"},
      {[](core::ParamSet& p) { p.has_gyro = false; },
       "dynamic_gyro: a dynamic gyro block in a parameter set without a gyroscope"},
  };
  for (const Case& k : cases) {
    core::ParamSet p = good;
    k.edit(p);
    absl::StatusOr<Corrector> c = Corrector::Create(p);
    ASSERT_FALSE(c.ok()) << k.message;
    EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_EQ(std::string(c.status().message()).rfind(k.message, 0), 0u) << c.status();
  }
}

}  // namespace
}  // namespace imucal::sdk
