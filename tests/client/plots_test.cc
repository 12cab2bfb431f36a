// The report plots (client/cli/plots.h): written from the report JSON of a real calibration of a
// simulated capture with an effect, one SVG per effect plus the per-pose residuals; malformed
// input names the field.
#include "client/cli/plots.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "client/cli/report_json.h"
#include "core/calibrate.h"
#include "core/simulator.h"

namespace imucal::cli {
namespace {

std::string Slurp(const std::string& path) {
  std::ifstream f(path);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

int Count(const std::string& s, const std::string& what) {
  int n = 0;
  for (size_t p = s.find(what); p != std::string::npos; p = s.find(what, p + 1)) ++n;
  return n;
}

TEST(PlotsTest, OneSvgPerEffectAndPerPoseResiduals) {
  core::SimOptions o;
  o.seed = 3;
  o.extra_poses = 24;
  o.effects = {{core::Sensor::kGyro, 1, "ax", 0.05 * M_PI / 180 / core::kStandardGravity}};
  const absl::StatusOr<core::SimResult> sim = core::Simulate(o);
  ASSERT_TRUE(sim.ok());
  const absl::StatusOr<core::CalibrationReport> rep = core::Calibrate(sim->capture, {});
  ASSERT_TRUE(rep.ok()) << rep.status();
  ASSERT_EQ(rep->params.effects.size(), 1u);
  const nlohmann::json report = nlohmann::json::parse(ReportToJson(*rep));
  const std::string dir = testing::TempDir() + "/plots_test";
  std::filesystem::remove_all(dir);
  const absl::StatusOr<std::vector<std::string>> files = WriteReportPlots(report, dir);
  ASSERT_TRUE(files.ok()) << files.status();
  ASSERT_EQ(files->size(), 3u);
  const size_t poses = report["effect_diagnostics"]["poses"].size();
  for (const std::string& f : *files) {
    const std::string svg = Slurp(f);
    EXPECT_EQ(svg.rfind("<svg xmlns=\"http://www.w3.org/2000/svg\"", 0), 0u) << f;
    EXPECT_NE(svg.find("</svg>\n"), std::string::npos) << f;
    // Two series of markers (before and after), one per used pose each.
    EXPECT_EQ(Count(svg, "<circle"), static_cast<int>(2 * poses)) << f;
  }
  EXPECT_NE((*files)[2].find("effect_1_gyro_y_ax.svg"), std::string::npos);
  EXPECT_NE(Slurp((*files)[2]).find("fitted term"), std::string::npos);
}

TEST(PlotsTest, NoDiagnosticsNoPlotsAndMalformedEffectIsNamed) {
  const std::string dir = testing::TempDir() + "/plots_test_bad";
  auto none = WriteReportPlots(nlohmann::json::object(), dir);
  ASSERT_TRUE(none.ok());
  EXPECT_TRUE(none->empty());
  nlohmann::json bad = {{"effect_diagnostics", {{"poses", nlohmann::json::array()}}},
                        {"effects", {{{"sensor", "accel"}, {"axis", "w"}, {"regressor", "ax"}}}}};
  auto r = WriteReportPlots(bad, dir);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("effects[0]"), std::string::npos) << r.status();
  bad["effect_diagnostics"]["poses"] = 3;
  r = WriteReportPlots(bad, dir);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("effect_diagnostics.poses"), std::string::npos);
}

}  // namespace
}  // namespace imucal::cli
