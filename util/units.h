// The constants of units every imucal library shares, defined once. Angles in rad unless a name
// says deg; specific force in m/s^2 unless a name says g or mg.
#ifndef IMUCAL_UTIL_UNITS_H_
#define IMUCAL_UTIL_UNITS_H_

#include <limits>
#include <numbers>

namespace imucal {

inline constexpr double kPi = std::numbers::pi;
inline constexpr double kRadToDeg = 180.0 / kPi;  // deg per rad
inline constexpr double kDegToRad = kPi / 180.0;  // rad per deg
// Standard gravity (CGPM 1901), m/s^2: what "1 g" means in every unit conversion, and the
// gravity a capture is fitted to when it does not state its local one (capture-format.md).
inline constexpr double kStandardGravity = 9.80665;
inline constexpr double kMgPerMs2 = kStandardGravity / 1e3;  // m/s^2 per mg
// "Not determined": what a figure the data did not reach reads (reports write it as null).
inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

}  // namespace imucal

#endif  // IMUCAL_UTIL_UNITS_H_
