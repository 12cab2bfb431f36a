#include "core/crb.h"

#include <cmath>
#include <limits>

#include "Eigen/Dense"

namespace imucal::core {
namespace {

// Below this, the smallest eigenvalue of the unit-diagonal (correlation-scaled) information is
// treated as zero: the free parameters are confounded and no finite bound exists.
constexpr double kSingularEigen = 1e-12;

std::vector<int> FreeIndices(const AccelMask& free) {
  std::vector<int> out;
  for (int c = 0; c < kAccelParams; ++c)
    if (free[static_cast<size_t>(c)]) out.push_back(c);
  return out;
}

}  // namespace

AccelVector AccelCramerRaoStd(const AccelParams& truth,
                              const std::vector<AccelPose>& poses_at_truth, double /*gravity_m_s2*/,
                              const AccelMask& free) {
  AccelVector out = AccelVector::Constant(std::numeric_limits<double>::quiet_NaN());
  const std::vector<int> index = FreeIndices(free);
  if (index.empty()) return out;
  const auto n_free = static_cast<Eigen::Index>(index.size());

  // Pose mean noise only: the fitted model error is not part of the sensor's noise.
  std::vector<AccelPose> poses = poses_at_truth;
  for (AccelPose& pose : poses) pose.model_sigma_m_s2 = 0.0;
  const Eigen::MatrixXd j = MagnitudeJacobian(truth, poses);
  const std::vector<double> sigma = MagnitudeSigmas(truth, poses);

  // Whitened Jacobian over the free columns: F = jw^T jw.
  Eigen::MatrixXd jw(j.rows(), n_free);
  for (Eigen::Index k = 0; k < n_free; ++k) jw.col(k) = j.col(index[static_cast<size_t>(k)]);
  for (Eigen::Index i = 0; i < jw.rows(); ++i) jw.row(i) /= sigma[static_cast<size_t>(i)];
  const Eigen::MatrixXd info = jw.transpose() * jw;

  // Parameters span ~10 orders of magnitude (counts of bias, 1e-5 of quadratic): invert the
  // unit-diagonal form D F D, D = diag(F_kk^-1/2), and scale back, F^-1 = D (D F D)^-1 D.
  const Eigen::VectorXd d = info.diagonal().cwiseSqrt().cwiseInverse();
  auto undetermined = [&] {
    for (int c : index) out(c) = std::numeric_limits<double>::infinity();
    return out;
  };
  if (!d.allFinite()) return undetermined();  // a parameter the poses do not touch at all
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(d.asDiagonal() * info * d.asDiagonal());
  if (eig.info() != Eigen::Success || !(eig.eigenvalues().minCoeff() > kSingularEigen)) {
    return undetermined();
  }
  const Eigen::MatrixXd inverse = eig.eigenvectors() *
                                  eig.eigenvalues().cwiseInverse().asDiagonal() *
                                  eig.eigenvectors().transpose();
  for (Eigen::Index k = 0; k < n_free; ++k)
    out(index[static_cast<size_t>(k)]) = d(k) * std::sqrt(inverse(k, k));
  return out;
}

}  // namespace imucal::core
