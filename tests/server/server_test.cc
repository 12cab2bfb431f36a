// The server through its real API: an in-process imucald on a loopback port with a SQLite file,
// driven by the generated stubs.
#include "server/server.h"

#include <cctype>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <utility>
#include <vector>

#include "core/accel_solver.h"
#include "core/calibrate/calibrate.h"
#include "core/simulator.h"
#include "formats/crc32c.h"
#include "formats/params_json.h"
#include "gmock/gmock.h"
#include "grpcpp/generic/generic_stub.h"
#include "grpcpp/grpcpp.h"
#include "gtest/gtest.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/active_cache.h"
#include "server/convert.h"
#include "server/status_util.h"
#include "server/stream_registry.h"
#include "storage/store.h"
#include "storage/types.h"
#include "tests/pg_test_cluster.h"
#include "tests/server/resume_proofs.h"
#include "tests/server/tcp_proxy.h"
#include "tests/server/watch.h"
#include "tests/test_dir.h"
#include "util/db.h"

namespace imucal::server {
namespace {

using std::chrono::seconds;
using std::chrono::system_clock;

constexpr int kBatch = 200;

class ServerTest : public testing::Test {
 protected:
  void SetUp() override {
    options_.listen = "127.0.0.1:0";
    options_.security.insecure = true;  // plaintext on loopback: auth_matrix_test covers TLS
    options_.db_path = dir_.File("imucal.db");
    StartServer();
  }

  // (Re)starts the server on options_.db_path and connects the stubs to it.
  void StartServer() {
    server_.reset();
    auto server = Server::Start(options_);
    ASSERT_TRUE(server.ok()) << server.status();
    server_ = *std::move(server);
    channel_ = grpc::CreateChannel(server_->address(), grpc::InsecureChannelCredentials());
    devices_ = v1::DeviceService::NewStub(channel_);
    sessions_ = v1::SessionService::NewStub(channel_);
    params_ = v1::ParameterService::NewStub(channel_);
  }

  // A second server on options_'s database, as replica "replica-b" (several servers sharing one
  // database).
  void StartReplicaB(std::unique_ptr<Server>* b) {
    ServerOptions b_options = options_;
    b_options.sessions.replica_id = "replica-b";
    absl::StatusOr<std::unique_ptr<Server>> started = Server::Start(b_options);
    ASSERT_TRUE(started.ok()) << started.status();
    *b = *std::move(started);
  }

  static std::unique_ptr<grpc::ClientContext> Ctx() {
    auto ctx = std::make_unique<grpc::ClientContext>();
    ctx->set_deadline(system_clock::now() + seconds(20));
    return ctx;
  }

  v1::Device Register(const std::string& id) {
    v1::RegisterDeviceRequest req;
    req.mutable_device()->set_id(id);
    req.mutable_device()->set_sensor_model("sim");
    req.mutable_device()->set_nominal_rate_hz(200);
    req.mutable_device()->set_accel_unit("m/s^2");
    req.mutable_device()->set_gyro_unit("rad/s");
    v1::Device out;
    grpc::Status s = devices_->RegisterDevice(Ctx().get(), req, &out);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return out;
  }

  v1::Session Create(const std::string& device, v1::Protocol protocol, grpc::Status* status) {
    v1::CreateSessionRequest req;
    req.set_device_id(device);
    req.set_protocol(protocol);
    v1::Session out;
    *status = sessions_->CreateSession(Ctx().get(), req, &out);
    return out;
  }

  static core::SimResult Sim() {
    core::SimOptions o;
    o.seed = 11;
    // Six faces alone leave the cross-axis and quadratic terms undetermined (verdict warn):
    // eight free orientations after them make a capture that passes the quality gate.
    o.extra_poses = 8;
    auto r = core::Simulate(o);
    EXPECT_TRUE(r.ok()) << r.status();
    return *std::move(r);
  }

  static std::vector<v1::SampleBatch> Batches(const core::Capture& cap, const std::string& id) {
    std::vector<v1::SampleBatch> out;
    for (size_t b = 0; b < cap.size(); b += kBatch) {
      v1::SampleBatch batch;
      batch.set_session_id(id);
      batch.set_seq(static_cast<int64_t>(out.size()) + 1);
      for (size_t i = b; i < std::min(cap.size(), b + kBatch); ++i) {
        batch.add_t_s(cap.t_s[i]);
        for (int k = 0; k < 3; ++k) {
          batch.add_accel(cap.accel[i](k));
          batch.add_gyro(cap.gyro[i](k));
        }
        if (cap.has_temp()) batch.add_temp_c(cap.temp[i]);
      }
      out.push_back(std::move(batch));
    }
    return out;
  }

  // Streams `batches` on one stream; returns the stream's final status and the acks. A stream
  // that continues a session proves it continues the stored capture (SampleBatch.
  // resume_sha256): the batches this test had acknowledged give the proof
  // (tests/server/resume_proofs.h; validation_test checks the proof itself).
  // `through`: another server's stub (default: this test's server).
  grpc::Status Stream(std::vector<v1::SampleBatch> batches, std::vector<v1::SampleAck>* acks,
                      v1::SessionService::Stub* through = nullptr) {
    if (through == nullptr) through = sessions_.get();
    proofs_.Prove(&batches, through);
    std::vector<v1::SampleAck> got;
    auto ctx = Ctx();
    auto stream = through->StreamSamples(ctx.get());
    for (const v1::SampleBatch& b : batches) {
      if (!stream->Write(b)) break;
      v1::SampleAck ack;
      if (!stream->Read(&ack)) break;
      got.push_back(ack);
    }
    stream->WritesDone();
    v1::SampleAck extra;
    while (stream->Read(&extra)) got.push_back(extra);
    proofs_.Acked(batches, got);
    acks->insert(acks->end(), got.begin(), got.end());
    return stream->Finish();
  }

  v1::Session GetSession(const std::string& id) {
    v1::GetSessionRequest req;
    req.set_session_id(id);
    v1::Session out;
    grpc::Status s = sessions_->GetSession(Ctx().get(), req, &out);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return out;
  }

  std::string ReportOf(const std::string& session_id) {
    v1::GetReportRequest req;
    req.set_session_id(session_id);
    v1::Report report;
    grpc::Status s = sessions_->GetReport(Ctx().get(), req, &report);
    return s.ok() ? report.json() : s.error_message();
  }

  testing_util::TestDir dir_{"server_test"};  // first: outlives the server that uses it
  testing_util::ResumeProofs proofs_;
  ServerOptions options_;
  std::unique_ptr<Server> server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::DeviceService::Stub> devices_;
  std::unique_ptr<v1::SessionService::Stub> sessions_;
  std::unique_ptr<v1::ParameterService::Stub> params_;
};

using testing_util::AcceptedPoses;  // tests/server/watch.h
using testing_util::Watch;

// The technician sets the robot down on its first face a second time without turning it: after
// the first pose, a short wobble about the vertical and back (no net rotation), then a hold on
// the same face, unturned; the rest of the capture follows, later in time. The online pair check
// must reject that pair ("not turned") and then accept the third placement, which the capture's
// real half turn makes 180 degrees from the first (CheckSixFacePairs's re-done placement).
core::Capture WithUnturnedPlacement(const core::SimResult& sim) {
  const core::Capture& in = sim.capture;
  const double dt = in.MedianDt();
  size_t end0 = 0;  // the first pose's last sample
  for (size_t i = 0; i < in.size(); ++i)
    if (in.t_s[i] <= sim.poses[0].t_end_s) end0 = i;
  const size_t hold = static_cast<size_t>(4.0 / dt), wobble = static_cast<size_t>(0.6 / dt);
  const size_t src = end0 + 1 - hold;  // the first pose's last `hold` samples
  Eigen::Vector3d accel_mean = Eigen::Vector3d::Zero(), gyro_mean = Eigen::Vector3d::Zero();
  for (size_t k = 0; k < hold; ++k) {
    accel_mean += in.accel[src + k] / static_cast<double>(hold);
    gyro_mean += in.gyro[src + k] / static_cast<double>(hold);
  }
  const Eigen::Vector3d up = accel_mean.normalized();
  core::Capture out = in;
  out.t_s.resize(end0 + 1), out.accel.resize(end0 + 1), out.gyro.resize(end0 + 1);
  if (in.has_temp()) out.temp.resize(end0 + 1);
  auto append = [&](double t, size_t from, const Eigen::Vector3d& extra_rate) {
    out.t_s.push_back(t);
    out.accel.push_back(in.accel[from]);
    out.gyro.push_back(in.gyro[from] + extra_rate);
    if (in.has_temp()) out.temp.push_back(in.temp[from]);
  };
  double t = in.t_s[end0];
  for (size_t k = 0; k < wobble; ++k)  // one sine period: turns 0.2 rad and back
    append(t += dt, src + k, up * std::sin(2 * M_PI * static_cast<double>(k + 1) / wobble));
  for (size_t k = 0; k < hold; ++k) append(t += dt, src + k, Eigen::Vector3d::Zero());
  const double shift = t - in.t_s[end0];
  for (size_t i = end0 + 1; i < in.size(); ++i)
    append(in.t_s[i] + shift, i, Eigen::Vector3d::Zero());
  EXPECT_TRUE(core::ValidateCapture(out).ok());
  EXPECT_TRUE(out.extra_columns.empty());
  return out;
}

std::vector<v1::PairVerdict> Pairs(const std::vector<v1::SessionEvent>& events) {
  std::vector<v1::PairVerdict> out;
  for (const auto& e : events)
    if (e.has_pair()) out.push_back(e.pair());
  return out;
}

int OkPairs(const std::vector<v1::SessionEvent>& events) {
  int n = 0;
  for (const auto& p : Pairs(events)) n += p.ok();
  return n;
}

// A solve left running by a server that was killed: the server, started again, runs it again
// from the stored samples with the seed the request gave (Store::ClaimLapsedSolve), although
// the lease its previous life took has not lapsed: that life cannot be running it.
TEST_F(ServerTest, AStartedServerRunsAgainTheSolveItsPreviousLifeLeft) {
  options_.sessions.replica_id = "replica-a";
  StartServer();
  Register("robot-1");
  grpc::Status created;
  const v1::Session session = Create("robot-1", v1::PROTOCOL_SIX_FACE, &created);
  ASSERT_TRUE(created.ok()) << created.error_message();
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream(Batches(Sim().capture, session.id()), &acks).ok());
  server_.reset();  // the kill, as far as storage can tell: the solve below never ends
  auto store = storage::Store::Open(options_.db_path);
  ASSERT_TRUE(store.ok()) << store.status();
  auto solve = (*store)->StartSolve(session.id(), "technician",
                                    {"replica-a", absl::Now() + absl::Hours(1)}, /*seed=*/7);
  ASSERT_TRUE(solve.ok()) << solve.status();

  options_.metrics_listen = "127.0.0.1:0";
  StartServer();  // the restart, on the same file
  ASSERT_TRUE(testing_util::FollowWhileSolving(sessions_.get(), session.id(), seconds(60)));
  EXPECT_THAT(server_->metrics()->Text(),
              testing::HasSubstr("imucal_solves_taken_over_total{outcome=\"rerun\"} 1"));

  auto after = (*store)->GetSolve(solve->id);
  ASSERT_TRUE(after.ok()) << after.status();
  EXPECT_EQ(after->state, storage::SolveState::kSucceeded) << after->error;
  EXPECT_EQ(after->owner, "replica-a");
  EXPECT_EQ(after->attempts, 2);
  EXPECT_EQ(after->version, 1);
  auto version = (*store)->GetVersion("robot-1", 1);
  ASSERT_TRUE(version.ok()) << version.status();
  EXPECT_THAT(version->provenance, testing::HasSubstr("seed 7"));
  EXPECT_EQ(version->session_id, session.id());
  EXPECT_EQ(GetSession(session.id()).state(), v1::SESSION_STATE_SOLVED);
  auto running = (*store)->ListRunningSolves();
  ASSERT_TRUE(running.ok()) << running.status();
  EXPECT_TRUE(running->empty());
  // GetSolveJob knows the job by the id the technician was given.
  v1::GetSolveJobRequest get;
  get.set_job_id(absl::StrCat("solve-", solve->id));
  v1::SolveJob job;
  ASSERT_TRUE(sessions_->GetSolveJob(Ctx().get(), get, &job).ok());
  EXPECT_EQ(job.state(), v1::JOB_STATE_DONE);
  EXPECT_EQ(job.version(), 1);
}

// Two servers on one database: a server that starts must not take the solves another live
// server is running (it claimed them, with a lease it renews), only those whose claim lapsed,
// which it runs again; and a server's own solves keep their claim while they wait for a solve
// thread.
TEST_F(ServerTest, AStartingServerLeavesAnotherServersLiveSolvesAlone) {
  options_.sessions.replica_id = "replica-a";
  options_.sessions.solve_threads = 0;  // A's solve stays queued, so running in storage
  options_.sessions.solve_lease = absl::Seconds(60);
  StartServer();
  Register("robot-1");
  Register("robot-2");
  auto store = storage::Store::Open(options_.db_path);
  ASSERT_TRUE(store.ok()) << store.status();
  storage::Session wanted;
  wanted.device_id = "robot-1";
  wanted.protocol = "six-face";
  auto live = (*store)->CreateSession(wanted, "test");
  ASSERT_TRUE(live.ok()) << live.status();
  v1::SolveSessionRequest req;
  req.set_session_id(live->id);
  v1::SolveJob job;
  const grpc::Status solved = sessions_->SolveSession(Ctx().get(), req, &job);
  ASSERT_TRUE(solved.ok()) << solved.error_message();
  // A dead replica's solve, its claim lapsed a second ago.
  wanted.device_id = "robot-2";
  auto dead = (*store)->CreateSession(wanted, "test");
  ASSERT_TRUE(dead.ok()) << dead.status();
  auto lapsed =
      (*store)->StartSolve(dead->id, "test", {"replica-dead", absl::Now() - absl::Seconds(1)});
  ASSERT_TRUE(lapsed.ok()) << lapsed.status();

  ServerOptions b = options_;
  b.sessions.replica_id = "replica-b";
  b.sessions.solve_threads = 2;
  absl::StatusOr<std::unique_ptr<Server>> other = Server::Start(b);
  ASSERT_TRUE(other.ok()) << other.status();

  auto solves = (*store)->ListSolves(live->id);
  ASSERT_TRUE(solves.ok() && solves->size() == 1) << solves.status();
  EXPECT_EQ(solves->at(0).state, storage::SolveState::kRunning);
  EXPECT_EQ(solves->at(0).owner, "replica-a");
  EXPECT_GT(solves->at(0).lease_until, absl::Now() + absl::Seconds(30));
  // The session names its running job, for a client that lost SolveSession's reply.
  EXPECT_EQ(GetSession(live->id).solve_job_id(), job.id());
  v1::SolveJob again;
  const grpc::Status twice = sessions_->SolveSession(Ctx().get(), req, &again);
  EXPECT_EQ(twice.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_THAT(twice.error_message(), testing::HasSubstr("solve_job_id"));
  // The dead replica's solve is B's now; its session holds no samples, so B's run of it is
  // refused and the session reopened to take them.
  auto b_sessions = v1::SessionService::NewStub(
      grpc::CreateChannel((*other)->address(), grpc::InsecureChannelCredentials()));
  ASSERT_TRUE(testing_util::FollowWhileSolving(b_sessions.get(), dead->id, seconds(60)));
  auto ended = (*store)->GetSolve(lapsed->id);
  ASSERT_TRUE(ended.ok()) << ended.status();
  EXPECT_EQ(ended->owner, "replica-b");
  EXPECT_EQ(ended->attempts, 2);
  EXPECT_EQ(ended->state, storage::SolveState::kFailed);
  EXPECT_THAT(ended->error, testing::HasSubstr("cannot support a calibration")) << ended->error;
  EXPECT_EQ(GetSession(dead->id).state(), v1::SESSION_STATE_OPEN);
}

// Two servers on one database: a promote or rollback through one is answered by the other's
// fetch once the other has synced its cache with the database (every active_cache_sync, 250 ms
// by default; here by hand, at known moments): before that it answers from its cache.
TEST_F(ServerTest, AnotherServersPromoteAndRollbackReachThisServersFetchAtTheNextSync) {
  StartServer();  // server A
  Register("robot-1");
  {
    auto store = storage::Store::Open(options_.db_path);
    ASSERT_TRUE(store.ok()) << store.status();
    for (int i = 1; i <= 2; ++i) {
      storage::ParamVersion v;
      v.device_id = "robot-1";
      v.params_json = "{\"format\": \"imucal-params\", \"n\": " + std::to_string(i) + "}";
      v.verdict = storage::Verdict::kPass;
      v.accel_rms = 0.01;
      v.state = i == 1 ? storage::VersionState::kActive : storage::VersionState::kCandidate;
      ASSERT_TRUE((*store)->AddVersion(v, "test").ok());
    }
  }
  ServerOptions b_options = options_;
  b_options.sessions.replica_id = "replica-b";
  b_options.active_cache_sync = absl::ZeroDuration();  // synced by hand below
  absl::StatusOr<std::unique_ptr<Server>> b = Server::Start(b_options);
  ASSERT_TRUE(b.ok()) << b.status();
  auto b_params = v1::ParameterService::NewStub(
      grpc::CreateChannel((*b)->address(), grpc::InsecureChannelCredentials()));
  const auto fetch_on_b = [&] {
    v1::GetActiveParametersRequest req;
    req.set_device_id("robot-1");
    v1::ParameterSet out;
    const grpc::Status st = b_params->GetActiveParameters(Ctx().get(), req, &out);
    EXPECT_TRUE(st.ok()) << st.error_message();
    return out.version();
  };
  EXPECT_EQ(fetch_on_b(), 1);  // now in B's cache

  v1::PromoteRequest promote;
  promote.set_device_id("robot-1");
  promote.set_version(2);
  v1::ParameterSet set;
  ASSERT_TRUE(params_->Promote(Ctx().get(), promote, &set).ok());
  EXPECT_EQ(fetch_on_b(), 1);  // B has not looked yet
  (*b)->SyncActiveCache();
  EXPECT_EQ(fetch_on_b(), 2);

  v1::RollbackRequest rollback;
  rollback.set_device_id("robot-1");
  rollback.set_to_version(1);
  ASSERT_TRUE(params_->Rollback(Ctx().get(), rollback, &set).ok());
  (*b)->SyncActiveCache();
  EXPECT_EQ(fetch_on_b(), 1);
  (*b)->SyncActiveCache();  // nothing new: the cache stays
  EXPECT_EQ(fetch_on_b(), 1);
}

// Two servers on one PostgreSQL database, in one process (so that the ThreadSanitizer build
// runs the listener's thread against the streams and the solve): a watch on B follows a session
// whose robot streams through A and whose solve runs on A, from the notifications A's commits
// send, and ends when the session is solved there.
TEST_F(ServerTest, OnPostgresAWatchOnAnotherServerFollowsTheStreamAndTheSolve) {
  absl::StatusOr<std::unique_ptr<testing_util::PgTestDatabase>> db =
      testing_util::PgTestDatabase::Create();
  ASSERT_TRUE(db.ok()) << db.status();
  options_.db_path = (*db)->url();
  options_.sessions.replica_id = "replica-a";
  StartServer();
  std::unique_ptr<Server> b;
  ASSERT_NO_FATAL_FAILURE(StartReplicaB(&b));
  auto b_sessions = v1::SessionService::NewStub(
      grpc::CreateChannel(b->address(), grpc::InsecureChannelCredentials()));
  Register("robot-1");
  grpc::Status status;
  const v1::Session session = Create("robot-1", v1::PROTOCOL_SIX_FACE, &status);
  ASSERT_TRUE(status.ok()) << status.error_message();
  Watch on_a(sessions_.get(), session.id());
  Watch on_b(b_sessions.get(), session.id());
  auto began = [](const std::vector<v1::SessionEvent>& events, bool ended) {
    return ended || !events.empty();
  };
  ASSERT_TRUE(on_a.WaitFor(began));
  ASSERT_TRUE(on_b.WaitFor(began));

  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream(Batches(Sim().capture, session.id()), &acks).ok());
  const int poses = AcceptedPoses(on_a.events());
  ASSERT_GE(poses, 6);
  EXPECT_TRUE(on_b.WaitFor([&](const std::vector<v1::SessionEvent>& events, bool) {
    return AcceptedPoses(events) >= poses;
  })) << "B's watch saw " << AcceptedPoses(on_b.events()) << " of " << poses << " poses";

  v1::SolveSessionRequest req;
  req.set_session_id(session.id());
  v1::SolveJob job;
  ASSERT_TRUE(sessions_->SolveSession(Ctx().get(), req, &job).ok());
  ASSERT_TRUE(on_b.WaitFor([](const std::vector<v1::SessionEvent>&, bool ended) { return ended; }))
      << "B's watch did not end when A solved the session";
  bool saw_done = false;
  for (const v1::SessionEvent& e : on_b.events())
    saw_done |= e.has_solve() && e.solve().id() == job.id() &&
                e.solve().state() == v1::JOB_STATE_DONE && e.solve().version() == 1;
  EXPECT_TRUE(saw_done);
  EXPECT_EQ(AcceptedPoses(on_b.events()), poses) << "each pose once";
  b.reset();  // before the database is dropped
  server_.reset();
}

// A robot sent to another server and back (several servers on one database): the server it
// returns to holds the session's live state from before, and catches it up with what the other
// stored, so the stream continues, the counts and poses are the whole capture's, and the solve
// sees every sample.
TEST_F(ServerTest, ASessionStreamedThroughAnotherServerAndBackContinuesWhole) {
  StartServer();  // server A
  Register("robot-1");
  grpc::Status status;
  const v1::Session session = Create("robot-1", v1::PROTOCOL_SIX_FACE, &status);
  ASSERT_TRUE(status.ok()) << status.error_message();
  const core::SimResult sim = Sim();
  const std::vector<v1::SampleBatch> all = Batches(sim.capture, session.id());
  const size_t third = all.size() / 3;
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream({all.begin(), all.begin() + third}, &acks).ok());
  ASSERT_GT(GetSession(session.id()).samples(), 0);  // A's live state holds the first third

  std::unique_ptr<Server> b;
  ASSERT_NO_FATAL_FAILURE(StartReplicaB(&b));
  auto b_sessions = v1::SessionService::NewStub(
      grpc::CreateChannel(b->address(), grpc::InsecureChannelCredentials()));
  grpc::Status on_b =
      Stream({all.begin() + third, all.begin() + 2 * third}, &acks, b_sessions.get());
  ASSERT_TRUE(on_b.ok()) << on_b.error_message();

  grpc::Status back = Stream({all.begin() + 2 * third, all.end()}, &acks);
  ASSERT_TRUE(back.ok()) << back.error_message();
  const v1::Session whole = GetSession(session.id());
  EXPECT_EQ(whole.samples(), static_cast<int64_t>(sim.capture.size()));
  EXPECT_EQ(whole.last_acked_seq(), static_cast<int64_t>(all.size()));

  v1::SolveSessionRequest solve;
  solve.set_session_id(session.id());
  v1::SolveJob job;
  ASSERT_TRUE(sessions_->SolveSession(Ctx().get(), solve, &job).ok());
  ASSERT_TRUE(testing_util::FollowToEnd(sessions_.get(), session.id(), seconds(120)).ok());
  v1::GetSolveJobRequest get;
  get.set_job_id(job.id());
  ASSERT_TRUE(sessions_->GetSolveJob(Ctx().get(), get, &job).ok());
  EXPECT_EQ(job.state(), v1::JOB_STATE_DONE) << job.error();
  EXPECT_TRUE(job.activated()) << "verdict " << job.verdict();
}

TEST(ParamCrcCacheTest, ComputesOncePerVersion) {
  storage::ParamVersion v;
  v.device_id = "robot-1";
  v.version = 3;
  v.params_json = std::string(4600, 'x') + "{\"accel\": 1}";
  ParamCrcCache cache;
  EXPECT_EQ(cache.Get(v), formats::Crc32c(v.params_json));
  EXPECT_EQ(cache.hits(), 0u);
  EXPECT_EQ(cache.Get(v), formats::Crc32c(v.params_json));
  EXPECT_EQ(cache.hits(), 1u);
  v.version = 4;  // another version: its own entry
  v.params_json += " ";
  EXPECT_EQ(cache.Get(v), formats::Crc32c(v.params_json));
  EXPECT_EQ(cache.hits(), 1u);
  // A listing (no JSON loaded) is not cached.
  v.params_json.clear();
  EXPECT_EQ(cache.Get(v), formats::Crc32c(""));
  EXPECT_EQ(cache.hits(), 1u);
}

// The fetch hot path's crc32c (cached after the first call) is the JSON's CRC-32C.
TEST_F(ServerTest, ActiveParametersCrcIsTheJsonCrcWhenCached) {
  Register("robot-1");
  {
    auto store = storage::Store::Open(options_.db_path);
    ASSERT_TRUE(store.ok()) << store.status();
    storage::ParamVersion v;
    v.device_id = "robot-1";
    v.params_json = "{\"format\": \"imucal-params\", \"pad\": \"" + std::string(4600, 'p') + "\"}";
    v.report_json = "{}";
    v.verdict = storage::Verdict::kPass;
    v.accel_rms = 0.01;
    v.state = storage::VersionState::kActive;
    ASSERT_TRUE((*store)->AddVersion(v, "test").ok());
  }
  for (int i = 0; i < 2; ++i) {
    v1::GetActiveParametersRequest req;
    req.set_device_id("robot-1");
    v1::ParameterSet out;
    grpc::Status s = params_->GetActiveParameters(Ctx().get(), req, &out);
    ASSERT_TRUE(s.ok()) << s.error_message();
    ASSERT_GT(out.json().size(), 4600u);
    EXPECT_EQ(out.crc32c(), formats::Crc32c(out.json())) << "call " << i;
  }
}

TEST_F(ServerTest, DevicesAndOneOpenSessionPerDevice) {
  const v1::Device d = Register("robot-1");
  EXPECT_EQ(d.id(), "robot-1");
  EXPECT_EQ(d.active_version(), 0);
  Register("robot-1");  // robots register at every boot: a no-op
  v1::RegisterDeviceRequest other;
  *other.mutable_device() = d;
  other.mutable_device()->set_nominal_rate_hz(100);
  v1::Device out;
  EXPECT_EQ(devices_->RegisterDevice(Ctx().get(), other, &out).error_code(),
            grpc::StatusCode::ALREADY_EXISTS);
  other.mutable_device()->set_id("bad id!");
  EXPECT_EQ(devices_->RegisterDevice(Ctx().get(), other, &out).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);

  grpc::Status s;
  const v1::Session first = Create("robot-1", v1::PROTOCOL_SIX_FACE, &s);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(first.state(), v1::SESSION_STATE_OPEN);
  Create("robot-1", v1::PROTOCOL_SIX_FACE, &s);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_NE(s.error_message().find(first.id()), std::string::npos) << s.error_message();
  Create("no-such-robot", v1::PROTOCOL_SIX_FACE, &s);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::NOT_FOUND) << s.error_message();

  v1::ListDevicesRequest list;
  list.set_page_size(1);
  v1::ListDevicesResponse page;
  ASSERT_TRUE(devices_->ListDevices(Ctx().get(), list, &page).ok());
  EXPECT_EQ(page.devices_size(), 1);
}

TEST_F(ServerTest, IngestAcksRetransmissionsGapsAndBadBatches) {
  Register("robot-2");
  grpc::Status s;
  const v1::Session session = Create("robot-2", v1::PROTOCOL_SIX_FACE, &s);
  ASSERT_TRUE(s.ok());
  const core::SimResult sim = Sim();
  const std::vector<v1::SampleBatch> batches = Batches(sim.capture, session.id());

  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream({batches.begin(), batches.begin() + 5}, &acks).ok());
  ASSERT_EQ(acks.size(), 5u);
  for (int i = 0; i < 5; ++i) EXPECT_EQ(acks[i].last_acked_seq(), i + 1);
  EXPECT_EQ(acks.back().samples(), 5 * kBatch);

  // A repeated batch is a no-op ack; a gap names the expected seq.
  acks.clear();
  s = Stream({batches[2], batches[6]}, &acks);
  ASSERT_EQ(acks.size(), 1u);
  EXPECT_EQ(acks[0].last_acked_seq(), 5);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_NE(s.error_message().find("expected 6"), std::string::npos) << s.error_message();

  // Bad batches name the field; nothing accepted before is lost.
  v1::SampleBatch nan = batches[5];
  nan.set_accel(7, std::nan(""));
  acks.clear();
  s = Stream({nan}, &acks);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("accel[7]"), std::string::npos) << s.error_message();
  v1::SampleBatch short_gyro = batches[5];
  short_gyro.mutable_gyro()->RemoveLast();
  s = Stream({short_gyro}, &acks);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("gyro"), std::string::npos) << s.error_message();
  v1::SampleBatch absurd = batches[5];
  absurd.set_gyro(4, 1e6);
  s = Stream({absurd}, &acks);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("gyro[4]"), std::string::npos) << s.error_message();
  v1::SampleBatch backwards = batches[5];
  backwards.set_t_s(0, batches[4].t_s(0));
  s = Stream({backwards}, &acks);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(s.error_message().find("t_s[0]"), std::string::npos) << s.error_message();
  EXPECT_TRUE(acks.empty());

  const v1::Session after = GetSession(session.id());
  EXPECT_EQ(after.last_acked_seq(), 5);
  EXPECT_EQ(after.samples(), 5 * kBatch);
  // The stream resumes after the last ack.
  acks.clear();
  ASSERT_TRUE(Stream({batches[5]}, &acks).ok());
  EXPECT_EQ(acks.at(0).last_acked_seq(), 6);
}

TEST_F(ServerTest, WatchGuidesSolveActivatesAndMatchesOfflineCalibrate) {
  Register("robot-3");
  grpc::Status s;
  const v1::Session session = Create("robot-3", v1::PROTOCOL_SIX_FACE, &s);
  ASSERT_TRUE(s.ok());
  core::SimResult sim = Sim();

  Watch watch(sessions_.get(), session.id());
  ASSERT_TRUE(watch.WaitFor([](const auto& ev, bool) {
    return ev.size() >= 2 && ev[0].has_session() && ev[1].has_next_pose();
  })) << "no snapshot";
  EXPECT_EQ(watch.events()[1].next_pose().face(), "Z+");

  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream(Batches(sim.capture, session.id()), &acks).ok());
  // The final hold ends with the stream: 11 poses are closed by a move, the 12th by the solve.
  ASSERT_TRUE(watch.WaitFor([](const auto& ev, bool) { return AcceptedPoses(ev) >= 11; }))
      << AcceptedPoses(watch.events()) << " poses";
  bool saw_z_minus = false, saw_turn = false, saw_stillness = false;
  for (const auto& e : watch.events()) {
    if (e.has_next_pose() && e.next_pose().face() == "Z-") saw_z_minus = true;
    if (e.has_next_pose() && e.next_pose().turn_half()) saw_turn = true;
    if (e.has_stillness()) saw_stillness = true;
  }
  EXPECT_TRUE(saw_z_minus);
  EXPECT_TRUE(saw_turn);
  EXPECT_TRUE(saw_stillness);
  // Every six-face pair was judged while streaming, with the offline check: all pass here.
  ASSERT_EQ(Pairs(watch.events()).size(), 6u);
  for (const auto& p : Pairs(watch.events())) {
    EXPECT_TRUE(p.ok()) << p.face() << ": " << p.reason();
    EXPECT_NEAR(p.rotation_deg(), 180, 15) << p.face();
  }
  EXPECT_GE(GetSession(session.id()).poses_accepted(), 11);

  v1::SolveSessionRequest solve;
  solve.set_session_id(session.id());
  solve.set_seed(1);
  v1::SolveJob job;
  ASSERT_TRUE(sessions_->SolveSession(Ctx().get(), solve, &job).ok());
  EXPECT_EQ(job.state(), v1::JOB_STATE_QUEUED);
  // Solving twice at once is not allowed: the session is solving.
  v1::SolveJob again;
  EXPECT_EQ(sessions_->SolveSession(Ctx().get(), solve, &again).error_code(),
            grpc::StatusCode::FAILED_PRECONDITION);

  // The watch ends when the session closes, after the solve's result.
  ASSERT_TRUE(watch.WaitFor([](const auto&, bool ended) { return ended; }, seconds(30)));
  EXPECT_TRUE(watch.status().ok()) << watch.status().error_message();
  bool saw_done = false;
  for (const auto& e : watch.events())
    if (e.has_solve() && e.solve().state() == v1::JOB_STATE_DONE) saw_done = true;
  EXPECT_TRUE(saw_done);
  EXPECT_EQ(AcceptedPoses(watch.events()), 20);

  v1::GetSolveJobRequest get;
  get.set_job_id(job.id());
  ASSERT_TRUE(sessions_->GetSolveJob(Ctx().get(), get, &job).ok());
  ASSERT_EQ(job.state(), v1::JOB_STATE_DONE) << job.error();
  EXPECT_EQ(job.version(), 1);
  EXPECT_EQ(job.verdict(), "pass") << ReportOf(session.id());
  EXPECT_EQ(job.verdict_kind(), v1::VERDICT_PASS);
  EXPECT_TRUE(job.activated());
  EXPECT_EQ(GetSession(session.id()).state(), v1::SESSION_STATE_SOLVED);

  v1::GetActiveParametersRequest active;
  active.set_device_id("robot-3");
  v1::ParameterSet ps;
  ASSERT_TRUE(params_->GetActiveParameters(Ctx().get(), active, &ps).ok());
  EXPECT_EQ(ps.version(), 1);
  EXPECT_EQ(ps.state(), v1::VERSION_STATE_ACTIVE);
  EXPECT_EQ(ps.verdict_kind(), v1::VERDICT_PASS);  // from the pre-serialised cache
  EXPECT_EQ(ps.verdict(), "pass");
  auto served = formats::ParamSetFromJson(ps.json());
  ASSERT_TRUE(served.ok()) << served.status();

  // Offline: the same capture, protocol and seed.
  sim.capture.device = "robot-3";
  sim.capture.rate_hz = 200;
  core::CalibrateOptions options;
  options.protocol = core::ProtocolKind::kSixFace;
  options.seed = 1;
  auto offline = core::Calibrate(sim.capture, options);
  ASSERT_TRUE(offline.ok()) << offline.status();
  const core::AccelVector a = core::PackAccel(served->accel);
  const core::AccelVector b = core::PackAccel(offline->params.accel);
  for (int i = 0; i < core::kAccelParams; ++i)
    EXPECT_NEAR(a(i), b(i), 1e-9 * std::max(1.0, std::abs(b(i)))) << "parameter " << i;

  // Not modified since: only the header.
  active.set_if_not_version(1);
  ASSERT_TRUE(params_->GetActiveParameters(Ctx().get(), active, &ps).ok());
  EXPECT_TRUE(ps.json().empty());

  v1::GetReportRequest report_req;
  report_req.set_session_id(session.id());
  v1::Report report;
  ASSERT_TRUE(sessions_->GetReport(Ctx().get(), report_req, &report).ok());
  EXPECT_NE(report.json().find("imucal-report v1"), std::string::npos);

  v1::ExportRequest exp;
  exp.set_device_id("robot-3");
  exp.set_format("json");
  v1::ExportResponse exported;
  ASSERT_TRUE(params_->Export(Ctx().get(), exp, &exported).ok());
  EXPECT_EQ(exported.content(), ps.json().empty() ? exported.content() : ps.json());
  exp.set_format("openvins");
  exp.set_rostopic("/robot3/imu");
  ASSERT_TRUE(params_->Export(Ctx().get(), exp, &exported).ok());
  EXPECT_NE(exported.content().find("imu0:"), std::string::npos) << exported.content();
  EXPECT_NE(exported.content().find("Tw:"), std::string::npos) << exported.content();
  EXPECT_NE(exported.content().find("/robot3/imu"), std::string::npos);
  EXPECT_NE(exported.filename().find("kalibr_imu_chain.yaml"), std::string::npos);
  ASSERT_FALSE(exported.notes().empty());
  EXPECT_NE(exported.notes(0).find("biases"), std::string::npos) << exported.notes(0);
  // Bad requests name the field.
  exp.set_format("bogus");
  grpc::Status bad = params_->Export(Ctx().get(), exp, &exported);
  EXPECT_EQ(bad.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(bad.error_message().find("format"), std::string::npos) << bad.error_message();
  exp.set_format("kalibr");
  exp.set_gyro_random_walk(-1);
  bad = params_->Export(Ctx().get(), exp, &exported);
  EXPECT_EQ(bad.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(bad.error_message().find("gyro_random_walk"), std::string::npos) << bad.error_message();
}

// Pair verdicts while streaming: each six-face pair is judged as soon as its second pose is held;
// a failed pair says why, the guidance asks for the re-do, and the re-done placement passes.
// Poses and verdicts are stored as they are judged and survive a restart.
TEST_F(ServerTest, PairVerdictsWhileStreamingWithARedoAndStoredPoses) {
  Register("robot-pairs");
  grpc::Status s;
  const v1::Session session = Create("robot-pairs", v1::PROTOCOL_SIX_FACE, &s);
  ASSERT_TRUE(s.ok());
  const core::Capture capture = WithUnturnedPlacement(Sim());
  auto watch = std::make_unique<Watch>(sessions_.get(), session.id());
  ASSERT_TRUE(watch->WaitFor([](const auto& ev, bool) { return !ev.empty(); })) << "no snapshot";
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream(Batches(capture, session.id()), &acks).ok());
  // The six faces' pairs are all judged while streaming (the X- pair's second pose is held
  // before the extra poses start).
  ASSERT_TRUE(watch->WaitFor([](const auto& ev, bool) { return OkPairs(ev) >= 6; }))
      << OkPairs(watch->events()) << " ok pairs";
  const std::vector<v1::SessionEvent> events = watch->events();
  watch.reset();  // before the restart below: an open watch would hold the server's drain
  const std::vector<v1::PairVerdict> pairs = Pairs(events);
  ASSERT_EQ(pairs.size(), 7u);
  EXPECT_FALSE(pairs[0].ok());
  EXPECT_EQ(pairs[0].face(), "Z+");
  EXPECT_EQ(pairs[0].pose_a(), 0);
  EXPECT_EQ(pairs[0].pose_b(), 1);
  EXPECT_LT(pairs[0].rotation_deg(), 20);
  EXPECT_NE(pairs[0].reason().find("not turned"), std::string::npos) << pairs[0].reason();
  EXPECT_TRUE(pairs[1].ok()) << pairs[1].reason();  // the re-done placement, from pose 0
  EXPECT_EQ(pairs[1].pose_a(), 0);
  EXPECT_EQ(pairs[1].pose_b(), 2);
  EXPECT_NEAR(pairs[1].rotation_deg(), 180, 15);
  for (size_t i = 1; i < pairs.size(); ++i) EXPECT_TRUE(pairs[i].ok()) << pairs[i].reason();
  // After the pose that failed the pair: the guidance wants the Z+ turn again (not Z-), says
  // why, and the protocol needs one pose more.
  size_t failed_at = 0;
  while (!(events[failed_at].has_pose() && events[failed_at].pose().index() == 1)) ++failed_at;
  bool saw_redo = false, saw_wanted = false;
  for (size_t i = failed_at; i < events.size() && !saw_redo; ++i) {
    if (events[i].has_progress()) {
      EXPECT_EQ(events[i].progress().poses_wanted(), 13);
      saw_wanted = true;
    }
    if (!events[i].has_next_pose()) continue;
    saw_redo = true;
    EXPECT_EQ(events[i].next_pose().face(), "Z+");
    EXPECT_TRUE(events[i].next_pose().turn_half());
    EXPECT_NE(events[i].next_pose().instruction().find("Pair Z+ failed (not turned"),
              std::string::npos)
        << events[i].next_pose().instruction();
  }
  EXPECT_TRUE(saw_redo);
  EXPECT_TRUE(saw_wanted);

  // Stored as judged: listed now, and after a restart (with the rows of the poses lost, as a
  // kill between a batch's commit and its poses' would leave them: the replay stores them again).
  auto list = [&] {
    v1::ListPosesRequest req;
    req.set_session_id(session.id());
    v1::ListPosesResponse out;
    grpc::Status st = sessions_->ListPoses(Ctx().get(), req, &out);
    EXPECT_TRUE(st.ok()) << st.error_message();
    return out;
  };
  const v1::ListPosesResponse before = list();
  EXPECT_EQ(before.pairs_size(), 7);
  EXPECT_GE(before.poses_size(), 13);
  int accepted = 0;
  for (const auto& p : before.poses()) accepted += p.accepted();
  EXPECT_EQ(accepted, AcceptedPoses(events));
  EXPECT_EQ(before.poses(1).face(), "Z+");
  EXPECT_EQ(before.pairs(0).reason(), pairs[0].reason());
  server_.reset();
  {
    auto store = storage::Store::Open(options_.db_path);
    ASSERT_TRUE(store.ok()) << store.status();
    ASSERT_TRUE((*store)->PutPoses(session.id(), {}, "test").ok());  // lose the pose rows
  }
  StartServer();
  EXPECT_EQ(GetSession(session.id()).poses_accepted(), accepted);  // loads the session
  const v1::ListPosesResponse after = list();
  EXPECT_EQ(after.DebugString(), before.DebugString());
}

// Memory per session is bounded: a closed session's live state is forgotten when it closes,
// and reading it afterwards (GetSession, WatchSession), before or after a restart, answers from
// storage without loading it back.
// ReadSamples gives back exactly what was stored, in order: a batch larger than a message
// (10,000 samples) split under its seq, batches with and without temperature, pages of storage
// crossed (20,000 samples a page); an empty id is INVALID_ARGUMENT naming session_id, an unknown
// one NOT_FOUND; the call is counted as a stream while it runs, and not after.
TEST_F(ServerTest, ReadSamplesGivesBackTheStoredSamplesInOrder) {
  Register("robot-read");
  grpc::Status status;
  const v1::Session session = Create("robot-read", v1::PROTOCOL_UNSPECIFIED, &status);
  ASSERT_TRUE(status.ok()) << status.error_message();
  // Batch 1: 15,000 samples with temperature; batches 2..151: 200 samples each, without.
  std::vector<v1::SampleBatch> sent;
  size_t i = 0;
  auto add = [&](size_t n, bool temp) {
    v1::SampleBatch b;
    b.set_session_id(session.id());
    b.set_seq(static_cast<int64_t>(sent.size()) + 1);
    for (size_t k = 0; k < n; ++k, ++i) {
      const double x = static_cast<double>(i);
      b.add_t_s(x / 200.0);
      for (double v : {std::sin(x), std::cos(x), 9.8 + 1e-7 * x}) b.add_accel(v);
      for (double v : {1e-3 * std::sin(0.1 * x), -2e-3, 1e-9 * x}) b.add_gyro(v);
      if (temp) b.add_temp_c(25 + 1e-4 * x);
    }
    sent.push_back(std::move(b));
  };
  add(15000, true);
  for (int b = 0; b < 150; ++b) add(200, false);
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream(sent, &acks).ok());
  ASSERT_EQ(acks.back().samples(), 45000);

  auto read = [&](const std::string& id, std::vector<v1::SampleBatch>* got) {
    v1::ReadSamplesRequest req;
    req.set_session_id(id);
    auto ctx = Ctx();
    auto reader = sessions_->ReadSamples(ctx.get(), req);
    v1::SampleBatch b;
    // (Not checked here that the call is counted while it runs: gRPC may have sent the whole
    // response, and the server ended the call, before the client reads its first message.)
    while (reader->Read(&b)) got->push_back(b);
    return reader->Finish();
  };
  // A call leaves the registry when gRPC is done with it, just after its client has finished.
  auto streams_closed = [&] {
    const auto deadline = system_clock::now() + seconds(5);
    while (server_->open_streams() != 0 && system_clock::now() < deadline)
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    return server_->open_streams() == 0;
  };
  std::vector<v1::SampleBatch> got;
  ASSERT_TRUE(read(session.id(), &got).ok());
  EXPECT_TRUE(streams_closed());
  ASSERT_EQ(got.size(), 152u);  // batch 1 in two messages
  EXPECT_EQ(got[0].seq(), 1);
  EXPECT_EQ(got[0].t_s_size(), 10000);
  EXPECT_EQ(got[1].seq(), 1);
  EXPECT_EQ(got[1].t_s_size(), 5000);
  v1::SampleBatch first = got[0];  // batch 1 joined again
  first.MergeFrom(got[1]);
  EXPECT_EQ(first.SerializeAsString(), sent[0].SerializeAsString());
  for (size_t k = 2; k < got.size(); ++k) {
    EXPECT_EQ(got[k].session_id(), session.id());
    EXPECT_EQ(got[k].temp_c_size(), 0);
    ASSERT_EQ(got[k].SerializeAsString(), sent[k - 1].SerializeAsString()) << "message " << k;
  }

  std::vector<v1::SampleBatch> none;
  grpc::Status empty = read("", &none);
  EXPECT_EQ(empty.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(empty.error_message().find("session_id"), std::string::npos) << empty.error_message();
  grpc::Status unknown = read("s-00000000000000000000000000000000", &none);
  EXPECT_EQ(unknown.error_code(), grpc::StatusCode::NOT_FOUND) << unknown.error_message();
  EXPECT_TRUE(none.empty());
  EXPECT_TRUE(streams_closed());
}

TEST_F(ServerTest, ReadingAClosedSessionDoesNotLoadIt) {
  Register("robot-mem");
  grpc::Status s;
  const v1::Session session = Create("robot-mem", v1::PROTOCOL_SIX_FACE, &s);
  ASSERT_TRUE(s.ok());
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream(Batches(Sim().capture, session.id()), &acks).ok());
  EXPECT_EQ(server_->live_sessions(), 1u);  // open, streamed into
  v1::SolveSessionRequest req;
  req.set_session_id(session.id());
  v1::SolveJob job;
  ASSERT_TRUE(sessions_->SolveSession(Ctx().get(), req, &job).ok());
  ASSERT_TRUE(testing_util::FollowToEnd(sessions_.get(), session.id(), seconds(30)).ok());

  for (int round = 0; round < 2; ++round) {  // then again after a restart
    SCOPED_TRACE(round == 0 ? "running since the solve" : "after a restart");
    EXPECT_EQ(server_->live_sessions(), 0u);
    v1::GetSessionRequest get;
    get.set_session_id(session.id());
    v1::Session got;
    ASSERT_TRUE(sessions_->GetSession(Ctx().get(), get, &got).ok());
    EXPECT_EQ(got.state(), v1::SESSION_STATE_SOLVED);
    EXPECT_GE(got.poses_accepted(), 12);  // from the stored poses
    Watch watch(sessions_.get(), session.id());
    ASSERT_TRUE(watch.WaitFor([](const auto&, bool ended) { return ended; }));
    EXPECT_TRUE(watch.status().ok()) << watch.status().error_message();
    ASSERT_EQ(watch.events().size(), 1u);  // the snapshot, then the end
    EXPECT_EQ(watch.events()[0].session().poses_accepted(), got.poses_accepted());
    EXPECT_EQ(server_->live_sessions(), 0u);
    StartServer();
  }
}

// CancelSession, StreamSamples and SolveSession on a closed session answer from the session's
// state in storage: the hub is not touched, so the session's samples are not decoded and
// replayed (10 M samples: 1.6 s and 470 MB, kept until the server stops). Measured in
// bench/misuse_bench.cc; here, through the count of sessions in memory.
TEST_F(ServerTest, ClosedSessionsAreRefusedWithoutLoadingThem) {
  Register("robot-closed");
  grpc::Status s;
  const v1::Session session = Create("robot-closed", v1::PROTOCOL_SIX_FACE, &s);
  ASSERT_TRUE(s.ok());
  std::vector<v1::SampleAck> acks;
  std::vector<v1::SampleBatch> batches = Batches(Sim().capture, session.id());
  batches.resize(10);
  ASSERT_TRUE(Stream(batches, &acks).ok());
  v1::CancelSessionRequest cancel;
  cancel.set_session_id(session.id());
  v1::Session cancelled;
  ASSERT_TRUE(sessions_->CancelSession(Ctx().get(), cancel, &cancelled).ok());
  EXPECT_EQ(cancelled.state(), v1::SESSION_STATE_CANCELLED);

  // Refused, naming the state, and nothing loaded.
  auto refused = [&](const grpc::Status& st, const char* call) {
    EXPECT_EQ(st.error_code(), grpc::StatusCode::FAILED_PRECONDITION)
        << call << ": " << st.error_message();
    EXPECT_NE(st.error_message().find("is cancelled"), std::string::npos) << st.error_message();
    EXPECT_EQ(server_->live_sessions(), 0u) << call;
  };
  for (int round = 0; round < 2; ++round) {  // then again after a restart
    SCOPED_TRACE(round == 0 ? "running since the cancel" : "after a restart");
    EXPECT_EQ(server_->live_sessions(), 0u);
    refused(sessions_->CancelSession(Ctx().get(), cancel, &cancelled), "CancelSession");
    acks.clear();
    refused(Stream({Batches(Sim().capture, session.id())[10]}, &acks), "StreamSamples");
    EXPECT_TRUE(acks.empty());
    v1::SolveSessionRequest solve;
    solve.set_session_id(session.id());
    v1::SolveJob job;
    refused(sessions_->SolveSession(Ctx().get(), solve, &job), "SolveSession");
    EXPECT_EQ(GetSession(session.id()).samples(), 10 * kBatch);
    StartServer();
  }
}

// Messages name the field, the id or the state, never the server's own functions: store
// operations ("SetSessionState: ...", "CreateSession: ...") stay in the server.
TEST_F(ServerTest, NoInternalFunctionNamesReachClients) {
  Register("robot-names");
  grpc::Status s;
  const v1::Session session = Create("robot-names", v1::PROTOCOL_FREE, &s);
  ASSERT_TRUE(s.ok());
  std::vector<grpc::Status> refused;
  Create("robot-names", v1::PROTOCOL_FREE, &s);  // a second open session
  refused.push_back(s);
  v1::RegisterDeviceRequest other;  // the same id, other metadata
  other.mutable_device()->set_id("robot-names");
  other.mutable_device()->set_sensor_model("another");
  other.mutable_device()->set_nominal_rate_hz(100);
  other.mutable_device()->set_accel_unit("g");
  other.mutable_device()->set_gyro_unit("deg/s");
  v1::Device device;
  refused.push_back(devices_->RegisterDevice(Ctx().get(), other, &device));
  v1::CancelSessionRequest cancel;
  cancel.set_session_id(session.id());
  v1::Session out;
  ASSERT_TRUE(sessions_->CancelSession(Ctx().get(), cancel, &out).ok());
  refused.push_back(sessions_->CancelSession(Ctx().get(), cancel, &out));
  v1::GetSessionRequest get;
  get.set_session_id("s-00000000000000000000000000000000");
  refused.push_back(sessions_->GetSession(Ctx().get(), get, &out));
  v1::PromoteRequest promote;
  promote.set_device_id("robot-names");
  promote.set_version(3);
  v1::ParameterSet set;
  refused.push_back(params_->Promote(Ctx().get(), promote, &set));
  v1::RollbackRequest rollback;
  rollback.set_device_id("robot-names");
  rollback.set_to_version(1);
  refused.push_back(params_->Rollback(Ctx().get(), rollback, &set));
  for (const grpc::Status& r : refused) {
    EXPECT_FALSE(r.ok());
    // "Word: ..." with a capitalised identifier is a function's name (fields are snake_case).
    const std::string& m = r.error_message();
    const size_t colon = m.find(": ");
    const std::string head = colon == std::string::npos ? "" : m.substr(0, colon);
    const bool function_name = !head.empty() && std::isupper(static_cast<unsigned char>(head[0])) &&
                               head.find(' ') == std::string::npos;
    EXPECT_FALSE(function_name) << m;
    for (const char* op : {"SetSessionState", "CreateSession", "CreateDevice", "LoadSession",
                           "GetSession", "Promote:", "Rollback:"})
      EXPECT_EQ(m.find(op), std::string::npos) << m;
  }
}

// GetSolveJob answers from memory while a job is queued or running and a while after; finished
// jobs beyond the bound leave memory (storage still answers for them).
TEST_F(ServerTest, FinishedSolveJobsLeaveMemory) {
  options_.sessions.finished_jobs_kept = 1;
  StartServer();
  Register("robot-jobs");
  grpc::Status s;
  const v1::Session session = Create("robot-jobs", v1::PROTOCOL_SIX_FACE, &s);
  ASSERT_TRUE(s.ok());
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream(Batches(Sim().capture, session.id()), &acks).ok());
  std::vector<std::string> jobs;
  for (uint64_t seed = 1; seed <= 3; ++seed) {
    v1::SolveSessionRequest req;
    req.set_session_id(session.id());
    req.set_seed(seed);
    v1::SolveJob job;
    ASSERT_TRUE(sessions_->SolveSession(Ctx().get(), req, &job).ok());
    jobs.push_back(job.id());
    ASSERT_TRUE(testing_util::FollowToEnd(sessions_.get(), session.id(), seconds(30)).ok());
  }
  EXPECT_EQ(server_->solve_jobs_in_memory(), 1u);
  for (const std::string& id : jobs) {
    v1::GetSolveJobRequest get;
    get.set_job_id(id);
    v1::SolveJob job;
    ASSERT_TRUE(sessions_->GetSolveJob(Ctx().get(), get, &job).ok()) << id;
    EXPECT_EQ(job.state(), v1::JOB_STATE_DONE) << id;
    EXPECT_GT(job.version(), 0) << id;
  }
}

// A capture that cannot support a calibration (two orientations: a rest, not a calibration)
// is refused by core with a report, not an error. The server keeps that report with the failed
// solve and makes no version; the session goes back to open with its samples, so the rest of
// the capture streamed into it afterwards solves. GetSolveJob says "refused" before and after a
// restart.
TEST_F(ServerTest, ARefusedCalibrationKeepsItsReportAndTheSessionMakesNoVersion) {
  Register("robot-refused");
  grpc::Status s;
  const v1::Session session = Create("robot-refused", v1::PROTOCOL_SIX_FACE, &s);
  ASSERT_TRUE(s.ok());
  const core::SimResult sim = Sim();
  ASSERT_GE(sim.poses.size(), 3u);
  std::vector<v1::SampleBatch> batches = Batches(sim.capture, session.id());
  // The batches up to the middle of the move after the second pose.
  const double cut_s = (sim.poses[1].t_end_s + sim.poses[2].t_start_s) / 2;
  size_t head = 0;
  while (head < batches.size() && batches[head].t_s(0) < cut_s) ++head;
  ASSERT_GT(head, 0u);
  ASSERT_LT(head, batches.size());
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(
      Stream(std::vector<v1::SampleBatch>(batches.begin(), batches.begin() + head), &acks).ok());
  const int64_t stored = GetSession(session.id()).samples();
  ASSERT_GT(stored, 0);

  // Watched from before the solve: a refusal is quick, and the watch ends when the solve does.
  Watch watch(sessions_.get(), session.id());
  ASSERT_TRUE(watch.WaitFor([](const auto& events, bool) { return !events.empty(); }));
  v1::SolveSessionRequest req;
  req.set_session_id(session.id());
  req.set_seed(1);
  v1::SolveJob job;
  ASSERT_TRUE(sessions_->SolveSession(Ctx().get(), req, &job).ok());
  ASSERT_TRUE(watch.WaitFor([](const auto&, bool ended) { return ended; }, seconds(30)));
  const std::string job_id = job.id();
  for (int round = 0; round < 2; ++round) {  // then again after a restart (from storage)
    SCOPED_TRACE(round == 0 ? "running since the solve" : "after a restart");
    v1::GetSolveJobRequest get;
    get.set_job_id(job_id);
    ASSERT_TRUE(sessions_->GetSolveJob(Ctx().get(), get, &job).ok());
    EXPECT_EQ(job.state(), v1::JOB_STATE_FAILED);
    EXPECT_EQ(job.verdict(), "refused");
    EXPECT_EQ(job.verdict_kind(), v1::VERDICT_REFUSED);  // also when read back after a restart
    EXPECT_EQ(job.version(), 0);
    EXPECT_EQ(job.error().rfind("the capture cannot support a calibration (", 0), 0u)
        << job.error();
    const v1::Session after = GetSession(session.id());
    EXPECT_EQ(after.state(), v1::SESSION_STATE_OPEN);
    EXPECT_EQ(after.samples(), stored);
    EXPECT_EQ(after.version(), 0);
    v1::ListVersionsRequest list;
    list.set_device_id("robot-refused");
    v1::ListVersionsResponse versions;
    ASSERT_TRUE(params_->ListVersions(Ctx().get(), list, &versions).ok());
    EXPECT_EQ(versions.versions_size(), 0);
    const std::string report = ReportOf(session.id());
    EXPECT_NE(report.find("\"verdict\": \"refused\""), std::string::npos) << report.substr(0, 600);
    EXPECT_NE(report.find("\"refusal\""), std::string::npos);
    if (round == 0) StartServer();
  }

  // The rest of the capture into the same session: it now calibrates.
  ASSERT_TRUE(
      Stream(std::vector<v1::SampleBatch>(batches.begin() + head, batches.end()), &acks).ok());
  EXPECT_EQ(GetSession(session.id()).samples(), static_cast<int64_t>(sim.capture.size()));
  Watch again(sessions_.get(), session.id());
  ASSERT_TRUE(again.WaitFor([](const auto& events, bool) { return !events.empty(); }));
  ASSERT_TRUE(sessions_->SolveSession(Ctx().get(), req, &job).ok());
  ASSERT_TRUE(again.WaitFor([](const auto&, bool ended) { return ended; }, seconds(60)));
  v1::GetSolveJobRequest get;
  get.set_job_id(job.id());
  ASSERT_TRUE(sessions_->GetSolveJob(Ctx().get(), get, &job).ok());
  EXPECT_EQ(job.state(), v1::JOB_STATE_DONE) << job.error();
  EXPECT_EQ(job.version(), 1);
  EXPECT_EQ(GetSession(session.id()).state(), v1::SESSION_STATE_SOLVED);
  EXPECT_EQ(ReportOf(session.id()).find("\"verdict\": \"refused\""), std::string::npos);
}

TEST_F(ServerTest, ResolvePromoteAndRollback) {
  Register("robot-4");
  grpc::Status s;
  const v1::Session session = Create("robot-4", v1::PROTOCOL_SIX_FACE, &s);
  ASSERT_TRUE(s.ok());
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream(Batches(Sim().capture, session.id()), &acks).ok());

  auto solve_and_wait = [&](uint64_t seed) {
    v1::SolveSessionRequest req;
    req.set_session_id(session.id());
    req.set_seed(seed);
    v1::SolveJob job;
    EXPECT_TRUE(sessions_->SolveSession(Ctx().get(), req, &job).ok());
    // Ends when the session closes: at once if the solve is already done.
    Watch watch(sessions_.get(), session.id());
    EXPECT_TRUE(watch.WaitFor([](const auto&, bool ended) { return ended; }, seconds(30)))
        << "seed " << seed << ": " << watch.events().size() << " events, last "
        << (watch.events().empty() ? "" : watch.events().back().DebugString());
    v1::GetSolveJobRequest get;
    get.set_job_id(job.id());
    EXPECT_TRUE(sessions_->GetSolveJob(Ctx().get(), get, &job).ok());
    return job;
  };
  const v1::SolveJob first = solve_and_wait(1);
  ASSERT_EQ(first.state(), v1::JOB_STATE_DONE) << first.error();
  {  // cached now: the re-solve's activation below must replace it
    v1::GetActiveParametersRequest fetch;
    fetch.set_device_id("robot-4");
    v1::ParameterSet fetched;
    ASSERT_TRUE(params_->GetActiveParameters(Ctx().get(), fetch, &fetched).ok());
    EXPECT_EQ(fetched.version(), 1);
  }
  const v1::SolveJob second = solve_and_wait(2);  // a re-solve is a new version
  ASSERT_EQ(second.state(), v1::JOB_STATE_DONE) << second.error();
  EXPECT_EQ(second.version(), 2);

  v1::ListVersionsRequest list;
  list.set_device_id("robot-4");
  list.set_page_size(1);
  v1::ListVersionsResponse page;
  ASSERT_TRUE(params_->ListVersions(Ctx().get(), list, &page).ok());
  ASSERT_EQ(page.versions_size(), 1);
  EXPECT_EQ(page.versions(0).version(), 1);
  EXPECT_EQ(page.versions(0).state(), v1::VERSION_STATE_SUPERSEDED);
  EXPECT_TRUE(page.versions(0).json().empty());
  list.set_page_token(page.next_page_token());
  ASSERT_TRUE(params_->ListVersions(Ctx().get(), list, &page).ok());
  ASSERT_EQ(page.versions_size(), 1);
  EXPECT_EQ(page.versions(0).state(), v1::VERSION_STATE_ACTIVE);

  // The fetch is served from the cache from now on: a rollback and a promote must show at once.
  v1::GetActiveParametersRequest fetch;
  fetch.set_device_id("robot-4");
  v1::ParameterSet fetched;
  ASSERT_TRUE(params_->GetActiveParameters(Ctx().get(), fetch, &fetched).ok());
  ASSERT_TRUE(params_->GetActiveParameters(Ctx().get(), fetch, &fetched).ok());
  EXPECT_EQ(fetched.version(), 2);
  EXPECT_FALSE(fetched.json().empty());
  EXPECT_EQ(fetched.crc32c(), formats::Crc32c(fetched.json()));

  v1::RollbackRequest rollback;
  rollback.set_device_id("robot-4");
  rollback.set_to_version(1);
  rollback.set_reason("test");
  v1::ParameterSet ps;
  ASSERT_TRUE(params_->Rollback(Ctx().get(), rollback, &ps).ok());
  EXPECT_EQ(ps.version(), 1);
  EXPECT_EQ(ps.state(), v1::VERSION_STATE_ACTIVE);
  rollback.set_to_version(2);  // not older than the active one
  EXPECT_EQ(params_->Rollback(Ctx().get(), rollback, &ps).error_code(),
            grpc::StatusCode::FAILED_PRECONDITION);
  v1::PromoteRequest promote;
  promote.set_device_id("robot-4");
  promote.set_version(2);  // superseded: promote is for candidates
  EXPECT_EQ(params_->Promote(Ctx().get(), promote, &ps).error_code(),
            grpc::StatusCode::FAILED_PRECONDITION);
  promote.set_version(1);  // the active one: a no-op
  ASSERT_TRUE(params_->Promote(Ctx().get(), promote, &ps).ok());
  v1::GetActiveParametersRequest active;
  active.set_device_id("robot-4");
  ASSERT_TRUE(params_->GetActiveParameters(Ctx().get(), active, &ps).ok());
  EXPECT_EQ(ps.version(), 1);
  EXPECT_NE(ps.crc32c(), 0u);
}

// A robot whose driver dropped the temperature channel for part of the session: the solve runs
// without temperature (a capture has it for every sample or none), and the stored report says
// so, with how many samples lacked it, instead of silently testing no temperature effect.
TEST_F(ServerTest, MixedTemperatureBatchesAreSaidInTheReport) {
  Register("robot-8");
  grpc::Status s;
  const v1::Session session = Create("robot-8", v1::PROTOCOL_SIX_FACE, &s);
  ASSERT_TRUE(s.ok());
  const core::SimResult sim = Sim();
  ASSERT_TRUE(sim.capture.has_temp());
  std::vector<v1::SampleBatch> batches = Batches(sim.capture, session.id());
  int dropped = 0;
  for (size_t b = 1; b < batches.size(); b += 2) {
    dropped += batches[b].temp_c_size();
    batches[b].clear_temp_c();
  }
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream(batches, &acks).ok());
  v1::SolveSessionRequest req;
  req.set_session_id(session.id());
  req.set_seed(1);
  v1::SolveJob job;
  ASSERT_TRUE(sessions_->SolveSession(Ctx().get(), req, &job).ok());
  Watch watch(sessions_.get(), session.id());
  ASSERT_TRUE(watch.WaitFor([](const auto&, bool ended) { return ended; }, seconds(30)));
  v1::GetSolveJobRequest get;
  get.set_job_id(job.id());
  ASSERT_TRUE(sessions_->GetSolveJob(Ctx().get(), get, &job).ok());
  ASSERT_EQ(job.state(), v1::JOB_STATE_DONE) << job.error();
  const std::string report = ReportOf(session.id());
  const std::string said = "temperature left out of the solve: " + std::to_string(dropped) +
                           " of the session's " + std::to_string(sim.capture.size()) + " samples";
  EXPECT_NE(report.find(said), std::string::npos) << report.substr(0, 2000);
  EXPECT_NE(report.find("no temperature channel: temperature effects could not be tested"),
            std::string::npos);
}

TEST(ActiveParamCacheTest, AFillThatRacedAnInvalidationIsDropped) {
  ActiveParamCache cache;
  auto entry = [](int version) {
    auto e = std::make_shared<ActiveParamCache::Entry>();
    e->version = version;
    e->full = grpc::Slice(std::string(100, 'x'));
    return e;
  };
  const uint64_t before_read = cache.generation();
  cache.Invalidate("robot-1");  // a promote committed while the fill read the store
  cache.Insert("robot-1", entry(1), before_read);
  EXPECT_EQ(cache.Find("robot-1"), nullptr);
  cache.Insert("robot-1", entry(2), cache.generation());
  ASSERT_NE(cache.Find("robot-1"), nullptr);
  EXPECT_EQ(cache.Find("robot-1")->version, 2);
  cache.Invalidate("robot-1");
  EXPECT_EQ(cache.Find("robot-1"), nullptr);
  EXPECT_EQ(cache.bytes(), 0u);
}

TEST(ActiveParamCacheTest, MemoryIsBounded) {
  ActiveParamCache cache(/*max_bytes=*/10000);
  for (int i = 0; i < 1000; ++i) {
    auto e = std::make_shared<ActiveParamCache::Entry>();
    e->version = 1;
    e->full = grpc::Slice(std::string(500, 'x'));
    cache.Insert("robot-" + std::to_string(i), e, cache.generation());
    if (i % 3 == 0) cache.Invalidate("robot-" + std::to_string(i - 1));
    ASSERT_LE(cache.bytes(), 10000u);
  }
  EXPECT_GT(cache.size(), 5u);
  EXPECT_NE(cache.Find("robot-999"), nullptr);  // the newest stays
  EXPECT_EQ(cache.Find("robot-1"), nullptr);    // the oldest went
}

TEST_F(ServerTest, HealthIsServingAndUnknownsAreNotFound) {
  grpc::GenericStub generic(channel_);
  grpc::ByteBuffer request, response;  // HealthCheckRequest{service: ""} is zero bytes
  grpc::Slice empty("");
  request = grpc::ByteBuffer(&empty, 1);
  grpc::ClientContext ctx;
  ctx.set_deadline(system_clock::now() + seconds(10));
  std::promise<grpc::Status> done;
  generic.UnaryCall(&ctx, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request, &response,
                    [&](grpc::Status st) { done.set_value(st); });
  grpc::Status st = done.get_future().get();
  ASSERT_TRUE(st.ok()) << st.error_message();
  std::vector<grpc::Slice> slices;
  ASSERT_TRUE(response.Dump(&slices).ok());
  std::string bytes;
  for (const auto& sl : slices) bytes.append(reinterpret_cast<const char*>(sl.begin()), sl.size());
  EXPECT_EQ(bytes, std::string("\x08\x01", 2));  // status: SERVING

  v1::GetActiveParametersRequest active;
  active.set_device_id("nobody");
  v1::ParameterSet ps;
  EXPECT_EQ(params_->GetActiveParameters(Ctx().get(), active, &ps).error_code(),
            grpc::StatusCode::NOT_FOUND);
  v1::GetSessionRequest get;
  get.set_session_id("s-nope");
  v1::Session session;
  EXPECT_EQ(sessions_->GetSession(Ctx().get(), get, &session).error_code(),
            grpc::StatusCode::NOT_FOUND);
  v1::GetSolveJobRequest job;
  job.set_job_id("bogus");
  v1::SolveJob j;
  EXPECT_EQ(sessions_->GetSolveJob(Ctx().get(), job, &j).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
}

// A throwaway PostgreSQL database behind a TCP proxy a test can cut: `url` reaches the database
// directly (postgresql://imucal@127.0.0.1:PORT/NAME), `proxied_url` through the proxy; `port` is
// the database's own.
struct ProxiedPostgres {
  std::unique_ptr<testing_util::PgTestDatabase> db;
  std::unique_ptr<testing_util::TcpProxy> proxy;
  std::string url, port, proxied_url;
};

absl::StatusOr<ProxiedPostgres> StartProxiedPostgres() {
  absl::StatusOr<std::unique_ptr<testing_util::PgTestDatabase>> db =
      testing_util::PgTestDatabase::Create();
  if (!db.ok()) return db.status();
  ProxiedPostgres pg;
  pg.url = (*db)->url();
  pg.db = *std::move(db);
  const size_t host = pg.url.find("@127.0.0.1:");
  if (host == std::string::npos) return absl::InternalError("not a loopback URL: " + pg.url);
  const size_t port_at = host + 11, port_end = pg.url.find('/', port_at);
  pg.port = pg.url.substr(port_at, port_end - port_at);
  pg.proxy = testing_util::TcpProxy::Start(std::stoi(pg.port));
  if (pg.proxy == nullptr) return absl::InternalError("the TCP proxy did not start");
  pg.proxied_url =
      pg.url.substr(0, port_at) + std::to_string(pg.proxy->port()) + pg.url.substr(port_end);
  return pg;
}

// PostgreSQL out of reach (the server cut off it by a proxy; the database itself stays up):
// every call that needs the database answers UNAVAILABLE with "the calibration service's
// database is unavailable", and nothing of the database: not its host or port, not libpq's
// text, not SQL (the detail goes to the server's log). Once it is back, the calls succeed again.
TEST_F(ServerTest, OnPostgresAnOutageSaysTheDatabaseIsUnavailableAndNothingOfIt) {
  absl::StatusOr<ProxiedPostgres> pg = StartProxiedPostgres();
  ASSERT_TRUE(pg.ok()) << pg.status();
  testing_util::TcpProxy* proxy = pg->proxy.get();
  const std::string& pg_port = pg->port;
  const std::string proxy_port = std::to_string(proxy->port());
  options_.db_path = pg->proxied_url;
  StartServer();
  Register("robot-1");
  grpc::Status status;
  const v1::Session session = Create("robot-1", v1::PROTOCOL_SIX_FACE, &status);
  ASSERT_TRUE(status.ok()) << status.error_message();
  const std::vector<v1::SampleBatch> batches = Batches(Sim().capture, session.id());
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream({batches[0], batches[1]}, &acks).ok());

  proxy->Cut();
  testing::internal::CaptureStderr();
  std::vector<std::pair<std::string, grpc::Status>> calls;
  {
    v1::RegisterDeviceRequest reg;
    reg.mutable_device()->set_id("robot-2");
    reg.mutable_device()->set_sensor_model("sim");
    reg.mutable_device()->set_nominal_rate_hz(200);
    reg.mutable_device()->set_accel_unit("m/s^2");
    reg.mutable_device()->set_gyro_unit("rad/s");
    v1::Device device;
    calls.emplace_back("RegisterDevice", devices_->RegisterDevice(Ctx().get(), reg, &device));
    v1::ListDevicesResponse devices;
    calls.emplace_back("ListDevices",
                       devices_->ListDevices(Ctx().get(), v1::ListDevicesRequest(), &devices));
    v1::GetSessionRequest get;
    get.set_session_id(session.id());
    v1::Session got;
    calls.emplace_back("GetSession", sessions_->GetSession(Ctx().get(), get, &got));
    v1::ListSessionsResponse sessions;
    calls.emplace_back("ListSessions",
                       sessions_->ListSessions(Ctx().get(), v1::ListSessionsRequest(), &sessions));
    calls.emplace_back("StreamSamples", Stream({batches[2], batches[3]}, &acks));
    v1::GetSolveJobRequest job;
    job.set_job_id("solve-1");
    v1::SolveJob j;
    calls.emplace_back("GetSolveJob", sessions_->GetSolveJob(Ctx().get(), job, &j));
    v1::PromoteRequest promote;
    promote.set_device_id("robot-1");
    promote.set_version(1);
    v1::ParameterSet set;
    calls.emplace_back("Promote", params_->Promote(Ctx().get(), promote, &set));
  }
  const std::string log = testing::internal::GetCapturedStderr();
  for (const auto& [method, st] : calls) {
    EXPECT_EQ(st.error_code(), grpc::StatusCode::UNAVAILABLE)
        << method << ": " << st.error_message();
    EXPECT_EQ(st.error_message(), "the calibration service's database is unavailable") << method;
    std::string lower = st.error_message();
    for (char& c : lower) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    for (const std::string& leak :
         {std::string("127.0.0.1"), proxy_port, pg_port, std::string("postgres"),
          std::string("select "), std::string("insert "), std::string("update "),
          std::string("connection to server"), std::string("libpq")})
      EXPECT_EQ(lower.find(leak), std::string::npos) << method << ": " << st.error_message();
  }
  // The operator is told what happened, in the log.
  EXPECT_THAT(log, testing::HasSubstr("database_unavailable"));
  EXPECT_THAT(log, testing::HasSubstr(proxy_port));

  ASSERT_TRUE(proxy->Restore());
  Register("robot-2");
  EXPECT_TRUE(Stream({batches[2], batches[3]}, &acks).ok());
  EXPECT_EQ(GetSession(session.id()).last_acked_seq(), 4);
  server_.reset();  // before the database is dropped
}

// grpc.health.v1.Health/Check for the whole server (""): its status, 1 SERVING, 2 NOT_SERVING
// (0 when the answer holds none); -1 when the call failed.
int HealthStatus(const std::shared_ptr<grpc::Channel>& channel) {
  grpc::GenericStub generic(channel);
  grpc::Slice empty("");  // HealthCheckRequest{service: ""} is zero bytes
  grpc::ByteBuffer request(&empty, 1), response;
  grpc::ClientContext ctx;
  ctx.set_deadline(system_clock::now() + seconds(10));
  std::promise<grpc::Status> done;
  generic.UnaryCall(&ctx, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request, &response,
                    [&](grpc::Status st) { done.set_value(st); });
  if (!done.get_future().get().ok()) return -1;
  std::vector<grpc::Slice> slices;
  if (!response.Dump(&slices).ok()) return -1;
  std::string bytes;
  for (const auto& sl : slices) bytes.append(reinterpret_cast<const char*>(sl.begin()), sl.size());
  return bytes.size() == 2 && bytes[0] == '\x08' ? bytes[1] : 0;
}

// Until `done()` or `timeout` has passed; whether done() held. Bounded polling, for what offers
// nothing to wait on (the database monitor's ping, the health service's status).
bool PollUntil(const std::function<bool()>& done, std::chrono::seconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!done()) {
    if (std::chrono::steady_clock::now() >= deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return true;
}

// PostgreSQL out of reach (cut off by a proxy): health answers NOT_SERVING, the log says why, the
// imucal_database_up gauge reads 0; a robot's fetch of its active parameters is answered from
// the server's cache, marked served_from_cache, while a device the cache does not hold gets the
// database's unavailability. Once the database answers again: SERVING, and fetches from the
// database, unmarked. (Before, health said SERVING throughout and every fetch failed.)
TEST_F(ServerTest, OnPostgresHealthFollowsTheDatabaseAndFetchesAreServedFromTheCache) {
  absl::StatusOr<ProxiedPostgres> pg = StartProxiedPostgres();
  ASSERT_TRUE(pg.ok()) << pg.status();
  testing_util::TcpProxy* proxy = pg->proxy.get();
  const std::string& url = pg->url;
  options_.db_path = pg->proxied_url;
  options_.metrics_listen = "127.0.0.1:0";
  StartServer();
  Register("robot-1");
  Register("robot-2");
  {
    absl::StatusOr<std::unique_ptr<storage::Store>> store = storage::Store::Open(url);
    ASSERT_TRUE(store.ok()) << store.status();
    for (const char* device : {"robot-1", "robot-2"}) {
      storage::ParamVersion v;
      v.device_id = device;
      v.params_json = "{\"format\": \"imucal-params\"}";
      v.report_json = "{}";
      v.verdict = storage::Verdict::kPass;
      v.accel_rms = 0.01;
      v.state = storage::VersionState::kActive;
      ASSERT_TRUE((*store)->AddVersion(v, "test").ok());
    }
  }
  auto fetch = [&](const std::string& device, v1::ParameterSet* out) {
    v1::GetActiveParametersRequest req;
    req.set_device_id(device);
    return params_->GetActiveParameters(Ctx().get(), req, out);
  };
  // robot-1 is in the cache, robot-2 is not. The versions' notifications reach the server
  // after they commit, and a fill that an invalidation may concern is not kept: fetch until the
  // cache holds robot-1's answer.
  v1::ParameterSet before;
  ASSERT_TRUE(PollUntil(
      [&] {
        return fetch("robot-1", &before).ok() &&
               server_->active_cache()->Find("robot-1") != nullptr;
      },
      seconds(10)))
      << "robot-1's answer never stayed in the fetch cache";
  EXPECT_FALSE(before.served_from_cache());
  EXPECT_EQ(HealthStatus(channel_), 1);

  testing::internal::CaptureStderr();
  proxy->Cut();
  const bool went_down = PollUntil([&] { return HealthStatus(channel_) == 2; }, seconds(30));
  v1::ParameterSet during;
  const grpc::Status cached = fetch("robot-1", &during);
  v1::ParameterSet uncached;
  const grpc::Status missed = fetch("robot-2", &uncached);
  const std::string metrics = server_->metrics()->Text();
  const std::string log = testing::internal::GetCapturedStderr();
  ASSERT_TRUE(went_down) << "health did not answer NOT_SERVING with the database cut off";
  ASSERT_TRUE(cached.ok()) << cached.error_message();
  EXPECT_TRUE(during.served_from_cache());
  EXPECT_EQ(during.version(), before.version());
  EXPECT_EQ(during.json(), before.json());
  EXPECT_EQ(during.crc32c(), before.crc32c());
  EXPECT_EQ(missed.error_code(), grpc::StatusCode::UNAVAILABLE);
  EXPECT_EQ(missed.error_message(), "the calibration service's database is unavailable");
  EXPECT_THAT(metrics, testing::HasSubstr("imucal_database_up 0"));
  EXPECT_THAT(log, testing::HasSubstr("database_unreachable"));

  ASSERT_TRUE(proxy->Restore());
  EXPECT_TRUE(PollUntil([&] { return HealthStatus(channel_) == 1; }, seconds(30)))
      << "health did not answer SERVING again";
  v1::ParameterSet after;
  ASSERT_TRUE(PollUntil([&] { return fetch("robot-2", &after).ok(); }, seconds(30)));
  EXPECT_FALSE(after.served_from_cache());
  ASSERT_TRUE(fetch("robot-1", &after).ok());
  EXPECT_FALSE(after.served_from_cache());
  EXPECT_THAT(server_->metrics()->Text(), testing::HasSubstr("imucal_database_up 1"));
  server_.reset();  // before the database is dropped
}

// A robot still uploading into a session (its stream open) holds off the solve: SolveSession
// is FAILED_PRECONDITION naming the session and the open stream, and Session.open_streams says
// 1; with `force` the solve starts. Once the stream has ended, open_streams is 0.
TEST_F(ServerTest, ASolveIsRefusedWhileAStreamIsOpenUnlessForced) {
  Register("robot-1");
  grpc::Status status;
  const v1::Session session = Create("robot-1", v1::PROTOCOL_SIX_FACE, &status);
  ASSERT_TRUE(status.ok()) << status.error_message();
  const std::vector<v1::SampleBatch> batches = Batches(Sim().capture, session.id());
  auto ctx = Ctx();
  auto stream = sessions_->StreamSamples(ctx.get());
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(stream->Write(batches[static_cast<size_t>(i)]));
    v1::SampleAck ack;
    ASSERT_TRUE(stream->Read(&ack));
  }
  EXPECT_EQ(GetSession(session.id()).open_streams(), 1);

  v1::SolveSessionRequest solve;
  solve.set_session_id(session.id());
  v1::SolveJob job;
  const grpc::Status refused = sessions_->SolveSession(Ctx().get(), solve, &job);
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << refused.error_message();
  EXPECT_THAT(refused.error_message(),
              testing::HasSubstr("session " + session.id() + " has 1 sample stream open"));
  EXPECT_EQ(GetSession(session.id()).state(), v1::SESSION_STATE_OPEN);

  solve.set_force(true);
  const grpc::Status forced = sessions_->SolveSession(Ctx().get(), solve, &job);
  ASSERT_TRUE(forced.ok()) << forced.error_message();
  EXPECT_FALSE(job.id().empty());
  // The robot ends its stream (a batch after the solve began would find the session solving,
  // or, the solve refused for want of poses, open again); then none is open.
  stream->WritesDone();
  v1::SampleAck ack;
  while (stream->Read(&ack)) {
  }
  EXPECT_TRUE(stream->Finish().ok());
  EXPECT_EQ(GetSession(session.id()).open_streams(), 0);
}

// The registry's rules alone (server/stream_registry.h): the caps count from Add, a revoked
// token's streams are told and its later streams refused, and the sweeper tells a stream past
// its deadline.
class RegisteredStream final : public StreamRegistry::Stream {
 public:
  void Revoke(const grpc::Status& status) override {
    std::lock_guard lock(mu_);
    revoked_ = status.error_message();
  }
  void Expire(absl::Time now) override {
    std::lock_guard lock(mu_);
    if (PastDeadline(now)) ++expired_;
    cv_.notify_all();
  }
  std::string revoked() {
    std::lock_guard lock(mu_);
    return revoked_;
  }
  bool WaitExpired(std::chrono::seconds timeout) {
    std::unique_lock lock(mu_);
    return cv_.wait_for(lock, timeout, [this] { return expired_ > 0; });
  }
  int expired() {
    std::lock_guard lock(mu_);
    return expired_;
  }

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  std::string revoked_;  // guarded by mu_
  int expired_ = 0;      // guarded by mu_
};

TEST(StreamRegistryTest, CapsRevocationAndDeadlines) {
  StreamRegistry::Options options;
  options.max_streams = 3;
  options.max_per_caller = 2;
  options.tick = absl::Milliseconds(10);
  StreamRegistry registry(options);
  std::vector<std::shared_ptr<RegisteredStream>> s;
  for (int i = 0; i < 5; ++i) s.push_back(std::make_shared<RegisteredStream>());
  ASSERT_TRUE(registry.Add(s[0], "token:1", 1).ok());
  ASSERT_TRUE(registry.Add(s[1], "token:1", 1).ok());
  absl::Status refused = registry.Add(s[2], "token:1", 1);
  EXPECT_TRUE(absl::IsResourceExhausted(refused)) << refused;
  EXPECT_NE(refused.message().find("token 1 already has 2 streams open"), std::string::npos)
      << refused;
  ASSERT_TRUE(registry.Add(s[2], "token:2", 2).ok());  // another token has its own share
  refused = registry.Add(s[3], "", 0);                 // but the server is full
  EXPECT_TRUE(absl::IsResourceExhausted(refused)) << refused;
  EXPECT_NE(refused.message().find("the server has 3 streams open"), std::string::npos) << refused;
  registry.Remove(s[1].get());  // a place of token 1's and of the server's again
  ASSERT_TRUE(registry.Add(s[3], "token:1", 1).ok());
  EXPECT_EQ(registry.size(), 3u);

  registry.RevokeToken(1, grpc::Status(grpc::StatusCode::UNAUTHENTICATED, "token 1 was revoked"));
  EXPECT_EQ(s[0]->revoked(), "token 1 was revoked");
  EXPECT_EQ(s[3]->revoked(), "token 1 was revoked");
  EXPECT_EQ(s[2]->revoked(), "");
  registry.Remove(s[0].get());
  refused = registry.Add(s[4], "token:1", 1);  // authorised before the revocation, added after
  EXPECT_TRUE(absl::IsUnauthenticated(refused)) << refused;

  s[2]->SetDeadline(absl::Now() - absl::Seconds(1));
  s[3]->SetDeadline(absl::InfiniteFuture());
  EXPECT_TRUE(s[2]->WaitExpired(std::chrono::seconds(10)));
  EXPECT_EQ(s[3]->expired(), 0);
  for (const auto& stream : s) registry.Remove(stream.get());
  EXPECT_EQ(registry.size(), 0u);
}

// Fair shares: with the server full, a caller with fewer streams takes the place of a silent
// stream of the caller with the most, which is told; a stream that has been heard from keeps
// its place; a caller with as many streams as the most is refused; the place of a stream that
// gives way is not counted while it ends.
TEST(StreamRegistryTest, ASilentFloodGivesWayToACallerWithFewerStreams) {
  StreamRegistry::Options options;
  options.max_streams = 4;
  options.max_per_caller = 3;
  StreamRegistry registry(options);
  std::vector<std::shared_ptr<RegisteredStream>> s;
  for (int i = 0; i < 8; ++i) s.push_back(std::make_shared<RegisteredStream>());
  ASSERT_TRUE(registry.Add(s[0], "token:1", 1, /*silent=*/true).ok());
  ASSERT_TRUE(registry.Add(s[1], "token:1", 1, /*silent=*/true).ok());
  ASSERT_TRUE(registry.Add(s[2], "token:1", 1, /*silent=*/true).ok());
  ASSERT_TRUE(registry.Add(s[3], "token:2", 2, /*silent=*/true).ok());
  registry.Heard(s[0].get());
  registry.Heard(s[1].get());
  // Full. Token 3 has none: one of token 1's silent streams (s[2]: the others were heard) gives
  // way.
  ASSERT_TRUE(registry.Add(s[4], "token:3", 3).ok());
  EXPECT_NE(s[2]->revoked().find("its place went to a caller with fewer streams"),
            std::string::npos)
      << s[2]->revoked();
  EXPECT_EQ(s[0]->revoked(), "");
  EXPECT_EQ(s[1]->revoked(), "");
  EXPECT_EQ(s[3]->revoked(), "");
  EXPECT_EQ(registry.size(), 5u);  // s[2] is still ending; its place is s[4]'s
  // Token 1 has no silent stream left, and the only silent one is token 2's own: refused.
  absl::Status refused = registry.Add(s[5], "token:2", 2);
  EXPECT_TRUE(absl::IsResourceExhausted(refused)) << refused;
  EXPECT_NE(refused.message().find("the server has 4 streams open"), std::string::npos) << refused;
  registry.Remove(s[2].get());
  EXPECT_EQ(registry.size(), 4u);
  // Token 4 (none) against token 2 (one silent stream): it takes its place.
  ASSERT_TRUE(registry.Add(s[6], "token:4", 4).ok());
  EXPECT_NE(s[3]->revoked(), "");
  // In insecure mode (no caller) nobody is fewer: refused.
  refused = registry.Add(s[7], "", 0);
  EXPECT_TRUE(absl::IsResourceExhausted(refused)) << refused;
  for (const auto& stream : s) registry.Remove(stream.get());
  EXPECT_EQ(registry.size(), 0u);
}

// Many streams ended: the sweeper gives memory back (malloc_trim), once per interval.
TEST(StreamRegistryTest, MemoryIsGivenBackAfterManyStreamsEnd) {
  StreamRegistry::Options options;
  options.tick = absl::Milliseconds(10);
  options.trim_after_ends = 100;
  options.trim_interval = absl::Hours(1);
  StreamRegistry registry(options);
  for (int i = 0; i < 99; ++i) {
    auto s = std::make_shared<RegisteredStream>();
    ASSERT_TRUE(registry.Add(s, "token:1", 1).ok());
    registry.Remove(s.get());
  }
  auto last = std::make_shared<RegisteredStream>();
  ASSERT_TRUE(registry.Add(last, "token:1", 1).ok());
  registry.Remove(last.get());
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (registry.trims() == 0 && std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  EXPECT_EQ(registry.trims(), 1);
  for (int i = 0; i < 200; ++i) {
    auto s = std::make_shared<RegisteredStream>();
    ASSERT_TRUE(registry.Add(s, "token:1", 1).ok());
    registry.Remove(s.get());
  }
  // Not again within the interval (the sweeper ticks every 10 ms meanwhile).
  EXPECT_EQ(registry.trims(), 1);
}

TEST(StatusUtilTest, MapsCodesOneToOneAndScrubsPaths) {
  const grpc::Status s =
      ToGrpcStatus(absl::UnavailableError("cannot open /var/lib/imucal/imucal.db: locked"));
  EXPECT_EQ(s.error_code(), grpc::StatusCode::UNAVAILABLE);
  EXPECT_EQ(s.error_message().find("/var"), std::string::npos) << s.error_message();
  EXPECT_EQ(ToGrpcStatus(absl::InvalidArgumentError("accel: in m/s^2")).error_message(),
            "accel: in m/s^2");
  EXPECT_EQ(ToGrpcStatus(absl::InternalError("SELECT * FROM x")).error_message().find("SELECT"),
            std::string::npos);
  EXPECT_LE(ToGrpcStatus(absl::NotFoundError(std::string(5000, 'x'))).error_message().size(),
            kMaxStatusMessage);
  EXPECT_EQ(ToGrpcStatus(absl::ResourceExhaustedError("full")).error_code(),
            grpc::StatusCode::RESOURCE_EXHAUSTED);
}

// The database's own errors (storage::FromDatabase) keep their code and lose their text: a
// client is told a fixed sentence, whatever wrapped the error on its way (WithOperation keeps
// the mark), and the same goes for errors carried in a response (ClientMessage: SolveJob.error).
TEST(StatusUtilTest, DatabaseErrorsKeepTheirCodeAndNotTheirText) {
  auto from_db = [](absl::StatusCode code, const std::string& text) {
    return storage::WithOperation(
        "AppendBatch", storage::WithOperation("step", sql::FromDatabase(absl::Status(code, text))));
  };
  const grpc::Status down = ToGrpcStatus(from_db(
      absl::StatusCode::kUnavailable,
      "cannot reconnect to PostgreSQL: connection to server at \"10.0.0.5\", port 5432 failed"));
  EXPECT_EQ(down.error_code(), grpc::StatusCode::UNAVAILABLE);
  EXPECT_EQ(down.error_message(), "the calibration service's database is unavailable");
  const grpc::Status race = ToGrpcStatus(from_db(
      absl::StatusCode::kAlreadyExists,
      "INSERT INTO sessions: duplicate key value violates unique constraint \"sessions_open\""));
  EXPECT_EQ(race.error_code(), grpc::StatusCode::ALREADY_EXISTS);
  EXPECT_EQ(race.error_message(),
            "the calibration service's database refused the change: another one made at the "
            "same time conflicts with it; retry");
  for (absl::StatusCode code : {absl::StatusCode::kFailedPrecondition, absl::StatusCode::kAborted,
                                absl::StatusCode::kResourceExhausted, absl::StatusCode::kCancelled,
                                absl::StatusCode::kInvalidArgument, absl::StatusCode::kInternal,
                                absl::StatusCode::kDataLoss}) {
    const grpc::Status st = ToGrpcStatus(from_db(code, "SELECT x FROM y at 10.0.0.5:5432"));
    EXPECT_EQ(static_cast<int>(st.error_code()), static_cast<int>(code));
    EXPECT_EQ(st.error_message().find("10.0.0.5"), std::string::npos) << st.error_message();
    EXPECT_EQ(st.error_message().find("SELECT"), std::string::npos) << st.error_message();
    EXPECT_EQ(st.error_message(), DatabaseErrorMessage(code));
  }
  EXPECT_EQ(ClientMessage(from_db(absl::StatusCode::kUnavailable, "port 5432 failed")),
            "the calibration service's database is unavailable");
  // Not from the database: told as before.
  EXPECT_EQ(ToGrpcStatus(storage::WithOperation("GetSession", absl::NotFoundError("session 's-1' "
                                                                                  "not found")))
                .error_message(),
            "session 's-1' not found");
}

}  // namespace
}  // namespace imucal::server
