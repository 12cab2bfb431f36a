// `imucal learn`'s core (issue 27): a dynamic gyro block learnt from recordings with a reference
// orientation, kept only if it proves itself on recordings it was not fitted on.
//
// The model (core/dynamic_gyro.h): corrected rate = C (u - b) - G a, then the gyro's delay, the
// odd rate non-linearity and a linear dilated filter. The fit: core/motion/fit.h.
// The gate: leave one training recording out; for each, the static model and the learnt one are
// fitted on the others and their absolute orientation error (AOE) measured on it. The block is
// kept when the mean held-out AOE is at least `gate_margin` below the static model's and no
// held-out recording is worse than under the static model; else the static result is the
// outcome, with the reason. The static model is the given parameter set, or else stage 1 (C, b,
// G fitted in motion) on the same recordings.
#ifndef IMUCAL_CORE_MOTION_LEARN_H_
#define IMUCAL_CORE_MOTION_LEARN_H_

#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/motion/align.h"
#include "core/motion/evaluate.h"
#include "core/motion/fit.h"
#include "core/motion/increments.h"
#include "core/params.h"

namespace imucal::core::motion {

struct LearnOptions {
  AlignOptions align;
  FitOptions fit;
  // Horizons: these in samples (seeds/003's) and these in seconds (what an integration feels).
  std::vector<int> horizons_samples = {16, 32};
  std::vector<double> horizons_s = {1.0, 5.0, 20.0};
  double block_s = 20.0;      // time blocks of the clustered standard errors
  double gate_margin = 0.05;  // the mean held-out AOE must fall by this fraction
  double rest_s = 0.5;        // the first rest of the rest-bias baseline
};

// A recording aligned and windowed.
struct PreparedRecording {
  const MotionRecording* recording = nullptr;
  Alignment alignment;
  FitRecording fit;
};

absl::StatusOr<PreparedRecording> Prepare(const MotionRecording& recording,
                                          const LearnOptions& options);

struct LearnResult {
  ParamSet static_params;  // the static model (given, or fitted in motion on the training set)
  ParamSet learnt_params;  // the outcome: with dynamic_gyro when the gate passed, else static
  ModelFit candidate;      // the learnt model on every training recording, gated or not
  bool gate_passed = false;
  std::string gate_reason;
  std::vector<DynamicGyroRecording> held_out;  // leave-one-recording-out figures
  std::vector<std::string> notes;
};

// `start`: a static parameter set, or nullopt for the nominal one (rad/s and m/s^2 in, identity).
absl::StatusOr<LearnResult> Learn(const std::vector<const PreparedRecording*>& training,
                                  const std::optional<ParamSet>& start,
                                  const LearnOptions& options);

// The baselines and the outcome on one recording (test or held out).
struct Evaluation {
  OrientationError raw, rest_bias, static_model, learnt;
  std::string rest_note;
  bool has_rest = false;
  int outside_envelope = 0;  // samples outside the block's training envelope
};

Evaluation Evaluate(const PreparedRecording& recording, const LearnResult& result,
                    const LearnOptions& options);

// The nominal parameter set: rad/s and m/s^2 in, identity, no bias.
ParamSet NominalParams();

// The gate on held-out figures, one rule for `imucal learn` and for the server that stores an
// uploaded block: at least 2 recordings held out, the mean held-out AOE at least `gate_margin`
// below the static model's, and no recording worse. The reason states the figures.
struct HeldOutVerdict {
  bool passed = false;
  std::string reason;
};
HeldOutVerdict JudgeHeldOut(const std::vector<DynamicGyroRecording>& held_out,
                            double gate_margin = 0.05);

}  // namespace imucal::core::motion

#endif  // IMUCAL_CORE_MOTION_LEARN_H_
