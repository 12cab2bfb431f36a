// The Uploader against an in-process fake SessionService (always) and the real imucald (when it
// is built): complete uploads, cancel + upload again resumes after the last ack, dropped streams
// reconnect, and the server ends up with every sample exactly once.
#include "client/sdk/uploader.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "client/sdk/client.h"
#include "core/simulator.h"
#include "formats/sample_digest.h"
#include "grpcpp/grpcpp.h"
#include "tests/client/fake_services.h"
#include "tests/client/imucald_process.h"

namespace imucal::sdk {
namespace {

namespace fs = std::filesystem;
namespace pb = imucal::v1;
using formats::SampleDigest;
using testing_util::FakeServer;
using testing_util::FakeSessionService;

SampleColumns MakeColumns(int n) {
  SampleColumns s;
  for (int i = 0; i < n; ++i) {
    s.t_s.push_back(0.005 * i);
    for (int k = 0; k < 3; ++k) s.accel.push_back(i * 3 + k);
    for (int k = 0; k < 3; ++k) s.gyro.push_back(-0.001 * i);
    s.temp_c.push_back(25.0);
  }
  return s;
}

UploadOptions SmallBatches() {
  UploadOptions o;
  o.batch_samples = 100;
  o.max_in_flight = 4;
  o.initial_backoff = absl::Milliseconds(10);
  return o;
}

class UploaderFakeTest : public testing::Test {
 protected:
  UploaderFakeTest() : server_({&service_}) { service_.AddSession("s-1"); }
  std::shared_ptr<grpc::Channel> Channel() { return MakeChannel(server_.address()); }

  FakeSessionService service_;
  FakeServer server_;
};

TEST_F(UploaderFakeTest, UploadsEverySampleOnceWithProgress) {
  const SampleColumns samples = MakeColumns(1050);
  std::vector<int64_t> progress;
  UploadOptions o = SmallBatches();
  o.progress = [&](int64_t acked, int64_t total) {
    EXPECT_EQ(total, 1050);
    progress.push_back(acked);
  };
  Uploader uploader(Channel(), o);
  absl::StatusOr<UploadResult> r = uploader.Upload("s-1", samples);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->sent_samples, 1050);
  EXPECT_EQ(r->skipped_samples, 0);
  EXPECT_EQ(r->last_acked_seq, 11);
  EXPECT_EQ(service_.StoredTimes("s-1"), samples.t_s);
  EXPECT_EQ(service_.StoredAccel("s-1"), samples.accel);
  ASSERT_FALSE(progress.empty());
  EXPECT_EQ(progress.back(), 1050);
  for (size_t i = 1; i < progress.size(); ++i) EXPECT_GT(progress[i], progress[i - 1]);
}

TEST_F(UploaderFakeTest, CancelThenUploadAgainResumesAfterLastAck) {
  const SampleColumns samples = MakeColumns(2000);
  UploadOptions o = SmallBatches();
  Uploader* self = nullptr;
  o.progress = [&](int64_t acked, int64_t) {
    if (acked >= 1000) self->Cancel();
  };
  Uploader first(Channel(), o);
  self = &first;
  absl::StatusOr<UploadResult> r = first.Upload("s-1", samples);
  ASSERT_TRUE(absl::IsCancelled(r.status())) << r.status();
  // Batches already in flight when the stream was cancelled may still be stored after Upload
  // returned: the second upload learns from the session where to resume.
  EXPECT_GE(service_.StoredTimes("s-1").size(), 1000u);

  Uploader second(Channel(), SmallBatches());
  r = second.Upload("s-1", samples);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_GE(r->skipped_samples, 1000);
  EXPECT_LT(r->skipped_samples, 2000);
  EXPECT_EQ(r->skipped_samples + r->sent_samples, 2000);
  EXPECT_EQ(service_.StoredTimes("s-1"), samples.t_s);  // every sample exactly once, in order
  EXPECT_EQ(service_.StoredAccel("s-1"), samples.accel);
}

TEST_F(UploaderFakeTest, ServerSideDropReconnectsAndResumes) {
  const SampleColumns samples = MakeColumns(1000);
  service_.FailStreamAfter(3);  // the 3rd batch is stored, but its ack never arrives
  Uploader uploader(Channel(), SmallBatches());
  absl::StatusOr<UploadResult> r = uploader.Upload("s-1", samples);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->reconnects, 1);
  EXPECT_EQ(service_.streams_opened(), 2);
  EXPECT_EQ(service_.StoredTimes("s-1"), samples.t_s);
}

TEST_F(UploaderFakeTest, ClientSideDropReconnectsAndResumes) {
  const SampleColumns samples = MakeColumns(1000);
  UploadOptions o = SmallBatches();
  Uploader* self = nullptr;
  bool dropped = false;
  o.progress = [&](int64_t acked, int64_t) {
    if (acked >= 400 && !dropped) {
      dropped = true;
      self->DropStream();
    }
  };
  Uploader uploader(Channel(), o);
  self = &uploader;
  absl::StatusOr<UploadResult> r = uploader.Upload("s-1", samples);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_GE(r->reconnects, 1);
  EXPECT_EQ(service_.StoredTimes("s-1"), samples.t_s);
}

TEST_F(UploaderFakeTest, CompleteSessionIsANoOp) {
  const SampleColumns samples = MakeColumns(300);
  Uploader uploader(Channel(), SmallBatches());
  ASSERT_TRUE(uploader.Upload("s-1", samples).ok());
  absl::StatusOr<UploadResult> r = uploader.Upload("s-1", samples);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->skipped_samples, 300);
  EXPECT_EQ(r->sent_samples, 0);
  EXPECT_EQ(service_.StoredTimes("s-1").size(), 300u);
}

TEST_F(UploaderFakeTest, LongerSessionThanCaptureIsFailedPrecondition) {
  Uploader uploader(Channel(), SmallBatches());
  ASSERT_TRUE(uploader.Upload("s-1", MakeColumns(300)).ok());
  EXPECT_TRUE(absl::IsFailedPrecondition(uploader.Upload("s-1", MakeColumns(200)).status()));
}

TEST_F(UploaderFakeTest, UnknownSessionIsNotFound) {
  Uploader uploader(Channel(), SmallBatches());
  EXPECT_TRUE(absl::IsNotFound(uploader.Upload("nope", MakeColumns(10)).status()));
}

// The uploader retries by time, not by count: it gives up only after retry_for without an
// acknowledgement, and says so.
TEST(UploaderTest, UnreachableServerGivesUpAfterItsRetryTime) {
  UploadOptions o = SmallBatches();
  o.retry_for = absl::Seconds(1);
  o.initial_backoff = absl::Milliseconds(1);
  o.call_deadline = absl::Milliseconds(300);
  Uploader uploader(MakeChannel(absl::StrCat("127.0.0.1:", testing_util::FreeLoopbackPort())), o);
  absl::Status s = uploader.Upload("s-1", MakeColumns(10)).status();
  EXPECT_TRUE(absl::IsUnavailable(s) || absl::IsDeadlineExceeded(s)) << s;
  EXPECT_NE(s.message().find("gave up after 1s without an acknowledgement"), std::string::npos)
      << s;
}

TEST(UploaderTest, MalformedColumnsAreInvalidArgument) {
  SampleColumns s = MakeColumns(10);
  s.gyro.pop_back();
  Uploader uploader(MakeChannel("127.0.0.1:1"), SmallBatches());
  EXPECT_TRUE(absl::IsInvalidArgument(uploader.Upload("s-1", s).status()));
}

// ---- against the real server ----

class UploaderImucaldTest : public testing_util::ImucaldTest {
 protected:
  UploaderImucaldTest() : ImucaldTest("imucal_uploader_test") {}

  std::string CreateSession(const std::string& device) {
    return testing_util::RegisterAndOpenSession(server_->NewChannel(), device,
                                                pb::PROTOCOL_SIX_FACE);
  }

  pb::Session GetSession(const std::string& id) {
    auto sessions = pb::SessionService::NewStub(server_->NewChannel());
    grpc::ClientContext c;
    pb::GetSessionRequest req;
    req.set_session_id(id);
    pb::Session session;
    grpc::Status s = sessions->GetSession(&c, req, &session);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return session;
  }
};

SampleColumns SimulatedColumns() {
  core::SimOptions sim;
  sim.seed = 7;
  auto result = core::Simulate(sim);
  EXPECT_TRUE(result.ok()) << result.status();
  return ColumnsFromCapture(result->capture);
}

TEST_F(UploaderImucaldTest, CancelThenUploadAgainStoresEverySampleOnce) {
  const SampleColumns samples = SimulatedColumns();
  const int64_t total = samples.size();
  const std::string session = CreateSession("robot-up-1");
  ASSERT_FALSE(session.empty());
  UploadOptions o;
  o.batch_samples = 500;
  Uploader* self = nullptr;
  o.progress = [&](int64_t acked, int64_t) {
    if (acked >= total / 2) self->Cancel();
  };
  Uploader first(server_->NewChannel(), o);
  self = &first;
  ASSERT_TRUE(absl::IsCancelled(first.Upload(session, samples).status()));
  const pb::Session half = GetSession(session);
  EXPECT_GE(half.samples(), total / 2);
  EXPECT_LT(half.samples(), total);

  UploadOptions o2;
  o2.batch_samples = 500;
  Uploader second(server_->NewChannel(), o2);
  absl::StatusOr<UploadResult> r = second.Upload(session, samples);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_GE(r->skipped_samples, half.samples());  // in-flight batches may have landed since
  EXPECT_EQ(r->skipped_samples + r->sent_samples, total);
  const pb::Session done = GetSession(session);
  EXPECT_EQ(done.samples(), total);
  EXPECT_EQ(done.last_acked_seq(), r->last_acked_seq);
}

// The SDK proves its resume as the CLI does: a session that holds the start of one capture
// does not take another one's rest (each Upload names its capture in UploadOptions::source).
TEST_F(UploaderImucaldTest, AnotherCaptureDoesNotResumeTheSession) {
  const SampleColumns first = SimulatedColumns();
  SampleColumns second = first;  // the same times, other readings: another capture
  for (double& g : second.gyro) g += 0.01;
  const int64_t total = first.size();
  const std::string session = CreateSession("robot-up-3");
  ASSERT_FALSE(session.empty());
  UploadOptions o;
  o.batch_samples = 500;
  o.source = "boot-1";
  Uploader* self = nullptr;
  o.progress = [&](int64_t acked, int64_t) {
    if (acked >= total / 2) self->Cancel();
  };
  Uploader cut(server_->NewChannel(), o);
  self = &cut;
  ASSERT_TRUE(absl::IsCancelled(cut.Upload(session, first).status()));
  const pb::Session half = GetSession(session);
  ASSERT_GT(half.samples(), 0);
  EXPECT_EQ(half.source(), "boot-1");

  UploadOptions other;
  other.batch_samples = 500;
  other.source = "boot-2";
  absl::Status refused = Uploader(server_->NewChannel(), other).Upload(session, second).status();
  EXPECT_TRUE(absl::IsFailedPrecondition(refused)) << refused;
  EXPECT_NE(refused.message().find("'boot-2' does not continue"), std::string::npos) << refused;
  EXPECT_NE(refused.message().find("'boot-1'"), std::string::npos) << refused;

  // The first capture resumes (after any batch still in flight when it was cut), and the
  // session then holds it alone: its digest is the first capture's.
  absl::StatusOr<UploadResult> resumed =
      Uploader(server_->NewChannel(), other).Upload(session, first);
  ASSERT_TRUE(resumed.ok()) << resumed.status();
  EXPECT_GE(resumed->skipped_samples, half.samples());
  const pb::Session done = GetSession(session);
  EXPECT_EQ(done.samples(), total);
  SampleDigest digest;
  for (int64_t i = 0; i < total; ++i) {
    const size_t k = static_cast<size_t>(i);
    digest.AddSample(first.t_s[k], &first.accel[3 * k], &first.gyro[3 * k],
                     first.temp_c.empty() ? nullptr : &first.temp_c[k]);
  }
  EXPECT_EQ(done.samples_sha256(), digest.Sha256());
}

TEST_F(UploaderImucaldTest, ServerRestartMidUploadResumes) {
  const SampleColumns samples = SimulatedColumns();
  const int64_t total = samples.size();
  const std::string session = CreateSession("robot-up-2");
  ASSERT_FALSE(session.empty());
  UploadOptions o;
  o.batch_samples = 500;
  o.initial_backoff = absl::Milliseconds(50);
  o.max_backoff = absl::Milliseconds(500);
  bool restarted = false;
  o.progress = [&](int64_t acked, int64_t) {
    if (acked >= total / 3 && !restarted) {
      restarted = true;
      ASSERT_TRUE(server_->Restart().ok());
    }
  };
  Uploader uploader(server_->NewChannel(), o);
  absl::StatusOr<UploadResult> r = uploader.Upload(session, samples);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_GE(r->reconnects, 1);
  EXPECT_EQ(GetSession(session).samples(), total);
}

}  // namespace
}  // namespace imucal::sdk
