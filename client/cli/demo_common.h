// What the offline and the server demos share: a simulated robot and the before/after check.
#ifndef IMUCAL_CLIENT_CLI_DEMO_COMMON_H_
#define IMUCAL_CLIENT_CLI_DEMO_COMMON_H_

#include "absl/status/statusor.h"
#include "core/capture.h"
#include "core/params.h"
#include "core/simulator.h"

namespace imucal::cli {

// The demo robot's calibration capture: six-face, `extra_poses` random poses after it.
core::SimOptions DemoCaptureOptions(uint64_t seed, int extra_poses);

// Applies `params` to every sample of `in` through the SDK's Corrector (as a robot does).
absl::StatusOr<core::Capture> ApplyParams(const core::ParamSet& params, const core::Capture& in);

// Applies `params` to a fresh noise-free capture of the same unit (same truth, new poses) and
// prints the error of the nominal conversion (before) and of the calibrated values (after).
absl::Status PrintBeforeAfter(const core::SimOptions& capture_options, const core::SimTruth& truth,
                              const core::ParamSet& params);

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_DEMO_COMMON_H_
