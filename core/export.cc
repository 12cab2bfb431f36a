#include "core/export.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "Eigen/LU"
#include "Eigen/QR"
#include "absl/status/status.h"
#include "core/capture.h"
#include "util/str_util.h"
#include "util/units.h"
#include "yaml-cpp/yaml.h"

namespace imucal::core {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

// ---------------------------------------------------------------------------------------------
// Matrix factorisations into a rotation (det +1) and a triangular factor. The triangular
// factor's diagonal is made positive; if the matrix is a reflection (det < 0) the last diagonal
// entry stays negative so that the orthogonal factor is a proper rotation.

struct Factors {
  Matrix3d rotation;
  Matrix3d triangular;
};

void MakeProper(Factors* f, int row) {
  if (f->rotation.determinant() < 0) {
    f->rotation.col(row) *= -1.0;
    f->triangular.row(row) *= -1.0;
  }
}

// m = Q U, U upper-triangular (QR).
Factors QrFactors(const Matrix3d& m) {
  Eigen::HouseholderQR<Matrix3d> qr(m);
  Factors f{qr.householderQ(), qr.matrixQR().triangularView<Eigen::Upper>()};
  for (int i = 0; i < 3; ++i) {
    if (f.triangular(i, i) < 0) {
      f.rotation.col(i) *= -1.0;
      f.triangular.row(i) *= -1.0;
    }
  }
  MakeProper(&f, 2);
  return f;
}

// m = Q L, L lower-triangular (QL): with J the exchange matrix, m J = Q' U' gives
// m = (Q' J)(J U' J), and J U' J is lower-triangular.
Factors QlFactors(const Matrix3d& m) {
  Matrix3d j = Matrix3d::Zero();
  j(0, 2) = j(1, 1) = j(2, 0) = 1.0;
  Eigen::HouseholderQR<Matrix3d> qr(m * j);
  Matrix3d u = qr.matrixQR().triangularView<Eigen::Upper>();
  Factors f{Matrix3d(qr.householderQ()) * j, j * u * j};
  for (int i = 0; i < 3; ++i) {
    if (f.triangular(i, i) < 0) {
      f.rotation.col(i) *= -1.0;
      f.triangular.row(i) *= -1.0;
    }
  }
  MakeProper(&f, 0);
  return f;
}

// m = L Q, L lower-triangular (LQ): m^T = Q' U' gives m = U'^T Q'^T. Here `rotation` is Q.
Factors LqFactors(const Matrix3d& m) {
  const Factors t = QrFactors(m.transpose());
  return Factors{t.rotation.transpose(), t.triangular.transpose()};
}

// ---------------------------------------------------------------------------------------------
// YAML text, written with yaml-cpp's emitter. Numbers go in as the text of YamlFloat, which the
// emitter writes as plain scalars: its own double output would give "200" for a whole number and
// 17 digits ("0.10000000000000001") for the rest.

std::string Num(double v) { return YamlFloat(v); }

std::string VecText(const Vector3d& v) {
  return Cat("[", Num(v(0)), ", ", Num(v(1)), ", ", Num(v(2)), "]");
}

// Comment lines, each "# line" on its own: the emitter would put a comment on the previous
// comment's line without a newline between them (a newline after the last one leaves a blank
// line). A line break inside a line continues it as a comment.
void EmitComments(YAML::Emitter* out, const std::vector<std::string>& lines) {
  for (size_t i = 0; i < lines.size(); ++i) {
    if (i > 0) *out << YAML::Newline;
    *out << YAML::Comment(lines[i]);
  }
}

template <typename... Lists>
std::vector<std::string> Lines(std::vector<std::string> first, const Lists&... more) {
  (first.insert(first.end(), more.begin(), more.end()), ...);
  return first;
}

// `key:` and a matrix under it, one flow row per line: "  - [a, b, c]".
void EmitMatrix(YAML::Emitter* out, const char* key, const Eigen::MatrixXd& m) {
  *out << YAML::Key << key << YAML::Value << YAML::BeginSeq;
  for (Eigen::Index r = 0; r < m.rows(); ++r) {
    *out << YAML::Flow << YAML::BeginSeq;
    for (Eigen::Index c = 0; c < m.cols(); ++c) *out << Num(m(r, c));
    *out << YAML::EndSeq;
  }
  *out << YAML::EndSeq;
}

// The emitter's text, ending in a newline; Internal if the emitter found the document
// malformed (a bug here, not a user's error).
absl::StatusOr<std::string> EmittedText(const YAML::Emitter& out, std::string prefix = "") {
  if (!out.good()) return absl::InternalError(Cat("YAML emitter: ", out.GetLastError()));
  return Cat(prefix, std::string_view(out.c_str(), out.size()), "\n");
}

Eigen::Matrix4d Homogeneous(const Matrix3d& r) {
  Eigen::Matrix4d t = Eigen::Matrix4d::Identity();
  t.topLeftCorner<3, 3>() = r;
  return t;
}

// ---------------------------------------------------------------------------------------------
// The parameter set in SI measurement units.

struct SiModel {
  double k_accel = 1.0, k_gyro = 1.0;  // SI per input unit
  Matrix3d accel_linear;               // A = R_f L S / k_a
  Matrix3d accel_lower;                // L S / k_a
  Matrix3d frame;                      // R_f
  Matrix3d gyro;                       // G' = G / k_g
  Matrix3d coupling;                   // C
  Vector3d accel_bias_si, gyro_bias_si;
};

bool AllFinite(const ParamSet& p) {
  return p.accel.bias.allFinite() && p.accel.scale.allFinite() && p.accel.tri_angles.allFinite() &&
         p.accel.frame_angles.allFinite() && p.gyro.matrix.allFinite() && p.gyro.bias.allFinite() &&
         p.gyro.accel_coupling.allFinite();
}

absl::StatusOr<SiModel> ToSi(const ParamSet& p) {
  if (p.accel_unit == AccelUnit::kCounts || p.gyro_unit == GyroUnit::kCounts) {
    return absl::InvalidArgumentError(
        "the parameter set takes raw counts; Kalibr and OpenVINS take m/s^2 and rad/s (a ROS "
        "sensor_msgs/Imu) and a count has no nominal SI factor: calibrate a capture recorded in "
        "the driver's SI output to export it");
  }
  if (!AllFinite(p)) return absl::InvalidArgumentError("the parameter set has a non-finite value");
  SiModel m;
  // A driver converts g with standard gravity, whatever the local gravity of the solve.
  m.k_accel = NominalAccelToSi(p.accel_unit, kStandardGravity);
  m.k_gyro = p.gyro_unit == GyroUnit::kDegPerSecond ? kPi / 180.0 : 1.0;
  m.frame = ExpSo3<double>(p.accel.frame_angles);
  m.accel_lower =
      LowerMisalignment<double>(p.accel.tri_angles) * p.accel.scale.asDiagonal() / m.k_accel;
  m.accel_linear = m.frame * m.accel_lower;
  m.gyro = p.gyro.matrix / m.k_gyro;
  m.coupling = p.gyro.accel_coupling;
  m.accel_bias_si = p.accel.bias * m.k_accel;
  m.gyro_bias_si = p.gyro.bias * m.k_gyro;
  for (int i = 0; i < 3; ++i) {
    if (p.accel.scale(i) == 0.0) return absl::InvalidArgumentError("accel.scale has a zero");
  }
  const Eigen::FullPivLU<Matrix3d> lu(m.gyro);
  if (!lu.isInvertible()) return absl::InvalidArgumentError("gyro.matrix is not invertible");
  return m;
}

// ---------------------------------------------------------------------------------------------
// Noise figures: the noise block's, else the user's.

struct Noise {
  double accel_density = 0, accel_walk = 0, gyro_density = 0, gyro_walk = 0, rate_hz = 0;
  std::vector<std::string> lines;  // where each value came from (the comment)
};

double Largest(const Vector3d& v) { return v.allFinite() ? v.maxCoeff() : ExportOptions::kUnset; }

absl::StatusOr<Noise> ResolveNoise(const ParamSet& p, const ExportOptions& o) {
  Noise n;
  std::vector<std::string> missing;
  const NoiseFigures* block = p.noise ? &*p.noise : nullptr;
  auto pick = [&](const char* key, const char* flag, const char* unit, double measured,
                  const Vector3d* per_axis, const Vector3d* bound, double user, double* out) {
    if (std::isfinite(measured)) {
      *out = measured;
      n.lines.push_back(Cat(key, ": measured, largest axis of ", VecText(*per_axis), " ", unit));
    } else if (std::isfinite(user)) {
      *out = user;
      n.lines.push_back(
          Cat(key, ": NOT measured (",
              block ? "the noise block lacks it" : "the parameter set has no noise block",
              "); the value supplied to the export, ", Num(user), " ", unit));
    } else if (o.random_walk_bound_as_value && bound != nullptr && Largest(*bound) > 0) {
      // Conservative: the filter is told of more bias wander than the sensor has, never less.
      *out = Largest(*bound);
      n.lines.push_back(Cat(key,
                            ": NOT measured (the capture's rest is too short to reach it); "
                            "the UPPER BOUND the data gives, largest axis of ",
                            VecText(*bound), " ", unit, ". Pass ", flag,
                            " (e.g. the datasheet's) to replace it"));
    } else {
      std::string why = block ? "not reached by the capture's rest" : "no noise block";
      if (bound != nullptr && Largest(*bound) > 0) {
        AppendTo(&why, "; the data bound it above by ", Num(Largest(*bound)), " ", unit);
      }
      missing.push_back(Cat(key, " (", why, "): pass ", flag, " VALUE in ", unit));
    }
  };
  const Vector3d nan3 = Vector3d::Constant(ExportOptions::kUnset);
  const SensorNoise& a = block ? block->accel : SensorNoise{};
  const SensorNoise& g = block ? block->gyro : SensorNoise{};
  pick("accelerometer_noise_density", "--accel-noise-density", "m/s^2/sqrt(Hz)",
       Largest(a.noise_density), &a.noise_density, nullptr, o.accel_noise_density,
       &n.accel_density);
  pick("accelerometer_random_walk", "--accel-random-walk", "m/s^3/sqrt(Hz)", Largest(a.random_walk),
       &a.random_walk, block ? &a.random_walk_bound : &nan3, o.accel_random_walk, &n.accel_walk);
  pick("gyroscope_noise_density", "--gyro-noise-density", "rad/s/sqrt(Hz)",
       Largest(g.noise_density), &g.noise_density, nullptr, o.gyro_noise_density, &n.gyro_density);
  pick("gyroscope_random_walk", "--gyro-random-walk", "rad/s^2/sqrt(Hz)", Largest(g.random_walk),
       &g.random_walk, block ? &g.random_walk_bound : &nan3, o.gyro_random_walk, &n.gyro_walk);
  if (std::isfinite(o.update_rate_hz) && o.update_rate_hz > 0) {
    n.rate_hz = o.update_rate_hz;
  } else if (block != nullptr && block->rate_hz > 0) {
    n.rate_hz = block->rate_hz;
  } else {
    missing.push_back("update_rate (no noise block states the capture's rate): pass --rate HZ");
  }
  if (!missing.empty()) {
    return absl::FailedPreconditionError(Cat("cannot write the noise keys: ", Join(missing, "; ")));
  }
  if (block != nullptr) {
    n.lines.push_back(
        Cat("measured: overlapping Allan deviation of the calibrated signal over "
            "the rest t = ",
            block->t_start_s, "..", block->t_end_s, " s (", block->samples, " samples, ",
            block->rate_hz,
            " Hz); continuous-time densities, "
            "per-sample std = density * sqrt(rate)"));
  }
  return n;
}

// ---------------------------------------------------------------------------------------------
// The common header comment: who wrote the file, what it leaves out, its units.

std::vector<std::string> HeaderLines(const ParamSet& p, ExportFormat format, const SiModel& m,
                                     const std::vector<std::string>& notes) {
  std::vector<std::string> lines;
  std::string first = Cat(ExportFormatName(format), " export by imucal");
  if (!p.software.empty()) AppendTo(&first, " (", p.software, ")");
  lines.push_back(std::move(first));
  std::string second =
      Cat("device: ", p.device.empty() ? "(none)" : p.device, "  parameter version: ", p.version);
  if (!p.created_at.empty()) AppendTo(&second, "  created: ", p.created_at);
  lines.push_back(std::move(second));
  lines.insert(lines.end(), notes.begin(), notes.end());
  std::string units = "measurements in SI (m/s^2, rad/s) as a ROS sensor_msgs/Imu carries them";
  if (m.k_accel != 1.0 || m.k_gyro != 1.0) {
    AppendTo(&units, "; imucal's input units converted with the nominal factors (accel ", m.k_accel,
             ", gyro ", m.k_gyro, " SI per unit)");
  }
  lines.push_back(std::move(units));
  return lines;
}

std::vector<std::string> NoiseCommentLines(const Noise& n) {
  std::vector<std::string> lines;
  for (const std::string& l : n.lines) lines.push_back(Cat("noise: ", l));
  return lines;
}

// The four noise keys, each with its unit in a comment; `out` is inside a map.
void EmitNoiseKeys(YAML::Emitter* out, const Noise& n) {
  *out << YAML::Key << "accelerometer_noise_density" << YAML::Value << Num(n.accel_density)
       << YAML::Comment("[m/s^2/sqrt(Hz)] continuous-time white noise");
  *out << YAML::Key << "accelerometer_random_walk" << YAML::Value << Num(n.accel_walk)
       << YAML::Comment("[m/s^3/sqrt(Hz)] bias random walk");
  *out << YAML::Key << "gyroscope_noise_density" << YAML::Value << Num(n.gyro_density)
       << YAML::Comment("[rad/s/sqrt(Hz)] continuous-time white noise");
  *out << YAML::Key << "gyroscope_random_walk" << YAML::Value << Num(n.gyro_walk)
       << YAML::Comment("[rad/s^2/sqrt(Hz)] bias random walk");
}

absl::StatusOr<std::string> KalibrImu(const ParamSet& p, const ExportOptions& o, const SiModel& m,
                                      const Noise& n, const std::vector<std::string>& notes) {
  YAML::Emitter out;
  EmitComments(&out,
               Lines(HeaderLines(p, ExportFormat::kKalibrImu, m, notes), NoiseCommentLines(n)));
  out << YAML::Newline << YAML::BeginMap;  // a blank line after the comments
  EmitNoiseKeys(&out, n);
  out << YAML::Key << "rostopic" << YAML::Value << o.rostopic;
  out << YAML::Key << "update_rate" << YAML::Value << Num(n.rate_hz) << YAML::Comment("[Hz]");
  out << YAML::EndMap;
  return EmittedText(out);
}

absl::StatusOr<std::string> KalibrIntrinsics(const ParamSet& p, const ExportOptions& o,
                                             const SiModel& m, const Noise& n,
                                             const std::vector<std::string>& notes) {
  // Kalibr's frame i: the accelerometer's sensing-aligned frame, a_i = R_f^T a_b.
  const Matrix3d c_i_b = m.frame.transpose();
  const Matrix3d m_accel = m.accel_lower.inverse();
  const Matrix3d g_inv = m.gyro.inverse();
  const Factors lq = LqFactors(g_inv * m.frame);  // M_g C_gyro_i
  const Matrix3d a_gyro = g_inv * m.coupling * m.frame * lq.rotation.transpose();
  YAML::Emitter out;
  EmitComments(
      &out,
      Lines(HeaderLines(p, ExportFormat::kKalibrIntrinsics, m, notes),
            std::vector<std::string>{
                "model (Kalibr scale-misalignment, FORWARD true -> measured, frame i):",
                "  a_meas = M_a a_i + b_a ;  w_meas = M_g C_gyro_i w_i + A C_gyro_i a_i + b_g",
                "  M lower-triangular, C_gyro_i a rotation, A [(rad/s)/(m/s^2)];",
                "  a_i = C_i_b a_b (C_i_b = T_i_b's rotation; b = imucal's body frame)"},
            NoiseCommentLines(n)));
  out << YAML::BeginMap << YAML::Key << "imu0" << YAML::Value << YAML::BeginMap;
  EmitMatrix(&out, "T_i_b", Homogeneous(c_i_b));
  EmitNoiseKeys(&out, n);
  out << YAML::Key << "model" << YAML::Value << "scale-misalignment";
  out << YAML::Key << "accelerometers" << YAML::Value << YAML::BeginMap;
  EmitMatrix(&out, "M", m_accel);
  out << YAML::EndMap;
  out << YAML::Key << "gyroscopes" << YAML::Value << YAML::BeginMap;
  EmitMatrix(&out, "M", lq.triangular);
  EmitMatrix(&out, "A", a_gyro);
  EmitMatrix(&out, "C_gyro_i", lq.rotation);
  out << YAML::EndMap;
  out << YAML::Key << "rostopic" << YAML::Value << o.rostopic;
  out << YAML::Key << "time_offset" << YAML::Value << Num(0.0);
  out << YAML::Key << "update_rate" << YAML::Value << Num(n.rate_hz);
  out << YAML::EndMap << YAML::EndMap;
  return EmittedText(out);
}

absl::StatusOr<std::string> OpenVins(const ParamSet& p, const ExportOptions& o, const SiModel& m,
                                     const Noise& n, const std::vector<std::string>& notes) {
  const bool kalibr = o.openvins_model == OpenVinsModel::kKalibr;
  Factors acc, gyr;
  if (kalibr) {
    acc = Factors{m.frame, m.accel_lower};
    gyr = QlFactors(m.gyro);
  } else {
    acc = QrFactors(m.accel_linear);
    gyr = QrFactors(m.gyro);
  }
  const Matrix3d tg = m.gyro.inverse() * m.coupling;
  YAML::Emitter out;
  EmitComments(
      &out,
      Lines(HeaderLines(p, ExportFormat::kOpenVins, m, notes),
            std::vector<std::string>{
                "model (OpenVINS, applied after it inverts Tw and Ta on load; I = imucal's body "
                "frame):",
                "  a_I = R_IMUtoACC^T Ta^-1 (a_m - b_a) ;  w_I = R_IMUtoGYRO^T Tw^-1 (w_m - b_g - "
                "Tg a_I)",
                Cat("  Tw, Ta ", kalibr ? "lower" : "upper", "-triangular (model ",
                    kalibr ? "kalibr" : "rpng", "), Tg [(rad/s)/(m/s^2)]")},
            NoiseCommentLines(n)));
  out << YAML::Newline << YAML::BeginMap << YAML::Key << "imu0" << YAML::Value << YAML::BeginMap;
  EmitMatrix(&out, "T_i_b", Eigen::Matrix4d::Identity());
  EmitNoiseKeys(&out, n);
  out << YAML::Key << "rostopic" << YAML::Value << o.rostopic;
  out << YAML::Key << "time_offset" << YAML::Value << Num(0.0);
  out << YAML::Key << "update_rate" << YAML::Value << Num(n.rate_hz);
  out << YAML::Key << "model" << YAML::Value << YAML::DoubleQuoted << (kalibr ? "kalibr" : "rpng");
  EmitMatrix(&out, "Tw", gyr.triangular.inverse());
  EmitMatrix(&out, "R_IMUtoGYRO", gyr.rotation.transpose());
  EmitMatrix(&out, "Ta", acc.triangular.inverse());
  EmitMatrix(&out, "R_IMUtoACC", acc.rotation.transpose());
  EmitMatrix(&out, "Tg", tg);
  out << YAML::EndMap << YAML::EndMap;
  // OpenCV's FileStorage, which OpenVINS reads the file with, wants this first line; yaml-cpp
  // cannot emit it (it is not a YAML 1.2 directive) and skips it when it reads the file.
  return EmittedText(out, "%YAML:1.0\n");
}

}  // namespace

std::string YamlFloat(double v) {
  if (std::isnan(v)) return ".nan";  // YAML's spelling
  if (std::isinf(v)) return v > 0 ? ".inf" : "-.inf";
  if (v == 0.0) return "0.0";  // also -0.0
  std::string s = Cat(v);
  const size_t e = s.find_first_of("eE");
  std::string mantissa = s.substr(0, e);
  std::string exponent = e == std::string::npos ? "" : s.substr(e + 1);
  if (mantissa.find('.') == std::string::npos) mantissa += ".0";
  if (!exponent.empty() && exponent[0] != '-' && exponent[0] != '+') exponent = "+" + exponent;
  return exponent.empty() ? mantissa : mantissa + "e" + exponent;
}

std::string_view ExportFormatName(ExportFormat format) {
  switch (format) {
    case ExportFormat::kKalibrImu:
      return "kalibr";
    case ExportFormat::kKalibrIntrinsics:
      return "kalibr-intrinsics";
    case ExportFormat::kOpenVins:
      return "openvins";
  }
  return "?";
}

absl::StatusOr<ExportFormat> ParseExportFormat(std::string_view name) {
  for (ExportFormat f :
       {ExportFormat::kKalibrImu, ExportFormat::kKalibrIntrinsics, ExportFormat::kOpenVins}) {
    if (ExportFormatName(f) == name) return f;
  }
  return absl::InvalidArgumentError(
      Cat("unknown export format \"", name, "\" (kalibr, kalibr-intrinsics or openvins)"));
}

std::vector<std::string> ExportNotes(const ParamSet& p, ExportFormat format,
                                     const ExportOptions& options) {
  std::vector<std::string> notes;
  const double ka =
      p.accel_unit == AccelUnit::kCounts ? 1.0 : NominalAccelToSi(p.accel_unit, kStandardGravity);
  const double kg = p.gyro_unit == GyroUnit::kDegPerSecond ? kPi / 180.0 : 1.0;
  if (format != ExportFormat::kKalibrImu) {
    notes.push_back(
        Cat("NOT IN THIS FILE: biases (the format holds none; estimate them online). "
            "imucal's, in the measurement's SI unit: accel ",
            VecText(p.accel.bias * ka), " m/s^2, gyro ", VecText(p.gyro.bias * kg), " rad/s"));
    if (!p.accel.quadratic.isZero(0.0)) {
      notes.push_back(
          Cat("NOT IN THIS FILE: accel second-order terms (quadratic ", VecText(p.accel.quadratic),
              " 1/(m/s^2)); the format is linear, so the exported model differs from "
              "imucal's by quadratic_i * y_i^2 (",
              Num(p.accel.quadratic.cwiseAbs().maxCoeff() * 9.80665 * 9.80665), " m/s^2 at 1 g)"));
    } else {
      notes.push_back("NOT IN THIS FILE: second-order terms (zero in this parameter set)");
    }
    if (!p.gyro_calibrated) {
      notes.push_back("the gyroscope matrix is nominal: the capture determined only its bias");
    }
  } else {
    notes.push_back(
        "NOT IN THIS FILE: biases, scale, misalignment and second-order terms (the "
        "format holds noise only; see --format kalibr-intrinsics or openvins)");
  }
  if (!p.effects.empty()) {
    std::vector<std::string> names;
    for (const Effect& e : p.effects) {
      const std::string axis(1, "xyz"[e.axis % 3]);
      const char* sensor = e.sensor == Sensor::kGyro ? "gyro " : "accel ";
      names.push_back(Cat(sensor, axis, " ~ ", e.regressor));
    }
    notes.push_back(Cat("NOT IN THIS FILE: ", p.effects.size(), " effect(s) imucal applies (",
                        Join(names, ", "), "); only imucal's SDK applies them"));
  } else {
    notes.push_back("NOT IN THIS FILE: effects (none in this parameter set)");
  }
  // The learnt dynamic gyro block (issue 27) needs the samples before each one: no static
  // format holds it. Said as effects are, rather than refused: the static model exported is
  // still a sound calibration, only the motion correction is missing.
  if (p.dynamic_gyro) {
    const DynamicGyro& b = *p.dynamic_gyro;
    notes.push_back(Cat("NOT IN THIS FILE: the learnt dynamic gyro block (", b.taps,
                        " taps, dilation ", b.dilation, ", delay ", Num(b.delay_s), " s, at ",
                        Num(b.rate_hz),
                        " Hz); this file holds the static model only: only imucal's SDK "
                        "(sdk::Stream) applies the block"));
  }
  auto user = [&](double v, const char* key) {
    if (std::isfinite(v))
      notes.push_back(Cat(key, " supplied to the export: ", Num(v),
                          " (used only if the noise block lacks it)"));
  };
  if (!p.has_gyro) {
    notes.push_back(
        "the capture had no gyroscope: gyroscope_noise_density and gyroscope_random_walk are the "
        "values supplied to the export, not measured");
  }
  user(options.accel_noise_density, "accelerometer_noise_density");
  user(options.accel_random_walk, "accelerometer_random_walk");
  user(options.gyro_noise_density, "gyroscope_noise_density");
  user(options.gyro_random_walk, "gyroscope_random_walk");
  if (format == ExportFormat::kKalibrImu || format == ExportFormat::kKalibrIntrinsics ||
      format == ExportFormat::kOpenVins) {
    const NoiseFigures* block = p.noise ? &*p.noise : nullptr;
    auto bounded = [&](const SensorNoise& s, double user_value, const char* key) {
      if (block != nullptr && options.random_walk_bound_as_value && !std::isfinite(user_value) &&
          !std::isfinite(Largest(s.random_walk)) && Largest(s.random_walk_bound) > 0)
        notes.push_back(Cat(key, " is an UPPER BOUND (", Num(Largest(s.random_walk_bound)),
                            "), not a measurement: the capture's rest was too short"));
    };
    if (block != nullptr) {
      bounded(block->accel, options.accel_random_walk, "accelerometer_random_walk");
      bounded(block->gyro, options.gyro_random_walk, "gyroscope_random_walk");
    }
  }
  return notes;
}

absl::Status ValidateRosTopic(std::string_view topic) {
  // Printable for the message: control characters and quotes as \xNN.
  std::string shown;
  for (const char c : topic) {
    const auto u = static_cast<unsigned char>(c);
    if (u < 0x20 || u >= 0x7f || c == '"' || c == '\\') {
      static constexpr char kHex[] = "0123456789abcdef";
      shown += Cat("\\x", std::string(1, kHex[u >> 4]), std::string(1, kHex[u & 15]));
    } else {
      shown += c;
    }
  }
  auto bad = [&](std::string_view why) {
    return absl::InvalidArgumentError(
        Cat("rostopic: \"", shown, "\" is not a ROS 2 topic name: ", why));
  };
  auto is_alnum = [](char c) {
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9');
  };
  if (topic.empty()) return bad("it is empty");
  for (size_t i = 0; i < topic.size(); ++i) {
    const char c = topic[i];
    if (!(is_alnum(c) || c == '_' || c == '/' || c == '{' || c == '}' || (c == '~' && i == 0))) {
      return bad(Cat("character ", i + 1,
                     " is not a letter, digit, underscore, slash, brace or leading tilde"));
    }
    const bool token_start = i == 0 || topic[i - 1] == '/' || (i == 1 && topic[0] == '~');
    if (token_start && c >= '0' && c <= '9')
      return bad(Cat("a name starts with a digit at character ", i + 1));
  }
  if (topic.find("//") != std::string_view::npos) return bad("it repeats a slash");
  if (topic.find("__") != std::string_view::npos) return bad("it repeats an underscore");
  if (topic == "/") return bad("it names no topic");
  if (topic.back() == '/') return bad("it ends with a slash");
  return absl::OkStatus();
}

// An accelerometer-only parameter set (ParamSet::has_gyro false) has no gyroscope to write.
// Kalibr's intrinsics and OpenVINS's chain hold a gyroscope model that their estimators apply to
// every rate: an identity written there would claim a calibrated gyroscope, so they are refused.
// Kalibr's noise file needs only the gyroscope's two noise figures: with both supplied (say, the
// datasheet's) it is written, and its notes say where they came from; without, it is refused.
absl::Status CheckGyroExportable(const ParamSet& params, ExportFormat format,
                                 const ExportOptions& options) {
  if (params.has_gyro) return absl::OkStatus();
  const std::string what =
      Cat("the parameter set has no gyroscope (fitted on an "
          "accelerometer-only capture), and ",
          ExportFormatName(format));
  if (format != ExportFormat::kKalibrImu) {
    return absl::FailedPreconditionError(
        Cat(what,
            " holds a gyroscope model that the estimator applies to every rate; it cannot "
            "be exported without a gyroscope (the accelerometer parameters are in the "
            "imucal JSON: --format json)"));
  }
  if (!std::isfinite(options.gyro_noise_density) || !std::isfinite(options.gyro_random_walk)) {
    return absl::FailedPreconditionError(
        Cat(what,
            " needs gyroscope_noise_density and gyroscope_random_walk: give the "
            "gyroscope's figures with --gyro-noise-density and --gyro-random-walk"));
  }
  return absl::OkStatus();
}

absl::StatusOr<std::string> ExportParams(const ParamSet& params, ExportFormat format,
                                         const ExportOptions& options) {
  if (absl::Status s = ValidateRosTopic(options.rostopic); !s.ok()) return s;
  if (absl::Status s = CheckGyroExportable(params, format, options); !s.ok()) return s;
  absl::StatusOr<SiModel> model = ToSi(params);
  if (!model.ok()) return model.status();
  absl::StatusOr<Noise> noise = ResolveNoise(params, options);
  if (!noise.ok()) return noise.status();
  const std::vector<std::string> notes = ExportNotes(params, format, options);
  switch (format) {
    case ExportFormat::kKalibrImu:
      return KalibrImu(params, options, *model, *noise, notes);
    case ExportFormat::kKalibrIntrinsics:
      return KalibrIntrinsics(params, options, *model, *noise, notes);
    case ExportFormat::kOpenVins:
      return OpenVins(params, options, *model, *noise, notes);
  }
  return absl::InvalidArgumentError("unknown export format");
}

}  // namespace imucal::core
