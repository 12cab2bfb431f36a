#include "storage/store.h"

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <future>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/sample_codec.h"
#include "tests/storage/test_util.h"

namespace imucal::storage {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

constexpr char kActor[] = "tech:alice";

Device MakeDevice(const std::string& id) {
  Device d;
  d.id = id;
  d.sensor_model = "ICM-20948";
  d.nominal_rate_hz = 200;
  d.accel_unit = "m/s^2";
  d.gyro_unit = "rad/s";
  return d;
}

Session MakeSession(const std::string& device_id, const std::string& id = "") {
  Session s;
  s.id = id;
  s.device_id = device_id;
  s.protocol = "six-face";
  return s;
}

// The batch a robot would send as `seq`: deterministic, so a reader can check it is intact.
std::string BatchPayload(int64_t seq, int samples = 50) {
  std::vector<ImuSample> out(static_cast<size_t>(samples));
  for (int i = 0; i < samples; ++i) {
    ImuSample& s = out[static_cast<size_t>(i)];
    s.t_s = static_cast<double>(seq) + 0.005 * i;
    s.accel = {0.01 * i, -0.02 * static_cast<double>(seq), 9.81};
    s.gyro = {1e-3 * static_cast<double>(seq), 2e-3, -1e-3 * i};
    s.temp = 25.0 + 1e-3 * static_cast<double>(seq);
  }
  return EncodeSamples(out).value();
}

ParamVersion MakeVersion(const std::string& device_id, Verdict verdict = Verdict::kPass,
                         VersionState state = VersionState::kCandidate) {
  ParamVersion v;
  v.device_id = device_id;
  v.params_json = R"({"format": "imucal-params v1"})";
  v.report_json = R"({"format": "imucal-report v1", "verdict": "pass"})";
  v.verdict = verdict;
  v.accel_rms = 0.0004;
  v.state = state;
  v.provenance = "imucal 0.1.0 test";
  return v;
}

class StoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    path_ = TempDbPath("db");
    Reopen();
  }

  void Reopen() {
    store_.reset();
    auto store = Store::Open(path_);
    ASSERT_TRUE(store.ok()) << store.status();
    store_ = *std::move(store);
  }

  std::vector<std::string> AuditActions(const std::string& target) {
    AuditQuery q;
    q.target = target;
    absl::StatusOr<std::vector<AuditEntry>> entries = store_->ListAudit(q);
    EXPECT_TRUE(entries.ok()) << entries.status();
    std::vector<std::string> actions;
    if (entries.ok()) {
      for (const AuditEntry& e : *entries) actions.push_back(e.action);
    }
    return actions;
  }

  size_t AuditCount() { return store_->ListAudit().value().size(); }

  std::string path_;
  std::unique_ptr<Store> store_;
};

// ---- Devices ---------------------------------------------------------------------------------

TEST_F(StoreTest, DevicesAreCreatedReadAndListed) {
  ASSERT_OK_AND_ASSIGN(Device b, store_->CreateDevice(MakeDevice("robot-b"), kActor));
  ASSERT_OK_AND_ASSIGN(Device a, store_->CreateDevice(MakeDevice("robot-a"), kActor));
  EXPECT_EQ(a.sensor_model, "ICM-20948");
  ASSERT_OK_AND_ASSIGN(Device got, store_->GetDevice("robot-b"));
  EXPECT_EQ(got.id, "robot-b");
  EXPECT_EQ(got.nominal_rate_hz, 200);
  EXPECT_EQ(got.accel_unit, "m/s^2");
  EXPECT_EQ(got.created_at, b.created_at);
  ASSERT_OK_AND_ASSIGN(std::vector<Device> all, store_->ListDevices());
  ASSERT_EQ(all.size(), 2u);
  EXPECT_EQ(all[0].id, "robot-a");
  EXPECT_EQ(all[1].id, "robot-b");

  EXPECT_EQ(store_->CreateDevice(MakeDevice(""), kActor).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->CreateDevice(MakeDevice("robot-c"), "").status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->GetDevice("robot-z").status().code(), absl::StatusCode::kNotFound);
}

TEST_F(StoreTest, RegisteringAgainIsANoOpUnlessTheMetadataDiffers) {
  ASSERT_OK_AND_ASSIGN(Device first, store_->CreateDevice(MakeDevice("robot-1"), kActor));
  // Robots register at every boot.
  ASSERT_OK_AND_ASSIGN(Device again, store_->CreateDevice(MakeDevice("robot-1"), "robot-1"));
  EXPECT_EQ(again.created_at, first.created_at);
  EXPECT_EQ(AuditActions(DeviceTarget("robot-1")), std::vector<std::string>{"device.create"});

  Device other = MakeDevice("robot-1");
  other.gyro_unit = "deg/s";
  absl::Status taken = store_->CreateDevice(other, kActor).status();
  EXPECT_EQ(taken.code(), absl::StatusCode::kAlreadyExists);
  EXPECT_THAT(taken.message(), HasSubstr("gyro_unit rad/s, not deg/s"));
}

TEST_F(StoreTest, DevicesPageByIdAndShowTheirActiveVersion) {
  for (const char* id : {"robot-c", "robot-a", "robot-d", "robot-b"}) {
    ASSERT_OK(store_->CreateDevice(MakeDevice(id), kActor).status());
  }
  ASSERT_OK_AND_ASSIGN(std::vector<Device> page1, store_->ListDevices("", 3));
  ASSERT_EQ(page1.size(), 3u);
  EXPECT_EQ(page1[2].id, "robot-c");
  ASSERT_OK_AND_ASSIGN(std::vector<Device> page2, store_->ListDevices(page1.back().id, 3));
  ASSERT_EQ(page2.size(), 1u);
  EXPECT_EQ(page2[0].id, "robot-d");

  EXPECT_EQ(store_->GetDevice("robot-b").value().active_version, 0);
  ASSERT_OK(
      store_->AddVersion(MakeVersion("robot-b", Verdict::kPass, VersionState::kActive), "server")
          .status());
  ASSERT_OK(store_->AddVersion(MakeVersion("robot-b"), "server").status());
  EXPECT_EQ(store_->GetDevice("robot-b").value().active_version, 1);
  EXPECT_EQ(store_->ListDevices().value()[1].active_version, 1);
}

TEST_F(StoreTest, TimesComeFromTheInjectedClock) {
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

// ---- Sessions --------------------------------------------------------------------------------

TEST_F(StoreTest, OneOpenSessionPerDevice) {
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-2"), kActor).status());
  ASSERT_OK_AND_ASSIGN(Session first, store_->CreateSession(MakeSession("robot-1"), kActor));
  EXPECT_EQ(first.state, SessionState::kOpen);
  EXPECT_EQ(first.last_acked_seq, 0);
  EXPECT_THAT(first.id, HasSubstr("s-"));

  absl::StatusOr<Session> second = store_->CreateSession(MakeSession("robot-1"), kActor);
  EXPECT_EQ(second.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(second.status().message(), HasSubstr(first.id));

  // Another device is independent.
  ASSERT_OK(store_->CreateSession(MakeSession("robot-2"), kActor).status());

  // Once the first is no longer open, a new one may start...
  ASSERT_OK(store_->SetSessionState(first.id, SessionState::kSolving, kActor).status());
  ASSERT_OK_AND_ASSIGN(Session third, store_->CreateSession(MakeSession("robot-1"), kActor));
  // ...and the first cannot go back to open while the third is.
  absl::StatusOr<Session> reopen = store_->SetSessionState(first.id, SessionState::kOpen, kActor);
  EXPECT_EQ(reopen.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(reopen.status().message(), HasSubstr(third.id));

  EXPECT_EQ(store_->CreateSession(MakeSession("robot-404"), kActor).status().code(),
            absl::StatusCode::kNotFound);
}

TEST_F(StoreTest, SessionIdsCanBeChosenButNotReused) {
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-2"), kActor).status());
  ASSERT_OK_AND_ASSIGN(Session s, store_->CreateSession(MakeSession("robot-1", "S1"), kActor));
  EXPECT_EQ(s.id, "S1");
  EXPECT_EQ(store_->CreateSession(MakeSession("robot-2", "S1"), kActor).status().code(),
            absl::StatusCode::kAlreadyExists);
  ASSERT_OK_AND_ASSIGN(Session got, store_->GetSession("S1"));
  EXPECT_EQ(got.device_id, "robot-1");
  EXPECT_EQ(got.protocol, "six-face");
  EXPECT_EQ(got.created_at, s.created_at);
  EXPECT_EQ(store_->GetSession("S404").status().code(), absl::StatusCode::kNotFound);
}

TEST_F(StoreTest, SessionStateFollowsTheTransitionTable) {
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK_AND_ASSIGN(Session s, store_->CreateSession(MakeSession("robot-1", "S1"), kActor));
  auto set = [&](SessionState to) { return store_->SetSessionState("S1", to, kActor).status(); };
  EXPECT_EQ(set(SessionState::kSolved).code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(set(SessionState::kOpen).code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_OK(set(SessionState::kSolving));
  EXPECT_EQ(set(SessionState::kSolving).code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_OK(set(SessionState::kSolved));
  EXPECT_OK(set(SessionState::kSolving));  // re-solve
  EXPECT_OK(set(SessionState::kFailed));
  EXPECT_OK(set(SessionState::kSolving));  // retry
  EXPECT_OK(set(SessionState::kOpen));     // collect more poses
  EXPECT_OK(set(SessionState::kCancelled));
  absl::Status final_state = set(SessionState::kSolving);
  EXPECT_EQ(final_state.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(final_state.message(), HasSubstr("final"));
  ASSERT_OK_AND_ASSIGN(Session got, store_->GetSession("S1"));
  EXPECT_EQ(got.state, SessionState::kCancelled);
  EXPECT_GE(got.updated_at, s.created_at);
}

TEST_F(StoreTest, SessionsPageAcrossDevicesInCreationOrder) {
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-2"), kActor).status());
  for (const char* id : {"Sz", "Sa", "Sm"}) {
    ASSERT_OK(store_->CreateSession(MakeSession("robot-1", id), kActor).status());
    ASSERT_OK(store_->SetSessionState(id, SessionState::kCancelled, kActor).status());
  }
  ASSERT_OK(store_->CreateSession(MakeSession("robot-2", "Sb"), kActor).status());
  ASSERT_OK_AND_ASSIGN(std::vector<Session> page1, store_->ListSessions({.limit = 2}));
  ASSERT_EQ(page1.size(), 2u);
  EXPECT_EQ(page1[0].id, "Sz");
  EXPECT_EQ(page1[1].id, "Sa");
  ASSERT_OK_AND_ASSIGN(std::vector<Session> page2,
                       store_->ListSessions({.after_id = page1.back().id, .limit = 2}));
  ASSERT_EQ(page2.size(), 2u);
  EXPECT_EQ(page2[0].id, "Sm");
  EXPECT_EQ(page2[1].id, "Sb");
  ASSERT_OK_AND_ASSIGN(std::vector<Session> of_device,
                       store_->ListSessions({.device_id = "robot-1", .after_id = "Sz"}));
  ASSERT_EQ(of_device.size(), 2u);
  EXPECT_EQ(of_device[1].id, "Sm");
  EXPECT_EQ(store_->ListSessions({.after_id = "S404"}).status().code(),
            absl::StatusCode::kInvalidArgument);
}

TEST_F(StoreTest, ListSessionsFiltersByState) {
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK(store_->CreateSession(MakeSession("robot-1", "S1"), kActor).status());
  ASSERT_OK(store_->SetSessionState("S1", SessionState::kCancelled, kActor).status());
  ASSERT_OK(store_->CreateSession(MakeSession("robot-1", "S2"), kActor).status());
  ASSERT_OK_AND_ASSIGN(std::vector<Session> all, store_->ListSessions({.device_id = "robot-1"}));
  ASSERT_EQ(all.size(), 2u);
  EXPECT_EQ(all[0].id, "S1");
  EXPECT_EQ(all[1].id, "S2");
  ASSERT_OK_AND_ASSIGN(
      std::vector<Session> open,
      store_->ListSessions({.device_id = "robot-1", .state = SessionState::kOpen}));
  ASSERT_EQ(open.size(), 1u);
  EXPECT_EQ(open[0].id, "S2");
  EXPECT_EQ(store_->ListSessions({.device_id = "robot-404"}).status().code(),
            absl::StatusCode::kNotFound);
}

// ---- Sample batches --------------------------------------------------------------------------

class BatchTest : public StoreTest {
 protected:
  void SetUp() override {
    StoreTest::SetUp();
    ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
    ASSERT_OK(store_->CreateSession(MakeSession("robot-1", "S1"), kActor).status());
  }
};

TEST_F(BatchTest, BatchesAreAcknowledgedInOrder) {
  for (int64_t seq = 1; seq <= 3; ++seq) {
    ASSERT_OK_AND_ASSIGN(BatchAck ack, store_->AppendBatch("S1", seq, BatchPayload(seq)));
    EXPECT_EQ(ack.last_acked_seq, seq);
    EXPECT_EQ(ack.samples, 50 * seq);
  }
  ASSERT_OK_AND_ASSIGN(Session s, store_->GetSession("S1"));
  EXPECT_EQ(s.last_acked_seq, 3);
  ASSERT_OK_AND_ASSIGN(std::vector<SampleBatch> batches, store_->ReadBatches("S1"));
  ASSERT_EQ(batches.size(), 3u);
  for (int64_t i = 0; i < 3; ++i) {
    EXPECT_EQ(batches[i].seq, i + 1);
    EXPECT_EQ(batches[i].session_id, "S1");
    EXPECT_EQ(batches[i].count, 50);
    EXPECT_EQ(batches[i].first_t_s, static_cast<double>(i + 1));
    EXPECT_EQ(batches[i].payload, BatchPayload(i + 1));
  }
  ASSERT_OK_AND_ASSIGN(std::vector<SampleBatch> tail, store_->ReadBatches("S1", 2));
  ASSERT_EQ(tail.size(), 1u);
  EXPECT_EQ(tail[0].seq, 3);
}

// Group commit: many sessions' batches submitted at once share commits; each answer is the one
// AppendBatch would give, a bad batch fails alone, and every acknowledged batch is stored.
TEST_F(BatchTest, AsyncAppendsShareCommitsAndAnswerEachBatch) {
  constexpr int kSessions = 8, kBatches = 30;
  for (int i = 0; i < kSessions; ++i) {
    const std::string device = "robot-g" + std::to_string(i);
    ASSERT_OK(store_->CreateDevice(MakeDevice(device), kActor).status());
    ASSERT_OK(store_->CreateSession(MakeSession(device, "G" + std::to_string(i)), kActor).status());
  }
  std::mutex mu;
  std::condition_variable cv;
  int answered = 0;
  std::vector<std::vector<int64_t>> acked(kSessions);
  std::vector<absl::Status> errors;
  std::vector<std::thread> robots;
  for (int i = 0; i < kSessions; ++i) {
    robots.emplace_back([&, i] {
      const std::string session = "G" + std::to_string(i);
      for (int64_t seq = 1; seq <= kBatches; ++seq) {
        std::promise<absl::StatusOr<BatchAck>> stored;
        store_->AppendBatchAsync(session, seq, BatchPayload(seq),
                                 [&](absl::StatusOr<BatchAck> a) { stored.set_value(a); });
        absl::StatusOr<BatchAck> a = stored.get_future().get();  // one in flight, as a stream
        std::lock_guard lock(mu);
        if (a.ok()) acked[static_cast<size_t>(i)].push_back(a->last_acked_seq);
        if (!a.ok()) errors.push_back(a.status());
      }
      // A gap fails this batch only (the others of its group are unaffected).
      std::promise<absl::StatusOr<BatchAck>> gap;
      store_->AppendBatchAsync(session, kBatches + 2, BatchPayload(kBatches + 2),
                               [&](absl::StatusOr<BatchAck> a) { gap.set_value(a); });
      EXPECT_EQ(gap.get_future().get().status().code(), absl::StatusCode::kFailedPrecondition);
      std::lock_guard lock(mu);
      ++answered;
      cv.notify_all();
    });
  }
  for (auto& t : robots) t.join();
  EXPECT_EQ(answered, kSessions);
  EXPECT_TRUE(errors.empty()) << errors.front();
  for (int i = 0; i < kSessions; ++i) {
    ASSERT_EQ(acked[static_cast<size_t>(i)].size(), static_cast<size_t>(kBatches));
    for (int64_t k = 0; k < kBatches; ++k) EXPECT_EQ(acked[static_cast<size_t>(i)][k], k + 1);
    ASSERT_OK_AND_ASSIGN(std::vector<SampleBatch> batches,
                         store_->ReadBatches("G" + std::to_string(i)));
    ASSERT_EQ(batches.size(), static_cast<size_t>(kBatches));
    for (int64_t k = 0; k < kBatches; ++k) EXPECT_EQ(batches[k].payload, BatchPayload(k + 1));
  }
  // A malformed batch is answered at once, on the caller's thread.
  bool answered_inline = false;
  store_->AppendBatchAsync("G0", kBatches + 1, "garbage", [&](absl::StatusOr<BatchAck> a) {
    answered_inline = a.status().code() == absl::StatusCode::kInvalidArgument;
  });
  EXPECT_TRUE(answered_inline);
  // Retransmissions through the group commit are no-ops, as with AppendBatch.
  std::promise<absl::StatusOr<BatchAck>> again;
  store_->AppendBatchAsync("G0", 1, BatchPayload(1),
                           [&](absl::StatusOr<BatchAck> a) { again.set_value(a); });
  ASSERT_OK_AND_ASSIGN(BatchAck ack, again.get_future().get());
  EXPECT_EQ(ack.last_acked_seq, kBatches);
  // Everything acknowledged survives closing and reopening the file.
  Reopen();
  EXPECT_EQ(store_->GetSession("G7").value().last_acked_seq, kBatches);
}

TEST_F(BatchTest, SavePosesUpsertsPosesAndPairs) {
  Pose a, b;
  a.index = 0, a.t_start_s = 1, a.t_end_s = 2, a.face = "Z+";
  b.index = 1, b.t_start_s = 4, b.t_end_s = 5, b.face = "Z+", b.used = false, b.reason = "moved";
  PosePair p;
  p.pose_a = 0, p.pose_b = 1, p.face = "Z+", p.rotation_deg = 91, p.reason = "turned 91";
  ASSERT_OK(store_->SavePoses("S1", {a}, {}));
  ASSERT_OK(store_->SavePoses("S1", {a, b}, {p}));  // a replay rewrites the same rows
  ASSERT_OK_AND_ASSIGN(std::vector<Pose> poses, store_->ListPoses("S1"));
  ASSERT_EQ(poses.size(), 2u);
  EXPECT_EQ(poses[1].face, "Z+");
  EXPECT_EQ(poses[1].reason, "moved");
  EXPECT_EQ(store_->GetSession("S1").value().poses_accepted, 1);
  ASSERT_OK_AND_ASSIGN(std::vector<PosePair> pairs, store_->ListPairs("S1"));
  ASSERT_EQ(pairs.size(), 1u);
  EXPECT_EQ(pairs[0].rotation_deg, 91);
  EXPECT_FALSE(pairs[0].ok);
  PosePair bad = p;
  bad.pose_b = 0;
  EXPECT_EQ(store_->SavePoses("S1", {}, {bad}).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->SavePoses("nope", {a}, {}).code(), absl::StatusCode::kNotFound);
}

TEST_F(BatchTest, ARepeatedBatchIsANoOp) {
  ASSERT_OK(store_->AppendBatch("S1", 1, BatchPayload(1)).status());
  ASSERT_OK(store_->AppendBatch("S1", 2, BatchPayload(2)).status());
  // The robot missed the ack of 1 and 2 and sends them again: acknowledged again, nothing new.
  ASSERT_OK_AND_ASSIGN(BatchAck ack, store_->AppendBatch("S1", 1, BatchPayload(1)));
  EXPECT_EQ(ack.last_acked_seq, 2);
  EXPECT_EQ(ack.samples, 100);
  ASSERT_OK_AND_ASSIGN(ack, store_->AppendBatch("S1", 2, BatchPayload(2)));
  EXPECT_EQ(ack.last_acked_seq, 2);
  EXPECT_EQ(store_->ReadBatches("S1").value().size(), 2u);
  // Even after the session has moved on, a late retransmission is still acknowledged.
  ASSERT_OK(store_->SetSessionState("S1", SessionState::kSolving, kActor).status());
  ASSERT_OK_AND_ASSIGN(ack, store_->AppendBatch("S1", 2, BatchPayload(2)));
  EXPECT_EQ(ack.last_acked_seq, 2);
}

TEST_F(BatchTest, ARepeatedSeqWithOtherContentIsInvalid) {
  ASSERT_OK(store_->AppendBatch("S1", 1, BatchPayload(1)).status());
  absl::StatusOr<BatchAck> conflict = store_->AppendBatch("S1", 1, BatchPayload(7));
  EXPECT_EQ(conflict.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(conflict.status().message(), HasSubstr("different content"));
  EXPECT_EQ(store_->ReadBatches("S1").value()[0].payload, BatchPayload(1));
}

TEST_F(BatchTest, AGapNamesTheExpectedSeq) {
  ASSERT_OK(store_->AppendBatch("S1", 1, BatchPayload(1)).status());
  absl::StatusOr<BatchAck> gap = store_->AppendBatch("S1", 3, BatchPayload(3));
  EXPECT_EQ(gap.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(gap.status().message(), HasSubstr("expected 2"));
  EXPECT_EQ(store_->GetSession("S1").value().last_acked_seq, 1);
}

TEST_F(BatchTest, TimeIncreasesAcrossBatches) {
  ASSERT_OK(store_->AppendBatch("S1", 1, BatchPayload(5)).status());  // t in [5, 5.245]
  absl::StatusOr<BatchAck> overlap = store_->AppendBatch("S1", 2, BatchPayload(5));
  EXPECT_EQ(overlap.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(overlap.status().message(), HasSubstr("not after the last sample of batch 1"));
  ASSERT_OK(store_->AppendBatch("S1", 2, BatchPayload(6)).status());
  ASSERT_OK_AND_ASSIGN(std::vector<SampleBatch> batches, store_->ReadBatches("S1"));
  EXPECT_EQ(batches[0].first_t_s, 5.0);
  EXPECT_DOUBLE_EQ(batches[0].last_t_s, 5.245);
}

TEST_F(BatchTest, BadInputIsRefusedBeforeItIsStored) {
  EXPECT_EQ(store_->AppendBatch("S1", 0, BatchPayload(0)).status().code(),
            absl::StatusCode::kInvalidArgument);
  std::string garbage = BatchPayload(1);
  garbage.pop_back();
  absl::StatusOr<BatchAck> truncated = store_->AppendBatch("S1", 1, garbage);
  EXPECT_EQ(truncated.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(truncated.status().message(), HasSubstr("offset"));
  EXPECT_EQ(store_->AppendBatch("S1", 1, EncodeSamples({}).value()).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->AppendBatch("S404", 1, BatchPayload(1)).status().code(),
            absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->GetSession("S1").value().last_acked_seq, 0);
}

TEST_F(BatchTest, OnlyAnOpenSessionTakesNewBatches) {
  ASSERT_OK(store_->AppendBatch("S1", 1, BatchPayload(1)).status());
  ASSERT_OK(store_->SetSessionState("S1", SessionState::kCancelled, kActor).status());
  absl::StatusOr<BatchAck> late = store_->AppendBatch("S1", 2, BatchPayload(2));
  EXPECT_EQ(late.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(late.status().message(), HasSubstr("cancelled"));
}

TEST_F(BatchTest, ParallelStreamsKeepTheirOwnSequences) {
  constexpr int kStreams = 6;
  constexpr int kBatches = 40;
  std::vector<std::string> sessions;
  for (int i = 0; i < kStreams; ++i) {
    const std::string device = "robot-p" + std::to_string(i);
    ASSERT_OK(store_->CreateDevice(MakeDevice(device), kActor).status());
    sessions.push_back(store_->CreateSession(MakeSession(device), kActor).value().id);
  }
  std::atomic<int> failures{0};
  std::vector<std::thread> threads;
  for (int i = 0; i < kStreams; ++i) {
    threads.emplace_back([&, i] {
      for (int64_t seq = 1; seq <= kBatches; ++seq) {
        absl::StatusOr<BatchAck> ack = store_->AppendBatch(sessions[i], seq, BatchPayload(seq));
        if (!ack.ok() || ack->last_acked_seq != seq) ++failures;
        // Readers run alongside the writers.
        if (!store_->GetSession(sessions[i]).ok()) ++failures;
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_EQ(failures.load(), 0);
  for (const std::string& s : sessions) {
    ASSERT_OK_AND_ASSIGN(std::vector<SampleBatch> batches, store_->ReadBatches(s));
    ASSERT_EQ(batches.size(), static_cast<size_t>(kBatches));
    for (int64_t i = 0; i < kBatches; ++i) EXPECT_EQ(batches[i].payload, BatchPayload(i + 1));
  }
}

// ---- Poses and solves ------------------------------------------------------------------------

TEST_F(BatchTest, PosesAreReplacedAsAWhole) {
  std::vector<Pose> poses(3);
  for (int i = 0; i < 3; ++i) {
    poses[i].index = i;
    poses[i].t_start_s = 10.0 * i;
    poses[i].t_end_s = 10.0 * i + 5;
    poses[i].detail_json = R"({"samples": 1000})";
  }
  poses[2].used = false;
  poses[2].reason = "moved during capture";
  ASSERT_OK(store_->PutPoses("S1", poses, "server"));
  poses.pop_back();
  ASSERT_OK(store_->PutPoses("S1", poses, "server"));
  ASSERT_OK_AND_ASSIGN(std::vector<Pose> got, store_->ListPoses("S1"));
  ASSERT_EQ(got.size(), 2u);
  EXPECT_EQ(got[1].index, 1);
  EXPECT_EQ(got[1].t_start_s, 10.0);
  EXPECT_EQ(got[1].t_end_s, 15.0);
  EXPECT_TRUE(got[1].used);
  EXPECT_EQ(got[1].detail_json, R"({"samples": 1000})");
  EXPECT_EQ(got[1].session_id, "S1");

  std::vector<Pose> misnumbered = poses;
  misnumbered[1].index = 5;
  EXPECT_EQ(store_->PutPoses("S1", misnumbered, "server").code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->PutPoses("S404", poses, "server").code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->ListPoses("S1").value().size(), 2u);
}

TEST_F(BatchTest, ASolveTurnsASessionIntoAVersionAndCanBeRepeated) {
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

TEST_F(BatchTest, AFailedSolveCanReopenTheSessionForMorePoses) {
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

// ---- Parameter versions ----------------------------------------------------------------------

TEST_F(StoreTest, VersionPolicyPromoteRollbackReject) {
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  EXPECT_EQ(store_->GetActive("robot-1").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->GetActive("robot-404").status().code(), absl::StatusCode::kNotFound);

  // 1: a candidate (say it failed the gates) that a technician promotes.
  ASSERT_OK_AND_ASSIGN(ParamVersion v1,
                       store_->AddVersion(MakeVersion("robot-1", Verdict::kWarn), "server"));
  EXPECT_EQ(v1.version, 1);
  EXPECT_EQ(v1.state, VersionState::kCandidate);
  EXPECT_EQ(store_->GetActive("robot-1").status().code(), absl::StatusCode::kNotFound);
  ASSERT_OK_AND_ASSIGN(ParamVersion p1, store_->Promote("robot-1", 1, kActor));
  EXPECT_EQ(p1.state, VersionState::kActive);
  ASSERT_OK_AND_ASSIGN(ParamVersion active, store_->GetActive("robot-1"));
  EXPECT_EQ(active.version, 1);
  EXPECT_EQ(active.verdict, Verdict::kWarn);
  EXPECT_EQ(active.params_json, v1.params_json);
  EXPECT_THAT(active.report_json, IsEmpty());  // the hot path does not load reports
  EXPECT_EQ(store_->GetVersion("robot-1", 1).value().report_json, v1.report_json);

  // 2: passed the gates, active at once; 1 superseded.
  ASSERT_OK(
      store_->AddVersion(MakeVersion("robot-1", Verdict::kPass, VersionState::kActive), "server")
          .status());
  EXPECT_EQ(store_->GetActive("robot-1").value().version, 2);
  EXPECT_EQ(store_->GetVersion("robot-1", 1).value().state, VersionState::kSuperseded);

  // 3: a candidate waits; the robot still gets 2.
  ASSERT_OK(store_->AddVersion(MakeVersion("robot-1", Verdict::kFail), "server").status());
  EXPECT_EQ(store_->GetActive("robot-1").value().version, 2);
  ASSERT_OK(store_->Promote("robot-1", 3, kActor).status());
  EXPECT_EQ(store_->GetActive("robot-1").value().version, 3);
  EXPECT_EQ(store_->GetVersion("robot-1", 2).value().state, VersionState::kSuperseded);

  // Promote is for candidates; promoting the active one is a no-op.
  EXPECT_EQ(store_->Promote("robot-1", 2, kActor).status().code(),
            absl::StatusCode::kFailedPrecondition);
  ASSERT_OK(store_->Promote("robot-1", 3, kActor).status());
  EXPECT_EQ(store_->Promote("robot-1", 9, kActor).status().code(), absl::StatusCode::kNotFound);

  // Rollback to any earlier version.
  ASSERT_OK_AND_ASSIGN(ParamVersion r1, store_->Rollback("robot-1", 1, kActor));
  EXPECT_EQ(r1.state, VersionState::kActive);
  EXPECT_EQ(store_->GetActive("robot-1").value().version, 1);
  EXPECT_EQ(store_->GetVersion("robot-1", 3).value().state, VersionState::kSuperseded);
  absl::Status forward = store_->Rollback("robot-1", 3, kActor).status();
  EXPECT_EQ(forward.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(forward.message(), HasSubstr("not older"));

  // Reject a candidate; only candidates.
  ASSERT_OK(store_->AddVersion(MakeVersion("robot-1", Verdict::kFail), "server").status());
  ASSERT_OK_AND_ASSIGN(ParamVersion r4, store_->Reject("robot-1", 4, kActor, "tilted table"));
  EXPECT_EQ(r4.state, VersionState::kRejected);
  EXPECT_EQ(store_->Promote("robot-1", 4, kActor).status().code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(store_->Reject("robot-1", 1, kActor, "x").status().code(),
            absl::StatusCode::kFailedPrecondition);

  // Exactly one active version throughout; versions immutable apart from state.
  ASSERT_OK_AND_ASSIGN(std::vector<ParamVersion> all, store_->ListVersions("robot-1"));
  ASSERT_EQ(all.size(), 4u);
  EXPECT_THAT(all[0].params_json, IsEmpty());  // headers only unless asked
  ASSERT_OK_AND_ASSIGN(
      std::vector<ParamVersion> page,
      store_->ListVersions("robot-1", {.after_version = 1, .limit = 2, .with_documents = true}));
  ASSERT_EQ(page.size(), 2u);
  EXPECT_EQ(page[0].version, 2);
  EXPECT_EQ(page[1].version, 3);
  EXPECT_EQ(page[1].report_json, v1.report_json);
  EXPECT_EQ(std::count_if(all.begin(), all.end(),
                          [](const ParamVersion& v) { return v.state == VersionState::kActive; }),
            1);
  EXPECT_EQ(all[2].verdict, Verdict::kFail);
  EXPECT_EQ(all[0].accel_rms, 0.0004);
}

TEST_F(StoreTest, ANewVersionIsCheckedAgainstItsDeviceAndSession) {
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-2"), kActor).status());
  ASSERT_OK(store_->CreateSession(MakeSession("robot-2", "S2"), kActor).status());
  ParamVersion v = MakeVersion("robot-1");
  v.session_id = "S2";
  EXPECT_EQ(store_->AddVersion(v, "server").status().code(), absl::StatusCode::kInvalidArgument);
  v.session_id = "S404";
  EXPECT_EQ(store_->AddVersion(v, "server").status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->AddVersion(MakeVersion("robot-404"), "server").status().code(),
            absl::StatusCode::kNotFound);
  ParamVersion superseded = MakeVersion("robot-1");
  superseded.state = VersionState::kSuperseded;
  EXPECT_EQ(store_->AddVersion(superseded, "server").status().code(),
            absl::StatusCode::kInvalidArgument);
  ParamVersion unknown_rms = MakeVersion("robot-1");
  unknown_rms.accel_rms = std::numeric_limits<double>::quiet_NaN();
  ASSERT_OK_AND_ASSIGN(ParamVersion stored, store_->AddVersion(unknown_rms, "server"));
  EXPECT_EQ(stored.version, 1);  // the failed attempts used no number
  EXPECT_TRUE(std::isnan(stored.accel_rms));
}

TEST_F(StoreTest, VersionsAreNumberedWithoutGapsUnderConcurrency) {
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-2"), kActor).status());
  // Two Stores on the same file: the numbering must hold across connections, not just
  // behind one mutex.
  ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> other, Store::Open(path_));
  constexpr int kThreads = 8;
  constexpr int kPerThread = 25;
  std::vector<std::vector<int>> numbers(kThreads);
  std::atomic<int> failures{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      Store* store = (t % 2 == 0) ? store_.get() : other.get();
      for (int i = 0; i < kPerThread; ++i) {
        // Every third one activates, so the active pointer moves concurrently too.
        const VersionState state = (i % 3 == 0) ? VersionState::kActive : VersionState::kCandidate;
        absl::StatusOr<ParamVersion> v =
            store->AddVersion(MakeVersion("robot-1", Verdict::kPass, state), "server");
        if (!v.ok()) {
          ++failures;
          ADD_FAILURE() << v.status();
          continue;
        }
        numbers[t].push_back(v->version);
        if (t == 0 && !store->AddVersion(MakeVersion("robot-2"), "server").ok()) ++failures;
      }
    });
  }
  for (std::thread& t : threads) t.join();
  ASSERT_EQ(failures.load(), 0);
  std::vector<int> all;
  for (const auto& n : numbers) all.insert(all.end(), n.begin(), n.end());
  std::sort(all.begin(), all.end());
  ASSERT_EQ(all.size(), static_cast<size_t>(kThreads * kPerThread));
  for (size_t i = 0; i < all.size(); ++i) ASSERT_EQ(all[i], static_cast<int>(i) + 1);
  // Each thread's own numbers increase (its calls are ordered).
  for (const auto& n : numbers) EXPECT_TRUE(std::is_sorted(n.begin(), n.end()));

  ASSERT_OK_AND_ASSIGN(std::vector<ParamVersion> listed, store_->ListVersions("robot-1"));
  EXPECT_EQ(listed.size(), all.size());
  EXPECT_EQ(std::count_if(listed.begin(), listed.end(),
                          [](const ParamVersion& v) { return v.state == VersionState::kActive; }),
            1);
  ASSERT_OK_AND_ASSIGN(std::vector<ParamVersion> other_device, store_->ListVersions("robot-2"));
  ASSERT_EQ(other_device.size(), static_cast<size_t>(kPerThread));
  EXPECT_EQ(other_device.back().version, kPerThread);
}

TEST_F(StoreTest, ReadersAlwaysSeeExactlyOneActiveVersion) {
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK(
      store_->AddVersion(MakeVersion("robot-1", Verdict::kPass, VersionState::kActive), "server")
          .status());
  std::atomic<bool> done{false};
  std::atomic<int> bad_reads{0};
  std::atomic<int> reads{0};
  std::vector<std::thread> readers;
  for (int r = 0; r < 6; ++r) {  // more readers than pooled connections
    readers.emplace_back([&] {
      while (!done.load()) {
        absl::StatusOr<ParamVersion> active = store_->GetActive("robot-1");
        if (!active.ok() || active->state != VersionState::kActive) ++bad_reads;
        ++reads;
      }
    });
  }
  for (int i = 0; i < 60; ++i) {
    if (i % 2 == 0) {
      ASSERT_OK(
          store_
              ->AddVersion(MakeVersion("robot-1", Verdict::kPass, VersionState::kActive), "server")
              .status());
    } else {
      ASSERT_OK(store_->Rollback("robot-1", 1, kActor).status());
    }
  }
  done = true;
  for (std::thread& t : readers) t.join();
  EXPECT_EQ(bad_reads.load(), 0);
  EXPECT_GT(reads.load(), 0);
}

// ---- Audit -----------------------------------------------------------------------------------

TEST_F(StoreTest, EveryMutationIsAuditedInItsTransaction) {
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK(store_->CreateSession(MakeSession("robot-1", "S1"), "robot-1").status());
  ASSERT_OK(store_->AppendBatch("S1", 1, BatchPayload(1)).status());  // data: not audited
  ASSERT_OK_AND_ASSIGN(Solve solve, store_->StartSolve("S1", "server"));
  ASSERT_OK(store_->FinishSolve(solve.id, MakeVersion(""), "server").status());
  ASSERT_OK(store_->Promote("robot-1", 1, kActor, "checked on the bench").status());
  ASSERT_OK(store_->AddVersion(MakeVersion("robot-1"), "server").status());
  ASSERT_OK(store_->Reject("robot-1", 2, kActor, "tilted table").status());

  EXPECT_THAT(AuditActions(DeviceTarget("robot-1")),
              ElementsAre("device.create", "version.add", "version.promote", "version.add",
                          "version.reject"));
  EXPECT_THAT(AuditActions(SessionTarget("S1")),
              ElementsAre("session.create", "session.state", "solve.start", "session.state",
                          "solve.finish"));

  AuditQuery q;
  q.target = DeviceTarget("robot-1");
  ASSERT_OK_AND_ASSIGN(std::vector<AuditEntry> device_log, store_->ListAudit(q));
  EXPECT_EQ(device_log[2].actor, kActor);
  EXPECT_THAT(device_log[2].detail, HasSubstr("version 1 active: checked on the bench"));
  EXPECT_THAT(device_log[4].detail, HasSubstr("tilted table"));

  // A refused call leaves no trace: its audit row was in the rolled-back transaction.
  const size_t before = AuditCount();
  EXPECT_FALSE(store_->Promote("robot-1", 2, kActor).ok());  // rejected
  EXPECT_OK(store_->CreateSession(MakeSession("robot-1"), kActor).status());
  EXPECT_FALSE(store_->CreateSession(MakeSession("robot-1"), kActor).ok());  // one open
  EXPECT_EQ(AuditCount(), before + 1);  // only the session that was created

  // Entries from outside storage, and paging.
  AuditEntry fetched;
  fetched.actor = "robot-1";
  fetched.action = "params.fetch";
  fetched.target = DeviceTarget("robot-1");
  fetched.detail = "version 1";
  ASSERT_OK_AND_ASSIGN(AuditEntry appended, store_->AppendAudit(fetched));
  EXPECT_GT(appended.id, 0);
  AuditQuery page;
  page.limit = 3;
  ASSERT_OK_AND_ASSIGN(std::vector<AuditEntry> first_page, store_->ListAudit(page));
  ASSERT_EQ(first_page.size(), 3u);
  page.after_id = first_page.back().id;
  page.limit = 1000;
  ASSERT_OK_AND_ASSIGN(std::vector<AuditEntry> rest, store_->ListAudit(page));
  EXPECT_EQ(first_page.size() + rest.size(), AuditCount());
  EXPECT_EQ(rest.back().action, "params.fetch");
  AuditEntry anonymous = fetched;
  anonymous.actor = "";
  EXPECT_EQ(store_->AppendAudit(anonymous).status().code(), absl::StatusCode::kInvalidArgument);
}

// ---- Durability ------------------------------------------------------------------------------

TEST_F(StoreTest, ReopeningTheFileKeepsEverything) {
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

TEST_F(StoreTest, AcknowledgedBatchesSurviveSigkill) {
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
}  // namespace imucal::storage
