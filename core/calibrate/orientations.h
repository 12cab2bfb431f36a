// Which orientations a capture's stops hold: distinct orientations, the same orientation held in
// two files, and the faces no stop has up. For the refusals (static_poses) and the protocol
// checks, which name them to the technician.
#ifndef IMUCAL_CORE_CALIBRATE_ORIENTATIONS_H_
#define IMUCAL_CORE_CALIBRATE_ORIENTATIONS_H_

#include <string>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "core/capture.h"
#include "core/static_detector.h"

namespace imucal::core::pipeline {

// Two directions within this are one orientation when counting distinct ones (raw directions
// are only as good as the sensor's uncalibrated axes).
inline constexpr double kSameOrientationDeg = 5.0;
// Two stops in different files within this hold the same orientation: one file was meant for
// another (the same face placed twice).
inline constexpr double kRepeatedOrientationDeg = 2.0;

// The raw up direction of each interval (unit; zero when not known): the accelerometer mean less
// a centre, zero for readings in m/s^2 or g, for counts the middle of the intervals' extremes.
std::vector<Eigen::Vector3d> RawUps(const Capture& capture,
                                    const std::vector<StaticInterval>& intervals);

// The number of distinct directions among `ups` (zero vectors count as one orientation).
int DistinctOrientations(const std::vector<Eigen::Vector3d>& ups);

// Sentences naming every two intervals of different files that hold the same orientation
// ("imu_posZ.csv (0.1-30.0 s) and imu_negZ.csv (0.1-31.0 s) hold the same orientation (Z-), 0.005
// degrees apart"), and, when the stops are on the faces and cover five of them, the face none
// has up ("no pose has Z+ up"). `ups` per interval, unit (zero: unknown); only intervals that are
// not turning are looked at.
std::vector<std::string> RepeatedOrientations(const Capture& capture,
                                              const std::vector<StaticInterval>& intervals,
                                              const std::vector<Eigen::Vector3d>& ups);

}  // namespace imucal::core::pipeline

#endif  // IMUCAL_CORE_CALIBRATE_ORIENTATIONS_H_
