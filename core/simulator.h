// Simulated calibration captures with known truth, for property tests, the demo and benchmarks.
//
// Physics (world frame z up, body frame = the accelerometer's calibrated frame):
//   specific force  f(t) = R_world_body(t)^T * (0, 0, +g)   (a level sensor reads +g on its up
//   axis) body rate       w(t) from the orientation path below; no translation; Earth rotation
//   ignored
//                   (15 deg/h = 7.3e-5 rad/s, far under the simulated gyro noise).
// Every move between two static orientations R_i -> R_j is one rotation about a fixed body axis:
//   R(t) = R_i * Exp(s(tau) * phi * axis_body),   w(t) = s'(tau) / move_s * phi * axis_body,
//   s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 (minimum jerk), tau = (t - t_move_start) / move_s,
// with (phi, axis) the angle-axis of R_i^T R_j, except for the six-face 180-degree turn, whose axis
// is the floor normal in body coordinates and angle pi + turn error. The rates are therefore
// exact: integrating them reproduces every pose.
//
// Sensor readings (truth in core/model.h's INVERSE form, raw -> calibrated):
//   accel raw = truth.accel.Invert(f + accel effects) + accel noise
//   gyro raw  = truth.gyro.Invert(w + gyro effects, f) + gyro noise
// converted to the chosen input unit (the truth's bias and scale are in that unit); counts are
// rounded to integers. Noise is white, drawn per sensing axis in raw units with standard
// deviation noise_SI / |scale_i|, so a calibrated reading has about the stated SI noise.
// An effect {sensor, axis, regressor, c} makes the calibrated output read
//   true[axis] + c * regressor(true signals)      (the convention of core/params.h's Effect)
// with the signals temperature (noiseless, degC), time (s from capture start), the true specific
// force and the true rate.
//
// Determinism: everything is a function of SimOptions (and the truth). Random numbers come from
// std::mt19937_64 (fully specified by the standard) with our own uniform and Box-Muller normal
// draws, not std::*_distribution, so a seed gives the same capture with any standard library.
// Geometry, noise and truth use separate streams derived from the seed: changing a noise level
// does not move the poses.
#ifndef IMUCAL_CORE_SIMULATOR_H_
#define IMUCAL_CORE_SIMULATOR_H_

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "core/capture.h"
#include "core/model.h"
#include "core/params.h"

namespace imucal::core {

enum class SimProtocol {
  kSixFace,      // field-notes 1: six faces up, each held, turned 180 degrees, held: 12 poses
  kPositions24,  // field-notes 2: axis x, y, z horizontal in turn, 8 positions 45 degrees apart
  kPositions36,  // field-notes 2: as kPositions24 with 12 positions 30 degrees apart
  kFree,         // field-notes 4 (Tedaldi): free_poses orientations uniform on SO(3)
};

// "six-face", "positions24", "positions36", "free".
std::string ProtocolName(SimProtocol protocol);
absl::StatusOr<SimProtocol> ParseSimProtocol(std::string_view name);

// An effect added to the truth; see core/params.h Effect for the sign convention.
struct SimEffect {
  Sensor sensor = Sensor::kAccel;
  int axis = 0;              // 0 = x, 1 = y, 2 = z
  std::string regressor;     // core/regressor.h grammar, e.g. "temperature", "ax*az"
  double coefficient = 0.0;  // SI output unit (m/s^2 or rad/s) per regressor unit
};

struct SimOptions {
  SimProtocol protocol = SimProtocol::kSixFace;
  uint64_t seed = 1;
  double rate_hz = 200.0;
  // The capture starts with a rest at the first pose's orientation: that rest IS the first static
  // pose (it lasts initial_rest_s instead of hold_s), as a static detector would see it.
  double initial_rest_s = 10.0;
  double hold_s = 4.0;  // every other static pose
  double move_s = 2.5;  // every move between two poses
  // RandomTruth draws the accelerometer's second-order terms from the wide prior of real MEMS
  // units: log-uniform in 1e-5..3e-4 per m/s^2 with a random sign, on every axis (issue 25),
  // instead of N(0, 3e-5) that most of them leave undetected. Drawn after everything else, so
  // the rest of the truth is the seed's as without it.
  bool wide_second_order = false;
  int extra_poses = 0;  // uniformly random orientations appended after the protocol's poses
  int free_poses = 36;  // kFree only
  // The floor (table) that six-face and positions poses rest on: its normal is tilted from the
  // vertical by this angle in a random direction. kFree and extra poses ignore it.
  double floor_tilt_deg = 1.0;
  double turn_error_deg = 3.0;     // std dev of the six-face 180-degree turn's error
  double accel_noise_m_s2 = 0.02;  // white, per axis per sample (about 2 mg)
  double gyro_noise_rad_s = 0.002;
  AccelUnit accel_unit = AccelUnit::kMetersPerSecond2;
  GyroUnit gyro_unit = GyroUnit::kRadPerSecond;
  // Counts only: nominal factor (per gravity_m_s2) and the register offset at zero input.
  double accel_counts_per_g = 2048.0;  // e.g. MPU-6050 at +-16 g
  double accel_offset_counts = 0.0;    // e.g. 32768 for an unsigned register
  double gyro_counts_per_rad_s = 16.4 * 180.0 / 3.14159265358979323846;  // 16.4 LSB/(deg/s)
  double gyro_offset_counts = 0.0;
  // Quantisation: readings are rounded to multiples of this step, in the capture's input unit
  // (e.g. 0.01 m/s^2, or 9.80665 / 16384 m/s^2 for a 16-bit register at +-2 g written in SI;
  // 0.01 rad/s, or 1 / 131 deg/s). 0: none, except that counts are always whole. Applied after
  // the noise: with noise below one step, a reading sits on one value through a rest.
  double accel_step = 0.0;
  double gyro_step = 0.0;
  double gravity_m_s2 = kStandardGravity;
  // Temperature T(t) = temp_start_c + temp_rise_c * (1 - exp(-t / temp_tau_s)) (warm-up), recorded
  // with temp_noise_c white noise. false: no temp column, and T stays at temp_start_c.
  bool temperature = true;
  double temp_start_c = 25.0;
  double temp_rise_c = 8.0;
  double temp_tau_s = 120.0;
  double temp_noise_c = 0.01;
  std::vector<SimEffect> effects;
  // Small random rotation jitter about a random fixed body axis during every hold (including
  // the initial rest): a few sinusoids of 0.5-3 Hz, about tremor_rms_deg RMS, faded in and out
  // over 0.25 s so that each hold starts and ends exactly at its pose with zero rate. Holds are
  // then not perfectly static; SimPose::R_world_body is the nominal orientation.
  bool hand_tremor = false;
  double tremor_rms_deg = 0.1;
  // A gyro bias that wanders (added to the calibrated rate, like an effect; its own random
  // stream, so turning it on moves neither the poses nor the noise):
  //   gyro_bias_shift_rad_s  a new offset per axis, N(0, shift^2), drawn at the middle of every
  //                          move: the bias moves when the unit is moved and holds while it
  //                          rests (what the imutk-ros2-repeat captures show, README "Effects
  //                          found in the real captures");
  //   gyro_bias_walk         a rate random walk K [rad/s/sqrt(s)] through the whole capture
  //                          (Allan deviation K sqrt(tau / 3)), per sample K sqrt(1 / rate_hz).
  double gyro_bias_shift_rad_s = 0.0;
  double gyro_bias_walk = 0.0;
};

// One static pose (hold) of the simulated capture.
struct SimPose {
  double t_start_s = 0.0;  // the hold's exact bounds; the moves lie between holds
  double t_end_s = 0.0;
  Eigen::Matrix3d R_world_body = Eigen::Matrix3d::Identity();
  // "Z+", "Z+ turned", ... (six-face); "pos 1".."pos 36" (positions); "free 1".. ; "extra 1"..
  std::string label;
};

// Truth in core/model.h's inverse form, in the capture's input units.
struct SimTruth {
  AccelParams accel;
  GyroParams gyro;
};

// Draws a realistic MEMS truth (magnitudes documented in simulator.cc, all one-sigma):
// accel bias 0.05 g, scale error 1 %, tri_angles 3 mrad, frame_angles 10 mrad, quadratic
// 3e-5 /(m/s^2); gyro bias 0.5 deg/s, scale error 1-2 % (random sign), misalignment 3 mrad off
// the diagonal; accel_coupling zero. Counts: the nominal scale is gravity_m_s2 /
// accel_counts_per_g (and 1 / gyro_counts_per_rad_s), the bias includes the offset.
// Only the counts fields and gravity_m_s2 of `options` are read.
SimTruth RandomTruth(uint64_t seed, AccelUnit accel_unit, GyroUnit gyro_unit,
                     const SimOptions& options);

struct SimResult {
  Capture capture;
  SimTruth truth;
  std::vector<SimPose> poses;  // in time order
  // Per sample, body frame, noiseless and without effects.
  std::vector<Eigen::Vector3d> true_accel_m_s2;
  std::vector<Eigen::Vector3d> true_gyro_rad_s;
  std::vector<double> true_temp_c;  // noiseless temperature, the effects' `temperature` signal
  std::vector<SimEffect> effects;   // as simulated, regressor names canonical
  // The floor's frame in world coordinates (z = the tilted floor normal). Drawn for every
  // protocol; only six-face and positions poses rest on it.
  Eigen::Matrix3d R_world_floor = Eigen::Matrix3d::Identity();
};

// InvalidArgument naming the offending field (e.g. "rate_hz", "effects[1].regressor").
absl::Status ValidateSimOptions(const SimOptions& options);
// InvalidArgument naming the offending parameter of a given truth (non-finite, zero scale, a
// singular gyroscope matrix).
absl::Status ValidateSimTruth(const SimTruth& truth);

// Simulates `options` with the given truth (in options' input units).
absl::StatusOr<SimResult> Simulate(const SimOptions& options, const SimTruth& truth);
// Same with RandomTruth(options.seed, options.accel_unit, options.gyro_unit, options).
absl::StatusOr<SimResult> Simulate(const SimOptions& options);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_SIMULATOR_H_
