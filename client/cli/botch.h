// A botched half turn, shared by `imucal demo --server --botch-turn` (streamed through the SDK)
// and `imucal simulate --botch-turn` (written to a file for `imucal upload`), so both show the
// guide the same failed pair and its re-do.
#ifndef IMUCAL_CLIENT_CLI_BOTCH_H_
#define IMUCAL_CLIENT_CLI_BOTCH_H_

#include "absl/status/statusor.h"
#include "core/capture.h"
#include "core/simulator.h"

namespace imucal::cli {

// The technician botches the first 180-degree turn of `sim`: the robot is set down a quarter
// turn into it, held there for `hold_s`, then turned the rest of the way. Returns the capture
// with that hold inserted (later samples move by the inserted time); InvalidArgument when `sim`
// has fewer than two poses or a first pose shorter than `hold_s`.
absl::StatusOr<core::Capture> BotchFirstTurn(const core::SimResult& sim, double hold_s);

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_BOTCH_H_
