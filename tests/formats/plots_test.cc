// The report plots (formats/plots.h): written from the report JSON of a real calibration of a
// simulated capture with an effect, one SVG per effect plus the per-pose residuals; malformed
// input names the field.
#include "formats/plots.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

#include "core/calibrate/calibrate.h"
#include "core/simulator.h"
#include "formats/report_json.h"

namespace imucal::formats {
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
  // The rotation residuals' trends are in the report too: one per signal the moves carry
  // (rotation angle, time, temperature), each with its unit and a finite slope.
  const nlohmann::json& trends = report["effect_diagnostics"]["move_trends"];
  ASSERT_EQ(trends.size(), 3u) << trends.dump();
  for (const auto& t : trends) {
    EXPECT_TRUE(t["slope"].is_number() && t["stderr"].is_number()) << t.dump();
    EXPECT_EQ(t["unit"].get<std::string>().rfind("deg per ", 0), 0u) << t.dump();
  }
  const std::string dir = testing::TempDir() + "/plots_test";
  std::filesystem::remove_all(dir);
  const absl::StatusOr<std::vector<std::string>> files = WriteReportPlots(report, dir);
  ASSERT_TRUE(files.ok()) << files.status();
  std::map<std::string, std::string> svg;  // file name -> content
  for (const std::string& f : *files) {
    svg[std::filesystem::path(f).filename().string()] = Slurp(f);
    EXPECT_EQ(svg.rbegin()->second.rfind("<svg xmlns=\"http://www.w3.org/2000/svg\"", 0), 0u) << f;
    EXPECT_NE(Slurp(f).find("</svg>\n"), std::string::npos) << f;
  }
  for (const char* name :
       {"residual_stages_per_pose.svg", "coverage.svg", "allan_accel.svg", "allan_gyro.svg",
        "residual_accel_per_pose.svg", "residual_gyro_per_pose.svg", "effect_1_gyro_y_ax.svg"}) {
    EXPECT_EQ(svg.count(name), 1u) << name;
  }
  EXPECT_EQ(files->size(), 7u);
  // Residual plots: two series of markers (before and after), one per used pose each.
  const size_t poses = report["effect_diagnostics"]["poses"].size();
  for (const char* name :
       {"residual_accel_per_pose.svg", "residual_gyro_per_pose.svg", "effect_1_gyro_y_ax.svg"}) {
    EXPECT_EQ(Count(svg[name], "<circle"), static_cast<int>(2 * poses)) << name;
  }
  EXPECT_NE(svg["effect_1_gyro_y_ax.svg"].find("fitted term"), std::string::npos);
  // Stages: a line and a marker per used pose for each stage that ran.
  const size_t stages = report["stages"].size();
  EXPECT_GE(stages, 3u);  // ls, bsas, lm (and effects)
  EXPECT_EQ(Count(svg["residual_stages_per_pose.svg"], "<polyline"), static_cast<int>(stages));
  EXPECT_EQ(Count(svg["residual_stages_per_pose.svg"], "<circle"),
            static_cast<int>(stages * poses));
  EXPECT_NE(svg["residual_stages_per_pose.svg"].find("after lm"), std::string::npos);
  // Coverage: the six faces, then one marker per pose with a direction; the two rims.
  int with_up = 0;
  for (const auto& p : report["poses"]) {
    const double x = p["up"][0], y = p["up"][1], z = p["up"][2];
    with_up += x * x + y * y + z * z > 0;
  }
  EXPECT_EQ(Count(svg["coverage.svg"], "<circle"), 6 + with_up);
  EXPECT_EQ(Count(svg["coverage.svg"], "<polyline"), 2);
  // Allan: log-log, three axes, decade ticks; the fitted figures dashed (N at least, on each
  // axis: the initial rest reaches it).
  const int dashed = Count(svg["allan_gyro.svg"], "stroke-dasharray=\"6 4\"");
  EXPECT_EQ(Count(svg["allan_gyro.svg"], "<polyline") - dashed, 3);
  EXPECT_GE(dashed, 3);
  EXPECT_NE(svg["allan_gyro.svg"].find(">0.1<"), std::string::npos);  // tau decade label
  // Every plot: a caption that says what good looks like, and units on its axes.
  for (const auto& [name, text] : svg) {
    EXPECT_NE(text.find("font-style=\"italic\">Good: "), std::string::npos) << name;
    // Units in brackets on both axes; a pose number (the per-pose plots' x axis) has none.
    if (name != "coverage.svg") {
      EXPECT_GE(Count(text, "["), name.starts_with("residual_") ? 1 : 2) << name;
    }
  }
  EXPECT_NE(svg["effect_1_gyro_y_ax.svg"].find("ax [m/s^2]"), std::string::npos);
  // The per-pose plots: the gates and the noise floor as lines, and the pose numbers.
  for (const char* name : {"residual_accel_per_pose.svg", "residual_stages_per_pose.svg"}) {
    EXPECT_NE(svg[name].find("warn: RMS above 2.0 mg"), std::string::npos) << name;
    EXPECT_NE(svg[name].find("fail: RMS above 5.1 mg"), std::string::npos) << name;
    EXPECT_NE(svg[name].find(">noise floor "), std::string::npos) << name;
  }
  EXPECT_NE(svg["residual_gyro_per_pose.svg"].find(">noise floor "), std::string::npos);
  EXPECT_EQ(Count(svg["residual_accel_per_pose.svg"], "font-size=\"9\""),
            static_cast<int>(poses));
  EXPECT_EQ(Count(svg["coverage.svg"], "font-size=\"9\""), with_up);

  // Each plot renders (rsvg-convert, librsvg) to a valid PNG of the canvas' size, 720 x 460.
  if (std::system("command -v rsvg-convert >/dev/null") != 0) {
    GTEST_SKIP() << "rsvg-convert (librsvg2-bin) not installed";
  }
  for (const std::string& f : *files) {
    SCOPED_TRACE(f);
    const std::string png = f + ".png";
    ASSERT_EQ(std::system(("rsvg-convert -o '" + png + "' '" + f + "'").c_str()), 0);
    std::ifstream in(png, std::ios::binary);
    std::string head(24, '\0');
    ASSERT_TRUE(in.read(head.data(), 24));
    EXPECT_EQ(head.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8));
    EXPECT_EQ(head.substr(12, 4), "IHDR");
    auto be32 = [&](size_t at) {
      uint32_t v = 0;
      for (size_t i = 0; i < 4; ++i) v = v << 8 | static_cast<unsigned char>(head[at + i]);
      return v;
    };
    EXPECT_EQ(be32(16), 720u);
    EXPECT_EQ(be32(20), 460u);
    // More than a blank canvas: a 720 x 460 PNG of one colour compresses to a few hundred bytes.
    EXPECT_GT(std::filesystem::file_size(png), 5000u);
  }
}

// A rate term (found on the moves, core/move_effects.h) does nothing at rest: its plot is each
// move's held-out gravity-direction error without and with it, and its file name spells `|gz|`
// as `absgz`.
TEST(PlotsTest, RateTermIsPlottedOnTheMoves) {
  const nlohmann::json report = {
      {"effect_diagnostics",
       {{"poses", nlohmann::json::array()},
        {"move_search",
         {{"noise_floor", 0.0007},
          {"heldout_before_per_move", {0.002, 0.0031, 0.0009}},
          {"heldout_after_per_move", {0.0008, 0.0009, 0.0008}}}}}},
      {"effects",
       {{{"sensor", "gyro"}, {"axis", "z"}, {"regressor", "gz*|gz|"}, {"coefficient", 5.7e-4},
         {"error_before", nullptr}, {"error_after", nullptr}}}}};
  const std::string dir = testing::TempDir() + "/plots_test_rate";
  std::filesystem::remove_all(dir);
  const absl::StatusOr<std::vector<std::string>> files = WriteReportPlots(report, dir);
  ASSERT_TRUE(files.ok()) << files.status();
  const std::string path = dir + "/effect_1_gyro_z_gzxabsgz.svg";
  ASSERT_TRUE(std::filesystem::exists(path));
  const std::string svg = Slurp(path);
  EXPECT_NE(svg.find("on the moves"), std::string::npos);
  EXPECT_NE(svg.find("move number"), std::string::npos);
  EXPECT_EQ(Count(svg, "<circle"), 6) << svg;  // 3 moves, without and with
}

TEST(PlotsTest, NoDiagnosticsNoPlotsAndMalformedEffectIsNamed) {
  const std::string dir = testing::TempDir() + "/plots_test_bad";
  auto none = WriteReportPlots(nlohmann::json::object(), dir);
  ASSERT_TRUE(none.ok());
  EXPECT_TRUE(none->empty());
  auto r0 = WriteReportPlots({{"allan", {{"tau", {1, 2}}, {"accel", {{1, 2, 3}}}}}}, dir);
  ASSERT_FALSE(r0.ok());
  EXPECT_NE(r0.status().message().find("allan.accel"), std::string::npos) << r0.status();
  r0 = WriteReportPlots({{"poses", {{{"up", {1, 0}}}}}}, dir);
  ASSERT_FALSE(r0.ok());
  EXPECT_NE(r0.status().message().find("poses[0].up"), std::string::npos) << r0.status();
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
}  // namespace imucal::formats
