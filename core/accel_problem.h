// The accelerometer's Ceres problem, one builder for every fit of the magnitude model: the
// accelerometer solver's Levenberg-Marquardt (core/accel_solver.h RefineAccelLm) and the effect
// search's joint refit of the model with its effects' coefficients (core/effects/refit.cc). Each
// adds its poses' residuals over the four parameter blocks; SolveAccelProblem adds the priors,
// holds what the mask leaves out and solves with the same options, so the two fits are the same
// maximum a posteriori fit (issue 25), one with more parameters.
#ifndef IMUCAL_CORE_ACCEL_PROBLEM_H_
#define IMUCAL_CORE_ACCEL_PROBLEM_H_

#include <array>
#include <string>

#include "absl/status/statusor.h"
#include "core/accel_solver.h"

namespace ceres {
class CostFunction;
class Problem;
}  // namespace ceres

namespace imucal::core {

// The parameter blocks of every Ceres problem over the model: bias, scale, tri_angles and
// quadratic of `p` (3 components each, in PackAccel's order).
using AccelBlocks = std::array<double*, 4>;
AccelBlocks AccelParamBlocks(AccelParams* p);
// What a solve of an accelerometer problem reports.
struct AccelProblemSummary {
  int iterations = 0;
  int evaluations = 0;  // residual evaluations
};
// Completes and solves a Ceres problem over the model as every fit of it does (RefineAccelLm; the
// effect search's joint refit with its coefficients, core/effects/refit.cc): `problem` holds the
// poses' residuals over `blocks`; this adds each active prior as the residual
// (theta[index] - value) / sigma on its block (accel_solver.h NewAccelPriorCost), holds what `free`
// leaves out (a block wholly, or a subset manifold), and runs Ceres's dense-QR Levenberg-Marquardt
// at tolerance 1e-14 on one thread. The solution is written through `blocks`. InternalError "<what>
// failed: <Ceres's message>" when it is not usable.
absl::StatusOr<AccelProblemSummary> SolveAccelProblem(const AccelMask& free,
                                                      const AccelPriors& priors,
                                                      const AccelBlocks& blocks,
                                                      const std::string& what,
                                                      ceres::Problem* problem);
// One pose's weighted magnitude residual r = (|L z(u) - offset| - g) * inv_sigma over the four
// blocks (core/model.h AccelModel; frame_angles drop out of |a|), differentiated automatically.
// The caller owns it until a problem does.
ceres::CostFunction* NewAccelMagnitudeCost(const AccelPose& pose, double g, double inv_sigma);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_ACCEL_PROBLEM_H_
