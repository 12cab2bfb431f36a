// Calibration stage "gyro": the gyroscope, twice.
//
// 1. Rough (before the protocol checks): the bias from the static poses and a scale good to a few
//    percent: the nominal factor of the capture's unit, or for raw counts an isotropic scale from
//    the data (the moves', else the full turns'). It measures the six-face turns and the path of
//    each move, which tolerate that error. The full turns (Ferraris et al. 1995) are found here:
//    between two still stretches, the same up direction at both ends, a path about one axis in
//    one direction, whole turns with the rough scale.
// 2. Final (after the accelerometer): scale and misalignment from the rotations between poses
//    (core/gyro_solver.h) and the full turns, against the final accelerometer's pose directions.
//    Moves across a time gap, or whose gravity direction turned further than the gyroscope
//    measured (a cut in the data), are left out with a warning.
// Then the pairs' turns are measured with the calibrated gyroscope, and (six-face) the case frame
// is taken from the axes the pairs were turned about; the gyroscope turns with the frame.
#ifndef IMUCAL_CORE_CALIBRATE_GYRO_STAGE_H_
#define IMUCAL_CORE_CALIBRATE_GYRO_STAGE_H_

#include <optional>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "core/calibrate/calibrate.h"
#include "core/calibrate/static_poses.h"
#include "core/capture.h"
#include "core/gyro_solver.h"
#include "core/model.h"
#include "core/protocol.h"
#include "core/static_detector.h"

namespace imucal::core::pipeline {

// Body rotation (rotation vector, rad) over samples [begin, end] with the calibrated gyro.
Eigen::Vector3d IntegrateRotation(const Capture& capture, size_t begin, size_t end,
                                  const GyroParams& gyro);
// Integral of |rate| (rad, with `gyro`) over samples [begin, end]: the path angle.
double PathAngle(const Capture& capture, size_t begin, size_t end, const GyroParams& gyro);
// Sample-weighted mean of the static gyro readings: the constant bias of the model.
Eigen::Vector3d StaticGyroBias(const std::vector<StaticInterval>& intervals,
                               const std::vector<int>& used);

// A full-turn candidate: its samples, end up directions and raw integral.
struct TurnCandidate {
  GyroFullTurn turn;
  Eigen::Vector3d up = Eigen::Vector3d::UnitZ();           // mean of the two ends' up directions
  Eigen::Vector3d raw_integral = Eigen::Vector3d::Zero();  // sum of c_k, input unit * s
};

struct RoughGyro {
  GyroParams params;                 // bias and an isotropic (or nominal) scale
  std::vector<TurnCandidate> turns;  // the full turns accepted with that scale
  std::vector<TurnReport> turn_reports;
};
RoughGyro EstimateRoughGyro(const Capture& capture, const CalibrateOptions& options,
                            const StaticPoses& static_poses);

// A move between two used poses as the gyroscope fit sees it (from_pose/to_pose index the
// intervals).
struct PlannedMove {
  int from_pose = 0, to_pose = 0;
  GyroMove move;
};
std::vector<GyroMove> OnlyMoves(const std::vector<PlannedMove>& planned);

// A gyroscope fitted to moves and turns.
struct GyroFit {
  GyroParams params;
  bool calibrated = false;  // scale and misalignment determined (else the rough matrix, bias only)
  std::optional<GyroSolveResult> result;
  std::vector<std::string> warnings;
};
// Fits the gyroscope matrix to `planned` and `turns` from `initial` (its matrix the start, its
// bias the constant bias; each move uses the bias measured at the poses on either side of it).
GyroFit FitGyro(const Capture& capture, const std::vector<PlannedMove>& planned,
                const std::vector<TurnCandidate>& turns, const GyroParams& initial);

struct FinalGyro {
  GyroFit fit;
  std::vector<PlannedMove> planned;   // the moves it was fitted on
  std::vector<std::string> warnings;  // moves left out, then the fit's own
};
// Plans the moves between the used poses with `accel`'s pose directions and fits the gyroscope to
// them and the full turns, from the rough gyroscope with the static bias.
FinalGyro SolveFinalGyro(const Capture& capture, const std::vector<StaticInterval>& intervals,
                         const std::vector<int>& used, const AccelParams& accel,
                         const TimeGaps& gaps, const RoughGyro& rough);

// The pairs' turns as `gyro` measures them (PairCheck::rotation_deg, and rotation_rad when the
// gyroscope is calibrated: only then is the angle good to the milliradians the turn axis needs),
// with the bias the pair's own two poses read: both have the same face up, so a bias that follows
// the pose or the warm-up cancels. Turns across a time gap stay unmeasured.
void MeasurePairTurns(const Capture& capture, const std::vector<StaticInterval>& intervals,
                      const GyroFit& gyro, std::vector<PairCheck>* pairs);

// Turns the gyroscope's output frame by R_new_old (new body = R_new_old * old body): its matrix
// and its coupling to specific force (which is in the body frame on both sides).
void TurnGyroParams(const Eigen::Matrix3d& R_new_old, GyroParams* gyro);
// TurnGyroParams, the fit's matrix and covariance (vec(R M) = (I kron R) vec(M)) and, unless
// null, the moves' up directions. Every move residual stays as it was. A covariance with
// undetermined (NaN) entries is left as it is: the frame moves by under a milliradian, far below
// what those entries' neighbours are known to.
void TurnGyroFrame(const Eigen::Matrix3d& R_new_old, GyroFit* gyro,
                   std::vector<PlannedMove>* planned);

}  // namespace imucal::core::pipeline

#endif  // IMUCAL_CORE_CALIBRATE_GYRO_STAGE_H_
