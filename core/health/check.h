// A health check from a rest (issue 28): what a short rest (10-60 s, any orientation) of a
// calibrated unit says about its calibration, in one small row a server stores per check.
//
// The device's active parameter set is applied to every sample as the robot applies it
// (core/correction.h SampleCorrection, its temperature effects included), and of the calibrated
// rest the check keeps:
//   f      the mean specific force, body frame [m/s^2]
//   |f| - g                         (g: the parameter set's gravity_m_s2)
//   f . u_ref - g                   the specific force along gravity; u_ref the reference
//                                   direction given (the dock's), else f / |f| (then = |f| - g)
//   u = f / |f|                     the gravity direction in the body frame (a unit vector): at a
//                                   dock the robot stands the same way each time, so a change of
//                                   u is the IMU's mounting moving (or an accel bias across g)
//   w      the mean calibrated rate [rad/s]: the gyro bias the calibration leaves (Earth's
//          rotation, <= 7.3e-5 rad/s, is in it; a dock's is the same at every check)
//
// STANDARD ERRORS. The mean of a rest of T seconds differs from the sensor's long-run value by
// the white noise averaged over T and by the bias wander over T. The Allan variance at cluster
// time T is the variance of the difference of two successive T-means over 2, i.e. what one
// T-mean scatters about its neighbours:
//   se^2 = N^2 / T + (0.664 B)^2 + K^2 T / 3          (core/allan.h: N, B, K per axis)
// from the parameter set's noise block (a figure it lacks counts 0; its random-walk bound is
// used where K was not reached: a bound, so the SE errs large). Without a noise block, from the
// rest itself: N^2 from the variance of successive differences (var(x_i+1 - x_i) / 2 = sigma^2
// for white noise, insensitive to a slow wander), and the wander as what the rest's Allan
// variance at T/6 (the longest time with 6 clusters) holds beyond white noise, taken flat to T.
// |f| - g and f . u_ref - g take the SE of f along u; each tilt angle of u the SE of f across u
// over |f| (the RMS of the two axes across u).
//
// A rest, or refused: a check is refused (FailedPrecondition, the reason in the message) when it
// is too short, has too few samples, or is not at rest: the project's still detector
// (core/noise_rest.h FindNoiseRest: still stretches of >= 10 s) must find the record still over
// at least min_still_fraction of it, and, since a learnt threshold is loose when the whole record
// moves (a robot driving), the calibrated signal's variance must be white noise: var(x) over
// var(x_i+1 - x_i) / 2 is about 1 for white noise and a slow wander, and many times that for a
// motion (its power is at low frequency); and the mean rate must be under a turn's.
#ifndef IMUCAL_CORE_HEALTH_CHECK_H_
#define IMUCAL_CORE_HEALTH_CHECK_H_

#include <cstdint>
#include <limits>
#include <optional>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "core/capture.h"
#include "core/params.h"
#include "util/units.h"

namespace imucal::core::health {

// One health check: a row.
struct HealthCheck {
  double t_start_s = 0;  // the capture's first time stamp (the server's clock: s since epoch)
  double duration_s = 0;
  int64_t samples = 0;
  double temp_mean_c = kNaN;               // NaN when the capture has no temperature
  double gravity_m_s2 = kStandardGravity;  // the parameter set's g, that the figures are about
  Eigen::Vector3d specific_force_m_s2 = Eigen::Vector3d::Zero();  // f, body frame
  Eigen::Vector3d specific_force_se_m_s2 = Eigen::Vector3d::Zero();
  double norm_minus_g_m_s2 = 0;  // |f| - g
  double norm_minus_g_se_m_s2 = 0;
  double along_gravity_m_s2 = 0;  // f . u_ref - g
  double along_gravity_se_m_s2 = 0;
  Eigen::Vector3d gravity_dir_body = Eigen::Vector3d::UnitZ();  // u = f / |f|
  double gravity_dir_se_rad = 0;                                // one tilt angle's SE
  Eigen::Vector3d gyro_bias_rad_s = Eigen::Vector3d::Zero();    // w
  Eigen::Vector3d gyro_bias_se_rad_s = Eigen::Vector3d::Zero();
  bool has_gyro = true;
  bool se_from_noise_block = false;  // the SEs used the parameter set's Allan figures
};

struct HealthCheckOptions {
  double min_duration_s = 10.0;
  int64_t min_samples = 200;
  // The dock's gravity direction in the body frame (unit); unset: the check's own.
  std::optional<Eigen::Vector3d> reference_gravity_dir_body;
  // The still detector (core/noise_rest.h) must find the record still over this much of it.
  // Off for a rest the detector has already found (a calibration's pose). Not used on an
  // accelerometer-only rest: without a gyroscope the detector cuts a white-noise rest into
  // stretches of a few seconds; the variance test below judges it alone.
  bool use_still_detector = true;
  double min_still_fraction = 0.9;
  // var(x) / (var of successive differences / 2) above this on any calibrated axis: motion.
  // White noise gives 1; a sensor's own low-pass filter colours its noise and raises it (the
  // shared ROS IMU's poses, imutk-ros2-repeat, read up to 3.6 at rest); a hand rocking a unit
  // by 5 degrees reads thousands.
  double max_variance_ratio = 10.0;
  // |mean rate| above this: turning (core/static_detector.h's power-up bound on a rest rate).
  double max_rate_deg_s = 5.0;
};

// The check of `rest` (input units of `params`) under `params`. FailedPrecondition with the
// reason when it is not a usable rest; InvalidArgument for a capture that fails
// ValidateCapture or whose units are not the parameter set's.
absl::StatusOr<HealthCheck> ComputeHealthCheck(const Capture& rest, const ParamSet& params,
                                               const HealthCheckOptions& options = {});

// The Allan-predicted SE of a T-second mean per axis (the model above), from a noise block;
// NaN on an axis whose white-noise density is unknown.
Eigen::Vector3d RestMeanSe(const SensorNoise& noise, double duration_s);

}  // namespace imucal::core::health

#endif  // IMUCAL_CORE_HEALTH_CHECK_H_
