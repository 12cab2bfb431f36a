// The offline CLI commands driven in-process: simulate -> calibrate -> apply round trips in a
// temporary directory, the documented exit codes, and the JSON report's keys (report.md).
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/strings/str_cat.h"
#include "client/cli/commands.h"
#include "client/cli/noise_source.h"
#include "core/capture.h"
#include "core/simulator.h"
#include "core/validation.h"
#include "formats/params_json.h"
#include "importers/imucal_csv.h"
#include "nlohmann/json.hpp"

namespace imucal::cli {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr double kMg = 1e-3 * core::kStandardGravity;

// A directory of its own per test: ctest runs the tests of this binary in parallel processes.
class CliTest : public testing::Test {
 protected:
  void SetUp() override {
    const testing::TestInfo* info = testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::path(testing::TempDir()) /
           absl::StrCat("imucal_cli_test_", info->name(), "_", ::getpid());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string Path(const std::string& name) const { return (dir_ / name).string(); }

  // Runs a command, keeping what it printed.
  int Run(int (*command)(const std::vector<std::string>&), const std::vector<std::string>& args) {
    testing::internal::CaptureStdout();
    testing::internal::CaptureStderr();
    const int code = command(args);
    out_ = testing::internal::GetCapturedStdout();
    err_ = testing::internal::GetCapturedStderr();
    return code;
  }

  static std::string ReadText(const std::string& path) {
    std::ifstream f(path, std::ios::binary);
    std::stringstream ss;
    ss << f.rdbuf();
    return ss.str();
  }
  static void WriteText(const std::string& path, const std::string& text) {
    std::ofstream f(path, std::ios::binary);
    f << text;
  }

  fs::path dir_;
  std::string out_, err_;
};

// The simulator options that `imucal simulate --seed S --extra-poses N [--accel-noise 0
// --gyro-noise 0]` uses (the CLI's defaults are the SimOptions defaults).
core::SimOptions CliSimOptions(uint64_t seed, int extra_poses, bool noise) {
  core::SimOptions o;
  o.seed = seed;
  o.extra_poses = extra_poses;
  if (!noise) o.accel_noise_m_s2 = o.gyro_noise_rad_s = 0;
  return o;
}

// A small valid capture with a non-numeric value on line `bad_line` (1-based, counting the
// header), column az.
std::string CaptureWithBadValue(int bad_line) {
  std::string text =
      "# imucal-capture v1\n"   // line 1
      "# accel_unit=m/s^2\n"    // line 2
      "# gyro_unit=rad/s\n"     // line 3
      "t,ax,ay,az,gx,gy,gz\n";  // line 4
  for (int line = 5; line <= 20; ++line) {
    const double t = 0.01 * (line - 5);
    text += absl::StrCat(t, ",0.01,-0.02,", line == bad_line ? "abc" : "9.81", ",0.001,0,0\n");
  }
  return text;
}

// ---------------------------------------------------------------------------------------------
// Round trip.

TEST_F(CliTest, SimulateCalibrateApplyRoundTrip) {
  const std::string capture = Path("capture.csv"), report = Path("report.json"),
                    params = Path("params.json"), truth = Path("truth.json");
  ASSERT_EQ(
      Run(RunSimulate, {"--out", capture, "--seed", "5", "--extra-poses", "24", "--truth", truth}),
      kExitOk)
      << err_;
  EXPECT_NE(out_.find(capture), std::string::npos) << out_;
  ASSERT_TRUE(fs::exists(capture));
  ASSERT_TRUE(fs::exists(truth));

  ASSERT_EQ(Run(RunCalibrate, {capture, "--json", "--out", report, "--params-out", params}),
            kExitOk)
      << err_;
  // --json prints exactly what --out writes.
  ASSERT_TRUE(fs::exists(report));
  EXPECT_EQ(out_, ReadText(report));
  const json j = json::parse(ReadText(report));
  EXPECT_EQ(j["verdict"], "pass");

  // --params-out holds the report's parameter set; both load in the SDK.
  const absl::StatusOr<core::ParamSet> from_report = formats::ParamSetFromJson(ReadText(report));
  const absl::StatusOr<core::ParamSet> from_params = formats::ParamSetFromJson(ReadText(params));
  ASSERT_TRUE(from_report.ok()) << from_report.status();
  ASSERT_TRUE(from_params.ok()) << from_params.status();
  EXPECT_EQ(from_report->accel.bias, from_params->accel.bias);
  EXPECT_EQ(from_report->gyro.matrix, from_params->gyro.matrix);
  EXPECT_EQ(json::parse(ReadText(params)), j["parameters"]);

  // Apply the report to a noise-free capture of the same unit (same seed: same truth and poses).
  const std::string clean = Path("clean.csv"), calibrated = Path("calibrated.csv");
  ASSERT_EQ(Run(RunSimulate, {"--out", clean, "--seed", "5", "--extra-poses", "24", "--accel-noise",
                              "0", "--gyro-noise", "0"}),
            kExitOk)
      << err_;
  ASSERT_EQ(Run(RunApply, {"--params", report, clean, calibrated}), kExitOk) << err_;
  EXPECT_NE(out_.find(calibrated), std::string::npos) << out_;

  const absl::StatusOr<core::Capture> in = importers::ReadImucalCsvFile(clean);
  const absl::StatusOr<core::Capture> out = importers::ReadImucalCsvFile(calibrated);
  ASSERT_TRUE(in.ok()) << in.status();
  ASSERT_TRUE(out.ok()) << out.status();
  EXPECT_EQ(out->accel_unit, core::AccelUnit::kMetersPerSecond2);
  EXPECT_EQ(out->gyro_unit, core::GyroUnit::kRadPerSecond);
  ASSERT_EQ(out->size(), in->size());
  EXPECT_EQ(out->t_s, in->t_s);                        // t kept exactly
  EXPECT_EQ(out->temp, in->temp);                      // temp kept exactly
  EXPECT_EQ(out->extra_metadata, in->extra_metadata);  // header metadata kept

  const absl::StatusOr<core::SimResult> sim = core::Simulate(CliSimOptions(5, 24, false));
  ASSERT_TRUE(sim.ok()) << sim.status();
  ASSERT_EQ(sim->true_accel_m_s2.size(), out->size());
  const double accel_error = core::VectorRmsError(out->accel, sim->true_accel_m_s2, true);
  const double gyro_error = core::VectorRmsError(out->gyro, sim->true_gyro_rad_s, true);
  std::vector<Eigen::Vector3d> nominal_gyro = in->gyro;  // rad/s input: nominal = raw
  const double gyro_nominal_error = core::VectorRmsError(nominal_gyro, sim->true_gyro_rad_s, true);
  std::printf("round trip: accel %.4f mg, gyro %.3g rad/s (uncalibrated %.3g rad/s)\n",
              accel_error / kMg, gyro_error, gyro_nominal_error);
  EXPECT_LT(accel_error, 0.3 * kMg);
  EXPECT_LT(gyro_error, 0.02 * gyro_nominal_error);  // at least 50 times better than nominal
}

TEST_F(CliTest, ApplyRejectsParametersForOtherUnits) {
  const std::string capture = Path("capture.csv"), params = Path("params.json");
  ASSERT_EQ(Run(RunSimulate, {"--out", capture, "--seed", "6", "--extra-poses", "12"}), kExitOk)
      << err_;
  ASSERT_EQ(Run(RunCalibrate, {capture, "--params-out", params, "--no-heldout"}), kExitOk) << err_;
  // The summary (no --json) is for people: it is not JSON and names the verdict.
  EXPECT_NE(out_.find("verdict     pass"), std::string::npos) << out_;
  EXPECT_FALSE(json::accept(out_));
  // ... and states the Allan figures of the parameter set's noise block, units spelt out: the
  // accelerometer's x density as written to params.json, and the random walk, which a short
  // simulated rest does not reach, as a labelled upper bound.
  {
    absl::StatusOr<core::ParamSet> written = formats::ParamSetFromJson(ReadText(params));
    ASSERT_TRUE(written.ok()) << written.status();
    ASSERT_TRUE(written->noise.has_value());
    char density[32];
    std::snprintf(density, sizeof density, "accel N   [%.3g, ",
                  written->noise->accel.noise_density.x());
    EXPECT_NE(out_.find(density), std::string::npos) << density << "\n" << out_;
    for (const char* text : {"m/s^2/sqrt(Hz)  white-noise density", "m/s^2  bias instability",
                             "m/s^3/sqrt(Hz)  rate random walk",
                             "rad/s/sqrt(Hz)  white-noise density", "rad/s  bias instability",
                             "rad/s^2/sqrt(Hz)  rate random walk", "UPPER BOUND, not reached"}) {
      EXPECT_NE(out_.find(text), std::string::npos) << text << "\n" << out_;
    }
    if (written->noise->accel.random_walk.array().isNaN().all()) {
      std::snprintf(density, sizeof density, "accel K   [<%.3g, ",
                    written->noise->accel.random_walk_bound.x());
      EXPECT_NE(out_.find(density), std::string::npos) << density << "\n" << out_;
    }
  }

  // A capture in counts cannot take parameters for m/s^2.
  const std::string counts = Path("counts.csv"), out = Path("out.csv");
  ASSERT_EQ(Run(RunSimulate, {"--out", counts, "--seed", "6", "--accel-unit", "counts",
                              "--gyro-unit", "counts"}),
            kExitOk)
      << err_;
  EXPECT_EQ(Run(RunApply, {"--params", params, counts, out}), kExitBadInput);
  EXPECT_NE(err_.find("units differ"), std::string::npos) << err_;
  EXPECT_FALSE(fs::exists(out));
}

// ---------------------------------------------------------------------------------------------
// Bad input: exit 2, the message names file and line, nothing written.

TEST_F(CliTest, CalibrateNonNumericValueNamesFileAndLine) {
  const std::string bad = Path("bad.csv"), report = Path("report.json");
  WriteText(bad, CaptureWithBadValue(9));
  EXPECT_EQ(Run(RunCalibrate, {bad, "--json", "--out", report}), kExitBadInput);
  EXPECT_NE(err_.find("bad.csv:9:"), std::string::npos) << err_;
  EXPECT_NE(err_.find("abc"), std::string::npos) << err_;
  EXPECT_NE(err_.find("az"), std::string::npos) << err_;
  EXPECT_EQ(err_.rfind("imucal: ", 0), 0u) << err_;
  EXPECT_TRUE(out_.empty()) << out_;
  EXPECT_FALSE(fs::exists(report));
}

TEST_F(CliTest, ApplyNonNumericValueNamesFileAndLineAndWritesNothing) {
  const std::string capture = Path("capture.csv"), params = Path("params.json");
  ASSERT_EQ(Run(RunSimulate, {"--out", capture, "--seed", "7", "--extra-poses", "12"}), kExitOk)
      << err_;
  ASSERT_EQ(Run(RunCalibrate, {capture, "--params-out", params, "--no-heldout"}), kExitOk) << err_;
  const std::string bad = Path("bad.csv"), out = Path("out.csv");
  WriteText(bad, CaptureWithBadValue(13));
  EXPECT_EQ(Run(RunApply, {"--params", params, bad, out}), kExitBadInput);
  EXPECT_NE(err_.find("bad.csv:13:"), std::string::npos) << err_;
  EXPECT_FALSE(fs::exists(out));
  EXPECT_FALSE(fs::exists(out + ".tmp"));
}

TEST_F(CliTest, MissingOrMalformedFilesAreBadInput) {
  const std::string missing = Path("nope.csv");
  EXPECT_EQ(Run(RunCalibrate, {missing}), kExitBadInput);
  EXPECT_NE(err_.find("nope.csv"), std::string::npos) << err_;

  // A parameter file that is not JSON: exit 2, the message names the parameter file.
  const std::string capture = Path("capture.csv"), params = Path("params.json"),
                    out = Path("out.csv");
  WriteText(capture, CaptureWithBadValue(0));  // valid: no bad line
  WriteText(params, "{ not json");
  EXPECT_EQ(Run(RunApply, {"--params", params, capture, out}), kExitBadInput);
  EXPECT_NE(err_.find("params.json"), std::string::npos) << err_;
  EXPECT_FALSE(fs::exists(out));

  EXPECT_EQ(Run(RunApply, {"--params", Path("absent.json"), capture, out}), kExitBadInput);
  EXPECT_NE(err_.find("absent.json"), std::string::npos) << err_;
  EXPECT_FALSE(fs::exists(out));
}

// ---------------------------------------------------------------------------------------------
// Usage errors: exit 1, naming the flag.

TEST_F(CliTest, UnknownFlagIsUsageError) {
  EXPECT_EQ(Run(RunCalibrate, {"x.csv", "--bogus"}), kExitUsage);
  EXPECT_NE(err_.find("--bogus"), std::string::npos) << err_;
  EXPECT_NE(err_.find("usage: imucal calibrate"), std::string::npos) << err_;
  EXPECT_EQ(Run(RunApply, {"--params", "p.json", "a.csv", "b.csv", "--bogus"}), kExitUsage);
  EXPECT_NE(err_.find("--bogus"), std::string::npos) << err_;
  EXPECT_EQ(Run(RunSimulate, {"--out", Path("s.csv"), "--bogus"}), kExitUsage);
  EXPECT_NE(err_.find("--bogus"), std::string::npos) << err_;
  EXPECT_FALSE(fs::exists(Path("s.csv")));
}

TEST_F(CliTest, MissingArgumentsAndBadValuesAreUsageErrors) {
  EXPECT_EQ(Run(RunCalibrate, {}), kExitUsage);
  EXPECT_EQ(Run(RunCalibrate, {"x.csv", "--seed", "abc"}), kExitUsage);
  EXPECT_NE(err_.find("--seed"), std::string::npos) << err_;
  EXPECT_EQ(Run(RunCalibrate, {"x.csv", "--protocol", "sixface"}), kExitUsage);
  EXPECT_NE(err_.find("sixface"), std::string::npos) << err_;
  EXPECT_EQ(Run(RunCalibrate, {"x.csv", "--out"}), kExitUsage);  // --out needs a value
  EXPECT_EQ(Run(RunApply, {"a.csv", "b.csv"}), kExitUsage);      // no --params
  EXPECT_NE(err_.find("--params"), std::string::npos) << err_;
  EXPECT_EQ(Run(RunApply, {"--params", "p.json", "b.csv"}), kExitUsage);  // no OUT
  EXPECT_EQ(Run(RunSimulate, {}), kExitUsage);                            // no --out
  EXPECT_EQ(Run(RunSimulate, {"--out", Path("s.csv"), "--protocol", "hexagon"}), kExitUsage);
  EXPECT_FALSE(fs::exists(Path("s.csv")));
  EXPECT_EQ(Run(RunCalibrate, {"--help"}), kExitOk);
  EXPECT_NE(out_.find("exit codes"), std::string::npos) << out_;
}

// A refusal is exit 3 with the reason on stderr, and with --out it still writes the report:
// verdict refused, every pose found with why it is or is not usable, no parameters to apply.
TEST_F(CliTest, TooFewPosesIsExitThreeAndStillWritesTheReport) {
  const std::string capture = Path("few.csv"), report = Path("report.json");
  ASSERT_EQ(Run(RunSimulate, {"--out", capture, "--protocol", "free", "--free-poses", "5"}),
            kExitOk)
      << err_;
  EXPECT_EQ(Run(RunCalibrate, {capture, "--out", report, "--params-out", Path("p.json")}),
            kExitUndetermined);
  EXPECT_NE(err_.find("10 distinct orientations"), std::string::npos) << err_;
  ASSERT_TRUE(fs::exists(report));
  const json j = json::parse(ReadText(report));
  EXPECT_EQ(j.at("verdict"), "refused");
  EXPECT_EQ(j.at("refusal").at("reason"), "too_few_orientations");
  EXPECT_FALSE(j.contains("parameters"));
  EXPECT_FALSE(fs::exists(Path("p.json")));  // nothing to apply
  int used = 0;
  for (const auto& p : j.at("poses")) {
    used += p.at("used").get<bool>();
    EXPECT_TRUE(p.at("used").get<bool>() || !p.at("reason").get<std::string>().empty()) << p;
  }
  EXPECT_EQ(used, 5);
  // --json prints the same report on stdout.
  EXPECT_EQ(Run(RunCalibrate, {capture, "--json"}), kExitUndetermined);
  EXPECT_EQ(json::parse(out_).at("verdict"), "refused");
}

// ---------------------------------------------------------------------------------------------
// The JSON report carries the keys of report.md.

TEST_F(CliTest, JsonReportHasTheDocumentedKeys) {
  const std::string capture = Path("capture.csv"), report = Path("report.json");
  ASSERT_EQ(Run(RunSimulate, {"--out", capture, "--seed", "8", "--extra-poses", "24"}), kExitOk)
      << err_;
  ASSERT_EQ(Run(RunCalibrate, {capture, "--json", "--out", report, "--device", "robot-0042"}),
            kExitOk)
      << err_;
  const json j = json::parse(ReadText(report));

  EXPECT_EQ(j.at("format"), "imucal-report v1");
  EXPECT_EQ(j.at("device"), "robot-0042");
  EXPECT_TRUE(j.at("gravity").is_number());

  ASSERT_TRUE(j.at("poses").is_array());
  // Every static interval, used or not: at least the 12 six-face poses and the 24 extra ones.
  EXPECT_GE(j["poses"].size(), 36u);
  int used = 0;
  double previous_start = -1;
  for (const json& p : j["poses"]) {
    used += p.at("used").get<bool>();
    EXPECT_TRUE(p.at("index").is_number_integer());
    EXPECT_TRUE(p.at("used").is_boolean());
    EXPECT_TRUE(p.at("reason").is_string());
    if (!p["used"].get<bool>()) {
      EXPECT_FALSE(p["reason"].get<std::string>().empty());
    }
    EXPECT_GT(p.at("t_start").get<double>(), previous_start);  // time order
    previous_start = p["t_start"].get<double>();
    EXPECT_GT(p.at("t_end").get<double>(), previous_start);
    EXPECT_TRUE(p.at("samples").is_number_integer());
    EXPECT_EQ(p.at("accel_mean").size(), 3u);
    EXPECT_EQ(p.at("gyro_mean").size(), 3u);
    EXPECT_TRUE(p.contains("temp_mean"));
  }
  EXPECT_EQ(used, 36);

  ASSERT_TRUE(j.at("pairs").is_array());
  EXPECT_EQ(j["pairs"].size(), 6u);
  for (const json& p : j["pairs"]) {
    ASSERT_EQ(p.at("poses").size(), 2u);
    EXPECT_TRUE(p["poses"][0].is_number_integer());
    EXPECT_EQ(p.at("status"), "ok");
    EXPECT_TRUE(p.at("tilt_deg").is_number());
    EXPECT_NEAR(p.at("rotation_deg").get<double>(), 180, 20);
    EXPECT_TRUE(p.at("reason").is_string());
  }

  ASSERT_TRUE(j.at("stages").is_array());
  std::vector<std::string> names;
  for (const json& s : j["stages"]) {
    names.push_back(s.at("name").get<std::string>());
    EXPECT_GE(s.at("accel_rms").get<double>(), 0.0);
    EXPECT_TRUE(s.at("iterations").is_number_integer());
    EXPECT_TRUE(s.at("ms").is_number());
  }
  EXPECT_EQ(names, (std::vector<std::string>{"ls", "bsas", "lm"}));

  const json& residual = j.at("residual");
  EXPECT_GT(residual.at("accel_rms").get<double>(), 0.0);
  EXPECT_GE(residual.at("accel_max").get<double>(), residual["accel_rms"].get<double>());
  EXPECT_TRUE(residual.at("gyro_static_rms").is_number());
  EXPECT_DOUBLE_EQ(residual["accel_rms"].get<double>(),
                   j["stages"].back()["accel_rms"].get<double>());

  EXPECT_TRUE(j.at("effects").is_array());
  const json& parameters = j.at("parameters");
  EXPECT_EQ(parameters.at("format"), "imucal-params v1");
  EXPECT_EQ(parameters.at("device"), "robot-0042");
  EXPECT_TRUE(parameters.at("model").is_string());
  EXPECT_TRUE(parameters.at("accel").is_object());
  EXPECT_TRUE(parameters.at("gyro").is_object());
  EXPECT_TRUE(parameters.at("quality").at("accel_rms").is_number());
  EXPECT_TRUE(parameters.at("source").at("software").get<std::string>().rfind("imucal ", 0) == 0);

  const std::string verdict = j.at("verdict").get<std::string>();
  EXPECT_TRUE(verdict == "pass" || verdict == "warn" || verdict == "fail") << verdict;
  ASSERT_TRUE(j.at("warnings").is_array());
  for (const json& w : j["warnings"]) EXPECT_TRUE(w.is_string());
}

// ---------------------------------------------------------------------------------------------
// `imucal noise` checks its rest (core/noise_rest.h).

int NoiseOfFiles(const std::vector<std::string>& args) { return RunNoiseWith(args, nullptr); }

// A rest of `seconds` at 100 Hz (white noise, gravity on z), with `handling_s` of motion from
// `handling_at_s` after which the unit reads 0.2 m/s^2 more on x (set down turned).
core::Capture RestCapture(double seconds, double handling_at_s, double handling_s) {
  std::mt19937_64 rng(81);
  std::normal_distribution<double> a(0.0, 0.02), g(0.0, 0.002);
  core::Capture c;
  for (int i = 0; i < static_cast<int>(seconds * 100); ++i) {
    const double t = i / 100.0;
    Eigen::Vector3d acc(a(rng), a(rng), core::kStandardGravity + a(rng));
    Eigen::Vector3d gyr(g(rng), g(rng), g(rng));
    if (t >= handling_at_s && t < handling_at_s + handling_s) {
      acc += Eigen::Vector3d::Constant(3 * std::sin(2 * M_PI * t));
      gyr += Eigen::Vector3d::Constant(1.5 * std::cos(2 * M_PI * t));
    } else if (t >= handling_at_s + handling_s) {
      acc.x() += 0.2;
    }
    c.t_s.push_back(t);
    c.accel.push_back(acc);
    c.gyro.push_back(gyr);
  }
  return c;
}

TEST_F(CliTest, NoiseRefusesAMovingRecord) {
  const std::string capture = Path("moving.csv");
  core::SimOptions o = CliSimOptions(7, 0, true);
  o.initial_rest_s = 5;  // a calibration capture: 5 s first rest, 4 s holds, moves between
  ASSERT_TRUE(importers::WriteImucalCsvFile(core::Simulate(o)->capture, capture).ok());
  EXPECT_EQ(Run(NoiseOfFiles, {capture, "--out", Path("out")}), kExitUndetermined) << out_;
  EXPECT_EQ(err_.rfind("imucal: the record is not at rest: ", 0), 0u) << err_;
  EXPECT_FALSE(fs::exists(Path("out/imu.yaml")));
}

TEST_F(CliTest, NoiseCutsHandlingOutAndSaysSo) {
  const std::string whole = Path("rest.csv"), handled = Path("handled.csv");
  ASSERT_TRUE(importers::WriteImucalCsvFile(RestCapture(120, 1e9, 0), whole).ok());
  ASSERT_TRUE(importers::WriteImucalCsvFile(RestCapture(120, 50, 5), handled).ok());
  ASSERT_EQ(Run(NoiseOfFiles, {whole, "--json"}), kExitOk) << err_;
  const json w = json::parse(out_);
  EXPECT_TRUE(w["rest"]["whole"].get<bool>()) << w["rest"];
  EXPECT_EQ(w["samples"], 12000);
  ASSERT_EQ(Run(NoiseOfFiles, {handled, "--json", "--out", Path("out")}), kExitOk) << err_;
  const json h = json::parse(out_);
  EXPECT_FALSE(h["rest"]["whole"].get<bool>());
  EXPECT_EQ(h["rest"]["segments"].size(), 2u) << h["rest"];
  EXPECT_NEAR(h["rest"]["cut_s"].get<double>(), 5.0, 1.5) << h["rest"];
  EXPECT_NE(h["notes"][0].get<std::string>().find("cut"), std::string::npos) << h["notes"];
  EXPECT_EQ(json::parse(ReadText(Path("out/noise.json")))["rest"], h["rest"]);
  // The accel x white-noise density is the untouched rest's, not the handling's.
  const double n_whole = w["axes"]["accel_x"]["noise_density"]["value"].get<double>();
  const double n_handled = h["axes"]["accel_x"]["noise_density"]["value"].get<double>();
  EXPECT_NEAR(n_handled / n_whole, 1.0, 0.05);
  ASSERT_EQ(Run(NoiseOfFiles, {handled}), kExitOk) << err_;
  EXPECT_NE(out_.find("s cut"), std::string::npos) << out_;
}

// The report records the units it was read in and how each was decided.
TEST_F(CliTest, CalibrateJsonRecordsTheInputUnits) {
  const std::string capture = Path("capture.csv");
  ASSERT_EQ(Run(RunSimulate, {"--out", capture, "--seed", "8", "--extra-poses", "4"}), kExitOk)
      << err_;
  ASSERT_EQ(Run(RunCalibrate, {capture, "--json", "--gyro-unit", "rad/s"}), kExitOk) << err_;
  const json r = json::parse(out_);
  EXPECT_EQ(r["input_units"], json({{"accel", "m/s^2"},
                                    {"gyro", "rad/s"},
                                    {"accel_source", "file"},
                                    {"gyro_source", "declared"}}));
}

}  // namespace
}  // namespace imucal::cli
