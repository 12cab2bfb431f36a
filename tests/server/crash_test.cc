// Crash safety: the real imucald (a separate process on a loopback port, its SQLite
// file in a temp dir) is SIGKILLed at random points of ingest and of solve/promote/rollback and
// restarted on the same file, again and again. After every restart:
//   - every acknowledged sample is stored, byte for byte (read back with the store's API) and
//     the server reports at least as much (GetSession);
//   - no half-written parameter version is visible: versions are 1..n without a gap, each one's
//     params JSON parses, names its own device/version/session and matches its crc32c, its
//     report parses, and each has the succeeded solve that made it (and no solve is left
//     running);
//   - the device's one active version is one that was fully written and is the one the
//     acknowledged operations say (or the operation in flight at the kill);
//   - sessions resume: each robot's Uploader continues after its last acknowledged batch (its
//     progress never goes back) and every session completes; a session killed mid-solve can
//     be solved again.
//
// Kill points come from a seeded RNG (the seed is printed; IMUCAL_CRASH_SEED overrides it):
// ingest is killed after a random number of acknowledgements, solve/promote after a random
// delay. Each TEST_P instance is one ctest entry, so ctest spreads them over the cores.
#include <signal.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <map>
#include <optional>
#include <memory>
#include <mutex>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "client/sdk/uploader.h"
#include "core/simulator.h"
#include "formats/crc32c.h"
#include "formats/params_json.h"
#include "grpcpp/grpcpp.h"
#include "gmock/gmock.h"
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
using Clock = std::chrono::steady_clock;

constexpr int kBatchSamples = 200;  // 1 s at 200 Hz per batch

using testing_util::SeedOr;

bool IsConnectionLoss(grpc::StatusCode code) {
  return code == grpc::StatusCode::UNAVAILABLE || code == grpc::StatusCode::DEADLINE_EXCEEDED ||
         code == grpc::StatusCode::CANCELLED;
}

// A unary call made around a restart: UNAVAILABLE (a call that met the killed server, or a
// connection to it that channels still share) is retried, each try waiting for the channel to
// be ready. Only for calls that may be repeated (reads, idempotent registration). `give_up`
// (optional) ends the retries early.
template <typename Call>
grpc::Status Retrying(Call call, const std::function<bool()>& give_up = nullptr) {
  grpc::Status s;
  for (int attempt = 0; attempt < 30; ++attempt) {
    grpc::ClientContext context;
    context.set_wait_for_ready(true);
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    s = call(&context);
    if (s.error_code() != grpc::StatusCode::UNAVAILABLE || (give_up && give_up())) return s;
  }
  return s;
}

using testing_util::SameBytes;  // tests/server/stored_samples.h

core::Capture Simulate(uint64_t seed, int extra_poses, double accel_noise_m_s2 = 0.02) {
  core::SimOptions o;
  o.seed = seed;
  o.extra_poses = extra_poses;
  o.accel_noise_m_s2 = accel_noise_m_s2;
  absl::StatusOr<core::SimResult> sim = core::Simulate(o);
  EXPECT_TRUE(sim.ok()) << sim.status();
  EXPECT_TRUE(sim.ok() && sim->capture.has_temp());
  return sim.ok() ? sim->capture : core::Capture();
}

class CrashTest : public testing_util::ImucaldTest {
 protected:
  CrashTest() : ImucaldTest("imucal_crash_test") {}

  // Registers `device` (idempotent, so retried) at 200 Hz in SI units.
  grpc::Status Register(const std::shared_ptr<grpc::Channel>& channel, const std::string& device,
                        const std::function<bool()>& give_up = nullptr) {
    auto stub = pb::DeviceService::NewStub(channel);
    const pb::RegisterDeviceRequest req = testing_util::SimDeviceRequest(device);
    pb::Device out;
    return Retrying([&](grpc::ClientContext* c) { return stub->RegisterDevice(c, req, &out); },
                    give_up);
  }

  // Registers `device` and opens its session. CreateSession is not idempotent: a kill after its
  // commit loses the answer, and the retry is FAILED_PRECONDITION naming the open session, which
  // is then the robot's (the device has no other).
  absl::StatusOr<std::string> OpenSession(const std::string& device, pb::Protocol protocol,
                                          const std::function<bool()>& give_up = nullptr) {
    auto channel = server_->NewChannel();
    if (grpc::Status s = Register(channel, device, give_up); !s.ok())
      return absl::UnavailableError(absl::StrCat("register ", device, ": ", s.error_message()));
    auto stub = pb::SessionService::NewStub(channel);
    for (int attempt = 0; attempt < 30; ++attempt) {
      pb::CreateSessionRequest create;
      create.set_device_id(device);
      create.set_protocol(protocol);
      pb::Session session;
      grpc::Status s =
          Retrying([&](grpc::ClientContext* c) { return stub->CreateSession(c, create, &session); },
                   give_up);
      if (s.ok()) return session.id();
      if (s.error_code() != grpc::StatusCode::FAILED_PRECONDITION)
        return absl::InternalError(absl::StrCat("create session: ", s.error_message()));
      pb::ListSessionsRequest list;
      list.set_device_id(device);
      list.set_state(pb::SESSION_STATE_OPEN);
      pb::ListSessionsResponse open;
      s = Retrying([&](grpc::ClientContext* c) { return stub->ListSessions(c, list, &open); },
                   give_up);
      if (s.ok() && open.sessions_size() == 1) return open.sessions(0).id();
      if (give_up && give_up()) break;
    }
    return absl::InternalError(absl::StrCat("no session for ", device));
  }

  pb::Session GetSession(const std::string& id) {
    auto stub = pb::SessionService::NewStub(server_->NewChannel());
    pb::GetSessionRequest req;
    req.set_session_id(id);
    pb::Session out;
    grpc::Status s =
        Retrying([&](grpc::ClientContext* c) { return stub->GetSession(c, req, &out); });
    EXPECT_TRUE(s.ok()) << id << ": " << s.error_message();
    return out;
  }

  // A store of our own on the server's file (WAL lets both in), opened fresh for each check so
  // that it never holds the file across a kill.
  std::unique_ptr<storage::Store> OpenStore() {
    absl::StatusOr<std::unique_ptr<storage::Store>> store =
        storage::Store::Open(server_->db_path());
    EXPECT_TRUE(store.ok()) << store.status();
    return store.ok() ? *std::move(store) : nullptr;
  }

  // The session's stored samples, checking that its batches are 1, 2, 3, ... without a gap.
  std::vector<storage::ImuSample> StoredSamples(storage::Store& store, const std::string& id) {
    std::vector<storage::ImuSample> out;
    absl::StatusOr<std::vector<storage::SampleBatch>> batches = store.ReadBatches(id);
    EXPECT_TRUE(batches.ok()) << batches.status();
    if (!batches.ok()) return out;
    int64_t seq = 0;
    for (const storage::SampleBatch& b : *batches) {
      EXPECT_EQ(b.seq, ++seq) << id << ": batches are 1, 2, 3, ... with no gap";
      EXPECT_TRUE(storage::DecodeSamplesInto(b.payload, &out).ok()) << id << " batch " << b.seq;
    }
    return out;
  }
};

// ---- Ingest ----------------------------------------------------------------------------------

// Robots stream sessions through the SDK's Uploader, one device and session after another,
// while the test kills the server after a random number of acknowledgements.
class CrashIngestTest : public CrashTest, public testing::WithParamInterface<uint64_t> {
 protected:
  static constexpr int kRobots = 3;
  static constexpr int kKills = 15;
  static constexpr int kMaxAcksBetweenKills = 60;

  struct SessionLog {
    int64_t acked = 0;  // the most samples the robot saw acknowledged
    bool complete = false;
  };

  void TearDown() override {
    StopRobots(/*cancel=*/true);  // after a failure: cut the uploads short
    CrashTest::TearDown();
  }

  void StartRobots() {
    running_ = kRobots;
    for (int r = 0; r < kRobots; ++r)
      robots_.emplace_back([this, r] {
        RunRobot(r);
        std::lock_guard lock(mu_);
        --running_;
        cv_.notify_all();
      });
  }

  // Each robot finishes its session (or, with `cancel`, stops its upload), then stops.
  void StopRobots(bool cancel) {
    std::unique_lock lock(mu_);
    stopping_ = true;
    cancelling_ = cancel;
    // An Upload that starts after a Cancel() forgets it: cancel again until every robot ended.
    while (!cv_.wait_for(lock, std::chrono::milliseconds(cancel ? 100 : 60000),
                         [this] { return running_ == 0; })) {
      if (!cancel) {
        errors_.push_back("the robots did not finish their sessions in 60 s");
        cancel = cancelling_ = true;
      }
      for (sdk::Uploader* u : uploaders_) u->Cancel();
    }
    lock.unlock();
    for (std::thread& t : robots_) t.join();
    robots_.clear();
  }

  void RunRobot(int robot) {
    for (int n = 0;; ++n) {
      {
        std::lock_guard lock(mu_);
        if (stopping_) return;
      }
      absl::StatusOr<std::string> session =
          OpenSession(absl::StrCat("robot-", robot, "-", n), pb::PROTOCOL_SIX_FACE, [this] {
            std::lock_guard lock(mu_);
            return cancelling_;
          });
      if (!session.ok()) return Fail(std::string(session.status().message()));
      {
        std::lock_guard lock(mu_);
        sessions_[*session];
      }
      sdk::UploadOptions o;
      o.batch_samples = kBatchSamples;
      // Reconnects without progress, counted from the last one that made some: a restart
      // takes well under the 100 * 200 ms this allows.
      o.initial_backoff = absl::Milliseconds(20);
      o.max_backoff = absl::Milliseconds(200);
      o.progress = [this, id = *session](int64_t acked, int64_t) { OnAck(id, acked); };
      sdk::Uploader uploader(server_->NewChannel(), o);
      {
        std::lock_guard lock(mu_);
        uploaders_.insert(&uploader);
      }
      absl::StatusOr<sdk::UploadResult> result = uploader.Upload(*session, capture_);
      std::lock_guard lock(mu_);
      uploaders_.erase(&uploader);
      if (!result.ok()) {
        errors_.push_back(absl::StrCat(*session, ": ", result.status().message()));
        cv_.notify_all();
        return;
      }
      sessions_[*session].complete = true;
      reconnects_ += result->reconnects;
    }
  }

  // The robot resumes after its last acknowledged batch: what it sees acknowledged never
  // goes back, across any number of kills.
  void OnAck(const std::string& session, int64_t acked) {
    std::lock_guard lock(mu_);
    SessionLog& log = sessions_[session];
    if (acked < log.acked) {
      errors_.push_back(absl::StrCat(session, ": acknowledged samples went back from ", log.acked,
                                     " to ", acked));
    }
    log.acked = std::max(log.acked, acked);
    ++acks_;
    cv_.notify_all();
  }

  void Fail(const std::string& error) {
    std::lock_guard lock(mu_);
    errors_.push_back(error);
    cv_.notify_all();
  }

  // Every sample acknowledged before the kill (`acked`, per session) is stored byte for byte
  // and the server reports it. Returns the samples checked; counts losses in lost_samples_.
  int64_t CheckAcked(const std::map<std::string, SessionLog>& acked) {
    std::unique_ptr<storage::Store> store = OpenStore();
    if (store == nullptr) return 0;
    int64_t checked = 0;
    for (const auto& [id, log] : acked) {
      const std::vector<storage::ImuSample> stored = StoredSamples(*store, id);
      const int64_t n = static_cast<int64_t>(stored.size());
      lost_samples_ += std::max<int64_t>(0, log.acked - n);
      EXPECT_GE(n, log.acked) << id << ": acknowledged samples missing after the kill";
      EXPECT_LE(n, static_cast<int64_t>(capture_.size())) << id;
      for (size_t i = 0; i < stored.size() && i < capture_.size(); ++i) {
        if (!SameBytes(stored[i], capture_, i)) {
          ADD_FAILURE() << id << ": stored sample " << i << " differs from the capture";
          break;
        }
      }
      EXPECT_GE(GetSession(id).samples(), log.acked) << id << ": the server lost acked samples";
      checked += log.acked;
    }
    return checked;
  }

  core::Capture capture_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::map<std::string, SessionLog> sessions_;  // guarded by mu_
  int64_t acks_ = 0;                            // guarded by mu_: every ack of every robot
  bool stopping_ = false;                       // guarded by mu_: finish the session, then stop
  bool cancelling_ = false;                     // guarded by mu_: stop now
  int running_ = 0;                             // guarded by mu_: robots not yet stopped
  std::set<sdk::Uploader*> uploaders_;          // guarded by mu_: uploads in progress
  std::vector<std::thread> robots_;
  std::vector<std::string> errors_;  // guarded by mu_
  int reconnects_ = 0;               // guarded by mu_
  int64_t lost_samples_ = 0;
};

TEST_P(CrashIngestTest, SigkillAfterRandomAcksLosesNoAckedSampleAndSessionsComplete) {
  const uint64_t seed = SeedOr(GetParam());
  SCOPED_TRACE(absl::StrCat("seed ", seed));
  std::mt19937_64 rng(seed);
  capture_ = Simulate(seed, /*extra_poses=*/0);
  ASSERT_GT(capture_.size(), 50u * kBatchSamples);

  StartRobots();
  int64_t acked_checked = 0;
  int kills = 0;
  for (; kills < kKills; ++kills) {
    std::map<std::string, SessionLog> acked;
    {
      std::unique_lock lock(mu_);
      const int64_t target =
          acks_ + std::uniform_int_distribution<int64_t>(1, kMaxAcksBetweenKills)(rng);
      const bool reached = cv_.wait_for(lock, std::chrono::seconds(60),
                                        [&] { return acks_ >= target || !errors_.empty(); });
      if (!reached || !errors_.empty()) break;
    }
    server_->Stop(SIGKILL);  // mid-stream: every robot has batches in flight
    {
      std::lock_guard lock(mu_);
      for (const auto& [id, log] : sessions_)
        if (!log.complete) acked[id] = log;  // complete ones are checked at the end
    }
    ASSERT_TRUE(server_->Restart().ok()) << "kill " << kills;
    acked_checked += CheckAcked(acked);
    if (HasFailure()) break;
  }
  StopRobots(/*cancel=*/false);
  for (const std::string& e : errors_) ADD_FAILURE() << e;
  ASSERT_EQ(kills, kKills) << "the robots stopped acknowledging";

  // Every session completed: the whole capture once, in order, byte for byte.
  std::unique_ptr<storage::Store> store = OpenStore();
  ASSERT_NE(store, nullptr);
  int complete = 0;
  for (const auto& [id, log] : sessions_) {
    ASSERT_TRUE(log.complete) << id;
    const std::vector<storage::ImuSample> stored = StoredSamples(*store, id);
    ASSERT_EQ(stored.size(), capture_.size()) << id;
    for (size_t i = 0; i < stored.size(); ++i)
      ASSERT_TRUE(SameBytes(stored[i], capture_, i)) << id << " sample " << i;
    const pb::Session s = GetSession(id);
    EXPECT_EQ(s.samples(), static_cast<int64_t>(capture_.size())) << id;
    EXPECT_EQ(s.last_acked_seq(),
              static_cast<int64_t>((capture_.size() + kBatchSamples - 1) / kBatchSamples))
        << id;
    ++complete;
  }
  EXPECT_EQ(lost_samples_, 0);
  EXPECT_GE(reconnects_, kKills) << "each kill breaks at least one robot's stream";
  std::printf(
      "[ crash    ] ingest: %d kills survived, %lld acknowledged samples checked at the "
      "kills, %lld lost; %d sessions completed, %d reconnects\n",
      kills, static_cast<long long>(acked_checked), static_cast<long long>(lost_samples_), complete,
      reconnects_);
}

INSTANTIATE_TEST_SUITE_P(Seeds, CrashIngestTest, testing::Values(uint64_t{101}, uint64_t{202}));

// ---- Solve, promote, rollback ----------------------------------------------------------------

// Two devices: `pass_` streams a capture that passes the quality gate (each solve makes an
// active version), `warn_` one that does not (each solve makes a candidate: with 1 m/s^2 of
// accelerometer noise per sample the pose residual is about 35 mg, between the gate's 20 mg
// pass and 50 mg fail). Each round
// re-solves both sessions while a technician promotes and rolls back `warn_`'s versions, and
// kills the server after a random delay.
class CrashSolveTest : public CrashTest, public testing::WithParamInterface<uint64_t> {
 protected:
  static constexpr int kKills = 13;
  static constexpr char kPass[] = "robot-pass";
  static constexpr char kWarn[] = "robot-warn";

  void SetUp() override {
    CrashTest::SetUp();
    if (IsSkipped() || HasFatalFailure()) return;
    pass_session_ = Upload(kPass, Simulate(11, /*extra_poses=*/8), &pass_samples_);
    warn_session_ =
        Upload(kWarn, Simulate(12, /*extra_poses=*/0, /*accel_noise_m_s2=*/1.0), &warn_samples_);
  }

  std::string Upload(const std::string& device, const core::Capture& capture, int64_t* samples) {
    absl::StatusOr<std::string> session = OpenSession(device, pb::PROTOCOL_SIX_FACE);
    EXPECT_TRUE(session.ok()) << session.status();
    if (!session.ok()) return "";
    sdk::UploadOptions o;
    o.batch_samples = 2000;
    absl::StatusOr<sdk::UploadResult> result =
        sdk::Uploader(server_->NewChannel(), o).Upload(*session, capture);
    EXPECT_TRUE(result.ok()) << result.status();
    *samples = static_cast<int64_t>(capture.size());
    return *session;
  }

  // Solves the session and waits for the job's end: WatchSession ends when the session
  // closes, at once if the solve has already finished. Returns the job.
  pb::SolveJob SolveAndWait(const std::string& session, uint64_t seed) {
    auto channel = server_->NewChannel();
    auto stub = pb::SessionService::NewStub(channel);
    pb::SolveSessionRequest req;
    req.set_session_id(session);
    req.set_seed(seed);
    pb::SolveJob job;
    grpc::Status s =
        Retrying([&](grpc::ClientContext* c) { return stub->SolveSession(c, req, &job); });
    EXPECT_TRUE(s.ok()) << s.error_message();
    EXPECT_TRUE(testing_util::FollowToEnd(stub.get(), session, std::chrono::seconds(120)).ok());
    pb::GetSolveJobRequest get;
    get.set_job_id(job.id());
    s = Retrying([&](grpc::ClientContext* c) { return stub->GetSolveJob(c, get, &job); });
    EXPECT_TRUE(s.ok()) << s.error_message();
    EXPECT_EQ(job.state(), pb::JOB_STATE_DONE) << job.error();
    return job;
  }

  // What a device holds after a restart, checked version by version.
  struct Versions {
    int count = 0;
    int active = 0;  // 0: none
    std::map<int, pb::ParameterSet> headers;
  };

  // No half-written version: 1..n without a gap, each one's JSON complete (crc32c, parses,
  // names its device, version and session), its report parses, and exactly one is active: the
  // one GetActiveParameters serves and the device names.
  Versions CheckVersions(storage::Store& store, const std::string& device,
                         const std::string& session) {
    Versions out;
    CheckVersionsInto(store, device, session, &out);
    return out;
  }
  void CheckVersionsInto(storage::Store& store, const std::string& device,
                         const std::string& session, Versions* versions) {
    Versions& out = *versions;
    auto stub = pb::ParameterService::NewStub(server_->NewChannel());
    pb::ListVersionsRequest list;
    list.set_device_id(device);
    list.set_page_size(1000);
    pb::ListVersionsResponse listed;
    grpc::Status s =
        Retrying([&](grpc::ClientContext* c) { return stub->ListVersions(c, list, &listed); });
    EXPECT_TRUE(s.ok()) << s.error_message();
    for (const pb::ParameterSet& header : listed.versions()) {
      const int v = ++out.count;
      EXPECT_EQ(header.version(), v) << device << ": versions are 1, 2, 3, ... with no gap";
      out.headers[v] = header;
      if (header.state() == pb::VERSION_STATE_ACTIVE) {
        EXPECT_EQ(out.active, 0) << device << ": two active versions, " << out.active << " and "
                                 << v;
        out.active = v;
      }
      pb::GetParametersRequest get;
      get.set_device_id(device);
      get.set_version(v);
      pb::ParameterSet full;
      s = Retrying([&](grpc::ClientContext* c) { return stub->GetParameters(c, get, &full); });
      ASSERT_TRUE(s.ok()) << device << " v" << v << ": " << s.error_message();
      EXPECT_EQ(full.crc32c(), formats::Crc32c(full.json())) << device << " v" << v;
      absl::StatusOr<core::ParamSet> params = formats::ParamSetFromJson(full.json());
      ASSERT_TRUE(params.ok()) << device << " v" << v << ": " << params.status();
      EXPECT_EQ(params->device, device);
      EXPECT_EQ(params->version, v) << device << ": the JSON of version " << v;
      EXPECT_EQ(params->source_session, session);
      absl::StatusOr<storage::ParamVersion> stored = store.GetVersion(device, v);
      ASSERT_TRUE(stored.ok()) << stored.status();
      EXPECT_EQ(stored->params_json, full.json());
      absl::StatusOr<core::ParamSet> from_report = formats::ParamSetFromJson(stored->report_json);
      ASSERT_TRUE(from_report.ok()) << device << " v" << v << " report: " << from_report.status();
      EXPECT_EQ(from_report->version, v);
    }
    pb::GetActiveParametersRequest active;
    active.set_device_id(device);
    pb::ParameterSet served;
    s = Retrying(
        [&](grpc::ClientContext* c) { return stub->GetActiveParameters(c, active, &served); });
    if (out.active == 0) {
      EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND) << device;
    } else {
      EXPECT_TRUE(s.ok()) << s.error_message();
      EXPECT_EQ(served.version(), out.active) << device;
      EXPECT_EQ(served.crc32c(), formats::Crc32c(served.json())) << device;
    }
    auto devices = pb::DeviceService::NewStub(server_->NewChannel());
    pb::GetDeviceRequest get_device;
    get_device.set_device_id(device);
    pb::Device d;
    s = Retrying([&](grpc::ClientContext* c) { return devices->GetDevice(c, get_device, &d); });
    EXPECT_TRUE(s.ok()) << s.error_message();
    EXPECT_EQ(d.active_version(), out.active) << device;
  }

  // A restarted server runs again the solves its kill interrupted (Store::ClaimLapsedSolve):
  // waits, by following the session's events, until the session is no longer solving.
  void WaitWhileSolving(const std::string& session) {
    auto stub = pb::SessionService::NewStub(server_->NewChannel());
    EXPECT_TRUE(testing_util::FollowWhileSolving(stub.get(), session, std::chrono::seconds(120)));
    EXPECT_NE(GetSession(session).state(), pb::SESSION_STATE_SOLVING) << session;
  }

  // Every version was made by a succeeded solve of the session (FinishSolve is one
  // transaction), and once, however many servers started it; no solve is left running or
  // failed (the restart ran the interrupted ones again), and the session is solved if its last
  // solve succeeded, else open again (it can be re-solved). Returns the number of solves a kill
  // interrupted and the restart finished.
  int CheckSolves(storage::Store& store, const std::string& session, int versions,
                  int64_t samples) {
    absl::StatusOr<std::vector<storage::Solve>> solves = store.ListSolves(session);
    EXPECT_TRUE(solves.ok()) << solves.status();
    if (!solves.ok() || solves->empty()) return 0;
    std::set<int> made;
    int resumed = 0;
    for (const storage::Solve& s : *solves) {
      EXPECT_EQ(s.state, storage::SolveState::kSucceeded)
          << "solve " << s.id << " " << storage::SolveStateName(s.state) << ": " << s.error;
      if (s.state == storage::SolveState::kSucceeded) {
        EXPECT_TRUE(made.insert(s.version).second) << "two solves made version " << s.version;
      }
      resumed += s.attempts > 1;
    }
    std::set<int> all;
    for (int v = 1; v <= versions; ++v) all.insert(v);
    EXPECT_EQ(made, all) << session << ": versions without their solve, or solves without theirs";
    const pb::Session s = GetSession(session);
    const bool last_succeeded = solves->back().state == storage::SolveState::kSucceeded;
    EXPECT_EQ(s.state(), last_succeeded ? pb::SESSION_STATE_SOLVED : pb::SESSION_STATE_OPEN)
        << session;
    EXPECT_EQ(s.samples(), samples) << session << ": the capture changed";
    return resumed;
  }

  std::string pass_session_, warn_session_;
  int64_t pass_samples_ = 0, warn_samples_ = 0;
};

// The technician during one round: solves both sessions, then promotes and rolls back the
// `warn` device's versions at random until the server dies. Knows which operation on the
// device's active version was last acknowledged and which one was in flight.
class Technician {
 public:
  Technician(std::shared_ptr<grpc::Channel> channel, uint64_t seed, std::string pass_session,
             std::string warn_session, std::string warn_device, int active)
      : sessions_(pb::SessionService::NewStub(channel)),
        params_(pb::ParameterService::NewStub(channel)),
        rng_(seed),
        warn_device_(std::move(warn_device)),
        acked_active_(active) {
    thread_ = std::thread([this, channel, seed, pass_session, warn_session] {
      // The server is up: wait for this channel to reach it (not for the server).
      if (!channel->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(10)))
        return;
      if (Solve(pass_session, seed) && Solve(warn_session, seed)) Operate();
    });
  }
  ~Technician() { Join(); }

  void Join() {
    if (thread_.joinable()) thread_.join();
  }
  int acked_active() const { return acked_active_; }
  int in_flight() const { return in_flight_; }
  int acked_ops() const { return acked_ops_; }
  const std::vector<std::string>& errors() const { return errors_; }

 private:
  static grpc::ClientContext* Prepare(grpc::ClientContext* c) {
    c->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    return c;
  }

  // An error is the kill (the round ends) or a bug (noted).
  bool Ok(const grpc::Status& s, const std::string& what) {
    if (s.ok()) return true;
    if (!IsConnectionLoss(s.error_code()))
      errors_.push_back(absl::StrCat(what, ": ", s.error_code(), " ", s.error_message()));
    return false;
  }

  bool Solve(const std::string& session, uint64_t seed) {
    grpc::ClientContext c;
    pb::SolveSessionRequest req;
    req.set_session_id(session);
    req.set_seed(seed);
    pb::SolveJob job;
    return Ok(sessions_->SolveSession(Prepare(&c), req, &job), "solve " + session);
  }

  void Operate() {
    for (;;) {
      grpc::ClientContext c;
      pb::ListVersionsRequest list;
      list.set_device_id(warn_device_);
      list.set_page_size(1000);
      pb::ListVersionsResponse versions;
      if (!Ok(params_->ListVersions(Prepare(&c), list, &versions), "list")) return;
      std::vector<int> candidates;
      int active = 0;
      for (const pb::ParameterSet& v : versions.versions()) {
        if (v.state() == pb::VERSION_STATE_CANDIDATE) candidates.push_back(v.version());
        if (v.state() == pb::VERSION_STATE_ACTIVE) active = v.version();
      }
      if (active != acked_active_) {
        errors_.push_back(absl::StrCat("active ", active, ", acknowledged ", acked_active_));
        return;
      }
      // Promote a candidate or roll back to an older version, with equal odds per target.
      const int options = static_cast<int>(candidates.size()) + std::max(0, active - 1);
      if (options == 0) continue;  // the round's solve has not made a candidate yet
      const int pick = std::uniform_int_distribution<int>(0, options - 1)(rng_);
      const bool promote = pick < static_cast<int>(candidates.size());
      const int target = promote ? candidates[static_cast<size_t>(pick)]
                                 : pick - static_cast<int>(candidates.size()) + 1;
      in_flight_ = target;
      grpc::ClientContext op;
      pb::ParameterSet result;
      grpc::Status s;
      if (promote) {
        pb::PromoteRequest req;
        req.set_device_id(warn_device_);
        req.set_version(target);
        req.set_reason("crash test");
        s = params_->Promote(Prepare(&op), req, &result);
      } else {
        pb::RollbackRequest req;
        req.set_device_id(warn_device_);
        req.set_to_version(target);
        req.set_reason("crash test");
        s = params_->Rollback(Prepare(&op), req, &result);
      }
      if (!Ok(s, absl::StrCat(promote ? "promote " : "rollback ", target))) return;
      if (result.version() != target || result.state() != pb::VERSION_STATE_ACTIVE)
        errors_.push_back(
            absl::StrCat("promote/rollback to ", target, " answered ", result.ShortDebugString()));
      acked_active_ = target;
      in_flight_ = 0;
      ++acked_ops_;
    }
  }

  std::unique_ptr<pb::SessionService::Stub> sessions_;
  std::unique_ptr<pb::ParameterService::Stub> params_;
  std::mt19937_64 rng_;
  std::string warn_device_;
  // Written by the thread, read after Join().
  int acked_active_ = 0;  // the active version as of the last acknowledged operation
  int in_flight_ = 0;     // the target of an operation sent and not answered; 0: none
  int acked_ops_ = 0;
  std::vector<std::string> errors_;
  std::thread thread_;
};

TEST_P(CrashSolveTest, SigkillDuringSolvePromoteRollbackLeavesOnlyWholeVersions) {
  const uint64_t seed = SeedOr(GetParam());
  SCOPED_TRACE(absl::StrCat("seed ", seed));
  std::mt19937_64 rng(seed);
  ASSERT_FALSE(pass_session_.empty());
  ASSERT_FALSE(warn_session_.empty());

  // A first solve of each (the warn device's candidate is promoted, so that it has an active
  // version to roll back from), timed: the kills fall within 3 solve times.
  const Clock::time_point t0 = Clock::now();
  ASSERT_TRUE(SolveAndWait(pass_session_, 1).activated());
  ASSERT_FALSE(SolveAndWait(warn_session_, 1).activated());
  const auto solve_time = (Clock::now() - t0) / 2;
  {
    auto stub = pb::ParameterService::NewStub(server_->NewChannel());
    pb::PromoteRequest promote;
    promote.set_device_id(kWarn);
    promote.set_version(1);
    pb::ParameterSet out;
    ASSERT_TRUE(
        Retrying([&](grpc::ClientContext* c) { return stub->Promote(c, promote, &out); }).ok());
  }
  std::unique_ptr<storage::Store> store = OpenStore();
  ASSERT_NE(store, nullptr);
  Versions pass = CheckVersions(*store, kPass, pass_session_);
  Versions warn = CheckVersions(*store, kWarn, warn_session_);
  store.reset();
  ASSERT_EQ(pass.active, 1);
  ASSERT_EQ(warn.active, 1);

  int resumed = 0, acked_ops = 0, in_flight_applied = 0, in_flight_lost = 0;
  for (int kill = 0; kill < kKills; ++kill) {
    SCOPED_TRACE(absl::StrCat("kill ", kill));
    const Versions pass_before = pass, warn_before = warn;
    Technician tech(server_->NewChannel(), seed * 1000 + kill, pass_session_, warn_session_, kWarn,
                    warn.active);
    // The random kill point itself (not a wait for anything): somewhere in the two solves,
    // their commits and the promotes and rollbacks that run meanwhile and after them.
    const auto delay = std::chrono::duration_cast<std::chrono::microseconds>(
        solve_time * std::uniform_real_distribution<double>(0.0, 3.0)(rng));
    std::this_thread::sleep_for(delay);
    server_->Stop(SIGKILL);
    tech.Join();
    for (const std::string& e : tech.errors()) ADD_FAILURE() << e;
    ASSERT_TRUE(server_->Restart().ok());
    WaitWhileSolving(pass_session_);
    WaitWhileSolving(warn_session_);

    store = OpenStore();
    ASSERT_NE(store, nullptr);
    pass = CheckVersions(*store, kPass, pass_session_);
    warn = CheckVersions(*store, kWarn, warn_session_);
    resumed = CheckSolves(*store, pass_session_, pass.count, pass_samples_) +
              CheckSolves(*store, warn_session_, warn.count, warn_samples_);
    store.reset();
    ASSERT_FALSE(HasFailure());

    // The pass device: its round's solve made one version or none; a version that passed the
    // gate was activated in the same transaction that wrote it.
    ASSERT_GE(pass.count, pass_before.count);
    ASSERT_LE(pass.count, pass_before.count + 1);
    if (pass.count > pass_before.count) {
      EXPECT_EQ(pass.active, pass.count);
    } else {
      EXPECT_EQ(pass.active, pass_before.active);
    }
    // The warn device: its solve only adds candidates; its active version is the one the last
    // acknowledged promote/rollback made, or the target of the one in flight at the kill.
    ASSERT_GE(warn.count, warn_before.count);
    ASSERT_LE(warn.count, warn_before.count + 1);
    if (warn.count > warn_before.count) {
      EXPECT_NE(warn.headers[warn.count].verdict(), "pass")
          << "the warn capture's solve makes a candidate; only a promote activates it";
    }
    if (warn.active != tech.acked_active()) {
      EXPECT_EQ(warn.active, tech.in_flight())
          << "active " << warn.active << ", acknowledged " << tech.acked_active();
      ++in_flight_applied;
    } else if (tech.in_flight() != 0 && tech.in_flight() != warn.active) {
      ++in_flight_lost;  // sent, killed before its commit: never acknowledged, so allowed
    }
    acked_ops += tech.acked_ops();
  }

  // Sessions resume: both solve again to the end, and the new versions are whole.
  const pb::SolveJob pass_job = SolveAndWait(pass_session_, 99);
  EXPECT_TRUE(pass_job.activated());
  EXPECT_EQ(pass_job.version(), pass.count + 1);
  const pb::SolveJob warn_job = SolveAndWait(warn_session_, 99);
  EXPECT_EQ(warn_job.version(), warn.count + 1);
  store = OpenStore();
  ASSERT_NE(store, nullptr);
  EXPECT_EQ(CheckVersions(*store, kPass, pass_session_).active, pass.count + 1);
  EXPECT_EQ(CheckVersions(*store, kWarn, warn_session_).count, warn.count + 1);
  CheckSolves(*store, pass_session_, pass.count + 1, pass_samples_);
  CheckSolves(*store, warn_session_, warn.count + 1, warn_samples_);
  std::printf(
      "[ crash    ] solve/promote: %d kills survived (solve time %.0f ms); %d solves "
      "interrupted by a kill and finished by the restart, %d + %d versions whole, %d promotes/"
      "rollbacks acknowledged, in flight at a kill: %d applied, %d not\n",
      kKills, 1e3 * std::chrono::duration<double>(solve_time).count(), resumed, pass.count,
      warn.count, acked_ops, in_flight_applied, in_flight_lost);
}

INSTANTIATE_TEST_SUITE_P(Seeds, CrashSolveTest, testing::Values(uint64_t{303}, uint64_t{404}));

// A kill mid-solve, for the third time for this solve, while the device has already opened its
// next session (CreateSession allows that: a solving session is not open). The restart must
// still serve: the solve has had its max_solve_attempts (3) and is failed rather than run a
// fourth time, and its session, which cannot reopen beside the open one, is left failed, from
// where it can be solved again; the new session takes samples.
TEST_F(CrashTest, ASolveThatStoppedItsServerThreeTimesFailsAndTheRestartServes) {
  const core::Capture capture = Simulate(11, /*extra_poses=*/8);
  absl::StatusOr<std::string> first = OpenSession("robot-busy", pb::PROTOCOL_SIX_FACE);
  ASSERT_TRUE(first.ok()) << first.status();
  ASSERT_TRUE(sdk::Uploader(server_->NewChannel()).Upload(*first, capture).ok());
  // The solve the kill interrupts, started through the store so that it is still running when
  // the kill comes (the server's own would finish in ~0.1 s); the same rows either way.
  std::unique_ptr<storage::Store> store = OpenStore();
  ASSERT_NE(store, nullptr);
  absl::StatusOr<storage::Solve> solve = store->StartSolve(*first, "technician");
  ASSERT_TRUE(solve.ok()) << solve.status();
  for (int restarted = 0; restarted < 2; ++restarted) {  // two earlier lives of a server ran it
    absl::StatusOr<std::optional<storage::Solve>> claimed =
        store->ClaimLapsedSolve(absl::Now(), {"crashed-server", absl::InfinitePast()});
    ASSERT_TRUE(claimed.ok() && claimed->has_value()) << claimed.status();
  }
  store.reset();
  absl::StatusOr<std::string> next = OpenSession("robot-busy", pb::PROTOCOL_SIX_FACE);
  ASSERT_TRUE(next.ok()) << next.status();
  ASSERT_NE(*next, *first);

  server_->Stop(SIGKILL);
  ASSERT_TRUE(server_->Restart().ok()) << "imucald did not come back";

  store = OpenStore();
  ASSERT_NE(store, nullptr);
  absl::StatusOr<storage::Solve> failed = store->GetSolve(solve->id);
  ASSERT_TRUE(failed.ok()) << failed.status();
  EXPECT_EQ(failed->state, storage::SolveState::kFailed);
  EXPECT_THAT(failed->error, testing::HasSubstr("started 3 times and each time its server stopped"));
  EXPECT_EQ(failed->attempts, 4);  // the restart's claim counted, and it ran nothing
  store.reset();
  EXPECT_EQ(GetSession(*first).state(), pb::SESSION_STATE_FAILED);
  EXPECT_EQ(GetSession(*next).state(), pb::SESSION_STATE_OPEN);
  sdk::UploadOptions o;
  o.batch_samples = 2000;
  EXPECT_TRUE(sdk::Uploader(server_->NewChannel(), o).Upload(*next, capture).ok());
  auto stub = pb::SessionService::NewStub(server_->NewChannel());
  pb::SolveSessionRequest req;
  req.set_session_id(*first);
  pb::SolveJob job;
  const grpc::Status s =
      Retrying([&](grpc::ClientContext* c) { return stub->SolveSession(c, req, &job); });
  EXPECT_TRUE(s.ok()) << "the failed session solves again: " << s.error_message();
}

}  // namespace
}  // namespace imucal::server
