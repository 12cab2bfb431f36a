// Which units a capture's numbers are in, for the formats that do not say (the imu_tk pair, a
// vendor CSV without --accel-unit/--gyro-unit).
#ifndef IMUCAL_IMPORTERS_UNIT_INFERENCE_H_
#define IMUCAL_IMPORTERS_UNIT_INFERENCE_H_

#include <optional>
#include <span>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "core/capture.h"
#include "importers/registry.h"

namespace imucal::importers {

// Unit inference for formats that carry no units (imu_tk, vendor CSV), applied unless
// ImportOptions names the unit. The rule, and why:
//
// Accelerometer: m = median over samples of |a| (the magnitude, so it is the same whichever
// face is up; most samples of a calibration capture are static, where |a| is about g).
//   |m - g| <= 0.3 g   -> m/s^2   (g = the capture's gravity, 9.80665 by default)
//   |m - 1| <= 0.3     -> g
//   otherwise          -> counts  (e.g. unsigned 16-bit around 32768, or 16384 LSB/g)
// The 30% band admits uncalibrated sensors (scale and bias errors of a few percent) and hand
// motion; the bands are far apart, so a sensor cannot fall into the wrong one.
//
// Gyroscope, in order:
//   1. the accelerometer is counts, and the gyro values are either all integers or have a
//      median |value| (over all components) above 50 -> counts (raw registers: no rate in rad/s
//      or deg/s has a median of 50 during a mostly static capture);
//   1b. physics (InferGyroUnitFromMoves): the rates integrated over each move between two rests
//      must turn the accelerometer's gravity direction at the first rest into the one at the
//      second. Read in the right unit they do (to the sensor's scale error, a few degrees);
//      read as rad/s when they are deg/s they turn 57 times too far, as deg/s when they are
//      rad/s 57 times too little. Whichever unit agrees, clearly better than the other, wins.
//      The rule below failed on a capture in deg/s whose moves were under 1% of its samples: the
//      99th percentile was a rest's rate. The physics does not depend on how long the moves are.
//   2. the 99th percentile of |w| (the rate magnitude) exceeds 20 -> deg/s (hand rotation reaches
//      tens to hundreds of deg/s, while 20 rad/s = 1150 deg/s is beyond a hand-held capture);
//   3. otherwise -> rad/s. A capture without rotation cannot tell deg/s from rad/s; the note
//      says so, and ImportOptions::gyro_unit settles it.
core::AccelUnit InferAccelUnit(std::span<const Eigen::Vector3d> accel, double gravity_m_s2,
                               std::string* reason);
core::GyroUnit InferGyroUnit(std::span<const Eigen::Vector3d> gyro, core::AccelUnit accel_unit,
                             std::string* reason);

// Rule 1b above, on a capture whose accelerometer unit is set (not counts: a raw offset bends
// the directions): the gyro unit the moves between rests agree with, or nullopt when no move
// tilts gravity by core::kMinTiltForUnitDeg or the moves agree with neither unit clearly (a
// gyroscope whose axes are not the accelerometer's, say); `reason` says why. core/gyro_unit.h
// holds the physics.
std::optional<core::GyroUnit> InferGyroUnitFromMoves(const core::Capture& capture,
                                                     std::string* reason);

// Sets capture->accel_unit and gyro_unit from `options` where it names them, else infers them
// from the samples with the rules above and appends each reason to `notes` (if non-null).
// Records how each was decided in capture->accel_unit_source / gyro_unit_source ("declared" or
// "inferred").
void ApplyOrInferUnits(const ImportOptions& options, core::Capture* capture,
                       std::vector<std::string>* notes);

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_UNIT_INFERENCE_H_
