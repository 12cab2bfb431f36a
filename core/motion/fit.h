// The fit of a gyro model to recordings with a reference (issue 27), in the order that the
// pre-filing measurement found to work (each stage starts from the one before):
//   1. static, in motion: C, b and the g-terms G of  w_s = C (u - b) - G a  (core/model.h),
//   2. dynamic: C, b, G again with the gyro's delay and the odd rate non-linearity
//      (core/dynamic_gyro.h), jointly, so their standard errors include each other's,
//   3. the linear dilated filter over [w_s; a], the rest fixed, its ridge chosen by
//      cross-validation grouped by recording (a filter that no ridge makes better on held-out
//      recordings than none is left out: taps 0).
// Each stage: Gauss-Newton on orientation increments over windows of several horizons
// (core/motion/increments.h), every horizon weighted alike (each window by 1 / (its horizon's
// robust residual variance x its horizon's window count)), Huber-weighted (IRLS) against
// outliers (a marker swap in the reference). Standard errors: clustered by time block (the
// windows overlap, so their residuals are not independent).
#ifndef IMUCAL_CORE_MOTION_FIT_H_
#define IMUCAL_CORE_MOTION_FIT_H_

#include <string>
#include <vector>

#include "Eigen/Core"
#include "core/motion/increments.h"
#include "core/params.h"

namespace imucal::core::motion {

struct FitOptions {
  int iterations = 4;    // Gauss-Newton steps per stage
  double huber_k = 2.0;  // normalised residual norm where the Huber weight starts to fall
  int taps = 10;         // the filter: taps x dilation samples back (50 ms x 4 at 200 Hz)
  int dilation = 4;
  // Ridge lambda (relative to the normal matrix's diagonal) tried by cross-validation.
  std::vector<double> ridge_grid = {1e-4, 1e-3, 1e-2, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0};
  bool filter = true;
  int threads = 1;
};

struct ModelFit {
  ParamSet params;  // the static part fitted; dynamic_gyro set after FitDynamic
  // Standard errors of C (row-major), b, G (row-major), delay, odd rate: 25 values (NaN where
  // the stage did not fit them).
  Eigen::VectorXd std_errors;
  std::vector<std::string> notes;
};

// Stage 1 from `start` (a given static parameter set or the nominal one).
ModelFit FitStatic(const std::vector<const FitRecording*>& recordings, const ParamSet& start,
                   const FitOptions& options);

// Stages 2 and 3 from stage 1's result.
ModelFit FitDynamic(const std::vector<const FitRecording*>& recordings, const ModelFit& stage1,
                    const FitOptions& options);

}  // namespace imucal::core::motion

#endif  // IMUCAL_CORE_MOTION_FIT_H_
