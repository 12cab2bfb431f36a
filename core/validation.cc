#include "core/validation.h"

#include <cmath>

#include "Eigen/Dense"

namespace imucal::core {

Eigen::Matrix3d BestFitRotation(const std::vector<Eigen::Vector3d>& estimate,
                                const std::vector<Eigen::Vector3d>& truth) {
  Eigen::Matrix3d h = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < estimate.size() && i < truth.size(); ++i)
    h += truth[i] * estimate[i].transpose();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1 : 1;
  return svd.matrixU() * d * svd.matrixV().transpose();
}

double VectorRmsError(const std::vector<Eigen::Vector3d>& estimate,
                      const std::vector<Eigen::Vector3d>& truth, bool align) {
  const Eigen::Matrix3d r = align ? BestFitRotation(estimate, truth) : Eigen::Matrix3d::Identity();
  double ss = 0;
  const size_t n = std::min(estimate.size(), truth.size());
  for (size_t i = 0; i < n; ++i) ss += (r * estimate[i] - truth[i]).squaredNorm();
  return n ? std::sqrt(ss / static_cast<double>(n)) : 0.0;
}

}  // namespace imucal::core
