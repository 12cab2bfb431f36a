#include "core/online_segmenter.h"

#include <cmath>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "core/simulator.h"
#include "gtest/gtest.h"

namespace imucal::core {
namespace {

struct Fed {
  std::vector<PoseUpdate> poses;
  std::vector<NextPoseUpdate> next;
  int stillness = 0;
};

Fed FeedAll(OnlineSegmenter& seg, const Capture& cap) {
  Fed fed;
  std::vector<SegmenterEvent> events;
  for (size_t i = 0; i < cap.size(); ++i) seg.Add(cap.t_s[i], cap.accel[i], cap.gyro[i], &events);
  seg.Flush(&events);
  for (const SegmenterEvent& e : events) {
    switch (e.kind) {
      case SegmenterEvent::Kind::kStillness:
        ++fed.stillness;
        break;
      case SegmenterEvent::Kind::kPose:
        fed.poses.push_back(e.pose);
        break;
      case SegmenterEvent::Kind::kNextPose:
        fed.next.push_back(e.next_pose);
        break;
    }
  }
  return fed;
}

// The pose events among `events`, in order.
std::vector<PoseUpdate> PosesOf(const std::vector<SegmenterEvent>& events) {
  std::vector<PoseUpdate> out;
  for (const SegmenterEvent& e : events)
    if (e.kind == SegmenterEvent::Kind::kPose) out.push_back(e.pose);
  return out;
}

std::vector<PoseUpdate> Accepted(const Fed& fed) {
  std::vector<PoseUpdate> out;
  for (const PoseUpdate& p : fed.poses)
    if (p.accepted) out.push_back(p);
  return out;
}

class SixFaceTest : public testing::TestWithParam<AccelUnit> {};

TEST_P(SixFaceTest, FindsTheTwelvePosesAndGuidesThroughThem) {
  SimOptions sim;
  sim.seed = 7;
  sim.accel_unit = GetParam();
  auto result = Simulate(sim);
  ASSERT_TRUE(result.ok()) << result.status();
  OnlineSegmenterOptions opt;
  opt.rate_hz = sim.rate_hz;
  opt.protocol = GuidedProtocol::kSixFace;
  opt.accel_unit = sim.accel_unit;
  OnlineSegmenter seg(opt);
  EXPECT_EQ(seg.CurrentNextPose().face, "Z+");
  const Fed fed = FeedAll(seg, result->capture);
  const std::vector<PoseUpdate> accepted = Accepted(fed);
  ASSERT_EQ(accepted.size(), result->poses.size()) << "seed " << sim.seed;
  for (size_t i = 0; i < accepted.size(); ++i) {
    const SimPose& truth = result->poses[i];
    EXPECT_GE(accepted[i].t_start_s, truth.t_start_s - 0.05) << i;
    EXPECT_LE(accepted[i].t_end_s, truth.t_end_s + 0.05) << i;
    if (sim.accel_unit != AccelUnit::kCounts || i >= 4) {
      EXPECT_EQ(accepted[i].face, truth.label.substr(0, 2)) << i;
    }
  }
  EXPECT_GT(fed.stillness, 100);
  if (sim.accel_unit != AccelUnit::kCounts) {
    EXPECT_EQ(seg.six_face_step(), OnlineSegmenter::kSixFaceSteps);
    ASSERT_FALSE(fed.next.empty());
    EXPECT_TRUE(fed.next.back().done);
    EXPECT_EQ(fed.next.front().face, "Z+");  // after Z+: its turned partner
    EXPECT_TRUE(fed.next.front().turn_half);
    EXPECT_EQ(fed.next[1].face, "Z-");
    EXPECT_EQ(seg.FacesDone().size(), 6u);
    EXPECT_TRUE(seg.FacesPending().empty());
  }
  // The learnt noise floor is the simulated one (0.02 m/s^2 per axis in m/s^2).
  if (sim.accel_unit == AccelUnit::kMetersPerSecond2) {
    EXPECT_NEAR(std::sqrt(seg.accel_noise_var()(0)), 0.02, 0.006);
  }
}

INSTANTIATE_TEST_SUITE_P(Units, SixFaceTest,
                         testing::Values(AccelUnit::kMetersPerSecond2, AccelUnit::kG,
                                         AccelUnit::kCounts));

// A synthetic signal: rest, a short pause, a hold that slides half way, a long hold.
TEST(OnlineSegmenterTest, RejectsTooShortAndMovedPoses) {
  std::mt19937_64 rng(3);
  std::normal_distribution<double> noise(0.0, 0.01);
  OnlineSegmenterOptions opt;
  opt.rate_hz = 100;
  OnlineSegmenter seg(opt);
  std::vector<SegmenterEvent> events;
  double t = 0;
  // `shift` is added from `shift_at_s` into the hold (default: half way).
  auto hold = [&](double seconds, Eigen::Vector3d a, const Eigen::Vector3d& shift,
                  double shift_at_s = -1) {
    const int n = static_cast<int>(seconds * opt.rate_hz);
    const int shift_at = shift_at_s < 0 ? n / 2 + 1 : static_cast<int>(shift_at_s * opt.rate_hz);
    for (int i = 0; i < n; ++i, t += 0.01) {
      const Eigen::Vector3d ai = a + (i >= shift_at ? shift : Eigen::Vector3d::Zero());
      seg.Add(t, ai + Eigen::Vector3d(noise(rng), noise(rng), noise(rng)),
              Eigen::Vector3d(noise(rng), noise(rng), noise(rng)) * 0.1, &events);
    }
  };
  auto move = [&](double seconds) {
    const int n = static_cast<int>(seconds * opt.rate_hz);
    for (int i = 0; i < n; ++i, t += 0.01)
      seg.Add(t, Eigen::Vector3d(3 * std::sin(7 * t), 0, 9.8), Eigen::Vector3d(1, 0, 0), &events);
  };
  const Eigen::Vector3d up(0, 0, 9.8), none = Eigen::Vector3d::Zero();
  hold(5, up, none);
  move(1);
  hold(1.0, up, none);  // 0.5 s window and 0.1 s trims leave well under 1 s
  move(1);
  // 6 noise std: a slide, not noise. It happens before the hold time is reached (a pose is
  // accepted then), so the run has moved when judged at the hold time and when it ends.
  hold(2, up, Eigen::Vector3d(0.06, 0, 0), 0.8);
  move(1);
  hold(4, up, none);
  seg.Flush(&events);
  const std::vector<PoseUpdate> poses = PosesOf(events);
  ASSERT_EQ(poses.size(), 4u);
  EXPECT_TRUE(poses[0].accepted);
  EXPECT_EQ(poses[0].face, "Z+");
  EXPECT_FALSE(poses[1].accepted);
  EXPECT_NE(poses[1].reason.find("too short"), std::string::npos) << poses[1].reason;
  EXPECT_FALSE(poses[2].accepted);
  EXPECT_NE(poses[2].reason.find("moved"), std::string::npos) << poses[2].reason;
  EXPECT_TRUE(poses[3].accepted);
  EXPECT_EQ(seg.poses_accepted(), 2);
}

// A steady turn about the vertical (issue 24): the accelerometer does not change and the
// gyroscope reads a constant rate, so neither variance sees it. The live guide must not count it
// as a pose: the gyroscope turned through it.
TEST(OnlineSegmenterTest, ASteadyTurnIsNotAPose) {
  for (const double rate_deg_s : {20.0, 100.0}) {
    SCOPED_TRACE(rate_deg_s);
    std::mt19937_64 rng(5);
    std::normal_distribution<double> noise(0.0, 0.01);
    OnlineSegmenterOptions opt;
    opt.rate_hz = 100;
    OnlineSegmenter seg(opt);
    std::vector<SegmenterEvent> events;
    double t = 0;
    auto run = [&](double seconds, const Eigen::Vector3d& rate) {
      const int n = static_cast<int>(seconds * opt.rate_hz);
      for (int i = 0; i < n; ++i, t += 0.01)
        seg.Add(t, Eigen::Vector3d(noise(rng), noise(rng), 9.8 + noise(rng)),
                rate + 0.1 * Eigen::Vector3d(noise(rng), noise(rng), noise(rng)), &events);
    };
    const Eigen::Vector3d none = Eigen::Vector3d::Zero();
    run(5, none);
    run(180.0 / rate_deg_s, Eigen::Vector3d(0, 0, rate_deg_s * std::numbers::pi / 180));
    run(4, none);
    seg.Flush(&events);
    for (const PoseUpdate& p : PosesOf(events)) {
      const bool in_turn = p.t_start_s > 5.2 && p.t_end_s < 5 + 180.0 / rate_deg_s - 0.2;
      if (in_turn) {
        EXPECT_FALSE(p.accepted);
        EXPECT_NE(p.reason.find("turning"), std::string::npos) << p.reason;
      }
      if (p.accepted) EXPECT_TRUE(p.t_end_s < 5.3 || p.t_start_s > 5 + 180.0 / rate_deg_s - 0.3)
          << p.t_start_s << "-" << p.t_end_s;
    }
    EXPECT_EQ(seg.poses_accepted(), 2);
  }
}

// The robot stops streaming while still after its last pose (no motion, no Flush): the pose
// counts once it has been held for the hold time, with its guidance, and only once.
TEST(OnlineSegmenterTest, AcceptsAPoseOnceHeldWithoutWaitingForMotion) {
  std::mt19937_64 rng(4);
  std::normal_distribution<double> noise(0.0, 0.01);
  OnlineSegmenterOptions opt;
  opt.rate_hz = 100;
  OnlineSegmenter seg(opt);
  std::vector<SegmenterEvent> events;
  double t = 0;
  auto hold = [&](double seconds, const Eigen::Vector3d& a) {
    for (int i = 0; i < static_cast<int>(seconds * opt.rate_hz); ++i, t += 0.01)
      seg.Add(t, a + Eigen::Vector3d(noise(rng), noise(rng), noise(rng)),
              Eigen::Vector3d(noise(rng), noise(rng), noise(rng)) * 0.1, &events);
  };
  auto move = [&](double seconds) {
    for (int i = 0; i < static_cast<int>(seconds * opt.rate_hz); ++i, t += 0.01)
      seg.Add(t, Eigen::Vector3d(3 * std::sin(7 * t), 0, 9.8), Eigen::Vector3d(1, 0, 0), &events);
  };
  auto poses = [&] {
    std::vector<PoseUpdate> out;
    for (const SegmenterEvent& e : events)
      if (e.kind == SegmenterEvent::Kind::kPose) out.push_back(e.pose);
    return out;
  };
  hold(5, Eigen::Vector3d(0, 0, 9.8));
  move(1);
  hold(3, Eigen::Vector3d(0, 9.8, 0));  // then the stream stops
  ASSERT_EQ(poses().size(), 2u);
  EXPECT_EQ(seg.poses_accepted(), 2);
  const PoseUpdate last = poses()[1];
  EXPECT_TRUE(last.accepted) << last.reason;
  EXPECT_EQ(last.index, 1);
  EXPECT_EQ(last.face, "Y+");
  // Fired at the hold time, not at the end of the hold.
  EXPECT_NEAR(last.t_end_s - last.t_start_s, opt.min_static_s, 0.02);
  // Its guidance follows it at once.
  size_t k = 0, pose_events = 0;
  for (; k < events.size() && pose_events < 2; ++k)
    pose_events += events[k].kind == SegmenterEvent::Kind::kPose;
  ASSERT_LT(k, events.size());
  EXPECT_EQ(events[k].kind, SegmenterEvent::Kind::kNextPose);
  // Motion (or Flush) ending the run adds no second pose event and no second count.
  events.clear();
  move(1);
  seg.Flush(&events);
  EXPECT_TRUE(poses().empty());
  EXPECT_EQ(seg.poses_accepted(), 2);
  EXPECT_EQ(seg.poses_total(), 2);
  // Its statistics grew with the run until the motion ended it.
  EXPECT_EQ(seg.last_pose().index, 1);
  EXPECT_TRUE(seg.last_pose().accepted);
  EXPECT_GT(seg.last_pose().t_end_s - seg.last_pose().t_start_s, 2.0);
}

// The six-face guide completes on the samples alone: the capture's last pose closes although
// the stream ends with the robot still (no Flush).
TEST(OnlineSegmenterTest, SixFaceCompletesWithoutFlush) {
  SimOptions sim;
  sim.seed = 7;
  auto result = Simulate(sim);
  ASSERT_TRUE(result.ok()) << result.status();
  OnlineSegmenterOptions opt;
  opt.rate_hz = sim.rate_hz;
  opt.protocol = GuidedProtocol::kSixFace;
  OnlineSegmenter seg(opt);
  std::vector<SegmenterEvent> events;
  const Capture& cap = result->capture;
  // Stop streaming 2.5 s into the last (4 s) hold: held past the hold time, still.
  const double stop_t = result->poses.back().t_start_s + 2.5;
  for (size_t i = 0; i < cap.size() && cap.t_s[i] <= stop_t; ++i)
    seg.Add(cap.t_s[i], cap.accel[i], cap.gyro[i], &events);
  EXPECT_EQ(seg.six_face_step(), OnlineSegmenter::kSixFaceSteps);
  EXPECT_TRUE(seg.CurrentNextPose().done);
}

// An hour at rest: memory stays bounded (chunks merge) and the mean stays exact.
TEST(OnlineSegmenterTest, LongRestIsOnePoseWithTheRightMean) {
  OnlineSegmenterOptions opt;
  opt.rate_hz = 200;
  OnlineSegmenter seg(opt);
  std::vector<SegmenterEvent> events;
  std::mt19937_64 rng(5);
  std::normal_distribution<double> noise(0.0, 0.02);
  const int n = 200 * 3600;
  for (int i = 0; i < n; ++i) {
    seg.Add(i / 200.0, Eigen::Vector3d(0.1, -0.2, 9.8) + Eigen::Vector3d(noise(rng), 0, 0),
            Eigen::Vector3d(noise(rng), noise(rng), noise(rng)), &events);
    if (events.size() > 64) events.clear();  // the caller drains events as it goes
  }
  // The pose and its guidance fired after the hold time; Flush ends the run without another.
  EXPECT_EQ(seg.poses_accepted(), 1);
  events.clear();
  seg.Flush(&events);
  EXPECT_TRUE(events.empty());
  const PoseUpdate& pose = seg.last_pose();  // its statistics, over the whole run
  EXPECT_TRUE(pose.accepted) << pose.reason;
  EXPECT_NEAR(pose.accel_mean(0), 0.1, 1e-3);
  EXPECT_NEAR(pose.accel_mean(2), 9.8, 1e-9);
  EXPECT_GT(pose.t_end_s - pose.t_start_s, 3590);
}

}  // namespace
}  // namespace imucal::core

namespace imucal::core {
namespace {

// The positions protocols (seeds/002) cover the 6 faces and 12 edges of the cube of
// directions; the guide's target is those 18 and 24 poses.
class PositionsTest : public testing::TestWithParam<SimProtocol> {};

TEST_P(PositionsTest, CoversEveryFaceAndEdgeAndCompletes) {
  SimOptions sim;
  sim.seed = 3;
  sim.protocol = GetParam();
  auto result = Simulate(sim);
  ASSERT_TRUE(result.ok()) << result.status();
  OnlineSegmenterOptions opt;
  opt.rate_hz = sim.rate_hz;
  opt.protocol = GuidedProtocol::kPositions;
  OnlineSegmenter seg(opt);
  const GuideProgress before = seg.Progress();
  EXPECT_EQ(before.poses_wanted, 24);
  EXPECT_EQ(before.pending.size(), 18u);
  EXPECT_EQ(before.coverage, 0.0);
  EXPECT_EQ(seg.CurrentNextPose().face, "Z+");  // the direction nearest to top up
  const Fed fed = FeedAll(seg, result->capture);
  ASSERT_EQ(Accepted(fed).size(), result->poses.size());
  const GuideProgress after = seg.Progress();
  EXPECT_TRUE(after.pending.empty()) << "first missing: " << after.pending.front();
  EXPECT_EQ(after.done.size(), 18u);
  EXPECT_EQ(after.coverage, 1.0);
  // Complete: the poses in (24 or 36) and nothing more to do.
  EXPECT_EQ(after.poses_wanted, static_cast<int>(result->poses.size()));
  ASSERT_FALSE(fed.next.empty());
  EXPECT_TRUE(fed.next.back().done) << fed.next.back().instruction;
}

INSTANTIATE_TEST_SUITE_P(Protocols, PositionsTest,
                         testing::Values(SimProtocol::kPositions24, SimProtocol::kPositions36));

// A hand-held capture built pose by pose: 3 s still at each up direction (the first 5 s: it is
// also the initial rest whose first 2 s teach the noise floor), 0.6 s of motion between poses.
class HandHeld {
 public:
  void Hold(const Eigen::Vector3d& up_body) {
    Append(up_body.normalized() * 9.80665, cap_.t_s.empty() ? 5.0 : 3.0, 0.02, 0.002);
    Append(Eigen::Vector3d(3, -2, 7), 0.6, 3.0, 1.0);  // picked up and turned
  }
  const Capture& capture() const { return cap_; }

 private:
  void Append(const Eigen::Vector3d& accel, double seconds, double accel_sd, double gyro_sd) {
    std::normal_distribution<double> n(0.0, 1.0);
    for (int i = 0; i < static_cast<int>(seconds * 200); ++i) {
      cap_.t_s.push_back(static_cast<double>(cap_.t_s.size()) / 200.0);
      cap_.accel.push_back(accel + accel_sd * Eigen::Vector3d(n(rng_), n(rng_), n(rng_)));
      cap_.gyro.push_back(gyro_sd * Eigen::Vector3d(n(rng_), n(rng_), n(rng_)));
    }
  }
  std::mt19937 rng_{5};
  Capture cap_;
};

TEST(FreeProtocolTest, AsksForTheNearestMissingFaceOrCornerUntilComplete) {
  OnlineSegmenterOptions opt;
  opt.rate_hz = 200;
  opt.protocol = GuidedProtocol::kFree;
  HandHeld robot;
  for (const Eigen::Vector3d& up :
       {Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(0, 0, -1), Eigen::Vector3d(0, 1, 0),
        Eigen::Vector3d(0, -1, 0), Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(-1, 0, 0)})
    robot.Hold(up);
  OnlineSegmenter seg(opt);
  Fed fed = FeedAll(seg, robot.capture());
  ASSERT_EQ(Accepted(fed).size(), 6u);
  GuideProgress p = seg.Progress();
  EXPECT_EQ(p.done, (std::vector<std::string>{"Z+", "Z-", "Y+", "Y-", "X+", "X-"}));
  EXPECT_EQ(p.pending.size(), 8u);  // the corners
  EXPECT_EQ(p.poses_wanted, 18);
  EXPECT_NEAR(p.coverage, 6.0 / 14.0, 1e-12);
  // The last pose had its tail up: the next is a corner with the tail up, in words.
  const NextPoseUpdate next = fed.next.back();
  EXPECT_EQ(next.face.substr(0, 2), "X-");
  EXPECT_EQ(next.face.size(), 6u);
  EXPECT_NE(next.instruction.find("its tail (-X)"), std::string::npos) << next.instruction;
  EXPECT_NE(next.instruction.find("(8 directions to go)"), std::string::npos) << next.instruction;
  EXPECT_FALSE(next.done);

  // A face again adds a pose, not coverage, and the guide says so.
  HandHeld again;
  for (const Eigen::Vector3d& up : {Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(0, 0, 1)})
    again.Hold(up);
  OnlineSegmenter seg2(opt);
  const Fed fed2 = FeedAll(seg2, again.capture());
  ASSERT_EQ(Accepted(fed2).size(), 2u);
  EXPECT_EQ(fed2.next.back().instruction.rfind("That was Z+ up again. ", 0), 0u)
      << fed2.next.back().instruction;
  EXPECT_EQ(seg2.Progress().done.size(), 1u);

  // The 8 corners, then 4 poses anywhere: complete at 18 poses.
  for (int c = 0; c < 8; ++c)
    robot.Hold(Eigen::Vector3d(c & 1 ? 1 : -1, c & 2 ? 1 : -1, c & 4 ? 1 : -1));
  OnlineSegmenter seg3(opt);
  fed = FeedAll(seg3, robot.capture());
  ASSERT_EQ(Accepted(fed).size(), 14u);
  p = seg3.Progress();
  EXPECT_TRUE(p.pending.empty());
  EXPECT_EQ(p.coverage, 1.0);
  EXPECT_EQ(p.poses_wanted, 18);
  EXPECT_NE(fed.next.back().instruction.find("4 more poses"), std::string::npos)
      << fed.next.back().instruction;
  for (int e = 0; e < 4; ++e) robot.Hold(Eigen::Vector3d(1, e & 1 ? 1 : -1, e & 2 ? 0.3 : -0.3));
  OnlineSegmenter seg4(opt);
  fed = FeedAll(seg4, robot.capture());
  ASSERT_EQ(Accepted(fed).size(), 18u);
  EXPECT_TRUE(fed.next.back().done) << fed.next.back().instruction;
  EXPECT_EQ(seg4.Progress().poses_wanted, 18);
}

}  // namespace
}  // namespace imucal::core
