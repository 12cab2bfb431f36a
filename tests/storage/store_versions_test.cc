// Store: parameter versions and their policy (storage/store_versions.cc).
#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/store.h"
#include "tests/storage/store_test_util.h"

namespace imucal::storage {
namespace {

using ::testing::HasSubstr;
using ::testing::IsEmpty;

TEST_P(StoreTest, VersionPolicyPromoteRollbackReject) {
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

TEST_P(StoreTest, ANewVersionIsCheckedAgainstItsDeviceAndSession) {
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

TEST_P(StoreTest, VersionsAreNumberedWithoutGapsUnderConcurrency) {
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

// The documents of a version carry its number (the parameter set's "version"), and only the
// store knows it: two servers on one database, each writing versions through a renderer that
// is called with the number the store assigned, must never store a document whose number is
// another row's. A renderer's error leaves nothing behind, and uses no number.
TEST_P(StoreTest, RenderedDocumentsCarryTheRowsNumberAcrossStores) {
  ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
  ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> other, Store::Open(path_));
  const auto render = [](int number, std::string* params, std::string* report) {
    *params = absl::StrCat("{\"version\": ", number, "}");
    *report = absl::StrCat("{\"parameters\": {\"version\": ", number, "}}");
    return absl::OkStatus();
  };
  constexpr int kThreads = 4;
  constexpr int kPerThread = 20;
  std::atomic<int> failures{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      Store* store = (t % 2 == 0) ? store_.get() : other.get();
      for (int i = 0; i < kPerThread; ++i) {
        ParamVersion v = MakeVersion("robot-1", Verdict::kPass, VersionState::kActive);
        v.params_json.clear();  // the renderer writes it
        absl::StatusOr<ParamVersion> added = store->AddVersion(v, "server", render);
        if (!added.ok() ||
            added->params_json != absl::StrCat("{\"version\": ", added->version, "}")) {
          ++failures;
          ADD_FAILURE() << (added.ok() ? added->params_json : added.status().ToString());
        }
      }
    });
  }
  for (std::thread& t : threads) t.join();
  ASSERT_EQ(failures.load(), 0);
  ASSERT_OK_AND_ASSIGN(std::vector<ParamVersion> listed, store_->ListVersions("robot-1"));
  ASSERT_EQ(listed.size(), static_cast<size_t>(kThreads * kPerThread));
  for (const ParamVersion& v : listed) {
    ASSERT_OK_AND_ASSIGN(ParamVersion full, other->GetVersion("robot-1", v.version));
    EXPECT_EQ(full.params_json, absl::StrCat("{\"version\": ", v.version, "}"));
    EXPECT_EQ(full.report_json, absl::StrCat("{\"parameters\": {\"version\": ", v.version, "}}"));
  }
  ASSERT_OK_AND_ASSIGN(ParamVersion active, other->GetActive("robot-1"));
  EXPECT_EQ(active.version, kThreads * kPerThread);

  // A renderer that fails: no row, no audit, no number used; one that writes no parameters is
  // refused like a version without them.
  const size_t audit = AuditCount();
  const auto failing = [](int, std::string*, std::string*) {
    return absl::InternalError("the report could not be written");
  };
  EXPECT_EQ(store_->AddVersion(MakeVersion("robot-1"), "server", failing).status().code(),
            absl::StatusCode::kInternal);
  const auto empty = [](int, std::string*, std::string*) { return absl::OkStatus(); };
  EXPECT_EQ(store_->AddVersion(MakeVersion("robot-1"), "server", empty).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(AuditCount(), audit);
  ASSERT_OK_AND_ASSIGN(ParamVersion next, store_->AddVersion(MakeVersion("robot-1"), "server",
                                                             render));
  EXPECT_EQ(next.version, kThreads * kPerThread + 1);
}

TEST_P(StoreTest, ReadersAlwaysSeeExactlyOneActiveVersion) {
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

}  // namespace
}  // namespace imucal::storage
