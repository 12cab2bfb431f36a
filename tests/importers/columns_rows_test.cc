// Tests of the column-mapped CSV importer (importers/columns.h) on files other tools write:
// accelerometer-only loggers, interleaved logs with rows of empty fields, quoted text fields.
#include <string>
#include <vector>

#include "core/capture.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "importers/columns.h"
#include "importers/registry.h"
#include "tests/importers/test_files.h"

namespace imucal::importers {
namespace {

using test_files::ImportText;
using ::testing::Contains;
using ::testing::HasSubstr;
using ::testing::Not;

ImportOptions SiOptions(std::string map) {
  ImportOptions options;
  options.columns.map = std::move(map);
  options.accel_unit = core::AccelUnit::kMetersPerSecond2;
  options.gyro_unit = core::GyroUnit::kRadPerSecond;
  return options;
}

// ---------------------------------------------------------------------------------------------
// Accelerometer-only captures.

TEST(ColumnCsvAccelOnlyTest, MapWithoutGyroGivesACaptureWithoutGyro) {
  ImportReport report;
  absl::StatusOr<core::Capture> c =
      ImportText("acc.csv", "time,acc_x,acc_y,acc_z\n0,0,0,9.8\n0.01,0.1,0,9.8\n",
                 SiOptions("t=time,ax=acc_x,ay=acc_y,az=acc_z"), &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_FALSE(c->has_gyro);
  EXPECT_TRUE(c->gyro.empty());  // a flag, not zeros a later stage could believe
  ASSERT_EQ(c->size(), 2u);
  EXPECT_DOUBLE_EQ(c->accel[1].x(), 0.1);
  EXPECT_TRUE(core::ValidateCapture(*c).ok());
  EXPECT_THAT(report.notes, Contains(HasSubstr("accelerometer-only")));
}

TEST(ColumnCsvAccelOnlyTest, NoGyroUnitIsInferredOrNoted) {
  ImportOptions options;
  options.columns.map = "t=time,ax=acc_x,ay=acc_y,az=acc_z";
  ImportReport report;
  absl::StatusOr<core::Capture> c =
      ImportText("acc.csv", "time,acc_x,acc_y,acc_z\n0,0,0,9.8\n0.01,0,0,9.8\n", options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  for (const std::string& note : report.notes) EXPECT_THAT(note, Not(HasSubstr("gyro unit")));
}

TEST(ColumnCsvAccelOnlyTest, PartOfTheGyroIsAnError) {
  absl::StatusOr<core::Capture> c = ImportText("part.csv", "t,ax,ay,az,gx,gy\n0,0,0,9.8,0,0\n",
                                               SiOptions("t=t,ax=ax,ay=ay,az=az,gx=gx,gy=gy"));
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(c.status().message(), HasSubstr("--columns: field 'gz' is missing"));
  EXPECT_THAT(c.status().message(), HasSubstr("or none for an accelerometer-only capture"));
}

// ---------------------------------------------------------------------------------------------
// Interleaved logs: rows whose mapped fields are empty.

constexpr char kInterleaved[] =
    "t,ax,ay,az,gx,gy,gz,mag\n"
    "0.00,0,0,9.8,0.01,0,0,\n"
    "0.00,,,,,,,\n"
    "0.01,0,0,9.8,0.01,0,0,\n"
    ",,,,,,,47.1\n"
    "0.02,0,0,9.8,0.01,0,0,\n"
    "0.025,0,0,,0.01,0,0,\n";

TEST(ColumnCsvRowsTest, EmptyFieldsWithoutTheFlagNameFileLineFieldAndTheFlag) {
  absl::StatusOr<core::Capture> c =
      ImportText("inter.csv", kInterleaved, SiOptions("t=t,ax=ax,ay=ay,az=az,gx=gx,gy=gy,gz=gz"));
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(c.status().message(), HasSubstr("inter.csv:3: column 'ax': empty field"));
  EXPECT_THAT(c.status().message(), HasSubstr("--skip-incomplete-rows"));
}

TEST(ColumnCsvRowsTest, SkipIncompleteRowsSkipsAndCountsThem) {
  ImportOptions options = SiOptions("t=t,ax=ax,ay=ay,az=az,gx=gx,gy=gy,gz=gz");
  options.columns.skip_incomplete_rows = true;
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportText("inter.csv", kInterleaved, options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  ASSERT_EQ(c->size(), 3u);
  EXPECT_EQ(c->line[1], 4u);  // each kept sample keeps its own line
  EXPECT_DOUBLE_EQ(c->t_s[2], 0.02);
  EXPECT_THAT(report.notes, Contains("skipped 3 rows with empty fields (first at " +
                                     test_files::TempPath("inter.csv") + ":3)"));
}

TEST(ColumnCsvRowsTest, SkipIncompleteRowsKeepsRowsOfOtherColumnsAlone) {
  // The empty 'mag' column is not mapped: no row is incomplete, none is skipped.
  ImportOptions options = SiOptions("t=t,ax=ax,ay=ay,az=az,gx=gx,gy=gy,gz=gz");
  options.columns.skip_incomplete_rows = true;
  ImportReport report;
  absl::StatusOr<core::Capture> c =
      ImportText("full.csv", "t,ax,ay,az,gx,gy,gz,mag\n0,0,0,9.8,0,0,0,\n0.01,0,0,9.8,0,0,0,\n",
                 options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->size(), 2u);
  for (const std::string& note : report.notes) EXPECT_THAT(note, Not(HasSubstr("skipped")));
}

TEST(ColumnCsvRowsTest, EveryRowIncompleteIsAnError) {
  ImportOptions options = SiOptions("t=t,ax=ax,ay=ay,az=az");
  options.columns.skip_incomplete_rows = true;
  absl::StatusOr<core::Capture> c = ImportText("none.csv", "t,ax,ay,az\n0,,,\n0.1,,,\n", options);
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(c.status().message(),
              HasSubstr("none.csv:2: every row (2) leaves a mapped column empty"));
}

TEST(ColumnCsvRowsTest, ShortRowWithoutTheFlagSuggestsIt) {
  absl::StatusOr<core::Capture> c =
      ImportText("short.csv", "t,ax,ay,az\n0,0,0,9.8\n0.1\n", SiOptions("t=t,ax=ax,ay=ay,az=az"));
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(c.status().message(), HasSubstr("short.csv:3: expected 4 fields, found 1"));
  EXPECT_THAT(c.status().message(), HasSubstr("--skip-incomplete-rows"));
}

// ---------------------------------------------------------------------------------------------
// Quoted fields (RFC 4180).

TEST(ColumnCsvQuotesTest, QuotedCommaIsOneField) {
  ImportOptions options = SiOptions("t=t,ax=ax,ay=ay,az=az,gx=gx,gy=gy,gz=gz");
  absl::StatusOr<core::Capture> c = ImportText("label.csv",
                                               "t,label,ax,ay,az,gx,gy,gz\n"
                                               "0,\"rest, face \"\"Z+\"\"\",0,0,9.8,0.01,0,0\n"
                                               "0.01,\"moving, by hand\",0.5,0,9.8,0.01,0,0\n",
                                               options);
  ASSERT_TRUE(c.ok()) << c.status();
  ASSERT_EQ(c->size(), 2u);
  EXPECT_DOUBLE_EQ(c->accel[1].x(), 0.5);
}

TEST(ColumnCsvQuotesTest, QuotedHeaderNamesAndNumbers) {
  absl::StatusOr<core::Capture> c =
      ImportText("q.csv", "\"t\",\"acc x\",\"acc,y\",\"acc z\"\n\"0\",\"1.5\",0,9.8\n",
                 SiOptions("t=t,ax=acc x,ay=3,az=acc z"));
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_DOUBLE_EQ(c->accel[0].x(), 1.5);
}

TEST(ColumnCsvQuotesTest, QuotedLineBreakJoinsLinesAndKeepsTheFirstLineNumber) {
  absl::StatusOr<core::Capture> c =
      ImportText("nl.csv", "t,note,ax,ay,az\n0,\"two\nlines\",0,0,9.8\n0.01,x,bad,0,9.8\n",
                 SiOptions("t=t,ax=ax,ay=ay,az=az"));
  ASSERT_FALSE(c.ok());
  // The second record starts on line 4: line 2's record spans lines 2-3.
  EXPECT_THAT(c.status().message(), HasSubstr("nl.csv:4: column 'ax': 'bad' is not a number"));
}

TEST(ColumnCsvQuotesTest, UnclosedQuoteNamesItsLine) {
  absl::StatusOr<core::Capture> c = ImportText(
      "open.csv", "t,note,ax,ay,az\n0,x,0,0,9.8\n0.01,\"never closed,0,0,9.8\n0.02,x,0,0,9.8\n",
      SiOptions("t=t,ax=ax,ay=ay,az=az"));
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(c.status().message(),
              HasSubstr("open.csv:3: a quoted field opened on this line is never closed"));
}

}  // namespace
}  // namespace imucal::importers
