// Calibration stage "protocol": which protocol the capture follows (declared, or detected from
// the poses' up directions) and the checks it allows:
//   six-face  each face's 180-degree pair: same face, mirrored horizontal components, turned
//             about the vertical by 180 degrees (core/protocol.h CheckSixFacePairs);
//   ferraris  a full turn about the vertical with each axis up;
//   all       a pose that repeats the previous one without a re-placement is a duplicate.
// And the references the protocol gives the accelerometer: each face's reading against +-g on
// its axis (pair-averaged for six-face, each placement for ferraris), and the case frame that
// maps the faces onto those axes.
#ifndef IMUCAL_CORE_CALIBRATE_PROTOCOL_CHECKS_H_
#define IMUCAL_CORE_CALIBRATE_PROTOCOL_CHECKS_H_

#include <functional>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "core/calibrate/calibrate.h"
#include "core/calibrate/gyro_stage.h"
#include "core/calibrate/static_poses.h"
#include "core/capture.h"
#include "core/protocol.h"

namespace imucal::core::pipeline {

struct ProtocolChecks {
  ProtocolKind protocol = ProtocolKind::kFree;
  bool detected = false;
  std::vector<PairCheck> pairs;  // six-face
  // The static intervals with duplicates marked unused (and why), and the up direction of each
  // with the sweep's rough accelerometer (unit, body frame).
  std::vector<StaticInterval> intervals;
  std::vector<Eigen::Vector3d> ups;
  std::vector<std::string> warnings;
};
ProtocolChecks CheckProtocol(const Capture& capture, const CalibrateOptions& options,
                             const StaticPoses& static_poses, const RoughGyro& rough);

// Face readings (raw means, input units) and their references (+-g on the face axis, m/s^2).
struct FaceReferences {
  std::vector<Eigen::Vector3d> means, refs;
};
// Six-face: the verified pairs' averaged readings (the floor tilt cancels to first order).
FaceReferences VerifiedFaces(const std::vector<StaticInterval>& intervals,
                             const std::vector<PairCheck>& pairs,
                             const std::vector<Eigen::Vector3d>& ups, double gravity_m_s2);
// Ferraris: each face held once (or more, averaged per face). No pair cancels the floor tilt: it
// stays in the misalignment angles.
FaceReferences SingleFaces(const std::vector<StaticInterval>& intervals,
                           const std::vector<int>& used, const std::vector<Eigen::Vector3d>& ups,
                           double gravity_m_s2);

// The case frame (frame_angles, rad) for `accel`: the rotation that best maps its frame-free
// output of the faces onto +-g (Kabsch), so frame_angles agree with the refined scale and angles.
Eigen::Vector3d FrameAngles(const AccelParams& accel, const FaceReferences& faces);

// A verified pair's face direction (unit) from its two poses' specific forces `a` and `b`: the
// axis the unit was turned about (core/protocol.h PairTurnAxis, from the turn the calibrated
// gyroscope measured) instead of the pair's mean, which a turn of 180 + e degrees on a floor
// tilted by t leaves t * e / 2 off. A pair whose turn was not measured keeps its mean.
Eigen::Vector3d PairFaceAxis(const PairCheck& pair, const Eigen::Vector3d& a,
                             const Eigen::Vector3d& b);

// The six-face case frame from the axes the pairs were turned about: FrameAngles with each
// verified pair's face direction its PairFaceAxis. `frame_free(i)` is the specific force of pose
// i (an interval index) in the model's frame-free output. Sets accel->frame_angles and returns
// R_new_old, the turn from the old case frame to the new one, for the gyroscope to follow
// (gyro_stage.h TurnGyroFrame).
Eigen::Matrix3d SetCaseFrameFromPairAxes(const std::vector<PairCheck>& pairs, double gravity_m_s2,
                                         const std::function<Eigen::Vector3d(int)>& frame_free,
                                         AccelParams* accel);

}  // namespace imucal::core::pipeline

#endif  // IMUCAL_CORE_CALIBRATE_PROTOCOL_CHECKS_H_
