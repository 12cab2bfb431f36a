// How well a gyro model keeps orientation over a recording with a reference (issue 27): the
// corrected rate of every sample through the one applier (core/correction.h for the static
// model, core/dynamic_gyro.h's DynamicGyroState for the learnt block, exactly as the SDK applies
// them), integrated from the reference's first orientation and compared with the reference.
//
// Integration: q(k+1) = q(k) Exp(dt (w(k) + w(k+1)) / 2) (the trapezoid: a sample is the rate
// at its stamp, so a learnt delay is the gyro's, not half a sample of the integrator's).
// AOE: the RMS over the IMU samples where the reference is valid of the angle of
// q_ref(k)^-1 q(k), deg. Final heading error: the angle about the reference world's up axis
// (gravity, from the accelerometer) of q(k) q_ref(k)^-1 at the last valid sample, deg, signed.
#ifndef IMUCAL_CORE_MOTION_EVALUATE_H_
#define IMUCAL_CORE_MOTION_EVALUATE_H_

#include <optional>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "core/dynamic_gyro_state.h"
#include "core/motion/align.h"
#include "core/motion/recording.h"
#include "core/params.h"

namespace imucal::core::motion {

// The median interval between successive time stamps (s); 0 for fewer than two.
double MedianStepS(const std::vector<double>& t_s);

// The static model's output w_s (rad/s) and the calibrated accelerometer (m/s^2) per sample.
void StaticOutputs(const MotionRecording& recording, const ParamSet& params,
                   std::vector<Eigen::Vector3d>* w_s, std::vector<Eigen::Vector3d>* accel);

// The corrected rate per sample: the static model, then params.dynamic_gyro when present (its
// state reset at a gap in the IMU's stamps). `outside`: samples outside its training envelope.
std::vector<Eigen::Vector3d> CorrectedRates(const MotionRecording& recording,
                                            const ParamSet& params, int* outside = nullptr);

struct OrientationError {
  double aoe_deg = 0.0;
  double final_heading_deg = 0.0;
  std::vector<double> t_s;        // the valid samples' stamps
  std::vector<double> error_deg;  // and the angle there
};

OrientationError CompareOrientation(const MotionRecording& recording,
                                    const AlignedReference& reference,
                                    const std::vector<Eigen::Vector3d>& rate_rad_s);

// The gyro's mean over the recording's first still interval (|rate| and its spread small for
// `duration_s`), or nullopt; `note` says where, or that there was none.
std::optional<Eigen::Vector3d> FirstRestBias(const MotionRecording& recording, double duration_s,
                                             std::string* note);

// Stamps further apart than this x the median are a gap in the IMU stream.
inline constexpr double kImuGapFactor = 2.5;

}  // namespace imucal::core::motion

#endif  // IMUCAL_CORE_MOTION_EVALUATE_H_
