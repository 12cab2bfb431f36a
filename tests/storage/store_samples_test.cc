// Store: raw sample batches, synchronous and group-committed (storage/store_samples.cc).
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <future>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/sample_codec.h"
#include "storage/store.h"
#include "tests/storage/store_test_util.h"

namespace imucal::storage {
namespace {

using ::testing::HasSubstr;

TEST_P(BatchTest, BatchesAreAcknowledgedInOrder) {
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

// Pages of a session's batches: in order, none twice or left out, bounded by batch count and
// by samples (the first batch of a page whole, however large), empty after the last.
TEST_P(BatchTest, BatchPagesCoverTheSessionInOrder) {
  // Batches of 50, 50, 200, 50, 50, 50 samples.
  const std::vector<int> sizes = {50, 50, 200, 50, 50, 50};
  for (size_t i = 0; i < sizes.size(); ++i) {
    const auto seq = static_cast<int64_t>(i + 1);
    ASSERT_OK(store_->AppendBatch("S1", seq, BatchPayload(seq, sizes[i])).status());
  }
  auto seqs = [](const std::vector<SampleBatch>& page) {
    std::vector<int64_t> out;
    for (const SampleBatch& b : page) out.push_back(b.seq);
    return out;
  };
  // At most 120 samples a page: 1+2 (100), 3 alone (200: the first of its page), 4+5 (100), 6.
  std::vector<std::vector<int64_t>> pages;
  int64_t after = 0;
  for (;;) {
    ASSERT_OK_AND_ASSIGN(std::vector<SampleBatch> page,
                         store_->ReadBatchPage("S1", after, 10, 120));
    if (page.empty()) break;
    for (const SampleBatch& b : page) EXPECT_EQ(b.payload, BatchPayload(b.seq, sizes[b.seq - 1]));
    pages.push_back(seqs(page));
    after = page.back().seq;
    ASSERT_LT(pages.size(), 10u);
  }
  EXPECT_EQ(pages, (std::vector<std::vector<int64_t>>{{1, 2}, {3}, {4, 5}, {6}}));
  // At most two batches a page, samples unbounded.
  ASSERT_OK_AND_ASSIGN(std::vector<SampleBatch> two, store_->ReadBatchPage("S1", 2, 2, 1 << 30));
  EXPECT_EQ(seqs(two), (std::vector<int64_t>{3, 4}));
  ASSERT_OK_AND_ASSIGN(std::vector<SampleBatch> end, store_->ReadBatchPage("S1", 6, 2, 100));
  EXPECT_TRUE(end.empty());
  EXPECT_EQ(store_->ReadBatchPage("nope", 0, 2, 100).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->ReadBatchPage("S1", 0, 0, 100).status().code(),
            absl::StatusCode::kInvalidArgument);
}

// Group commit: many sessions' batches submitted at once share commits; each answer is the one
// AppendBatch would give, a bad batch fails alone, and every acknowledged batch is stored.
TEST_P(BatchTest, AsyncAppendsShareCommitsAndAnswerEachBatch) {
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

TEST_P(BatchTest, ARepeatedBatchIsANoOp) {
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

TEST_P(BatchTest, ARepeatedSeqWithOtherContentIsInvalid) {
  ASSERT_OK(store_->AppendBatch("S1", 1, BatchPayload(1)).status());
  absl::StatusOr<BatchAck> conflict = store_->AppendBatch("S1", 1, BatchPayload(7));
  EXPECT_EQ(conflict.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(conflict.status().message(), HasSubstr("different content"));
  EXPECT_EQ(store_->ReadBatches("S1").value()[0].payload, BatchPayload(1));
}

TEST_P(BatchTest, AGapNamesTheExpectedSeq) {
  ASSERT_OK(store_->AppendBatch("S1", 1, BatchPayload(1)).status());
  absl::StatusOr<BatchAck> gap = store_->AppendBatch("S1", 3, BatchPayload(3));
  EXPECT_EQ(gap.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(gap.status().message(), HasSubstr("expected 2"));
  EXPECT_EQ(store_->GetSession("S1").value().last_acked_seq, 1);
}

TEST_P(BatchTest, TimeIncreasesAcrossBatches) {
  ASSERT_OK(store_->AppendBatch("S1", 1, BatchPayload(5)).status());  // t in [5, 5.245]
  absl::StatusOr<BatchAck> overlap = store_->AppendBatch("S1", 2, BatchPayload(5));
  EXPECT_EQ(overlap.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(overlap.status().message(), HasSubstr("not after the last sample of batch 1"));
  ASSERT_OK(store_->AppendBatch("S1", 2, BatchPayload(6)).status());
  ASSERT_OK_AND_ASSIGN(std::vector<SampleBatch> batches, store_->ReadBatches("S1"));
  EXPECT_EQ(batches[0].first_t_s, 5.0);
  EXPECT_DOUBLE_EQ(batches[0].last_t_s, 5.245);
}

TEST_P(BatchTest, BadInputIsRefusedBeforeItIsStored) {
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

TEST_P(BatchTest, OnlyAnOpenSessionTakesNewBatches) {
  ASSERT_OK(store_->AppendBatch("S1", 1, BatchPayload(1)).status());
  ASSERT_OK(store_->SetSessionState("S1", SessionState::kCancelled, kActor).status());
  absl::StatusOr<BatchAck> late = store_->AppendBatch("S1", 2, BatchPayload(2));
  EXPECT_EQ(late.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(late.status().message(), HasSubstr("cancelled"));
}

TEST_P(BatchTest, ParallelStreamsKeepTheirOwnSequences) {
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

}  // namespace
}  // namespace imucal::storage
