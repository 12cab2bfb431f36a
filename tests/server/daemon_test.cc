// imucald as an operator runs it, end to end through the real binary (server/main.cc,
// server/daemon_commands.{h,cc}, Server::Shutdown):
//   - SIGTERM drains: with a robot streaming and solves queued on the one solve thread, imucald
//     exits 0 within its drain deadline (plus the queued solves' run time); every batch
//     acknowledged before the signal is in the file byte for byte; every solve accepted before
//     the signal finished and stored its version (docs/operations.md: "gives in-flight ones drain_deadline,
//     then finishes queued solves"); the restarted server resumes the robot's stream.
//   - `imucald backup` while the server serves and a robot streams, `imucald restore` into a new
//     path: a server started on it has the devices, sessions, versions, the active version (the
//     same document and CRC) and every sample acknowledged before the backup started. A restore
//     onto a running server's database is refused, naming the reason; over a stopped server's
//     database it keeps the previous one as DB.pre-restore; a file that is not a backup is
//     refused.
//   - `imucald --health-check`: exit 0 against a serving imucald (by address, and by the
//     configuration's `listen`), 1 with a message when nothing listens.
#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

#include "absl/strings/str_cat.h"
#include "client/sdk/uploader.h"
#include "core/simulator.h"
#include "formats/crc32c.h"
#include "google/protobuf/util/message_differencer.h"
#include "grpcpp/grpcpp.h"
#include "gtest/gtest.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "storage/sample_codec.h"
#include "storage/store.h"
#include "tests/client/imucald_process.h"
#include "tests/server/daemon_clients.h"
#include "tests/server/stored_samples.h"
#include "tests/server/watch.h"

namespace imucal::server {
namespace {

namespace pb = ::imucal::v1;
using google::protobuf::util::MessageDifferencer;
using testing_util::ImucaldProcess;
using testing_util::SameBytes;  // tests/server/stored_samples.h

struct CommandResult {
  int exit_code = -1;  // -1: did not exit normally
  std::string out;
  std::string err;
};

std::string ReadFile(const std::filesystem::path& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

// Runs `imucald args...` to completion, its stdout and stderr captured in files in `dir`.
CommandResult RunImucald(const std::filesystem::path& dir, const std::vector<std::string>& args) {
  CommandResult result;
#ifdef IMUCAL_IMUCALD_PATH
  const std::filesystem::path out = dir / "command.out";
  const std::filesystem::path err = dir / "command.err";
  // Everything the child needs is built before fork (other threads run): it only execs.
  std::vector<const char*> argv = {IMUCAL_IMUCALD_PATH};
  for (const std::string& arg : args) argv.push_back(arg.c_str());
  argv.push_back(nullptr);
  // The commands read the configuration from the environment too: none of imucald's.
  std::vector<const char*> env;
  for (char** e = environ; *e != nullptr; ++e)
    if (std::string_view(*e).substr(0, 8) != "IMUCALD_") env.push_back(*e);
  env.push_back(nullptr);
  const pid_t pid = ::fork();
  if (pid == 0) {
    const int out_fd = ::open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
    const int err_fd = ::open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
    if (out_fd < 0 || err_fd < 0) ::_exit(126);
    ::dup2(out_fd, STDOUT_FILENO);
    ::dup2(err_fd, STDERR_FILENO);
    ::execve(IMUCAL_IMUCALD_PATH, const_cast<char* const*>(argv.data()),
             const_cast<char* const*>(env.data()));
    ::_exit(127);
  }
  int status = 0;
  if (pid < 0 || ::waitpid(pid, &status, 0) != pid) return result;
  if (WIFEXITED(status)) result.exit_code = WEXITSTATUS(status);
  result.out = ReadFile(out);
  result.err = ReadFile(err);
#endif
  return result;
}

std::string Describe(const CommandResult& r) {
  return absl::StrCat("exit ", r.exit_code, "\nstdout: ", r.out, "\nstderr: ", r.err);
}

core::Capture Simulate(uint64_t seed, int extra_poses) {
  core::SimOptions o;
  o.seed = seed;
  o.extra_poses = extra_poses;
  absl::StatusOr<core::SimResult> sim = core::Simulate(o);
  EXPECT_TRUE(sim.ok()) << sim.status();
  EXPECT_TRUE(sim.ok() && sim->capture.has_temp());
  return sim.ok() ? sim->capture : core::Capture();
}

// Just after a restart a call may meet a connection to the stopped server: UNAVAILABLE is
// retried, each try waiting for the channel to be ready. Only for calls that may be repeated.
template <typename Call>
grpc::Status Retrying(Call call) {
  grpc::Status s;
  for (int attempt = 0; attempt < 20; ++attempt) {
    grpc::ClientContext context;
    context.set_wait_for_ready(true);
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    s = call(&context);
    if (s.error_code() != grpc::StatusCode::UNAVAILABLE) return s;
  }
  return s;
}

// What a server holds, as its clients see it.
struct Snapshot {
  pb::ListDevicesResponse devices;
  pb::ListSessionsResponse sessions;
  std::map<std::string, pb::ListVersionsResponse> versions;  // by device
  std::map<std::string, pb::ParameterSet> active;            // by device, those with one
};

class DaemonTest : public testing_util::ImucaldTest {
 protected:
  explicit DaemonTest(std::vector<std::string> extra_args = {})
      : ImucaldTest("imucal_daemon_test", std::move(extra_args)) {}

  // Registers `device` and opens a six-face session for it.
  std::string OpenSession(const ImucaldProcess& server, const std::string& device) {
    auto channel = server.NewChannel();
    auto devices = pb::DeviceService::NewStub(channel);
    const pb::RegisterDeviceRequest reg = testing_util::SimDeviceRequest(device);
    pb::Device d;
    grpc::Status s =
        Retrying([&](grpc::ClientContext* c) { return devices->RegisterDevice(c, reg, &d); });
    EXPECT_TRUE(s.ok()) << s.error_message();
    auto sessions = pb::SessionService::NewStub(channel);
    grpc::ClientContext context;
    pb::CreateSessionRequest create;
    create.set_device_id(device);
    create.set_protocol(pb::PROTOCOL_SIX_FACE);
    pb::Session session;
    s = sessions->CreateSession(&context, create, &session);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return session.id();
  }

  void UploadAll(const std::string& session, const core::Capture& capture) {
    sdk::UploadOptions o;
    o.batch_samples = 2000;
    absl::StatusOr<sdk::UploadResult> r =
        sdk::Uploader(server_->NewChannel(), o).Upload(session, capture);
    EXPECT_TRUE(r.ok()) << r.status();
  }

  pb::SolveJob StartSolve(const std::string& session, uint64_t seed) {
    auto stub = pb::SessionService::NewStub(server_->NewChannel());
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    pb::SolveSessionRequest req;
    req.set_session_id(session);
    req.set_seed(seed);
    pb::SolveJob job;
    const grpc::Status s = stub->SolveSession(&context, req, &job);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return job;
  }

  // Solves the session and waits for the job's end: WatchSession ends when the session closes,
  // at once if the solve has already finished.
  pb::SolveJob SolveAndWait(const std::string& session, uint64_t seed) {
    pb::SolveJob job = StartSolve(session, seed);
    auto stub = pb::SessionService::NewStub(server_->NewChannel());
    EXPECT_TRUE(testing_util::FollowToEnd(stub.get(), session, std::chrono::seconds(60)).ok());
    return GetSolveJob(*server_, job.id());
  }

  pb::SolveJob GetSolveJob(const ImucaldProcess& server, const std::string& job_id) {
    auto stub = pb::SessionService::NewStub(server.NewChannel());
    pb::GetSolveJobRequest get;
    get.set_job_id(job_id);
    pb::SolveJob job;
    const grpc::Status s =
        Retrying([&](grpc::ClientContext* c) { return stub->GetSolveJob(c, get, &job); });
    EXPECT_TRUE(s.ok()) << s.error_message();
    return job;
  }

  pb::Session GetSession(const ImucaldProcess& server, const std::string& id) {
    auto stub = pb::SessionService::NewStub(server.NewChannel());
    pb::GetSessionRequest req;
    req.set_session_id(id);
    pb::Session out;
    const grpc::Status s =
        Retrying([&](grpc::ClientContext* c) { return stub->GetSession(c, req, &out); });
    EXPECT_TRUE(s.ok()) << id << ": " << s.error_message();
    return out;
  }

  grpc::Status GetActive(const ImucaldProcess& server, const std::string& device,
                         pb::ParameterSet* out) {
    auto stub = pb::ParameterService::NewStub(server.NewChannel());
    pb::GetActiveParametersRequest req;
    req.set_device_id(device);
    return Retrying([&](grpc::ClientContext* c) { return stub->GetActiveParameters(c, req, out); });
  }

  Snapshot Take(const ImucaldProcess& server) {
    Snapshot snap;
    auto channel = server.NewChannel();
    auto devices = pb::DeviceService::NewStub(channel);
    auto sessions = pb::SessionService::NewStub(channel);
    auto params = pb::ParameterService::NewStub(channel);
    pb::ListDevicesRequest list_devices;
    list_devices.set_page_size(1000);
    grpc::Status s = Retrying([&](grpc::ClientContext* c) {
      return devices->ListDevices(c, list_devices, &snap.devices);
    });
    EXPECT_TRUE(s.ok()) << s.error_message();
    pb::ListSessionsRequest list_sessions;
    list_sessions.set_page_size(1000);
    s = Retrying([&](grpc::ClientContext* c) {
      return sessions->ListSessions(c, list_sessions, &snap.sessions);
    });
    EXPECT_TRUE(s.ok()) << s.error_message();
    for (const pb::Device& d : snap.devices.devices()) {
      pb::ListVersionsRequest list_versions;
      list_versions.set_device_id(d.id());
      list_versions.set_page_size(1000);
      s = Retrying([&](grpc::ClientContext* c) {
        return params->ListVersions(c, list_versions, &snap.versions[d.id()]);
      });
      EXPECT_TRUE(s.ok()) << s.error_message();
      if (d.active_version() != 0) {
        s = GetActive(server, d.id(), &snap.active[d.id()]);
        EXPECT_TRUE(s.ok()) << d.id() << ": " << s.error_message();
      }
    }
    return snap;
  }

  // The session's samples as stored in the file at `db_path`, read with a store of our own
  // (a server may have it open: WAL lets both in); batches must be 1, 2, 3, ... with no gap.
  std::vector<storage::ImuSample> StoredSamples(const std::string& db_path,
                                                const std::string& session_id) {
    std::vector<storage::ImuSample> out;
    auto store = storage::Store::Open(db_path);
    EXPECT_TRUE(store.ok()) << store.status();
    if (!store.ok()) return out;
    auto batches = (*store)->ReadBatches(session_id);
    EXPECT_TRUE(batches.ok()) << batches.status();
    if (!batches.ok()) return out;
    int64_t seq = 0;
    for (const storage::SampleBatch& b : *batches) {
      EXPECT_EQ(b.seq, ++seq) << session_id << ": batches are 1, 2, 3, ... with no gap";
      EXPECT_TRUE(storage::DecodeSamplesInto(b.payload, &out).ok());
    }
    return out;
  }

  // At least `acked` samples stored, at most the capture, each the capture's byte for byte.
  void ExpectPrefixOfCapture(const std::vector<storage::ImuSample>& stored,
                             const core::Capture& cap, int64_t acked, const std::string& what) {
    EXPECT_GE(static_cast<int64_t>(stored.size()), acked)
        << what << ": samples acknowledged before it are missing";
    EXPECT_LE(stored.size(), cap.size()) << what;
    for (size_t i = 0; i < stored.size() && i < cap.size(); ++i) {
      if (!SameBytes(stored[i], cap, i)) {
        ADD_FAILURE() << what << ": stored sample " << i << " differs from the capture";
        return;
      }
    }
  }
};

// ---- SIGTERM -------------------------------------------------------------------------------

// A drain deadline shorter than the queued solves take on the one solve thread: the robot's
// stream holds the drain until the deadline, and the solves accepted just before the signal are
// still queued then, so they finish after the drain (Server::Shutdown's DrainSolves).
class DrainTest : public DaemonTest {
 protected:
  static constexpr int kDrainDeadlineMs = 10;
  DrainTest()
      : DaemonTest(
            {"--drain-deadline", absl::StrCat(kDrainDeadlineMs, "ms"), "--solve-threads", "1"}) {}
};

TEST_F(DrainTest, SigtermFinishesQueuedSolvesKeepsAckedSamplesExitsZeroAndTheRobotResumes) {
  // Three sessions, each holding a whole capture that passes the quality gate, to be solved
  // just before the signal: on one solve thread at least the later ones are still queued.
  const core::Capture solve_capture = Simulate(11, /*extra_poses=*/8);
  std::vector<std::string> solve_devices, solve_sessions;
  for (int i = 0; i < 3; ++i) {
    solve_devices.push_back(absl::StrCat("robot-solve-", i));
    solve_sessions.push_back(OpenSession(*server_, solve_devices.back()));
    ASSERT_FALSE(solve_sessions.back().empty());
    UploadAll(solve_sessions.back(), solve_capture);
  }
  ASSERT_FALSE(HasFailure());

  const core::Capture cap = Simulate(5, /*extra_poses=*/0);
  const int64_t total = static_cast<int64_t>(cap.size());
  const std::string stream_session = OpenSession(*server_, "robot-stream");
  ASSERT_FALSE(stream_session.empty());

  sdk::UploadOptions o;
  o.batch_samples = 200;
  // Reconnects while imucald drains, is down and restarts: 200 tries, backoff at most 200 ms.
  o.initial_backoff = absl::Milliseconds(20);
  o.max_backoff = absl::Milliseconds(200);
  bool signalled = false;
  int64_t acked_at_signal = 0;
  std::vector<std::string> job_ids;
  absl::StatusOr<int> wait_status = absl::UnknownError("not signalled");
  std::vector<storage::ImuSample> stored_at_exit;
  std::vector<std::vector<storage::Solve>> solves_at_exit(solve_sessions.size());
  absl::Status restarted = absl::UnknownError("not restarted");
  o.progress = [&](int64_t acked, int64_t) {
    if (signalled || acked < total / 3) return;
    signalled = true;
    acked_at_signal = acked;
    // The stream is open (this callback holds the robot's ack reader; its writer keeps up to
    // 8 batches in flight). Queue the solves, then SIGTERM at once.
    for (const std::string& session : solve_sessions) {
      const pb::SolveJob job = StartSolve(session, 7);
      EXPECT_TRUE(job.state() == pb::JOB_STATE_QUEUED) << job.ShortDebugString();
      job_ids.push_back(job.id());
    }
    // A hang guard, not a measurement: the exit follows the drain deadline (which the open
    // stream runs into) and the three queued solves, each well under a second.
    wait_status =
        server_->SignalAndWait(SIGTERM, std::chrono::milliseconds(kDrainDeadlineMs + 15000));
    // What the stopped server left in the file, before anything else opens it.
    stored_at_exit = StoredSamples(server_->db_path(), stream_session);
    auto store = storage::Store::Open(server_->db_path());
    EXPECT_TRUE(store.ok()) << store.status();
    for (size_t i = 0; store.ok() && i < solve_sessions.size(); ++i) {
      auto solves = (*store)->ListSolves(solve_sessions[i]);
      EXPECT_TRUE(solves.ok()) << solves.status();
      if (solves.ok()) solves_at_exit[i] = *std::move(solves);
    }
    store = absl::UnknownError("closed");
    restarted = server_->Restart();
  };
  sdk::Uploader uploader(server_->NewChannel(), o);
  absl::StatusOr<sdk::UploadResult> result = uploader.Upload(stream_session, cap);
  ASSERT_TRUE(signalled);

  // Exit status 0 within the bound.
  ASSERT_TRUE(wait_status.ok()) << wait_status.status();
  EXPECT_TRUE(WIFEXITED(*wait_status) && WEXITSTATUS(*wait_status) == 0)
      << "wait status " << *wait_status;
  // Every batch acknowledged before the signal is in the file, byte for byte.
  ExpectPrefixOfCapture(stored_at_exit, cap, acked_at_signal, "after SIGTERM");
  // Every solve accepted before the signal finished: succeeded, its version stored, nothing
  // left running for the next start to fail.
  ASSERT_EQ(job_ids.size(), solve_sessions.size());
  std::vector<int> versions;
  {
    auto store = storage::Store::Open(server_->db_path());
    ASSERT_TRUE(store.ok()) << store.status();
    for (size_t i = 0; i < solve_sessions.size(); ++i) {
      SCOPED_TRACE(solve_sessions[i]);
      ASSERT_EQ(solves_at_exit[i].size(), 1u);
      const storage::Solve& solve = solves_at_exit[i][0];
      EXPECT_EQ(solve.state, storage::SolveState::kSucceeded) << solve.error;
      ASSERT_GE(solve.version, 1);
      auto version = (*store)->GetVersion(solve_devices[i], solve.version);
      ASSERT_TRUE(version.ok()) << version.status();
      EXPECT_EQ(version->session_id, solve_sessions[i]);
      EXPECT_FALSE(version->params_json.empty());
      versions.push_back(solve.version);
    }
  }

  // The restarted server reports the solves done and the sessions solved.
  ASSERT_TRUE(restarted.ok()) << restarted;
  for (size_t i = 0; i < solve_sessions.size(); ++i) {
    SCOPED_TRACE(solve_sessions[i]);
    const pb::SolveJob job = GetSolveJob(*server_, job_ids[i]);
    EXPECT_EQ(job.state(), pb::JOB_STATE_DONE) << job.error();
    EXPECT_EQ(job.version(), versions[i]);
    const pb::Session s = GetSession(*server_, solve_sessions[i]);
    EXPECT_EQ(s.state(), pb::SESSION_STATE_SOLVED);
    EXPECT_EQ(s.version(), versions[i]);
  }

  // The robot resumed on the restarted server after its last acknowledged batch and finished:
  // every sample once, in order, byte for byte.
  ASSERT_TRUE(result.ok()) << result.status();
  EXPECT_GE(result->reconnects, 1);
  const std::vector<storage::ImuSample> all = StoredSamples(server_->db_path(), stream_session);
  ASSERT_EQ(static_cast<int64_t>(all.size()), total);
  for (size_t i = 0; i < all.size(); ++i) ASSERT_TRUE(SameBytes(all[i], cap, i)) << "sample " << i;
  const pb::Session done = GetSession(*server_, stream_session);
  EXPECT_EQ(done.samples(), total);
  EXPECT_EQ(done.last_acked_seq(), (total + o.batch_samples - 1) / o.batch_samples);
}

// ---- Backup and restore --------------------------------------------------------------------

TEST_F(DaemonTest, OnlineBackupWhileStreamingRestoresEverythingAcknowledgedBeforeIt) {
  // A device with versions 1 and 2 (both pass) and version 1 active again after a rollback, so
  // that the active version is not simply the latest one.
  const core::Capture pass = Simulate(11, /*extra_poses=*/8);
  const std::string solved_session = OpenSession(*server_, "robot-solved");
  ASSERT_FALSE(solved_session.empty());
  UploadAll(solved_session, pass);
  ASSERT_TRUE(SolveAndWait(solved_session, 1).activated());
  ASSERT_TRUE(SolveAndWait(solved_session, 2).activated());
  {
    auto stub = pb::ParameterService::NewStub(server_->NewChannel());
    grpc::ClientContext context;
    pb::RollbackRequest req;
    req.set_device_id("robot-solved");
    req.set_to_version(1);
    req.set_reason("daemon test");
    pb::ParameterSet out;
    ASSERT_TRUE(stub->Rollback(&context, req, &out).ok());
  }

  // A robot streaming; the backup runs while its stream is open.
  const core::Capture cap = Simulate(5, /*extra_poses=*/0);
  const int64_t total = static_cast<int64_t>(cap.size());
  const std::string stream_session = OpenSession(*server_, "robot-stream");
  ASSERT_FALSE(stream_session.empty());
  const std::filesystem::path backup = dir_ / "backups" / "imucal-backup.db";
  std::filesystem::create_directories(backup.parent_path());  // --out does not make it
  bool backed_up = false;
  int64_t acked_before_backup = 0;
  Snapshot before;
  CommandResult backup_run;
  sdk::UploadOptions o;
  o.batch_samples = 200;
  o.progress = [&](int64_t acked, int64_t) {
    if (backed_up || acked < total / 3) return;
    backed_up = true;
    acked_before_backup = acked;
    before = Take(*server_);
    backup_run = RunImucald(dir_, {"backup", "--db", server_->db_path(), "--out", backup.string()});
  };
  absl::StatusOr<sdk::UploadResult> uploaded =
      sdk::Uploader(server_->NewChannel(), o).Upload(stream_session, cap);
  ASSERT_TRUE(backed_up);
  ASSERT_TRUE(uploaded.ok()) << uploaded.status() << " (the server kept serving the robot)";
  ASSERT_EQ(backup_run.exit_code, 0) << Describe(backup_run);
  EXPECT_NE(backup_run.out.find("backup: "), std::string::npos) << Describe(backup_run);
  EXPECT_NE(backup_run.out.find(backup.string()), std::string::npos) << Describe(backup_run);
  EXPECT_TRUE(std::filesystem::exists(backup));
  EXPECT_FALSE(std::filesystem::exists(backup.string() + ".tmp"));

  // After the backup: a third version becomes active on the live server only.
  ASSERT_EQ(SolveAndWait(solved_session, 3).version(), 3);

  // Restore into a new path and serve it.
  const std::filesystem::path restored_dir = dir_ / "restored";
  std::filesystem::create_directories(restored_dir);
  const std::string restored_db = (restored_dir / "imucal.db").string();
  const CommandResult restore_run =
      RunImucald(dir_, {"restore", "--from", backup.string(), "--db", restored_db});
  ASSERT_EQ(restore_run.exit_code, 0) << Describe(restore_run);
  EXPECT_NE(restore_run.out.find("restore: "), std::string::npos) << Describe(restore_run);
  auto restored = ImucaldProcess::Start(restored_dir.string());
  ASSERT_TRUE(restored.ok()) << restored.status();
  const Snapshot after = Take(**restored);

  // Devices (with their active version), versions and the active document as at the backup.
  ASSERT_EQ(before.devices.devices_size(), 2);
  EXPECT_TRUE(MessageDifferencer::Equals(after.devices, before.devices))
      << "before: " << before.devices.ShortDebugString()
      << "\nafter: " << after.devices.ShortDebugString();
  ASSERT_EQ(before.versions["robot-solved"].versions_size(), 2);
  for (const auto& [device, list] : before.versions) {
    EXPECT_TRUE(MessageDifferencer::Equals(after.versions.at(device), list)) << device;
  }
  ASSERT_EQ(before.active.size(), 1u);
  const pb::ParameterSet& active_before = before.active.at("robot-solved");
  EXPECT_EQ(active_before.version(), 1);
  ASSERT_EQ(after.active.count("robot-solved"), 1u);
  const pb::ParameterSet& active_after = after.active.at("robot-solved");
  EXPECT_EQ(active_after.version(), 1);
  EXPECT_EQ(active_after.json(), active_before.json());
  EXPECT_EQ(active_after.crc32c(), active_before.crc32c());
  EXPECT_EQ(active_after.crc32c(), formats::Crc32c(active_after.json()));
  // Sessions: the solved one as it was; the streaming one open, with at least what was
  // acknowledged before the backup started (its count moved on while the backup ran).
  ASSERT_EQ(after.sessions.sessions_size(), before.sessions.sessions_size());
  for (const pb::Session& b : before.sessions.sessions()) {
    const pb::Session* a = nullptr;
    for (const pb::Session& s : after.sessions.sessions())
      if (s.id() == b.id()) a = &s;
    ASSERT_NE(a, nullptr) << b.id() << " is missing";
    if (b.id() == stream_session) {
      EXPECT_EQ(a->device_id(), "robot-stream");
      EXPECT_EQ(a->state(), pb::SESSION_STATE_OPEN);
      EXPECT_GE(a->samples(), acked_before_backup);
      EXPECT_LT(a->samples(), total) << "the backup is from before the upload ended";
    } else {
      EXPECT_TRUE(MessageDifferencer::Equals(*a, b))
          << "before: " << b.ShortDebugString() << "\nafter: " << a->ShortDebugString();
    }
  }
  // The samples themselves, byte for byte.
  ExpectPrefixOfCapture(StoredSamples(restored_db, stream_session), cap, acked_before_backup,
                        "restored stream session");
  const std::vector<storage::ImuSample> solved = StoredSamples(restored_db, solved_session);
  EXPECT_EQ(solved.size(), pass.size());
  restored->reset();

  // Onto the running server's database: refused with the reason, the database untouched.
  const CommandResult refused =
      RunImucald(dir_, {"restore", "--from", backup.string(), "--db", server_->db_path()});
  EXPECT_EQ(refused.exit_code, 1) << Describe(refused);
  EXPECT_NE(refused.err.find("is in use (is imucald running?): stop it before restoring"),
            std::string::npos)
      << Describe(refused);
  EXPECT_FALSE(std::filesystem::exists(server_->db_path() + ".pre-restore"));
  pb::ParameterSet live;
  ASSERT_TRUE(GetActive(*server_, "robot-solved", &live).ok());
  EXPECT_EQ(live.version(), 3);

  // A file that is not a backup: refused.
  const std::filesystem::path junk = dir_ / "junk.db";
  std::ofstream(junk) << "not a database\n";
  const CommandResult not_backup =
      RunImucald(dir_, {"restore", "--from", junk.string(), "--db", restored_db});
  EXPECT_EQ(not_backup.exit_code, 1) << Describe(not_backup);
  EXPECT_NE(not_backup.err.find("refusing to restore"), std::string::npos) << Describe(not_backup);

  // Over the stopped server's database: done, the replaced one kept as DB.pre-restore; the
  // server restarted on it serves the backup's active version.
  auto stopped = server_->SignalAndWait(SIGTERM, std::chrono::seconds(15));
  ASSERT_TRUE(stopped.ok()) << stopped.status();
  const CommandResult over =
      RunImucald(dir_, {"restore", "--from", backup.string(), "--db", server_->db_path()});
  ASSERT_EQ(over.exit_code, 0) << Describe(over);
  EXPECT_NE(over.out.find(".pre-restore"), std::string::npos) << Describe(over);
  {
    auto pre = storage::Store::Open(server_->db_path() + ".pre-restore");
    ASSERT_TRUE(pre.ok()) << pre.status();
    auto active = (*pre)->GetActive("robot-solved");
    ASSERT_TRUE(active.ok()) << active.status();
    EXPECT_EQ(active->version, 3) << "DB.pre-restore is the database the restore replaced";
  }
  ASSERT_TRUE(server_->Restart().ok());
  pb::ParameterSet back;
  ASSERT_TRUE(GetActive(*server_, "robot-solved", &back).ok());
  EXPECT_EQ(back.version(), 1);
  EXPECT_EQ(back.json(), active_before.json());
  EXPECT_EQ(back.crc32c(), active_before.crc32c());
}

// ---- Health probes -------------------------------------------------------------------------

// The database, its WAL files and backups hold every calibration and the token hashes: imucald
// keeps them from other users whatever umask it was started with (by hand, in a container),
// not only under the systemd unit's UMask=0077.
TEST_F(DaemonTest, TheDatabaseAndBackupsAreNotWorldReadable) {
  const mode_t before = ::umask(022);  // a login shell's: files 0644 unless imucald sets its own
  const std::filesystem::path dir = dir_ / "fresh";
  std::filesystem::create_directories(dir);
  absl::StatusOr<std::unique_ptr<ImucaldProcess>> fresh = ImucaldProcess::Start(dir.string());
  ASSERT_TRUE(fresh.ok()) << fresh.status();
  ASSERT_FALSE(OpenSession(**fresh, "robot-perm").empty());  // writes: the WAL files exist
  const std::filesystem::path backup = dir / "backup.db";
  const CommandResult run =
      RunImucald(dir_, {"backup", "--db", (*fresh)->db_path(), "--out", backup.string()});
  ::umask(before);
  ASSERT_EQ(run.exit_code, 0) << Describe(run);
  for (const std::filesystem::path& file :
       {std::filesystem::path((*fresh)->db_path()),
        std::filesystem::path((*fresh)->db_path() + "-wal"), backup}) {
    struct stat st {};
    ASSERT_EQ(::stat(file.c_str(), &st), 0) << file;
    EXPECT_EQ(st.st_mode & 07, 0) << file << " is readable by other users: mode " << std::oct
                                  << (st.st_mode & 0777);
    EXPECT_EQ(st.st_mode & 020, 0) << file << " is writable by the group";
  }
}

TEST_F(DaemonTest, HealthCheckIsZeroAgainstAServingImucaldAndNonZeroWhenNothingListens) {
  const CommandResult serving =
      RunImucald(dir_, {"--health-check", server_->address(), "--insecure", "--timeout", "5s"});
  EXPECT_EQ(serving.exit_code, 0) << Describe(serving);
  EXPECT_NE(serving.out.find(absl::StrCat(server_->address(), ": SERVING")), std::string::npos)
      << Describe(serving);

  // Without an address: the configuration's `listen`, plaintext as the configuration says.
  const std::filesystem::path config = dir_ / "imucald.toml";
  std::ofstream(config) << "listen = \"" << server_->address() << "\"\ninsecure = true\n";
  const CommandResult by_config =
      RunImucald(dir_, {"--health-check", "--config", config.string(), "--timeout", "5s"});
  EXPECT_EQ(by_config.exit_code, 0) << Describe(by_config);

  // Nothing listens on a port that was free a moment ago.
  const std::string nowhere = absl::StrCat("127.0.0.1:", testing_util::FreeLoopbackPort());
  const CommandResult down =
      RunImucald(dir_, {"--health-check", nowhere, "--insecure", "--timeout", "5s"});
  EXPECT_EQ(down.exit_code, 1) << Describe(down);
  EXPECT_NE(down.err.find(absl::StrCat(nowhere, ": health check failed")), std::string::npos)
      << Describe(down);
}

}  // namespace
}  // namespace imucal::server
