// The physical bound on a rest: whatever threshold the variance test learnt, a still pose must
// not turn. The gyroscope's rotation over an interval, with its rest rate (bias) removed, stays
// under what its noise and a generous bound on the bias's wander can turn; a turn at any steady
// rate, however smooth (the accelerometer does not see a turn about the vertical, and a steady
// rate has no variance), turns far more. Used by core/static_detector.cc to call an interval
// "turning" and to decide that two still runs with nothing between them are one rest.
//
// Angles are small-angle sums of the rate (the rotation vector while it stays small; a turn of
// any size makes it large, which is all the test needs).
#ifndef IMUCAL_CORE_REST_ROTATION_H_
#define IMUCAL_CORE_REST_ROTATION_H_

#include <cstddef>
#include <vector>

#include "Eigen/Core"
#include "core/capture.h"

namespace imucal::core {

// Prefix integrals of the gyroscope (input units x s) and of time (s): sample i's contribution is
// its rate times the interval to the next sample (never more than 3 median intervals: a time gap
// or a file's start is not integrated across).
struct GyroIntegral {
  std::vector<Eigen::Vector3d> angle;  // angle[i] = sum over k < i of w_k dt_k
  std::vector<double> time_s;          // time_s[i] = sum over k < i of dt_k
  double median_dt_s = 0;

  GyroIntegral() = default;
  explicit GyroIntegral(const Capture& capture) : GyroIntegral(capture, capture.MedianDt()) {}
  // With the capture's median sample interval already known (Capture::MedianDt).
  GyroIntegral(const Capture& capture, double median_dt_s);
  // The largest rotation (input units x s) from sample b to any sample up to e, `rate` (input
  // units) removed: the excursion of [b, e). A rest's stays at its noise however it shakes (a
  // hand's tremor goes back and forth); a turn's grows with its duration.
  double Excursion(size_t b, size_t e, const Eigen::Vector3d& rate) const;
  // Seconds spanned by [b, e).
  double Duration(size_t b, size_t e) const { return time_s[e] - time_s[b]; }
};

// One interval's mean gyroscope reading and its weight (its samples), for the rest rate.
struct RateSample {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  double weight = 0;
};

// The rest rate of a set of still runs: the runs' means cluster at the gyroscope's bias (within
// its wander), a turn's mean lies anywhere. The densest cluster (the run with the most weight
// within `bound` of its mean, on every axis) is the rest; its weighted median per axis is the
// rate, and `members` how many runs agree on it (a lone run can only vouch for itself). Zero
// rate and members when there are no samples.
struct RestRate {
  Eigen::Vector3d rate = Eigen::Vector3d::Zero();
  int members = 0;
};
RestRate DenseRestRate(const std::vector<RateSample>& runs, double bound);

// Radians per input unit of the gyroscope, a rough figure from the capture's moves (for raw
// counts, or to check a nominal unit): between two rests, the gravity direction turns by no more
// than the rotation (a turn about the vertical shows it nothing), so the largest ratio of the
// accelerometer's turn to the gyroscope's integral, over the moves that tilt the unit by 30
// degrees or more, is about the gyroscope's scale. A raw-count accelerometer's offset is taken
// from the middle of each axis' extreme rest readings. 0 when nothing tells (no such move).
double RoughRadPerGyroUnit(const Capture& capture, const GyroIntegral& integral,
                           const std::vector<std::pair<size_t, size_t>>& rests,
                           const Eigen::Vector3d& rest_rate);

// The most a rest may turn over `samples` samples spanning `duration_s`, in radians: `sigmas`
// times the random walk of the per-sample noise `gyro_noise_rad_s` (per axis, as a vector norm),
// plus the bias bound times the duration.
double RestRotationBound(const Eigen::Vector3d& gyro_noise_rad_s, size_t samples, double dt_s,
                         double duration_s, double bias_bound_rad_s, double sigmas);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_REST_ROTATION_H_
