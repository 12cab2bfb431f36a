// Durability, server side: the real imucald on a loopback port with a real
// SQLite file, a robot streaming through the SDK Uploader, the server SIGKILLed in the middle of
// the stream and restarted on the same file. Every sample the robot saw acknowledged must be in
// the file byte for byte (read back with the store, not through the server), the restarted
// server must report at least the robot's last acknowledged batch as stored (the robot resumes
// after it, through GetSession), and the upload completes with every sample stored exactly once.
// (tests/client/uploader_test.cc covers the uploader's side: reconnects, cancel, resume.)
#include <signal.h>

#include <atomic>
#include <chrono>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "client/sdk/uploader.h"
#include "core/simulator.h"
#include "grpcpp/grpcpp.h"
#include "gtest/gtest.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "storage/sample_codec.h"
#include "storage/store.h"
#include "tests/client/imucald_process.h"
#include "tests/server/stored_samples.h"

namespace imucal::server {
namespace {

namespace pb = ::imucal::v1;

class DurabilityTest : public testing_util::ImucaldTest {
 protected:
  DurabilityTest() : ImucaldTest("imucal_durability_test") {}

  std::string CreateSession(const std::string& device) {
    auto channel = server_->NewChannel();
    auto devices = pb::DeviceService::NewStub(channel);
    auto sessions = pb::SessionService::NewStub(channel);
    grpc::ClientContext c1;
    pb::RegisterDeviceRequest reg;
    reg.mutable_device()->set_id(device);
    reg.mutable_device()->set_nominal_rate_hz(200);
    reg.mutable_device()->set_accel_unit("m/s^2");
    reg.mutable_device()->set_gyro_unit("rad/s");
    pb::Device d;
    grpc::Status s = devices->RegisterDevice(&c1, reg, &d);
    EXPECT_TRUE(s.ok()) << s.error_message();
    grpc::ClientContext c2;
    pb::CreateSessionRequest create;
    create.set_device_id(device);
    create.set_protocol(pb::PROTOCOL_SIX_FACE);
    pb::Session session;
    s = sessions->CreateSession(&c2, create, &session);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return session.id();
  }

  // Just after a restart a call may land on a connection to the killed server (channels share
  // subchannels): UNAVAILABLE is retried, each try waiting for the channel to be ready.
  pb::Session GetSession(const std::string& id) {
    auto sessions = pb::SessionService::NewStub(server_->NewChannel());
    pb::GetSessionRequest req;
    req.set_session_id(id);
    pb::Session session;
    grpc::Status s;
    for (int attempt = 0; attempt < 20; ++attempt) {
      grpc::ClientContext c;
      c.set_wait_for_ready(true);
      c.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
      s = sessions->GetSession(&c, req, &session);
      if (s.error_code() != grpc::StatusCode::UNAVAILABLE) break;
    }
    EXPECT_TRUE(s.ok()) << s.error_message();
    return session;
  }

  // The session's samples as stored in the file, read with a store of our own (the server may
  // be running: WAL lets both in).
  std::vector<storage::ImuSample> StoredSamples(const std::string& session_id) {
    auto store = storage::Store::Open(server_->db_path());
    EXPECT_TRUE(store.ok()) << store.status();
    if (!store.ok()) return {};
    auto batches = (*store)->ReadBatches(session_id);
    EXPECT_TRUE(batches.ok()) << batches.status();
    std::vector<storage::ImuSample> out;
    if (!batches.ok()) return out;
    int64_t seq = 0;
    for (const storage::SampleBatch& b : *batches) {
      EXPECT_EQ(b.seq, ++seq) << "batches are 1, 2, 3, ... with no gap";
      EXPECT_TRUE(storage::DecodeSamplesInto(b.payload, &out).ok());
    }
    return out;
  }
};

using testing_util::SameBytes;  // tests/server/stored_samples.h

TEST_F(DurabilityTest, SigkillMidStreamKeepsEveryAckedSampleAndTheRobotResumes) {
  core::SimOptions sim;
  sim.seed = 5;
  auto capture = core::Simulate(sim);
  ASSERT_TRUE(capture.ok()) << capture.status();
  const core::Capture& cap = capture->capture;
  ASSERT_TRUE(cap.has_temp());
  const int64_t total = static_cast<int64_t>(cap.size());
  const std::string session = CreateSession("robot-durable");
  ASSERT_FALSE(session.empty());

  sdk::UploadOptions o;
  o.batch_samples = 500;
  o.initial_backoff = absl::Milliseconds(50);
  o.max_backoff = absl::Milliseconds(500);
  bool killed = false;
  int64_t acked_at_kill = 0;  // samples the robot had seen acknowledged when the server died
  std::vector<storage::ImuSample> stored_after_kill;
  int64_t seq_after_restart = 0;
  int64_t min_acked_after_restart = -1;
  o.progress = [&](int64_t acked, int64_t) {
    if (killed && min_acked_after_restart < 0) min_acked_after_restart = acked;
    if (killed || acked < total / 3) return;
    killed = true;
    acked_at_kill = acked;
    // SIGKILL mid-stream (batches are in flight), then the same file again.
    ASSERT_TRUE(server_->Restart().ok());
    stored_after_kill = StoredSamples(session);
    seq_after_restart = GetSession(session).last_acked_seq();
  };
  sdk::Uploader uploader(server_->NewChannel(), o);
  absl::StatusOr<sdk::UploadResult> result = uploader.Upload(session, cap);
  ASSERT_TRUE(killed);
  ASSERT_TRUE(result.ok()) << result.status();

  // Every acknowledged sample survived the kill, byte for byte (batches in flight may have been
  // committed too: whatever is stored is a prefix of the capture).
  ASSERT_GE(static_cast<int64_t>(stored_after_kill.size()), acked_at_kill);
  ASSERT_LE(static_cast<int64_t>(stored_after_kill.size()), total);
  for (size_t i = 0; i < stored_after_kill.size(); ++i)
    ASSERT_TRUE(SameBytes(stored_after_kill[i], cap, i)) << "sample " << i;
  // The restarted server knows the robot's last acknowledged batch as stored: the robot resumes
  // after it (at its first ack after the restart nothing acknowledged went missing).
  EXPECT_GE(seq_after_restart * o.batch_samples, acked_at_kill);
  EXPECT_GE(min_acked_after_restart, acked_at_kill);
  EXPECT_GE(result->reconnects, 1);

  // Completed: every sample once, in order, byte for byte.
  const std::vector<storage::ImuSample> all = StoredSamples(session);
  ASSERT_EQ(static_cast<int64_t>(all.size()), total);
  for (size_t i = 0; i < all.size(); ++i) ASSERT_TRUE(SameBytes(all[i], cap, i)) << "sample " << i;
  const pb::Session done = GetSession(session);
  EXPECT_EQ(done.samples(), total);
  EXPECT_EQ(done.last_acked_seq(), (total + o.batch_samples - 1) / o.batch_samples);
}

}  // namespace
}  // namespace imucal::server
