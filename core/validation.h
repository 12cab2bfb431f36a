// Comparing calibrated values with a known truth (simulated captures): the figures the
// acceptance criteria name ("within 0.3 mg RMS of the true specific force after the best-fit
// rotation").
#ifndef IMUCAL_CORE_VALIDATION_H_
#define IMUCAL_CORE_VALIDATION_H_

#include <vector>

#include "Eigen/Core"

namespace imucal::core {

// The rotation R minimising sum |R * estimate_i - truth_i|^2 (Kabsch). A calibration without
// known orientations fixes its body frame by convention (accelerometer x axis, x-y plane), so
// comparisons with a truth in another frame are made after this rotation.
Eigen::Matrix3d BestFitRotation(const std::vector<Eigen::Vector3d>& estimate,
                                const std::vector<Eigen::Vector3d>& truth);

// RMS over samples of |R * estimate_i - truth_i| (vector error norm), R the best-fit rotation
// when `align` is set, identity otherwise.
double VectorRmsError(const std::vector<Eigen::Vector3d>& estimate,
                      const std::vector<Eigen::Vector3d>& truth, bool align);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_VALIDATION_H_
