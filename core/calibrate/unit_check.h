// After the fit: does the fitted scale fit the unit the capture was read in?
//
// A sensor's scale is within a few percent of its unit's nominal factor (m/s^2 per m/s^2, 9.81
// m/s^2 per g, pi/180 rad/s per deg/s). A fitted scale more than kUnitScaleTolerance from it
// means the unit is wrong: --accel-unit g on data in m/s^2 fits a scale of 1/9.8 of g's and
// exported an OpenVINS Ta of 9.7; a gyroscope in deg/s read as rad/s fits 1/57.3. That is a
// refusal naming the unit the data look like, not a calibration in the wrong unit. Raw counts
// are exempt: their scale is what the fit finds.
#ifndef IMUCAL_CORE_CALIBRATE_UNIT_CHECK_H_
#define IMUCAL_CORE_CALIBRATE_UNIT_CHECK_H_

#include <optional>
#include <vector>

#include "core/calibrate/report.h"
#include "core/capture.h"
#include "core/params.h"
#include "core/static_detector.h"

namespace imucal::core::pipeline {

// The bound: a scale more than 20% from its unit's is not a sensor's scale error.
inline constexpr double kUnitScaleTolerance = 0.2;

// A refusal (RefusalReason::kUnitMismatch) whose first sentence names the likely unit, or
// nullopt when both sensors' fitted scales fit their units (the gyroscope's only when its
// scale was calibrated) and the gyroscope's moves between `rests` (the used poses, in time
// order) agree with its unit (core/gyro_unit.h).
std::optional<Refusal> CheckFittedUnits(const Capture& capture, const ParamSet& params,
                                        const std::vector<StaticInterval>& rests);

}  // namespace imucal::core::pipeline

#endif  // IMUCAL_CORE_CALIBRATE_UNIT_CHECK_H_
