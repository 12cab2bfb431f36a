// The priors of the model's own physical terms (core/params.h TermPriors) and what each did to
// its term, for the report. Issue 25: every term is estimated by its evidence, never by a switch.
#ifndef IMUCAL_CORE_CALIBRATE_TERM_PRIORS_H_
#define IMUCAL_CORE_CALIBRATE_TERM_PRIORS_H_

#include <limits>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "core/accel_solver.h"
#include "core/params.h"

namespace imucal::core {

// The widths of a sensor class: "mems" or "tactical". InvalidArgument names the classes known.
absl::StatusOr<TermPriors> TermPriorsFor(std::string_view sensor_class);

// The accelerometer priors of a class: each second-order term 0 +- accel_quadratic_per_m_s2,
// and each non-orthogonality angle 0 +- accel_angle_rad unless `angles_measured` (the face
// references give them their own prior).
AccelPriors ClassAccelPriors(const TermPriors& priors, bool angles_measured);

// What a prior did to one term. The data's precision is taken as the posterior's less the
// prior's (the term's marginal; its correlations with the others are in the covariance).
struct TermPriorEffect {
  std::string name;        // "accel quadratic_x", "accel t_yx"
  std::string source;      // "sensor class mems", "face references"
  double estimate = 0;     // the final value, parameter units
  double prior_value = 0;  // the prior's centre and one-sigma width, parameter units
  double prior_sigma = 0;
  double posterior_sigma = 0;  // the final standard error
  // What the poses alone say: +inf when they add nothing beyond the prior.
  double data_sigma = std::numeric_limits<double>::infinity();
  // The poses' share of the estimate's precision, 1 - (posterior / prior)^2 in [0, 1]: 1 the
  // poses decide the term, 0 the prior does (the term is then shrunk to the prior's centre).
  double data_weight = 0;
};
std::vector<TermPriorEffect> DescribePriors(const AccelPriors& priors, const AccelParams& fit,
                                            const AccelMatrix& covariance);
// One line per effect for the report's notes: "accel quadratic_x = 1.2e-04 +- 4.0e-05: the poses
// decide 99% (prior 0 +- 2e-04, sensor class mems)".
std::string DescribePriorEffect(const TermPriorEffect& e);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_CALIBRATE_TERM_PRIORS_H_
