#include "core/health/check.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "core/allan.h"
#include "core/correction.h"
#include "core/noise_rest.h"
#include "util/units.h"

namespace imucal::core::health {
namespace {

// The moments of one calibrated axis that the check needs.
struct AxisStats {
  double mean = 0;
  double variance = 0;       // sample variance
  double diff_variance = 0;  // var(x_i+1 - x_i) / 2: the white noise's per-sample variance
};

AxisStats StatsOf(const std::vector<double>& x) {
  AxisStats s;
  const double n = static_cast<double>(x.size());
  for (double v : x) s.mean += v;
  s.mean /= n;
  for (double v : x) s.variance += (v - s.mean) * (v - s.mean);
  s.variance /= n - 1;
  for (size_t i = 1; i < x.size(); ++i) s.diff_variance += (x[i] - x[i - 1]) * (x[i] - x[i - 1]);
  s.diff_variance /= 2 * (n - 1);
  return s;
}

// The SE of the rest's mean from the rest alone (header: white part from successive
// differences, wander from the Allan variance at T/6 beyond white, taken flat to T).
double SelfSe(const std::vector<double>& x, const AxisStats& s, double rate_hz) {
  const size_t n = x.size();
  const double white_var = s.diff_variance / static_cast<double>(n);
  const size_t m = std::max<size_t>(1, n / 6);
  double wander_var = 0;
  if (2 * m + 1 < n) {
    const double adev = OverlappingAllanDeviation(x, rate_hz, {m}).front();
    wander_var = std::max(0.0, adev * adev - s.diff_variance / static_cast<double>(m));
  }
  return std::sqrt(white_var + wander_var);
}

absl::Status CheckInput(const Capture& rest, const ParamSet& params,
                        const HealthCheckOptions& options) {
  if (absl::Status st = ValidateCapture(rest); !st.ok()) return st;
  if (rest.accel_unit != params.accel_unit) {
    return absl::InvalidArgumentError(
        absl::StrFormat("the rest's accelerometer unit is %s but the parameter set expects %s",
                        AccelUnitName(rest.accel_unit), AccelUnitName(params.accel_unit)));
  }
  const bool gyro = rest.has_gyro && params.has_gyro;
  if (gyro && rest.gyro_unit != params.gyro_unit) {
    return absl::InvalidArgumentError(
        absl::StrFormat("the rest's gyroscope unit is %s but the parameter set expects %s",
                        GyroUnitName(rest.gyro_unit), GyroUnitName(params.gyro_unit)));
  }
  const int64_t n = static_cast<int64_t>(rest.size());
  if (n < options.min_samples) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "too few samples for a health check: %d, at least %d", n, options.min_samples));
  }
  const double duration_s = rest.t_s.back() - rest.t_s.front() + rest.MedianDt();
  if (duration_s < options.min_duration_s) {
    return absl::FailedPreconditionError(
        absl::StrFormat("too short for a health check: %.1f s, at least %.1f s of rest", duration_s,
                        options.min_duration_s));
  }
  // Without a gyroscope the still detector cuts a white-noise rest into stretches of a few
  // seconds (a simulated accelerometer-only dock rest: its longest still stretch 3.5 s of 20 s),
  // so an accelerometer-only rest is judged by the variance test alone.
  if (!options.use_still_detector || !gyro) return absl::OkStatus();
  const absl::StatusOr<NoiseRest> still = FindNoiseRest(rest);
  if (!still.ok()) {
    return absl::FailedPreconditionError("not a rest: the still detector says " +
                                         std::string(still.status().message()));
  }
  if (still->rest_s < options.min_still_fraction * still->record_s) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "not a rest: the still detector finds it still over %.1f s of %.1f s (at least %.0f%% "
        "needed); %s",
        still->rest_s, still->record_s, 100 * options.min_still_fraction, still->note));
  }
  return absl::OkStatus();
}

}  // namespace

Eigen::Vector3d RestMeanSe(const SensorNoise& noise, double duration_s) {
  Eigen::Vector3d se;
  for (int k = 0; k < 3; ++k) {
    const double n = noise.noise_density(k);
    const double b = std::isnan(noise.bias_instability(k)) ? 0.0 : noise.bias_instability(k);
    double rw = noise.random_walk(k);
    if (std::isnan(rw)) rw = noise.random_walk_bound(k);
    if (std::isnan(rw)) rw = 0;
    se(k) = std::sqrt(n * n / duration_s + 0.664 * 0.664 * b * b + rw * rw * duration_s / 3.0);
  }
  return se;
}

absl::StatusOr<HealthCheck> ComputeHealthCheck(const Capture& rest, const ParamSet& params,
                                               const HealthCheckOptions& options) {
  if (absl::Status st = CheckInput(rest, params, options); !st.ok()) return st;
  const size_t n = rest.size();
  const bool gyro = rest.has_gyro && params.has_gyro;
  const bool temp_c = rest.has_temp() && rest.temp_unit == TempUnit::kCelsius;
  const SampleCorrection correction(params, rest.t_s.front());
  std::vector<std::vector<double>> axes(6, std::vector<double>(n));
  double temp_sum = 0;
  for (size_t i = 0; i < n; ++i) {
    const double t = temp_c ? rest.temp[i] : kNaN;
    const CorrectedSample c = correction.Apply(
        rest.accel[i], gyro ? rest.gyro[i] : Eigen::Vector3d::Zero(), t, rest.t_s[i]);
    for (int k = 0; k < 3; ++k) {
      axes[k][i] = c.accel_m_s2(k);
      axes[3 + k][i] = c.gyro_rad_s(k);
    }
    temp_sum += t;
  }
  HealthCheck out;
  out.t_start_s = rest.t_s.front();
  out.duration_s = rest.t_s.back() - rest.t_s.front() + rest.MedianDt();
  out.samples = static_cast<int64_t>(n);
  out.temp_mean_c = temp_c ? temp_sum / static_cast<double>(n) : kNaN;
  out.gravity_m_s2 = params.gravity_m_s2;
  out.has_gyro = gyro;
  const double rate_hz = 1.0 / rest.MedianDt();
  const char* kAxisNames[6] = {"accel x", "accel y", "accel z", "gyro x", "gyro y", "gyro z"};
  Eigen::Matrix<double, 6, 1> mean, self_se;
  for (int k = 0; k < (gyro ? 6 : 3); ++k) {
    const AxisStats s = StatsOf(axes[k]);
    const double ratio = s.variance / std::max(s.diff_variance, 1e-300);
    if (ratio > options.max_variance_ratio) {
      return absl::FailedPreconditionError(absl::StrFormat(
          "not a rest: %s varies %.1f times what its sample-to-sample noise allows (at most "
          "%.1f): the unit moved or vibrated",
          kAxisNames[k], ratio, options.max_variance_ratio));
    }
    mean(k) = s.mean;
    self_se(k) = SelfSe(axes[k], s, rate_hz);
  }
  out.specific_force_m_s2 = mean.head<3>();
  out.specific_force_se_m_s2 = self_se.head<3>();
  if (gyro) {
    out.gyro_bias_rad_s = mean.tail<3>();
    out.gyro_bias_se_rad_s = self_se.tail<3>();
    if (out.gyro_bias_rad_s.norm() > options.max_rate_deg_s * kDegToRad) {
      return absl::FailedPreconditionError(absl::StrFormat(
          "not a rest: the calibrated gyroscope turns at %.2f deg/s (a rest reads under %.1f)",
          out.gyro_bias_rad_s.norm() / kDegToRad, options.max_rate_deg_s));
    }
  }
  if (params.noise) {  // the Allan prediction where the figures are known, per axis
    const Eigen::Vector3d a = RestMeanSe(params.noise->accel, out.duration_s);
    const Eigen::Vector3d g = RestMeanSe(params.noise->gyro, out.duration_s);
    for (int k = 0; k < 3; ++k) {
      if (!std::isnan(a(k))) out.specific_force_se_m_s2(k) = a(k);
      if (gyro && !std::isnan(g(k))) out.gyro_bias_se_rad_s(k) = g(k);
    }
    out.se_from_noise_block = !a.array().isNaN().any();
  }
  const Eigen::Vector3d& f = out.specific_force_m_s2;
  const double norm = f.norm();
  if (!(norm > 0.5 * params.gravity_m_s2 && norm < 1.5 * params.gravity_m_s2)) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "not a rest under this calibration: |a| = %.3f m/s^2, g = %.3f (a free fall, an "
        "acceleration, or a parameter set of another unit)",
        norm, params.gravity_m_s2));
  }
  out.gravity_dir_body = f / norm;
  const Eigen::Vector3d& u = out.gravity_dir_body;
  const Eigen::Vector3d var = out.specific_force_se_m_s2.array().square();
  const double var_along = u.array().square().matrix().dot(var);
  out.norm_minus_g_m_s2 = norm - params.gravity_m_s2;
  out.norm_minus_g_se_m_s2 = std::sqrt(var_along);
  const Eigen::Vector3d ref = options.reference_gravity_dir_body.value_or(u).normalized();
  out.along_gravity_m_s2 = f.dot(ref) - params.gravity_m_s2;
  out.along_gravity_se_m_s2 = std::sqrt(ref.array().square().matrix().dot(var));
  out.gravity_dir_se_rad = std::sqrt(std::max(0.0, (var.sum() - var_along) / 2)) / norm;
  return out;
}

}  // namespace imucal::core::health
