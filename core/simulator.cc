#include "core/simulator.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <optional>
#include <random>
#include <string>
#include <string_view>
#include <tuple>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "core/capture.h"
#include "core/model.h"
#include "core/params.h"
#include "core/regressor.h"
#include "util/units.h"

namespace imucal::core {
namespace {

// ---------------------------------------------------------------------------------------------
// Random numbers: std::mt19937_64 is specified bit for bit by the standard; the distributions
// below are ours (std::normal_distribution differs between standard libraries).

// SplitMix64 finaliser: decorrelates the per-stream seeds derived from one user seed.
uint64_t SplitMix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ULL;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
  return x ^ (x >> 31);
}

enum class Stream : uint64_t { kGeometry = 1, kNoise = 2, kTruth = 3, kWander = 4 };

uint64_t StreamSeed(uint64_t seed, Stream stream) {
  return SplitMix64(SplitMix64(seed) ^ static_cast<uint64_t>(stream));
}

class Rng {
 public:
  explicit Rng(uint64_t seed) : engine_(seed) {}

  // Uniform in [0, 1) with 53 random bits.
  double Uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }
  double Uniform(double lo, double hi) { return lo + (hi - lo) * Uniform(); }

  // Standard normal by Box-Muller (one value per two uniforms; simple and reproducible).
  double Normal() {
    const double u1 = 1.0 - Uniform();  // (0, 1]: log is finite
    const double u2 = Uniform();
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
  }
  double Normal(double sigma) { return sigma * Normal(); }
  Eigen::Vector3d Normal3(double sigma) {
    const double x = Normal(sigma);
    const double y = Normal(sigma);
    return Eigen::Vector3d(x, y, Normal(sigma));
  }

  Eigen::Vector3d UnitVector() {
    Eigen::Vector3d v = Normal3(1.0);
    while (v.norm() < 1e-6) v = Normal3(1.0);
    return v.normalized();
  }

  // Uniform on SO(3) (Haar measure): a normalised 4-D Gaussian as a unit quaternion. This is
  // "direction uniform on the sphere with a uniform yaw about it".
  Eigen::Matrix3d Rotation() {
    Eigen::Vector4d q;
    do {
      const double w = Normal();
      const double x = Normal();
      const double y = Normal();
      q = Eigen::Vector4d(w, x, y, Normal());
    } while (q.norm() < 1e-6);
    q.normalize();
    return Eigen::Quaterniond(q(0), q(1), q(2), q(3)).toRotationMatrix();
  }

 private:
  std::mt19937_64 engine_;
};

Eigen::Matrix3d Rot(double angle_rad, const Eigen::Vector3d& axis) {
  return Eigen::AngleAxisd(angle_rad, axis).toRotationMatrix();
}

// ---------------------------------------------------------------------------------------------
// Poses.

// A static orientation the protocol asks for. A pose reached by the six-face 180-degree turn
// carries the turn explicitly (axis in body coordinates, angle) instead of the angle-axis of
// the relative rotation, which is ill-defined at 180 degrees.
struct PlannedPose {
  Eigen::Matrix3d R_world_body;
  std::string label;
  std::optional<std::pair<Eigen::Vector3d, double>> turn;
};

// The floor normal tilted by tilt_deg from the vertical, in a uniformly random direction.
Eigen::Matrix3d RandomFloor(double tilt_deg, Rng& rng) {
  const double azimuth = rng.Uniform(0.0, 2.0 * kPi);
  const Eigen::Vector3d axis(-std::sin(azimuth), std::cos(azimuth), 0.0);
  return Rot(tilt_deg * kDegToRad, axis);
}

// Field-notes 1: each face up on the floor with a random yaw, then turned 180 degrees (plus a
// random error) about the floor normal. Face "Y-" puts the sensor's -y axis up.
void PlanSixFace(const SimOptions& options, const Eigen::Matrix3d& R_world_floor, Rng& rng,
                 std::vector<PlannedPose>& poses) {
  struct Face {
    const char* label;
    Eigen::Vector3d up_body;       // the body axis that points along the floor normal
    Eigen::Matrix3d R_floor_face;  // a rotation taking up_body to floor z
  };
  const Eigen::Vector3d x = Eigen::Vector3d::UnitX();
  const Eigen::Vector3d y = Eigen::Vector3d::UnitY();
  const std::array<Face, 6> faces = {{
      {"Z+", Eigen::Vector3d::UnitZ(), Eigen::Matrix3d::Identity()},
      {"Z-", -Eigen::Vector3d::UnitZ(), Rot(kPi, x)},
      {"Y+", y, Rot(kPi / 2, x)},
      {"Y-", -y, Rot(-kPi / 2, x)},
      {"X+", x, Rot(-kPi / 2, y)},
      {"X-", -x, Rot(kPi / 2, y)},
  }};
  for (const Face& face : faces) {
    const double yaw = rng.Uniform(0.0, 2.0 * kPi);
    const Eigen::Matrix3d R_face =
        R_world_floor * Rot(yaw, Eigen::Vector3d::UnitZ()) * face.R_floor_face;
    poses.push_back({R_face, face.label, std::nullopt});
    // R_face * Exp(angle * up_body) = Exp(angle * floor normal) * R_face: a turn about the
    // floor normal, which is up_body in body coordinates.
    const double angle = kPi + rng.Normal(options.turn_error_deg * kDegToRad);
    poses.push_back({R_face * ExpSo3<double>(angle * face.up_body),
                     absl::StrCat(face.label, " turned"), std::make_pair(face.up_body, angle)});
  }
}

// Field-notes 2: three groups; in group k the body axis k lies in the floor plane (random yaw)
// and the unit turns about it in `steps` equal steps through a full circle.
void PlanPositions(int steps, const Eigen::Matrix3d& R_world_floor, Rng& rng,
                   std::vector<PlannedPose>& poses) {
  // Start of each group: body x and y groups with z up; the z group with x up (z horizontal).
  const std::array<Eigen::Matrix3d, 3> R_floor_start = {Eigen::Matrix3d::Identity(),
                                                        Eigen::Matrix3d::Identity(),
                                                        Rot(-kPi / 2, Eigen::Vector3d::UnitY())};
  const double step_rad = 2.0 * kPi / steps;
  int number = 1;
  for (int k = 0; k < 3; ++k) {
    const double yaw = rng.Uniform(0.0, 2.0 * kPi);
    const Eigen::Matrix3d R_start =
        R_world_floor * Rot(yaw, Eigen::Vector3d::UnitZ()) * R_floor_start[k];
    for (int j = 0; j < steps; ++j) {
      poses.push_back({R_start * Rot(j * step_rad, Eigen::Vector3d::Unit(k)),
                       absl::StrCat("pos ", number++), std::nullopt});
    }
  }
}

std::vector<PlannedPose> PlanPoses(const SimOptions& options, const Eigen::Matrix3d& R_world_floor,
                                   Rng& rng) {
  std::vector<PlannedPose> poses;
  switch (options.protocol) {
    case SimProtocol::kSixFace:
      PlanSixFace(options, R_world_floor, rng, poses);
      break;
    case SimProtocol::kPositions24:
      PlanPositions(8, R_world_floor, rng, poses);
      break;
    case SimProtocol::kPositions36:
      PlanPositions(12, R_world_floor, rng, poses);
      break;
    case SimProtocol::kFree:
      for (int i = 0; i < options.free_poses; ++i) {
        poses.push_back({rng.Rotation(), absl::StrCat("free ", i + 1), std::nullopt});
      }
      break;
  }
  for (int i = 0; i < options.extra_poses; ++i) {
    poses.push_back({rng.Rotation(), absl::StrCat("extra ", i + 1), std::nullopt});
  }
  return poses;
}

// ---------------------------------------------------------------------------------------------
// The orientation path: a list of segments, each R(t) = R_start * Exp(theta(t) * axis_body)
// about a fixed body axis, so the body rate is exactly theta'(t) * axis_body.

struct TremorTerm {
  double amplitude_rad;
  double frequency_hz;
  double phase_rad;
};

// Minimum-jerk step s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 on [0, 1] and ds/dtau: rest to rest
// with zero rate and zero angular acceleration at both ends.
std::pair<double, double> MinimumJerk(double tau) {
  tau = std::clamp(tau, 0.0, 1.0);
  const double s = tau * tau * tau * (10.0 + tau * (-15.0 + 6.0 * tau));
  const double ds = 30.0 * tau * tau * (1.0 - tau) * (1.0 - tau);
  return {s, ds};
}

struct Segment {
  double t_start_s;
  double t_end_s;
  Eigen::Matrix3d R_start;
  Eigen::Vector3d axis_body = Eigen::Vector3d::UnitZ();
  bool is_move = false;
  double angle_rad = 0.0;          // move: the total angle phi
  std::vector<TremorTerm> tremor;  // hold: jitter terms (empty: perfectly still)
  double tremor_ramp_s = 0.0;      // hold: fade-in/out time of the jitter

  // theta(t) and theta'(t).
  std::pair<double, double> Angle(double t_s) const {
    const double duration = t_end_s - t_start_s;
    if (is_move) {
      const auto [s, ds] = MinimumJerk((t_s - t_start_s) / duration);
      return {s * angle_rad, ds / duration * angle_rad};
    }
    if (tremor.empty()) return {0.0, 0.0};
    // Sinusoids under an envelope that rises and falls by minimum-jerk ramps, so the hold starts
    // and ends exactly at its pose with zero rate (no rate step at the hold's ends).
    const auto [rise, rise_rate] = MinimumJerk((t_s - t_start_s) / tremor_ramp_s);
    const auto [fall, fall_rate] = MinimumJerk((t_end_s - t_s) / tremor_ramp_s);
    const double envelope = rise * fall;
    const double envelope_rate = (rise_rate * fall - rise * fall_rate) / tremor_ramp_s;
    double wave = 0.0;
    double wave_rate = 0.0;
    for (const TremorTerm& term : tremor) {
      const double omega = 2.0 * kPi * term.frequency_hz;
      const double arg = omega * (t_s - t_start_s) + term.phase_rad;
      wave += term.amplitude_rad * std::sin(arg);
      wave_rate += term.amplitude_rad * omega * std::cos(arg);
    }
    return {envelope * wave, envelope_rate * wave + envelope * wave_rate};
  }
};

// A few sinusoids of 0.5-3 Hz about one random body axis, faded in and out over 0.25 s (at most
// a quarter of the hold), with about rms_rad RMS away from the ends (incoherent sinusoids add in
// power, each of mean square amplitude^2 / 2).
void AddTremor(double rms_rad, Rng& rng, Segment& hold) {
  constexpr int kTerms = 4;
  const double duration = hold.t_end_s - hold.t_start_s;
  hold.axis_body = rng.UnitVector();
  hold.tremor_ramp_s = std::min(0.25, 0.25 * duration);
  double sum_sq = 0.0;
  for (int i = 0; i < kTerms; ++i) {
    const double frequency_hz = rng.Uniform(0.5, 3.0);
    const double phase_rad = rng.Uniform(0.0, 2.0 * kPi);
    const double amplitude = rng.Normal();
    hold.tremor.push_back({amplitude, frequency_hz, phase_rad});
    sum_sq += 0.5 * amplitude * amplitude;
  }
  const double gain = sum_sq > 0.0 ? rms_rad / std::sqrt(sum_sq) : 0.0;
  for (TremorTerm& term : hold.tremor) term.amplitude_rad *= gain;
}

// Builds holds and moves; fills `poses` with the orientations actually reached (each move ends
// exactly where its rates lead, so gyro integration reproduces the poses to rounding).
std::vector<Segment> BuildPath(const SimOptions& options, const std::vector<PlannedPose>& planned,
                               Rng& rng, std::vector<SimPose>& poses) {
  std::vector<Segment> segments;
  double t_s = 0.0;
  Eigen::Matrix3d R = planned.front().R_world_body;
  for (size_t i = 0; i < planned.size(); ++i) {
    if (i > 0) {
      Eigen::Vector3d axis;
      double angle;
      if (planned[i].turn.has_value()) {
        std::tie(axis, angle) = *planned[i].turn;
      } else {
        const Eigen::AngleAxisd relative(R.transpose() * planned[i].R_world_body);
        axis = relative.axis();
        angle = relative.angle();
      }
      Segment move{t_s, t_s + options.move_s, R, axis, true, angle, {}, 0.0};
      segments.push_back(move);
      R = R * ExpSo3<double>(angle * axis);
      t_s = move.t_end_s;
    }
    const double hold_s = i == 0 ? options.initial_rest_s : options.hold_s;
    Segment hold{t_s, t_s + hold_s, R, Eigen::Vector3d::UnitZ(), false, 0.0, {}, 0.0};
    if (options.hand_tremor) AddTremor(options.tremor_rms_deg * kDegToRad, rng, hold);
    segments.push_back(hold);
    poses.push_back({hold.t_start_s, hold.t_end_s, R, planned[i].label});
    t_s = hold.t_end_s;
  }
  return segments;
}

// ---------------------------------------------------------------------------------------------
// Sampling.

struct CompiledEffect {
  Sensor sensor;
  int axis;
  Regressor regressor;
  double coefficient;
};

std::vector<CompiledEffect> CompileEffects(const std::vector<SimEffect>& effects) {
  std::vector<CompiledEffect> compiled;
  for (const SimEffect& effect : effects) {
    compiled.push_back(
        {effect.sensor, effect.axis, *ParseRegressor(effect.regressor), effect.coefficient});
  }
  return compiled;
}

double TrueTemperature(const SimOptions& options, double t_s) {
  if (!options.temperature) return options.temp_start_c;
  return options.temp_start_c + options.temp_rise_c * (1.0 - std::exp(-t_s / options.temp_tau_s));
}

// Raw-unit noise per sensing axis that gives about `sigma_si` on the calibrated output: a raw
// error e on axis i moves the calibrated value by |column i of the linear map| * e.
Eigen::Vector3d RawNoiseSigma(const Eigen::Matrix3d& raw_to_si, double sigma_si) {
  return sigma_si * raw_to_si.colwise().norm().cwiseInverse().transpose();
}

// Adds the noise, then rounds to multiples of `step` (0: no rounding).
void AddNoiseAndQuantise(const Eigen::Vector3d& sigma, double step, Rng& rng,
                         Eigen::Vector3d& raw) {
  for (int i = 0; i < 3; ++i) raw(i) += rng.Normal(sigma(i));
  if (step > 0) raw = ((raw / step).array().round() * step).matrix();
}

// The rounding step of a sensor's readings: the option's, else whole counts for counts.
double QuantisationStep(double step, bool counts) { return step > 0 ? step : (counts ? 1.0 : 0.0); }

std::vector<std::pair<std::string, std::string>> SimMetadata(const SimOptions& options) {
  return {{"simulator", "imucal"},
          {"sim_protocol", ProtocolName(options.protocol)},
          {"sim_seed", absl::StrCat(options.seed)}};
}

}  // namespace

// Magnitudes (one-sigma unless stated), typical of consumer MEMS IMUs (MPU-6050, ICM-20948 class
// datasheets; field-notes 7) before calibration:
//   accel bias          0.05 g per axis (datasheet zero-g offset +-50..80 mg)
//   accel scale error   1 % (datasheet sensitivity tolerance +-1..3 %)
//   accel tri_angles    3 mrad (cross-axis sensitivity ~0.3 %)
//   accel frame_angles  10 mrad (0.6 deg: the die in its package and the board in its case)
//   accel quadratic     3e-5 /(m/s^2) (0.3 mg at 1 g: nonlinearity ~0.3-0.5 % FS)
//   gyro bias           0.5 deg/s per axis (zero-rate offset +-1..5 deg/s, less after power-up)
//   gyro scale error    uniform 1-2 % with random sign (sensitivity tolerance +-1..3 %)
//   gyro misalignment   3 mrad per off-diagonal entry (cross-axis sensitivity ~0.3 %)
//   gyro accel_coupling zero
SimTruth RandomTruth(uint64_t seed, AccelUnit accel_unit, GyroUnit gyro_unit,
                     const SimOptions& options) {
  Rng rng(StreamSeed(seed, Stream::kTruth));
  const double g = options.gravity_m_s2;
  const bool accel_counts = accel_unit == AccelUnit::kCounts;
  const bool gyro_counts = gyro_unit == GyroUnit::kCounts;
  const double accel_nominal =
      accel_counts ? g / options.accel_counts_per_g : NominalAccelToSi(accel_unit, g);
  const double gyro_nominal =
      gyro_counts ? 1.0 / options.gyro_counts_per_rad_s : NominalGyroToSi(gyro_unit);

  SimTruth truth;
  AccelParams& accel = truth.accel;
  accel.bias = rng.Normal3(0.05 * g) / accel_nominal;
  if (accel_counts) accel.bias.array() += options.accel_offset_counts;
  accel.scale = accel_nominal * (Eigen::Vector3d::Ones() + rng.Normal3(0.01));
  accel.tri_angles = rng.Normal3(3e-3);
  accel.frame_angles = rng.Normal3(10e-3);
  accel.quadratic = rng.Normal3(3e-5);

  GyroParams& gyro = truth.gyro;
  Eigen::Vector3d scale;
  for (int i = 0; i < 3; ++i) {
    const double sign = rng.Uniform() < 0.5 ? -1.0 : 1.0;
    scale(i) = gyro_nominal * (1.0 + sign * rng.Uniform(0.01, 0.02));
  }
  Eigen::Matrix3d misalignment = Eigen::Matrix3d::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      if (r != c) misalignment(r, c) = rng.Normal(3e-3);
    }
  }
  gyro.matrix = misalignment * scale.asDiagonal();  // so matrix(j, j) = scale_j
  gyro.bias = rng.Normal3(0.5 * kDegToRad) / gyro_nominal;
  if (gyro_counts) gyro.bias.array() += options.gyro_offset_counts;
  gyro.accel_coupling.setZero();
  if (options.wide_second_order) {
    for (int i = 0; i < 3; ++i) {
      const double sign = rng.Uniform() < 0.5 ? -1.0 : 1.0;
      accel.quadratic(i) = sign * std::exp(rng.Uniform(std::log(1e-5), std::log(3e-4)));
    }
  }
  return truth;
}

namespace {

// The capture's header, and room for `n` samples.
void StartCapture(const SimOptions& options, size_t n, SimResult* result) {
  Capture& capture = result->capture;
  capture.device = "simulated";
  capture.accel_unit = options.accel_unit;
  capture.gyro_unit = options.gyro_unit;
  capture.temp_unit = TempUnit::kCelsius;
  capture.gravity_m_s2 = options.gravity_m_s2;
  capture.rate_hz = options.rate_hz;
  capture.extra_metadata = SimMetadata(options);
  capture.t_s.reserve(n);
  capture.accel.reserve(n);
  capture.gyro.reserve(n);
  if (options.temperature) capture.temp.reserve(n);
  result->true_accel_m_s2.reserve(n);
  result->true_gyro_rad_s.reserve(n);
  result->true_temp_c.reserve(n);
}

}  // namespace

absl::StatusOr<SimResult> Simulate(const SimOptions& options, const SimTruth& truth) {
  if (absl::Status s = ValidateSimOptions(options); !s.ok()) return s;
  if (absl::Status s = ValidateSimTruth(truth); !s.ok()) return s;

  SimResult result;
  result.truth = truth;
  Rng geometry(StreamSeed(options.seed, Stream::kGeometry));
  result.R_world_floor = RandomFloor(options.floor_tilt_deg, geometry);
  const std::vector<PlannedPose> planned = PlanPoses(options, result.R_world_floor, geometry);
  const std::vector<Segment> segments = BuildPath(options, planned, geometry, result.poses);

  const std::vector<CompiledEffect> effects = CompileEffects(options.effects);
  for (const CompiledEffect& e : effects)
    result.effects.push_back({e.sensor, e.axis, e.regressor.Name(), e.coefficient});

  // Samples at k / rate_hz from 0 through the end of the last hold (1e-9: rounding slack).
  const double duration_s = segments.back().t_end_s;
  const size_t n = static_cast<size_t>(std::floor(duration_s * options.rate_hz + 1e-9)) + 1;
  StartCapture(options, n, &result);
  Capture& capture = result.capture;

  const Eigen::Vector3d up_world(0.0, 0.0, options.gravity_m_s2);
  const Eigen::Matrix3d accel_linear = truth.accel.Misalignment() * truth.accel.scale.asDiagonal();
  const Eigen::Vector3d accel_sigma = RawNoiseSigma(accel_linear, options.accel_noise_m_s2);
  const Eigen::Vector3d gyro_sigma = RawNoiseSigma(truth.gyro.matrix, options.gyro_noise_rad_s);
  const double accel_step =
      QuantisationStep(options.accel_step, options.accel_unit == AccelUnit::kCounts);
  const double gyro_step =
      QuantisationStep(options.gyro_step, options.gyro_unit == GyroUnit::kCounts);
  Rng noise(StreamSeed(options.seed, Stream::kNoise));
  // The wandering bias (SimOptions::gyro_bias_shift_rad_s, gyro_bias_walk), in SI on the
  // calibrated rate. A move's shift is drawn once, when its middle is passed.
  Rng wander_rng(StreamSeed(options.seed, Stream::kWander));
  Eigen::Vector3d walk = Eigen::Vector3d::Zero(), shift = Eigen::Vector3d::Zero();
  const double walk_step = options.gyro_bias_walk * std::sqrt(1.0 / options.rate_hz);
  size_t shifted_move = segments.size();  // the last move whose shift was drawn

  size_t segment = 0;
  for (size_t k = 0; k < n; ++k) {
    const double t_s = static_cast<double>(k) / options.rate_hz;
    while (segment + 1 < segments.size() && t_s >= segments[segment].t_end_s) ++segment;
    const Segment& seg = segments[segment];
    if (options.gyro_bias_walk > 0.0 && k > 0) walk += wander_rng.Normal3(walk_step);
    if (options.gyro_bias_shift_rad_s > 0.0 && seg.is_move && shifted_move != segment &&
        t_s >= 0.5 * (seg.t_start_s + seg.t_end_s)) {
      shift = wander_rng.Normal3(options.gyro_bias_shift_rad_s);
      shifted_move = segment;
    }
    const auto [theta, theta_rate] = seg.Angle(t_s);
    const Eigen::Matrix3d R = seg.R_start * ExpSo3<double>(theta * seg.axis_body);
    const Eigen::Vector3d f_true = R.transpose() * up_world;
    const Eigen::Vector3d w_true = theta_rate * seg.axis_body;
    const double temp_true = TrueTemperature(options, t_s);

    const SignalArray signals = {temp_true,  t_s,        f_true.x(), f_true.y(),
                                 f_true.z(), w_true.x(), w_true.y(), w_true.z()};
    Eigen::Vector3d f_out = f_true;
    Eigen::Vector3d w_out = w_true;
    for (const CompiledEffect& effect : effects) {
      Eigen::Vector3d& out = effect.sensor == Sensor::kAccel ? f_out : w_out;
      out(effect.axis) += effect.coefficient * effect.regressor.Evaluate(signals);
    }
    w_out += walk + shift;

    Eigen::Vector3d accel_raw = truth.accel.Invert(f_out);
    AddNoiseAndQuantise(accel_sigma, accel_step, noise, accel_raw);
    Eigen::Vector3d gyro_raw = truth.gyro.Invert(w_out, f_true);
    AddNoiseAndQuantise(gyro_sigma, gyro_step, noise, gyro_raw);

    capture.t_s.push_back(t_s);
    capture.accel.push_back(accel_raw);
    capture.gyro.push_back(gyro_raw);
    if (options.temperature) capture.temp.push_back(temp_true + noise.Normal(options.temp_noise_c));
    result.true_accel_m_s2.push_back(f_true);
    result.true_gyro_rad_s.push_back(w_true);
    result.true_temp_c.push_back(temp_true);
  }
  return result;
}

absl::StatusOr<SimResult> Simulate(const SimOptions& options) {
  if (absl::Status s = ValidateSimOptions(options); !s.ok()) return s;
  return Simulate(options,
                  RandomTruth(options.seed, options.accel_unit, options.gyro_unit, options));
}

}  // namespace imucal::core
