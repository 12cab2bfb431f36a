// The human-readable calibration summary printed by `imucal calibrate`.
#ifndef IMUCAL_CLIENT_CLI_SUMMARY_H_
#define IMUCAL_CLIENT_CLI_SUMMARY_H_

#include <optional>
#include <string>

#include "core/calibrate/calibrate.h"
#include "core/params.h"

namespace imucal::cli {

std::string FormatSummary(const core::CalibrationReport& report);

// The Allan figures of a parameter set's noise block (core/allan.h), one line per figure and
// sensor, units spelt out: N (white-noise density), B (bias instability), K (rate random walk),
// continuous-time. A random walk the rest did not reach shows the data's upper bound, marked
// "<" and labelled. Shared by `calibrate` and the server's `report`; no noise block: one line
// that says so.
// `has_gyro` false: the accelerometer's figures only (an accelerometer-only parameter set).
std::string FormatAllanFigures(const std::optional<core::NoiseFigures>& noise,
                               bool has_gyro = true);

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_SUMMARY_H_
