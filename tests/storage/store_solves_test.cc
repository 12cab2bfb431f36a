// Store: solves (storage/store_solves.cc).
#include <string>
#include <thread>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/store.h"
#include "tests/storage/store_test_util.h"

namespace imucal::storage {
namespace {

using ::testing::IsEmpty;

TEST_P(BatchTest, ASolveTurnsASessionIntoAVersionAndCanBeRepeated) {
  ASSERT_OK(store_->AppendBatch("S1", 1, BatchPayload(1)).status());
  ASSERT_OK(store_->AppendBatch("S1", 2, BatchPayload(2)).status());
  std::vector<Pose> poses(3);
  for (int i = 0; i < 3; ++i) poses[i].index = i;
  poses[1].used = false;
  ASSERT_OK(store_->PutPoses("S1", poses, "server"));
  ASSERT_OK_AND_ASSIGN(Solve solve, store_->StartSolve("S1", "server"));
  EXPECT_EQ(solve.state, SolveState::kRunning);
  ASSERT_OK_AND_ASSIGN(std::vector<Solve> running, store_->ListRunningSolves());
  ASSERT_EQ(running.size(), 1u);
  EXPECT_EQ(running[0].id, solve.id);
  EXPECT_EQ(store_->GetSession("S1").value().state, SessionState::kSolving);
  // A second solve of the same session cannot start while one runs.
  EXPECT_EQ(store_->StartSolve("S1", "server").status().code(),
            absl::StatusCode::kFailedPrecondition);

  ParamVersion v = MakeVersion("");  // device and session come from the solve
  v.state = VersionState::kActive;   // passed the quality gates
  ASSERT_OK_AND_ASSIGN(ParamVersion v1, store_->FinishSolve(solve.id, v, "server"));
  EXPECT_EQ(v1.version, 1);
  EXPECT_EQ(v1.device_id, "robot-1");
  EXPECT_EQ(v1.session_id, "S1");
  EXPECT_EQ(v1.state, VersionState::kActive);
  ASSERT_OK_AND_ASSIGN(Session solved, store_->GetSession("S1"));
  EXPECT_EQ(solved.state, SessionState::kSolved);
  EXPECT_EQ(solved.version, 1);
  EXPECT_EQ(solved.samples, 100);
  EXPECT_EQ(solved.last_acked_seq, 2);
  EXPECT_EQ(solved.poses_accepted, 2);
  EXPECT_EQ(solved.gravity_m_s2, 9.80665);
  EXPECT_THAT(store_->ListRunningSolves().value(), IsEmpty());
  ASSERT_OK_AND_ASSIGN(Solve done, store_->GetSolve(solve.id));
  EXPECT_EQ(done.state, SolveState::kSucceeded);
  EXPECT_EQ(done.version, 1);
  EXPECT_TRUE(done.finished_at.has_value());
  EXPECT_EQ(store_->FinishSolve(solve.id, v, "server").status().code(),
            absl::StatusCode::kFailedPrecondition);

  // Re-solve later from the same raw data: a new candidate version.
  ASSERT_OK_AND_ASSIGN(Solve again, store_->StartSolve("S1", "tech:bob"));
  ASSERT_OK_AND_ASSIGN(ParamVersion v2,
                       store_->FinishSolve(again.id, MakeVersion("robot-1"), "tech:bob"));
  EXPECT_EQ(v2.version, 2);
  EXPECT_EQ(v2.state, VersionState::kCandidate);
  EXPECT_EQ(store_->GetActive("robot-1").value().version, 1);
  EXPECT_EQ(store_->GetSession("S1").value().version, 2);
  ASSERT_OK_AND_ASSIGN(std::vector<Solve> solves, store_->ListSolves("S1"));
  ASSERT_EQ(solves.size(), 2u);
  EXPECT_EQ(solves[1].actor, "tech:bob");
}

TEST_P(BatchTest, AFailedSolveCanReopenTheSessionForMorePoses) {
  ASSERT_OK(store_->AppendBatch("S1", 1, BatchPayload(1)).status());
  ASSERT_OK_AND_ASSIGN(Solve solve, store_->StartSolve("S1", "server"));
  ASSERT_OK_AND_ASSIGN(Solve failed,
                       store_->FailSolve(solve.id, "not enough poses: add Z-",
                                         R"({"verdict": "fail"})", "server", SessionState::kOpen));
  EXPECT_EQ(failed.state, SolveState::kFailed);
  EXPECT_EQ(failed.error, "not enough poses: add Z-");
  EXPECT_EQ(failed.report_json, R"({"verdict": "fail"})");
  EXPECT_EQ(store_->GetSession("S1").value().state, SessionState::kOpen);
  ASSERT_OK(store_->AppendBatch("S1", 2, BatchPayload(2)).status());

  // Leaving `solving` by hand abandons the running solve.
  ASSERT_OK_AND_ASSIGN(Solve second, store_->StartSolve("S1", "server"));
  ASSERT_OK(store_->SetSessionState("S1", SessionState::kFailed, kActor).status());
  EXPECT_EQ(store_->GetSolve(second.id).value().state, SolveState::kFailed);
  EXPECT_EQ(store_->FinishSolve(second.id, MakeVersion(""), "server").status().code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(store_->ListVersions("robot-1").value(), IsEmpty());
}

// Servers sharing one database claim the solves they run (SolveClaim): a solve is an orphan
// when its claim has lapsed, or when the server that claimed it asks after a restart; another
// server's live solve is never listed, and renewing a claim keeps it live.
TEST_P(StoreTest, SolveClaimsDecideWhichRunningSolvesAreOrphans) {
  const absl::Time t0 = absl::FromUnixSeconds(1'800'000'000);
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  std::vector<Solve> solves;
  const std::vector<SolveClaim> claims = {
      {"replica-a", t0 + absl::Seconds(30)},  // live
      {"replica-b", t0 - absl::Seconds(1)},   // its server stopped renewing it
      {"replica-b", t0 + absl::Seconds(30)},  // live, then renewed
      {},                                     // unclaimed: lapsed already
  };
  for (size_t i = 0; i < claims.size(); ++i) {
    const std::string device = "robot-" + std::to_string(i + 10);
    const std::string session = "S" + std::to_string(i + 10);
    ASSERT_OK(store_->CreateDevice(MakeDevice(device), kActor).status());
    ASSERT_OK(store_->CreateSession(MakeSession(device, session), kActor).status());
    ASSERT_OK_AND_ASSIGN(Solve solve, store_->StartSolve(session, "server", claims[i]));
    EXPECT_EQ(solve.owner, claims[i].owner);
    EXPECT_EQ(solve.lease_until, claims[i].lease_until);
    solves.push_back(solve);
  }
  const auto ids = [](const std::vector<Solve>& listed) {
    std::vector<int64_t> out;
    for (const Solve& s : listed) out.push_back(s.id);
    return out;
  };
  ASSERT_OK_AND_ASSIGN(std::vector<Solve> orphans, store_->ListOrphanedSolves(t0));
  EXPECT_THAT(ids(orphans), ::testing::ElementsAre(solves[1].id, solves[3].id));
  // replica-a restarted: its own solve cannot be running any more.
  ASSERT_OK_AND_ASSIGN(orphans, store_->ListOrphanedSolves(t0, "replica-a"));
  EXPECT_THAT(ids(orphans), ::testing::ElementsAre(solves[0].id, solves[1].id, solves[3].id));
  // 40 s later every lease has lapsed, unless renewed: replica-b renews (its lapsed one too,
  // which it is still running after all) and only replica-a's and the unclaimed are orphans.
  ASSERT_OK_AND_ASSIGN(int renewed, store_->RenewSolveLeases("replica-b", t0 + absl::Seconds(70)));
  EXPECT_EQ(renewed, 2);
  ASSERT_OK_AND_ASSIGN(orphans, store_->ListOrphanedSolves(t0 + absl::Seconds(40)));
  EXPECT_THAT(ids(orphans), ::testing::ElementsAre(solves[0].id, solves[3].id));
  // A finished solve is nobody's orphan and is not renewed.
  ASSERT_OK(store_->FailSolve(solves[3].id, "gone", "", "server").status());
  ASSERT_OK_AND_ASSIGN(orphans, store_->ListOrphanedSolves(t0 + absl::Seconds(40)));
  EXPECT_THAT(ids(orphans), ::testing::ElementsAre(solves[0].id));
  EXPECT_EQ(store_->RenewSolveLeases("", t0).status().code(), absl::StatusCode::kInvalidArgument);
}

// A lapsed solve goes to exactly one of several stores claiming at once (two connections to one
// database: FOR UPDATE SKIP LOCKED on PostgreSQL), and only its new holder can end it.
TEST_P(StoreTest, ALapsedSolveIsClaimedOnceAndOnlyItsHolderEndsIt) {
  const absl::Time t0 = absl::FromUnixSeconds(1'800'000'000);
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK(store_->CreateSession(MakeSession("robot-1", "S1"), kActor).status());
  // A seed of 64 bits: stored as its bits in a signed column, read back whole.
  constexpr uint64_t kSeed = 0x8000000000000001ull;
  ASSERT_OK_AND_ASSIGN(Solve dead, store_->StartSolve("S1", "server", {"dead", t0}, kSeed));
  EXPECT_EQ(dead.seed, kSeed);
  EXPECT_EQ(dead.attempts, 1);
  ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> other, Store::Open(path_));
  std::optional<Solve> got_a, got_b;
  std::thread a([&] {
    auto r = store_->ClaimLapsedSolve(t0 + absl::Seconds(1), {"a", t0 + absl::Seconds(31)});
    ASSERT_TRUE(r.ok()) << r.status();
    got_a = *r;
  });
  std::thread b([&] {
    auto r = other->ClaimLapsedSolve(t0 + absl::Seconds(1), {"b", t0 + absl::Seconds(31)});
    ASSERT_TRUE(r.ok()) << r.status();
    got_b = *r;
  });
  a.join();
  b.join();
  ASSERT_NE(got_a.has_value(), got_b.has_value()) << "exactly one claimer gets it";
  const Solve& claimed = got_a ? *got_a : *got_b;
  EXPECT_EQ(claimed.id, dead.id);
  const std::string holder = got_a ? "a" : "b";
  EXPECT_EQ(claimed.owner, holder);
  EXPECT_EQ(claimed.attempts, 2);
  EXPECT_EQ(claimed.seed, kSeed);
  EXPECT_EQ(claimed.lease_until, t0 + absl::Seconds(31));
  // Nothing else has lapsed; the old owner cannot end it; the holder can.
  ASSERT_OK_AND_ASSIGN(std::optional<Solve> none,
                       store_->ClaimLapsedSolve(t0 + absl::Seconds(1), {"c", t0}));
  EXPECT_FALSE(none.has_value());
  EXPECT_EQ(store_->FailSolve(dead.id, "late", "", "server", SessionState::kOpen, "dead")
                .status()
                .code(),
            absl::StatusCode::kFailedPrecondition);
  ASSERT_OK(
      store_->FailSolve(dead.id, "done", "", "server", SessionState::kOpen, holder).status());
}

// A server that starts again gives up the claims of its previous life at once (that life cannot
// be running them), so they are claimed again without waiting for their leases; another
// server's live claims are not touched, nor finished solves.
TEST_P(StoreTest, ARestartedServerReleasesOnlyItsOwnRunningClaims) {
  const absl::Time t0 = absl::FromUnixSeconds(1'800'000'000);
  const absl::Time far = t0 + absl::Hours(1);
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-2"), kActor).status());
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-3"), kActor).status());
  ASSERT_OK(store_->CreateSession(MakeSession("robot-1", "S1"), kActor).status());
  ASSERT_OK(store_->CreateSession(MakeSession("robot-2", "S2"), kActor).status());
  ASSERT_OK(store_->CreateSession(MakeSession("robot-3", "S3"), kActor).status());
  ASSERT_OK_AND_ASSIGN(Solve mine, store_->StartSolve("S1", "server", {"me", far}));
  ASSERT_OK_AND_ASSIGN(Solve theirs, store_->StartSolve("S2", "server", {"them", far}));
  ASSERT_OK_AND_ASSIGN(Solve ended, store_->StartSolve("S3", "server", {"me", far}));
  ASSERT_OK(store_->FailSolve(ended.id, "x", "", "server", SessionState::kOpen, "me").status());

  ASSERT_OK_AND_ASSIGN(int released, store_->ReleaseSolveClaims("me"));
  EXPECT_EQ(released, 1);
  ASSERT_OK_AND_ASSIGN(std::optional<Solve> claimed,
                       store_->ClaimLapsedSolve(t0, {"me", t0 + absl::Seconds(30)}));
  ASSERT_TRUE(claimed.has_value());
  EXPECT_EQ(claimed->id, mine.id);
  EXPECT_EQ(claimed->attempts, 2);
  ASSERT_OK_AND_ASSIGN(std::optional<Solve> none,
                       store_->ClaimLapsedSolve(t0, {"me", t0 + absl::Seconds(30)}));
  EXPECT_FALSE(none.has_value()) << "solve " << none->id << " of " << none->owner;
  ASSERT_OK_AND_ASSIGN(Solve still, store_->GetSolve(theirs.id));
  EXPECT_EQ(still.owner, "them");
  EXPECT_EQ(still.lease_until, far);
  EXPECT_EQ(store_->ReleaseSolveClaims("").status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace imucal::storage
