#include "core/health/fleet_sim.h"

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "Eigen/Geometry"
#include "absl/strings/str_format.h"
#include "core/health/drift.h"
#include "core/so3.h"

namespace imucal::core::health {
namespace {

// Own uniform and Box-Muller draws (as core/simulator.h): the same seed gives the same fleet
// with any standard library.
class Rng {
 public:
  explicit Rng(uint64_t seed) : engine_(seed) {}
  double Uniform() { return (static_cast<double>(engine_() >> 11) + 0.5) * 0x1.0p-53; }
  double Uniform(double lo, double hi) { return lo + (hi - lo) * Uniform(); }
  double Normal() { return std::sqrt(-2 * std::log(Uniform())) * std::cos(2 * M_PI * Uniform()); }
  Eigen::Vector3d Normal3() { return Eigen::Vector3d(Normal(), Normal(), Normal()); }

 private:
  std::mt19937_64 engine_;
};

uint64_t StreamSeed(uint64_t seed, uint64_t unit, uint64_t check) {
  return seed * 0x9E3779B97F4A7C15ull ^ (unit + 1) * 0xBF58476D1CE4E5B9ull ^
         (check + 1) * 0x94D049BB133111EBull;
}

Effect TemperatureEffect(Sensor sensor, int axis, double coefficient) {
  Effect e;
  e.sensor = sensor;
  e.axis = axis;
  e.regressor = "temperature";
  e.coefficient = coefficient;
  return e;
}

// The unit's active parameter set: a plausible MEMS calibration in SI input units, with its
// noise block (the simulator's own figures) and stored temperature effects.
ParamSet UnitParams(Rng& rng, const FleetSimOptions& o, int unit, Eigen::Vector3d* g_tc,
                    Eigen::Vector3d* a_tc) {
  ParamSet p;
  p.device = absl::StrFormat("robot-%04d", unit);
  p.version = 1;
  p.accel.bias = 0.1 * rng.Normal3();
  p.accel.scale = Eigen::Vector3d::Ones() + 0.01 * rng.Normal3();
  p.accel.tri_angles = 0.002 * rng.Normal3();
  p.gyro.bias = 0.01 * rng.Normal3();
  p.gyro.matrix = Eigen::Matrix3d::Identity() + 0.005 * Eigen::Matrix3d::Random();
  p.stderrs.accel.bias = Eigen::Vector3d::Constant(2e-4);
  p.stderrs.accel.scale = Eigen::Vector3d::Constant(1e-4);
  p.stderrs.accel.tri_angles = Eigen::Vector3d::Constant(1e-4);
  p.stderrs.gyro_bias = Eigen::Vector3d::Constant(1e-5);
  p.stderrs.gyro_matrix = Eigen::Matrix3d::Constant(1e-4);
  NoiseFigures n;
  n.rate_hz = o.rate_hz;
  n.accel.noise_density = Eigen::Vector3d::Constant(o.accel_noise_density);
  n.accel.random_walk = Eigen::Vector3d::Constant(o.accel_random_walk);
  n.gyro.noise_density = Eigen::Vector3d::Constant(o.gyro_noise_density);
  n.gyro.random_walk = Eigen::Vector3d::Constant(o.gyro_random_walk);
  p.noise = n;
  *g_tc = o.gyro_tempco_rad_s_per_c * rng.Normal3();
  *a_tc = o.accel_tempco_m_s2_per_c * rng.Normal3();
  for (int k = 0; k < 3; ++k) {
    // stored = true * (1 + error): the correction leaves (true - stored) T.
    const double eg = o.tempco_stored_error * rng.Normal(),
                 ea = o.tempco_stored_error * rng.Normal();
    p.effects.push_back(TemperatureEffect(Sensor::kGyro, k, (*g_tc)(k) * (1 + eg)));
    p.effects.push_back(TemperatureEffect(Sensor::kAccel, k, (*a_tc)(k) * (1 + ea)));
  }
  return p;
}

void PlanChange(Rng& rng, const FleetSimOptions& o, SimUnit* u) {
  if (o.change == FleetChange::kNone) return;
  u->change_t_s = rng.Uniform(o.change_start_min_d, o.change_start_max_d) * kDay_s;
  const double sign = rng.Uniform() < 0.5 ? -1.0 : 1.0;
  const Eigen::Vector3d up = u->dock_gravity_body.normalized();
  Eigen::Vector3d across = up.cross(rng.Normal3()).normalized();
  switch (o.change) {
    case FleetChange::kAccelBiasStep:
      u->change_vector = sign * o.accel_step_m_s2 * up;
      break;
    case FleetChange::kMountingStep:
      u->change_vector = o.mounting_step_rad * across;
      break;
    case FleetChange::kGyroBiasStep: {
      const int axis = static_cast<int>(rng.Uniform() * 3) % 3;
      u->change_vector =
          sign * o.gyro_step_spreads * u->gyro_spread_rad_s * Eigen::Vector3d::Unit(axis);
      break;
    }
    case FleetChange::kScaleDrift:
      u->change_vector = Eigen::Vector3d::Constant(sign);
      break;
    case FleetChange::kNone:
      break;
  }
}

}  // namespace

const char* FleetChangeName(FleetChange change) {
  switch (change) {
    case FleetChange::kNone:
      return "none";
    case FleetChange::kAccelBiasStep:
      return "accel bias step along g";
    case FleetChange::kMountingStep:
      return "mounting rotation";
    case FleetChange::kGyroBiasStep:
      return "gyro bias step";
    case FleetChange::kScaleDrift:
      return "accel scale drift";
  }
  return "?";
}

std::vector<SimUnit> SimulateFleet(const FleetSimOptions& o) {
  std::vector<SimUnit> units;
  for (int i = 0; i < o.units; ++i) {
    Rng rng(StreamSeed(o.seed, static_cast<uint64_t>(i), ~0ull));
    SimUnit u;
    u.index = i;
    u.params = UnitParams(rng, o, i, &u.gyro_tempco_error, &u.accel_tempco_error);
    u.device = u.params.device;
    // Tempco errors: what the stored effects miss (stored = true (1 + e)).
    for (const Effect& e : u.params.effects) {
      Eigen::Vector3d& err = e.sensor == Sensor::kGyro ? u.gyro_tempco_error : u.accel_tempco_error;
      err(e.axis) -= e.coefficient;
    }
    // The dock: within 3 degrees of level, any heading.
    const Eigen::Vector3d tilt(rng.Uniform(-3, 3), rng.Uniform(-3, 3), 0);
    const Eigen::Matrix3d r_world_body = ExpSo3<double>(kDegToRad * tilt);
    u.dock_gravity_body = r_world_body.transpose() * Eigen::Vector3d(0, 0, kStandardGravity);
    u.gyro_spread_rad_s = rng.Uniform(o.gyro_spread_min_rad_s, o.gyro_spread_max_rad_s);
    u.gyro_offset_rad_s = u.gyro_spread_rad_s * rng.Normal3();
    const double temp_mean_c = rng.Uniform(15, 30);
    PlanChange(rng, o, &u);
    for (int d = 0; d < static_cast<int>(o.days); ++d) {
      const int visits = rng.Uniform() < o.second_dock_probability ? 2 : 1;
      for (int v = 0; v < visits; ++v) {
        SimCheckPlan c;
        c.t_s = (d + (v == 0 ? rng.Uniform(0.2, 0.45) : rng.Uniform(0.55, 0.9))) * kDay_s;
        c.temp_c = temp_mean_c + rng.Uniform(-o.temp_swing_c, o.temp_swing_c);
        c.changed = u.change_t_s >= 0 && c.t_s >= u.change_t_s;
        if (c.changed && u.first_changed < 0) u.first_changed = static_cast<int>(u.plan.size());
        u.plan.push_back(c);
      }
    }
    units.push_back(std::move(u));
  }
  return units;
}

Capture SimulateDockRest(const SimUnit& u, int check, const FleetSimOptions& o) {
  Rng rng(StreamSeed(o.seed, static_cast<uint64_t>(u.index), static_cast<uint64_t>(check)));
  const SimCheckPlan& c = u.plan[check];
  const double T = c.temp_c;
  // The rest's constant part (calibrated units), before the stored effects are undone.
  Eigen::Vector3d f = u.dock_gravity_body;
  const Eigen::Vector3d jitter = o.dock_jitter_rad * rng.Normal3();
  f = ExpSo3<double>(jitter).transpose() * f;
  Eigen::Vector3d w = u.gyro_offset_rad_s + u.gyro_spread_rad_s * rng.Normal3();
  if (c.changed) {
    const double days = (c.t_s - u.change_t_s) / kDay_s;
    switch (o.change) {
      case FleetChange::kAccelBiasStep:
        f += u.change_vector;
        break;
      case FleetChange::kMountingStep:
        f = ExpSo3<double>(u.change_vector).transpose() * f;
        break;
      case FleetChange::kGyroBiasStep:
        w += u.change_vector;
        break;
      case FleetChange::kScaleDrift:
        f = f.cwiseProduct(Eigen::Vector3d::Ones() +
                           o.scale_drift_per_day * days * u.change_vector);
        break;
      case FleetChange::kNone:
        break;
    }
  }
  f += o.accel_power_up_m_s2 * rng.Normal3() + u.accel_tempco_error * T;
  w += u.gyro_tempco_error * T;
  // The stored effects subtract stored * T from the model's output: add it back here.
  Eigen::Vector3d stored_a = Eigen::Vector3d::Zero(), stored_g = Eigen::Vector3d::Zero();
  for (const Effect& e : u.params.effects)
    (e.sensor == Sensor::kGyro ? stored_g : stored_a)(e.axis) += e.coefficient * T;
  Capture cap;
  cap.device = u.device;
  cap.rate_hz = o.rate_hz;
  const int n = static_cast<int>(std::lround(o.rest_s * o.rate_hz));
  const double dt = 1.0 / o.rate_hz;
  const double sa = o.accel_noise_density * std::sqrt(o.rate_hz);
  const double sg = o.gyro_noise_density * std::sqrt(o.rate_hz);
  Eigen::Vector3d walk_a = Eigen::Vector3d::Zero(), walk_g = Eigen::Vector3d::Zero();
  for (int i = 0; i < n; ++i) {
    walk_a += o.accel_random_walk * std::sqrt(dt) * rng.Normal3();
    walk_g += o.gyro_random_walk * std::sqrt(dt) * rng.Normal3();
    const Eigen::Vector3d a = f + walk_a + sa * rng.Normal3() + stored_a;
    const Eigen::Vector3d g = w + walk_g + sg * rng.Normal3() + stored_g;
    cap.t_s.push_back(c.t_s + i * dt);
    cap.accel.push_back(u.params.accel.Invert(a));
    cap.gyro.push_back(u.params.gyro.Invert(g, a - stored_a));
    cap.temp.push_back(T);
  }
  return cap;
}

}  // namespace imucal::core::health
