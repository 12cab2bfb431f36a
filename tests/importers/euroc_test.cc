// Tests of the EuRoC importer (importers/euroc.h) on files written here by an independent
// writer.
#include "importers/euroc.h"

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Dense"
#include "core/capture.h"
#include "core/simulator.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "importers/imucal_csv.h"
#include "importers/registry.h"
#include "tests/importers/test_files.h"

namespace imucal::importers {
namespace {

using test_files::ImportText;
using ::testing::Contains;
using ::testing::HasSubstr;
using ::testing::Pair;

// ---------------------------------------------------------------------------------------------
// EuRoC, written here independently of the importer (printf, the dataset's exact header).

constexpr char kEurocHeader[] =
    "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n";

std::string EurocRow(int64_t ns, const Eigen::Vector3d& w, const Eigen::Vector3d& a) {
  char row[512];
  std::snprintf(row, sizeof(row), "%lld,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g\n",
                static_cast<long long>(ns), w.x(), w.y(), w.z(), a.x(), a.y(), a.z());
  return row;
}

TEST(EurocTest, AutoDetectedRowsOfTheDataset) {
  // The first rows of EuRoC MH_01_easy/mav0/imu0/data.csv, as published.
  const std::string text = std::string(kEurocHeader) +
                           "1403636579758555392,-0.099134701513277898,0.14730578886832138,"
                           "0.02722713633111154,8.1476917083333333,-0.37592158333333331,"
                           "-2.4026292499999999\n"
                           "1403636579763555584,-0.099134701513277898,0.14032447186034408,"
                           "0.029321531433504737,8.033280791666666,-0.40861041666666664,"
                           "-2.4026292499999999\n";
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportText("data.csv", text, ImportOptions{}, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(report.format, "euroc");
  ASSERT_EQ(c->size(), 2u);
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kMetersPerSecond2);
  EXPECT_EQ(c->gyro_unit, core::GyroUnit::kRadPerSecond);
  EXPECT_EQ(c->t_s[0], 0.0);
  EXPECT_EQ(c->t_s[1], 0.005000192);  // 5,000,192 ns, exact despite the 1.4e18 origin
  EXPECT_EQ(c->gyro[0],
            Eigen::Vector3d(-0.099134701513277898, 0.14730578886832138, 0.02722713633111154));
  EXPECT_EQ(c->accel[1],
            Eigen::Vector3d(8.033280791666666, -0.40861041666666664, -2.4026292499999999));
  EXPECT_THAT(c->extra_metadata, Contains(Pair("t0_ns", "1403636579758555392")));
}

TEST(EurocTest, SimulatedCaptureRoundTrip) {
  core::SimOptions sim;
  sim.seed = 7;
  sim.rate_hz = 200;
  sim.temperature = false;
  absl::StatusOr<core::SimResult> result = core::Simulate(sim);
  ASSERT_TRUE(result.ok()) << result.status();
  const core::Capture& truth = result->capture;
  const int64_t origin_ns = 1'700'000'000'123'456'789;
  std::string text = kEurocHeader;
  std::vector<int64_t> stamps;
  for (size_t i = 0; i < truth.size(); ++i) {
    stamps.push_back(origin_ns + std::llround(truth.t_s[i] * 1e9));
    text += EurocRow(stamps.back(), truth.gyro[i], truth.accel[i]);
  }
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportText("roundtrip.csv", text, ImportOptions{}, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(report.format, "euroc");
  ASSERT_EQ(c->size(), truth.size());
  for (size_t i = 0; i < truth.size(); ++i) {
    ASSERT_EQ(c->accel[i], truth.accel[i]) << i;  // %.17g round-trips exactly
    ASSERT_EQ(c->gyro[i], truth.gyro[i]) << i;
    ASSERT_NEAR(c->t_s[i], truth.t_s[i] - truth.t_s[0], 1e-9) << i;
    ASSERT_EQ(c->t_s[i], static_cast<double>(stamps[i] - stamps[0]) / 1e9) << i;
  }
  EXPECT_THAT(c->extra_metadata, Contains(Pair("t0_ns", std::to_string(stamps[0]))));
  // The imported capture writes and reads back as an imucal capture unchanged.
  absl::StatusOr<core::Capture> again = ParseImucalCsv(FormatImucalCsv(*c), "again");
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_EQ(again->accel, c->accel);
  EXPECT_EQ(again->t_s, c->t_s);
}

TEST(EurocTest, MalformedInputNamesFileLineAndColumn) {
  const std::string row = EurocRow(1000, Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0, 0, 9.8));
  const std::vector<std::pair<std::string, std::string>> cases = {
      {std::string(kEurocHeader) + row + "2000,0,0,x,0,0,9.8\n",
       "euroc_bad.csv:3: column 'w_RS_S_z [rad s^-1]': 'x' is not a number"},
      {std::string(kEurocHeader) + row + "2.5e3,0,0,0,0,0,9.8\n",
       "euroc_bad.csv:3: column '#timestamp [ns]': '2.5e3' is not an integer number of "
       "nanoseconds"},
      {std::string(kEurocHeader) + row + row,
       "euroc_bad.csv:3: timestamp 1000 ns does not increase (previous 1000 ns at line 2)"},
      {std::string(kEurocHeader) + row + "2000,0,0,0,0,0\n",
       "euroc_bad.csv:3: expected 7 fields, found 6"},
      {"#timestamp [ns],w_RS_S_x [deg s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
       "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n" +
           row,
       "euroc_bad.csv:1: column 'w_RS_S_x [deg s^-1]': unit 'deg s^-1' is not the EuRoC unit "
       "'rad s^-1'"},
      {"#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
       "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2]\n" +
           row,
       "euroc_bad.csv:1: missing column 'a_RS_S_z [m s^-2]'"},
      {kEurocHeader, "euroc_bad.csv:1: no samples after the header"},
  };
  for (const auto& [text, expected] : cases) {
    SCOPED_TRACE(expected);
    ImportOptions options;
    options.format = "euroc";
    absl::StatusOr<core::Capture> c = ImportText("euroc_bad.csv", text, options);
    ASSERT_FALSE(c.ok());
    EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_THAT(c.status().message(), HasSubstr(expected));
  }
}

TEST(EurocTest, OverridesAndExtraColumns) {
  const std::string text =
      "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
      "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2],temp [C]\n"
      "10,1,2,3,4,5,6,30\n20,1,2,3,4,5,6,30\n";
  ImportOptions options;
  options.device = "drone-3";
  options.gravity_m_s2 = 9.81;
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportText("extra.csv", text, options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->device, "drone-3");
  EXPECT_EQ(c->gravity_m_s2, 9.81);
  EXPECT_EQ(c->gyro[0], Eigen::Vector3d(1, 2, 3));
  EXPECT_EQ(c->accel[0], Eigen::Vector3d(4, 5, 6));
  EXPECT_THAT(report.notes, Contains("ignored columns: 'temp [C]'"));
}

}  // namespace
}  // namespace imucal::importers
