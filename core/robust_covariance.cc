#include "core/robust_covariance.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>

namespace imucal::core {
namespace {

// A block's leverage above this is clamped: (I - H)^-1/2 would blow a block that alone determines
// a parameter up to infinity (its residual is then 0/0: the fit says nothing of its error).
constexpr double kMaxLeverage = 0.95;

// (I - H)^-1/2 r with H's eigenvalues clamped to [0, kMaxLeverage].
Eigen::VectorXd LeverageCorrected(const Eigen::MatrixXd& h, const Eigen::VectorXd& r) {
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(0.5 * (h + h.transpose()));
  const Eigen::MatrixXd& v = eigen.eigenvectors();
  Eigen::VectorXd scaled = v.transpose() * r;
  for (Eigen::Index k = 0; k < scaled.size(); ++k)
    scaled(k) /= std::sqrt(1.0 - std::clamp(eigen.eigenvalues()(k), 0.0, kMaxLeverage));
  return v * scaled;
}

}  // namespace

size_t NeweyWestLags(size_t blocks) {
  return static_cast<size_t>(
      std::floor(4.0 * std::pow(static_cast<double>(blocks) / 100.0, 2.0 / 9.0)));
}

Eigen::MatrixXd LoewnerUpperBound(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  const Eigen::MatrixXd d = b - a;
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(0.5 * (d + d.transpose()));
  const Eigen::VectorXd positive = eigen.eigenvalues().cwiseMax(0.0);
  return a + eigen.eigenvectors() * positive.asDiagonal() * eigen.eigenvectors().transpose();
}

Eigen::MatrixXd RobustCovariance(const Eigen::MatrixXd& pseudo_inverse,
                                 const std::vector<ObservationBlock>& blocks,
                                 const Eigen::MatrixXd& other_information,
                                 const Eigen::MatrixXd& model_covariance) {
  if (other_information.rows() != pseudo_inverse.rows()) return model_covariance;
  std::vector<Eigen::VectorXd> scores;
  scores.reserve(blocks.size());
  for (const ObservationBlock& b : blocks) {
    const Eigen::MatrixXd h = b.jacobian * pseudo_inverse * b.jacobian.transpose();
    scores.push_back(b.jacobian.transpose() * LeverageCorrected(h, b.residual));
  }
  Eigen::MatrixXd meat = other_information;
  const size_t lags = NeweyWestLags(scores.size());
  for (size_t i = 0; i < scores.size(); ++i) {
    meat += scores[i] * scores[i].transpose();
    for (size_t l = 1; l <= lags && i + l < scores.size(); ++l) {
      const Eigen::MatrixXd cross = scores[i] * scores[i + l].transpose();
      meat += (1.0 - static_cast<double>(l) / static_cast<double>(lags + 1)) *
              (cross + cross.transpose());
    }
  }
  const Eigen::MatrixXd sandwich = pseudo_inverse * meat * pseudo_inverse;
  return LoewnerUpperBound(model_covariance, sandwich);
}

}  // namespace imucal::core
