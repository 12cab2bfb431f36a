// A robot rides out a server restart: the real imucald (its own process on a loopback port, its
// SQLite file in a temp dir) is SIGKILLed once the upload has its first acknowledgement, stays
// down for 0, 5, 30 or 60 s, and is started again on the same port and file. The SDK's Uploader
// with its default policy (client/sdk/uploader.h: retries by time, each call waiting for the
// channel to be ready, jittered exponential backoff) over the SDK's channel (sdk::MakeChannel:
// reconnect backoff capped) must finish the upload, every sample stored once, byte for byte.
// The CLI's `upload` is the same Uploader on the same channel. How soon the upload resumes once
// the server is back is measured by bench/outage_bench.cc (tests do not time things).
#include <signal.h>

#include <chrono>
#include <condition_variable>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "client/sdk/client.h"
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

class OutageTest : public testing_util::ImucaldTest, public testing::WithParamInterface<int> {
 protected:
  OutageTest() : ImucaldTest("imucal_outage_test") {}
};

TEST_P(OutageTest, TheUploadCompletesWithEverySampleOnce) {
  const int outage_s = GetParam();
  core::SimOptions sim;
  sim.seed = 3;
  absl::StatusOr<core::SimResult> simulated = core::Simulate(sim);
  ASSERT_TRUE(simulated.ok()) << simulated.status();
  const core::Capture& capture = simulated->capture;
  ASSERT_TRUE(capture.has_temp());
  const std::string session = testing_util::RegisterAndOpenSession(
      server_->NewChannel(), "robot-outage", pb::PROTOCOL_SIX_FACE);
  ASSERT_FALSE(session.empty());

  // The first acknowledgement holds the robot's reading thread until the server is dead, so
  // the kill always lands mid-upload.
  std::mutex mu;
  std::condition_variable cv;
  bool first_ack = false, killed = false;
  sdk::UploadOptions options;  // the default retry policy is what is under test
  options.batch_samples = 500;
  options.progress = [&](int64_t acked, int64_t) {
    std::unique_lock lock(mu);
    if (first_ack || acked == 0) return;
    first_ack = true;
    cv.notify_all();
    cv.wait(lock, [&] { return killed; });
  };
  sdk::Uploader uploader(sdk::MakeChannel(server_->address()), options);
  absl::StatusOr<sdk::UploadResult> result;
  std::thread robot([&] { result = uploader.Upload(session, capture); });
  {
    std::unique_lock lock(mu);
    cv.wait(lock, [&] { return first_ack; });
  }
  server_->Stop(SIGKILL);
  {
    std::lock_guard lock(mu);
    killed = true;
  }
  cv.notify_all();
  // The outage itself: the server stays down this long, whatever the robot does meanwhile.
  std::this_thread::sleep_for(std::chrono::seconds(outage_s));
  ASSERT_TRUE(server_->Relaunch().ok());
  robot.join();
  ASSERT_TRUE(result.ok()) << "after a " << outage_s << " s outage: " << result.status();
  EXPECT_GE(result->reconnects, 1);
  EXPECT_EQ(result->skipped_samples + result->sent_samples, static_cast<int64_t>(capture.size()));

  // Every sample once, in order, byte for byte, in batches 1, 2, 3, ... without a gap.
  server_->Stop(SIGTERM);
  absl::StatusOr<std::unique_ptr<storage::Store>> store = storage::Store::Open(server_->db_path());
  ASSERT_TRUE(store.ok()) << store.status();
  absl::StatusOr<std::vector<storage::SampleBatch>> batches = (*store)->ReadBatches(session);
  ASSERT_TRUE(batches.ok()) << batches.status();
  std::vector<storage::ImuSample> stored;
  int64_t seq = 0;
  for (const storage::SampleBatch& b : *batches) {
    EXPECT_EQ(b.seq, ++seq);
    ASSERT_TRUE(storage::DecodeSamplesInto(b.payload, &stored).ok());
  }
  ASSERT_EQ(stored.size(), capture.size());
  for (size_t i = 0; i < stored.size(); ++i)
    ASSERT_TRUE(testing_util::SameBytes(stored[i], capture, i)) << "sample " << i;
}

INSTANTIATE_TEST_SUITE_P(Outages, OutageTest, testing::Values(0, 5, 30, 60),
                         [](const testing::TestParamInfo<int>& p) {
                           return std::to_string(p.param) + "s";
                         });

}  // namespace
}  // namespace imucal::server
