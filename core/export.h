// Exporters: a parameter set written in the formats robots' estimators already load.
//
// imucal stores the INVERSE model (raw u -> calibrated, core/model.h), body frame b:
//   a_b = R_f L S (u_a - b_a)  [+ quadratic terms]        R_f = exp([frame_angles]x),
//   w_b = G (u_g - b_g) - C a_b                           L unit lower-triangular, S = diag(scale)
// Every format below takes measurements in SI (m/s^2, rad/s), as a ROS sensor_msgs/Imu carries
// them: u_SI = k u with k the nominal factor of the input unit (m/s^2 and rad/s: 1; g: 9.80665;
// deg/s: pi/180). A parameter set in raw counts has no nominal factor and is refused.
// Write A = R_f L S / k_a (linear accel part, SI), G' = G / k_g. Biases in SI: k b.
//
// kKalibrImu: Kalibr's noise file `imu.yaml` (flat keys):
//   accelerometer_noise_density [m/s^2/sqrt(Hz)], accelerometer_random_walk [m/s^3/sqrt(Hz)],
//   gyroscope_noise_density [rad/s/sqrt(Hz)], gyroscope_random_walk [rad/s^2/sqrt(Hz)],
//   rostopic, update_rate [Hz]. One number per sensor: the largest of the three axes
//   (conservative; the per-axis values are in a comment). Continuous-time densities (core/allan.h).
//
// kKalibrIntrinsics: Kalibr's IMU "scale-misalignment" model (Rehder et al. 2016; Kalibr's
// IccSensors.py IccScaledMisalignedImu), FORWARD (true -> measured), in Kalibr's IMU frame i:
//   a_meas = M_a a_i + b_a                               M_a lower-triangular
//   w_meas = M_g C_gyro_i w_i + A_g C_gyro_i a_i + b_g   M_g lower-triangular, C_gyro_i rotation
//   a_i = C_i_b a_b, w_i = C_i_b w_b                     (T_i_b's rotation)
// Kalibr's accelerometer has no rotation, so its frame i is imucal's sensing-aligned frame:
//   C_i_b = R_f^T,  M_a = (L S / k_a)^-1,
//   M_g C_gyro_i = G'^-1 R_f  (an LQ decomposition: lower-triangular times rotation),
//   A_g = G'^-1 C R_f C_gyro_i^T.
// Written as `imu0:` with T_i_b, the noise keys, model: scale-misalignment,
// accelerometers: {M}, gyroscopes: {M, A, C_gyro_i}, rostopic, time_offset, update_rate.
//
// kOpenVins: OpenVINS's `kalibr_imu_chain.yaml` (`%YAML:1.0`, key imu0). OpenVINS
// (ov_msckf VioManagerOptions.h print_and_load_state, Propagator.cpp predict_and_compute)
// inverts the matrices on load, Dw = Tw^-1, Da = Ta^-1, keeps only their lower triangle
// (model "kalibr") or upper triangle (model "rpng"), and applies, with I its IMU frame:
//   a_I = R_ACCtoIMU Da (a_m - b_a)                      R_ACCtoIMU = R_IMUtoACC^T
//   w_I = R_GYROtoIMU Dw (w_m - b_g - Tg a_I)            R_GYROtoIMU = R_IMUtoGYRO^T
// imucal writes I = its body frame b, so (exactly, biases aside):
//   R_ACCtoIMU Da = A,  R_GYROtoIMU Dw = G',  Tg = G'^-1 C
//   model kalibr: Da = L S / k_a (lower), R_ACCtoIMU = R_f;  G' = Q_w Dw by a QL
//                 decomposition (rotation times lower-triangular)
//   model rpng:   A = Q_a Da and G' = Q_w Dw by QR decompositions (upper-triangular)
// Ta = Da^-1 and Tw = Dw^-1 are written (triangular like Da, Dw). T_i_b is the identity.
//
// None of the formats holds biases, imucal's second-order (quadratic) terms or its effects: the
// file says so in a comment at its top (with the biases, for reference), and ExportNotes returns
// the same for the CLI. The files are written with yaml-cpp's emitter (comments included); numbers
// in their shortest round-trip form, always with a decimal point (YamlFloat).
#ifndef IMUCAL_CORE_EXPORT_H_
#define IMUCAL_CORE_EXPORT_H_

#include <limits>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "core/params.h"

namespace imucal::core {

// imucal's own JSON ("imucal-params v1") is written by formats/params_json.h, not here.
enum class ExportFormat { kKalibrImu, kKalibrIntrinsics, kOpenVins };
// The intrinsic model OpenVINS is told to use (its StateOptions::ImuModel).
enum class OpenVinsModel { kKalibr, kRpng };

// "kalibr", "kalibr-intrinsics", "openvins".
std::string_view ExportFormatName(ExportFormat format);
absl::StatusOr<ExportFormat> ParseExportFormat(std::string_view name);

struct ExportOptions {
  static constexpr double kUnset = std::numeric_limits<double>::quiet_NaN();
  std::string rostopic = "/imu0";
  double update_rate_hz = kUnset;  // unset: the rate of the noise block's interval
  OpenVinsModel openvins_model = OpenVinsModel::kKalibr;
  // Values the user supplies (e.g. from the datasheet) for figures the parameter set's noise
  // block lacks; used only for those, and said so in the file. Units as the Kalibr keys.
  double accel_noise_density = kUnset;
  double accel_random_walk = kUnset;
  double gyro_noise_density = kUnset;
  double gyro_random_walk = kUnset;
  // A random walk the capture's rest did not reach is written as the upper bound the data gives
  // (core/allan.h; conservative for a filter), with a note. false: such a gap is an error that
  // asks for the value instead.
  bool random_walk_bound_as_value = true;
};

// A double as YAML text every reader of these files takes as the same float: the shortest digits
// that read back to the same double (std::to_chars), always with a decimal point and a signed
// exponent ("1.0e-05", "200.0", "0.0"): YAML 1.1 readers such as PyYAML (Kalibr) read "1e-05" as
// a string, and OpenCV's FileStorage (OpenVINS) reads "200" as an integer. Non-finite values are
// YAML's ".nan", ".inf", "-.inf" (ExportParams never writes them: it refuses them).
std::string YamlFloat(double v);

// OK when `topic` is a valid ROS 2 topic name (design.ros2.org "Topic and Service name
// mapping"): not empty; only letters, digits, '_', '/', a leading '~' and '{' '}' for
// substitutions; no token starting with a digit; no "//" or "__"; no trailing '/'. It is
// written into the YAML as is, so anything else (a newline, a quote, ': ') could change the
// file's meaning. InvalidArgument naming `rostopic` and the offending character otherwise.
absl::Status ValidateRosTopic(std::string_view topic);

// The file text. InvalidArgument when the parameter set is in raw counts, a matrix is singular,
// a value is not finite or options.rostopic is not a topic name (ValidateRosTopic);
// FailedPrecondition naming each noise figure (or the rate) that neither the noise block nor
// `options` provides, and the option that supplies it.
absl::StatusOr<std::string> ExportParams(const ParamSet& params, ExportFormat format,
                                         const ExportOptions& options);

// What the export leaves out or substitutes, one line each (biases, non-zero quadratic terms,
// effects, a nominal gyro matrix, noise values taken from `options`), for the CLI to print.
std::vector<std::string> ExportNotes(const ParamSet& params, ExportFormat format,
                                     const ExportOptions& options);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_EXPORT_H_
