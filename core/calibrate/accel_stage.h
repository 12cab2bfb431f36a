// Calibration stage "accel": the accelerometer from the static poses (core/accel_solver.h).
//
//   ls    stage 1, linear least squares: the face references' affine fit (six-face, ferraris;
//         seeds/000), else the ellipsoid of |a| = g; with too few poses for either, bias and
//         scale alone (the axis-aligned ellipsoid);
//   then  what the poses determine (observability). The terms the poses may not determine are
//         estimated with a prior, never switched off (maximum a posteriori): the faces' angles
//         with the face references' own fit, the second-order terms (and the angles without
//         faces) with the sensor class's widths (term_priors.h);
//   bsas  stage 2 (seeds/002), in units of the stage-1 standard errors;
//   lm    stage 3, Levenberg-Marquardt with the covariance; the case frame from the faces.
// With the six faces once each and nothing more, the affine fit is the result.
#ifndef IMUCAL_CORE_CALIBRATE_ACCEL_STAGE_H_
#define IMUCAL_CORE_CALIBRATE_ACCEL_STAGE_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/accel_solver.h"
#include "core/calibrate/calibrate.h"
#include "core/calibrate/protocol_checks.h"
#include "core/calibrate/term_priors.h"
#include "core/static_detector.h"

namespace imucal::core::pipeline {

struct AccelStage {
  AccelParams params;  // the final accelerometer (case frame from the faces when they gave one)
  AccelMatrix covariance = AccelMatrix::Zero();
  double chi2_reduced = 0;
  // The used poses (interval indices) and their pose data, with the final fit's model error in
  // their weights.
  std::vector<int> used;
  std::vector<AccelPose> poses;
  AccelMask free{};  // the parameters estimated
  AccelObservability observability;
  // The priors of the |a| = g fit: the face references' angles, then the sensor class's
  // second-order terms (and angles, without face references).
  AccelPriors priors;
  // What each prior did to its term (the report's term_priors).
  std::vector<TermPriorEffect> term_priors;
  bool from_faces = false;   // stage 1 came from the face references (the case frame is known)
  bool affine_only = false;  // the face references' fit is the result (nothing to refine on)
  std::vector<StageReport> stages;  // ls, bsas, lm
  std::vector<std::string> warnings;
  // What the model lacks or assumes, for the verdict (at best warn).
  std::vector<std::string> incomplete;
};

// Errors: FailedPrecondition when the poses determine not even bias and scale.
absl::StatusOr<AccelStage> SolveAccel(const Capture& capture, const CalibrateOptions& options,
                                      const NoiseLevel& noise, const ProtocolChecks& checks);

// One BSAS unit per parameter: its stage-1 standard error over the `free` parameters (seeds/002
// needs parameters of similar magnitude; standard errors make every coordinate equally
// uncertain). 1 for fixed parameters and where the error is not finite.
AccelVector StageOneUnits(const AccelParams& stage_one, const std::vector<AccelPose>& poses,
                          const AccelMask& free, const AccelPriors& priors = {});

// Sets every pose's common model error to the one the residual of `fit` shows
// (EstimateModelSigma with the number of `free` parameters).
void SetModelSigma(const AccelParams& fit, double gravity_m_s2, const AccelMask& free,
                   const AccelPriors& priors, std::vector<AccelPose>* poses);

}  // namespace imucal::core::pipeline

#endif  // IMUCAL_CORE_CALIBRATE_ACCEL_STAGE_H_
