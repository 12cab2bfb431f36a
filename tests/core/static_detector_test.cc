#include "core/static_detector.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/strings/str_format.h"
#include "core/capture.h"
#include "core/simulator.h"

namespace imucal::core {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr uint64_t kSeeds[] = {1, 2, 3, 5, 8, 13};

SimResult MustSimulate(const SimOptions& options) {
  absl::StatusOr<SimResult> result = Simulate(options);
  EXPECT_TRUE(result.ok()) << result.status();
  if (!result.ok()) return SimResult();
  return *std::move(result);
}

// Everything the detector needs, computed the way core/calibrate/static_poses.cc does.
struct Detection {
  MotionSignal motion;
  NoiseLevel noise;
  std::vector<StaticInterval> intervals;
};

Detection Detect(const Capture& capture, double multiplier,
                 const StaticDetectorOptions& options = {}) {
  Detection d;
  d.motion = ComputeMotionSignal(capture, options);
  d.noise = EstimateNoise(capture, d.motion);
  d.intervals = DetectStatic(capture, d.motion, d.noise, multiplier, options);
  return d;
}

std::string Describe(const std::vector<StaticInterval>& intervals) {
  std::string out;
  for (const StaticInterval& s : intervals) {
    out += absl::StrFormat("  [%.3f, %.3f] used=%d %s\n", s.t_start_s, s.t_end_s, s.used, s.reason);
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// Hand-built captures: still segments, vigorous moves and slow ramps, with white noise drawn by
// our own Box-Muller (the capture is the same with any standard library).

class CaptureBuilder {
 public:
  CaptureBuilder(double rate_hz, double accel_noise, double gyro_noise, uint64_t seed)
      : dt_(1.0 / rate_hz), accel_noise_(accel_noise), gyro_noise_(gyro_noise), rng_(seed) {
    capture_.rate_hz = rate_hz;
  }

  // Holds `accel` (input units) and zero rate for `duration_s`.
  CaptureBuilder& Still(double duration_s, const Eigen::Vector3d& accel) {
    return Ramp(duration_s, accel, accel, Eigen::Vector3d::Zero());
  }
  // Moves the accelerometer linearly from `from` to `to` while the gyro reads `rate`: a slow tilt.
  CaptureBuilder& Ramp(double duration_s, const Eigen::Vector3d& from, const Eigen::Vector3d& to,
                       const Eigen::Vector3d& rate) {
    const int n = Samples(duration_s);
    for (int k = 0; k < n; ++k) {
      const double s = n > 1 ? static_cast<double>(k) / (n - 1) : 0.0;
      Push(from + s * (to - from), rate);
    }
    last_ = to;
    return *this;
  }
  // A vigorous hand move of `duration_s` from the last accel value to `to`: large swings on
  // every axis of both sensors, far above the noise.
  CaptureBuilder& Move(double duration_s, const Eigen::Vector3d& to, double swing = 3.0,
                       double rate_swing = 2.0) {
    const int n = Samples(duration_s);
    const Eigen::Vector3d from = last_;
    for (int k = 0; k < n; ++k) {
      const double s = static_cast<double>(k) / n;
      const double bump = std::sin(kPi * s);
      const Eigen::Vector3d wobble(std::sin(2 * kPi * 1.3 * s), std::cos(2 * kPi * 0.9 * s),
                                   std::sin(2 * kPi * 1.7 * s + 0.4));
      Push(from + s * (to - from) + swing * bump * wobble, rate_swing * bump * wobble);
    }
    last_ = to;
    return *this;
  }
  CaptureBuilder& Clip(double lo, double hi) {
    for (auto& a : capture_.accel) a = a.cwiseMax(lo).cwiseMin(hi);
    return *this;
  }
  CaptureBuilder& Round() {
    for (auto& a : capture_.accel) a = a.array().round().matrix();
    for (auto& g : capture_.gyro) g = g.array().round().matrix();
    return *this;
  }
  double now() const { return static_cast<double>(capture_.size()) * dt_; }
  Capture Build(AccelUnit accel_unit = AccelUnit::kMetersPerSecond2,
                GyroUnit gyro_unit = GyroUnit::kRadPerSecond) const {
    Capture c = capture_;
    c.accel_unit = accel_unit;
    c.gyro_unit = gyro_unit;
    EXPECT_TRUE(ValidateCapture(c).ok()) << ValidateCapture(c);
    return c;
  }

 private:
  int Samples(double duration_s) const { return static_cast<int>(std::lround(duration_s / dt_)); }
  double Normal() {
    const double u1 = 1.0 - Uniform(), u2 = Uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
  }
  double Uniform() { return static_cast<double>(rng_() >> 11) * 0x1.0p-53; }
  Eigen::Vector3d Noise(double sigma) {
    const double x = Normal(), y = Normal();
    return sigma * Eigen::Vector3d(x, y, Normal());
  }
  void Push(const Eigen::Vector3d& accel, const Eigen::Vector3d& rate) {
    capture_.t_s.push_back(static_cast<double>(capture_.size()) * dt_);
    capture_.accel.push_back(accel + Noise(accel_noise_));
    capture_.gyro.push_back(rate + Noise(gyro_noise_));
  }

  double dt_, accel_noise_, gyro_noise_;
  std::mt19937_64 rng_;
  Capture capture_;
  Eigen::Vector3d last_ = Eigen::Vector3d::Zero();
};

// The interval that overlaps [t0, t1], or nullptr.
const StaticInterval* Overlapping(const std::vector<StaticInterval>& intervals, double t0,
                                  double t1) {
  for (const StaticInterval& s : intervals)
    if (s.t_end_s > t0 && s.t_start_s < t1) return &s;
  return nullptr;
}

// ---------------------------------------------------------------------------------------------
// Noise level.

TEST(StaticDetectorTest, NoiseEstimateMatchesSimulatedNoise) {
  for (const uint64_t seed : kSeeds) {
    for (const AccelUnit unit : {AccelUnit::kMetersPerSecond2, AccelUnit::kCounts}) {
      SCOPED_TRACE(absl::StrFormat("seed %d, accel unit %s", seed, AccelUnitName(unit)));
      SimOptions options;
      options.seed = seed;
      options.extra_poses = 6;
      options.accel_unit = unit;
      options.accel_offset_counts = 32768;
      const SimResult sim = MustSimulate(options);
      const Detection d = Detect(sim.capture, 8.0);
      for (int i = 0; i < 3; ++i) {
        SCOPED_TRACE(absl::StrFormat("axis %d, noise source: %s", i, d.noise.source));
        // The simulator draws noise_SI / |scale_i| per raw axis; counts add a rounding step's
        // 1/12 variance.
        double expected_accel = options.accel_noise_m_s2 / std::abs(sim.truth.accel.scale(i));
        if (unit == AccelUnit::kCounts)
          expected_accel = std::hypot(expected_accel, std::sqrt(1.0 / 12));
        const double expected_gyro =
            options.gyro_noise_rad_s / std::abs(sim.truth.gyro.matrix(i, i));
        EXPECT_NEAR(d.noise.accel_std(i), expected_accel, 0.10 * expected_accel);
        EXPECT_NEAR(d.noise.gyro_std(i), expected_gyro, 0.10 * expected_gyro);
      }
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Intervals of simulated captures.

struct HoldCase {
  const char* name;
  SimProtocol protocol;
  AccelUnit accel_unit;
  GyroUnit gyro_unit;
};

TEST(StaticDetectorTest, FindsExactlyTheSimulatedHolds) {
  const HoldCase cases[] = {
      {"six-face + 6 extra, SI", SimProtocol::kSixFace, AccelUnit::kMetersPerSecond2,
       GyroUnit::kRadPerSecond},
      {"free, SI", SimProtocol::kFree, AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond},
      {"six-face + 6 extra, counts", SimProtocol::kSixFace, AccelUnit::kCounts, GyroUnit::kCounts},
      {"free, g and deg/s", SimProtocol::kFree, AccelUnit::kG, GyroUnit::kDegPerSecond},
  };
  for (const HoldCase& c : cases) {
    for (const uint64_t seed : {1, 2, 3}) {
      SCOPED_TRACE(absl::StrFormat("%s, seed %d", c.name, seed));
      SimOptions options;
      options.protocol = c.protocol;
      options.seed = seed;
      options.extra_poses = c.protocol == SimProtocol::kSixFace ? 6 : 0;
      options.accel_unit = c.accel_unit;
      options.gyro_unit = c.gyro_unit;
      options.accel_offset_counts = 32768;
      const SimResult sim = MustSimulate(options);
      const Detection d = Detect(sim.capture, 8.0);
      ASSERT_EQ(d.intervals.size(), sim.poses.size()) << Describe(d.intervals);
      for (size_t i = 0; i < sim.poses.size(); ++i) {
        const SimPose& pose = sim.poses[i];
        const StaticInterval& s = d.intervals[i];
        SCOPED_TRACE(absl::StrFormat("pose %d (%s) holds [%.3f, %.3f]", i, pose.label,
                                     pose.t_start_s, pose.t_end_s));
        EXPECT_GE(s.t_start_s, pose.t_start_s);
        EXPECT_LE(s.t_end_s, pose.t_end_s);
        EXPECT_TRUE(s.used) << s.reason;
        EXPECT_EQ(s.samples(), s.end - s.begin);
        // Most of the hold is kept: the window and trims cost well under a second.
        EXPECT_GT(s.t_end_s - s.t_start_s, pose.t_end_s - pose.t_start_s - 1.0);
      }
    }
  }
}

// ---------------------------------------------------------------------------------------------
// The checks that need no calibration.

TEST(StaticDetectorTest, ShortHoldIsReportedTooShort) {
  const Eigen::Vector3d up(0.1, -0.2, 9.8), side(9.7, 0.3, 0.5), down(-0.2, 0.1, -9.8);
  CaptureBuilder b(200, 0.02, 0.002, 7);
  b.Still(10, up).Move(2, side);
  const double short_start = b.now();
  b.Still(1.2, side);  // the window and the trims leave well under min_static_s = 1 s
  const double short_end = b.now();
  b.Move(2, down).Still(5, down);
  const Capture capture = b.Build();
  const Detection d = Detect(capture, 8.0);
  ASSERT_EQ(d.intervals.size(), 3u) << Describe(d.intervals);
  EXPECT_TRUE(d.intervals[0].used) << d.intervals[0].reason;
  EXPECT_TRUE(d.intervals[2].used) << d.intervals[2].reason;
  const StaticInterval& s = d.intervals[1];
  EXPECT_GE(s.t_start_s, short_start);
  EXPECT_LE(s.t_end_s, short_end);
  EXPECT_FALSE(s.used);
  EXPECT_NE(s.reason.find("too short"), std::string::npos) << s.reason;
}

TEST(StaticDetectorTest, SlowTiltDuringHoldIsMovedDuringCapture) {
  const Eigen::Vector3d up(0.1, -0.2, 9.8), side(9.7, 0.3, 0.5), down(-0.2, 0.1, -9.8);
  // A slow tilt of 0.3 m/s^2 (about 1.8 degrees) over 3 s: the window variance stays far below
  // the threshold (the ramp adds 1e-4 to a threshold of about 1e-2), but the two halves' means
  // differ by 0.15 m/s^2, 7 noise std.
  const Eigen::Vector3d tilted = side + Eigen::Vector3d(0, 0.3, 0);
  CaptureBuilder b(200, 0.02, 0.002, 11);
  b.Still(10, up).Move(2, side);
  const double hold_start = b.now();
  b.Still(3, side).Ramp(3, side, tilted, Eigen::Vector3d(0, 0, 0.01));
  const double hold_end = b.now();
  b.Move(2, down).Still(5, down);
  const Capture capture = b.Build();
  const Detection d = Detect(capture, 8.0);
  ASSERT_EQ(d.intervals.size(), 3u) << Describe(d.intervals);
  EXPECT_TRUE(d.intervals[0].used) << d.intervals[0].reason;
  EXPECT_TRUE(d.intervals[2].used) << d.intervals[2].reason;
  const StaticInterval& s = d.intervals[1];
  EXPECT_GE(s.t_start_s, hold_start);
  EXPECT_LE(s.t_end_s, hold_end);
  EXPECT_GT(s.t_end_s, hold_start + 4.5) << "the ramp should not end the static interval";
  EXPECT_FALSE(s.used);
  EXPECT_NE(s.reason.find("moved during capture"), std::string::npos) << s.reason;
}

TEST(StaticDetectorTest, StillHoldWithoutTiltIsNotMoved) {
  // The control for the test above: the same capture without the ramp is used.
  const Eigen::Vector3d up(0.1, -0.2, 9.8), side(9.7, 0.3, 0.5), down(-0.2, 0.1, -9.8);
  for (const uint64_t seed : kSeeds) {
    SCOPED_TRACE(absl::StrFormat("seed %d", seed));
    CaptureBuilder b(200, 0.02, 0.002, seed);
    b.Still(10, up).Move(2, side).Still(6, side).Move(2, down).Still(5, down);
    const Detection d = Detect(b.Build(), 8.0);
    ASSERT_EQ(d.intervals.size(), 3u) << Describe(d.intervals);
    for (const StaticInterval& s : d.intervals) EXPECT_TRUE(s.used) << s.reason;
  }
}

TEST(StaticDetectorTest, HoldOnTheRailIsSaturated) {
  // Raw counts around an offset of 32768 with 4 counts of noise; the second hold's z axis
  // would read 32767 + 1 count but the register tops out at 32767.
  constexpr double kRail = 32767;
  const Eigen::Vector3d level(100, -50, 16000), on_rail(-300, 200, kRail + 1), side(16100, 40, 20);
  CaptureBuilder b(200, 4.0, 2.0, 5);
  b.Still(10, level).Move(2, on_rail, 3000, 2000);
  const double hold_start = b.now();
  b.Still(4, on_rail);
  const double hold_end = b.now();
  b.Move(2, side, 3000, 2000).Still(5, side);
  const Capture capture =
      b.Clip(-kRail - 1, kRail).Round().Build(AccelUnit::kCounts, GyroUnit::kCounts);
  const Detection d = Detect(capture, 8.0);
  const StaticInterval* s = Overlapping(d.intervals, hold_start, hold_end);
  ASSERT_NE(s, nullptr) << Describe(d.intervals);
  EXPECT_FALSE(s->used);
  EXPECT_NE(s->reason.find("saturated"), std::string::npos) << s->reason;
  EXPECT_NE(s->reason.find("axis z"), std::string::npos) << s->reason;
  const StaticInterval* first = Overlapping(d.intervals, 0, 10);
  ASSERT_NE(first, nullptr) << Describe(d.intervals);
  EXPECT_TRUE(first->used) << first->reason;
}

// ---------------------------------------------------------------------------------------------
// A rest is a rest (issue 24): physics bounds the threshold.

// A turn about the vertical at a steady rate leaves the accelerometer unchanged and the
// gyroscope constant: no variance at all. Whatever the threshold, it is not a rest.
TEST(StaticDetectorTest, ASteadyTurnAtAnyRateIsNeverARest) {
  const Eigen::Vector3d up(0.1, -0.2, 9.8), side(9.7, 0.3, 0.5);
  for (const double rate_deg_s : {20.0, 50.0, 100.0, 200.0}) {
    SCOPED_TRACE(absl::StrFormat("%.0f deg/s", rate_deg_s));
    const Eigen::Vector3d rate(0, 0, rate_deg_s * kPi / 180);
    CaptureBuilder b(200, 0.02, 0.002, 17);
    b.Still(10, up).Move(2, side).Still(4, side);
    const double turn_start = b.now();
    b.Ramp(kPi / rate(2), side, side, rate);  // half a turn about the vertical
    const double turn_end = b.now();
    b.Still(4, side).Move(2, up).Still(5, up);
    const Capture capture = b.Build();
    // Loose thresholds too (a hand-held capture learns one): the turn has no variance at all.
    for (const double multiplier : {8.0, 1e3}) {
      const Detection d = Detect(capture, multiplier);
      for (const StaticInterval& s : d.intervals) {
        if (s.t_end_s <= turn_start + 0.3 || s.t_start_s >= turn_end - 0.3) continue;
        EXPECT_FALSE(s.used) << Describe(d.intervals);
        EXPECT_EQ(s.issue, IntervalIssue::kTurning) << s.reason;
        EXPECT_GT(s.rotation_deg, 10 * s.rotation_bound_deg) << s.reason;
      }
      // The rests on either side are found, and not joined across the turn.
      const StaticInterval* before = Overlapping(d.intervals, turn_start - 3, turn_start - 1);
      const StaticInterval* after = Overlapping(d.intervals, turn_end + 1, turn_end + 3);
      ASSERT_NE(before, nullptr) << Describe(d.intervals);
      ASSERT_NE(after, nullptr) << Describe(d.intervals);
      EXPECT_TRUE(before->used) << before->reason;
      EXPECT_TRUE(after->used) << after->reason;
      EXPECT_LT(before->t_end_s, turn_start + 0.3) << Describe(d.intervals);
      EXPECT_GT(after->t_start_s, turn_end - 0.3) << Describe(d.intervals);
    }
  }
}

// A hand shakes the unit back and forth (the gyroscope swings by several deg/s, far above the
// noise) but does not turn it: with a threshold loose enough to take the shaking, the rest is
// one used pose.
TEST(StaticDetectorTest, AShakingHandIsStillARest) {
  const Eigen::Vector3d up(0.1, -0.2, 9.8), side(9.7, 0.3, 0.5);
  CaptureBuilder b(200, 0.02, 0.002, 19);
  b.Still(10, up).Move(2, side);
  const double start = b.now();
  for (int k = 0; k < 4 * 200; ++k) {  // 4 s of an 8 Hz wobble of 0.05 rad/s amplitude
    const double w = 0.05 * std::sin(2 * kPi * 8 * k / 200.0);
    b.Ramp(1.0 / 200, side, side, Eigen::Vector3d(w, -w, 0.5 * w));
  }
  const double end = b.now();
  b.Move(2, up).Still(5, up);
  const Detection d = Detect(b.Build(), 1e3);
  const StaticInterval* s = Overlapping(d.intervals, start + 1, end - 1);
  ASSERT_NE(s, nullptr) << Describe(d.intervals);
  EXPECT_TRUE(s->used) << s->reason;
  EXPECT_LT(s->rotation_deg, s->rotation_bound_deg);
}

// A rotation table's servo buzzes in bursts through a long rest: the variance test cuts the rest
// at every burst, the gyroscope says nothing turned, so it is one pose.
TEST(StaticDetectorTest, ALongRestCutByVibrationIsOnePose) {
  const Eigen::Vector3d up(0.1, -0.2, 9.8), side(9.7, 0.3, 0.5);
  CaptureBuilder b(200, 0.02, 0.002, 23);
  b.Still(10, up).Move(2, side);
  const double start = b.now();
  for (int burst = 0; burst < 8; ++burst) {
    b.Still(4, side);
    for (int k = 0; k < 100; ++k) {  // 0.5 s at 37 Hz, 10x the noise on both sensors
      const double v = std::sin(2 * kPi * 37 * k / 200.0);
      b.Ramp(1.0 / 200, side + Eigen::Vector3d(0.3 * v, -0.3 * v, 0.2 * v), side,
             Eigen::Vector3d(0.03 * v, 0.02 * v, -0.03 * v));
    }
  }
  b.Still(4, side);
  const double end = b.now();
  b.Move(2, up).Still(5, up);
  const Detection d = Detect(b.Build(), 8.0);
  std::vector<const StaticInterval*> in_rest;
  for (const StaticInterval& s : d.intervals)
    if (s.t_end_s > start && s.t_start_s < end) in_rest.push_back(&s);
  ASSERT_EQ(in_rest.size(), 1u) << Describe(d.intervals);
  EXPECT_TRUE(in_rest[0]->used) << in_rest[0]->reason;
  EXPECT_GT(in_rest[0]->t_end_s - in_rest[0]->t_start_s, 0.9 * (end - start));
}

// Two files: the first ends in a rest and the second starts in the same orientation (a per-face
// file holding the wrong face). No interval crosses the file's start.
TEST(StaticDetectorTest, NoRestCrossesAFileStart) {
  const Eigen::Vector3d up(0.1, -0.2, 9.8), side(9.7, 0.3, 0.5);
  CaptureBuilder b(200, 0.02, 0.002, 29);
  b.Still(10, up).Move(2, side).Still(6, side);
  const size_t second = b.Build().size();
  b.Still(6, side).Move(2, up).Still(5, up);
  Capture capture = b.Build();
  capture.files = {{"a.csv", 0}, {"b.csv", second}};
  const Detection d = Detect(capture, 8.0);
  for (const StaticInterval& s : d.intervals)
    EXPECT_FALSE(s.begin < second && s.end > second) << Describe(d.intervals);
  EXPECT_NE(Overlapping(d.intervals, 13, 17), nullptr) << Describe(d.intervals);
  EXPECT_NE(Overlapping(d.intervals, 19, 23), nullptr) << Describe(d.intervals);
}

// Per-file thresholds: the second file's noise is 5x the first's. Learnt across files, the
// quiet file's floor would hide the noisy file's rests; learnt per file, both are found.
TEST(StaticDetectorTest, EachFileLearnsItsOwnNoise) {
  const Eigen::Vector3d up(0.1, -0.2, 9.8), side(9.7, 0.3, 0.5), down(-0.2, 0.1, -9.8);
  CaptureBuilder quiet(200, 0.02, 0.002, 31), noisy(200, 0.1, 0.01, 37);
  quiet.Still(20, up).Move(2, side).Still(8, side);
  noisy.Still(8, down).Move(2, side).Still(8, side);
  Capture capture = quiet.Build();
  const Capture tail = noisy.Build();
  const size_t second = capture.size();
  const double t0 = capture.t_s.back() + 10;
  for (size_t i = 0; i < tail.size(); ++i) {
    capture.t_s.push_back(t0 + tail.t_s[i]);
    capture.accel.push_back(tail.accel[i]);
    capture.gyro.push_back(tail.gyro[i]);
  }
  capture.files = {{"quiet.csv", 0}, {"noisy.csv", second}};
  const Detection d = Detect(capture, 8.0);
  ASSERT_EQ(d.noise.segments.size(), 2u);
  EXPECT_NEAR(d.noise.segments[1].accel_std(0) / d.noise.segments[0].accel_std(0), 5.0, 1.0);
  int used_in_noisy = 0;
  for (const StaticInterval& s : d.intervals) used_in_noisy += s.used && s.begin >= second;
  EXPECT_EQ(used_in_noisy, 2) << Describe(d.intervals);
}

TEST(StaticDetectorTest, SummariseIntervalGivesMeansAndStd) {
  Capture c;
  for (int k = 0; k < 4; ++k) {
    c.t_s.push_back(0.01 * k);
    c.accel.push_back(Eigen::Vector3d(k, 2 * k, 5));
    c.gyro.push_back(Eigen::Vector3d(-k, 0, 1));
    c.temp.push_back(20 + k);
  }
  const StaticInterval s = SummariseInterval(c, 1, 4);
  EXPECT_EQ(s.samples(), 3u);
  EXPECT_DOUBLE_EQ(s.t_start_s, 0.01);
  EXPECT_DOUBLE_EQ(s.t_end_s, 0.03);
  EXPECT_TRUE(s.accel_mean.isApprox(Eigen::Vector3d(2, 4, 5)));
  EXPECT_TRUE(s.gyro_mean.isApprox(Eigen::Vector3d(-2, 0, 1)));
  EXPECT_NEAR(s.accel_std(0), 1.0, 1e-12);  // sample std of {1, 2, 3}
  EXPECT_NEAR(s.accel_std(1), 2.0, 1e-12);
  EXPECT_NEAR(s.accel_std(2), 0.0, 1e-12);
  EXPECT_DOUBLE_EQ(s.temp_mean, 22.0);
}

}  // namespace
}  // namespace imucal::core
