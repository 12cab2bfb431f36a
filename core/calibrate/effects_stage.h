// Calibration stage "effects": close the loop. The effect search (core/effects.h) examines what
// the final model leaves on the static poses and the rotations between them, and adds the
// effects the data supports, refitting the model jointly. Then:
//   - the report's residuals, poses and stages become those of the model as stored (its applied
//     effects included, as the SDK applies them);
//   - an applied accelerometer effect moves the pose directions the case frame and the gyroscope
//     were fitted to: both are fitted again to the corrected directions, and the rotation
//     residuals examined again;
//   - six-face: each verified face's per-axis residual with the stored model.
// Not run when every pose went into the face references' fit (none is spare to test on).
#ifndef IMUCAL_CORE_CALIBRATE_EFFECTS_STAGE_H_
#define IMUCAL_CORE_CALIBRATE_EFFECTS_STAGE_H_

#include <vector>

#include "absl/status/status.h"
#include "core/calibrate/accel_stage.h"
#include "core/calibrate/calibrate.h"
#include "core/calibrate/gyro_stage.h"
#include "core/calibrate/protocol_checks.h"
#include "core/calibrate/report.h"
#include "core/capture.h"

namespace imucal::core::pipeline {

// The model and its fits before the search, as the earlier stages left them.
struct EffectsStageInput {
  const ProtocolChecks& checks;  // intervals, protocol, and (in the report) the measured pairs
  const AccelStage& accel;       // used poses, their weights, the free parameters
  const RoughGyro& rough;        // the full turns
  const FinalGyro& gyro;         // the gyroscope (in the final case frame) and its moves
};

// Runs the search and what follows it. Updates `report` in place: params (model, effects,
// standard errors), residual, poses, moves, turns, stages ("effects") and effect_diagnostics.
absl::Status RunEffectsStage(const Capture& capture, const CalibrateOptions& options,
                             const EffectsStageInput& input, CalibrationReport* report);

}  // namespace imucal::core::pipeline

#endif  // IMUCAL_CORE_CALIBRATE_EFFECTS_STAGE_H_
