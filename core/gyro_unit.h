// Which unit a gyroscope's numbers are in, by physics: the rates integrated over a move between
// two rests must turn the gravity direction the accelerometer sees at the first rest into the
// one it sees at the second. Read in the right unit they do, to the sensor's scale error (a few
// degrees over a 90-degree move); read as rad/s when they are deg/s they turn 57.3 times too far,
// as deg/s when they are rad/s 57.3 times too little. Unlike the size of the rates (a capture's
// moves may be under 1% of its samples) or a fitted scale (a gyro fit on rates 57.3 times too
// large can settle on a scale near 1, the turns aliased by whole revolutions), this does not
// depend on how the capture was recorded. Used by the importers' inference
// (importers/unit_inference.h) and by the check after the fit (core/calibrate/unit_check.h).
#ifndef IMUCAL_CORE_GYRO_UNIT_H_
#define IMUCAL_CORE_GYRO_UNIT_H_

#include <optional>
#include <string>
#include <vector>

#include "core/capture.h"
#include "core/static_detector.h"

namespace imucal::core {

// Only moves that tilt gravity by this much tell the units apart (a turn about the vertical
// leaves gravity where it is at any rate).
inline constexpr double kMinTiltForUnitDeg = 15.0;

struct GyroUnitEvidence {
  int moves = 0;  // moves between consecutive rests, in one file, with no time gap
  // Median error (degrees) of the gravity direction the moves predict, the rates read as rad/s
  // and as deg/s (NaN without moves).
  double error_as_rad_s_deg = std::numeric_limits<double>::quiet_NaN();
  double error_as_deg_s_deg = std::numeric_limits<double>::quiet_NaN();
  // The unit that agrees (median error under 10 degrees) and is more than 3 times better than
  // the other, or nullopt.
  std::optional<GyroUnit> unit;
  std::string Describe() const;  // one clause for notes and messages
};

// The evidence of the moves between consecutive `rests` (used static intervals, in time order,
// in the capture's input units; the accelerometer not in raw counts, whose offset bends the
// directions).
GyroUnitEvidence GyroUnitFromMoves(const Capture& capture,
                                   const std::vector<StaticInterval>& rests);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_GYRO_UNIT_H_
