// Noise characterisation: overlapping Allan deviation of each axis of the calibrated
// accelerometer and gyroscope over a static interval (normally the initial rest), and the
// classic figures read off it (IEEE Std 952, Annex C):
//
//   white noise       adev(tau) = N / sqrt(tau)       slope -1/2   N = the line at tau = 1 s
//   bias instability  adev(tau) ~ 0.664 B             slope  0     B = flat minimum / 0.664
//   rate random walk  adev(tau) = K sqrt(tau / 3)     slope +1/2   K = the line at tau = 3 s
//
// UNITS: continuous-time versus discrete, the classic confusion.
//   N is a density: accel [m/s^2/sqrt(Hz)] (= m/s/sqrt(s)), gyro [rad/s/sqrt(Hz)] (= rad/sqrt(s)).
//   A white sequence sampled at rate f with per-sample standard deviation sigma has
//       N = sigma / sqrt(f)        i.e.   sigma = N * sqrt(f).
//   So 0.02 m/s^2 per sample at 200 Hz is N = 0.02 / sqrt(200) = 1.41e-3 m/s^2/sqrt(Hz).
//   Kalibr's and OpenVINS's *_noise_density keys are N; their *_random_walk keys are K:
//   accel [m/s^3/sqrt(Hz)], gyro [rad/s^2/sqrt(Hz)] (discrete per-step bias change:
//   K * sqrt(1 / f)). B is in the signal's unit: accel [m/s^2], gyro [rad/s].
//
// Cluster times are log-spaced (about 10 per decade) from one sample to half the interval.
// Figures are read only from cluster times with at least kMinClustersForFit independent
// clusters, and only where the curve has the figure's slope (local log-log slope within
// +-0.25 of it): a figure the data does not reach is NaN, with a note that says so (a 10 s rest
// gives N, but neither B nor K, which need minutes to hours of rest). B, a minimum, is looked
// for only where there are at least 30 clusters (allan.cc kMinClustersForFloor): a minimum
// searched over the scattered last cluster times finds their dips, also in pure white noise.
#ifndef IMUCAL_CORE_ALLAN_H_
#define IMUCAL_CORE_ALLAN_H_

#include <array>
#include <cstddef>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "core/capture.h"
#include "core/correction.h"
#include "core/model.h"
#include "core/params.h"
#include "core/static_detector.h"

namespace imucal::core {

// Cluster times with fewer independent clusters (interval length / tau) than this are plotted
// but not used for the figures: their deviation scatters by more than ~30%.
inline constexpr double kMinClustersForFit = 6.0;

// The Allan deviation curves of one interval, for plots: tau_s[i] and the deviation of each
// body axis at that cluster time.
struct AllanCurves {
  std::vector<double> tau_s;
  std::vector<Eigen::Vector3d> accel_m_s2;  // calibrated specific force, m/s^2
  std::vector<Eigen::Vector3d> gyro_rad_s;  // calibrated rate, rad/s
};

// Overlapping Allan deviation of a uniformly sampled series x (any unit) at the cluster sizes
// m (in samples; each 1 <= m <= (x.size() - 1) / 2), tau = m / rate_hz:
//   theta_k = sum_{i<k} x_i / rate_hz
//   avar(tau) = sum_{k=0}^{n-2m} (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2
//               / (2 tau^2 (n - 2m + 1))
std::vector<double> OverlappingAllanDeviation(const std::vector<double>& x, double rate_hz,
                                              const std::vector<size_t>& cluster_sizes);

// About `per_decade` log-spaced distinct cluster sizes from 1 to (n - 1) / 2.
std::vector<size_t> LogSpacedClusterSizes(size_t n, int per_decade = 10);

// The figures of one series from its curve (duration_s: the series' length, for the cluster
// count): N, B, K, NaN where not reached.
struct AxisFigures {
  double noise_density = SensorNoise::kUnknown;
  double bias_instability = SensorNoise::kUnknown;
  double random_walk = SensorNoise::kUnknown;
  double random_walk_bound = SensorNoise::kUnknown;
  double tau_max_fit_s = 0.0;  // the longest cluster time used for the figures
  // The cluster time each figure was read at (NaN where not reached): N the point of its
  // slope -1/2 run nearest 1 s; B the flat minimum; K the point that weighs most in its fit.
  double noise_density_tau_s = SensorNoise::kUnknown;
  double bias_instability_tau_s = SensorNoise::kUnknown;
  double random_walk_tau_s = SensorNoise::kUnknown;
};
AxisFigures FitAllanFigures(const std::vector<double>& tau_s, const std::vector<double>& adev,
                            double duration_s);

// One figure as `imucal noise` states it: the value, the cluster time it was read at and its
// 95% confidence interval. upper_bound: the record is too short to reach the figure, and value
// is a 95% upper limit (low NaN, high = value): each term alone bounds its figure (white noise:
// avar(tau) >= N^2 / tau; flicker: avar >= (0.664 B)^2; random walk: avar >= K^2 tau / 3), so
// the deviation's 95% upper limit at one cluster time bounds the figure; the least of these over
// the usable cluster times.
struct AllanReading {
  double value = SensorNoise::kUnknown;
  double tau_s = SensorNoise::kUnknown;
  double low = SensorNoise::kUnknown;  // 95% confidence interval of value
  double high = SensorNoise::kUnknown;
  bool upper_bound = false;
};
struct AxisReadings {
  AllanReading noise_density;     // N
  AllanReading bias_instability;  // B
  AllanReading random_walk;       // K
};

// The noise types of the three figures (their Allan deviation slopes -1/2, 0, +1/2; in the
// frequency-stability literature white FM, flicker FM and random-walk FM).
enum class AllanNoise { kWhite, kFlicker, kRandomWalk };

// Equivalent degrees of freedom of the overlapping Allan variance at cluster size m of a series
// of n samples (NIST SP 1065, Howe, Allan and Barnes, Table 5, with N = n + 1 phase points).
double AllanEdf(AllanNoise noise, size_t n, size_t m);

// The figures of one series with the cluster time each was read at, 95% confidence intervals
// (chi-squared with AllanEdf degrees of freedom at that cluster time) and upper bounds for those
// the record does not reach. n: samples of the series; rate_hz: its rate.
AxisReadings ReadAllanFigures(const std::vector<double>& tau_s, const std::vector<double>& adev,
                              size_t n, double rate_hz);

// A stretch of samples [begin, end) of a capture.
struct SampleRange {
  size_t begin = 0;
  size_t end = 0;
  size_t size() const { return end - begin; }
};

struct NoiseAnalysis {
  NoiseFigures figures;
  // The still stretches the curves were computed on (one, unless a rest was cut into pieces:
  // ComputeNoiseOfSegments).
  std::vector<SampleRange> segments;
  AllanCurves curves;
  // accel x, y, z, then gyro x, y, z.
  std::array<AxisReadings, 6> readings;
};

// Noise of samples [begin, end) of `capture`, calibrated with `accel` and `gyro` (core/model.h;
// the noise is that of the calibrated body-frame signal, in SI). InvalidArgument for a range
// outside the capture; FailedPrecondition for fewer than 64 samples (too short to tell noise
// from drift).
absl::StatusOr<NoiseAnalysis> ComputeNoise(const Capture& capture, size_t begin, size_t end,
                                           const AccelParams& accel, const GyroParams& gyro);
// The same, each sample calibrated by `correction` (a parameter set with its effects).
absl::StatusOr<NoiseAnalysis> ComputeNoise(const Capture& capture, size_t begin, size_t end,
                                           const SampleCorrection& correction);

// The noise of a rest cut into still segments (disjoint, in time order; handling cut out of a
// long rest, core/noise_rest.h): the overlapping Allan variance POOLED over the segments, every
// second difference (theta_{k+2m} - 2 theta_{k+m} + theta_k) taken wholly inside one segment,
//   avar(tau) = sum_s sum_k d_{s,k}^2 / (2 tau^2 sum_s (n_s - 2m + 1)),
// i.e. the segments' own overlapping Allan variances averaged with weights their numbers of
// terms (as NIST SP 1065 treats gaps: a term that would straddle one is left out). Why not join
// the segments into one series: a step of orientation (or of bias) between them enters every
// difference that straddles the joint, and inflates B and K. Why not the longest segment alone:
// it throws away the other segments' clusters at the shorter cluster times. One segment gives
// ComputeNoise's figures exactly. Cluster times reach half the longest segment; a cluster time
// is used for the figures only where the segments long enough for it hold kMinClustersForFit
// clusters (the others contribute nothing there), and the figures' intervals count the
// segments' samples together (slightly optimistic where only the longest segment contributes).
absl::StatusOr<NoiseAnalysis> ComputeNoiseOfSegments(const Capture& capture,
                                                     const std::vector<SampleRange>& segments,
                                                     const SampleCorrection& correction);

// What the pipeline calls: the noise of the longest used static interval (the initial rest of a
// protocol capture), calibrated with `params` as the SDK applies them (effects included).
// FailedPrecondition when no used interval is long enough.
absl::StatusOr<NoiseAnalysis> NoiseFromLongestInterval(const Capture& capture,
                                                       const std::vector<StaticInterval>& intervals,
                                                       const ParamSet& params);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_ALLAN_H_
