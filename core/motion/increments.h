// The fit's linearisation (issue 27): orientation increments over windows of a recording,
// predicted by integrating the model's corrected rate and compared with the reference's.
//
// For a window of H steps from sample s, with phi_j = dt_j (w_j + w_j+1) / 2 (the trapezoid of
// core/motion/evaluate.h):
//   dR_pred = Exp(phi_s) ... Exp(phi_s+H-1),   dR_ref = R_ref(s)^T R_ref(s+H)
//   r = Log(dR_pred^T dR_ref)
// A change dw_k of the rates moves dR_pred to dR_pred Exp(sum_j M_j^T Jr(phi_j) dphi_j), with
// M_j = Exp(phi_j+1) ... Exp(phi_s+H-1) (the steps after j), so to first order
//   r(theta + d) = r - A d,   A = sum_k c_k J_k,   c_k = the coefficients of dw_k above,
// with J_k = d w_k / d theta the model's Jacobian at sample k. Increments are nearly linear in
// small rate corrections, so a few Gauss-Newton steps on many windows converge. A window needs
// the reference only at its two ends, so gaps inside it do not matter.
#ifndef IMUCAL_CORE_MOTION_INCREMENTS_H_
#define IMUCAL_CORE_MOTION_INCREMENTS_H_

#include <cstdint>
#include <functional>
#include <vector>

#include "Eigen/Core"
#include "core/motion/align.h"
#include "core/motion/recording.h"

namespace imucal::core::motion {

struct Window {
  int start = 0;    // sample
  int steps = 0;    // H
  int horizon = 0;  // index into the horizons
  int block = 0;    // time block (for the clustered standard errors)
};

// A recording ready to fit: its aligned reference and windows.
struct FitRecording {
  const MotionRecording* recording = nullptr;
  AlignedReference reference;
  std::vector<Window> windows;
  std::vector<int> segment_start;  // per sample: the first sample after the last IMU gap
  double rate_hz = 0.0;
  int blocks = 0;
};

// Windows of every horizon (steps), each every steps/2 samples, with the reference valid at both
// ends and no IMU gap inside; time blocks of `block_s`.
FitRecording PrepareFit(const MotionRecording& recording, const AlignedReference& reference,
                        const std::vector<int>& horizons, double block_s);

// Each window's residual r for the given rates.
std::vector<Eigen::Vector3d> WindowResiduals(const FitRecording& fit,
                                             const std::vector<Eigen::Vector3d>& rate_rad_s);

// The weighted normal equations of one recording: N = sum w A^T A, g = sum w A^T r,
// c = sum w |r|^2, and g per time block.
struct LinearSystem {
  Eigen::MatrixXd n;
  Eigen::VectorXd g;
  double c = 0.0;
  int windows = 0;
  std::vector<Eigen::VectorXd> block_g;
  void Add(const LinearSystem& other);
};

// Adds c_k J_k to `a` (3 x P) for sample k: the model's Jacobian applied to a coefficient.
using JacobianTimes = std::function<void(int k, const Eigen::Matrix3d& c_k, Eigen::MatrixXd* a)>;

LinearSystem Accumulate(const FitRecording& fit, const std::vector<Eigen::Vector3d>& rate_rad_s,
                        const std::vector<Eigen::Vector3d>& residuals,
                        const std::vector<double>& weights, int parameters,
                        const JacobianTimes& jacobian);

}  // namespace imucal::core::motion

#endif  // IMUCAL_CORE_MOTION_INCREMENTS_H_
