// The Store as a whole: its options, and what survives closing the file or a killed process.
#include "storage/store.h"

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "tests/storage/store_test_util.h"

namespace imucal::storage {
namespace {

TEST_P(StoreTest, TimesComeFromTheInjectedClock) {
  store_.reset();
  StoreOptions options;
  const absl::Time t0 = absl::FromUnixSeconds(1'800'000'000);
  options.clock = [t0] { return t0; };
  ASSERT_OK_AND_ASSIGN(store_, Store::Open(path_, options));
  ASSERT_OK_AND_ASSIGN(Device d, store_->CreateDevice(MakeDevice("robot-1"), kActor));
  EXPECT_EQ(d.created_at, t0);
  ASSERT_OK_AND_ASSIGN(std::vector<AuditEntry> audit, store_->ListAudit());
  ASSERT_EQ(audit.size(), 1u);
  EXPECT_EQ(audit[0].time, t0);
}

TEST_P(StoreTest, ReopeningTheFileKeepsEverything) {
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK(store_->CreateSession(MakeSession("robot-1", "S1"), kActor).status());
  for (int64_t seq = 1; seq <= 5; ++seq) {
    ASSERT_OK(store_->AppendBatch("S1", seq, BatchPayload(seq)).status());
  }
  std::vector<Pose> poses(1);
  poses[0].t_end_s = 3;
  ASSERT_OK(store_->PutPoses("S1", poses, "server"));
  ASSERT_OK_AND_ASSIGN(Solve solve, store_->StartSolve("S1", "server"));
  ParamVersion v = MakeVersion("");
  v.state = VersionState::kActive;
  ASSERT_OK_AND_ASSIGN(ParamVersion v1, store_->FinishSolve(solve.id, v, "server"));
  const std::vector<AuditEntry> audit = store_->ListAudit().value();

  Reopen();

  ASSERT_OK_AND_ASSIGN(Device d, store_->GetDevice("robot-1"));
  EXPECT_EQ(d.sensor_model, "ICM-20948");
  ASSERT_OK_AND_ASSIGN(Session s, store_->GetSession("S1"));
  EXPECT_EQ(s.state, SessionState::kSolved);
  EXPECT_EQ(s.last_acked_seq, 5);
  ASSERT_OK_AND_ASSIGN(std::vector<SampleBatch> batches, store_->ReadBatches("S1"));
  ASSERT_EQ(batches.size(), 5u);
  EXPECT_EQ(batches[4].payload, BatchPayload(5));
  EXPECT_EQ(store_->ListPoses("S1").value().size(), 1u);
  EXPECT_EQ(store_->GetSolve(solve.id).value().version, 1);
  ASSERT_OK_AND_ASSIGN(ParamVersion active, store_->GetActive("robot-1"));
  EXPECT_EQ(active.version, 1);
  EXPECT_EQ(active.created_at, v1.created_at);
  EXPECT_EQ(active.session_id, "S1");
  EXPECT_EQ(active.provenance, v1.provenance);
  ASSERT_OK_AND_ASSIGN(std::vector<AuditEntry> audit_after, store_->ListAudit());
  ASSERT_EQ(audit_after.size(), audit.size());
  for (size_t i = 0; i < audit.size(); ++i) {
    EXPECT_EQ(audit_after[i].id, audit[i].id);
    EXPECT_EQ(audit_after[i].time, audit[i].time);
    EXPECT_EQ(audit_after[i].detail, audit[i].detail);
  }
  // And the robot resumes where it left off.
  ASSERT_OK(store_->SetSessionState("S1", SessionState::kSolving, kActor).status());
  ASSERT_OK(store_->SetSessionState("S1", SessionState::kOpen, kActor).status());
  EXPECT_EQ(store_->AppendBatch("S1", s.last_acked_seq + 1, BatchPayload(6)).value().last_acked_seq,
            6);
}

// Reads exactly one 8-byte record; false at end of stream.
bool ReadAck(int fd, int64_t* seq) {
  char buf[sizeof(int64_t)];
  size_t got = 0;
  while (got < sizeof(buf)) {
    const ssize_t n = ::read(fd, buf + got, sizeof(buf) - got);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    got += static_cast<size_t>(n);
  }
  std::memcpy(seq, buf, sizeof(buf));
  return true;
}

// The child: a robot stream that appends batches from `first_seq` on and reports each
// acknowledged seq on `fd`, until it is killed. Never returns.
[[noreturn]] void StreamUntilKilled(const std::string& path, int64_t first_seq, int fd) {
  absl::StatusOr<std::unique_ptr<Store>> store = Store::Open(path);
  if (!store.ok()) ::_exit(2);
  for (int64_t seq = first_seq;; ++seq) {
    absl::StatusOr<BatchAck> ack = (*store)->AppendBatch("S1", seq, BatchPayload(seq, 200));
    if (!ack.ok() || ack->last_acked_seq != seq) ::_exit(3);
    if (::write(fd, &seq, sizeof(seq)) != static_cast<ssize_t>(sizeof(seq))) ::_exit(4);
  }
}

TEST_P(StoreTest, AcknowledgedBatchesSurviveSigkill) {
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK(store_->CreateSession(MakeSession("robot-1", "S1"), kActor).status());
  store_.reset();  // no SQLite connection may cross fork()

  const uint64_t seed = std::random_device{}();
  SCOPED_TRACE(testing::Message() << "seed " << seed);
  std::mt19937_64 rng(seed);
  int64_t last_acked_seen = 0;
  for (int round = 0; round < 4; ++round) {
    SCOPED_TRACE(testing::Message() << "round " << round);
    // Resume as a reconnecting robot does: from the last acknowledged batch.
    int64_t resume_from = 1;
    {
      ASSERT_OK_AND_ASSIGN(auto store, Store::Open(path_));
      resume_from = store->GetSession("S1").value().last_acked_seq + 1;
    }
    int fds[2];
    ASSERT_EQ(::pipe(fds), 0);
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      ::close(fds[0]);
      StreamUntilKilled(path_, resume_from, fds[1]);
    }
    ::close(fds[1]);
    // Kill after a random number of acks: the child is mid-append at that moment, at a point
    // the test does not choose. No assertion before the kill, so the child never outlives us.
    const int64_t acks_wanted = std::uniform_int_distribution<int64_t>(1, 300)(rng);
    std::vector<int64_t> acked;
    int64_t seq = 0;
    while (static_cast<int64_t>(acked.size()) < acks_wanted && ReadAck(fds[0], &seq)) {
      acked.push_back(seq);
    }
    ::kill(pid, SIGKILL);
    int status = 0;
    const pid_t waited = ::waitpid(pid, &status, 0);
    ::close(fds[0]);
    ASSERT_EQ(waited, pid);
    ASSERT_EQ(static_cast<int64_t>(acked.size()), acks_wanted)
        << "the child stopped early, wait status " << status;
    ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL) << status;
    for (size_t i = 0; i < acked.size(); ++i) {
      ASSERT_EQ(acked[i], resume_from + static_cast<int64_t>(i));
    }
    last_acked_seen = acked.back();

    ASSERT_OK_AND_ASSIGN(auto store, Store::Open(path_));
    ASSERT_OK_AND_ASSIGN(Session s, store->GetSession("S1"));
    EXPECT_GE(s.last_acked_seq, last_acked_seen);  // it may have committed one more
    ASSERT_OK_AND_ASSIGN(std::vector<SampleBatch> batches, store->ReadBatches("S1"));
    ASSERT_EQ(static_cast<int64_t>(batches.size()), s.last_acked_seq);
    for (size_t i = 0; i < batches.size(); ++i) {
      ASSERT_EQ(batches[i].seq, static_cast<int64_t>(i) + 1);
      ASSERT_EQ(batches[i].payload, BatchPayload(batches[i].seq, 200)) << "seq " << batches[i].seq;
    }
  }
}

}  // namespace
// Every Store test runs on SQLite and on PostgreSQL (store_test_util.h).
INSTANTIATE_TEST_SUITE_P(Backends, StoreTest,
                         ::testing::Values(Backend::kSqlite, Backend::kPostgres), BackendName);
INSTANTIATE_TEST_SUITE_P(Backends, BatchTest,
                         ::testing::Values(Backend::kSqlite, Backend::kPostgres), BackendName);

}  // namespace imucal::storage
