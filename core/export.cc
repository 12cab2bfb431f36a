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

namespace imucal::core {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

constexpr double kPi = 3.14159265358979323846;

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
// YAML text.

// Shortest round-trip digits, always with a decimal point and a signed exponent, so that YAML
// 1.1 readers (PyYAML: Kalibr) and OpenCV's FileStorage (OpenVINS) all read a float.
std::string Num(double v) {
  if (v == 0.0) return "0.0";  // also -0.0
  std::string s = Cat(v);
  const size_t e = s.find_first_of("eE");
  std::string mantissa = s.substr(0, e);
  std::string exponent = e == std::string::npos ? "" : s.substr(e + 1);
  if (mantissa.find('.') == std::string::npos) mantissa += ".0";
  if (!exponent.empty() && exponent[0] != '-' && exponent[0] != '+') exponent = "+" + exponent;
  return exponent.empty() ? mantissa : mantissa + "e" + exponent;
}

std::string VecText(const Vector3d& v) {
  return Cat("[", Num(v(0)), ", ", Num(v(1)), ", ", Num(v(2)), "]");
}

// A block-style matrix under `key:` at `indent` spaces, one flow row per line.
void AppendMatrix(std::string* out, int indent, const char* key, const Eigen::MatrixXd& m) {
  const std::string pad(static_cast<size_t>(indent), ' ');
  AppendTo(out, pad, key, ":\n");
  for (Eigen::Index r = 0; r < m.rows(); ++r) {
    AppendTo(out, pad, "  - [");
    for (Eigen::Index c = 0; c < m.cols(); ++c) AppendTo(out, c ? ", " : "", Num(m(r, c)));
    AppendTo(out, "]\n");
  }
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
// The common header comment.

void AppendHeader(std::string* out, const ParamSet& p, ExportFormat format, const SiModel& m,
                  const std::vector<std::string>& notes) {
  AppendTo(out, "# ", ExportFormatName(format), " export by imucal");
  if (!p.software.empty()) AppendTo(out, " (", p.software, ")");
  AppendTo(out, "\n# device: ", p.device.empty() ? "(none)" : p.device,
           "  parameter version: ", p.version);
  if (!p.created_at.empty()) AppendTo(out, "  created: ", p.created_at);
  AppendTo(out, "\n");
  for (const std::string& n : notes) AppendTo(out, "# ", n, "\n");
  AppendTo(out, "# measurements in SI (m/s^2, rad/s) as a ROS sensor_msgs/Imu carries them");
  if (m.k_accel != 1.0 || m.k_gyro != 1.0) {
    AppendTo(out, "; imucal's input units converted with the nominal factors (accel ", m.k_accel,
             ", gyro ", m.k_gyro, " SI per unit)");
  }
  AppendTo(out, "\n");
}

void AppendNoiseKeys(std::string* out, int indent, const Noise& n) {
  const std::string pad(static_cast<size_t>(indent), ' ');
  AppendTo(out, pad, "accelerometer_noise_density: ", Num(n.accel_density),
           "  # [m/s^2/sqrt(Hz)] continuous-time white noise\n");
  AppendTo(out, pad, "accelerometer_random_walk: ", Num(n.accel_walk),
           "  # [m/s^3/sqrt(Hz)] bias random walk\n");
  AppendTo(out, pad, "gyroscope_noise_density: ", Num(n.gyro_density),
           "  # [rad/s/sqrt(Hz)] continuous-time white noise\n");
  AppendTo(out, pad, "gyroscope_random_walk: ", Num(n.gyro_walk),
           "  # [rad/s^2/sqrt(Hz)] bias random walk\n");
}

void AppendNoiseComment(std::string* out, const Noise& n) {
  for (const std::string& l : n.lines) AppendTo(out, "# noise: ", l, "\n");
}

std::string KalibrImu(const ParamSet& p, const ExportOptions& o, const SiModel& m, const Noise& n,
                      const std::vector<std::string>& notes) {
  std::string out;
  AppendHeader(&out, p, ExportFormat::kKalibrImu, m, notes);
  AppendNoiseComment(&out, n);
  AppendTo(&out, "\n");
  AppendNoiseKeys(&out, 0, n);
  AppendTo(&out, "rostopic: ", o.rostopic, "\n");
  AppendTo(&out, "update_rate: ", Num(n.rate_hz), "  # [Hz]\n");
  return out;
}

std::string KalibrIntrinsics(const ParamSet& p, const ExportOptions& o, const SiModel& m,
                             const Noise& n, const std::vector<std::string>& notes) {
  // Kalibr's frame i: the accelerometer's sensing-aligned frame, a_i = R_f^T a_b.
  const Matrix3d c_i_b = m.frame.transpose();
  const Matrix3d m_accel = m.accel_lower.inverse();
  const Matrix3d g_inv = m.gyro.inverse();
  const Factors lq = LqFactors(g_inv * m.frame);  // M_g C_gyro_i
  const Matrix3d a_gyro = g_inv * m.coupling * m.frame * lq.rotation.transpose();
  std::string out;
  AppendHeader(&out, p, ExportFormat::kKalibrIntrinsics, m, notes);
  AppendTo(&out,
           "# model (Kalibr scale-misalignment, FORWARD true -> measured, frame i):\n"
           "#   a_meas = M_a a_i + b_a ;  w_meas = M_g C_gyro_i w_i + A C_gyro_i a_i + b_g\n"
           "#   M lower-triangular, C_gyro_i a rotation, A [(rad/s)/(m/s^2)];\n"
           "#   a_i = C_i_b a_b (C_i_b = T_i_b's rotation; b = imucal's body frame)\n");
  AppendNoiseComment(&out, n);
  AppendTo(&out, "imu0:\n");
  AppendMatrix(&out, 2, "T_i_b", Homogeneous(c_i_b));
  AppendNoiseKeys(&out, 2, n);
  AppendTo(&out, "  model: scale-misalignment\n  accelerometers:\n");
  AppendMatrix(&out, 4, "M", m_accel);
  AppendTo(&out, "  gyroscopes:\n");
  AppendMatrix(&out, 4, "M", lq.triangular);
  AppendMatrix(&out, 4, "A", a_gyro);
  AppendMatrix(&out, 4, "C_gyro_i", lq.rotation);
  AppendTo(&out, "  rostopic: ", o.rostopic, "\n  time_offset: 0.0\n");
  AppendTo(&out, "  update_rate: ", Num(n.rate_hz), "\n");
  return out;
}

std::string OpenVins(const ParamSet& p, const ExportOptions& o, const SiModel& m, const Noise& n,
                     const std::vector<std::string>& notes) {
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
  std::string out = "%YAML:1.0\n";
  AppendHeader(&out, p, ExportFormat::kOpenVins, m, notes);
  AppendTo(&out,
           "# model (OpenVINS, applied after it inverts Tw and Ta on load; I = imucal's body "
           "frame):\n"
           "#   a_I = R_IMUtoACC^T Ta^-1 (a_m - b_a) ;  w_I = R_IMUtoGYRO^T Tw^-1 (w_m - b_g - Tg "
           "a_I)\n#   Tw, Ta ",
           kalibr ? "lower" : "upper", "-triangular (model ", kalibr ? "kalibr" : "rpng",
           "), Tg [(rad/s)/(m/s^2)]\n");
  AppendNoiseComment(&out, n);
  AppendTo(&out, "\nimu0:\n");
  AppendMatrix(&out, 2, "T_i_b", Eigen::Matrix4d::Identity());
  AppendNoiseKeys(&out, 2, n);
  AppendTo(&out, "  rostopic: ", o.rostopic, "\n  time_offset: 0.0\n");
  AppendTo(&out, "  update_rate: ", Num(n.rate_hz), "\n");
  AppendTo(&out, "  model: \"", kalibr ? "kalibr" : "rpng", "\"\n");
  AppendMatrix(&out, 2, "Tw", gyr.triangular.inverse());
  AppendMatrix(&out, 2, "R_IMUtoGYRO", gyr.rotation.transpose());
  AppendMatrix(&out, 2, "Ta", acc.triangular.inverse());
  AppendMatrix(&out, 2, "R_IMUtoACC", acc.rotation.transpose());
  AppendMatrix(&out, 2, "Tg", tg);
  return out;
}

}  // namespace

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
  auto user = [&](double v, const char* key) {
    if (std::isfinite(v))
      notes.push_back(Cat(key, " supplied to the export: ", Num(v),
                          " (used only if the noise block lacks it)"));
  };
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

absl::StatusOr<std::string> ExportParams(const ParamSet& params, ExportFormat format,
                                         const ExportOptions& options) {
  if (absl::Status s = ValidateRosTopic(options.rostopic); !s.ok()) return s;
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
