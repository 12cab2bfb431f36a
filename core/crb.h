// Cramer-Rao lower bound of the accelerometer's magnitude calibration: the smallest standard
// deviation any unbiased estimator of the 12 magnitude parameters (core/accel_solver.h order:
// bias, scale, tri_angles, quadratic) can reach from the given static poses.
//
// The model it bounds is the one the LM stage fits: every pose i has an UNKNOWN orientation, so
// only its magnitude carries information,
//   m_i = |L(tri) z(u_i)| - g,   z_j = y_j + q_j y_j^2,   y = diag(scale) (u_i - bias),
// where u_i is the pose's mean raw reading with independent Gaussian noise of std mean_std per
// axis. To first order m_i has std sigma_i = |d m_i / d u_i . mean_std| (MagnitudeSigmas), and
// the Fisher information is
//   F = J^T W J,   J_ik = d m_i / d theta_k at the TRUE parameters,   W = diag(1 / sigma_i^2),
// with CRB(theta_k) = sqrt((F_free^-1)_kk) over the free parameters. frame_angles leave |a|
// unchanged, so they are not part of it.
//
// What it does not include: the poses' model_sigma_m_s2 (a fitted misfit, not sensor noise, so
// it is ignored here: pose mean noise only), nor the information a known orientation (six-face
// faces) would add; an estimator that used orientations could beat this bound. The linearised
// magnitude keeps only the noise along gravity: across it, the unknown orientation absorbs the
// reading (exactly so for noise isotropic in the calibrated frame, as the simulator draws it).
#ifndef IMUCAL_CORE_CRB_H_
#define IMUCAL_CORE_CRB_H_

#include <vector>

#include "core/accel_solver.h"
#include "core/model.h"

namespace imucal::core {

// One-sigma Cramer-Rao bounds of the 12 magnitude parameters, in the parameters' units.
// `poses_at_truth`: the static poses with `mean` the noise-free raw reading at the truth
// (truth.Invert(specific force)); measured means also do, the Jacobian changing by O(noise).
// `mean_std` is the std of each mean (per-sample raw noise / sqrt(samples)).
// `gravity_m_s2` is a constant offset of m_i and does not enter F; it keeps the call in the
// solver's form. NaN for parameters that are not free; +infinity for every free parameter when
// the poses do not determine the free set (singular information).
AccelVector AccelCramerRaoStd(const AccelParams& truth,
                              const std::vector<AccelPose>& poses_at_truth, double gravity_m_s2,
                              const AccelMask& free);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_CRB_H_
