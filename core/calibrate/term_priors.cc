#include "core/calibrate/term_priors.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_format.h"

namespace imucal::core {

absl::StatusOr<TermPriors> TermPriorsFor(std::string_view sensor_class) {
  // mems: consumer and industrial MEMS (MPU-6050, BMI160, ICM-42688, ADXL355): cross-axis
  //   sensitivity of about 1 % (10 mrad), second-order terms of 1e-5 to 3e-4 per m/s^2; the
  //   width, 5e-4, shrinks a term by less than 10 % where the poses know it to 1.5e-4 (a prior
  //   of the class's own RMS, about 1.2e-4, shrank the larger terms by half and cost up to 4x
  //   the full-model reference's validation error on 18-stop captures).
  // tactical: tactical-grade MEMS and quartz (cross-axis 0.1 %, nonlinearity tens of ppm/g).
  if (sensor_class == "mems") return TermPriors{};
  if (sensor_class == "tactical") {
    return TermPriors{
        .sensor_class = "tactical", .accel_quadratic_per_m_s2 = 5e-5, .accel_angle_rad = 1e-3};
  }
  return absl::InvalidArgumentError(absl::StrFormat(
      "sensor class '%s' is not known; the classes are mems and tactical", sensor_class));
}

AccelPriors ClassAccelPriors(const TermPriors& priors, bool angles_measured) {
  const std::string source = "sensor class " + priors.sensor_class;
  AccelPriors out;
  if (!angles_measured)
    for (int c : kAccelTri.Indices()) out.push_back({c, 0.0, priors.accel_angle_rad, source});
  for (int c : kAccelQuadratic.Indices())
    out.push_back({c, 0.0, priors.accel_quadratic_per_m_s2, source});
  return out;
}

std::vector<TermPriorEffect> DescribePriors(const AccelPriors& priors, const AccelParams& fit,
                                            const AccelMatrix& covariance) {
  std::vector<TermPriorEffect> out;
  const AccelVector theta = PackAccel(fit);
  for (const AccelPrior& q : priors) {
    TermPriorEffect e;
    e.name = "accel " + AccelParamName(q.index);
    e.source = q.source;
    e.estimate = theta(q.index);
    e.prior_value = q.value;
    e.prior_sigma = q.sigma;
    e.posterior_sigma = std::sqrt(std::max(0.0, covariance(q.index, q.index)));
    const double data_precision =
        1.0 / (e.posterior_sigma * e.posterior_sigma) - 1.0 / (q.sigma * q.sigma);
    e.data_sigma = data_precision > 0 ? 1.0 / std::sqrt(data_precision)
                                      : std::numeric_limits<double>::infinity();
    const double ratio = e.posterior_sigma / q.sigma;
    e.data_weight = std::clamp(1.0 - ratio * ratio, 0.0, 1.0);
    out.push_back(e);
  }
  return out;
}

std::string DescribePriorEffect(const TermPriorEffect& e) {
  return absl::StrFormat(
      "%s = %.2g +- %.2g: the poses decide %.0f%% of it (prior %.2g +- %.2g, %s)%s", e.name,
      e.estimate, e.posterior_sigma, 100 * e.data_weight, e.prior_value, e.prior_sigma, e.source,
      e.data_weight < 0.5 ? "; shrunk toward the prior's centre, add poses to resolve it" : "");
}

}  // namespace imucal::core
