// The gyroscope's bias between poses (core/bias_wander.h): sequences of pose means drawn from
// each model, then simulated captures (core/simulator.h) whose bias shifts at every move, drifts
// in time, or holds, run through the whole calibration.
#include "core/bias_wander.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "core/calibrate/calibrate.h"
#include "core/simulator.h"

namespace imucal::core {
namespace {

constexpr double kDegS = M_PI / 180.0;

// Reproducible normal draws (Box-Muller on mt19937_64; std::normal_distribution differs between
// standard libraries).
class Normal {
 public:
  explicit Normal(uint64_t seed) : engine_(seed) {}
  double operator()(double sigma) {
    const double u1 = 1.0 - static_cast<double>(engine_() >> 11) * 0x1.0p-53;
    const double u2 = static_cast<double>(engine_() >> 11) * 0x1.0p-53;
    return sigma * std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
  }
  Eigen::Vector3d Three(double sigma) {
    const double x = (*this)(sigma), y = (*this)(sigma);
    return {x, y, (*this)(sigma)};
  }

 private:
  std::mt19937_64 engine_;
};

// n poses 4 s apart, each mean with white noise sigma, plus an iid offset (shift) and a random
// walk over the moves (walk); the halves differ by noise alone.
std::vector<WanderPose> Sequence(int n, double sigma, double shift, double walk, uint64_t seed) {
  Normal draw(seed);
  std::vector<WanderPose> out;
  Eigen::Vector3d x = Eigen::Vector3d::Zero();
  const Eigen::Vector3d bias(1e-3, -2e-3, 5e-4);
  for (int k = 0; k < n; ++k) {
    if (k > 0) x += draw.Three(walk);
    WanderPose p;
    p.t_s = 4.0 * k;
    p.duration_s = 2.0;
    p.rate_rad_s = bias + x + draw.Three(shift) + draw.Three(sigma);
    p.sigma_rad_s = Eigen::Vector3d::Constant(sigma);
    p.half_diff_sigma_rad_s = Eigen::Vector3d::Constant(2 * sigma);
    p.half_diff_rad_s = draw.Three(2 * sigma);
    out.push_back(p);
  }
  return out;
}

const Eigen::Vector3d kNoK = Eigen::Vector3d::Constant(std::nan(""));

TEST(BiasWanderTest, TooFewPosesDoesNotRun) {
  EXPECT_FALSE(AnalyseBiasWander(Sequence(5, 1e-4, 0, 0, 1), kNoK, kNoK).ran);
}

TEST(BiasWanderTest, NoiseAloneIsNoWander) {
  int none = 0;
  for (uint64_t seed = 1; seed <= 10; ++seed) {
    const BiasWander w = AnalyseBiasWander(Sequence(40, 1e-4, 0, 0, seed), kNoK, kNoK);
    ASSERT_TRUE(w.ran);
    for (const AxisWander& a : w.axes) none += a.model == WanderModel::kNone;
    EXPECT_NEAR(w.static_rms_rad_s / w.noise_floor_rad_s, 1.0, 0.25);
    EXPECT_NEAR(w.within_pose_ratio, 1.0, 0.3);
  }
  EXPECT_GE(none, 27) << "of 30 axes";  // BIC's false alarms: a few percent
}

TEST(BiasWanderTest, AnOffsetPerPoseIsAShiftTheNeighboursDoNotPredict) {
  for (uint64_t seed = 1; seed <= 5; ++seed) {
    const double shift = 1e-3;  // 10 x the noise
    const BiasWander w = AnalyseBiasWander(Sequence(40, 1e-4, shift, 0, seed), kNoK, kNoK);
    for (const AxisWander& a : w.axes) {
      EXPECT_EQ(a.model, WanderModel::kShift) << "seed " << seed;
      EXPECT_NEAR(a.shift_rad_s, shift, 0.3 * shift) << "seed " << seed;
    }
    EXPECT_GT(w.heldout_after_rad_s, 0.95 * w.heldout_before_rad_s);
    EXPECT_GT(w.step_rms_rad_s, 10 * w.noise_floor_rad_s);
  }
}

TEST(BiasWanderTest, HalvesThatCannotTellAreNotReadAsProof) {
  // Offsets 1.5 x the noise: a drift in time of that size would part a 2 s pose's halves by
  // under 1.5 x the noise, so agreeing halves rule nothing out, and the note says so.
  const BiasWander w = AnalyseBiasWander(Sequence(40, 1e-4, 1.5e-4, 0, 2), kNoK, kNoK);
  ASSERT_TRUE(w.ran);
  EXPECT_LT(w.drift_within_pose_ratio, 1.5);
  for (const AxisWander& a : w.axes) EXPECT_EQ(a.model, WanderModel::kShift) << w.note;
  EXPECT_EQ(w.note.find("not while it rests"), std::string::npos) << w.note;
  EXPECT_NE(w.note.find("too short"), std::string::npos) << w.note;
}

TEST(BiasWanderTest, StepsThatStayAreAWalkTheNeighboursPredict) {
  for (uint64_t seed = 1; seed <= 5; ++seed) {
    const double walk = 5e-4;
    const BiasWander w = AnalyseBiasWander(Sequence(40, 1e-4, 0, walk, seed), kNoK, kNoK);
    for (const AxisWander& a : w.axes) {
      EXPECT_EQ(a.model, WanderModel::kWalk) << "seed " << seed;
      EXPECT_NEAR(a.walk_rad_s, walk, 0.4 * walk) << "seed " << seed;
    }
    EXPECT_LT(w.heldout_after_rad_s, 0.7 * w.heldout_before_rad_s);
    // The persistent part is followed: the smoothed bias tracks the walk.
    EXPECT_GT(w.smoothed_rad_s.back().norm() + w.smoothed_rad_s.front().norm(), 0);
  }
}

TEST(BiasWanderTest, ComparesTheStepsWithTheRestsRandomWalk) {
  const Eigen::Vector3d k = Eigen::Vector3d::Constant(1e-5);  // rad/s/sqrt(s)
  const BiasWander w = AnalyseBiasWander(Sequence(40, 1e-4, 1e-3, 0, 3), k, kNoK);
  EXPECT_NEAR(w.allan_step_rad_s, k.norm() * std::sqrt(4.0), 1e-12);
  EXPECT_FALSE(w.allan_is_bound);
  const BiasWander b = AnalyseBiasWander(Sequence(40, 1e-4, 1e-3, 0, 3), kNoK, k);
  EXPECT_TRUE(b.allan_is_bound);
  EXPECT_NE(b.note.find("at most"), std::string::npos) << b.note;
}

// Simulated Tedaldi captures through the whole calibration.
SimOptions Tedaldi(uint64_t seed) {
  SimOptions o;
  o.protocol = SimProtocol::kFree;
  o.free_poses = 36;
  o.seed = seed;
  o.rate_hz = 100;
  o.hold_s = 2.5;
  o.move_s = 1.5;
  o.temperature = false;
  o.gyro_noise_rad_s = 0.03 * kDegS;  // per sample, as the imutk-ros2-repeat unit
  return o;
}

BiasWander WanderOf(const SimOptions& o) {
  const absl::StatusOr<SimResult> sim = Simulate(o);
  EXPECT_TRUE(sim.ok()) << sim.status();
  CalibrateOptions opt;
  opt.use_bsas = false;
  const absl::StatusOr<CalibrationReport> r = Calibrate(sim->capture, opt);
  EXPECT_TRUE(r.ok()) << r.status();
  return r.ok() ? r->gyro_wander : BiasWander();
}

TEST(BiasWanderTest, SimulatedShiftAtEachMoveIsFoundAsAShiftThatHoldsWhileTheUnitRests) {
  for (uint64_t seed = 1; seed <= 3; ++seed) {
    SimOptions o = Tedaldi(seed);
    const double shift = 0.04 * kDegS;  // about what the imutk-ros2-repeat captures show
    o.gyro_bias_shift_rad_s = shift;
    const BiasWander w = WanderOf(o);
    ASSERT_TRUE(w.ran);
    for (int a = 0; a < 3; ++a) {
      const AxisWander& ax = w.axes[static_cast<size_t>(a)];
      EXPECT_TRUE(ax.model == WanderModel::kShift || ax.model == WanderModel::kShiftAndWalk)
          << "seed " << seed << " axis " << a << ": " << WanderModelName(ax.model);
      EXPECT_NEAR(ax.shift_rad_s, shift, 0.35 * shift) << "seed " << seed << " axis " << a;
    }
    EXPECT_LT(w.within_pose_ratio, 1.3) << w.note;
    EXPECT_GT(w.drift_within_pose_ratio, 2.0) << w.note;
    EXPECT_GT(w.heldout_after_rad_s, 0.9 * w.heldout_before_rad_s) << w.note;
    EXPECT_NE(w.note.find("not while it rests"), std::string::npos) << w.note;
  }
}

TEST(BiasWanderTest, SimulatedDriftInTimeShowsWithinThePoses) {
  SimOptions o = Tedaldi(4);
  o.gyro_bias_walk = 0.03 * kDegS;  // rad/s/sqrt(s): the same steps as above, but in time
  const BiasWander w = WanderOf(o);
  ASSERT_TRUE(w.ran);
  EXPECT_GT(w.within_pose_ratio, 1.5) << w.note;
  EXPECT_NEAR(w.within_pose_ratio, w.drift_within_pose_ratio, 0.4 * w.drift_within_pose_ratio)
      << w.note;
  for (const AxisWander& ax : w.axes)
    EXPECT_TRUE(ax.model == WanderModel::kWalk || ax.model == WanderModel::kShiftAndWalk) << w.note;
  EXPECT_LT(w.heldout_after_rad_s, 0.8 * w.heldout_before_rad_s) << w.note;
  EXPECT_NE(w.note.find("moves within the poses too"), std::string::npos) << w.note;
}

TEST(BiasWanderTest, SimulatedCleanCaptureHoldsItsBias) {
  int none = 0;
  for (uint64_t seed = 1; seed <= 3; ++seed) {
    const BiasWander w = WanderOf(Tedaldi(seed));
    ASSERT_TRUE(w.ran);
    for (const AxisWander& ax : w.axes) none += ax.model == WanderModel::kNone;
    EXPECT_LT(w.static_rms_rad_s, 1.5 * w.noise_floor_rad_s) << w.note;
  }
  EXPECT_GE(none, 8) << "of 9 axes";
}

}  // namespace
}  // namespace imucal::core
