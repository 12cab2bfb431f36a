// The real captures under ../shared/data/real: the acceptance figures on the Xsens pair that
// ships with IMU-TK (Tedaldi, Pretto, Menegatti, ICRA 2014). The bounds are IMU-TK's own figures
// on this data; imucal must beat each.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "core/calibrate/calibrate.h"
#include "core/capture.h"
#include "core/protocol.h"
#include "importers/registry.h"
#include "tests/core/real_captures.h"

namespace imucal::core {
namespace {

constexpr double kXsensGravity = 9.81744;  // local gravity used by the data's authors
constexpr double kMicroG = 1e-6 * kXsensGravity;

// IMU-TK on this capture (the peer to beat).
constexpr double kImuTkAccelRms = 113.8 * kMicroG;
constexpr double kImuTkAccelMax = 257.5 * kMicroG;
constexpr double kImuTkAccelHeldOutRms = 146.0 * kMicroG;
constexpr double kImuTkMoveRmsDeg = 0.517;
constexpr double kImuTkMoveMaxDeg = 1.006;

const std::string kXsensDir = IMUCAL_SHARED_DIR "/data/real/xsens-imutk";

TEST(RealDataTest, XsensBeatsImuTkOnEveryFigure) {
  const std::string acc = kXsensDir + "/xsens_acc.mat", gyr = kXsensDir + "/xsens_gyro.mat";
  if (!std::filesystem::exists(acc) || !std::filesystem::exists(gyr))
    GTEST_SKIP() << "shared data not found under " << kXsensDir;

  importers::ImportOptions io;  // format auto: the imu_tk pair is recognised from the content
  io.gravity_m_s2 = kXsensGravity;
  importers::ImportReport import;
  const absl::StatusOr<Capture> capture = importers::ImportCapture({acc, gyr}, io, &import);
  ASSERT_TRUE(capture.ok()) << capture.status();
  EXPECT_EQ(import.format, "imutk");
  EXPECT_EQ(capture->size(), 51175u);
  EXPECT_EQ(capture->gravity_m_s2, kXsensGravity);
  // Raw unsigned 16-bit ADC values: both sensors must be inferred as counts.
  EXPECT_EQ(capture->accel_unit, AccelUnit::kCounts);
  EXPECT_EQ(capture->gyro_unit, GyroUnit::kCounts);

  const absl::StatusOr<CalibrationReport> report = Calibrate(*capture, CalibrateOptions{});
  ASSERT_TRUE(report.ok()) << report.status();
  const CalibrationReport& r = *report;
  const Residuals& res = r.residual;

  int used = 0;
  for (const PoseReport& p : r.poses) used += p.interval.used;
  std::printf(
      "xsens: %d used static intervals of %zu (multiplier %g), protocol %s, verdict %s\n"
      "  accel in-sample rms %.1f ug (IMU-TK %.1f), max %.1f ug (IMU-TK %.1f)\n"
      "  accel held-out rms %.1f ug (IMU-TK %.1f)\n"
      "  gravity direction after moves: rms %.3f deg (IMU-TK %.3f), max %.3f deg (IMU-TK %.3f)\n",
      used, r.poses.size(), r.threshold_multiplier,
      std::string(ProtocolKindName(r.protocol)).c_str(),
      std::string(VerdictName(r.verdict)).c_str(), res.accel_rms_m_s2 / kMicroG,
      kImuTkAccelRms / kMicroG, res.accel_max_m_s2 / kMicroG, kImuTkAccelMax / kMicroG,
      res.accel_heldout_rms_m_s2 / kMicroG, kImuTkAccelHeldOutRms / kMicroG, res.move_rms_deg,
      kImuTkMoveRmsDeg, res.move_max_deg, kImuTkMoveMaxDeg);
  for (const std::string& w : r.warnings) std::printf("  warning: %s\n", w.c_str());

  // The capture holds the initial rest and about 37 hand-placed poses.
  EXPECT_GE(used, 37);
  EXPECT_LE(used, 40);
  EXPECT_LT(res.accel_rms_m_s2, kImuTkAccelRms);
  EXPECT_LT(res.accel_max_m_s2, kImuTkAccelMax);
  // Held out, each pose predicted by a fit without it (the priors kept, as every refit keeps
  // them): within 5% of IMU-TK's. The model adds three second-order terms that the 38 poses
  // hardly determine; shrunk to their prior, they still move a little in each refit without a
  // pose, which costs about 1% held out here (147.8 against 146.0 ug) and buys the in-sample
  // and the moves' figures above. Until issue 25 the effect search held them at the full fit's
  // values in its refits, which let the left-out pose into its own prediction (131-134 ug).
  EXPECT_LT(res.accel_heldout_rms_m_s2, 1.05 * kImuTkAccelHeldOutRms);
  EXPECT_LT(res.move_rms_deg, kImuTkMoveRmsDeg);
  EXPECT_LT(res.move_max_deg, kImuTkMoveMaxDeg);
  EXPECT_TRUE(r.params.gyro_calibrated);
  EXPECT_NE(r.verdict, Verdict::kFail);
  // Every used pose has its in-sample and held-out residual, and the unused ones say why.
  for (const PoseReport& p : r.poses) {
    if (p.interval.used) {
      EXPECT_TRUE(std::isfinite(p.residual_m_s2)) << "pose " << p.index;
      EXPECT_TRUE(std::isfinite(p.heldout_m_s2)) << "pose " << p.index;
    } else {
      EXPECT_FALSE(p.interval.reason.empty()) << "pose " << p.index;
    }
  }
}

TEST(RealDataTest, XsensCalibrationIsDeterministic) {
  const std::string acc = kXsensDir + "/xsens_acc.mat", gyr = kXsensDir + "/xsens_gyro.mat";
  if (!std::filesystem::exists(acc) || !std::filesystem::exists(gyr))
    GTEST_SKIP() << "shared data not found under " << kXsensDir;
  importers::ImportOptions io;
  io.gravity_m_s2 = kXsensGravity;
  const absl::StatusOr<Capture> capture = importers::ImportCapture({acc, gyr}, io);
  ASSERT_TRUE(capture.ok()) << capture.status();
  CalibrateOptions options;
  options.heldout = false;
  const absl::StatusOr<CalibrationReport> a = Calibrate(*capture, options);
  const absl::StatusOr<CalibrationReport> b = Calibrate(*capture, options);
  ASSERT_TRUE(a.ok()) << a.status();
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_EQ(a->params.accel.bias, b->params.accel.bias);
  EXPECT_EQ(a->params.accel.scale, b->params.accel.scale);
  EXPECT_EQ(a->params.accel.tri_angles, b->params.accel.tri_angles);
  EXPECT_EQ(a->params.accel.quadratic, b->params.accel.quadratic);
  EXPECT_EQ(a->params.gyro.matrix, b->params.gyro.matrix);
  EXPECT_EQ(a->params.gyro.bias, b->params.gyro.bias);
}

// ---------------------------------------------------------------------------------------------
// The captures read through the column-mapped importer (README "Vendor CSV").

using real_captures::ImportColumns;
using real_captures::kRealDir;

std::vector<double> ReadNumbers(const std::string& path) {
  std::vector<double> out;
  if (FILE* f = std::fopen(path.c_str(), "r")) {
    double x;
    while (std::fscanf(f, "%lf", &x) == 1) out.push_back(x);
    std::fclose(f);
  }
  return out;
}

void PrintReport(const char* name, const CalibrationReport& r) {
  std::printf("%s: protocol %s, verdict %s, multiplier %g, accel rms %.1f ug, move rms %.3f deg\n",
              name, std::string(ProtocolKindName(r.protocol)).c_str(),
              std::string(VerdictName(r.verdict)).c_str(), r.threshold_multiplier,
              r.residual.accel_rms_m_s2 / kMicroG, r.residual.move_rms_deg);
  const auto& a = r.params.accel;
  const auto& se = r.params.stderrs.accel;
  for (int i = 0; i < 3; ++i)
    std::printf("  axis %d: bias %.4f +- %.4f, scale %.7g +- %.2g, gyro M(i,i) %.7g +- %.2g\n", i,
                a.bias(i), se.bias(i), a.scale(i), se.scale(i), r.params.gyro.matrix(i, i),
                r.params.stderrs.gyro_matrix(i, i));
  for (const TurnReport& t : r.turns)
    std::printf("  turn %.2f-%.2f s: %d x 360 about %s, measured %.2f deg, error %.3f deg\n",
                t.t_start_s, t.t_end_s, t.turns, t.axis.c_str(), t.angle_deg, t.error_deg);
  for (const std::string& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
}

// MPU-6050 (tomisuarez2/ImuCalibration): 10 hand-held poses after a 37 s rest on a table. The
// poses shake (gyro std up to 11x the rest's), so the variance test cuts some of them in pieces;
// the pieces between which the gyroscope did not turn are one rest (issue 24), and all 10
// orientations that the repository's own detector found are poses, at the usual thresholds or
// at a raised one.
TEST(RealDataTest, Mpu6050HandHeldPosesCalibrateAndAgreeWithTheRepository) {
  const importers::ImportOptions io = real_captures::Mpu6050Options();
  const std::string dir = kRealDir + "/mpu6050-tedaldi-raw";
  const absl::StatusOr<Capture> capture = ImportColumns(dir + "/example_data_calibration.csv", io);
  if (absl::IsNotFound(capture.status())) GTEST_SKIP() << capture.status();
  ASSERT_TRUE(capture.ok()) << capture.status();
  const absl::StatusOr<CalibrationReport> report = Calibrate(*capture, CalibrateOptions{});
  ASSERT_TRUE(report.ok()) << report.status();
  const CalibrationReport& r = *report;
  PrintReport("mpu6050", r);
  int used = 0;
  for (const PoseReport& p : r.poses) used += p.interval.used;
  EXPECT_EQ(used, 10);
  EXPECT_EQ(r.verdict, Verdict::kWarn);  // hand-held: moves above a degree
  EXPECT_TRUE(r.params.gyro_calibrated);
  // The repository's params_acc.csv: 3 misalignments, 3 scales [m/s^2 per LSB], 3 biases [LSB]
  // in its convention a = T K (u + b) (so its bias is minus ours); params_gyro.csv: 6
  // misalignments, 3 scales [rad/s per LSB], 3 biases. Its fit (IMU-TK's 9 parameters, its own
  // intervals) is not ours, so agreement is asked within 4 of our standard errors plus the
  // difference its detector's intervals make: 0.1 % of scale and 30 LSB (2 mg) of bias, the spread
  // of our own pose means between thresholds on this capture.
  const std::vector<double> acc = ReadNumbers(dir + "/reference_results/params_acc.csv");
  const std::vector<double> gyr = ReadNumbers(dir + "/reference_results/params_gyro.csv");
  ASSERT_EQ(acc.size(), 9u);
  ASSERT_EQ(gyr.size(), 12u);  // 6 misalignments, 3 scales, 3 biases
  for (int i = 0; i < 3; ++i) {
    const double s = r.params.accel.scale(i), se_s = r.params.stderrs.accel.scale(i);
    EXPECT_NEAR(s, acc[3 + i], 4 * se_s + 1e-3 * s) << "accel scale " << i;
    EXPECT_NEAR(r.params.accel.bias(i), -acc[6 + i], 4 * r.params.stderrs.accel.bias(i) + 30)
        << "accel bias " << i;
    // Gyro scale: ours against theirs within 4 standard errors plus 2 % (their gyro fit differs).
    EXPECT_NEAR(r.params.gyro.matrix(i, i), gyr[6 + i],
                4 * r.params.stderrs.gyro_matrix(i, i) + 0.02 * gyr[6 + i])
        << "gyro scale " << i;
  }
}

// mad-lab-fau/imucal's Ferraris example: six faces once each and three full turns, in m/s^2 and
// deg/s (nominally scaled, not calibrated).
TEST(RealDataTest, FerrarisExampleSessionIsDetectedAndCalibrated) {
  const absl::StatusOr<Capture> capture =
      ImportColumns(real_captures::kFerrarisExample, real_captures::FerrarisExampleOptions());
  if (absl::IsNotFound(capture.status())) GTEST_SKIP() << capture.status();
  ASSERT_TRUE(capture.ok()) << capture.status();
  const absl::StatusOr<CalibrationReport> report = Calibrate(*capture, CalibrateOptions{});
  ASSERT_TRUE(report.ok()) << report.status();
  const CalibrationReport& r = *report;
  PrintReport("ferraris example", r);
  EXPECT_EQ(ProtocolKindName(r.protocol), "ferraris");
  ASSERT_EQ(r.turns.size(), 3u);
  std::array<bool, 3> axes{};
  for (const TurnReport& t : r.turns) {
    EXPECT_EQ(t.turns, 1);
    ASSERT_GT(t.axis_body.norm(), 0.5);
    axes[static_cast<size_t>(ClassifyFace(t.axis_body).axis)] = true;
    // The calibrated gyroscope turns each by 360 degrees (its constraint) within a degree.
    EXPECT_LT(t.error_deg, 1.0);
  }
  EXPECT_TRUE(axes[0] && axes[1] && axes[2]);
  EXPECT_TRUE(r.params.gyro_calibrated);
  EXPECT_NE(r.verdict, Verdict::kFail);
  // The data's own faces (SOURCE.txt): +X 10.31, -X -9.24 m/s^2 etc., so bias_x ~ 0.535 and
  // scale_x ~ 2 g / 19.55; ours within 4 standard errors plus the 1 - cos(tilt) the faces leave.
  const double g = r.gravity_m_s2;
  const Eigen::Vector3d plus(10.31, 9.22, 10.44), minus(-9.24, -10.45, -9.64);
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(r.params.accel.bias(i), 0.5 * (plus(i) + minus(i)),
                4 * r.params.stderrs.accel.bias(i) + 0.01);
    EXPECT_NEAR(r.params.accel.scale(i), 2 * g / (plus(i) - minus(i)),
                4 * r.params.stderrs.accel.scale(i) + 1e-3);
    // Gyro scale within 3 % of the nominal deg/s factor (a MEMS gyro's scale tolerance).
    EXPECT_NEAR(r.params.gyro.matrix(i, i), M_PI / 180, 0.03 * M_PI / 180);
  }
}

// The same protocol, pre-cut into labelled parts (the labels are ignored): the six faces are
// joined without the moves between them, and the turns' parts are cut short.
TEST(RealDataTest, FerrarisAnnotatedSessionAgreesWithThePublishedCalibration) {
  const absl::StatusOr<Capture> capture =
      ImportColumns(real_captures::kFerrarisAnnotated, real_captures::FerrarisAnnotatedOptions());
  if (absl::IsNotFound(capture.status())) GTEST_SKIP() << capture.status();
  ASSERT_TRUE(capture.ok()) << capture.status();
  const absl::StatusOr<CalibrationReport> report = Calibrate(*capture, CalibrateOptions{});
  ASSERT_TRUE(report.ok()) << report.status();
  const CalibrationReport& r = *report;
  PrintReport("ferraris annotated", r);
  EXPECT_EQ(ProtocolKindName(r.protocol), "ferraris");
  EXPECT_EQ(r.verdict, Verdict::kWarn);
  int cut = 0;
  for (const std::string& w : r.warnings)
    cut += w.find("the data is cut there") != std::string::npos;
  EXPECT_EQ(cut, 5);  // the five joins between the six face parts
  // annotated_session_reference_cal.json (imucal's convention: a = R_a^-1 K_a^-1 (u - b_a),
  // K_a in LSB per m/s^2): scale = 1 / K_a. Same faces, same affine model: the scales agree
  // within 4 of our standard errors. Its bias is the mean of each axis' two faces, ours the
  // least-squares mean over all six (the affine fit): they differ by the cross-axis readings
  // the affine model does not fit, bounded by the faces' residual, so 4 standard errors.
  const Eigen::Vector3d k_a(208.54567263762615, 208.0011341167055, 214.78455364603022);
  const Eigen::Vector3d b_a(-6.018868019671572, -48.287874016760156, -28.96636637224333);
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(r.params.accel.scale(i), 1 / k_a(i), 4 * r.params.stderrs.accel.scale(i))
        << "scale " << i;
    EXPECT_NEAR(r.params.accel.bias(i), b_a(i), 4 * r.params.stderrs.accel.bias(i)) << "bias " << i;
  }
}

}  // namespace
}  // namespace imucal::core
