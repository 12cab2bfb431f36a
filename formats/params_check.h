// Whether a parameter set can be applied: the checks a robot's SDK makes before it applies a
// set (client/sdk/corrector.h) and the server makes before it stores an uploaded one, so that
// no version is stored, let alone activated, that every robot would refuse.
#ifndef IMUCAL_FORMATS_PARAMS_CHECK_H_
#define IMUCAL_FORMATS_PARAMS_CHECK_H_

#include "absl/status/status.h"
#include "core/params.h"

namespace imucal::formats {

// InvalidArgument naming the parameter by its JSON path (e.g. `gyro.matrix: not invertible
// (condition number 3e+14)`, `accel.scale[1]: zero (not invertible)`) when a model value is not
// finite, an accel scale is zero, the gyro matrix is singular or ill-conditioned (condition
// number > 1e12), or the dynamic gyro block is malformed or sits in a set without a gyroscope.
// The effects are the SDK's to check (Corrector::Create), with their time origin.
absl::Status ModelIsApplicable(const core::ParamSet& params);

}  // namespace imucal::formats

#endif  // IMUCAL_FORMATS_PARAMS_CHECK_H_
