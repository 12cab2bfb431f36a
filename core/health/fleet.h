// The fleet as a reference (issue 28): per sensor model, the spread of each parameter over the
// fleet's active versions, the robust distance of one parameter set to its siblings, and the
// units whose health checks walk away from the fleet.
//
// Per parameter p over the n siblings: the median m_p and the scaled MAD s_p = 1.4826 MAD (the
// standard deviation for a normal fleet, unmoved by a few odd units), floored at the median of
// the siblings' own standard errors (a fleet more alike than its calibrations can tell apart is
// not a reason). The distance of a parameter set is per parameter z_p = (x_p - m_p) / s_p; it is
// far from its siblings when max |z_p| exceeds `max_mads` (5 by default: for a normal fleet
// and 21 parameters a sibling exceeds it with probability about 21 * 5.7e-7 = 1.2e-5; the MAD of
// a small fleet is itself uncertain, hence the margin), and the verdict reason names the worst
// parameter: "accel scale x is 7.2 MADs from 48 siblings (median 1.0012, MAD 0.0004)".
#ifndef IMUCAL_CORE_HEALTH_FLEET_H_
#define IMUCAL_CORE_HEALTH_FLEET_H_

#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "core/health/check.h"
#include "core/params.h"

namespace imucal::core::health {

// The parameters compared, in order: accel bias x,y,z (input units), accel scale x,y,z, accel
// tri angles (rad), gyro bias x,y,z (input units), gyro matrix diagonal x,y,z and its six
// off-diagonal terms (the gyro's only when every sibling has a gyro).
std::vector<std::string> FleetParameterNames(bool with_gyro);
Eigen::VectorXd FleetParameterVector(const ParamSet& params, bool with_gyro);
Eigen::VectorXd FleetStdErrorVector(const ParamSet& params, bool with_gyro);

struct FleetReference {
  std::string sensor_model;
  int siblings = 0;
  bool with_gyro = true;
  std::vector<std::string> names;
  Eigen::VectorXd median, mad;  // mad: 1.4826 MAD, floored (header)
};

// FailedPrecondition with fewer than `min_siblings` parameter sets; InvalidArgument when their
// units differ (a model's devices deliver one unit).
absl::StatusOr<FleetReference> BuildFleetReference(const std::string& sensor_model,
                                                   const std::vector<ParamSet>& actives,
                                                   int min_siblings = 8);

struct FleetDistance {
  Eigen::VectorXd z;    // per parameter, in MADs
  double max_mads = 0;  // max |z|
  int worst = -1;       // index of the parameter
  bool far = false;
  std::string reason;  // empty unless far
};
FleetDistance DistanceToFleet(const FleetReference& fleet, const ParamSet& params,
                              double max_mads = 5.0);

// Health checks against the fleet: per unit, where its checks sit (the median of its first and of
// its last `window` checks) in what every check reads (|f| - g, the gyro bias x,y,z). A unit is
// walking away when its last checks sit more than `max_mads` fleet MADs (the spread of the units'
// last checks) from the fleet's median, and farther by `min_move_mads` than its first checks did.
struct UnitChecks {
  std::string device;
  std::vector<HealthCheck> checks;  // in time order
};
struct WalkingAway {
  std::string device;
  std::string quantity;  // "|a| - g", "gyro bias x", ...
  double first_mads = 0, last_mads = 0;
  std::string reason;
};
std::vector<WalkingAway> UnitsWalkingAway(const std::vector<UnitChecks>& units, int window = 3,
                                          double max_mads = 5.0, double min_move_mads = 3.0);

// The fleet's median check-to-check gyro spread (rad/s), the prior for a unit whose own spread
// is still being learnt (DriftOptions::gyro_spread_prior_rad_s): per unit the 1.4826 MAD of
// successive differences over sqrt(2), per axis; the median over units and axes. NaN when no
// unit has 4 checks.
double FleetGyroSpread(const std::vector<UnitChecks>& units);

}  // namespace imucal::core::health

#endif  // IMUCAL_CORE_HEALTH_FLEET_H_
