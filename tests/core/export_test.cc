// Exporters (core/export.h), round-tripped: each exported file is read back with a small YAML
// reader written here (the layout: one key per line, matrix rows in flow style) and with yaml-cpp
// (every number to 1e-15 relative, YamlCppReadsBackEveryNumber), its model applied to simulated raw
// data with the format's own equations (written here from OpenVINS's and Kalibr's source,
// independently of export.cc), and the result compared with imucal's SDK Corrector on the same raw
// data, the biases removed both ways.
#include "core/export.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "Eigen/LU"
#include "client/sdk/corrector.h"
#include "core/model.h"
#include "core/params.h"
#include "core/simulator.h"
#include "yaml-cpp/yaml.h"

namespace imucal::core {
namespace {

constexpr double kTolerance = 1e-9;  // relative

// ---------------------------------------------------------------------------------------------
// A reader for the YAML subset the exporters write: `key: value`, nested `key:` blocks by
// indentation, matrices as `- [a, b, c]` rows, `#` comments, a `%YAML` directive.

struct Yaml {
  std::map<std::string, std::string> scalars;       // "imu0.update_rate" -> "200.0"
  std::map<std::string, Eigen::MatrixXd> matrices;  // "imu0.Tw" -> 3x3
  std::vector<std::string> comments;
  std::vector<std::string> numbers;  // every numeric token, as written
};

std::string Trim(const std::string& s) {
  const size_t b = s.find_first_not_of(' ');
  if (b == std::string::npos) return "";
  return s.substr(b, s.find_last_not_of(' ') - b + 1);
}

Yaml ParseYaml(const std::string& text) {
  Yaml y;
  std::vector<std::pair<int, std::string>> stack;
  std::map<std::string, std::vector<std::vector<double>>> rows;
  auto path = [&]() {
    std::string p;
    for (const auto& [indent, key] : stack) p += (p.empty() ? "" : ".") + key;
    return p;
  };
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    if (!line.empty() && line[0] == '%') continue;
    const size_t hash = line.find('#');
    if (hash != std::string::npos) {
      y.comments.push_back(line.substr(hash + 1));
      line = line.substr(0, hash);
    }
    if (Trim(line).empty()) continue;
    const int indent = static_cast<int>(line.find_first_not_of(' '));
    const std::string content = Trim(line);
    if (content.rfind("- [", 0) == 0) {
      std::string inner = content.substr(3, content.find(']') - 3);
      std::vector<double> row;
      std::stringstream ss(inner);
      std::string tok;
      while (std::getline(ss, tok, ',')) {
        y.numbers.push_back(Trim(tok));
        row.push_back(std::strtod(Trim(tok).c_str(), nullptr));
      }
      rows[path()].push_back(row);
      continue;
    }
    while (!stack.empty() && stack.back().first >= indent) stack.pop_back();
    const size_t colon = content.find(':');
    const std::string key = content.substr(0, colon);
    std::string value = Trim(content.substr(colon + 1));
    if (value.empty()) {
      stack.emplace_back(indent, key);
      continue;
    }
    if (value.size() >= 2 && value.front() == '"') value = value.substr(1, value.size() - 2);
    const std::string p = path();
    y.scalars[(p.empty() ? "" : p + ".") + key] = value;
    char* end = nullptr;
    std::strtod(value.c_str(), &end);
    if (end != value.c_str() && *end == '\0') y.numbers.push_back(value);
  }
  for (const auto& [key, r] : rows) {
    Eigen::MatrixXd m(static_cast<Eigen::Index>(r.size()), static_cast<Eigen::Index>(r[0].size()));
    for (size_t i = 0; i < r.size(); ++i)
      for (size_t j = 0; j < r[i].size(); ++j)
        m(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = r[i][j];
    y.matrices[key] = m;
  }
  return y;
}

Eigen::Matrix3d Mat3(const Yaml& y, const std::string& key) {
  auto it = y.matrices.find(key);
  EXPECT_TRUE(it != y.matrices.end()) << key;
  if (it == y.matrices.end() || it->second.rows() < 3) return Eigen::Matrix3d::Constant(NAN);
  return it->second.topLeftCorner<3, 3>();
}

Eigen::Matrix3d Mat3FromNode(const YAML::Node& node) {
  Eigen::Matrix3d m = Eigen::Matrix3d::Constant(NAN);
  if (!node.IsSequence() || node.size() < 3) return m;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m(r, c) = node[r][c].as<double>();
  return m;
}

double Scalar(const Yaml& y, const std::string& key) {
  auto it = y.scalars.find(key);
  EXPECT_TRUE(it != y.scalars.end()) << key;
  return it == y.scalars.end() ? NAN : std::strtod(it->second.c_str(), nullptr);
}

// ---------------------------------------------------------------------------------------------
// The unit under test: nonzero accel misalignment and frame rotation, a gyro matrix with
// misalignment, g-sensitivity, biases; no second-order terms (no format holds them).

ParamSet TestParams(AccelUnit accel_unit, GyroUnit gyro_unit) {
  ParamSet p;
  p.device = "robot-0042";
  p.version = 7;
  p.accel_unit = accel_unit;
  p.gyro_unit = gyro_unit;
  const double ka = accel_unit == AccelUnit::kG ? kStandardGravity : 1.0;
  const double kg = gyro_unit == GyroUnit::kDegPerSecond ? std::numbers::pi / 180.0 : 1.0;
  p.accel.bias = Eigen::Vector3d(0.3, -0.2, 0.15) / ka;
  p.accel.scale = Eigen::Vector3d(1.01, 0.99, 1.005) * ka;
  p.accel.tri_angles = Eigen::Vector3d(0.004, -0.003, 0.002);
  p.accel.frame_angles = Eigen::Vector3d(0.02, -0.015, 0.03);
  Eigen::Matrix3d g;
  g << 1.02, 0.004, -0.003,  //
      -0.005, 0.98, 0.006,   //
      0.002, -0.007, 1.01;
  p.gyro.matrix = g * kg;
  p.gyro.bias = Eigen::Vector3d(0.01, -0.02, 0.005) / kg;
  p.gyro.accel_coupling << 1e-3, -2e-4, 3e-4,  //
      5e-4, -8e-4, 1e-4,                       //
      -3e-4, 2e-4, 6e-4;
  p.gyro_calibrated = true;
  NoiseFigures n;
  n.t_start_s = 0.1;
  n.t_end_s = 29.9;
  n.samples = 5961;
  n.rate_hz = 200;
  n.accel.noise_density = Eigen::Vector3d(1.4e-3, 1.5e-3, 1.45e-3);
  n.accel.random_walk = Eigen::Vector3d(3e-4, 3.2e-4, 3.1e-4);
  n.gyro.noise_density = Eigen::Vector3d(1.4e-4, 1.6e-4, 1.5e-4);
  n.gyro.random_walk = Eigen::Vector3d(2e-5, 2.1e-5, 2.2e-5);
  p.noise = n;
  return p;
}

struct RawData {
  std::vector<Eigen::Vector3d> accel, gyro;  // input units
};

// Simulated raw readings of the unit through a six-face session with moves.
RawData SimulatedRaw(const ParamSet& p) {
  SimOptions o;
  o.seed = 3;
  o.rate_hz = 50;
  o.initial_rest_s = 2;
  o.hold_s = 1;
  o.accel_unit = p.accel_unit;
  o.gyro_unit = p.gyro_unit;
  o.temperature = false;
  absl::StatusOr<SimResult> sim = Simulate(o, SimTruth{p.accel, p.gyro});
  EXPECT_TRUE(sim.ok()) << sim.status();
  RawData raw;
  if (sim.ok()) raw = RawData{sim->capture.accel, sim->capture.gyro};
  return raw;
}

double SiPerAccelUnit(const ParamSet& p) {
  return p.accel_unit == AccelUnit::kG ? kStandardGravity : 1.0;
}
double SiPerGyroUnit(const ParamSet& p) {
  return p.gyro_unit == GyroUnit::kDegPerSecond ? std::numbers::pi / 180.0 : 1.0;
}

// Compares a format's calibrated output with imucal's Corrector, sample by sample.
template <typename FormatApply>
void ExpectSameAsImucal(const ParamSet& p, const RawData& raw, FormatApply apply) {
  absl::StatusOr<sdk::Corrector> corrector = sdk::Corrector::Create(p);
  ASSERT_TRUE(corrector.ok()) << corrector.status();
  ASSERT_GT(raw.accel.size(), 100u);
  double worst = 0;
  for (size_t i = 0; i < raw.accel.size(); ++i) {
    sdk::RawSample in;
    for (int k = 0; k < 3; ++k) in.accel[k] = raw.accel[i](k), in.gyro[k] = raw.gyro[i](k);
    sdk::CalibratedSample out;
    corrector->Apply(in, &out);
    const Eigen::Vector3d a_ref(out.accel_m_s2), w_ref(out.gyro_rad_s);
    Eigen::Vector3d a, w;
    apply(raw.accel[i], raw.gyro[i], &a, &w);
    const double ea = (a - a_ref).norm() / std::max(a_ref.norm(), 1e-6);
    const double ew = (w - w_ref).norm() / std::max(w_ref.norm(), 1e-6);
    worst = std::max({worst, ea, ew});
    ASSERT_LT(ea, kTolerance) << "sample " << i << ": " << a.transpose() << " vs "
                              << a_ref.transpose();
    ASSERT_LT(ew, kTolerance) << "sample " << i << ": " << w.transpose() << " vs "
                              << w_ref.transpose();
  }
  std::printf("  %zu samples, worst relative difference %.3g\n", raw.accel.size(), worst);
}

Eigen::Matrix3d LowerPart(const Eigen::Matrix3d& m) { return m.triangularView<Eigen::Lower>(); }
Eigen::Matrix3d UpperPart(const Eigen::Matrix3d& m) { return m.triangularView<Eigen::Upper>(); }

void ExpectRotation(const Eigen::Matrix3d& r, const char* name) {
  EXPECT_LT((r * r.transpose() - Eigen::Matrix3d::Identity()).norm(), 1e-12) << name;
  EXPECT_NEAR(r.determinant(), 1.0, 1e-12) << name;
}

void ExpectNumbersHaveDecimalPoint(const Yaml& y) {
  for (const std::string& n : y.numbers) {
    EXPECT_NE(n.find('.'), std::string::npos) << n << " (PyYAML would read it as a string)";
  }
}

// ---------------------------------------------------------------------------------------------
// OpenVINS: VioManagerOptions.h inverts Tw and Ta on load (Dw = Tw^-1, Da = Ta^-1) and keeps
// the lower triangle (model kalibr) or the upper (rpng); Propagator.cpp applies
//   a_I = R_ACCtoIMU Da (a_m - b_a),  w_I = R_GYROtoIMU Dw (w_m - b_g - Tg a_I),
// R_ACCtoIMU = R_IMUtoACC^T, R_GYROtoIMU = R_IMUtoGYRO^T.

void OpenVinsRoundTrip(AccelUnit au, GyroUnit gu, OpenVinsModel model) {
  const ParamSet p = TestParams(au, gu);
  ExportOptions o;
  o.openvins_model = model;
  absl::StatusOr<std::string> text = ExportParams(p, ExportFormat::kOpenVins, o);
  ASSERT_TRUE(text.ok()) << text.status();
  ASSERT_EQ(text->rfind("%YAML:1.0\n", 0), 0u);
  const Yaml y = ParseYaml(*text);
  ExpectNumbersHaveDecimalPoint(y);
  const bool kalibr = model == OpenVinsModel::kKalibr;
  EXPECT_EQ(y.scalars.at("imu0.model"), kalibr ? "kalibr" : "rpng");
  const Eigen::Matrix3d tw = Mat3(y, "imu0.Tw"), ta = Mat3(y, "imu0.Ta");
  const Eigen::Matrix3d tg = Mat3(y, "imu0.Tg");
  const Eigen::Matrix3d r_imu_gyro = Mat3(y, "imu0.R_IMUtoGYRO");
  const Eigen::Matrix3d r_imu_acc = Mat3(y, "imu0.R_IMUtoACC");
  ExpectRotation(r_imu_gyro, "R_IMUtoGYRO");
  ExpectRotation(r_imu_acc, "R_IMUtoACC");
  // The written matrices are triangular as the model says (the loader drops the other half).
  const Eigen::Matrix3d diag_w = tw.diagonal().asDiagonal();
  const Eigen::Matrix3d dropped_w = (kalibr ? UpperPart(tw) : LowerPart(tw)) - diag_w;
  EXPECT_LT(dropped_w.norm(), 1e-15 * tw.norm()) << "Tw\n" << tw;
  const Eigen::Matrix3d dw_full = tw.inverse(), da_full = ta.inverse();
  const Eigen::Matrix3d dw = kalibr ? LowerPart(dw_full) : UpperPart(dw_full);
  const Eigen::Matrix3d da = kalibr ? LowerPart(da_full) : UpperPart(da_full);
  const double ka = SiPerAccelUnit(p), kg = SiPerGyroUnit(p);
  const Eigen::Vector3d b_a = ka * p.accel.bias, b_g = kg * p.gyro.bias;  // biases removed
  std::printf("OpenVINS model %s, units %s %s:\n", kalibr ? "kalibr" : "rpng",
              std::string(AccelUnitName(au)).c_str(), std::string(GyroUnitName(gu)).c_str());
  ExpectSameAsImucal(p, SimulatedRaw(p),
                     [&](const Eigen::Vector3d& ua, const Eigen::Vector3d& ug, Eigen::Vector3d* a,
                         Eigen::Vector3d* w) {
                       const Eigen::Vector3d a_m = ka * ua, w_m = kg * ug;
                       *a = r_imu_acc.transpose() * da * (a_m - b_a);
                       *w = r_imu_gyro.transpose() * dw * (w_m - b_g - tg * *a);
                     });
}

TEST(ExportTest, OpenVinsKalibrModelRoundTrip) {
  OpenVinsRoundTrip(AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond, OpenVinsModel::kKalibr);
}

TEST(ExportTest, OpenVinsKalibrModelRoundTripFromGAndDegPerSecond) {
  OpenVinsRoundTrip(AccelUnit::kG, GyroUnit::kDegPerSecond, OpenVinsModel::kKalibr);
}

TEST(ExportTest, OpenVinsRpngModelRoundTrip) {
  OpenVinsRoundTrip(AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond, OpenVinsModel::kRpng);
}

// In model kalibr the accelerometer's triangle carries no rotation of its own: R_IMUtoACC is
// imucal's frame rotation (transposed), and Ta the inverse of L diag(scale).
TEST(ExportTest, OpenVinsKalibrAccelFactorsAreImucals) {
  const ParamSet p = TestParams(AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond);
  absl::StatusOr<std::string> text = ExportParams(p, ExportFormat::kOpenVins, ExportOptions());
  ASSERT_TRUE(text.ok()) << text.status();
  const Yaml y = ParseYaml(*text);
  const Eigen::Matrix3d r = ExpSo3<double>(p.accel.frame_angles);
  EXPECT_LT((Mat3(y, "imu0.R_IMUtoACC") - r.transpose()).norm(), 1e-15);
  const Eigen::Matrix3d ls =
      LowerMisalignment<double>(p.accel.tri_angles) * p.accel.scale.asDiagonal();
  EXPECT_LT((Mat3(y, "imu0.Ta") * ls - Eigen::Matrix3d::Identity()).norm(), 1e-14);
  EXPECT_EQ(Mat3(y, "imu0.T_i_b"), Eigen::Matrix3d::Identity());
}

// ---------------------------------------------------------------------------------------------
// Kalibr scale-misalignment (IccSensors.py IccScaledMisalignedImu), forward, frame i:
//   a_meas = M_a a_i + b_a,  w_meas = M_g C_gyro_i w_i + A C_gyro_i a_i + b_g,
// a_i = C_i_b a_b. Solved here for a_b, w_b from the measurements.

void KalibrIntrinsicsRoundTrip(AccelUnit au, GyroUnit gu) {
  const ParamSet p = TestParams(au, gu);
  absl::StatusOr<std::string> text =
      ExportParams(p, ExportFormat::kKalibrIntrinsics, ExportOptions());
  ASSERT_TRUE(text.ok()) << text.status();
  const Yaml y = ParseYaml(*text);
  ExpectNumbersHaveDecimalPoint(y);
  EXPECT_EQ(y.scalars.at("imu0.model"), "scale-misalignment");
  const Eigen::Matrix3d m_a = Mat3(y, "imu0.accelerometers.M");
  const Eigen::Matrix3d m_g = Mat3(y, "imu0.gyroscopes.M");
  const Eigen::Matrix3d a_g = Mat3(y, "imu0.gyroscopes.A");
  const Eigen::Matrix3d c_gyro_i = Mat3(y, "imu0.gyroscopes.C_gyro_i");
  const Eigen::Matrix3d c_i_b = Mat3(y, "imu0.T_i_b");
  ExpectRotation(c_gyro_i, "C_gyro_i");
  ExpectRotation(c_i_b, "T_i_b");
  EXPECT_EQ(UpperPart(m_a) - Eigen::Matrix3d(m_a.diagonal().asDiagonal()), Eigen::Matrix3d::Zero());
  EXPECT_LT((UpperPart(m_g) - Eigen::Matrix3d(m_g.diagonal().asDiagonal())).norm(), 1e-15);
  const double ka = SiPerAccelUnit(p), kg = SiPerGyroUnit(p);
  const Eigen::Vector3d b_a = ka * p.accel.bias, b_g = kg * p.gyro.bias;
  const Eigen::Matrix3d m_a_inv = LowerPart(m_a).inverse(), m_g_inv = LowerPart(m_g).inverse();
  std::printf("Kalibr scale-misalignment, units %s %s:\n", std::string(AccelUnitName(au)).c_str(),
              std::string(GyroUnitName(gu)).c_str());
  ExpectSameAsImucal(p, SimulatedRaw(p),
                     [&](const Eigen::Vector3d& ua, const Eigen::Vector3d& ug, Eigen::Vector3d* a,
                         Eigen::Vector3d* w) {
                       const Eigen::Vector3d a_i = m_a_inv * (ka * ua - b_a);
                       const Eigen::Vector3d w_i =
                           c_gyro_i.transpose() * m_g_inv * (kg * ug - b_g - a_g * c_gyro_i * a_i);
                       *a = c_i_b.transpose() * a_i;
                       *w = c_i_b.transpose() * w_i;
                     });
}

TEST(ExportTest, KalibrIntrinsicsRoundTrip) {
  KalibrIntrinsicsRoundTrip(AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond);
}

TEST(ExportTest, KalibrIntrinsicsRoundTripFromGAndDegPerSecond) {
  KalibrIntrinsicsRoundTrip(AccelUnit::kG, GyroUnit::kDegPerSecond);
}

// ---------------------------------------------------------------------------------------------
// Kalibr imu.yaml: the noise keys.

TEST(ExportTest, KalibrImuWritesNoiseKeys) {
  const ParamSet p = TestParams(AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond);
  ExportOptions o;
  o.rostopic = "/robot/imu";
  absl::StatusOr<std::string> text = ExportParams(p, ExportFormat::kKalibrImu, o);
  ASSERT_TRUE(text.ok()) << text.status();
  const Yaml y = ParseYaml(*text);
  ExpectNumbersHaveDecimalPoint(y);
  // One number per sensor: the largest axis.
  EXPECT_EQ(Scalar(y, "accelerometer_noise_density"), 1.5e-3);
  EXPECT_EQ(Scalar(y, "accelerometer_random_walk"), 3.2e-4);
  EXPECT_EQ(Scalar(y, "gyroscope_noise_density"), 1.6e-4);
  EXPECT_EQ(Scalar(y, "gyroscope_random_walk"), 2.2e-5);
  EXPECT_EQ(Scalar(y, "update_rate"), 200.0);
  EXPECT_EQ(y.scalars.at("rostopic"), "/robot/imu");
  // The OpenVINS file carries the same keys under imu0.
  absl::StatusOr<std::string> ov = ExportParams(p, ExportFormat::kOpenVins, o);
  ASSERT_TRUE(ov.ok());
  const Yaml yo = ParseYaml(*ov);
  EXPECT_EQ(Scalar(yo, "imu0.accelerometer_random_walk"), 3.2e-4);
  EXPECT_EQ(Scalar(yo, "imu0.update_rate"), 200.0);
  EXPECT_EQ(yo.scalars.at("imu0.rostopic"), "/robot/imu");
}

// By default a random walk the rest did not reach is written as the data's upper bound, and
// the file and the notes say it is a bound.
TEST(ExportTest, UnreachedRandomWalkIsWrittenAsItsBound) {
  ParamSet p = TestParams(AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond);
  p.noise->accel.random_walk.setConstant(NAN);
  p.noise->accel.random_walk_bound = Eigen::Vector3d(3e-3, 4e-3, 3.5e-3);
  for (ExportFormat f :
       {ExportFormat::kKalibrImu, ExportFormat::kKalibrIntrinsics, ExportFormat::kOpenVins}) {
    absl::StatusOr<std::string> text = ExportParams(p, f, ExportOptions());
    ASSERT_TRUE(text.ok()) << text.status();
    EXPECT_NE(text->find("UPPER BOUND"), std::string::npos) << *text;
    bool noted = false;
    for (const std::string& n : ExportNotes(p, f, ExportOptions()))
      noted |= n.find("accelerometer_random_walk is an UPPER BOUND") != std::string::npos;
    EXPECT_TRUE(noted);
  }
  const Yaml y = ParseYaml(*ExportParams(p, ExportFormat::kKalibrImu, ExportOptions()));
  EXPECT_EQ(Scalar(y, "accelerometer_random_walk"), 4e-3);  // the largest axis's bound
  EXPECT_EQ(Scalar(y, "gyroscope_random_walk"), 2.2e-5);    // measured: unchanged
}

TEST(ExportTest, MissingNoiseIsRefusedUnlessSupplied) {
  ParamSet p = TestParams(AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond);
  p.noise->accel.random_walk.setConstant(NAN);  // a short rest does not reach it
  p.noise->accel.random_walk_bound.setConstant(4e-3);
  ExportOptions strict;
  strict.random_walk_bound_as_value = false;
  for (ExportFormat f :
       {ExportFormat::kKalibrImu, ExportFormat::kKalibrIntrinsics, ExportFormat::kOpenVins}) {
    absl::StatusOr<std::string> refused = ExportParams(p, f, strict);
    ASSERT_EQ(refused.status().code(), absl::StatusCode::kFailedPrecondition);
    const std::string msg(refused.status().message());
    EXPECT_NE(msg.find("accelerometer_random_walk"), std::string::npos) << msg;
    EXPECT_NE(msg.find("--accel-random-walk"), std::string::npos) << msg;
    EXPECT_NE(msg.find("0.004"), std::string::npos) << msg;  // the bound, as a hint
    EXPECT_EQ(msg.find("gyroscope_random_walk"), std::string::npos) << msg;
  }
  ExportOptions o = strict;
  o.accel_random_walk = 5e-4;  // e.g. from the datasheet
  absl::StatusOr<std::string> text = ExportParams(p, ExportFormat::kKalibrImu, o);
  ASSERT_TRUE(text.ok()) << text.status();
  const Yaml y = ParseYaml(*text);
  EXPECT_EQ(Scalar(y, "accelerometer_random_walk"), 5e-4);
  EXPECT_NE(text->find("NOT measured"), std::string::npos);

  // No noise block at all (an older parameter set): every key and the rate are named.
  p.noise.reset();
  absl::StatusOr<std::string> none = ExportParams(p, ExportFormat::kKalibrImu, ExportOptions());
  ASSERT_FALSE(none.ok());
  for (const char* key : {"accelerometer_noise_density", "gyroscope_noise_density",
                          "gyroscope_random_walk", "--rate"}) {
    EXPECT_NE(none.status().message().find(key), std::string::npos) << none.status();
  }
}

// A parameter set without a gyroscope (an accelerometer-only capture): the formats whose
// estimators apply a gyroscope model refuse it (an identity there would claim a calibrated
// gyroscope); Kalibr's noise file takes the gyroscope's two figures from the user, and says so.
TEST(ExportTest, WithoutGyroscope) {
  ParamSet p = TestParams(AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond);
  p.has_gyro = false;
  p.noise->gyro = SensorNoise{};
  ExportOptions o;
  for (ExportFormat f : {ExportFormat::kKalibrIntrinsics, ExportFormat::kOpenVins}) {
    absl::StatusOr<std::string> text = ExportParams(p, f, o);
    ASSERT_FALSE(text.ok()) << ExportFormatName(f);
    EXPECT_EQ(text.status().code(), absl::StatusCode::kFailedPrecondition);
    EXPECT_NE(text.status().message().find("cannot be exported without a gyroscope"),
              std::string::npos)
        << text.status();
  }
  absl::StatusOr<std::string> kalibr = ExportParams(p, ExportFormat::kKalibrImu, o);
  ASSERT_FALSE(kalibr.ok());
  EXPECT_NE(kalibr.status().message().find("--gyro-noise-density and --gyro-random-walk"),
            std::string::npos)
      << kalibr.status();
  o.gyro_noise_density = 1e-4;
  o.gyro_random_walk = 1e-5;
  kalibr = ExportParams(p, ExportFormat::kKalibrImu, o);
  ASSERT_TRUE(kalibr.ok()) << kalibr.status();
  const Yaml y = ParseYaml(*kalibr);
  EXPECT_EQ(Scalar(y, "gyroscope_noise_density"), 1e-4);
  EXPECT_EQ(Scalar(y, "accelerometer_random_walk"), 3.2e-4);
  EXPECT_NE(kalibr->find("not measured"), std::string::npos);
}

TEST(ExportTest, RefusesRawCounts) {
  ParamSet p = TestParams(AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond);
  p.gyro_unit = GyroUnit::kCounts;
  absl::StatusOr<std::string> r = ExportParams(p, ExportFormat::kOpenVins, ExportOptions());
  EXPECT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("counts"), std::string::npos);
}

// The topic is written into the YAML as is: anything but a ROS 2 topic name is refused, so a
// newline cannot add keys to the file (found by review of the server's ExportRequest).
TEST(ExportTest, RostopicMustBeATopicName) {
  for (const char* ok : {"/imu0", "imu/data", "~/imu_raw", "/robot_{ns}/imu"})
    EXPECT_TRUE(ValidateRosTopic(ok).ok()) << ok << ": " << ValidateRosTopic(ok);
  for (const char* bad : {"", "/", "/imu0\nTw: [1]", "/imu 0", "/imu0/", "//imu", "/0imu", "/a__b",
                          "/imu: x", "'/imu'", "/im~u"})
    EXPECT_EQ(ValidateRosTopic(bad).code(), absl::StatusCode::kInvalidArgument) << bad;
  const absl::Status nl = ValidateRosTopic("/imu0\nTw: [1]");
  EXPECT_NE(nl.message().find("rostopic: \"/imu0\\x0aTw: [1]\""), std::string::npos)
      << nl.message();
  EXPECT_NE(nl.message().find("character 6"), std::string::npos) << nl.message();

  ParamSet p = TestParams(AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond);
  ExportOptions o;
  o.rostopic = "/imu0\nextra_key: 1";
  for (ExportFormat f :
       {ExportFormat::kKalibrImu, ExportFormat::kKalibrIntrinsics, ExportFormat::kOpenVins}) {
    const absl::StatusOr<std::string> r = ExportParams(p, f, o);
    EXPECT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument) << ExportFormatName(f);
  }
}

// What the formats cannot hold is said at the top of the file and in ExportNotes.
TEST(ExportTest, SaysWhatIsLeftOut) {
  ParamSet p = TestParams(AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond);
  p.accel.quadratic = Eigen::Vector3d(2e-5, 0, 0);
  Effect e;
  e.sensor = Sensor::kGyro;
  e.axis = 1;
  e.regressor = "temperature";
  e.coefficient = 1e-4;
  p.effects.push_back(e);
  for (ExportFormat f : {ExportFormat::kKalibrIntrinsics, ExportFormat::kOpenVins}) {
    absl::StatusOr<std::string> text = ExportParams(p, f, ExportOptions());
    ASSERT_TRUE(text.ok()) << text.status();
    const size_t first_key = text->find("\nimu0:");
    ASSERT_NE(first_key, std::string::npos);
    const std::string header = text->substr(0, first_key);
    EXPECT_NE(header.find("NOT IN THIS FILE: biases"), std::string::npos) << header;
    EXPECT_NE(header.find("second-order terms (quadratic"), std::string::npos) << header;
    EXPECT_NE(header.find("gyro y ~ temperature"), std::string::npos) << header;
  }
  const std::vector<std::string> notes = ExportNotes(p, ExportFormat::kOpenVins, ExportOptions());
  std::string all;
  for (const auto& n : notes) all += n + "\n";
  EXPECT_NE(all.find("biases"), std::string::npos);
  EXPECT_NE(all.find("quadratic"), std::string::npos);
  EXPECT_NE(all.find("effect"), std::string::npos);
}

std::string WithoutComments(const std::string& text) {
  std::string out, line;
  for (std::istringstream in(text); std::getline(in, line);) {
    if (line.rfind("#", 0) != 0) out += line + "\n";
  }
  return out;
}

// A learnt dynamic gyro block cannot be carried: every format says so and writes the static
// model, the same numbers as without the block.
TEST(ExportTest, SaysTheDynamicGyroBlockIsLeftOut) {
  const ParamSet without = TestParams(AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond);
  ParamSet with = without;
  with.dynamic_gyro = DynamicGyro{.rate_hz = 200, .delay_s = 0.0026, .taps = 1, .dilation = 1};
  with.dynamic_gyro->weights.assign(18, 1e-3);
  for (ExportFormat f :
       {ExportFormat::kKalibrImu, ExportFormat::kKalibrIntrinsics, ExportFormat::kOpenVins}) {
    absl::StatusOr<std::string> a = ExportParams(with, f, ExportOptions());
    absl::StatusOr<std::string> b = ExportParams(without, f, ExportOptions());
    ASSERT_TRUE(a.ok() && b.ok()) << a.status() << b.status();
    EXPECT_NE(a->find("NOT IN THIS FILE: the learnt dynamic gyro block (1 taps"), std::string::npos)
        << *a;
    EXPECT_EQ(WithoutComments(*a), WithoutComments(*b));
    EXPECT_EQ(b->find("dynamic gyro"), std::string::npos);
  }
}

// ---------------------------------------------------------------------------------------------
// Every exported file read back with yaml-cpp (a full YAML parser, not the subset reader above):
// each number is the double the parameter set gives, to 1e-15 relative (the text is the shortest
// that reads back to the same double, so it is exact), the strings as written, and the header's
// units and frames still there as comments.

double Rel(double got, double want) {
  return want == 0 ? std::abs(got) : std::abs(got - want) / std::abs(want);
}

// `node` (a matrix as a sequence of rows) against `want`, entry by entry; a zero entry must be
// exactly zero.
void ExpectMatrix(const YAML::Node& node, const Eigen::MatrixXd& want, const std::string& what) {
  ASSERT_TRUE(node.IsSequence()) << what;
  ASSERT_EQ(node.size(), static_cast<size_t>(want.rows())) << what;
  for (Eigen::Index r = 0; r < want.rows(); ++r) {
    ASSERT_EQ(node[r].size(), static_cast<size_t>(want.cols())) << what;
    for (Eigen::Index c = 0; c < want.cols(); ++c) {
      const double got = node[r][c].as<double>();
      EXPECT_LE(Rel(got, want(r, c)), 1e-15)
          << what << "(" << r << ", " << c << "): " << got << " vs " << want(r, c);
    }
  }
}

Eigen::Matrix4d Homogeneous4(const Eigen::Matrix3d& r) {
  Eigen::Matrix4d t = Eigen::Matrix4d::Identity();
  t.topLeftCorner<3, 3>() = r;
  return t;
}

void ExpectNoiseKeys(const YAML::Node& n, const ParamSet& p) {
  const NoiseFigures& f = *p.noise;
  for (const auto& [key, want] :
       {std::pair{"accelerometer_noise_density", f.accel.noise_density.maxCoeff()},
        std::pair{"accelerometer_random_walk", f.accel.random_walk.maxCoeff()},
        std::pair{"gyroscope_noise_density", f.gyro.noise_density.maxCoeff()},
        std::pair{"gyroscope_random_walk", f.gyro.random_walk.maxCoeff()},
        std::pair{"update_rate", f.rate_hz}}) {
    ASSERT_TRUE(n[key]) << key;
    EXPECT_LE(Rel(n[key].as<double>(), want), 1e-15) << key;
  }
}

TEST(ExportTest, YamlCppReadsBackEveryNumber) {
  for (const auto& [au, gu] : {std::pair{AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond},
                               std::pair{AccelUnit::kG, GyroUnit::kDegPerSecond}}) {
    const ParamSet p = TestParams(au, gu);
    // What each format derives from the parameter set (core/export.h), computed here.
    const double ka = SiPerAccelUnit(p), kg = SiPerGyroUnit(p);
    const Eigen::Matrix3d frame = ExpSo3<double>(p.accel.frame_angles);
    const Eigen::Matrix3d lower =
        LowerMisalignment<double>(p.accel.tri_angles) * p.accel.scale.asDiagonal() / ka;
    const Eigen::Matrix3d gyro = p.gyro.matrix / kg;
    ExportOptions o;
    o.rostopic = "/robot/imu_raw";

    absl::StatusOr<std::string> kalibr = ExportParams(p, ExportFormat::kKalibrImu, o);
    ASSERT_TRUE(kalibr.ok()) << kalibr.status();
    const YAML::Node k = YAML::Load(*kalibr);
    ExpectNoiseKeys(k, p);
    EXPECT_EQ(k["rostopic"].as<std::string>(), "/robot/imu_raw");
    EXPECT_EQ(k.size(), 6u);

    absl::StatusOr<std::string> intrinsics = ExportParams(p, ExportFormat::kKalibrIntrinsics, o);
    ASSERT_TRUE(intrinsics.ok()) << intrinsics.status();
    const YAML::Node ki = YAML::Load(*intrinsics)["imu0"];
    ExpectNoiseKeys(ki, p);
    ExpectMatrix(ki["T_i_b"], Homogeneous4(frame.transpose()), "T_i_b");
    ExpectMatrix(ki["accelerometers"]["M"], lower.inverse(), "accelerometers.M");
    EXPECT_EQ(ki["model"].as<std::string>(), "scale-misalignment");
    EXPECT_EQ(ki["rostopic"].as<std::string>(), "/robot/imu_raw");
    EXPECT_EQ(ki["time_offset"].as<double>(), 0.0);
    // The gyroscope's factors multiply back to G'^-1 R_f and G'^-1 C R_f.
    const Eigen::Matrix3d m_g = Mat3FromNode(ki["gyroscopes"]["M"]);
    const Eigen::Matrix3d c_gyro_i = Mat3FromNode(ki["gyroscopes"]["C_gyro_i"]);
    const Eigen::Matrix3d a_g = Mat3FromNode(ki["gyroscopes"]["A"]);
    EXPECT_LT((m_g * c_gyro_i - gyro.inverse() * frame).norm(), 1e-14);
    EXPECT_LT((a_g * c_gyro_i - gyro.inverse() * p.gyro.accel_coupling * frame).norm(), 1e-14);

    for (OpenVinsModel model : {OpenVinsModel::kKalibr, OpenVinsModel::kRpng}) {
      o.openvins_model = model;
      absl::StatusOr<std::string> ov = ExportParams(p, ExportFormat::kOpenVins, o);
      ASSERT_TRUE(ov.ok()) << ov.status();
      ASSERT_EQ(ov->rfind("%YAML:1.0\n", 0), 0u);  // OpenCV's first line; yaml-cpp skips it
      const YAML::Node v = YAML::Load(*ov)["imu0"];
      ExpectNoiseKeys(v, p);
      ExpectMatrix(v["T_i_b"], Eigen::Matrix4d::Identity(), "T_i_b");
      ExpectMatrix(v["Tg"], gyro.inverse() * p.gyro.accel_coupling, "Tg");
      EXPECT_EQ(v["model"].as<std::string>(), model == OpenVinsModel::kKalibr ? "kalibr" : "rpng");
      EXPECT_EQ(v["rostopic"].as<std::string>(), "/robot/imu_raw");
      const Eigen::Matrix3d tw = Mat3FromNode(v["Tw"]), ta = Mat3FromNode(v["Ta"]);
      const Eigen::Matrix3d r_gyro = Mat3FromNode(v["R_IMUtoGYRO"]);
      const Eigen::Matrix3d r_acc = Mat3FromNode(v["R_IMUtoACC"]);
      if (model == OpenVinsModel::kKalibr) {
        // The accelerometer's factors are imucal's own: no decomposition in between.
        ExpectMatrix(v["R_IMUtoACC"], frame.transpose(), "R_IMUtoACC");
        ExpectMatrix(v["Ta"], lower.inverse(), "Ta");
      }
      EXPECT_LT((r_gyro.transpose() * tw.inverse() - gyro).norm(), 1e-14);
      EXPECT_LT((r_acc.transpose() * ta.inverse() - frame * lower).norm(), 1e-14);
    }
    // The header's conventions survive as comments, in every format.
    for (const std::string* text : {&*kalibr, &*intrinsics}) {
      EXPECT_NE(text->find("# measurements in SI (m/s^2, rad/s) as a ROS sensor_msgs/Imu"),
                std::string::npos);
      EXPECT_NE(text->find("# device: robot-0042  parameter version: 7"), std::string::npos);
      EXPECT_NE(text->find("  # [m/s^2/sqrt(Hz)] continuous-time white noise"), std::string::npos);
    }
    EXPECT_NE(intrinsics->find("#   a_meas = M_a a_i + b_a ;"), std::string::npos) << *intrinsics;
  }
}

// A device id or software name with a line break cannot add YAML to the file: the emitter keeps
// each line of a comment a comment (a hand-written "# " + text did not).
TEST(ExportTest, ALineBreakInTheHeaderStaysAComment) {
  ParamSet p = TestParams(AccelUnit::kMetersPerSecond2, GyroUnit::kRadPerSecond);
  p.device = "robot-1\nTw: [[9]]";
  p.software = "imucal\nextra_key: 1";
  for (ExportFormat f :
       {ExportFormat::kKalibrImu, ExportFormat::kKalibrIntrinsics, ExportFormat::kOpenVins}) {
    absl::StatusOr<std::string> text = ExportParams(p, f, ExportOptions());
    ASSERT_TRUE(text.ok()) << text.status();
    const YAML::Node n = YAML::Load(*text);
    EXPECT_FALSE(n["extra_key"]) << *text;
    EXPECT_FALSE(n["Tw"]) << *text;
    EXPECT_NE(text->find("# Tw: [[9]]"), std::string::npos) << *text;
  }
}

TEST(ExportTest, FormatNames) {
  for (const char* name : {"kalibr", "kalibr-intrinsics", "openvins"}) {
    absl::StatusOr<ExportFormat> f = ParseExportFormat(name);
    ASSERT_TRUE(f.ok());
    EXPECT_EQ(ExportFormatName(*f), name);
  }
  EXPECT_FALSE(ParseExportFormat("json").ok());
}

}  // namespace
}  // namespace imucal::core
