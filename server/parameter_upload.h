// ParameterService.UploadParameters' rules: a parameter set made offline (e.g. `imucal learn`'s,
// with a learnt dynamic gyro block) stored as a device's next version, judged and activated as a
// solved version is. Pure functions (no I/O): the handler reads the device, calls these, stores.
//
// The verdict of an uploaded set is core::JudgeVerdict's, over what the document itself states
// (its quality.accel_rms against the same accelerometer gates, an uncalibrated gyroscope matrix
// as an incompleteness), plus the dynamic block's own gate: a block must show, in its training
// list, recordings it was held out of (aoe_static_deg and aoe_learnt_deg both stated) on which
// its mean AOE is below the static model's; otherwise the verdict is fail (issue 27: a block
// that has not proven itself on held-out recordings does not ship on its own). ActivationOf
// then decides, as for a solve: pass is active at once, anything else a candidate.
#ifndef IMUCAL_SERVER_PARAMETER_UPLOAD_H_
#define IMUCAL_SERVER_PARAMETER_UPLOAD_H_

#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "core/calibrate/verdict.h"
#include "core/params.h"
#include "storage/types.h"

namespace imucal::server {

// The activation policy, the quality gate: only a passing version becomes active on its own;
// the others are candidates, for a person to promote. Solves and uploads alike.
inline storage::VersionState ActivationOf(core::Verdict verdict) {
  return verdict == core::Verdict::kPass ? storage::VersionState::kActive
                                         : storage::VersionState::kCandidate;
}

// Parses `json` ("imucal-params v1") for `device`: InvalidArgument naming the JSON path when it
// does not parse, is malformed, could not be applied by a robot (formats::ModelIsApplicable: a
// zero scale, a singular gyro matrix, ...), names another device, or expects other input units
// than the device delivers. An empty "device" is set to the device's id.
absl::StatusOr<core::ParamSet> ParseUploadedParams(std::string_view json,
                                                   const storage::Device& device);

// The verdict of an uploaded parameter set (see the file comment), with its reasons.
core::VerdictResult JudgeUploadedParams(const core::ParamSet& params);

// The version's provenance: who uploaded it, the software that made it, and, with a dynamic
// block, its training recordings with their digests and the held-out figures.
std::string UploadProvenance(const core::ParamSet& params, std::string_view actor);

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_PARAMETER_UPLOAD_H_
