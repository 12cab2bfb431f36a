// Three imucald replicas on one real PostgreSQL (tests/pg_test_cluster.h), each a process on a
// loopback port. Per seed:
//   1. two robots stream their captures through the SDK's Uploader on a channel given replica 1
//      then replica 2 (gRPC's pick_first over the address list: nothing home-made);
//   2. replica 1 is SIGKILLed after a random number of acknowledgements, mid-stream;
//   3. the robots resume on replica 2 from their last durable ack and finish: every sample
//      acknowledged before the kill is stored, and each session holds its whole capture once, in
//      order, byte for byte (batches 1..n without a gap or a repeat);
//   4. robot 0's session is solved on replica 3 twice: versions 1 and 2, both active in turn;
//   5. replica 1 is started again; a rollback to version 1 through it is seen by replica 3's
//      fetch (whose cache held version 2) through PostgreSQL's notifications;
//   6. robot 1's session is solved on replica 3, which is SIGKILLed a random moment after it
//      took the solve: replica 1 or 2 claims the solve once its lease (1 s) lapses and runs it
//      again, and exactly one version is written (when the kill came after the version, there
//      is nothing to run again: the same checks hold).
// The seed comes from the instance (IMUCAL_CRASH_SEED overrides it); the kill point from it.
#include <signal.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "client/sdk/uploader.h"
#include "core/simulator.h"
#include "grpcpp/grpcpp.h"
#include "gtest/gtest.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "storage/sample_codec.h"
#include "storage/store.h"
#include "tests/client/imucald_process.h"
#include "tests/pg_test_cluster.h"
#include "tests/server/daemon_clients.h"
#include "tests/server/stored_samples.h"
#include "tests/server/watch.h"

namespace imucal::server {
namespace {

namespace pb = ::imucal::v1;
using testing_util::ImucaldProcess;
using testing_util::SameBytes;

constexpr int kRobots = 2;
constexpr int kBatchSamples = 200;

using testing_util::SeedOr;

// One channel over several replicas: gRPC's pick_first takes the first that answers and moves
// on when it dies.
std::shared_ptr<grpc::Channel> ChannelTo(const std::vector<const ImucaldProcess*>& replicas) {
  std::string target = "ipv4:";
  for (size_t i = 0; i < replicas.size(); ++i)
    target += (i == 0 ? "" : ",") + replicas[i]->address();
  grpc::ChannelArguments args;
  args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, 100);
  args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, 500);
  return grpc::CreateCustomChannel(target, grpc::InsecureChannelCredentials(), args);
}

grpc::Status Call(const std::function<grpc::Status(grpc::ClientContext*)>& call) {
  grpc::ClientContext context;
  context.set_wait_for_ready(true);
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  return call(&context);
}

class ReplicasTest : public ::testing::TestWithParam<uint64_t> {
 protected:
  void SetUp() override {
    if (!testing_util::kHaveImucald) GTEST_SKIP() << "imucald is not built yet";
    auto db = testing_util::PgTestDatabase::Create();
    ASSERT_TRUE(db.ok()) << db.status();
    db_ = *std::move(db);
    for (int r = 1; r <= 3; ++r) {
      auto replica = ImucaldProcess::StartOnDatabase(
          db_->url(), {"--replica-id", absl::StrCat("r", r), "--log-level", "warning",
                       "--solve-lease", "1s", "--stream-lease", "1s"});
      ASSERT_TRUE(replica.ok()) << "replica " << r << ": " << replica.status();
      replicas_.push_back(*std::move(replica));
    }
  }
  void TearDown() override {
    replicas_.clear();  // before the database is dropped
    db_.reset();
  }

  std::string OpenSession(const std::string& device) {
    auto channel = replicas_[0]->NewChannel();
    const pb::RegisterDeviceRequest reg = testing_util::SimDeviceRequest(device);
    pb::Device d;
    grpc::Status s = Call([&](grpc::ClientContext* c) {
      return pb::DeviceService::NewStub(channel)->RegisterDevice(c, reg, &d);
    });
    EXPECT_TRUE(s.ok()) << s.error_message();
    pb::CreateSessionRequest create;
    create.set_device_id(device);
    create.set_protocol(pb::PROTOCOL_SIX_FACE);
    pb::Session session;
    s = Call([&](grpc::ClientContext* c) {
      return pb::SessionService::NewStub(channel)->CreateSession(c, create, &session);
    });
    EXPECT_TRUE(s.ok()) << s.error_message();
    return session.id();
  }

  // Solves `session` through `replica` and waits for the job; the version it made.
  pb::SolveJob Solve(const ImucaldProcess& replica, const std::string& session) {
    auto stub = pb::SessionService::NewStub(replica.NewChannel());
    pb::SolveSessionRequest req;
    req.set_session_id(session);
    pb::SolveJob job;
    grpc::Status s = Call([&](grpc::ClientContext* c) { return stub->SolveSession(c, req, &job); });
    EXPECT_TRUE(s.ok()) << s.error_message();
    // WatchSession ends when the session closes (at once if the solve has finished).
    EXPECT_TRUE(testing_util::FollowToEnd(stub.get(), session, std::chrono::seconds(120)).ok());
    pb::GetSolveJobRequest get;
    get.set_job_id(job.id());
    s = Call([&](grpc::ClientContext* c) { return stub->GetSolveJob(c, get, &job); });
    EXPECT_TRUE(s.ok()) << s.error_message();
    return job;
  }

  int FetchedVersion(const ImucaldProcess& replica, const std::string& device) {
    auto stub = pb::ParameterService::NewStub(replica.NewChannel());
    pb::GetActiveParametersRequest req;
    req.set_device_id(device);
    pb::ParameterSet set;
    grpc::Status s =
        Call([&](grpc::ClientContext* c) { return stub->GetActiveParameters(c, req, &set); });
    EXPECT_TRUE(s.ok()) << s.error_message();
    return set.version();
  }

  std::unique_ptr<testing_util::PgTestDatabase> db_;
  std::vector<std::unique_ptr<ImucaldProcess>> replicas_;
};

TEST_P(ReplicasTest, AReplicaKilledMidStreamLosesNoAckedSampleAndTheOthersCarryOn) {
  const uint64_t seed = SeedOr(GetParam());
  SCOPED_TRACE(absl::StrCat("seed ", seed));
  std::mt19937_64 rng(seed);
  core::SimOptions sim;
  sim.seed = seed;
  absl::StatusOr<core::SimResult> simulated = core::Simulate(sim);
  ASSERT_TRUE(simulated.ok()) << simulated.status();
  const core::Capture& capture = simulated->capture;
  const int64_t batches_each =
      (static_cast<int64_t>(capture.size()) + kBatchSamples - 1) / kBatchSamples;

  std::vector<std::string> sessions, devices;
  for (int r = 0; r < kRobots; ++r) {
    devices.push_back(absl::StrCat("robot-", r));
    sessions.push_back(OpenSession(devices.back()));
    ASSERT_FALSE(sessions.back().empty());
  }

  // 1-3. Stream through replica 1, kill it after `kill_after` acks, finish on replica 2.
  std::mutex mu;
  std::condition_variable cv;
  std::map<std::string, int64_t> acked;  // guarded by mu: the most samples seen acknowledged
  int64_t acks = 0;                      // guarded by mu
  const int64_t kill_after =
      std::uniform_int_distribution<int64_t>(1, kRobots * batches_each - 2)(rng);
  auto channel = ChannelTo({replicas_[0].get(), replicas_[1].get()});
  std::vector<absl::StatusOr<sdk::UploadResult>> results(kRobots, absl::UnknownError("not run"));
  std::vector<std::thread> robots;
  for (int r = 0; r < kRobots; ++r) {
    robots.emplace_back([&, r] {
      sdk::UploadOptions o;
      o.batch_samples = kBatchSamples;
      o.max_in_flight = 4;
      o.initial_backoff = absl::Milliseconds(20);
      o.max_backoff = absl::Milliseconds(200);
      o.progress = [&, id = sessions[r]](int64_t samples, int64_t) {
        std::lock_guard lock(mu);
        if (samples < acked[id]) ADD_FAILURE() << id << ": acknowledged samples went back";
        acked[id] = std::max(acked[id], samples);
        ++acks;
        cv.notify_all();
      };
      sdk::Uploader uploader(channel, o);
      results[r] = uploader.Upload(sessions[r], capture);
    });
  }
  std::map<std::string, int64_t> acked_at_kill;
  {
    std::unique_lock lock(mu);
    ASSERT_TRUE(cv.wait_for(lock, std::chrono::seconds(120), [&] { return acks >= kill_after; }))
        << "the robots stopped acknowledging before the kill";
    acked_at_kill = acked;
  }
  replicas_[0]->Stop(SIGKILL);
  for (std::thread& t : robots) t.join();
  int reconnects = 0;
  for (int r = 0; r < kRobots; ++r) {
    ASSERT_TRUE(results[r].ok()) << sessions[r] << ": " << results[r].status();
    reconnects += results[r]->reconnects;
  }

  {
    absl::StatusOr<std::unique_ptr<storage::Store>> store = storage::Store::Open(db_->url());
    ASSERT_TRUE(store.ok()) << store.status();
    for (const std::string& id : sessions) {
      absl::StatusOr<std::vector<storage::SampleBatch>> batches = (*store)->ReadBatches(id);
      ASSERT_TRUE(batches.ok()) << batches.status();
      std::vector<storage::ImuSample> stored;
      int64_t seq = 0;
      for (const storage::SampleBatch& b : *batches) {
        ASSERT_EQ(b.seq, ++seq) << id << ": batches 1, 2, 3, ... without a gap or a repeat";
        ASSERT_TRUE(storage::DecodeSamplesInto(b.payload, &stored).ok());
      }
      EXPECT_GE(static_cast<int64_t>(stored.size()), acked_at_kill[id]) << id;
      ASSERT_EQ(stored.size(), capture.size()) << id << ": the whole capture, once";
      for (size_t i = 0; i < stored.size(); ++i)
        ASSERT_TRUE(SameBytes(stored[i], capture, i)) << id << " sample " << i;
    }
  }

  // 4. Solved on replica 3, twice: versions 1 then 2, each active (the capture passes).
  for (int expected = 1; expected <= 2; ++expected) {
    const pb::SolveJob job = Solve(*replicas_[2], sessions[0]);
    ASSERT_EQ(job.state(), pb::JOB_STATE_DONE) << job.error();
    EXPECT_EQ(job.version(), expected);
    ASSERT_TRUE(job.activated()) << "verdict " << job.verdict();
  }
  ASSERT_EQ(FetchedVersion(*replicas_[2], devices[0]), 2);  // now in replica 3's cache

  // 5. Replica 1 again: its rollback reaches replica 3's fetch.
  ASSERT_TRUE(replicas_[0]->Relaunch().ok());
  {
    auto stub = pb::ParameterService::NewStub(replicas_[0]->NewChannel());
    pb::RollbackRequest req;
    req.set_device_id(devices[0]);
    req.set_to_version(1);
    req.set_reason("replicas test");
    pb::ParameterSet out;
    grpc::Status s = Call([&](grpc::ClientContext* c) { return stub->Rollback(c, req, &out); });
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  const auto rolled_back = std::chrono::steady_clock::now();
  int seen = 0;
  // Fetched until it changes, for at most 10 s (the notification takes milliseconds).
  while (seen != 1 && std::chrono::steady_clock::now() - rolled_back < std::chrono::seconds(10))
    seen = FetchedVersion(*replicas_[2], devices[0]);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() -
                                                              rolled_back)
                        .count();
  EXPECT_EQ(seen, 1) << "replica 3 still serves version " << seen << " after the rollback";

  // 6. Replica 3 takes robot 1's solve and is killed within about one solve's time; replica 1
  // or 2 runs it again once the claim lapses, and a watch on replica 2 sees it end either way.
  bool solve_run_again = false;
  {
    auto stub = pb::SessionService::NewStub(replicas_[2]->NewChannel());
    pb::SolveSessionRequest req;
    req.set_session_id(sessions[1]);
    req.set_seed(seed);
    pb::SolveJob job;
    grpc::Status s = Call([&](grpc::ClientContext* c) { return stub->SolveSession(c, req, &job); });
    ASSERT_TRUE(s.ok()) << s.error_message();
    std::this_thread::sleep_for(  // the random kill point itself, not a wait for anything
        std::chrono::microseconds(std::uniform_int_distribution<int>(0, 100'000)(rng)));
    replicas_[2]->Stop(SIGKILL);
    auto survivor = pb::SessionService::NewStub(replicas_[1]->NewChannel());
    ASSERT_TRUE(
        testing_util::FollowWhileSolving(survivor.get(), sessions[1], std::chrono::seconds(60)))
        << "the killed replica's solve was not finished by the other";
    absl::StatusOr<std::unique_ptr<storage::Store>> store = storage::Store::Open(db_->url());
    ASSERT_TRUE(store.ok()) << store.status();
    absl::StatusOr<std::vector<storage::Solve>> solves = (*store)->ListSolves(sessions[1]);
    ASSERT_TRUE(solves.ok()) << solves.status();
    ASSERT_EQ(solves->size(), 1u);
    const storage::Solve& solve = solves->front();
    EXPECT_EQ(absl::StrCat("solve-", solve.id), job.id());
    ASSERT_EQ(solve.state, storage::SolveState::kSucceeded) << solve.error;
    EXPECT_EQ(solve.version, 1);
    EXPECT_EQ(solve.seed, seed);
    solve_run_again = solve.attempts > 1;
    if (solve_run_again) {
      EXPECT_TRUE(solve.owner == "r1" || solve.owner == "r2") << solve.owner;
    } else {
      EXPECT_EQ(solve.owner, "r3");
    }
    EXPECT_EQ(solve.attempts, solve_run_again ? 2 : 1);
    absl::StatusOr<std::vector<storage::ParamVersion>> versions =
        (*store)->ListVersions(devices[1]);
    ASSERT_TRUE(versions.ok()) << versions.status();
    ASSERT_EQ(versions->size(), 1u) << "the version is written once";
    EXPECT_EQ(versions->front().session_id, sessions[1]);
  }
  std::printf("[ replicas ] kill after %lld of %lld acks, %d reconnects; solve %s; rollback on "
              "replica 1 seen by replica 3 after %.1f ms\n",
              static_cast<long long>(kill_after), static_cast<long long>(kRobots * batches_each),
              reconnects,
              solve_run_again ? "killed on replica 3, run again on another"
                              : "ended on replica 3 before its kill",
              ms);
}

// 50 kill points, one ctest entry each.
INSTANTIATE_TEST_SUITE_P(Seeds, ReplicasTest, ::testing::Range(uint64_t{1}, uint64_t{51}));

// A technician's watch on one replica while the robot streams through another and the solve
// runs on a third: the watch gets the poses as the other replica stores them, then the solve's
// job and the solved session, and ends as a watch on the solving replica would.
using WatchAcrossReplicasTest = ReplicasTest;

TEST_P(WatchAcrossReplicasTest, AWatchFollowsAStreamAndASolveThatRunElsewhere) {
  core::SimOptions sim;
  sim.seed = GetParam();
  absl::StatusOr<core::SimResult> simulated = core::Simulate(sim);
  ASSERT_TRUE(simulated.ok()) << simulated.status();
  const std::string session = OpenSession("robot-0");
  auto streaming = pb::SessionService::NewStub(replicas_[0]->NewChannel());
  auto watching = pb::SessionService::NewStub(replicas_[1]->NewChannel());
  testing_util::Watch local(streaming.get(), session);  // where the robot streams
  testing_util::Watch remote(watching.get(), session);  // another replica
  // Both watches have begun (their first event is the session as it is) before any sample.
  auto began = [](const std::vector<pb::SessionEvent>& events, bool ended) {
    return ended || !events.empty();
  };
  ASSERT_TRUE(local.WaitFor(began));
  ASSERT_TRUE(remote.WaitFor(began));

  sdk::UploadOptions o;
  o.batch_samples = kBatchSamples;
  ASSERT_TRUE(sdk::Uploader(replicas_[0]->NewChannel(), o).Upload(session, simulated->capture).ok());
  const int poses = testing_util::AcceptedPoses(local.events());
  ASSERT_GE(poses, 6) << "the capture's poses, as the streaming replica saw them";
  EXPECT_TRUE(remote.WaitFor([&](const std::vector<pb::SessionEvent>& events, bool) {
    return testing_util::AcceptedPoses(events) >= poses;
  })) << "the other replica's watch saw " << testing_util::AcceptedPoses(remote.events())
      << " of " << poses << " poses";
  EXPECT_EQ(testing_util::AcceptedPoses(remote.events()), poses) << "each pose once";

  const pb::SolveJob job = Solve(*replicas_[2], session);
  ASSERT_EQ(job.state(), pb::JOB_STATE_DONE) << job.error();
  ASSERT_TRUE(remote.WaitFor([](const std::vector<pb::SessionEvent>&, bool ended) {
    return ended;
  })) << "the watch did not end when the session was solved elsewhere";
  EXPECT_TRUE(remote.status().ok()) << remote.status().error_message();
  bool saw_done = false, saw_solved = false;
  for (const pb::SessionEvent& e : remote.events()) {
    saw_done |= e.has_solve() && e.solve().id() == job.id() &&
                e.solve().state() == pb::JOB_STATE_DONE && e.solve().version() == job.version();
    saw_solved |= e.has_session() && e.session().state() == pb::SESSION_STATE_SOLVED;
  }
  EXPECT_TRUE(saw_done) << "the solve's job, done, with its version";
  EXPECT_TRUE(saw_solved) << "the session, solved";
}

INSTANTIATE_TEST_SUITE_P(Seed, WatchAcrossReplicasTest, ::testing::Values(uint64_t{7}));

}  // namespace
}  // namespace imucal::server
