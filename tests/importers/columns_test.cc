// Tests of the column-mapped CSV importer (importers/columns.h) on the real captures in
// ../shared/data/real, which it did not write, and on layouts and malformed input written here.
#include "importers/columns.h"

#include <cmath>
#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Dense"
#include "core/capture.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "importers/registry.h"
#include "tests/importers/test_files.h"

namespace imucal::importers {
namespace {

using test_files::ImportText;
using test_files::TempPath;
using test_files::WriteText;
using ::testing::AllOf;
using ::testing::Contains;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::Not;

const std::string kReal = std::string(IMUCAL_SHARED_DIR) + "/data/real";
const std::string kMpu = kReal + "/mpu6050-tedaldi-raw/example_data_calibration.csv";
const std::string kFerraris = kReal + "/imucal-ferraris/example_ferraris_session.csv";
const std::string kAnnotated = kReal + "/imucal-ferraris/annotated_session.csv";

ImportOptions ColumnsOptions(std::string map) {
  ImportOptions options;
  options.columns.map = std::move(map);
  return options;
}

// Mean of accel over the samples with t in [t0, t1).
Eigen::Vector3d MeanAccel(const core::Capture& c, double t0, double t1) {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  int n = 0;
  for (size_t i = 0; i < c.size(); ++i) {
    if (c.t_s[i] >= t0 && c.t_s[i] < t1) sum += c.accel[i], ++n;
  }
  return n > 0 ? Eigen::Vector3d(sum / n) : Eigen::Vector3d::Constant(NAN);
}

// ---------------------------------------------------------------------------------------------
// Real captures through the column mapping.

// MPU-6050 (Tedaldi protocol): "Fs,100" and three more preamble lines, then ax..gz in raw
// counts, no time column.
TEST(ColumnCsvRealTest, Mpu6050RateFromPreambleAndHeaderFoundByName) {
  ImportOptions options = ColumnsOptions("ax=ax,ay=ay,az=az,gx=gx,gy=gy,gz=gz");
  options.columns.rate_from_preamble = "Fs";
  options.accel_unit = core::AccelUnit::kCounts;
  options.gyro_unit = core::GyroUnit::kCounts;
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({kMpu}, options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(report.format, "columns");
  ASSERT_EQ(c->size(), 10245u);  // 10,250 lines - 5 preamble/header lines
  EXPECT_EQ(c->rate_hz, 100.0);
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kCounts);
  EXPECT_EQ(c->gyro_unit, core::GyroUnit::kCounts);
  EXPECT_FALSE(c->has_temp());
  EXPECT_EQ(c->t_s[0], 0.0);
  EXPECT_DOUBLE_EQ(c->t_s[1], 0.01);
  EXPECT_DOUBLE_EQ(c->t_s.back(), 102.44);
  EXPECT_EQ(c->accel[0], Eigen::Vector3d(-12, -812, 15032));
  EXPECT_EQ(c->gyro[0], Eigen::Vector3d(-447, 156, -86));
  EXPECT_EQ(c->accel[1], Eigen::Vector3d(-208, -828, 14796));
  EXPECT_EQ(c->accel.back(), Eigen::Vector3d(8636, -268, 12792));
  EXPECT_EQ(c->gyro.back(), Eigen::Vector3d(-413, 144, -81));
  EXPECT_THAT(report.notes, Contains(HasSubstr("time = row / 100 Hz")));
  EXPECT_TRUE(core::ValidateCapture(*c).ok());

  // The same with the preamble counted and the rate given.
  ImportOptions explicit_options = ColumnsOptions("ax=1,ay=2,az=3,gx=4,gy=5,gz=6");
  explicit_options.columns.skip_lines = 4;
  explicit_options.columns.rate_hz = 100.0;
  absl::StatusOr<core::Capture> same = ImportCapture({kMpu}, explicit_options);
  ASSERT_TRUE(same.ok()) << same.status();
  EXPECT_EQ(same->t_s, c->t_s);
  EXPECT_EQ(same->accel, c->accel);
  EXPECT_EQ(same->gyro, c->gyro);
  // Units were not given: inferred as counts, and said so.
  EXPECT_EQ(same->accel_unit, core::AccelUnit::kCounts);
  EXPECT_EQ(same->gyro_unit, core::GyroUnit::kCounts);
}

TEST(ColumnCsvRealTest, Mpu6050WithoutARateIsAnOptionError) {
  absl::StatusOr<core::Capture> c =
      ImportCapture({kMpu}, ColumnsOptions("ax=ax,ay=ay,az=az,gx=gx,gy=gy,gz=gz"));
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(c.status().message(), HasSubstr("--rate"));
}

// Ferraris session: n_samples index at 102.4 Hz, gyro deg/s, acc m/s^2 (nominal).
TEST(ColumnCsvRealTest, FerrarisSampleIndexTimeBase) {
  ImportOptions options =
      ColumnsOptions("t=n_samples,gx=gyr_x,gy=gyr_y,gz=gyr_z,ax=acc_x,ay=acc_y,az=acc_z");
  options.columns.time_unit = ColumnTimeUnit::kSampleIndex;
  options.columns.rate_hz = 102.4;
  options.accel_unit = core::AccelUnit::kMetersPerSecond2;
  options.gyro_unit = core::GyroUnit::kDegPerSecond;
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({kFerraris}, options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  ASSERT_EQ(c->size(), 10376u);
  EXPECT_EQ(c->rate_hz, 102.4);
  EXPECT_EQ(c->t_s[0], 0.0);
  EXPECT_DOUBLE_EQ(c->t_s[1], 1 / 102.4);
  EXPECT_DOUBLE_EQ(c->t_s.back(), 10375 / 102.4);
  EXPECT_EQ(c->gyro[0], Eigen::Vector3d(-0.6103515625, -0.30517578125, 0.06103515625));
  EXPECT_EQ(c->accel[0], Eigen::Vector3d(10.332114257812501, -0.5795947265625, 0.51732421875));
  EXPECT_EQ(c->accel.back(), Eigen::Vector3d(0.45984375, -0.5700146484375, 10.432705078125));
  EXPECT_THAT(report.notes, Contains(HasSubstr("sample index")));
  EXPECT_THAT(report.notes, Not(Contains(HasSubstr("time has"))));
  // The static faces of SOURCE.txt (example_ferraris_session_list.json's x_p and z_a, samples
  // 540-1271 and 5376-5983): +X 10.31 and -Z -9.64 m/s^2.
  EXPECT_NEAR(MeanAccel(*c, 540 / 102.4, 1271 / 102.4).x(), 10.31, 0.01);
  EXPECT_NEAR(MeanAccel(*c, 5376 / 102.4, 5983 / 102.4).z(), -9.64, 0.01);
}

// Ferraris annotated session: a text `part` column, a `samples` index at 204.8 Hz, raw counts,
// and the parts saved one after the other in alphabetical order (x_a before x_p), so the index
// goes back at every part boundary.
ImportOptions AnnotatedOptions() {
  ImportOptions options =
      ColumnsOptions("t=samples,ax=acc_x,ay=acc_y,az=acc_z,gx=gyr_x,gy=gyr_y,gz=gyr_z");
  options.columns.time_unit = ColumnTimeUnit::kSampleIndex;
  options.columns.rate_hz = 204.8;
  options.accel_unit = core::AccelUnit::kCounts;
  options.gyro_unit = core::GyroUnit::kCounts;
  return options;
}

TEST(ColumnCsvRealTest, AnnotatedSessionOutOfOrderIsAnErrorNamingTheLine) {
  absl::StatusOr<core::Capture> c = ImportCapture({kAnnotated}, AnnotatedOptions());
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument);
  // Line 1063 starts part x_p at sample 0, after x_a ended at sample 2088 (line 1062).
  EXPECT_THAT(c.status().message(),
              AllOf(HasSubstr("annotated_session.csv:1063: t=0 s does not increase"),
                    HasSubstr("at line 1062"), HasSubstr("--sort-time")));
}

TEST(ColumnCsvRealTest, AnnotatedSessionSortedIsTheContinuousSession) {
  ImportOptions options = AnnotatedOptions();
  options.columns.sort_by_time = true;
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({kAnnotated}, options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  ASSERT_EQ(c->size(), 9414u);
  // The parts tile samples 0..9413 exactly: sorted, the session has no gap.
  for (size_t i = 0; i < c->size(); ++i) {
    ASSERT_DOUBLE_EQ(c->t_s[i], static_cast<double>(i) / 204.8) << i;
  }
  EXPECT_EQ(c->accel[0], Eigen::Vector3d(2027, -75, 3));  // line 1063: x_p, sample 0
  EXPECT_EQ(c->gyro[0], Eigen::Vector3d(5, -6, -4));
  EXPECT_EQ(c->accel[1028], Eigen::Vector3d(-2052, -28, -73));  // line 2: x_a, sample 1028
  EXPECT_EQ(c->accel.back(), Eigen::Vector3d(-45, 23, 2061));   // last line: z_rot, 9413
  // 8 part boundaries, 5 of them going back in the index.
  EXPECT_THAT(report.notes, Contains(HasSubstr("sorted the rows by time: 5 rows")));
  EXPECT_THAT(report.notes, Contains("ignored columns: 'part'"));
  EXPECT_THAT(report.notes, Not(Contains(HasSubstr("time has"))));

  // Cross-check with the third-party calibration of this file
  // (annotated_session_reference_cal.json, mad-lab-fau/imucal's Ferraris model
  // a = R_a^-1 K_a^-1 (u - b_a)): applied to our static face means (x_p = samples 0-1027,
  // z_a = 4552-5595), it gives about 1 g. A wrong column, unit or order would not.
  Eigen::Matrix3d k_a =
      Eigen::Vector3d(208.54567263762615, 208.0011341167055, 214.78455364603022).asDiagonal();
  Eigen::Matrix3d r_a;
  r_a << 0.9999125214309234, 0.007122056140390757, -0.011145662922687352,  //
      -0.007947378455060604, 0.9996887358297629, 0.023648903373787954,     //
      0.021342900724016442, -0.010781879507682177, 0.9997140749549175;
  const Eigen::Vector3d b_a(-6.018868019671572, -48.287874016760156, -28.96636637224333);
  auto calibrated = [&](double first, double last) -> Eigen::Vector3d {
    const Eigen::Vector3d u = MeanAccel(*c, (first + 200) / 204.8, (last - 200) / 204.8);
    return r_a.inverse() * k_a.inverse() * (u - b_a);
  };
  const Eigen::Vector3d x_p = calibrated(0, 1027);
  const Eigen::Vector3d z_a = calibrated(4552, 5595);
  EXPECT_NEAR(x_p.norm(), 9.81, 0.05) << x_p.transpose();
  EXPECT_NEAR(z_a.norm(), 9.81, 0.05) << z_a.transpose();
  EXPECT_GT(std::abs(x_p.x()), 9.7);
  EXPECT_GT(std::abs(z_a.z()), 9.7);
}

// ---------------------------------------------------------------------------------------------
// Column mapping: layouts and malformed input.

TEST(ColumnCsvTest, SemicolonsQuotesMillisecondsTemperatureAndColumnNumbers) {
  ImportOptions options = ColumnsOptions("t=1,ax=3,ay=4,az=5,gx=6,gy=7,gz=8,temp=2");
  options.columns.time_unit = ColumnTimeUnit::kMilliseconds;
  options.accel_unit = core::AccelUnit::kG;
  options.gyro_unit = core::GyroUnit::kRadPerSecond;
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportText("semi.csv",
                                               "\"time_ms\";\"T\";a;b;c;d;e;f\r\n"
                                               "10;25.5;0;0;1;0.1;0.2;0.3\r\n"
                                               "\r\n"
                                               "20;25.6;0;0;1;0.1;0.2;-0.3\r\n",
                                               options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  ASSERT_EQ(c->size(), 2u);
  EXPECT_DOUBLE_EQ(c->t_s[0], 0.010);
  EXPECT_DOUBLE_EQ(c->t_s[1], 0.020);
  EXPECT_THAT(c->temp, ElementsAre(25.5, 25.6));
  EXPECT_EQ(c->gyro[1], Eigen::Vector3d(0.1, 0.2, -0.3));
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kG);
}

TEST(ColumnCsvTest, WhitespaceDelimitedWithoutHeader) {
  ImportOptions options = ColumnsOptions("t=1,ax=2,ay=3,az=4,gx=5,gy=6,gz=7");
  options.columns.no_header = true;
  options.columns.delimiter = "space";
  options.accel_unit = core::AccelUnit::kMetersPerSecond2;
  options.gyro_unit = core::GyroUnit::kRadPerSecond;
  absl::StatusOr<core::Capture> c =
      ImportText("ws.txt", "0.0  1 2 3\t4 5 6\n0.5 7 8 9 10 11 12\n", options);
  ASSERT_TRUE(c.ok()) << c.status();
  ASSERT_EQ(c->size(), 2u);
  EXPECT_EQ(c->accel[1], Eigen::Vector3d(7, 8, 9));
  EXPECT_EQ(c->t_s[1], 0.5);
}

TEST(ColumnCsvTest, AutoUsesColumnsOnlyWhenMapped) {
  const std::string path = TempPath("plain.csv");
  WriteText(path, "ax,ay,az,gx,gy,gz\n0,0,9.8,0,0,0\n");
  absl::StatusOr<core::Capture> unmapped = ImportCapture({path}, ImportOptions{});
  ASSERT_FALSE(unmapped.ok());
  EXPECT_THAT(unmapped.status().message(),
              AllOf(HasSubstr("unrecognised capture format"),
                    HasSubstr("columns: used only when --columns names the columns")));
}

struct BadCase {
  std::string name;
  std::string text;
  std::string map;
  std::string expected;
};

TEST(ColumnCsvTest, MalformedInputNamesFileLineAndColumn) {
  const std::string header = "time,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z\n";
  const std::string map = "t=time,ax=acc_x,ay=acc_y,az=acc_z,gx=gyr_x,gy=gyr_y,gz=gyr_z";
  const std::vector<BadCase> cases = {
      {"bad_number.csv", header + "0,0,0,9.8,0,0,0\n0.01,0,abc,9.8,0,0,0\n", map,
       "bad_number.csv:3: column 'acc_y': 'abc' is not a number"},
      {"empty_field.csv", header + "0,0,0,9.8,0,,0\n", map,
       "empty_field.csv:2: column 'gyr_y': empty field"},
      {"nan.csv", header + "0,0,0,nan,0,0,0\n", map,
       "nan.csv:2: column 'acc_z': 'nan' is not finite"},
      {"short_row.csv", header + "0,0,0,9.8,0,0,0\n0.01,0,0,9.8,0,0\n", map,
       "short_row.csv:3: expected 7 fields, found 6"},
      {"time_back.csv", header + "0,0,0,9.8,0,0,0\n0.01,0,0,9.8,0,0,0\n0.01,0,0,9.8,0,0,0\n", map,
       "time_back.csv:4: t=0.01 s does not increase (previous 0.01 s at line 3)"},
      {"missing_column.csv", header + "0,0,0,9.8,0,0,0\n",
       "t=time,ax=acc_x,ay=acc_y,az=acc_w,gx=gyr_x,gy=gyr_y,gz=gyr_z",
       "missing_column.csv:1: no column 'acc_w' (mapped to az) in the header; it has: time, "
       "acc_x, acc_y, acc_z, gyr_x, gyr_y, gyr_z (a preamble before the header: --skip-lines N)"},
      {"no_rows.csv", header, map, "no_rows.csv:1: no rows after the header"},
      {"bad_map.csv", header, "ax=acc_x,ay=acc_y,az=acc_z,gx=gyr_x,gy=gyr_y",
       "--columns: field 'gz' is missing"},
      {"unknown_field.csv", header, map + ",mag=gyr_x", "--columns: unknown field 'mag'"},
      {"same_column.csv", header + "0,0,0,9.8,0,0,0\n",
       "t=time,ax=acc_x,ay=acc_x,az=acc_z,gx=gyr_x,gy=gyr_y,gz=gyr_z",
       "--columns: ax and ay name the same column 'acc_x'"},
  };
  for (const BadCase& bad : cases) {
    SCOPED_TRACE(bad.name);
    ImportOptions options = ColumnsOptions(bad.map);
    options.accel_unit = core::AccelUnit::kMetersPerSecond2;
    options.gyro_unit = core::GyroUnit::kRadPerSecond;
    absl::StatusOr<core::Capture> c = ImportText(bad.name, bad.text, options);
    ASSERT_FALSE(c.ok());
    EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_THAT(c.status().message(), HasSubstr(bad.expected));
  }
}

TEST(ColumnCsvTest, MissingNameWithSkipLinesListsTheHeader) {
  ImportOptions options = ColumnsOptions("ax=ax,ay=ay,az=az,gx=gx,gy=gy,gz=gyro_z");
  options.columns.skip_lines = 1;
  options.columns.rate_hz = 10;
  absl::StatusOr<core::Capture> c =
      ImportText("skip.csv", "Fs,10\nax,ay,az,gx,gy,gz\n0,0,1,0,0,0\n", options);
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(c.status().message(),
              HasSubstr("skip.csv:2: no column 'gyro_z' (mapped to gz) in the header; it has: "
                        "ax, ay, az, gx, gy, gz"));
}

TEST(ColumnCsvTest, PreambleRateErrors) {
  ImportOptions options = ColumnsOptions("ax=ax,ay=ay,az=az,gx=gx,gy=gy,gz=gz");
  options.columns.rate_from_preamble = "Fs";
  absl::StatusOr<core::Capture> missing =
      ImportText("nofs.csv", "Rate,100\nax,ay,az,gx,gy,gz\n0,0,1,0,0,0\n", options);
  ASSERT_FALSE(missing.ok());
  EXPECT_THAT(missing.status().message(), HasSubstr("no preamble line starts with 'Fs'"));
  absl::StatusOr<core::Capture> bad =
      ImportText("badfs.csv", "Fs,fast\nax,ay,az,gx,gy,gz\n0,0,1,0,0,0\n", options);
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.status().message(),
              HasSubstr("badfs.csv:1: column 'Fs': 'fast' is not a number"));
}

TEST(ColumnCsvTest, SortRejectsRepeatedTimes) {
  ImportOptions options = ColumnsOptions("t=n,ax=a,ay=b,az=c,gx=d,gy=e,gz=f");
  options.columns.time_unit = ColumnTimeUnit::kSampleIndex;
  options.columns.rate_hz = 10;
  options.columns.sort_by_time = true;
  absl::StatusOr<core::Capture> c = ImportText(
      "dup.csv", "n,a,b,c,d,e,f\n1,0,0,1,0,0,0\n0,0,0,1,0,0,0\n1,0,0,1,0,0,0\n", options);
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(c.status().message(), HasSubstr("dup.csv:4: t=0.1 s repeats the time of line 2"));
}

TEST(ColumnCsvTest, IndexJumpStaysAGapAndIsNoted) {
  ImportOptions options = ColumnsOptions("t=n,ax=a,ay=b,az=c,gx=d,gy=e,gz=f");
  options.columns.time_unit = ColumnTimeUnit::kSampleIndex;
  options.columns.rate_hz = 10;
  std::string text = "n,a,b,c,d,e,f\n";
  for (int n : {0, 1, 2, 3, 50, 51, 52}) text += std::to_string(n) + ",0,0,9.8,0,0,0\n";
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportText("gap.csv", text, options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_DOUBLE_EQ(c->t_s[4], 5.0);
  EXPECT_THAT(report.notes, Contains(AllOf(HasSubstr("time has 1 gap"),
                                           HasSubstr("the largest 4.7 s after t=0.3 s"))));
}

TEST(ColumnCsvTest, OptionChecks) {
  ColumnCsvOptions o;
  o.map = "ax=1,ay=2,az=3,gx=4,gy=5,gz=6";
  EXPECT_THAT(CheckColumnCsvOptions(o).message(), HasSubstr("no time column"));
  o.rate_hz = 100;
  EXPECT_TRUE(CheckColumnCsvOptions(o).ok());
  o.rate_from_preamble = "Fs";
  EXPECT_THAT(CheckColumnCsvOptions(o).message(), HasSubstr("not both"));
  o.rate_from_preamble.clear();
  o.delimiter = "|";
  EXPECT_THAT(CheckColumnCsvOptions(o).message(), HasSubstr("--delimiter"));
  o.delimiter.clear();
  o.map = "t=time,ax=1,ay=2,az=3,gx=4,gy=5,gz=6";
  o.no_header = true;
  EXPECT_THAT(CheckColumnCsvOptions(o).message(), HasSubstr("map t by column number"));
  EXPECT_FALSE(ParseColumnTimeUnit("min").ok());
  EXPECT_EQ(*ParseColumnTimeUnit("us"), ColumnTimeUnit::kMicroseconds);
}

}  // namespace
}  // namespace imucal::importers
