#include "core/protocol.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <numbers>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/simulator.h"

namespace imucal::core {
namespace {

constexpr double kPi = std::numbers::pi;
constexpr double kDegToRad = kPi / 180.0;

Eigen::Matrix3d Rot(double deg, const Eigen::Vector3d& axis) {
  return Eigen::AngleAxisd(deg * kDegToRad, axis.normalized()).toRotationMatrix();
}

// ---------------------------------------------------------------------------------------------
// Faces and names.

TEST(ProtocolTest, ClassifyFaceFindsTheAxisClosestToUp) {
  struct Case {
    Eigen::Vector3d up;
    int axis, sign;
    const char* label;
  };
  const Case cases[] = {
      {{0, 0, 1}, 2, 1, "Z+"},     {{0, 0, -9.8}, 2, -1, "Z-"}, {{9.8, 0.3, -0.2}, 0, 1, "X+"},
      {{-1, 0.1, 0}, 0, -1, "X-"}, {{0.2, 5, 0.1}, 1, 1, "Y+"}, {{0.1, -3, 0.4}, 1, -1, "Y-"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.label);
    const Face f = ClassifyFace(c.up);
    EXPECT_EQ(f.axis, c.axis);
    EXPECT_EQ(f.sign, c.sign);
    EXPECT_EQ(f.Label(), c.label);
    const Eigen::Vector3d u = c.up.normalized();
    EXPECT_NEAR(f.off_axis_deg, std::acos(std::abs(u(c.axis))) / kDegToRad, 1e-9);
  }
  EXPECT_NEAR(ClassifyFace(Eigen::Vector3d(-1, 0.1, 0)).off_axis_deg, std::atan(0.1) / kDegToRad,
              1e-9);
  // 45 degrees between two axes is far off every face.
  EXPECT_GT(ClassifyFace(Eigen::Vector3d(1, 1, 0)).off_axis_deg, kFaceToleranceDeg);
  Face a = ClassifyFace(Eigen::Vector3d(0, 0, 1)), b = ClassifyFace(Eigen::Vector3d(0.1, 0, 1));
  EXPECT_TRUE(a == b);
  EXPECT_FALSE(a == ClassifyFace(Eigen::Vector3d(0, 0, -1)));
}

TEST(ProtocolTest, ParsesProtocolNames) {
  EXPECT_EQ(*ParseProtocolKind("auto"), ProtocolKind::kAuto);
  EXPECT_EQ(*ParseProtocolKind("six-face"), ProtocolKind::kSixFace);
  EXPECT_EQ(*ParseProtocolKind("positions"), ProtocolKind::kPositions);
  EXPECT_EQ(*ParseProtocolKind("positions24"), ProtocolKind::kPositions);
  EXPECT_EQ(*ParseProtocolKind("positions36"), ProtocolKind::kPositions);
  EXPECT_EQ(*ParseProtocolKind("free"), ProtocolKind::kFree);
  const absl::StatusOr<ProtocolKind> bad = ParseProtocolKind("sixface");
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(bad.status().message().find("sixface"), std::string::npos);
  for (ProtocolKind k : {ProtocolKind::kAuto, ProtocolKind::kSixFace, ProtocolKind::kPositions,
                         ProtocolKind::kFree}) {
    EXPECT_EQ(*ParseProtocolKind(ProtocolKindName(k)), k);
  }
}

// ---------------------------------------------------------------------------------------------
// Detection from the simulator's true up directions.

std::vector<Eigen::Vector3d> TrueUps(const SimResult& sim) {
  std::vector<Eigen::Vector3d> ups;
  for (const SimPose& p : sim.poses)
    ups.push_back(p.R_world_body.transpose() * Eigen::Vector3d::UnitZ());
  return ups;
}

TEST(ProtocolTest, DetectsSimulatedProtocols) {
  struct Case {
    SimProtocol sim;
    int extra_poses;
    ProtocolKind expected;
  };
  const Case cases[] = {
      {SimProtocol::kSixFace, 0, ProtocolKind::kSixFace},
      {SimProtocol::kSixFace, 24, ProtocolKind::kSixFace},
      {SimProtocol::kPositions24, 0, ProtocolKind::kPositions},
      {SimProtocol::kPositions36, 0, ProtocolKind::kPositions},
      {SimProtocol::kFree, 0, ProtocolKind::kFree},
  };
  for (const Case& c : cases) {
    for (uint64_t seed = 1; seed <= 10; ++seed) {
      SCOPED_TRACE(
          absl::StrFormat("%s + %d extra, seed %d", ProtocolName(c.sim), c.extra_poses, seed));
      SimOptions options;
      options.protocol = c.sim;
      options.seed = seed;
      options.extra_poses = c.extra_poses;
      options.rate_hz = 20;  // only the poses matter here
      const absl::StatusOr<SimResult> sim = Simulate(options);
      ASSERT_TRUE(sim.ok()) << sim.status();
      EXPECT_EQ(ProtocolKindName(DetectProtocol(TrueUps(*sim))), ProtocolKindName(c.expected));
    }
  }
  EXPECT_EQ(DetectProtocol({}), ProtocolKind::kFree);
}

// ---------------------------------------------------------------------------------------------
// Six-face pair checks on hand-made placements.
//
// A placement is R_world_body = R_world_floor * Rz(yaw) * F, with F the face's orientation on a
// level floor and R_world_floor a small floor tilt. Turning the robot about the floor normal
// changes yaw only; the rotation between two placements (body frame) is Log(R_a^T R_b).

class Placements {
 public:
  explicit Placements(double floor_tilt_deg = 1.0)
      : floor_(Rot(floor_tilt_deg, Eigen::Vector3d(0.6, 0.8, 0))) {}

  // Face orientation F: body `axis` (0..2) with `sign` pointing up.
  static Eigen::Matrix3d FaceUp(int axis, int sign) {
    Eigen::Vector3d body_axis = Eigen::Vector3d::Zero();
    body_axis(axis) = sign;
    // F maps body to floor: F * body_axis = e_z.
    return Eigen::Quaterniond::FromTwoVectors(body_axis, Eigen::Vector3d::UnitZ())
        .toRotationMatrix();
  }

  Placements& Place(int axis, int sign, double yaw_deg) {
    return PlaceRotation(floor_ * Rot(yaw_deg, Eigen::Vector3d::UnitZ()) * FaceUp(axis, sign));
  }
  Placements& PlaceRotation(const Eigen::Matrix3d& r_world_body) {
    FacePose p;
    p.index = static_cast<int>(poses_.size());
    p.up = r_world_body.transpose() * Eigen::Vector3d::UnitZ();
    if (!rotations_.empty()) {
      const Eigen::AngleAxisd aa(rotations_.back().transpose() * r_world_body);
      p.rotation_from_previous = aa.angle() * aa.axis();
    }
    rotations_.push_back(r_world_body);
    poses_.push_back(p);
    return *this;
  }
  // The full protocol: each face, then the same face turned by 180 + turn_error_deg.
  Placements& AllFaces(double turn_error_deg = 0.0) {
    double yaw = 10;
    for (int axis : {2, 0, 1}) {
      for (int sign : {1, -1}) {
        Place(axis, sign, yaw).Place(axis, sign, yaw + 180 + turn_error_deg);
        yaw += 37;
      }
    }
    return *this;
  }
  const std::vector<FacePose>& poses() const { return poses_; }

 private:
  Eigen::Matrix3d floor_;
  std::vector<Eigen::Matrix3d> rotations_;
  std::vector<FacePose> poses_;
};

std::string Describe(const SixFaceCheck& check) {
  std::string out;
  for (const PairCheck& p : check.pairs) {
    out += absl::StrFormat("  pair %d-%d %s ok=%d tilt %.2f rot %.1f: %s\n", p.pose_a, p.pose_b,
                           p.face, p.ok, p.tilt_deg, p.rotation_deg, p.reason);
  }
  for (const std::string& m : check.missing) out += "  missing: " + m + "\n";
  return out;
}

const PairCheck* FindPair(const SixFaceCheck& check, int a, int b) {
  for (const PairCheck& p : check.pairs)
    if (p.pose_a == a && p.pose_b == b) return &p;
  return nullptr;
}

TEST(ProtocolTest, GoodPairPasses) {
  for (const double turn_error : {-15.0, -3.0, 0.0, 4.0, 15.0}) {
    SCOPED_TRACE(absl::StrFormat("turn error %.0f degrees", turn_error));
    Placements pl(1.0);
    pl.Place(2, 1, 30).Place(2, 1, 30 + 180 + turn_error);
    const SixFaceCheck check = CheckSixFacePairs(pl.poses());
    ASSERT_EQ(check.pairs.size(), 1u) << Describe(check);
    const PairCheck& p = check.pairs[0];
    EXPECT_TRUE(p.ok) << p.reason;
    EXPECT_TRUE(p.reason.empty()) << p.reason;
    EXPECT_EQ(p.pose_a, 0);
    EXPECT_EQ(p.pose_b, 1);
    EXPECT_EQ(p.face, "Z+");
    // The measured rotation is an angle in [0, 180]: 180 + e and 180 - e read the same.
    EXPECT_NEAR(p.rotation_deg, 180 - std::abs(turn_error), 1e-6);
    // Half the angle between the two ups is the floor tilt (exactly, for a 180-degree turn).
    if (turn_error == 0.0) {
      EXPECT_NEAR(p.tilt_deg, 1.0, 1e-6);
    }
    // The other five faces are missing.
    EXPECT_EQ(check.missing.size(), 5u) << Describe(check);
  }
}

// A turn of 180 + e degrees on a tilted floor: the pair's mean misses the face axis by about
// tilt * e / 2; the axis recovered with the gyro's turn angle does not, whichever way the unit
// was turned and whichever side of 180 degrees the turn ended.
TEST(ProtocolTest, PairTurnAxisUndoesTheTurnError) {
  const Eigen::Vector3d axis = Eigen::Vector3d(0.01, -0.02, 1.0).normalized();
  const Eigen::Vector3d across = axis.cross(Eigen::Vector3d::UnitX()).normalized();
  for (const double tilt_deg : {0.5, 1.0, 3.0}) {
    for (const double turn_error_deg : {-6.0, -3.0, 2.0, 5.0}) {
      for (const double sense : {1.0, -1.0}) {
        SCOPED_TRACE(absl::StrFormat("tilt %.1f deg, turn 180 %+.0f deg, sense %+.0f", tilt_deg,
                                     turn_error_deg, sense));
        const Eigen::Vector3d up_a = Rot(tilt_deg, across) * axis;
        const Eigen::Matrix3d turn = Rot(sense * (180 + turn_error_deg), axis);  // R_a^T R_b
        const Eigen::Vector3d up_b = turn.transpose() * up_a;
        const Eigen::AngleAxisd logged(turn);  // as integrated: an angle in [0, 180] degrees
        const Eigen::Vector3d turn_rad = logged.angle() * logged.axis();
        const double mean_miss = std::acos(std::min(1.0, (up_a + up_b).normalized().dot(axis)));
        EXPECT_NEAR(mean_miss, 0.5 * tilt_deg * std::abs(turn_error_deg) * kDegToRad * kDegToRad,
                    0.1 * mean_miss);
        EXPECT_LT((PairTurnAxis(up_a, up_b, turn_rad) - axis).norm(), 1e-9);
        // The gyro's own misalignment (a few mrad) turns its rotation vector, not its angle.
        const Eigen::Vector3d misaligned = Rot(0.3, Eigen::Vector3d(1, 2, 0)) * turn_rad;
        EXPECT_LT((PairTurnAxis(up_a, up_b, misaligned) - axis).norm(), 1e-9);
      }
    }
  }
  // Degenerate input gives the mean: no tilt (the ups coincide), or no turn at all.
  const Eigen::Vector3d up = Eigen::Vector3d(0.0, 0.1, 1.0).normalized();
  EXPECT_LT((PairTurnAxis(up, up, Eigen::Vector3d(0, 0, 3.0)) - up).norm(), 1e-12);
  const Eigen::Vector3d other = Eigen::Vector3d(0.0, -0.1, 1.0).normalized();
  EXPECT_LT((PairTurnAxis(up, other, Eigen::Vector3d::Zero()) - Eigen::Vector3d::UnitZ()).norm(),
            1e-12);
}

TEST(ProtocolTest, AllSixFacesPairedWithNothingMissing) {
  for (const double turn_error : {0.0, 3.0, -7.0}) {
    SCOPED_TRACE(absl::StrFormat("turn error %.0f degrees", turn_error));
    Placements pl(1.5);
    pl.AllFaces(turn_error);
    const SixFaceCheck check = CheckSixFacePairs(pl.poses());
    ASSERT_EQ(check.pairs.size(), 6u) << Describe(check);
    for (size_t k = 0; k < 6; ++k) {
      EXPECT_TRUE(check.pairs[k].ok) << Describe(check);
      EXPECT_EQ(check.pairs[k].pose_a, static_cast<int>(2 * k));
      EXPECT_EQ(check.pairs[k].pose_b, static_cast<int>(2 * k + 1));
      EXPECT_NEAR(check.pairs[k].tilt_deg, 1.5, 0.01);
    }
    EXPECT_TRUE(check.missing.empty()) << Describe(check);
  }
}

TEST(ProtocolTest, NinetyDegreeTurnIsRejected) {
  Placements pl;
  pl.Place(0, -1, 0).Place(0, -1, 90);
  const SixFaceCheck check = CheckSixFacePairs(pl.poses());
  ASSERT_EQ(check.pairs.size(), 1u) << Describe(check);
  EXPECT_FALSE(check.pairs[0].ok);
  EXPECT_NEAR(check.pairs[0].rotation_deg, 90, 1e-6);
  EXPECT_NE(check.pairs[0].reason.find("turned 90"), std::string::npos) << check.pairs[0].reason;
  ASSERT_EQ(check.missing.size(), 6u) << Describe(check);
  bool x_minus = false;
  for (const std::string& m : check.missing)
    x_minus |= m.find("X-") != std::string::npos && m.find("0, 1") != std::string::npos;
  EXPECT_TRUE(x_minus) << "X- must be named with its placements:\n" << Describe(check);
}

TEST(ProtocolTest, TurnOutsideToleranceIsRejected) {
  Placements pl;
  pl.Place(1, 1, 0).Place(1, 1, 150);
  const SixFaceCheck strict = CheckSixFacePairs(pl.poses(), 20.0);
  ASSERT_EQ(strict.pairs.size(), 1u) << Describe(strict);
  EXPECT_FALSE(strict.pairs[0].ok);
  EXPECT_NE(strict.pairs[0].reason.find("turned 150"), std::string::npos) << strict.pairs[0].reason;
  const SixFaceCheck loose = CheckSixFacePairs(pl.poses(), 40.0);
  ASSERT_EQ(loose.pairs.size(), 1u) << Describe(loose);
  EXPECT_TRUE(loose.pairs[0].ok) << loose.pairs[0].reason;
}

TEST(ProtocolTest, PlacementWithoutTurnIsRejected) {
  Placements pl;
  pl.Place(2, -1, 40).Place(2, -1, 43);
  const SixFaceCheck check = CheckSixFacePairs(pl.poses());
  ASSERT_EQ(check.pairs.size(), 1u) << Describe(check);
  EXPECT_FALSE(check.pairs[0].ok);
  EXPECT_NE(check.pairs[0].reason.find("not turned"), std::string::npos) << check.pairs[0].reason;
}

TEST(ProtocolTest, WrongFaceGivesNoPairAndNamesTheFace) {
  // The second placement should have been Z- turned, but Y+ was put up instead. Z- is never
  // verified; the other faces are.
  Placements pl;
  pl.Place(2, 1, 0).Place(2, 1, 180);
  pl.Place(2, -1, 20).Place(1, 1, 200);  // wrong face
  pl.Place(0, 1, 0).Place(0, 1, 180).Place(0, -1, 0).Place(0, -1, 180);
  pl.Place(1, 1, 0).Place(1, 1, 180).Place(1, -1, 0).Place(1, -1, 180);
  const SixFaceCheck check = CheckSixFacePairs(pl.poses());
  int ok = 0;
  for (const PairCheck& p : check.pairs) {
    ok += p.ok;
    EXPECT_FALSE(p.ok && p.face == "Z-") << Describe(check);
    // Nothing is ever paired across two different faces.
    if (p.ok) {
      EXPECT_EQ(ClassifyFace(pl.poses()[p.pose_a].up).Label(),
                ClassifyFace(pl.poses()[p.pose_b].up).Label());
    }
  }
  EXPECT_EQ(ok, 5) << Describe(check);
  ASSERT_EQ(check.missing.size(), 1u) << Describe(check);
  EXPECT_NE(check.missing[0].find("Z-"), std::string::npos) << check.missing[0];
  EXPECT_NE(check.missing[0].find("poses 2)"), std::string::npos)
      << "names the placement: " << check.missing[0];
}

TEST(ProtocolTest, RedonePlacementIsPairedAndTheBadOneRejected) {
  // X+ at yaw 0, then a 90-degree placement (bad), then the technician turns it another 90:
  // the third placement is the proper half turn from the first.
  Placements pl;
  pl.Place(0, 1, 0).Place(0, 1, 90).Place(0, 1, 181);
  const SixFaceCheck check = CheckSixFacePairs(pl.poses());
  const PairCheck* bad = FindPair(check, 0, 1);
  const PairCheck* redo = FindPair(check, 0, 2);
  ASSERT_NE(bad, nullptr) << Describe(check);
  ASSERT_NE(redo, nullptr) << Describe(check);
  EXPECT_FALSE(bad->ok);
  EXPECT_NE(bad->reason.find("turned 90"), std::string::npos) << bad->reason;
  EXPECT_TRUE(redo->ok) << redo->reason;
  EXPECT_NEAR(redo->rotation_deg, 179, 1e-6);
  for (const std::string& m : check.missing) EXPECT_EQ(m.find("X+"), std::string::npos) << m;
  EXPECT_EQ(check.missing.size(), 5u) << Describe(check);
}

TEST(ProtocolTest, RedoneSequenceContinuesWithTheNextFace) {
  // A full session with one re-done placement in the middle: all six faces verified.
  Placements pl;
  pl.Place(2, 1, 0).Place(2, 1, 180);
  pl.Place(2, -1, 10).Place(2, -1, 100).Place(2, -1, 190);  // 90, then 90 more
  pl.Place(0, 1, 0).Place(0, 1, 180).Place(0, -1, 0).Place(0, -1, 180);
  pl.Place(1, 1, 0).Place(1, 1, 180).Place(1, -1, 0).Place(1, -1, 180);
  const SixFaceCheck check = CheckSixFacePairs(pl.poses());
  int ok = 0, rejected = 0;
  for (const PairCheck& p : check.pairs) (p.ok ? ok : rejected)++;
  EXPECT_EQ(ok, 6) << Describe(check);
  EXPECT_EQ(rejected, 1) << Describe(check);
  ASSERT_NE(FindPair(check, 2, 4), nullptr) << Describe(check);
  EXPECT_TRUE(FindPair(check, 2, 4)->ok);
  EXPECT_TRUE(check.missing.empty()) << Describe(check);
}

TEST(ProtocolTest, ExtraPlacementsAfterAVerifiedPairAreNotPairs) {
  // Extra poses after the protocol may put a face up twice in a row, turned by anything: they
  // are not a six-face pair and must not be "rejected" (a technician would redo them).
  Placements pl;
  pl.AllFaces(2.0);
  pl.Place(0, -1, 5).Place(0, -1, 65);  // X- again, turned 60 degrees
  pl.Place(2, 1, 0).Place(2, 1, 3);     // Z+ again, not turned
  const SixFaceCheck check = CheckSixFacePairs(pl.poses());
  EXPECT_EQ(check.pairs.size(), 6u) << Describe(check);
  for (const PairCheck& p : check.pairs) EXPECT_TRUE(p.ok) << Describe(check);
  EXPECT_TRUE(check.missing.empty()) << Describe(check);
}

TEST(ProtocolTest, MissingFacesAreListed) {
  Placements pl;
  pl.Place(0, 1, 0).Place(0, 1, 180).Place(1, 1, 0).Place(1, 1, 180);
  const SixFaceCheck check = CheckSixFacePairs(pl.poses());
  ASSERT_EQ(check.pairs.size(), 2u) << Describe(check);
  EXPECT_TRUE(check.pairs[0].ok && check.pairs[1].ok) << Describe(check);
  ASSERT_EQ(check.missing.size(), 4u) << Describe(check);
  for (const char* face : {"X-", "Y-", "Z+", "Z-"}) {
    bool listed = false;
    for (const std::string& m : check.missing)
      listed |= m.find(face) != std::string::npos && m.find("never placed") != std::string::npos;
    EXPECT_TRUE(listed) << face << " not listed as never placed:\n" << Describe(check);
  }
}

TEST(ProtocolTest, PosesOffEveryFaceAreNotPaired) {
  Placements pl;
  // Two placements 45 degrees between X and Z, turned 180 about the vertical.
  const Eigen::Matrix3d tilt45 = Rot(45, Eigen::Vector3d::UnitY());
  pl.PlaceRotation(tilt45).PlaceRotation(Rot(180, Eigen::Vector3d::UnitZ()) * tilt45);
  const SixFaceCheck check = CheckSixFacePairs(pl.poses());
  EXPECT_TRUE(check.pairs.empty()) << Describe(check);
  EXPECT_EQ(check.missing.size(), 6u) << Describe(check);
}

}  // namespace
}  // namespace imucal::core
