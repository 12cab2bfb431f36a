// The CLI's server commands driven in-process against a real imucald (skipped until the server
// is built): register -> session -> upload (resumable) -> solve -> report -> params -> export,
// the JSON outputs scripts read, and the exit code for an unreachable server.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "client/cli/commands.h"
#include "client/cli/server_common.h"
#include "core/simulator.h"
#include "formats/params_json.h"
#include "grpcpp/grpcpp.h"
#include "importers/imucal_csv.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "nlohmann/json.hpp"
#include "tests/client/imucald_process.h"
#include "yaml-cpp/yaml.h"

namespace imucal::cli {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

class CliServerTest : public testing_util::ImucaldTest {
 protected:
  CliServerTest() : ImucaldTest("imucal_cli_server_test") {}

  int Run(int (*command)(const std::vector<std::string>&), std::vector<std::string> args) {
    args.insert(args.begin(), {"--server", server_->address()});
    testing::internal::CaptureStdout();
    testing::internal::CaptureStderr();
    const int code = command(args);
    out_ = testing::internal::GetCapturedStdout();
    err_ = testing::internal::GetCapturedStderr();
    return code;
  }

  std::string WriteSimulatedCapture(uint64_t seed) {
    core::SimOptions sim;
    sim.seed = seed;
    auto r = core::Simulate(sim);
    EXPECT_TRUE(r.ok()) << r.status();
    const std::string path = (dir_ / absl::StrCat("capture", seed, ".csv")).string();
    EXPECT_TRUE(importers::WriteImucalCsvFile(r->capture, path).ok());
    return path;
  }

  void Register(const std::string& device) {
    ASSERT_EQ(Run(RunDevices, {"register", device, "--sensor-model", "sim", "--rate", "200",
                               "--accel-unit", "m/s^2", "--gyro-unit", "rad/s"}),
              kExitOk)
        << err_;
  }

  std::string out_, err_;
};

TEST_F(CliServerTest, RegisterListAndShowDevices) {
  Register("robot-cli-1");
  Register("robot-cli-1");  // the same metadata again is a no-op
  ASSERT_EQ(Run(RunDevices, {"--json"}), kExitOk) << err_;
  json j = json::parse(out_);
  ASSERT_EQ(j["devices"].size(), 1u) << out_;
  EXPECT_EQ(j["devices"][0]["id"], "robot-cli-1");
  ASSERT_EQ(Run(RunDevices, {"get", "robot-cli-1"}), kExitOk) << err_;
  EXPECT_NE(out_.find("robot-cli-1"), std::string::npos);
  EXPECT_EQ(Run(RunDevices, {"get", "robot-none"}), kExitBadInput);
  EXPECT_NE(err_.find("robot-none"), std::string::npos) << err_;
}

TEST_F(CliServerTest, SessionStartListCancel) {
  Register("robot-cli-2");
  ASSERT_EQ(
      Run(RunSession, {"start", "--device", "robot-cli-2", "--protocol", "six-face", "--json"}),
      kExitOk)
      << err_;
  const std::string id = json::parse(out_)["id"];
  EXPECT_EQ(Run(RunSession, {"start", "--device", "robot-cli-2"}), kExitUndetermined)
      << "a second open session must be refused: " << out_;
  ASSERT_EQ(Run(RunSession, {"list", "--device", "robot-cli-2"}), kExitOk) << err_;
  EXPECT_NE(out_.find(id), std::string::npos) << out_;
  ASSERT_EQ(Run(RunSession, {"cancel", id}), kExitOk) << err_;
  EXPECT_NE(out_.find("cancelled"), std::string::npos) << out_;
}

TEST_F(CliServerTest, UploadSolveReportParamsExport) {
  Register("robot-cli-3");
  const std::string capture = WriteSimulatedCapture(5);
  ASSERT_EQ(
      Run(RunUpload, {capture, "--device", "robot-cli-3", "--protocol", "six-face", "--solve"}),
      kExitOk)
      << out_ << err_;
  EXPECT_NE(out_.find("uploaded"), std::string::npos) << out_;
  EXPECT_NE(out_.find("verdict"), std::string::npos) << out_;
  ASSERT_EQ(Run(RunSession, {"list", "--device", "robot-cli-3", "--json"}), kExitOk) << err_;
  const std::string session = json::parse(out_)["sessions"][0]["id"];

  ASSERT_EQ(Run(RunReport, {"--session", session, "--json"}), kExitOk) << err_;
  json report = json::parse(out_);
  EXPECT_EQ(report["format"], "imucal-report v1");
  ASSERT_EQ(Run(RunReport, {"--session", session}), kExitOk) << err_;
  EXPECT_NE(out_.find("verdict"), std::string::npos) << out_;
  // The summary states the Allan figures of the stored parameter set's noise block, units spelt
  // out (the accelerometer's x density as the report holds it).
  {
    const json& noise = report["parameters"]["noise"];
    ASSERT_TRUE(noise.is_object()) << report.dump(2);
    char density[48];
    std::snprintf(density, sizeof density, "accel N   [%.3g, ",
                  noise["accel"]["noise_density"][0].get<double>());
    EXPECT_NE(out_.find(density), std::string::npos) << density << "\n" << out_;
    for (const char* text :
         {"m/s^2/sqrt(Hz)  white-noise density", "m/s^3/sqrt(Hz)  rate random walk",
          "rad/s/sqrt(Hz)  white-noise density", "rad/s^2/sqrt(Hz)  rate random walk",
          "m/s^2  bias instability", "rad/s  bias instability"}) {
      EXPECT_NE(out_.find(text), std::string::npos) << text << "\n" << out_;
    }
  }
  // --out DIR: the stored report as is, the summary as printed, and the plots.
  const fs::path report_dir = dir_ / "report";
  ASSERT_EQ(Run(RunReport, {"--session", session, "--out", report_dir.string()}), kExitOk) << err_;
  const std::string printed = out_;
  for (const char* name :
       {"report.json", "summary.txt", "residual_stages_per_pose.svg", "coverage.svg",
        "allan_accel.svg", "allan_gyro.svg", "residual_accel_per_pose.svg"}) {
    EXPECT_TRUE(fs::exists(report_dir / name)) << name << "\n" << err_;
  }
  {
    std::ifstream f(report_dir / "summary.txt");
    std::stringstream text;
    text << f.rdbuf();
    EXPECT_EQ(text.str(), printed);
    std::ifstream rj(report_dir / "report.json");
    EXPECT_EQ(json::parse(rj), report);
  }

  ASSERT_EQ(Run(RunParams, {"get", "--device", "robot-cli-3", "--version", "1", "--json"}), kExitOk)
      << err_;
  EXPECT_EQ(json::parse(out_)["format"], "imucal-params v1");
  // Whether a version activates by itself is the server's gates' call; promote it either way.
  ASSERT_EQ(Run(RunParams, {"promote", "--device", "robot-cli-3", "--version", "1"}), kExitOk)
      << err_;
  EXPECT_NE(out_.find("robot-cli-3 v1 is now active"), std::string::npos) << out_;
  ASSERT_EQ(Run(RunParams, {"get", "--device", "robot-cli-3"}), kExitOk) << err_;
  EXPECT_NE(out_.find("accel bias"), std::string::npos) << out_;
  ASSERT_EQ(Run(RunParams, {"list", "--device", "robot-cli-3"}), kExitOk) << err_;
  EXPECT_NE(out_.find("v1"), std::string::npos) << out_;

  // json: the document exactly as served. The YAML formats: the same text as the offline
  // export of that document, with what the format cannot hold on stderr.
  const std::string out = (dir_ / "params.json").string();
  ASSERT_EQ(Run(RunExport, {"--device", "robot-cli-3", "--format", "json", "--out", out}), kExitOk)
      << err_;
  EXPECT_TRUE(fs::exists(out));
  ASSERT_EQ(Run(RunExport, {"--device", "robot-cli-3", "--format", "json"}), kExitOk) << err_;
  EXPECT_EQ(json::parse(out_)["format"], "imucal-params v1");
  for (const std::string format : {"kalibr", "kalibr-intrinsics", "openvins"}) {
    ASSERT_EQ(
        Run(RunExport, {"--device", "robot-cli-3", "--format", format, "--rostopic", "/robot/imu"}),
        kExitOk)
        << err_;
    const std::string served = out_;
    EXPECT_NE(served.find("/robot/imu"), std::string::npos) << served;
    EXPECT_NE(err_.find("NOT IN THIS FILE"), std::string::npos) << err_;
    ASSERT_EQ(Run(RunExportFile, {"--params", out, "--format", format, "--rostopic", "/robot/imu"}),
              kExitOk)
        << err_;
    EXPECT_EQ(served, out_) << format;
  }
  EXPECT_EQ(Run(RunExport,
                {"--device", "robot-cli-3", "--format", "openvins", "--openvins-model", "bogus"}),
            kExitUsage);
  EXPECT_NE(err_.find("--openvins-model"), std::string::npos) << err_;
  EXPECT_EQ(Run(RunExport, {"--device", "robot-cli-3", "--format", "bogus"}), kExitUsage);
  // ExportRequest.rostopic goes into the YAML: not a topic name is INVALID_ARGUMENT, named.
  EXPECT_EQ(Run(RunExport,
                {"--device", "robot-cli-3", "--format", "kalibr", "--rostopic", "/imu0\nextra: 1"}),
            kExitBadInput);
  EXPECT_NE(err_.find("rostopic: "), std::string::npos) << err_;
  // The session's poses, as the server judged them while the capture streamed in.
  ASSERT_EQ(Run(RunSession, {"show", session}), kExitOk) << err_;
  EXPECT_NE(out_.find("pose  0 Z+"), std::string::npos) << out_;
  EXPECT_NE(out_.find("pair Z+  poses 0, 1: ok"), std::string::npos) << out_;
  ASSERT_EQ(Run(RunSession, {"poses", session, "--json"}), kExitOk) << err_;
  EXPECT_EQ(json::parse(out_)["pairs"].size(), 6u) << out_;
}

TEST_F(CliServerTest, UploadAgainToTheSameSessionResumes) {
  Register("robot-cli-4");
  const std::string capture = WriteSimulatedCapture(6);
  ASSERT_EQ(Run(RunSession, {"start", "--device", "robot-cli-4", "--json"}), kExitOk) << err_;
  const std::string id = json::parse(out_)["id"];
  ASSERT_EQ(Run(RunUpload, {capture, "--session", id}), kExitOk) << err_;
  ASSERT_EQ(Run(RunUpload, {capture, "--session", id}), kExitOk) << err_;
  EXPECT_NE(out_.find("uploaded 0 samples"), std::string::npos) << out_;
  EXPECT_NE(out_.find("already stored"), std::string::npos) << out_;
}

// An upload cut short, then another capture "resumed" into its session: refused, naming both
// files, the session untouched; the right file then resumes. (It used to print "resumed: 4001
// were already stored" and splice the second capture onto the first one's start.)
TEST_F(CliServerTest, UploadingAnotherCaptureToAStartedSessionIsRefused) {
  Register("robot-cli-7");
  core::SimOptions sim;
  sim.seed = 9;
  auto a = core::Simulate(sim);
  sim.seed = 10;
  auto b = core::Simulate(sim);
  ASSERT_TRUE(a.ok() && b.ok());
  const std::string a_path = (dir_ / "a.csv").string();
  const std::string b_path = (dir_ / "b.csv").string();
  ASSERT_TRUE(importers::WriteImucalCsvFile(a->capture, a_path).ok());
  ASSERT_TRUE(importers::WriteImucalCsvFile(b->capture, b_path).ok());
  // What an interrupted upload of a.csv leaves: its first 4001 samples (the same file name).
  core::Capture part = a->capture;
  part.t_s.resize(4001), part.accel.resize(4001), part.gyro.resize(4001);
  if (part.has_temp()) part.temp.resize(4001);
  fs::create_directories(dir_ / "cut");
  const std::string part_path = (dir_ / "cut" / "a.csv").string();
  ASSERT_TRUE(importers::WriteImucalCsvFile(part, part_path).ok());
  ASSERT_EQ(Run(RunSession, {"start", "--device", "robot-cli-7", "--json"}), kExitOk) << err_;
  const std::string id = json::parse(out_)["id"];
  ASSERT_EQ(Run(RunUpload, {part_path, "--session", id}), kExitOk) << err_;

  EXPECT_EQ(Run(RunUpload, {b_path, "--session", id}), kExitUndetermined) << out_;
  EXPECT_NE(err_.find("'b.csv' does not continue"), std::string::npos) << err_;
  EXPECT_NE(err_.find("'a.csv'"), std::string::npos) << err_;
  EXPECT_EQ(err_.find("to resume"), std::string::npos) << err_;  // nothing to resume with b.csv
  ASSERT_EQ(Run(RunSession, {"show", id, "--json"}), kExitOk) << err_;
  EXPECT_EQ(json::parse(out_)["samples"], "4001") << out_;

  ASSERT_EQ(Run(RunUpload, {a_path, "--session", id}), kExitOk) << err_;
  EXPECT_NE(out_.find("(resumed: 4001 were already stored)"), std::string::npos) << out_;
}

// `guide --device D` opens the session; `upload FILE --device D` beside it streams into it.
// A device's open session that already holds samples is not joined (the uploader resumes by
// batch number and would skip this capture's first batches): the message says what to do.
TEST_F(CliServerTest, UploadByDeviceJoinsItsEmptyOpenSessionOnly) {
  Register("robot-cli-6");
  ASSERT_EQ(Run(RunSession, {"start", "--device", "robot-cli-6", "--json"}), kExitOk) << err_;
  const std::string id = json::parse(out_)["id"];
  const std::string capture = WriteSimulatedCapture(8);
  ASSERT_EQ(Run(RunUpload, {capture, "--device", "robot-cli-6"}), kExitOk) << err_;
  EXPECT_NE(out_.find("streaming into robot-cli-6's open session " + id), std::string::npos)
      << out_;
  ASSERT_EQ(Run(RunSession, {"list", "--device", "robot-cli-6", "--json"}), kExitOk) << err_;
  const json sessions = json::parse(out_)["sessions"];
  ASSERT_EQ(sessions.size(), 1u) << out_;
  EXPECT_GT(std::stoll(sessions[0]["samples"].get<std::string>()), 0) << out_;

  EXPECT_EQ(Run(RunUpload, {capture, "--device", "robot-cli-6"}), kExitUndetermined);
  EXPECT_NE(err_.find("already has an open session " + id), std::string::npos) << err_;
  EXPECT_NE(err_.find("--session " + id), std::string::npos) << err_;
}

TEST_F(CliServerTest, UnitsDifferentFromTheDevicesAreRefused) {
  ASSERT_EQ(Run(RunDevices, {"register", "robot-cli-5", "--rate", "200", "--accel-unit", "g",
                             "--gyro-unit", "deg/s"}),
            kExitOk)
      << err_;
  EXPECT_EQ(Run(RunUpload, {WriteSimulatedCapture(7), "--device", "robot-cli-5"}), kExitBadInput);
  EXPECT_NE(err_.find("registered with accel g"), std::string::npos) << err_;
}

// A rest of `seconds` at 200 Hz, gravity on z: white noise of density n (per axis: accel
// m/s^2/sqrt(Hz), gyro rad/s/sqrt(Hz)) and a rate random walk, the sensor's own values
// (m/s^2, rad/s).
core::Capture SimulatedRest(double seconds, uint64_t seed) {
  constexpr double kRate = 200;
  const double accel_n = 1.4e-3, gyro_n = 1.4e-4, accel_k = 2e-4, gyro_k = 2e-5;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal;
  core::Capture cap;
  cap.device = "robot-noise";
  cap.rate_hz = kRate;
  Eigen::Vector3d walk_a = Eigen::Vector3d::Zero(), walk_g = Eigen::Vector3d::Zero();
  const auto n = static_cast<size_t>(seconds * kRate);
  for (size_t i = 0; i < n; ++i) {
    Eigen::Vector3d a, g;
    for (int k = 0; k < 3; ++k) {
      walk_a(k) += accel_k / std::sqrt(kRate) * normal(rng);
      walk_g(k) += gyro_k / std::sqrt(kRate) * normal(rng);
      a(k) = walk_a(k) + accel_n * std::sqrt(kRate) * normal(rng);
      g(k) = walk_g(k) + gyro_n * std::sqrt(kRate) * normal(rng);
    }
    cap.t_s.push_back(static_cast<double>(i) / kRate);
    cap.accel.push_back(a + Eigen::Vector3d(0, 0, core::kStandardGravity));
    cap.gyro.push_back(g);
  }
  return cap;
}

std::string ReadFile(const fs::path& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream text;
  text << f.rdbuf();
  return text.str();
}

// `imucal noise --session S` reads a robot's stored rest through ReadSamples and gives the same
// figures, YAML and JSON as `imucal noise FILE` on the same samples, with and without --params;
// what it writes parses back (yaml-cpp) to the figures it printed.
TEST_F(CliServerTest, NoiseFromAStoredSessionEqualsTheSameSamplesAsAFile) {
  Register("robot-noise");
  const std::string rest = (dir_ / "rest.csv").string();
  ASSERT_TRUE(importers::WriteImucalCsvFile(SimulatedRest(120, 21), rest).ok());
  ASSERT_EQ(Run(RunUpload, {rest, "--device", "robot-noise", "--batch", "5000"}), kExitOk) << err_;
  ASSERT_EQ(Run(RunSession, {"list", "--device", "robot-noise", "--json"}), kExitOk) << err_;
  const std::string session = json::parse(out_)["sessions"][0]["id"];

  // A calibration to apply first (--params), as a robot's parameter set would be.
  core::ParamSet params;
  params.device = "robot-noise";
  params.version = 1;
  params.accel.scale = Eigen::Vector3d(1.01, 0.99, 1.002);
  params.accel.bias = Eigen::Vector3d(0.02, -0.01, 0.03);
  params.gyro.matrix = Eigen::Vector3d(1.02, 0.98, 1.0).asDiagonal();
  params.gyro.bias = Eigen::Vector3d(1e-3, -2e-3, 5e-4);
  const std::string params_path = (dir_ / "params.json").string();
  std::ofstream(params_path) << formats::ParamSetToJson(params);

  for (const std::vector<std::string>& extra :
       {std::vector<std::string>{}, std::vector<std::string>{"--params", params_path}}) {
    const std::string tag = extra.empty() ? "raw" : "params";
    std::vector<std::string> from_file = {rest, "--json", "--out",
                                          (dir_ / ("file_" + tag)).string()};
    std::vector<std::string> from_session = {"--session", session, "--json", "--out",
                                             (dir_ / ("session_" + tag)).string()};
    from_file.insert(from_file.end(), extra.begin(), extra.end());
    from_session.insert(from_session.end(), extra.begin(), extra.end());
    ASSERT_EQ(Run(RunNoise, from_file), kExitOk) << err_;
    const json file = json::parse(out_);
    ASSERT_EQ(Run(RunNoise, from_session), kExitOk) << err_;
    const json stored = json::parse(out_);
    EXPECT_EQ(stored["samples"], 24000) << tag;
    for (const char* key : {"samples", "rate_hz", "axes", "units", "notes"})
      EXPECT_EQ(stored[key], file[key]) << tag << " " << key;
    EXPECT_EQ(stored["session"]["id"], session);
    EXPECT_EQ(stored["session"]["device"], "robot-noise");
    EXPECT_EQ(stored["inputs"], json::array({session}));
    EXPECT_FALSE(file.contains("session"));
    for (const char* name : {"imu.yaml", "kalibr_imu_chain.yaml", "allan_accel.svg"}) {
      EXPECT_EQ(ReadFile(dir_ / ("session_" + tag) / name), ReadFile(dir_ / ("file_" + tag) / name))
          << tag << " " << name;
    }
    // The YAML keys are the largest axis' figure, to the last bit (shortest round-trip text).
    const YAML::Node kalibr = YAML::LoadFile((dir_ / ("session_" + tag) / "imu.yaml").string());
    const YAML::Node openvins =
        YAML::LoadFile((dir_ / ("session_" + tag) / "kalibr_imu_chain.yaml").string())["imu0"];
    auto largest = [&](const char* sensor, const char* figure) {
      double v = 0;
      for (const char* axis : {"x", "y", "z"}) {
        const json& f = stored["axes"][std::string(sensor) + "_" + axis][figure]["value"];
        if (f.is_number()) v = std::max(v, f.get<double>());
      }
      return v;
    };
    for (const auto& [key, sensor, figure] :
         {std::tuple{"accelerometer_noise_density", "accel", "noise_density"},
          std::tuple{"accelerometer_random_walk", "accel", "random_walk"},
          std::tuple{"gyroscope_noise_density", "gyro", "noise_density"},
          std::tuple{"gyroscope_random_walk", "gyro", "random_walk"}}) {
      const double want = largest(sensor, figure);
      EXPECT_GT(want, 0) << key;
      EXPECT_NEAR(kalibr[key].as<double>(), want, 1e-15 * want) << tag << " " << key;
      EXPECT_NEAR(openvins[key].as<double>(), want, 1e-15 * want) << tag << " " << key;
    }
    EXPECT_EQ(kalibr["update_rate"].as<double>(), stored["rate_hz"].get<double>());
    EXPECT_EQ(openvins["update_rate"].as<double>(), stored["rate_hz"].get<double>());
  }
  // The human summary says where the samples came from.
  ASSERT_EQ(Run(RunNoise, {"--session", session}), kExitOk) << err_;
  EXPECT_NE(out_.find("input       " + session + " (stored session of robot-noise at "),
            std::string::npos)
      << out_;
  EXPECT_NE(out_.find("accel x"), std::string::npos) << out_;
}

TEST_F(CliServerTest, NoiseFromASessionRefusesWhatCannotBeRead) {
  Register("robot-noise-2");
  // An unknown session: the server's NOT_FOUND, exit 2.
  EXPECT_EQ(Run(RunNoise, {"--session", "s-00000000000000000000000000000000"}), kExitBadInput);
  EXPECT_NE(err_.find("s-00000000000000000000000000000000"), std::string::npos) << err_;
  // --session without its value, or empty; files and a session at once; file-only flags.
  EXPECT_EQ(Run(RunNoise, {"--session"}), kExitUsage);
  EXPECT_NE(err_.find("--session needs a value"), std::string::npos) << err_;
  for (const std::vector<std::string>& empty_value :
       {std::vector<std::string>{"--session="}, std::vector<std::string>{"--session", ""}}) {
    EXPECT_EQ(Run(RunNoise, empty_value), kExitUsage);
    EXPECT_NE(err_.find("imucal: --session"), std::string::npos) << err_;
  }
  EXPECT_EQ(Run(RunNoise, {"rest.csv", "--session", "s-1"}), kExitUsage);
  EXPECT_NE(err_.find("not both"), std::string::npos) << err_;
  EXPECT_EQ(Run(RunNoise, {"--session", "s-1", "--accel-unit", "g"}), kExitUsage);
  EXPECT_NE(err_.find("--accel-unit applies to files"), std::string::npos) << err_;
  // A session without samples yet: nothing to analyse, said so.
  ASSERT_EQ(Run(RunSession, {"start", "--device", "robot-noise-2", "--json"}), kExitOk) << err_;
  const std::string empty = json::parse(out_)["id"];
  EXPECT_EQ(Run(RunNoise, {"--session", empty}), kExitUndetermined);
  EXPECT_NE(err_.find("holds no samples"), std::string::npos) << err_;
  // No server there: exit 6, naming the address.
  const std::string nowhere = absl::StrCat("127.0.0.1:", testing_util::FreeLoopbackPort());
  testing::internal::CaptureStdout();
  testing::internal::CaptureStderr();
  const int code = RunNoise({"--session", empty, "--server", nowhere});
  testing::internal::GetCapturedStdout();
  const std::string err = testing::internal::GetCapturedStderr();
  EXPECT_EQ(code, kExitUnavailable) << err;
  EXPECT_NE(err.find(nowhere), std::string::npos) << err;
}

// A robot still streaming into the session: `imucal solve` is refused, saying so (exit 3, as
// the server's FAILED_PRECONDITION), and `imucal solve --force` starts the solve regardless.
TEST_F(CliServerTest, SolveIsRefusedWhileTheRobotStreamsUnlessForced) {
  Register("robot-cli-7");
  ASSERT_EQ(Run(RunSession, {"start", "--device", "robot-cli-7", "--json"}), kExitOk) << err_;
  const std::string id = json::parse(out_)["id"];
  core::SimOptions sim;
  sim.seed = 9;
  auto r = core::Simulate(sim);
  ASSERT_TRUE(r.ok()) << r.status();
  auto channel = grpc::CreateChannel(server_->address(), grpc::InsecureChannelCredentials());
  auto sessions = v1::SessionService::NewStub(channel);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  auto stream = sessions->StreamSamples(&ctx);
  v1::SampleBatch batch;
  batch.set_session_id(id);
  batch.set_seq(1);
  for (size_t i = 0; i < 2000; ++i) {
    batch.add_t_s(r->capture.t_s[i]);
    for (int k = 0; k < 3; ++k) {
      batch.add_accel(r->capture.accel[i](k));
      batch.add_gyro(r->capture.gyro[i](k));
    }
  }
  ASSERT_TRUE(stream->Write(batch));
  v1::SampleAck ack;
  ASSERT_TRUE(stream->Read(&ack));

  EXPECT_EQ(Run(RunSolve, {"--session", id}), kExitUndetermined) << out_;
  EXPECT_NE(err_.find("session " + id + " has 1 sample stream open"), std::string::npos) << err_;
  EXPECT_NE(err_.find("imucal solve --force"), std::string::npos) << err_;
  ASSERT_EQ(Run(RunSolve, {"--session", id, "--force"}), kExitOk) << err_;
  EXPECT_NE(out_.find("solve job solve-"), std::string::npos) << out_;
  ctx.TryCancel();
  stream->Finish();
}

// A server whose database is down answers, UNAVAILABLE: the CLI says the server is up and its
// database is not, rather than that the server is unreachable.
TEST(CliServerUnreachableTest, ADatabaseOutageIsNotCalledAnUnreachableServer) {
  Server server;
  server.address = "127.0.0.1:50051";
  testing::internal::CaptureStderr();
  const int code = RpcError(server, grpc::Status(grpc::StatusCode::UNAVAILABLE,
                                                 "the calibration service's database is "
                                                 "unavailable"));
  const std::string err = testing::internal::GetCapturedStderr();
  EXPECT_EQ(code, kExitUnavailable);
  EXPECT_EQ(err,
            "imucal: server 127.0.0.1:50051 is up, but the calibration service's database is "
            "unavailable; retry later\n");
}

TEST(CliServerUnreachableTest, ExitCodeSix) {
  const std::string address = absl::StrCat("127.0.0.1:", testing_util::FreeLoopbackPort());
  testing::internal::CaptureStderr();
  const int code = RunDevices({"--server", address});
  const std::string err = testing::internal::GetCapturedStderr();
  EXPECT_EQ(code, kExitUnavailable);
  EXPECT_NE(err.find("unreachable"), std::string::npos) << err;
}

}  // namespace
}  // namespace imucal::cli

namespace imucal::cli {
namespace {

// A --server (or $IMUCAL_SERVER) that gRPC would only log about, and then fail every call with
// "Failed to create secure client channel", is refused before any call, naming what is wrong.
TEST(ServerAddressTest, ATargetGrpcCannotParseIsRefusedNamingWhatIsWrong) {
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"ipv4:localhost:50051", "'localhost:50051' is not IPV4:PORT"},
      {"ipv4:127.0.0.1:5, 127.0.0.1:6", "contains a space"},
      {"ipv4:127.0.0.1:99999", "'127.0.0.1:99999' is not IPV4:PORT"},
      {"ipv4:127.0.0.1:5,", "'' is not IPV4:PORT"},
      {"ipv6:[::1]:50051,fe80::zz:1", "is not [IPV6]:PORT"},
  };
  for (const auto& [target, why] : bad) {
    std::vector<std::string> argv = {"imucal", "--server", target, "devices"};
    absl::Status s = TakeConnectionFlags(&argv);
    EXPECT_TRUE(absl::IsInvalidArgument(s)) << target << ": " << s;
    EXPECT_NE(s.message().find(why), std::string::npos) << s;
    EXPECT_NE(s.message().find(target), std::string::npos) << s;
    argv = {"imucal", "devices", "--server=" + target};
    EXPECT_TRUE(absl::IsInvalidArgument(TakeConnectionFlags(&argv))) << target;
  }
  for (const std::string good :
       {"127.0.0.1:50051", "localhost:50051", "dns:///imucal.internal:50051",
        "ipv4:10.0.0.1:50051,10.0.0.2:50051", "ipv6:[::1]:50051,[fd00::2]:50052"}) {
    std::vector<std::string> argv = {"imucal", "--server", good, "devices"};
    EXPECT_TRUE(TakeConnectionFlags(&argv).ok()) << good;
    EXPECT_EQ(argv.size(), 4u) << "--server stays for the command";
  }
}

}  // namespace
}  // namespace imucal::cli
