// A simulated fleet of docked robots for the health benchmark (bench/fleet_bench.cc) and tests:
// each unit has an active parameter set and docks once or twice a day, always in its dock's
// orientation, at a temperature that varies; each dock visit is a rest (a Capture in the
// parameter set's input units, made on demand from the unit's plan) with
//   calibrated output = truth + what the stored parameters miss:
//   accel  f_dock (+ dock jitter) (+ scale drift) + accel power-up offset
//          + (c_true - c_stored) T  + white noise N_a + random walk K_a within the rest
//   gyro   the unit's constant offset (its calibration's power-up draw) + a new power-up offset
//          per check ~ N(0, s_unit), s_unit uniform per unit in [gyro_spread_min, _max]
//          + (c_true - c_stored) T + white noise N_g + random walk K_g within the rest
// and at most one change per unit after a random time: an accelerometer bias step along gravity,
// a mounting rotation (about an axis across gravity), a gyro bias step of gyro_step_spreads times
// the unit's own spread on one axis, or a scale drift (every accel axis, linear in time).
// The bias is not a random walk across days at the Allan K (that K holds over minutes to hours;
// over days a MEMS bias is bounded, and its power-up repeatability dominates).
// Deterministic: std::mt19937_64 streams derived from (seed, unit, check), own normal draws.
#ifndef IMUCAL_CORE_HEALTH_FLEET_SIM_H_
#define IMUCAL_CORE_HEALTH_FLEET_SIM_H_

#include <cstdint>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "core/capture.h"
#include "core/params.h"
#include "util/units.h"

namespace imucal::core::health {

enum class FleetChange { kNone, kAccelBiasStep, kMountingStep, kGyroBiasStep, kScaleDrift };
const char* FleetChangeName(FleetChange change);

struct FleetSimOptions {
  int units = 50;
  double days = 90;
  uint64_t seed = 1;
  double rate_hz = 100;
  double rest_s = 20;
  double second_dock_probability = 0.5;  // a day has one dock rest, or two with this probability
  // Noise (per axis, calibrated units): the defaults are the MPU-6050 long rest's white noise
  // (tests/core/real_effects_test.cc) and random-walk bounds of the order that rest gives;
  // bench/fleet_bench.cc measures them from the shared rest and passes them in.
  double accel_noise_density = 3.5e-3;                // m/s^2/sqrt(Hz)
  double gyro_noise_density = 1.6e-4;                 // rad/s/sqrt(Hz)
  double accel_random_walk = 2e-4;                    // m/s^3/sqrt(Hz)
  double gyro_random_walk = 2e-5;                     // rad/s^2/sqrt(Hz)
  double gyro_spread_min_rad_s = 0.025 * kDegToRad;   // power-up to power-up, per axis
  double gyro_spread_max_rad_s = 0.05 * kDegToRad;
  double accel_power_up_m_s2 = 1e-4 * kStandardGravity;  // 0.1 mg per axis
  double dock_jitter_rad = 0.01 * kDegToRad;             // the dock's placement repeatability
  double temp_swing_c = 8;  // a check's temperature: the unit's mean +- this (uniform)
  double gyro_tempco_rad_s_per_c = 0.003 * kDegToRad;  // per axis, N(0, this)
  double accel_tempco_m_s2_per_c = 5e-5 * kStandardGravity;
  double tempco_stored_error = 0.05;  // the stored temperature effect is off by this fraction
  // The change and its size; it starts uniformly in [change_start_min_d, change_start_max_d].
  FleetChange change = FleetChange::kNone;
  double change_start_min_d = 20, change_start_max_d = 80;
  double accel_step_m_s2 = 5e-3 * kStandardGravity;  // 5 mg
  double mounting_step_rad = 0.3 * kDegToRad;
  double gyro_step_spreads = 5;
  double scale_drift_per_day = 3e-5;  // 30 ppm a day
};

struct SimCheckPlan {
  double t_s = 0;
  double temp_c = 0;
  bool changed = false;  // the change is in effect at this check
};

struct SimUnit {
  std::string device;
  int index = 0;
  ParamSet params;  // the active version (effects: temperature on every axis)
  Eigen::Vector3d dock_gravity_body = Eigen::Vector3d::Zero();  // f at the dock, m/s^2
  double gyro_spread_rad_s = 0;
  Eigen::Vector3d gyro_offset_rad_s = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_tempco_error = Eigen::Vector3d::Zero();  // (c_true - c_stored)
  Eigen::Vector3d accel_tempco_error = Eigen::Vector3d::Zero();
  double change_t_s = -1;  // < 0: none
  int first_changed = -1;  // the first check with the change in effect
  Eigen::Vector3d change_vector = Eigen::Vector3d::Zero();  // the step (accel, gyro) or axis
  std::vector<SimCheckPlan> plan;
};

std::vector<SimUnit> SimulateFleet(const FleetSimOptions& options);

// The rest of unit `unit` at its check `check` (input units: m/s^2, rad/s; temperature degC).
Capture SimulateDockRest(const SimUnit& unit, int check, const FleetSimOptions& options);

}  // namespace imucal::core::health

#endif  // IMUCAL_CORE_HEALTH_FLEET_SIM_H_
