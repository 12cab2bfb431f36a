// Store: the audit log (storage/store_audit.cc).
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/store.h"
#include "tests/storage/store_test_util.h"

namespace imucal::storage {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

TEST_P(StoreTest, EveryMutationIsAuditedInItsTransaction) {
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

}  // namespace
}  // namespace imucal::storage
