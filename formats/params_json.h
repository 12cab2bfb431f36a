// The "imucal-params v1" JSON form of a core::ParamSet (../shared/spec/report.md): what the
// server stores per version, `imucal params get --json` prints and robots load.
//
// {
//   "format": "imucal-params v1",
//   "device": "robot-0042", "version": 7, "created_at": "2026-11-21T10:00:00Z",
//   "model": core::kModelText,               // the equations below, spelled out for readers
//   "gravity": 9.80665,                      // m/s^2, local gravity the solve used
//   "accel": {
//     "input_unit": "m/s^2" | "g" | "counts",
//     "bias": [3], "scale": [3], "tri_angles": [3], "frame_angles": [3], "quadratic": [3],
//     "misalignment": [[3],[3],[3]],         // R(frame_angles)*L(tri_angles), row-major;
//                                            // informational, ignored on read
//     "stderr": {"bias", "scale", "tri_angles", "frame_angles", "quadratic": [3]}
//   },
//   "gyro": {
//     "input_unit": "rad/s" | "deg/s" | "counts", "calibrated": true,
//     "bias": [3], "matrix": [[3],[3],[3]],  // row-major
//     "scale": [3],                          // diagonal of matrix; informational, ignored on read
//     "accel_coupling": [[3],[3],[3]],       // row-major, (rad/s)/(m/s^2)
//     "stderr": {"bias": [3], "matrix": [[3],[3],[3]]}
//   },
//   "effects": [{"sensor": "accel"|"gyro", "axis": "x"|"y"|"z", "regressor": "temperature",
//                "coefficient": 0.0, "stderr": 0.0, "error_before": 0.0, "error_after": 0.0,
//                "applied": true, "evidence": {"what": "..."}}],
//   "quality": {"accel_rms": 0.0004, "gyro_static_rms": 0.00002},
//   "noise": {                               // optional (core::NoiseFigures, core/allan.h)
//     "method": "...",                       // informational, ignored on read
//     "interval": {"t_start": 0.1, "t_end": 9.9, "samples": 1960, "rate_hz": 200},
//     "units": {...},                        // each figure's unit spelled out; informational
//     "accel": {"noise_density": [3],        // N, m/s^2/sqrt(Hz), CONTINUOUS-time density
//               "bias_instability": [3],     // B, m/s^2
//               "random_walk": [3],          // K, m/s^3/sqrt(Hz)
//               "random_walk_bound": [3],    // upper bound on K when K was not reached
//               "noise_std_per_sample": [3]},// N*sqrt(rate_hz), m/s^2; informational
//     "gyro":  {... the same in rad/s/sqrt(Hz), rad/s, rad/s^2/sqrt(Hz), rad/s},
//     "notes": ["gyro random walk not reached on x, y, z: ..."]
//   },                                       // figures not reached are null (NaN)
//   "source": {"session": "...", "software": "imucal x.y.z"}
// }
//
// Numbers are written with the shortest representation that reads back to the same double, so
// ParamSet -> JSON -> ParamSet is exact. Standard errors may be NaN (not determined by the data):
// they are written as null, and null reads back as NaN. Every other number must be a number.
//
// Reading: "noise" is optional (older parameter sets have none); when present, its
// interval.rate_hz and each sensor's noise_density are required (null allowed: NaN).
// "format", "accel" (bias, scale, tri_angles, frame_angles, quadratic, input_unit) and
// "gyro" (bias, matrix, input_unit) are required. Missing optional members take the ParamSet
// defaults, except missing standard errors, which read as NaN (unknown). Unknown members are
// ignored ("more fields are welcome"). Effect evidence is a string in core::Effect: it is written
// as the JSON object it holds if it holds one, else as {"what": evidence}; a string or an object
// is accepted on read ({"what": s} alone reads as s, any other object as its compact JSON).
#ifndef IMUCAL_FORMATS_PARAMS_JSON_H_
#define IMUCAL_FORMATS_PARAMS_JSON_H_

#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "core/capture.h"
#include "core/params.h"

namespace imucal::formats {

inline constexpr std::string_view kParamsFormat = "imucal-params v1";
inline constexpr std::string_view kReportFormat = "imucal-report v1";

// Pretty-printed (2-space indent) "imucal-params v1" JSON. Does not validate: a parameter set
// that Corrector::Create rejects is written as it is (an axis outside 0..2 is written as "?",
// which ParamSetFromJson rejects).
std::string ParamSetToJson(const core::ParamSet& params);

// Parses an "imucal-params v1" object, or an "imucal-report v1" object whose `parameters`
// member is one. InvalidArgument on anything else, the message starting with the JSON path of
// the first fault: `accel.scale[2]: expected a number`, `effects[1].regressor: unknown
// regressor "ax*bz"`, `parameters.format: expected "imucal-params v1"`. Checks types and
// names only; Corrector::Create checks that the values make an invertible model.
absl::StatusOr<core::ParamSet> ParamSetFromJson(std::string_view json);

// Input unit names as the capture header and the JSON write them ("m/s^2", "g", "counts";
// "rad/s", "deg/s", "counts"). The same strings as core/capture.h's AccelUnitName and
// GyroUnitName, kept here so that the SDK does not link core's compiled library.
std::string_view UnitName(core::AccelUnit unit);
std::string_view UnitName(core::GyroUnit unit);

}  // namespace imucal::formats

#endif  // IMUCAL_FORMATS_PARAMS_JSON_H_
