// End to end: the real imucald on a loopback port with a real SQLite file, the
// robot SDK and the real `imucal` CLI binary, as the fleet uses them.
//
//   1. A device is registered; a simulated six-face capture (plus free poses, so the model is well
//      determined) is written as an imucal CSV.
//   2. A simulated robot streams it through sdk::Uploader while another thread follows the
//      session's WatchSession events: poses accepted, pair verdicts, progress, next-pose guidance.
//   3. The session is solved (v1: passes the quality gate, active at once). A later noisy session
//      gives a candidate (v2, warn) that the Promote RPC makes active; a Rollback returns to v1.
//   4. The robot fetches its active set through sdk::ParamClient and applies it with
//      sdk::Corrector to a fresh validation capture of the same unit.
//   5. Offline, `imucal calibrate` on the same CSV with the same seed and `imucal apply` on the
//      validation CSV give the same samples; the calibrated error is far below the raw error.
#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "client/sdk/client.h"
#include "client/sdk/corrector.h"
#include "client/sdk/uploader.h"
#include "core/simulator.h"
#include "core/validation.h"
#include "grpcpp/grpcpp.h"
#include "gtest/gtest.h"
#include "importers/imucal_csv.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "nlohmann/json.hpp"
#include "tests/client/imucald_process.h"
#include "tests/server/watch.h"

namespace imucal::server {
namespace {

namespace pb = ::imucal::v1;
using std::chrono::seconds;
using std::chrono::system_clock;

constexpr char kDevice[] = "robot-e2e";
constexpr uint64_t kSolveSeed = 7;  // BSAS seed of the server's solves and of the offline CLI

std::unique_ptr<grpc::ClientContext> Ctx() {
  auto ctx = std::make_unique<grpc::ClientContext>();
  ctx->set_deadline(system_clock::now() + seconds(20));
  return ctx;
}

using testing_util::AcceptedPoses;  // tests/server/watch.h
using testing_util::Watch;

int OkPairs(const std::vector<pb::SessionEvent>& events) {
  int n = 0;
  for (const auto& e : events) n += e.has_pair() && e.pair().ok();
  return n;
}

// True once a Progress event says the protocol's wanted poses are all accepted.
bool ProgressComplete(const std::vector<pb::SessionEvent>& events) {
  for (const auto& e : events) {
    if (e.has_progress() && e.progress().poses_wanted() > 0 &&
        e.progress().poses_accepted() >= e.progress().poses_wanted())
      return true;
  }
  return false;
}

// The solve result in the events, if any.
const pb::SolveJob* DoneSolve(const std::vector<pb::SessionEvent>& events) {
  for (const auto& e : events)
    if (e.has_solve() && e.solve().state() == pb::JOB_STATE_DONE) return &e.solve();
  return nullptr;
}

// Runs the real CLI binary with `args`, its stdout and stderr into `log_path` (stderr into
// `err_path` when given); the exit code (-1 if it did not exit normally).
int RunCli(const std::vector<std::string>& args, const std::string& log_path,
           const std::string& err_path = "") {
#ifdef IMUCAL_CLI_PATH
  std::vector<char*> argv;
  std::string exe = IMUCAL_CLI_PATH;
  argv.push_back(exe.data());
  std::vector<std::string> copy = args;
  for (std::string& a : copy) argv.push_back(a.data());
  argv.push_back(nullptr);
  const pid_t pid = ::fork();
  if (pid == 0) {
    const int fd = ::open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd >= 0) {
      ::dup2(fd, STDOUT_FILENO);
      ::dup2(fd, STDERR_FILENO);
    }
    if (!err_path.empty()) {
      const int err = ::open(err_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      if (err >= 0) ::dup2(err, STDERR_FILENO);
    }
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  if (pid < 0) return -1;
  int status = 0;
  ::waitpid(pid, &status, 0);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
#else
  (void)args, (void)log_path, (void)err_path;
  return -1;
#endif
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

class EndToEndTest : public testing_util::ImucaldTest {
 protected:
  EndToEndTest() : ImucaldTest("imucal_e2e_test") {}

  void SetUp() override {
    ImucaldTest::SetUp();
    if (IsSkipped() || HasFatalFailure()) return;
#ifndef IMUCAL_CLI_PATH
    GTEST_SKIP() << "the imucal CLI is not built";
#endif
    channel_ = server_->NewChannel();
    devices_ = pb::DeviceService::NewStub(channel_);
    sessions_ = pb::SessionService::NewStub(channel_);
    params_ = pb::ParameterService::NewStub(channel_);
  }

  void TearDown() override {
    devices_.reset(), sessions_.reset(), params_.reset(), channel_.reset();
    ImucaldTest::TearDown();
  }

  pb::SolveJob GetSolveJob(const std::string& job_id) {
    pb::GetSolveJobRequest req;
    req.set_job_id(job_id);
    pb::SolveJob job;
    grpc::Status s = sessions_->GetSolveJob(Ctx().get(), req, &job);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return job;
  }

  pb::ParameterSet Active() {
    pb::GetActiveParametersRequest req;
    req.set_device_id(kDevice);
    pb::ParameterSet set;
    grpc::Status s = params_->GetActiveParameters(Ctx().get(), req, &set);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return set;
  }

  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<pb::DeviceService::Stub> devices_;
  std::unique_ptr<pb::SessionService::Stub> sessions_;
  std::unique_ptr<pb::ParameterService::Stub> params_;
};

TEST_F(EndToEndTest, StreamWatchSolvePromoteFetchApplyMatchesOfflineCli) {
  // --- 1. The device and its capture, as a CSV file. ---
  {
    pb::RegisterDeviceRequest reg;
    reg.mutable_device()->set_id(kDevice);
    reg.mutable_device()->set_sensor_model("sim");
    reg.mutable_device()->set_nominal_rate_hz(200);
    reg.mutable_device()->set_accel_unit("m/s^2");
    reg.mutable_device()->set_gyro_unit("rad/s");
    pb::Device device;
    grpc::Status s = devices_->RegisterDevice(Ctx().get(), reg, &device);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  core::SimOptions sim_options;
  sim_options.seed = 11;
  // Six faces alone leave the cross-axis and quadratic terms undetermined (verdict warn): eight
  // free orientations after them make a capture that passes the quality gate.
  sim_options.extra_poses = 8;
  absl::StatusOr<core::SimResult> sim = core::Simulate(sim_options);
  ASSERT_TRUE(sim.ok()) << sim.status();
  sim->capture.device = kDevice;
  const std::string capture_csv = (dir_ / "capture.csv").string();
  ASSERT_TRUE(importers::WriteImucalCsvFile(sim->capture, capture_csv).ok());
  // The robot streams what the file holds, as `imucal upload` would.
  absl::StatusOr<core::Capture> capture = importers::ReadImucalCsvFile(capture_csv);
  ASSERT_TRUE(capture.ok()) << capture.status();
  ASSERT_EQ(capture->size(), sim->capture.size());

  pb::Session session;
  {
    pb::CreateSessionRequest req;
    req.set_device_id(kDevice);
    req.set_protocol(pb::PROTOCOL_SIX_FACE);
    grpc::Status s = sessions_->CreateSession(Ctx().get(), req, &session);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }

  // --- 2. The robot streams through the SDK while the technician's event stream follows. ---
  Watch watch(sessions_.get(), session.id());
  ASSERT_TRUE(watch.WaitFor([](const auto& ev, bool) { return !ev.empty(); })) << "no snapshot";
  sdk::UploadOptions upload_options;
  upload_options.batch_samples = 400;
  int64_t last_acked = 0;
  upload_options.progress = [&](int64_t acked, int64_t) { last_acked = acked; };
  sdk::Uploader uploader(server_->NewChannel(), upload_options);
  absl::StatusOr<sdk::UploadResult> uploaded = uploader.Upload(session.id(), *capture);
  ASSERT_TRUE(uploaded.ok()) << uploaded.status();
  const int64_t total = static_cast<int64_t>(capture->size());
  EXPECT_EQ(uploaded->total_samples, total);
  EXPECT_EQ(uploaded->sent_samples, total);
  EXPECT_EQ(last_acked, total);

  // The six faces' pairs are judged while streaming (the last one's second pose is closed by the
  // move to the first free pose); the final hold is closed only by the solve.
  ASSERT_TRUE(watch.WaitFor([](const auto& ev, bool) {
    return OkPairs(ev) >= 6 && ProgressComplete(ev) && AcceptedPoses(ev) >= 12;
  })) << OkPairs(watch.events())
      << " ok pairs, " << AcceptedPoses(watch.events()) << " poses";
  {
    const std::vector<pb::SessionEvent> events = watch.events();
    ASSERT_TRUE(events[0].has_session()) << "the stream starts with the session's snapshot";
    bool saw_instruction = false, saw_turn = false, saw_first_face = false;
    pb::Progress last_progress;
    for (const auto& e : events) {
      if (e.has_next_pose() && !e.next_pose().instruction().empty()) saw_instruction = true;
      if (e.has_next_pose() && e.next_pose().turn_half()) saw_turn = true;
      if (e.has_next_pose() && e.next_pose().face() == "Z+") saw_first_face = true;
      if (e.has_pair()) {
        EXPECT_TRUE(e.pair().ok()) << e.pair().face() << ": " << e.pair().reason();
        EXPECT_NEAR(e.pair().rotation_deg(), 180, 15) << e.pair().face();
      }
      if (e.has_progress()) last_progress = e.progress();
    }
    EXPECT_TRUE(saw_instruction);
    EXPECT_TRUE(saw_turn) << "no instruction to turn the robot half a turn";
    EXPECT_TRUE(saw_first_face);
    // Six faces, each twice, at least (the free poses after them count too); all verified.
    EXPECT_GE(last_progress.poses_wanted(), 12);
    EXPECT_GE(last_progress.poses_accepted(), last_progress.poses_wanted());
    EXPECT_EQ(last_progress.faces_done_size(), 6);
    EXPECT_EQ(last_progress.faces_pending_size(), 0);
  }

  // --- 3. Solve: v1 passes the quality gate and becomes active on its own. ---
  pb::SolveJob job1;
  {
    pb::SolveSessionRequest req;
    req.set_session_id(session.id());
    req.set_seed(kSolveSeed);
    grpc::Status s = sessions_->SolveSession(Ctx().get(), req, &job1);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  // The watch ends when the session closes, after the solve's result.
  ASSERT_TRUE(watch.WaitFor([](const auto&, bool ended) { return ended; }, seconds(30)));
  EXPECT_TRUE(watch.status().ok()) << watch.status().error_message();
  {
    const std::vector<pb::SessionEvent> events = watch.events();
    const pb::SolveJob* done = DoneSolve(events);
    ASSERT_NE(done, nullptr) << "no solve result in the event stream";
    EXPECT_EQ(done->id(), job1.id());
    EXPECT_EQ(done->version(), 1);
    EXPECT_GE(AcceptedPoses(events), 20) << "12 six-face poses and 8 free ones";
  }
  job1 = GetSolveJob(job1.id());
  ASSERT_EQ(job1.state(), pb::JOB_STATE_DONE) << job1.error();
  EXPECT_EQ(job1.version(), 1);
  EXPECT_EQ(job1.verdict(), "pass");
  ASSERT_TRUE(job1.activated());
  EXPECT_EQ(Active().version(), 1);

  // Promote only applies to a candidate (a passing solve is active at once; a superseded version
  // comes back through Rollback). A later session on a loose mount (six faces, 1 m/s^2 of
  // vibration noise: pose residual ~0.035 m/s^2, over the 0.02 pass gate and under the 0.05 fail
  // one) gives one: v2, verdict warn. The technician promotes it, then rolls back to v1, the
  // well-determined set the robot must end up with.
  {
    core::SimOptions six_face_only = sim_options;
    six_face_only.seed = 12;
    six_face_only.extra_poses = 0;
    six_face_only.accel_noise_m_s2 = 1.0;
    absl::StatusOr<core::SimResult> second = core::Simulate(six_face_only, sim->truth);
    ASSERT_TRUE(second.ok()) << second.status();
    pb::CreateSessionRequest create;
    create.set_device_id(kDevice);
    create.set_protocol(pb::PROTOCOL_SIX_FACE);
    pb::Session session2;
    grpc::Status s = sessions_->CreateSession(Ctx().get(), create, &session2);
    ASSERT_TRUE(s.ok()) << s.error_message();
    absl::StatusOr<sdk::UploadResult> up = uploader.Upload(session2.id(), second->capture);
    ASSERT_TRUE(up.ok()) << up.status();
    Watch watch2(sessions_.get(), session2.id());
    pb::SolveSessionRequest req;
    req.set_session_id(session2.id());
    req.set_seed(kSolveSeed);
    pb::SolveJob job2;
    s = sessions_->SolveSession(Ctx().get(), req, &job2);
    ASSERT_TRUE(s.ok()) << s.error_message();
    ASSERT_TRUE(watch2.WaitFor([](const auto&, bool ended) { return ended; }, seconds(30)));
    EXPECT_TRUE(watch2.status().ok()) << watch2.status().error_message();
    job2 = GetSolveJob(job2.id());
    ASSERT_EQ(job2.state(), pb::JOB_STATE_DONE) << job2.error();
    ASSERT_EQ(job2.version(), 2);
    EXPECT_NE(job2.verdict(), "pass");
    ASSERT_FALSE(job2.activated()) << "the quality gate keeps a non-passing solve a candidate";
  }
  EXPECT_EQ(Active().version(), 1);
  {
    pb::PromoteRequest req;
    req.set_device_id(kDevice);
    req.set_version(2);
    req.set_reason("e2e: the technician accepts the six-face-only solve");
    pb::ParameterSet set;
    grpc::Status s = params_->Promote(Ctx().get(), req, &set);
    ASSERT_TRUE(s.ok()) << s.error_message();
    EXPECT_EQ(set.version(), 2);
  }
  {
    const pb::ParameterSet promoted = Active();
    EXPECT_EQ(promoted.version(), 2);
    EXPECT_EQ(promoted.state(), pb::VERSION_STATE_ACTIVE);
  }
  {
    pb::RollbackRequest req;
    req.set_device_id(kDevice);
    req.set_to_version(1);
    req.set_reason("e2e: back to the well-determined set");
    pb::ParameterSet set;
    grpc::Status s = params_->Rollback(Ctx().get(), req, &set);
    ASSERT_TRUE(s.ok()) << s.error_message();
    EXPECT_EQ(set.version(), 1);
  }
  const pb::ParameterSet active = Active();
  EXPECT_EQ(active.version(), 1);
  EXPECT_EQ(active.state(), pb::VERSION_STATE_ACTIVE);

  // --- 4. The robot fetches its set through the SDK and applies it to a fresh capture. ---
  sdk::ParamClient client(server_->NewChannel());
  absl::StatusOr<sdk::LoadedParams> fetched = client.FetchActive(kDevice, absl::Seconds(10));
  ASSERT_TRUE(fetched.ok()) << fetched.status();
  EXPECT_EQ(fetched->stored.version, 1);
  EXPECT_EQ(fetched->stored.json, active.json());

  // Same unit (truth), new poses; noise-free so that the error left after calibration is the
  // calibration's own, not the sensor noise.
  core::SimOptions validation_options = sim_options;
  validation_options.seed = 1011;
  validation_options.protocol = core::SimProtocol::kFree;
  validation_options.extra_poses = 0;
  validation_options.accel_noise_m_s2 = 0;
  validation_options.gyro_noise_rad_s = 0;
  absl::StatusOr<core::SimResult> validation = core::Simulate(validation_options, sim->truth);
  ASSERT_TRUE(validation.ok()) << validation.status();
  const core::Capture& raw = validation->capture;
  ASSERT_GT(raw.size(), 1000u);
  absl::StatusOr<sdk::Corrector> corrector = sdk::Corrector::Create(fetched->params, raw.t_s[0]);
  ASSERT_TRUE(corrector.ok()) << corrector.status();
  ASSERT_TRUE(corrector->CheckInputUnits(raw.accel_unit, raw.gyro_unit).ok());
  std::vector<Eigen::Vector3d> served_accel, served_gyro;
  for (size_t i = 0; i < raw.size(); ++i) {
    sdk::RawSample in;
    in.t_s = raw.t_s[i];
    for (int k = 0; k < 3; ++k) {
      in.accel[k] = raw.accel[i](k);
      in.gyro[k] = raw.gyro[i](k);
    }
    if (raw.has_temp()) in.temp_c = raw.temp[i];
    sdk::CalibratedSample out;
    corrector->Apply(in, &out);
    EXPECT_EQ(out.effects_skipped, 0);
    served_accel.emplace_back(out.accel_m_s2[0], out.accel_m_s2[1], out.accel_m_s2[2]);
    served_gyro.emplace_back(out.gyro_rad_s[0], out.gyro_rad_s[1], out.gyro_rad_s[2]);
  }

  // --- 5. Offline: the real CLI on the same capture file, with the solve's seed. ---
  const std::string params_json = (dir_ / "offline_params.json").string();
  const std::string log = (dir_ / "cli.log").string();
  ASSERT_EQ(RunCli({"calibrate", capture_csv, "--protocol", "six-face", "--seed",
                    std::to_string(kSolveSeed), "--device", kDevice, "--params-out", params_json},
                   log),
            0)
      << ReadText(log);
  const std::string validation_csv = (dir_ / "validation.csv").string();
  const std::string applied_csv = (dir_ / "validation_applied.csv").string();
  ASSERT_TRUE(importers::WriteImucalCsvFile(raw, validation_csv).ok());
  ASSERT_EQ(RunCli({"apply", "--params", params_json, validation_csv, applied_csv}, log), 0)
      << ReadText(log);
  absl::StatusOr<core::Capture> offline = importers::ReadImucalCsvFile(applied_csv);
  ASSERT_TRUE(offline.ok()) << offline.status();
  ASSERT_EQ(offline->size(), raw.size());
  EXPECT_EQ(offline->accel_unit, core::AccelUnit::kMetersPerSecond2);
  EXPECT_EQ(offline->gyro_unit, core::GyroUnit::kRadPerSecond);

  // Served-and-applied == offline-applied. Both run core::Calibrate with the same protocol and
  // seed on the same samples (the server's stored f64 batches; the CLI's CSV, written as the
  // shortest text that parses back to the same double, so the same doubles) and then the same
  // Corrector: the same deterministic code path, so they agree to the last bit unless an input
  // differs. The CSV round trip is the only step between them, hence a relative 1e-9 (with an
  // absolute floor of 1e-9 near zero): far above rounding (1e-16), far below what a real
  // difference moves (gravity 9.80665 vs 9.81 is 3e-4 relative; the other version or capture,
  // other units or options, 1e-6 and up). Even a different BSAS seed moves this capture's
  // parameters by only ~2e-12 (the solve converges to one optimum), which this cannot see.
  double max_rel_diff = 0;
  for (size_t i = 0; i < raw.size(); ++i) {
    for (int k = 0; k < 3; ++k) {
      const double accel_scale = std::max(1.0, std::abs(offline->accel[i](k)));
      const double gyro_scale = std::max(1.0, std::abs(offline->gyro[i](k)));
      ASSERT_NEAR(served_accel[i](k), offline->accel[i](k), 1e-9 * accel_scale)
          << "sample " << i << " accel axis " << k;
      ASSERT_NEAR(served_gyro[i](k), offline->gyro[i](k), 1e-9 * gyro_scale)
          << "sample " << i << " gyro axis " << k;
      max_rel_diff =
          std::max({max_rel_diff, std::abs(served_accel[i](k) - offline->accel[i](k)) / accel_scale,
                    std::abs(served_gyro[i](k) - offline->gyro[i](k)) / gyro_scale});
    }
  }
  RecordProperty("served_vs_offline_max_rel_diff", std::to_string(max_rel_diff));

  // The calibration works: error vs the truth far below the raw readings'. The accelerometer is
  // compared after the best-fit rotation (a calibration without known orientations fixes its body
  // frame by convention, core/validation.h); the raw readings, in m/s^2 and rad/s already, are
  // what a robot without calibration would use.
  const double raw_accel = core::VectorRmsError(raw.accel, validation->true_accel_m_s2, false);
  const double cal_accel = core::VectorRmsError(served_accel, validation->true_accel_m_s2, true);
  const double raw_gyro = core::VectorRmsError(raw.gyro, validation->true_gyro_rad_s, false);
  const double cal_gyro = core::VectorRmsError(served_gyro, validation->true_gyro_rad_s, false);
  RecordProperty("raw_accel_rms_m_s2", std::to_string(raw_accel));
  RecordProperty("calibrated_accel_rms_m_s2", std::to_string(cal_accel));
  RecordProperty("raw_gyro_rms_rad_s", std::to_string(raw_gyro));
  RecordProperty("calibrated_gyro_rms_rad_s", std::to_string(cal_gyro));
  std::printf(
      "served vs offline: max relative difference %.3g\n"
      "accel RMS error raw %.4g -> calibrated %.4g m/s^2; gyro %.4g -> %.4g rad/s\n",
      max_rel_diff, raw_accel, cal_accel, raw_gyro, cal_gyro);
  // Here raw ~0.76 -> ~0.002 m/s^2 and ~0.020 -> ~0.0002 rad/s: the bounds leave room.
  EXPECT_LT(cal_accel, raw_accel / 50);
  EXPECT_LT(cal_gyro, raw_gyro / 20);
}

// `imucal noise --session S` as a technician runs it, all through the real binaries: a 2-minute
// rest from the independent simulator (tests/tools/write_euroc.py, imu_sim.py) uploaded with
// `imucal upload`, its stored samples read back through ReadSamples, and the figures equal to
// those of `imucal noise` on the same file; the white-noise densities are the simulated ones.
TEST_F(EndToEndTest, NoiseOfAStoredRestThroughTheCliBinary) {
#ifndef IMUCAL_TOOLS_DIR
  GTEST_SKIP() << "IMUCAL_TOOLS_DIR is not set";
#else
  const std::string rest_dir = (dir_ / "rest").string();
  const std::string write = std::string("python3 '") + IMUCAL_TOOLS_DIR + "/write_euroc.py' '" +
                            rest_dir +
                            "' --protocol random --poses 0 --first-hold-s 120 --rate-hz 200 "
                            "--seed 5 >/dev/null";
  ASSERT_EQ(std::system(write.c_str()), 0) << write;
  const std::string rest = rest_dir + "/mav0/imu0/data.csv";
  const nlohmann::json truth = nlohmann::json::parse(ReadText(rest_dir + "/truth.json"));
  const std::string server = server_->address();
  const std::string log = (dir_ / "noise_cli.log").string();
  const std::string err = (dir_ / "noise_cli.err").string();
  ASSERT_EQ(RunCli({"--server", server, "devices", "register", "robot-rest", "--rate", "200",
                    "--accel-unit", "m/s^2", "--gyro-unit", "rad/s"},
                   log),
            0)
      << ReadText(log);
  ASSERT_EQ(RunCli({"--server", server, "upload", rest, "--device", "robot-rest"}, log), 0)
      << ReadText(log);
  ASSERT_EQ(
      RunCli({"--server", server, "session", "list", "--device", "robot-rest", "--json"}, log, err),
      0)
      << ReadText(err);
  const std::string session = nlohmann::json::parse(ReadText(log))["sessions"][0]["id"];

  ASSERT_EQ(RunCli({"noise", "--session", session, "--server", server, "--json"}, log, err), 0)
      << ReadText(err);
  const nlohmann::json stored = nlohmann::json::parse(ReadText(log));
  ASSERT_EQ(RunCli({"noise", rest, "--json"}, log, err), 0) << ReadText(err);
  const nlohmann::json file = nlohmann::json::parse(ReadText(log));
  EXPECT_EQ(stored["samples"], 24000);
  EXPECT_EQ(stored["session"]["id"], session);
  for (const char* key : {"samples", "rate_hz", "axes", "notes"})
    EXPECT_EQ(stored[key], file[key]) << key;
  // The simulated white noise per sample, as a density: sigma / sqrt(rate), within 10%.
  const double rate = truth["rate_hz"].get<double>();
  for (const char* axis : {"accel_x", "accel_y", "accel_z", "gyro_x", "gyro_y", "gyro_z"}) {
    const double sigma =
        truth[std::string(axis).rfind("accel", 0) == 0 ? "accel_noise_m_s2" : "gyro_noise_rad_s"]
            .get<double>();
    const double n = stored["axes"][axis]["noise_density"]["value"].get<double>();
    EXPECT_NEAR(n, sigma / std::sqrt(rate), 0.1 * sigma / std::sqrt(rate)) << axis;
  }

  // Refusals, with the exit codes scripts rely on.
  EXPECT_EQ(RunCli({"noise", "--session"}, log), 1) << ReadText(log);
  EXPECT_NE(ReadText(log).find("--session needs a value"), std::string::npos) << ReadText(log);
  EXPECT_EQ(
      RunCli({"--server", server, "noise", "--session", "s-00000000000000000000000000000000"}, log),
      2)
      << ReadText(log);
  EXPECT_NE(ReadText(log).find("s-00000000000000000000000000000000"), std::string::npos)
      << ReadText(log);
#endif
}

}  // namespace
}  // namespace imucal::server
