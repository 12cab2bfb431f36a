// The `dynamic_gyro` member of an "imucal-params v1" document (issue 27): the learnt dynamic
// gyro block of core/dynamic_gyro.h, written and read by formats/params_json.cc. Present only
// when the parameter set has a block: a document without one is what it always was.
//
// "dynamic_gyro": {
//   "model": kDynamicGyroModelText,          // the equations, spelled out; ignored on read
//   "rate_hz": 200,                          // > 0: the rate it was learnt at (applied within 2 %)
//   "delay_s": 0.0026, "delay_stderr_s": 1e-4,     // the gyro's delay behind the true rate
//   "odd_rate_per_rad_s": [3], "odd_rate_stderr_per_rad_s": [3],  // 1/(rad/s), per axis
//   "taps": 29,                              // >= 0 (0: no filter)
//   "dilation": 16,                          // >= 1 samples between taps
//   "weights": [18*taps numbers],            // 3 rows (x, y, z) of 6*taps, row-major: column
//                                            // l*6 + c is channel c (0-2 static gyro output,
//                                            // rad/s per rad/s; 3-5 calibrated accel, rad/s per
//                                            // m/s^2) at lag l*dilation samples
//   "ridge_lambda": 0.01,                    // >= 0, chosen by cross-validation
//   "envelope": {"max_abs_rate_rad_s": [3], "max_abs_accel_m_s2": [3]},  // >= 0 each
//   "training": [{"name": "imu.csv:ref.csv", "sha256": "...", "duration_s": 120.5,
//                 "aoe_static_deg": 1.6, "aoe_learnt_deg": 0.8}],  // leave-one-out; null: not
//                                                                  // held out
//   "gate_reason": "learnt beats static on every held-out recording: ..."
// }
//
// Numbers are exact on a round trip. Standard errors and the AOE figures may be null (NaN);
// every other number must be a finite number. Required on read: rate_hz, taps, dilation,
// weights; the rest take core::DynamicGyro's defaults when missing.
#ifndef IMUCAL_FORMATS_DYNAMIC_GYRO_JSON_H_
#define IMUCAL_FORMATS_DYNAMIC_GYRO_JSON_H_

#include <string>

#include "absl/status/status.h"
#include "core/dynamic_gyro.h"
#include "nlohmann/json.hpp"

namespace imucal::formats {

// The block's equations, written as its "model" member (core::kModelText stays the static
// model's text: exports embed it, and a document without a block keeps its bytes).
inline constexpr const char* kDynamicGyroModelText =
    "dynamic gyro block, applied after the static model at rate_hz, per sample k: "
    "v(k) = w_s(k) + delay_s*rate_hz*(w_s(k) - w_s(k-1)); "
    "v_i += odd_rate_i*v_i*|v_i|; "
    "w(k) = v(k) + sum_{l=0}^{taps-1} W_l x(k - l*dilation), x = [w_s; a] (rad/s; m/s^2), "
    "W_l the 3x6 block of weights at lag l*dilation; before the window fills, missing lags "
    "read the oldest sample held. w_s: the static gyro output, a: the calibrated accel.";

// The largest window (taps-1)*dilation+1 a block may ask for, in samples: the filter
// spans 448 samples; a document asking for millions would make every robot allocate them.
inline constexpr int kMaxDynamicGyroWindowSamples = 65536;

nlohmann::ordered_json DynamicGyroToJson(const core::DynamicGyro& block);

// Reads the block at `path` ("dynamic_gyro", or "parameters.dynamic_gyro" in a report) and
// checks it with DynamicGyroIsValid. InvalidArgument naming the JSON path of the first fault.
absl::Status DynamicGyroFromJson(const nlohmann::ordered_json& j, const std::string& path,
                                 core::DynamicGyro* out);

// The checks a block must pass before anything applies it (the reader and sdk::Corrector::Create
// share them): rate_hz finite and > 0, taps >= 0, dilation >= 1, the window at most
// kMaxDynamicGyroWindowSamples, weights.size() == 18*taps, every weight, delay_s, odd_rate and
// ridge_lambda finite, the envelope finite and >= 0. InvalidArgument naming the field under
// `path`, e.g. `dynamic_gyro.weights: 17 values but taps*18 = 18 expected`.
absl::Status DynamicGyroIsValid(const core::DynamicGyro& block, const std::string& path);

}  // namespace imucal::formats

#endif  // IMUCAL_FORMATS_DYNAMIC_GYRO_JSON_H_
