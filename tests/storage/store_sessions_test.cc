// Store: sessions and their state machine (storage/store_sessions.cc).
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/store.h"
#include "tests/storage/store_test_util.h"

namespace imucal::storage {
namespace {

using ::testing::HasSubstr;

TEST_P(StoreTest, OneOpenSessionPerDevice) {
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

TEST_P(StoreTest, SessionIdsCanBeChosenButNotReused) {
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

TEST_P(StoreTest, SessionStateFollowsTheTransitionTable) {
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

TEST_P(StoreTest, SessionsPageAcrossDevicesInCreationOrder) {
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

TEST_P(StoreTest, ListSessionsFiltersByState) {
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

}  // namespace
}  // namespace imucal::storage
