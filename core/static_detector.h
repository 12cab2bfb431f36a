// Static-pose detection that learns the noise level from the capture itself.
//
// A sample is static when the variance of the accelerometer AND of the gyroscope over a centred
// window of `window_s` is below `multiplier` times the white-noise variance of that sensor. The
// noise variance is learnt from the data: the low quantile of all window variances (a
// calibration capture is mostly at rest), refined by the longest static interval (the initial
// rest). The multiplier is not a constant to tune: core/calibrate/static_poses.cc sweeps it and
// keeps the value whose calibration predicts held-out poses best (IMU-TK sweeps it on the in-sample
// cost).
#ifndef IMUCAL_CORE_STATIC_DETECTOR_H_
#define IMUCAL_CORE_STATIC_DETECTOR_H_

#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "core/capture.h"

namespace imucal::core {

struct StaticDetectorOptions {
  double window_s = 0.5;      // variance window, seconds (rate independent)
  double min_static_s = 1.0;  // shorter intervals are reported as too short
  double trim_s = 0.1;        // removed from each end of an interval (settling, hand release)
  // Relative tilt between the first and second half of an interval above which it "moved".
  // Compared against the noise of the two half means, so the test is scale free.
  double moved_sigma = 8.0;
};

// Per-sample white-noise standard deviation, in the capture's input units.
struct NoiseLevel {
  Eigen::Vector3d accel_std = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_std = Eigen::Vector3d::Zero();
  std::string source;  // how it was measured, for the report
};

struct StaticInterval {
  size_t begin = 0;  // first sample (after trimming)
  size_t end = 0;    // one past the last sample
  double t_start_s = 0.0;
  double t_end_s = 0.0;
  Eigen::Vector3d accel_mean = Eigen::Vector3d::Zero();  // input units
  Eigen::Vector3d accel_std = Eigen::Vector3d::Zero();   // sample std, input units
  Eigen::Vector3d gyro_mean = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_std = Eigen::Vector3d::Zero();
  double temp_mean = std::numeric_limits<double>::quiet_NaN();
  bool used = true;
  std::string reason;  // why not used, in a technician's words
  size_t samples() const { return end - begin; }
};

// Window variances (sum over the three axes), one per sample, computed once per capture.
struct MotionSignal {
  std::vector<double> accel_var;
  std::vector<double> gyro_var;
  size_t window = 0;  // samples
  // The extreme reading of each axis over the capture: a sensor's range limit shows up here.
  Eigen::Vector3d accel_lo, accel_hi, gyro_lo, gyro_hi;
};

MotionSignal ComputeMotionSignal(const Capture& capture, const StaticDetectorOptions& options);
NoiseLevel EstimateNoise(const Capture& capture, const MotionSignal& motion);

// Static intervals at one threshold multiplier, with summary statistics and the checks that need
// no calibration: too short, moved during capture, saturated.
std::vector<StaticInterval> DetectStatic(const Capture& capture, const MotionSignal& motion,
                                         const NoiseLevel& noise, double multiplier,
                                         const StaticDetectorOptions& options);

// Recomputes the summary statistics of [begin, end) of `capture`.
StaticInterval SummariseInterval(const Capture& capture, size_t begin, size_t end);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_STATIC_DETECTOR_H_
