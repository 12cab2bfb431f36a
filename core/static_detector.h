// Static-pose detection that learns the noise level from the capture itself, bounded by physics.
//
// A sample is still when the variance of the accelerometer AND of the gyroscope over a centred
// window of `window_s` is below `multiplier` times the white-noise variance of that sensor. The
// noise variance is learnt from the data, file by file: the low quantile of the file's window
// variances (a calibration capture is mostly at rest), refined by its longest quiet run. The
// multiplier is not a constant to tune: core/calibrate/static_poses.cc sweeps it and keeps the
// value whose calibration predicts held-out poses best (IMU-TK sweeps it on the in-sample cost).
// A learnt threshold can be loose (a hand-held capture shakes as much as it turns), so the
// threshold only proposes: an interval is a rest only if the gyroscope did not turn over it
// (core/rest_rotation.h).
#ifndef IMUCAL_CORE_STATIC_DETECTOR_H_
#define IMUCAL_CORE_STATIC_DETECTOR_H_

#include <array>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "core/capture.h"
#include "core/rest_rotation.h"

namespace imucal::core {

struct StaticDetectorOptions {
  double window_s = 0.5;      // variance window, seconds (rate independent)
  double min_static_s = 1.0;  // shorter intervals are reported as too short
  double trim_s = 0.1;        // removed from each end of an interval (settling, hand release)
  // Relative tilt between the first and second half of an interval above which it "moved".
  // Compared against the noise of the two half means, so the test is scale free.
  double moved_sigma = 8.0;
  // The physical bound on a rest (core/rest_rotation.h): over a still interval the gyroscope,
  // its rest rate removed, turns less than `rotation_sigmas` times its noise's random walk plus
  // the bias bound times the duration. The bias bound is how far a rest's rate may sit from the
  // rest rate of its file (temperature, wander: a MEMS gyroscope moves a few hundredths of a
  // deg/s between poses, so 0.5 is generous), or, for a file with a single rest, from the rest
  // rate of the other files, which may come from another power-up (turn-on bias repeatability of
  // low-cost MEMS is a few deg/s). A turn at 20 deg/s and more is far beyond either.
  double rotation_sigmas = 5.0;
  double rest_rate_bound_deg_s = 0.5;
  double power_up_rate_bound_deg_s = 5.0;
  // False while the gyroscope's unit is being inferred (importers/unit_inference.h): its scale
  // is then taken from the moves alone, as for raw counts.
  bool gyro_unit_known = true;
};

// Per-sample white-noise standard deviation, in the capture's input units.
//
// Never below what the readings' own resolution gives: readings on a grid of step q (a sensor's
// quantisation: whole counts, 0.01 m/s^2, 1/131 deg/s) carry at least q^2 / 12 of rounding
// variance however quiet the sensor is, and readings that a rest leaves exactly constant (no
// noise at all) are still held to 1e-6 of the readings' magnitude, far below any sensor's noise
// and far above the rounding of the window variances.
struct NoiseLevel {
  Eigen::Vector3d accel_std = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_std = Eigen::Vector3d::Zero();
  // The grid step of each axis' readings (input units), 0 where they sit on no grid.
  Eigen::Vector3d accel_step = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_step = Eigen::Vector3d::Zero();
  // The floor each std is held to (step / sqrt(12), and 1e-6 of the largest reading).
  Eigen::Vector3d accel_floor = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_floor = Eigen::Vector3d::Zero();
  std::string source;  // how it was measured, for the report
  // The noise of each file of the capture (one entry per file, in order; one for the whole
  // capture when it has no files): the still thresholds are learnt per file, never across files,
  // since the files of one capture may be recorded with other settings or on a noisier support.
  struct Segment {
    size_t begin = 0, end = 0;  // samples [begin, end)
    Eigen::Vector3d accel_std = Eigen::Vector3d::Zero();
    Eigen::Vector3d gyro_std = Eigen::Vector3d::Zero();
    std::string source;
  };
  std::vector<Segment> segments;
};

// Why a static interval is not used (StaticInterval::issue).
enum class IntervalIssue {
  kNone,       // used
  kTooShort,   // held shorter than min_static_s: still, but too briefly to average
  kSaturated,  // an axis sits on the sensor's range limit
  kMoved,      // the orientation changed within it
  kTurning,    // steady but not at rest: the gyroscope turned more than a rest can (a steady
               // turn about the vertical leaves the accelerometer unchanged and has no variance)
  kDuplicate,  // the orientation of the previous pose, not re-placed (core/calibrate)
};
// "", "too_short", "saturated", "moved", "turning", "duplicate".
std::string_view IntervalIssueName(IntervalIssue issue);

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
  // The noise of the interval's file (NoiseLevel::Segment), input units per sample.
  Eigen::Vector3d accel_noise_std = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_noise_std = Eigen::Vector3d::Zero();
  // The gyroscope's largest rotation over the interval, its rest rate removed, and the most a
  // rest could turn (core/rest_rotation.h), degrees; NaN when the gyroscope's unit is unknown.
  double rotation_deg = std::numeric_limits<double>::quiet_NaN();
  double rotation_bound_deg = std::numeric_limits<double>::quiet_NaN();
  bool used = true;
  IntervalIssue issue = IntervalIssue::kNone;
  std::string reason;  // why not used, in a technician's words
  size_t samples() const { return end - begin; }
};

// Window variances (sum over the three axes), one per sample, computed once per capture.
struct MotionSignal {
  std::vector<double> accel_var;
  std::vector<double> gyro_var;
  // Whether the mean stays put around each sample: the largest over the six axes of the
  // difference between the means of the half-windows before and after it, in units of that
  // difference's own noise (the half-windows' scatter). A rest reads about 1 whatever its noise
  // (a motor's vibration, a hand on the unit); a move reads far more, since its trend, not noise,
  // makes its scatter. The variance test misses the noisy rest, this one the noiseless.
  std::vector<double> mean_shift;
  size_t window = 0;  // samples
  // The extreme reading of each axis over the capture: a sensor's range limit shows up here.
  Eigen::Vector3d accel_lo, accel_hi, gyro_lo, gyro_hi;
  // Per axis, the samples that read its extreme, in order: an interval's count of them is two
  // binary searches, not a pass over its samples at every threshold the sweep tries.
  std::array<std::vector<uint32_t>, 3> accel_at_rail, gyro_at_rail;
  // The gyroscope's prefix integral (core/rest_rotation.h), for the rotation test at every
  // threshold the sweep tries: computed once per capture.
  GyroIntegral integral;
};

// MotionSignal::mean_shift at or under this is still (4: a rest's |N(0,1)| on any of six axes
// exceeds it on about 1 sample in 3000).
inline constexpr double kSteadyMeanShift = 4.0;

MotionSignal ComputeMotionSignal(const Capture& capture, const StaticDetectorOptions& options);
// The capture's noise (the quietest rest over all files), and each file's (NoiseLevel::segments).
NoiseLevel EstimateNoise(const Capture& capture, const MotionSignal& motion);

// Static intervals at one threshold multiplier, with summary statistics and the checks that need
// no calibration: too short, moved during capture, saturated, turning.
//
// A sample is still when both sensors' window variances are under their file's thresholds
// (the multiplier times the file's noise variance), or when the means around it stay put
// (MotionSignal::mean_shift under kSteadyMeanShift): a rest much noisier than the quietest (a
// motor running) never passes the variance test at any multiplier.
// Whatever the threshold, a rest is still by physics: an interval over which the gyroscope turns
// more than its noise and the bias bound allow (core/rest_rotation.h) is "turning", never used
// and never a turn's anchor, however steady its rate.
// One rest is one interval: still runs of one file with no time gap between them are joined,
// with the samples between them, when the gyroscope does not turn over the whole span (the same
// bound) and the accelerometer's means agree (the "moved" test) before, between and after. A
// long rest on a vibrating support or under a hand is therefore one pose, not ten; a rest that
// ends in one file and starts again in the next is two.
std::vector<StaticInterval> DetectStatic(const Capture& capture, const MotionSignal& motion,
                                         const NoiseLevel& noise, double multiplier,
                                         const StaticDetectorOptions& options);

// Recomputes the summary statistics of [begin, end) of `capture`.
StaticInterval SummariseInterval(const Capture& capture, size_t begin, size_t end);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_STATIC_DETECTOR_H_
