// The accelerometer's Ceres problem (accel_problem.h): the only translation unit of imucal that
// instantiates Ceres autodiff (build time on 2 cores).
#include "core/accel_problem.h"

#include <string>
#include <vector>

#include "ceres/ceres.h"
#include "core/model.h"

namespace imucal::core {
namespace {

// Residual of one static pose:  r = (|a(u)| - g) / sigma,  a(u) = L(tri) * z(u) - offset, where
// z = AccelModel::PerAxis(u) (core/model.h: z_i = y_i + q_i y_i^2, y = diag(scale) (u - bias)).
// frame_angles drop out of |a|.
struct MagnitudeError {
  MagnitudeError(const Eigen::Vector3d& u, const Eigen::Vector3d& offset, double g,
                 double inv_sigma)
      : u_(u), offset_(offset), g_(g), inv_sigma_(inv_sigma) {}

  template <typename T>
  bool operator()(const T* bias, const T* scale, const T* tri, const T* quad, T* r) const {
    AccelModel<T> model;
    model.bias = Eigen::Map<const Vec3<T>>(bias);
    model.scale = Eigen::Map<const Vec3<T>>(scale);
    model.tri_angles = Eigen::Map<const Vec3<T>>(tri);
    model.quadratic = Eigen::Map<const Vec3<T>>(quad);
    const Vec3<T> a =
        LowerMisalignment<T>(model.tri_angles) * model.PerAxis(u_.cast<T>()) - offset_.cast<T>();
    r[0] = (a.norm() - T(g_)) * T(inv_sigma_);
    return true;
  }

 private:
  Eigen::Vector3d u_;
  Eigen::Vector3d offset_;
  double g_;
  double inv_sigma_;
};

// One prior as a Ceres residual on its parameter block (3 components).
struct PriorError {
  PriorError(int k, double value, double inv_sigma) : k_(k), value_(value), inv_sigma_(inv_sigma) {}
  template <typename T>
  bool operator()(const T* block, T* r) const {
    r[0] = (block[k_] - T(value_)) * T(inv_sigma_);
    return true;
  }
  static ceres::CostFunction* Create(const AccelPrior& q) {
    return new ceres::AutoDiffCostFunction<PriorError, 1, 3>(
        new PriorError(q.index % 3, q.value, 1.0 / q.sigma));
  }

 private:
  int k_;
  double value_, inv_sigma_;
};

}  // namespace

ceres::CostFunction* NewAccelPriorCost(const AccelPrior& prior) {
  return PriorError::Create(prior);
}

ceres::CostFunction* NewAccelMagnitudeCost(const AccelPose& pose, double g, double inv_sigma) {
  return new ceres::AutoDiffCostFunction<MagnitudeError, 1, 3, 3, 3, 3>(
      new MagnitudeError(pose.mean, pose.offset_m_s2, g, inv_sigma));
}

AccelBlocks AccelParamBlocks(AccelParams* p) {
  return {p->bias.data(), p->scale.data(), p->tri_angles.data(), p->quadratic.data()};
}

absl::StatusOr<AccelProblemSummary> SolveAccelProblem(const AccelMask& free,
                                                      const AccelPriors& priors,
                                                      const AccelBlocks& blocks,
                                                      const std::string& what,
                                                      ceres::Problem* problem) {
  for (const AccelPrior& q : ActivePriors(free, priors))
    problem->AddResidualBlock(NewAccelPriorCost(q), nullptr, blocks[q.index / 3]);
  for (int b = 0; b < 4; ++b) {
    std::vector<int> fixed;
    for (int k = 0; k < 3; ++k)
      if (!free[static_cast<size_t>(3 * b + k)]) fixed.push_back(k);
    if (fixed.size() == 3) {
      problem->SetParameterBlockConstant(blocks[b]);
    } else if (!fixed.empty()) {
      problem->SetManifold(blocks[b], new ceres::SubsetManifold(3, fixed));
    }
  }
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_QR;
  options.max_num_iterations = 100;
  options.function_tolerance = 1e-14;
  options.gradient_tolerance = 1e-14;
  options.parameter_tolerance = 1e-14;
  options.num_threads = 1;
  ceres::Solver::Summary summary;
  ceres::Solve(options, problem, &summary);
  if (!summary.IsSolutionUsable()) return absl::InternalError(what + " failed: " + summary.message);
  return AccelProblemSummary{static_cast<int>(summary.iterations.size()),
                             summary.num_residual_evaluations};
}

}  // namespace imucal::core
