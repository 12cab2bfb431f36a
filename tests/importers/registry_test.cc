// Tests of the importer registry (importers/registry.h): the formats, auto-detection, the
// overrides and the errors of ImportCapture, and the real Xsens capture read as imu_tk counts.
#include "importers/registry.h"

#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Core"
#include "core/capture.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "importers/imucal_csv.h"
#include "tests/core/test_captures.h"
#include "tests/importers/test_files.h"

namespace imucal::importers {
namespace {

using core::test_captures::AwkwardCapture;
using core::test_captures::ExpectSameCapture;
using test_files::ImuTkTexts;
using test_files::kSpecExample;
using test_files::TempPath;
using test_files::WriteText;
using ::testing::AllOf;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::StartsWith;

TEST(ImportCaptureTest, RegistryListsTheFormats) {
  std::vector<std::string_view> names;
  for (const CaptureImporter* importer : CaptureImporters()) {
    names.push_back(importer->name());
    EXPECT_FALSE(importer->description().empty());
  }
  EXPECT_THAT(names, ElementsAre("imucal", "euroc", "imutk", "columns", "rosbag2", "mcap"));
}

TEST(ImportCaptureTest, AutoDetectsImucal) {
  const std::string path = TempPath("auto_imucal.csv");
  WriteText(path, kSpecExample);
  ImportOptions options;
  options.device = "robot-7";
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({path}, options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(report.format, "imucal");
  EXPECT_THAT(report.paths, ElementsAre(path));
  EXPECT_EQ(c->device, "robot-7");
  EXPECT_THAT(report.notes,
              ElementsAre("device 'robot-7' used instead of the file's 'robot-0042'"));
  // The caller that does not want the report.
  EXPECT_TRUE(ImportCapture({path}, ImportOptions{}).ok());
}

TEST(ImportCaptureTest, ImucalOverridesUnitsAndGravity) {
  const std::string path = TempPath("override_imucal.csv");
  WriteText(path, kSpecExample);
  ImportOptions options;
  options.format = "imucal";
  options.accel_unit = core::AccelUnit::kG;
  options.gravity_m_s2 = 9.81;
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({path}, options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kG);
  EXPECT_EQ(c->gravity_m_s2, 9.81);
  EXPECT_THAT(report.notes, ElementsAre("accel unit g used instead of the file's m/s^2",
                                        "gravity 9.81 m/s^2 used instead of the file's 9.80665"));
}

TEST(ImportCaptureTest, AutoDetectsImuTkAndSwapsByName) {
  const auto [accel, gyro] = ImuTkTexts();
  const std::string accel_path = TempPath("pair_Acc.txt");
  const std::string gyro_path = TempPath("pair_GYRO.txt");
  WriteText(accel_path, accel);
  WriteText(gyro_path, gyro);
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({gyro_path, accel_path}, {}, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(report.format, "imutk");
  EXPECT_THAT(report.paths, ElementsAre(accel_path, gyro_path));
  ASSERT_EQ(report.notes.size(), 3u);
  EXPECT_THAT(report.notes[0], StartsWith("swapped the inputs by their names"));
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kMetersPerSecond2);
  EXPECT_EQ(c->gyro_unit, core::GyroUnit::kDegPerSecond);
  EXPECT_EQ(c->accel[0].z(), 9.81);

  // In the right order nothing is swapped.
  ASSERT_TRUE(ImportCapture({accel_path, gyro_path}, {}, &report).ok());
  EXPECT_THAT(report.notes[0], StartsWith("accel unit inferred"));
}

TEST(ImportCaptureTest, ExplicitImuTkPairMismatch) {
  const auto [accel, gyro] = ImuTkTexts();
  const std::string accel_path = TempPath("mismatch_acc.txt");
  const std::string gyro_path = TempPath("mismatch_gyro.txt");
  WriteText(accel_path, accel);
  WriteText(gyro_path, gyro.substr(0, gyro.find("0.500000")));  // 50 rows of 120
  ImportOptions options;
  options.format = "imutk";
  absl::StatusOr<core::Capture> c = ImportCapture({accel_path, gyro_path}, options);
  EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(c.status().message()),
              StartsWith(gyro_path + ":50: ends after 50 samples, but " + accel_path +
                         " has 120 (sample 51 at " + accel_path + ":51"));
}

TEST(ImportCaptureTest, UnrecognisedFormatSaysWhatWasTried) {
  const std::string path = TempPath("vendor.csv");
  WriteText(path, "time,acc_x,acc_y,acc_z\n0,1,2,3\n");
  absl::StatusOr<core::Capture> c = ImportCapture({path}, {});
  EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument);
  const std::string message(c.status().message());
  EXPECT_THAT(message, StartsWith(path + ": unrecognised capture format (tried imucal: "));
  EXPECT_THAT(message, HasSubstr("; imutk: "));
  EXPECT_THAT(message, HasSubstr("'time,acc_x,acc_y,acc_z'"));
}

TEST(ImportCaptureTest, WrongCallsAreClearErrors) {
  const std::string imucal_path = TempPath("count_imucal.csv");
  WriteText(imucal_path, kSpecExample);
  const std::string tk_path = TempPath("count_tk.txt");
  WriteText(tk_path, "0 1 2 3\n");

  EXPECT_THAT(std::string(ImportCapture({}, {}).status().message()), HasSubstr("no input"));
  EXPECT_THAT(std::string(ImportCapture({tk_path, tk_path, tk_path}, {}).status().message()),
              HasSubstr("the imutk format reads its files in 2s, got 3"));
  EXPECT_THAT(std::string(ImportCapture({tk_path}, {}).status().message()),
              HasSubstr("the imutk format reads two files"));
  ImportOptions hdf5;
  hdf5.format = "hdf5";
  EXPECT_EQ(ImportCapture({imucal_path}, hdf5).status().message(),
            "unknown capture format 'hdf5' (known: auto, imucal, euroc, imutk, columns, rosbag2, "
            "mcap)");
  ImportOptions mcap;
  mcap.format = "mcap";
  EXPECT_THAT(std::string(ImportCapture({imucal_path}, mcap).status().message()),
              HasSubstr("count_imucal.csv: not an MCAP file (no MCAP magic at the start)"));
  ImportOptions bad_gravity;
  bad_gravity.gravity_m_s2 = -1.0;
  EXPECT_FALSE(ImportCapture({imucal_path}, bad_gravity).ok());
  EXPECT_EQ(ImportCapture({TempPath("missing.txt")}, {}).status().code(),
            absl::StatusCode::kNotFound);
}

// Several files of a one-file format are one capture, joined in the order given: each file's
// samples and lines are kept, a later file that starts before the earlier one ends is moved
// after it (its clock restarted), and each file's start is a gap nothing integrates across.
TEST(ImportCaptureTest, JoinsFilesInOrderAndKeepsTheirLines) {
  const std::string a = TempPath("join_a.csv");
  const std::string b = TempPath("join_b.csv");
  WriteText(a, kSpecExample);
  WriteText(b, kSpecExample);
  ImportReport report;
  absl::StatusOr<core::Capture> one = ImportCapture({a}, {});
  absl::StatusOr<core::Capture> both = ImportCapture({a, b}, {}, &report);
  ASSERT_TRUE(one.ok()) << one.status();
  ASSERT_TRUE(both.ok()) << both.status();
  const size_t n = one->size();
  ASSERT_EQ(both->size(), 2 * n);
  EXPECT_THAT(report.paths, ElementsAre(a, b));
  ASSERT_EQ(both->files.size(), 2u);
  EXPECT_EQ(both->files[1].path, b);
  EXPECT_EQ(both->files[1].first_sample, n);
  EXPECT_THAT(both->FileStarts(), ElementsAre(n));
  EXPECT_EQ(both->FileOf(0), 0);
  EXPECT_EQ(both->FileOf(n), 1);
  EXPECT_EQ(both->line[n], one->line[0]);
  for (size_t i = 1; i < both->size(); ++i) ASSERT_GT(both->t_s[i], both->t_s[i - 1]) << i;
  EXPECT_GE(both->t_s[n] - both->t_s[n - 1], 1.0 - 1e-9);
  EXPECT_EQ(both->accel[n], one->accel[0]);

  // Files that disagree on units are refused, naming both.
  const std::string c = TempPath("join_c.csv");
  core::Capture other = *one;
  other.gyro_unit = one->gyro_unit == core::GyroUnit::kDegPerSecond ? core::GyroUnit::kRadPerSecond
                                                                    : core::GyroUnit::kDegPerSecond;
  other.files = {{c, 0}};
  absl::StatusOr<core::Capture> refused = JoinCaptures({*one, other}, &report.notes);
  ASSERT_FALSE(refused.ok());
  EXPECT_THAT(std::string(refused.status().message()),
              AllOf(HasSubstr("do not agree on units"), HasSubstr(a), HasSubstr(c)));
}

// Accelerometer-only files join each other, never a file with a gyroscope (zeros would have to
// stand in for the missing rates).
TEST(ImportCaptureTest, JoinsFilesWithoutGyroOnlyWithEachOther) {
  const std::string a = TempPath("join_acc_a.csv");
  const std::string b = TempPath("join_acc_b.csv");
  const std::string g = TempPath("join_gyro.csv");
  const std::string accel_only = "# imucal-capture v1\n# accel_unit=m/s^2\nt,ax,ay,az\n"
                                 "0,0,0,9.8\n0.01,0,0,9.8\n";
  WriteText(a, accel_only);
  WriteText(b, accel_only);
  WriteText(g, kSpecExample);
  absl::StatusOr<core::Capture> both = ImportCapture({a, b}, {});
  ASSERT_TRUE(both.ok()) << both.status();
  EXPECT_FALSE(both->has_gyro);
  EXPECT_EQ(both->size(), 4u);
  EXPECT_TRUE(core::ValidateCapture(*both).ok());
  absl::StatusOr<core::Capture> mixed = ImportCapture({a, g}, {});
  ASSERT_FALSE(mixed.ok());
  EXPECT_THAT(std::string(mixed.status().message()),
              AllOf(HasSubstr("do not agree on the sensors"), HasSubstr(a + " has no gyroscope"),
                    HasSubstr(g)));
}

TEST(ImportCaptureTest, ExportThenImportRoundTrip) {
  const std::string path = TempPath("export_import.csv");
  const core::Capture original = AwkwardCapture();
  ASSERT_TRUE(WriteImucalCsvFile(original, path).ok());
  absl::StatusOr<core::Capture> c = ImportCapture({path}, {});
  ASSERT_TRUE(c.ok()) << c.status();
  ExpectSameCapture(original, *c);
}

// ---------------------------------------------------------------------------------------------
// Real data: the Xsens capture shipped with imu_tk (../shared/data/real/xsens-imutk/SOURCE.txt).

TEST(RealDataTest, XsensImuTkPairAutoDetectedAsCounts) {
  const std::string dir = IMUCAL_SHARED_DIR "/data/real/xsens-imutk/";
  const std::string accel_path = dir + "xsens_acc.mat";
  const std::string gyro_path = dir + "xsens_gyro.mat";
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({accel_path, gyro_path}, {}, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(report.format, "imutk");
  EXPECT_EQ(c->size(), 51175u);
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kCounts);
  EXPECT_EQ(c->gyro_unit, core::GyroUnit::kCounts);
  ASSERT_EQ(report.notes.size(), 2u);
  EXPECT_THAT(report.notes[0], StartsWith("accel unit inferred as counts"));
  EXPECT_THAT(report.notes[1], StartsWith("gyro unit inferred as counts"));
  EXPECT_EQ(c->t_s.front(), 2.984e-02);
  EXPECT_EQ(c->accel.front(), Eigen::Vector3d(33108, 33329, 36429));
  EXPECT_EQ(c->gyro.front(), Eigen::Vector3d(32786, 32429, 32499));
  EXPECT_EQ(c->t_s.back(), 511.718);
  EXPECT_EQ(c->accel.back(), Eigen::Vector3d(35290, 35137, 27631));
  EXPECT_NEAR(c->MedianDt(), 0.01, 1e-4);  // 100 Hz
  EXPECT_FALSE(c->has_temp());
  EXPECT_TRUE(core::ValidateCapture(*c).ok());

  // Given in the other order, the names put them right.
  ASSERT_TRUE(ImportCapture({gyro_path, accel_path}, {}, &report).ok());
  EXPECT_THAT(report.paths, ElementsAre(accel_path, gyro_path));
}

}  // namespace
}  // namespace imucal::importers
