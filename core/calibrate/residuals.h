// Calibration stage "residuals": what the final model leaves, and the parameter set.
//
//   accelerometer  |a| - g per used pose, in-sample and held out (each pose left out of a refit;
//                  for ferraris a face placed once is not predictable without itself)
//   gyroscope      the static rate (|calibrated rate| over the static poses), and the
//                  gravity-direction error after each move, in-sample and held out (one move left
//                  out), each full turn's error and angle
//   poses          each interval's calibrated up direction, face and residuals
//   parameters     the model, its standard errors (the accelerometer's from its covariance, NaN
//                  where held; the gyro bias's from the scatter of the pose means)
#ifndef IMUCAL_CORE_CALIBRATE_RESIDUALS_H_
#define IMUCAL_CORE_CALIBRATE_RESIDUALS_H_

#include <vector>

#include "Eigen/Core"
#include "core/calibrate/accel_stage.h"
#include "core/calibrate/gyro_stage.h"
#include "core/calibrate/report.h"
#include "core/calibrate/verdict.h"
#include "core/bias_wander.h"
#include "core/capture.h"
#include "core/params.h"

namespace imucal::core::pipeline {

// The largest finite |x| (0 when none); the RMS of the finite values (NaN when none).
double MaxAbsFinite(const std::vector<double>& v);
double RmsFinite(const std::vector<double>& v);

struct AccelResiduals {
  // Per used pose, m/s^2: |a| - g in-sample, and held out (NaN where not predictable or not
  // computed).
  std::vector<double> in_sample, heldout;
};
// In-sample and (unless !heldout or the fit is the face references' alone) held-out residuals of
// the final accelerometer; fills the accel_* figures of `out`.
AccelResiduals ComputeAccelResiduals(const AccelStage& accel, ProtocolKind protocol,
                                     const std::vector<Eigen::Vector3d>& ups, double gravity_m_s2,
                                     bool heldout, Residuals* out);

// RMS over the used poses of |calibrated static rate|, rad/s.
double GyroStaticRms(const std::vector<StaticInterval>& intervals, const std::vector<int>& used,
                     const GyroParams& gyro);

// The gyroscope fit's figures in the report: each move's error (in-sample and held out) and
// rotation, their RMS and maximum, each full turn's error and integrated angle, and the matrix's
// standard errors. Replaces what an earlier fit put there.
void ReportGyroFit(const Capture& capture, const std::vector<PlannedMove>& planned,
                   const std::vector<TurnCandidate>& turns, const GyroFit& gyro,
                   CalibrationReport* report);

// The figures a robot will see, from the final parameter set applied as the SDK applies it
// (core/correction.h: the stored bias, effects included), replacing the fits' own:
//   - each move's gravity-direction error (its in-sample figure; the held-out one stays the
//     fit's, a refit without the move), their RMS and maximum: the corrected rates integrated
//     over the move, the ups of its two poses corrected.
// (The static rate's RMS is already the stored model's: GyroStaticRms, or the effects stage's.)
// The fits' figures differ: the gyroscope's fit interpolates the bias between each move's poses
// and its ups come from the accelerometer before the effects were added. Does nothing when the
// gyroscope's output is not in rad/s (neither calibrated nor a known unit).
void ReportFinalFigures(const Capture& capture, const std::vector<StaticInterval>& intervals,
                        const std::vector<PlannedMove>& planned, CalibrationReport* report);

// One report per interval (used or not): calibrated up direction, face, and for used poses the
// residuals of `residuals` (in the order of `used`).
std::vector<PoseReport> MakePoseReports(const std::vector<StaticInterval>& intervals,
                                        const AccelParams& accel, const AccelResiduals& residuals);

// Sets each pose's file and line range from the capture's record of where its samples came from.
void AttachSources(const Capture& capture, std::vector<PoseReport>* poses);

// The parameter set of the final model, with its standard errors (the gyro matrix's are
// ReportGyroFit's; the gyro bias's never below what the readings' grid, noise.gyro_step,
// allows) and the quality figures of `residual`.
ParamSet MakeParamSet(const Capture& capture, const AccelStage& accel, const GyroFit& gyro,
                      const std::vector<StaticInterval>& intervals, const Residuals& residual,
                      const NoiseLevel& noise);

// Each estimated parameter's standard error against the range a sensor plausibly has, for the
// verdict: the accelerometer's free parameters (AccelPlausibleRange) and, when calibrated, the
// gyroscope matrix's entries (kGyroPlausibleRelative of its mean scale).
std::vector<ParameterSpread> ParameterSpreads(const ParamSet& params, const AccelMask& accel_free);

// A pose's calibrated specific force (m/s^2) with the applied accelerometer effects taken out at
// its own signals (its mean temperature, its middle's time since `t0_s`), as the SDK's
// Corrector would give it.
Eigen::Vector3d CorrectedSpecificForce(const AccelParams& accel, const std::vector<Effect>& effects,
                                       const StaticInterval& interval, double t0_s);

// Per-axis residuals of the verified faces with the stored model and its applied effects at
// each pose's signals (as the SDK's Corrector would apply them). A face's direction is the axis
// its pair was turned about (core/protocol.h PairTurnAxis), its size the mean of the two poses'.
std::vector<FaceResidual> FaceResiduals(const Capture& capture,
                                        const std::vector<StaticInterval>& intervals,
                                        const std::vector<PairCheck>& pairs,
                                        const ParamSet& params);

// The gyroscope's bias between poses (core/bias_wander.h), from each used pose's samples
// corrected with `params` as the SDK applies them: the mean rate and its white-noise standard
// deviation, and the difference of the pose's two halves. The rest's Allan rate random walk
// (params.noise) is what it is compared with. Not run (ran false) when the gyroscope's output is
// not in rad/s.
BiasWander GyroWanderOf(const Capture& capture, const std::vector<StaticInterval>& intervals,
                        const std::vector<int>& used, const ParamSet& params,
                        const NoiseLevel& noise);

}  // namespace imucal::core::pipeline

#endif  // IMUCAL_CORE_CALIBRATE_RESIDUALS_H_
