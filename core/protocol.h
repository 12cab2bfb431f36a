// Calibration protocols: which poses a capture holds and what can be checked about them.
//   six-face  (seeds/000): each face up twice, the second time turned 180 degrees about the
//             vertical; the pair's mean cancels the floor tilt to first order, the turn's
//             axis (PairTurnAxis) whatever the turn's error.
//   positions (seeds/002): 24 or 36 positions, three groups turned about a horizontal axis.
//   free      (Tedaldi, IMU-TK): hand-held poses anywhere on the sphere.
//   faces     (seeds/000 without pairs): the six faces, each held once (or more), nothing else:
//             the 12-parameter least squares against +-g, the floor assumed level.
//   ferraris  (Ferraris et al. 1995): each face up once (no 180-degree pair, so the floor tilt
//             is not cancelled) plus full 360-degree turns, whose known angle gives the
//             gyroscope's scale and misalignment. core/calibrate/gyro_stage.cc detects the turns.
#ifndef IMUCAL_CORE_PROTOCOL_H_
#define IMUCAL_CORE_PROTOCOL_H_

#include <array>
#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"

namespace imucal::core {

enum class ProtocolKind { kAuto, kSixFace, kPositions, kFree, kFerraris, kFaces };

// "auto", "six-face", "positions", "free", "ferraris", "faces"
std::string_view ProtocolKindName(ProtocolKind kind);
// Accepts the names above and "positions24", "positions36".
absl::StatusOr<ProtocolKind> ParseProtocolKind(std::string_view name);

// The face that is up: the body axis closest to the measured up (specific-force) direction.
struct Face {
  int axis = 2;               // 0 x, 1 y, 2 z
  int sign = 1;               // +1: that axis points up (reads +g)
  double off_axis_deg = 0;    // angle between up and that axis
  std::string Label() const;  // "Z+", "X-", ...
  // What the face reads at rest: `g` on its axis with its sign, zero on the others (in the unit
  // of g: m/s^2 when g is).
  Eigen::Vector3d Reference(double g) const;
  bool operator==(const Face& o) const { return axis == o.axis && sign == o.sign; }
};
Face ClassifyFace(const Eigen::Vector3d& up_body);

// Poses more than this far from every axis are not "on a face".
inline constexpr double kFaceToleranceDeg = 20.0;

// The placements of each face (indices into `ups`), in the order X+, X-, Y+, Y-, Z+, Z-: the
// poses whose up direction is within kFaceToleranceDeg of that face's axis.
std::array<std::vector<int>, 6> FacePlacements(const std::vector<Eigen::Vector3d>& ups);
// True when every one of the six faces has at least one placement.
bool CoversSixFaces(const std::vector<Eigen::Vector3d>& ups);

// Auto-detection from the up directions of the usable poses (body frame, unit vectors), in
// time order.
ProtocolKind DetectProtocol(const std::vector<Eigen::Vector3d>& ups);

struct PairCheck {
  int pose_a = -1, pose_b = -1;  // indices into the caller's pose list
  bool ok = false;
  double tilt_deg = 0;      // half the angle between the two up directions (floor tilt)
  double rotation_deg = 0;  // gyro-integrated rotation between the poses about the vertical
  // The calibrated gyroscope's body rotation vector from pose a to pose b, rad (Exp = R_a^T R_b):
  // core/calibrate/gyro_stage.cc measures it once the gyroscope is calibrated. Zero until then,
  // when the gyroscope could not be calibrated, and when the turn crossed a time gap (not
  // measured).
  Eigen::Vector3d rotation_rad = Eigen::Vector3d::Zero();
  std::string face;
  std::string reason;  // why rejected, in a technician's words
  // False when the gyroscope could not measure the turn (a time gap, or a capture without a
  // gyroscope): only the faces and the mirrored components were checked; the turn is "not
  // checked", neither passed nor failed.
  bool turn_checked = true;
};

// What the six-face check needs to know about one usable pose, in time order.
struct FacePose {
  int index = -1;      // the caller's pose index
  Eigen::Vector3d up;  // unit up direction, body frame
  // Rotation from the previous FacePose to this one (body frame rotation vector, rad), from the
  // calibrated gyroscope; ignored for the first pose.
  Eigen::Vector3d rotation_from_previous = Eigen::Vector3d::Zero();
  // False when the gyroscope cannot measure that rotation (a time gap in the move): the pair's
  // turn is then not checked, only its faces and mirrored components.
  bool rotation_known = true;
};

// Pairs consecutive placements of the same face and verifies each: same face up, horizontal
// components mirrored (their mean is the installation misalignment, small), turned about the
// vertical by 180 +- tolerance. Faces with no valid pair are named in `missing`.
struct SixFaceCheck {
  std::vector<PairCheck> pairs;
  // "face X-: no verified 180-degree pair (placements at poses 4, 5)" or "face X-: never placed".
  // A wrong face after a turn shows here: its placement is missing its partner.
  std::vector<std::string> missing;
};
SixFaceCheck CheckSixFacePairs(const std::vector<FacePose>& poses,
                               double turn_tolerance_deg = 20.0);

// The face axis of a verified pair: the floor normal (body frame, unit) that the unit was turned
// about between its two up directions `up_a` and `up_b` (unit, body frame). `turn_rad` is the
// gyro-integrated body rotation vector from pose a to pose b (Exp(turn) = R_a^T R_b, so
// up_b = Exp(-turn) up_a).
//
// The pair's mean (up_a + up_b) / 2 is that axis only for an exact 180-degree turn. A turn of
// 180 + e degrees on a floor tilted by t leaves the mean t * e / 2 off (1 degree and 3 degrees:
// 0.46 mrad, several times the frame's noise). The axis lies in the bisector plane of up_a and
// up_b; the turn's angle |turn| fixes where: with half-angle t between the ups (tan t = b / a
// in the plane's coordinates), the axis is tilted from the mean by phi, sin phi = tan t /
// tan(|turn| / 2), towards the side the turn's sense selects. Only |turn| and the sign of turn
// along the mean are read, so the gyro's own misalignment (what the frame is used to fit) does
// not enter. Returns the mean direction when the ups coincide or there is no turn, and when the
// axis would lie more than 0.1 rad from the mean (a turn far from 180 degrees on a steep floor;
// at 1 degree of tilt, a turn under about 20 degrees). The caller passes only turns measured by
// a calibrated gyroscope, of pairs whose turn was verified near 180 degrees.
Eigen::Vector3d PairTurnAxis(const Eigen::Vector3d& up_a, const Eigen::Vector3d& up_b,
                             const Eigen::Vector3d& turn_rad);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_PROTOCOL_H_
