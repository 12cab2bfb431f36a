// Every input validated at the boundary, and the limits: an in-process imucald on a loopback
// port (port 0) with a SQLite file in a temp dir, driven by the generated stubs and, for bytes
// that are not protobuf at all, by grpc::GenericStub.
#include <chrono>
#include <cmath>
#include <cstdint>
#include <future>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include "client/sdk/uploader.h"
#include "gmock/gmock.h"
#include "grpcpp/generic/generic_stub.h"
#include "grpcpp/grpcpp.h"
#include "gtest/gtest.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/server.h"
#include "server/validate.h"
#include "storage/sample_codec.h"
#include "storage/store.h"
#include "tests/server/resume_proofs.h"
#include "tests/test_dir.h"

namespace imucal::server {
namespace {

using std::chrono::seconds;
using std::chrono::system_clock;
using ::testing::HasSubstr;

constexpr int kBatch = 200;
constexpr double kRateHz = 200;

// A robot at rest, z up: sample i of the session at t = i / rate.
v1::SampleBatch RestBatch(const std::string& session, int64_t seq, int n = kBatch,
                          bool with_temp = true) {
  v1::SampleBatch b;
  b.set_session_id(session);
  b.set_seq(seq);
  const int64_t first = (seq - 1) * kBatch;
  for (int i = 0; i < n; ++i) {
    const double k = static_cast<double>(first + i);
    b.add_t_s(k / kRateHz);
    b.add_accel(0.01 * std::sin(k));
    b.add_accel(-0.02 * std::cos(k));
    b.add_accel(9.80665 + 0.01 * std::sin(3 * k));
    b.add_gyro(1e-3 * std::cos(k));
    b.add_gyro(-1e-3 * std::sin(2 * k));
    b.add_gyro(2e-3);
    if (with_temp) b.add_temp_c(25.0 + 1e-3 * k);
  }
  return b;
}

grpc::ByteBuffer Buffer(const std::string& bytes) {
  grpc::Slice slice(bytes);
  return grpc::ByteBuffer(&slice, 1);
}

// A StreamSamples call through the generic stub: writes `messages` (raw bytes) one after the
// other, then half-closes; counts the acks and returns the final status.
class RawIngestStream final : public grpc::ClientBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer> {
 public:
  RawIngestStream(grpc::GenericStub* stub, std::vector<std::string> messages)
      : messages_(std::move(messages)) {
    ctx_.set_deadline(system_clock::now() + seconds(20));
    stub->PrepareBidiStreamingCall(&ctx_, "/imucal.v1.SessionService/StreamSamples",
                                   grpc::StubOptions(), this);
    StartRead(&in_);
    WriteNext();
    StartCall();
  }
  void OnWriteDone(bool ok) override {
    if (ok) WriteNext();
  }
  void OnReadDone(bool ok) override {
    if (!ok) return;
    ++acks_;
    StartRead(&in_);
  }
  void OnDone(const grpc::Status& s) override { done_.set_value(s); }
  grpc::Status Wait() { return done_.get_future().get(); }
  int acks() const { return acks_; }  // after Wait()

 private:
  void WriteNext() {
    if (next_ < messages_.size()) {
      out_ = Buffer(messages_[next_++]);
      StartWrite(&out_);
    } else {
      StartWritesDone();
    }
  }
  grpc::ClientContext ctx_;
  std::vector<std::string> messages_;
  size_t next_ = 0;
  grpc::ByteBuffer out_, in_;
  int acks_ = 0;
  std::promise<grpc::Status> done_;
};

class ValidationTest : public testing::Test {
 protected:
  void SetUp() override {
    options_.listen = "127.0.0.1:0";
    options_.security.insecure = true;  // loopback, no TLS: authentication is not under test
    options_.db_path = dir_.File("imucal.db");
  }
  void TearDown() override { server_.reset(); }

  void StartServer() {
    server_.reset();
    auto server = Server::Start(options_);
    ASSERT_TRUE(server.ok()) << server.status();
    server_ = *std::move(server);
    grpc::ChannelArguments args;
    args.SetMaxSendMessageSize(64 << 20);  // the server's receive limit is under test
    channel_ =
        grpc::CreateCustomChannel(server_->address(), grpc::InsecureChannelCredentials(), args);
    devices_ = v1::DeviceService::NewStub(channel_);
    sessions_ = v1::SessionService::NewStub(channel_);
  }

  static std::unique_ptr<grpc::ClientContext> Ctx() {
    auto ctx = std::make_unique<grpc::ClientContext>();
    ctx->set_deadline(system_clock::now() + seconds(20));
    return ctx;
  }

  // Registers `device` and opens a session on it; returns the session id.
  std::string NewSession(const std::string& device, const std::string& accel_unit = "m/s^2",
                         const std::string& gyro_unit = "rad/s") {
    v1::RegisterDeviceRequest reg;
    reg.mutable_device()->set_id(device);
    reg.mutable_device()->set_sensor_model("sim");
    reg.mutable_device()->set_nominal_rate_hz(kRateHz);
    reg.mutable_device()->set_accel_unit(accel_unit);
    reg.mutable_device()->set_gyro_unit(gyro_unit);
    v1::Device d;
    grpc::Status s = devices_->RegisterDevice(Ctx().get(), reg, &d);
    EXPECT_TRUE(s.ok()) << s.error_message();
    v1::CreateSessionRequest create;
    create.set_device_id(device);
    create.set_protocol(v1::PROTOCOL_FREE);
    v1::Session session;
    s = sessions_->CreateSession(Ctx().get(), create, &session);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return session.id();
  }

  // Streams `batches` on one stream, one ack awaited per batch. A stream that continues a
  // session proves it continues the stored capture (SampleBatch.resume_sha256): the batches
  // this test had acknowledged give the proof (tests/server/resume_proofs.h).
  grpc::Status Stream(std::vector<v1::SampleBatch> batches,
                      std::vector<v1::SampleAck>* acks = nullptr) {
    proofs_.Prove(&batches, sessions_.get());
    std::vector<v1::SampleAck> got;
    const grpc::Status s = StreamAsIs(batches, &got);
    proofs_.Acked(batches, got);
    if (acks != nullptr) acks->insert(acks->end(), got.begin(), got.end());
    return s;
  }

  // The SHA-256 a stream continuing after `stored` sends.
  static std::string Digest(const std::vector<v1::SampleBatch>& stored) {
    return testing_util::DigestOf(stored);
  }

  // Streams `batches` exactly as given.
  grpc::Status StreamAsIs(const std::vector<v1::SampleBatch>& batches,
                          std::vector<v1::SampleAck>* acks = nullptr) {
    auto ctx = Ctx();
    auto stream = sessions_->StreamSamples(ctx.get());
    for (const v1::SampleBatch& b : batches) {
      if (!stream->Write(b)) break;
      v1::SampleAck ack;
      if (!stream->Read(&ack)) break;
      if (acks != nullptr) acks->push_back(ack);
    }
    stream->WritesDone();
    v1::SampleAck extra;
    while (stream->Read(&extra))
      if (acks != nullptr) acks->push_back(extra);
    return stream->Finish();
  }

  v1::Session GetSession(const std::string& id) {
    v1::GetSessionRequest req;
    req.set_session_id(id);
    v1::Session out;
    grpc::Status s = sessions_->GetSession(Ctx().get(), req, &out);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return out;
  }

  testing_util::TestDir dir_{"validation_test"};  // first: outlives the server that uses it
  testing_util::ResumeProofs proofs_;
  ServerOptions options_;
  std::unique_ptr<Server> server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::DeviceService::Stub> devices_;
  std::unique_ptr<v1::SessionService::Stub> sessions_;
};

#define EXPECT_STATUS(status, code, text)                                       \
  do {                                                                          \
    const grpc::Status st_ = (status);                                          \
    EXPECT_EQ(st_.error_code(), grpc::StatusCode::code) << st_.error_message(); \
    EXPECT_THAT(st_.error_message(), HasSubstr(text));                          \
  } while (0)

TEST_F(ValidationTest, NonFiniteValuesNameBatchSampleAndField) {
  StartServer();
  const std::string s = NewSession("robot-nan");
  v1::SampleBatch b = RestBatch(s, 1);
  b.set_accel(3 * 3 + 1, std::nan(""));
  EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT, "batch 1, sample 3: accel.y (accel[10]) is NaN");
  b = RestBatch(s, 1);
  b.set_gyro(3 * 7 + 2, -std::numeric_limits<double>::infinity());
  EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT, "batch 1, sample 7: gyro.z (gyro[23]) is -infinity");
  b = RestBatch(s, 1);
  b.set_temp_c(5, std::numeric_limits<double>::infinity());
  EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT,
                "batch 1, sample 5: temp_c (temp_c[5]) is +infinity");
  b = RestBatch(s, 1);
  b.set_t_s(9, std::nan(""));
  EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT, "batch 1, sample 9: t_s (t_s[9]) is NaN");
  b = RestBatch(s, 1);
  b.mutable_gyro()->RemoveLast();
  EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT,
                "batch 1: gyro has 599 values, expected 600 (3 per sample for the 200 samples");
  b = RestBatch(s, 1);
  b.clear_t_s();
  EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT, "batch 1: t_s is empty");
  b = RestBatch(s, 1);
  b.set_seq(0);
  EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT, "batch 0: seq must be 1 or more");
  b = RestBatch(s, 1);
  b.clear_session_id();
  EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT, "session_id: required");
  EXPECT_EQ(GetSession(s).samples(), 0);  // nothing refused was stored
}

// The bounds come from the units the device declared; a value just inside each is taken.
TEST_F(ValidationTest, AbsurdMagnitudesByDeclaredUnit) {
  StartServer();
  struct Case {
    std::string accel_unit, gyro_unit;
    double accel_ok, accel_bad, gyro_ok, gyro_bad;
  };
  const std::vector<Case> cases = {
      {"m/s^2", "rad/s", 980.0, 981.0, 99.0, 101.0},       // 100 g, 100 rad/s
      {"g", "deg/s", 99.0, 101.0, 5700.0, 5800.0},         // 100 g, 5730 deg/s
      {"counts", "counts", 2.0e9, 2.2e9, -2.0e9, -2.2e9},  // a signed 32-bit register
  };
  int device = 0;
  for (const Case& c : cases) {
    SCOPED_TRACE(c.accel_unit + " " + c.gyro_unit);
    const std::string s =
        NewSession("robot-unit-" + std::to_string(device++), c.accel_unit, c.gyro_unit);
    v1::SampleBatch b = RestBatch(s, 1);
    b.set_accel(3 * 4 + 0, c.accel_bad);
    EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT, "batch 1, sample 4: accel.x (accel[12]) = ");
    EXPECT_THAT(Stream({b}).error_message(), HasSubstr("outside the physical range"));
    b = RestBatch(s, 1);
    b.set_gyro(3 * 6 + 1, c.gyro_bad);
    EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT, "batch 1, sample 6: gyro.y (gyro[19]) = ");
    b = RestBatch(s, 1);
    b.set_temp_c(2, 151);
    EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT,
                  "batch 1, sample 2: temp_c (temp_c[2]) = 151 degC is outside the physical "
                  "range -60..150 degC");
    b.set_temp_c(2, -61);
    EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT, "temp_c (temp_c[2]) = -61 degC");
    // Just inside every bound: stored.
    b = RestBatch(s, 1);
    b.set_accel(0, c.accel_ok);
    b.set_gyro(1, c.gyro_ok);
    b.set_temp_c(2, 149);
    b.set_temp_c(3, -59);
    std::vector<v1::SampleAck> acks;
    const grpc::Status ok = Stream({b}, &acks);
    EXPECT_TRUE(ok.ok()) << ok.error_message();
    ASSERT_EQ(acks.size(), 1u);
    EXPECT_EQ(acks[0].samples(), kBatch);
  }
}

TEST_F(ValidationTest, TimeMustIncreaseWithinAndAcrossBatches) {
  StartServer();
  const std::string s = NewSession("robot-time");
  v1::SampleBatch b = RestBatch(s, 1);
  b.set_t_s(50, b.t_s(49));
  EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT,
                "batch 1, sample 50: t_s (t_s[50]) = 0.245 s is not after the previous sample");
  ASSERT_TRUE(Stream({RestBatch(s, 1)}).ok());
  b = RestBatch(s, 2);
  b.set_t_s(0, 0.5);  // batch 1 ended at 0.995 s
  EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT,
                "batch 2, sample 0: t_s (t_s[0]) = 0.5 s is not after the session's last stored "
                "sample (0.995 s)");
  b.set_t_s(0, 1e13);
  EXPECT_STATUS(Stream({b}), INVALID_ARGUMENT, "t_s (t_s[0]) = 1e+13 s is beyond");
  EXPECT_EQ(GetSession(s).samples(), kBatch);
}

// A gap is FAILED_PRECONDITION naming the seq to resume from (the API's contract, which the SDK
// resumes by); a duplicate is an idempotent no-op; the same seq with other content is refused.
TEST_F(ValidationTest, GapsDuplicatesAndConflictingRetransmissions) {
  StartServer();
  const std::string s = NewSession("robot-seq");
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream({RestBatch(s, 1), RestBatch(s, 2)}, &acks).ok());
  acks.clear();
  const grpc::Status gap = Stream({RestBatch(s, 2), RestBatch(s, 4)}, &acks);
  EXPECT_STATUS(gap, FAILED_PRECONDITION, "expected 3");
  ASSERT_EQ(acks.size(), 1u);  // the duplicate of batch 2 is acknowledged again
  EXPECT_EQ(acks[0].last_acked_seq(), 2);
  EXPECT_EQ(acks[0].samples(), 2 * kBatch);
  v1::SampleBatch other = RestBatch(s, 2);
  other.set_accel(0, 1.0);
  EXPECT_EQ(Stream({other}).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  const v1::Session after = GetSession(s);
  EXPECT_EQ(after.last_acked_seq(), 2);
  EXPECT_EQ(after.samples(), 2 * kBatch);
}

// Nothing acknowledged is lost or changed by a bad batch that follows it on the same stream,
// and the session continues after it.
TEST_F(ValidationTest, BadBatchAfterGoodOnesLosesNothing) {
  StartServer();
  const std::string s = NewSession("robot-keep");
  std::vector<v1::SampleBatch> good;
  for (int64_t seq = 1; seq <= 5; ++seq) good.push_back(RestBatch(s, seq));
  v1::SampleBatch bad = RestBatch(s, 6);
  bad.set_accel(3 * 11 + 2, std::nan(""));
  std::vector<v1::SampleBatch> all = good;
  all.push_back(bad);
  std::vector<v1::SampleAck> acks;
  EXPECT_STATUS(Stream(all, &acks), INVALID_ARGUMENT, "batch 6, sample 11: accel.z");
  ASSERT_EQ(acks.size(), 5u);
  EXPECT_EQ(acks.back().last_acked_seq(), 5);

  // Every acknowledged sample is stored exactly as sent (read back from the file, with the
  // server stopped).
  server_.reset();
  {
    auto store = storage::Store::Open(options_.db_path);
    ASSERT_TRUE(store.ok()) << store.status();
    auto batches = (*store)->ReadBatches(s);
    ASSERT_TRUE(batches.ok()) << batches.status();
    ASSERT_EQ(batches->size(), 5u);
    for (size_t k = 0; k < 5; ++k) {
      auto samples = storage::DecodeSamples((*batches)[k].payload);
      ASSERT_TRUE(samples.ok()) << samples.status();
      ASSERT_EQ(samples->size(), static_cast<size_t>(kBatch));
      for (int i = 0; i < kBatch; ++i) {
        const storage::ImuSample& x = (*samples)[static_cast<size_t>(i)];
        ASSERT_EQ(x.t_s, good[k].t_s(i));
        for (int a = 0; a < 3; ++a) {
          ASSERT_EQ(x.accel[static_cast<size_t>(a)], good[k].accel(3 * i + a));
          ASSERT_EQ(x.gyro[static_cast<size_t>(a)], good[k].gyro(3 * i + a));
        }
        ASSERT_EQ(x.temp, good[k].temp_c(i));
      }
    }
  }
  // The session continues where it stopped.
  StartServer();
  acks.clear();
  ASSERT_TRUE(Stream({RestBatch(s, 6)}, &acks).ok());
  ASSERT_EQ(acks.size(), 1u);
  EXPECT_EQ(acks[0].last_acked_seq(), 6);
  EXPECT_EQ(acks[0].samples(), 6 * kBatch);
}

TEST_F(ValidationTest, OversizedMessagesAndBatchesAreResourceExhausted) {
  options_.max_receive_message_bytes = 64 << 10;
  options_.sessions.ingest.max_batch_samples = 500;
  StartServer();
  const std::string s = NewSession("robot-big");
  // 2000 samples with temperature: 2000 * 7 * 8 bytes = 112 kB > 64 KiB.
  EXPECT_STATUS(Stream({RestBatch(s, 1, 2000)}), RESOURCE_EXHAUSTED, "larger than max");
  // Under the byte limit but over the sample limit.
  EXPECT_STATUS(Stream({RestBatch(s, 1, 501)}), RESOURCE_EXHAUSTED,
                "batch 1: t_s has 501 samples, at most 500 per batch");
  // The server goes on serving, and the session takes a batch within the limits.
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream({RestBatch(s, 1, 500)}, &acks).ok());
  EXPECT_EQ(acks.at(0).samples(), 500);
}

TEST_F(ValidationTest, SessionSampleLimit) {
  options_.sessions.ingest.max_session_samples = 2 * kBatch + 50;
  StartServer();
  const std::string s = NewSession("robot-full");
  std::vector<v1::SampleAck> acks;
  EXPECT_STATUS(Stream({RestBatch(s, 1), RestBatch(s, 2), RestBatch(s, 3)}, &acks),
                RESOURCE_EXHAUSTED,
                "batch 3: session " + s + " holds 400 samples and may hold at most 450");
  EXPECT_EQ(acks.size(), 2u);
  EXPECT_EQ(GetSession(s).samples(), 2 * kBatch);
  // A retransmission of a stored batch is still acknowledged.
  acks.clear();
  EXPECT_TRUE(Stream({RestBatch(s, 2)}, &acks).ok());
  EXPECT_EQ(acks.at(0).last_acked_seq(), 2);
}

// One stream per device (the default): a second concurrent stream is RESOURCE_EXHAUSTED; the
// slot is free as soon as the first stream ends, or is cancelled (the SDK's Uploader backs off
// and retries); other devices are not affected.
TEST_F(ValidationTest, OneConcurrentStreamPerDevice) {
  StartServer();
  const std::string s = NewSession("robot-one");
  const std::string other = NewSession("robot-two");
  auto first_ctx = Ctx();
  auto first = sessions_->StreamSamples(first_ctx.get());
  ASSERT_TRUE(first->Write(RestBatch(s, 1)));
  v1::SampleAck ack;
  ASSERT_TRUE(first->Read(&ack));  // the first stream holds the device's slot
  EXPECT_EQ(ack.last_acked_seq(), 1);

  std::vector<v1::SampleAck> acks;
  EXPECT_STATUS(Stream({RestBatch(s, 2)}, &acks), RESOURCE_EXHAUSTED,
                "device robot-one already has 1 sample stream(s) open");
  EXPECT_TRUE(acks.empty());
  EXPECT_TRUE(Stream({RestBatch(other, 1)}).ok());  // another device streams meanwhile

  // The first stream goes on; once it ends, the device streams again at once.
  ASSERT_TRUE(first->Write(RestBatch(s, 2)));
  ASSERT_TRUE(first->Read(&ack));
  first->WritesDone();
  ASSERT_TRUE(first->Finish().ok());
  ASSERT_TRUE(Stream({RestBatch(s, 3)}).ok());

  // A stream cancelled by the robot frees the slot too: the Uploader resumes after it.
  auto third_ctx = Ctx();
  auto third = sessions_->StreamSamples(third_ctx.get());
  v1::SampleBatch fourth = RestBatch(s, 4);
  fourth.set_resume_sha256(Digest({RestBatch(s, 1), RestBatch(s, 2), RestBatch(s, 3)}));
  ASSERT_TRUE(third->Write(fourth));
  ASSERT_TRUE(third->Read(&ack));
  third_ctx->TryCancel();
  EXPECT_EQ(third->Finish().error_code(), grpc::StatusCode::CANCELLED);
  sdk::SampleColumns rest;
  for (int64_t seq = 1; seq <= 8; ++seq) {
    const v1::SampleBatch b = RestBatch(s, seq);
    rest.t_s.insert(rest.t_s.end(), b.t_s().begin(), b.t_s().end());
    rest.accel.insert(rest.accel.end(), b.accel().begin(), b.accel().end());
    rest.gyro.insert(rest.gyro.end(), b.gyro().begin(), b.gyro().end());
    rest.temp_c.insert(rest.temp_c.end(), b.temp_c().begin(), b.temp_c().end());
  }
  sdk::UploadOptions o;
  o.batch_samples = kBatch;
  o.initial_backoff = absl::Milliseconds(5);
  sdk::Uploader uploader(channel_, o);
  absl::StatusOr<sdk::UploadResult> r = uploader.Upload(s, rest);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(r->skipped_samples, 4 * kBatch);
  EXPECT_EQ(GetSession(s).samples(), 8 * kBatch);
}

TEST_F(ValidationTest, WatchersPerSessionLimit) {
  options_.sessions.max_watchers_per_session = 2;
  StartServer();
  const std::string s = NewSession("robot-watched");
  std::vector<std::unique_ptr<grpc::ClientContext>> contexts;
  std::vector<std::unique_ptr<grpc::ClientReader<v1::SessionEvent>>> readers;
  v1::WatchSessionRequest req;
  req.set_session_id(s);
  for (int i = 0; i < 2; ++i) {
    contexts.push_back(Ctx());
    readers.push_back(sessions_->WatchSession(contexts.back().get(), req));
    v1::SessionEvent first;
    ASSERT_TRUE(readers.back()->Read(&first));  // the snapshot: the watcher is registered
    EXPECT_TRUE(first.has_session());
  }
  auto ctx = Ctx();
  auto third = sessions_->WatchSession(ctx.get(), req);
  v1::SessionEvent e;
  EXPECT_FALSE(third->Read(&e));
  EXPECT_STATUS(third->Finish(), RESOURCE_EXHAUSTED, "already has 2 watchers");
  // One watcher leaves: another may follow.
  contexts[0]->TryCancel();
  readers[0]->Finish();
  // The server frees the slot when it sees the cancellation (asynchronously): the next watch
  // is admitted then, each attempt a round trip, within a deadline. Each admitted watcher
  // cancels right after its snapshot, while the server may still be writing the next event:
  // the cycle repeats so that a watch that misses its end (and keeps its slot) shows here.
  for (int cycle = 0; cycle < 20; ++cycle) {
    bool admitted = false;
    const auto deadline = system_clock::now() + seconds(10);
    while (!admitted && system_clock::now() < deadline) {
      auto c = Ctx();
      auto r = sessions_->WatchSession(c.get(), req);
      if (r->Read(&e)) {
        admitted = true;
        c->TryCancel();
        r->Finish();
      } else {
        EXPECT_EQ(r->Finish().error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
      }
    }
    ASSERT_TRUE(admitted) << "cycle " << cycle;
  }
  contexts[1]->TryCancel();
  readers[1]->Finish();
}

// SolveSession beyond the queue's limit is RESOURCE_EXHAUSTED. No workers (solve_threads 0), so
// the queued solves stay queued and the limit is reached deterministically.
TEST_F(ValidationTest, SolveQueueLimitIsResourceExhausted) {
  options_.sessions.solve_threads = 0;
  options_.sessions.solve_queue_limit = 2;
  StartServer();
  std::vector<std::string> ids;
  for (int i = 0; i < 3; ++i) {
    ids.push_back(NewSession("robot-solve-" + std::to_string(i)));
    ASSERT_TRUE(Stream({RestBatch(ids.back(), 1)}).ok());
  }
  for (int i = 0; i < 2; ++i) {
    v1::SolveSessionRequest req;
    req.set_session_id(ids[static_cast<size_t>(i)]);
    v1::SolveJob job;
    grpc::Status st = sessions_->SolveSession(Ctx().get(), req, &job);
    ASSERT_TRUE(st.ok()) << st.error_message();
    EXPECT_EQ(job.state(), v1::JOB_STATE_QUEUED);
  }
  v1::SolveSessionRequest req;
  req.set_session_id(ids[2]);
  v1::SolveJob job;
  EXPECT_STATUS(sessions_->SolveSession(Ctx().get(), req, &job), RESOURCE_EXHAUSTED,
                "the solve queue is full");
  // The refused session is untouched: still open, its samples still there.
  const v1::Session third = GetSession(ids[2]);
  EXPECT_EQ(third.state(), v1::SESSION_STATE_OPEN);
  EXPECT_EQ(third.samples(), kBatch);
}

// Bytes that are not protobuf: the ingest stream (a raw method) and the parameter fetch (raw too)
// answer INVALID_ARGUMENT, the stream after acknowledging what came before. The other unary
// methods are generated callback methods: gRPC 1.51 answers a request it cannot parse with
// UNIMPLEMENTED and no message before any imucal code runs (its callback handler does so for a
// failed parse). Either way the server keeps serving.
TEST_F(ValidationTest, GarbageBytesAreRefusedAndTheServerKeepsServing) {
  StartServer();
  const std::string s = NewSession("robot-garbage");
  grpc::GenericStub generic(channel_);
  const std::string garbage("\x0a\xff\xff\xff\xff\xff\xff\xff\xff\xff\xff\x01", 12);
  {
    RawIngestStream stream(&generic, {RestBatch(s, 1).SerializeAsString(), garbage});
    const grpc::Status st = stream.Wait();
    EXPECT_STATUS(st, INVALID_ARGUMENT,
                  "message 2 of the stream (after batch 1): 12 bytes that are not a SampleBatch");
    EXPECT_EQ(stream.acks(), 1);
  }
  // Seeded random bytes: each answered (never OK for a stream that has no valid first batch),
  // the server never falls over.
  std::mt19937 rng(20240501);
  int refused = 0;
  for (int i = 0; i < 100; ++i) {
    std::string bytes(1 + rng() % 64, '\0');
    for (char& c : bytes) c = static_cast<char>(rng());
    RawIngestStream stream(&generic, {bytes});
    const grpc::Status st = stream.Wait();
    EXPECT_TRUE(st.error_code() == grpc::StatusCode::INVALID_ARGUMENT ||
                st.error_code() == grpc::StatusCode::NOT_FOUND)
        << "bytes " << i << ": " << st.error_code() << " " << st.error_message();
    refused += !st.ok();

    grpc::ClientContext ctx;
    ctx.set_deadline(system_clock::now() + seconds(10));
    grpc::ByteBuffer request = Buffer(bytes), response;
    std::promise<grpc::Status> done;
    generic.UnaryCall(&ctx, "/imucal.v1.DeviceService/RegisterDevice", grpc::StubOptions(),
                      &request, &response, [&](grpc::Status u) { done.set_value(u); });
    const grpc::Status unary = done.get_future().get();
    EXPECT_TRUE(unary.error_code() == grpc::StatusCode::INVALID_ARGUMENT ||
                unary.error_code() == grpc::StatusCode::UNIMPLEMENTED)
        << "bytes " << i << ": " << unary.error_code() << " " << unary.error_message();
  }
  EXPECT_EQ(refused, 100);
  {
    grpc::ClientContext ctx;
    ctx.set_deadline(system_clock::now() + seconds(10));
    grpc::ByteBuffer request = Buffer(garbage), response;
    std::promise<grpc::Status> done;
    generic.UnaryCall(&ctx, "/imucal.v1.ParameterService/GetActiveParameters", grpc::StubOptions(),
                      &request, &response, [&](grpc::Status u) { done.set_value(u); });
    EXPECT_STATUS(done.get_future().get(), INVALID_ARGUMENT, "not a GetActiveParametersRequest");
  }
  // Still serving, and the session intact.
  const v1::Session after = GetSession(s);
  EXPECT_EQ(after.samples(), kBatch);
  EXPECT_TRUE(Stream({RestBatch(s, 2)}).ok());
}

// Streams that never send, and watchers that never read, give their place back: a stream gets
// first_batch_timeout for its first batch and stream_idle_timeout between an ack and the next
// batch; a watcher whose write has not gone out for watch_stall_timeout (its client stopped
// reading) is cancelled and its slot freed. The server as a whole holds at most max_streams.
// (Before these, 30,000 silent streams took imucald from 190 to 574 MB: bench/misuse_bench.)
// The timeouts are long enough that a loaded machine (a sanitizer build on 2 cores) opens the
// four streams, or sends the first batch, well within them: what is asserted is that the server
// ends what stays silent, not how fast.
TEST_F(ValidationTest, SilentStreamsAreEndedAndCounted) {
  options_.sessions.first_batch_timeout = absl::Seconds(5);
  options_.sessions.max_streams = 3;
  StartServer();
  const std::string s = NewSession("robot-silent");
  // Four silent streams: three fill the server, whichever comes fourth is refused at once, and
  // the three are ended by the server, no batch ever sent.
  std::vector<std::unique_ptr<grpc::ClientContext>> contexts;
  std::vector<std::unique_ptr<grpc::ClientReaderWriter<v1::SampleBatch, v1::SampleAck>>> silent;
  for (int i = 0; i < 4; ++i) {
    contexts.push_back(Ctx());
    silent.push_back(sessions_->StreamSamples(contexts.back().get()));
  }
  v1::SampleAck ack;
  int refused = 0, ended = 0;
  for (auto& stream : silent) {
    EXPECT_FALSE(stream->Read(&ack));
    const grpc::Status st = stream->Finish();
    if (st.error_code() == grpc::StatusCode::RESOURCE_EXHAUSTED) {
      ++refused;
      EXPECT_THAT(st.error_message(), HasSubstr("the server has 3 streams open"));
    } else {
      ++ended;
      EXPECT_STATUS(st, DEADLINE_EXCEEDED, "no batch within 5 s of the stream's start");
    }
  }
  EXPECT_EQ(refused, 1);
  EXPECT_EQ(ended, 3);
  // The slots are free again: a robot that streams is served.
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream({RestBatch(s, 1)}, &acks).ok());
  EXPECT_EQ(acks.at(0).last_acked_seq(), 1);
}

// A stream that sends a batch and then falls silent: its batch is stored and acknowledged, then
// the server ends the stream after stream_idle_timeout (its first batch has all of
// first_batch_timeout to arrive, however loaded the machine).
TEST_F(ValidationTest, AStreamSilentAfterAnAckIsEnded) {
  options_.sessions.first_batch_timeout = absl::Seconds(60);
  options_.sessions.stream_idle_timeout = absl::Milliseconds(300);
  StartServer();
  const std::string s = NewSession("robot-idle");
  v1::SampleAck ack;
  auto idle_ctx = Ctx();
  auto idle = sessions_->StreamSamples(idle_ctx.get());
  ASSERT_TRUE(idle->Write(RestBatch(s, 1)));
  ASSERT_TRUE(idle->Read(&ack));
  EXPECT_EQ(ack.last_acked_seq(), 1);
  EXPECT_FALSE(idle->Read(&ack));
  EXPECT_STATUS(idle->Finish(), DEADLINE_EXCEEDED, "no batch within 0.3 s of the last ack");
  EXPECT_EQ(GetSession(s).samples(), kBatch);
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(Stream({RestBatch(s, 2)}, &acks).ok());
  EXPECT_EQ(acks.at(0).last_acked_seq(), 2);
}

// A watcher that reads its snapshot and then stops reading: once its unread events fill the
// transport's window, the server's write cannot finish; after watch_stall_timeout the server
// cancels the watch and the session's watcher slot is free for a technician who reads. (The
// client that does not read does not learn of it: its transport holds the status behind the
// unread events.)
class StalledWatch final : public grpc::ClientReadReactor<v1::SessionEvent> {
 public:
  StalledWatch(v1::SessionService::Stub* stub, const std::string& session) {
    request_.set_session_id(session);
    context_.set_deadline(system_clock::now() + seconds(120));
    stub->async()->WatchSession(&context_, &request_, this);
    StartRead(&event_);
    StartCall();
  }
  // Hangs up, and lets the call end before the reactor goes.
  ~StalledWatch() override {
    context_.TryCancel();
    done_.get_future().wait();
  }
  // The snapshot arrived: the watch holds its slot. No read follows.
  void OnReadDone(bool ok) override { snapshot_.set_value(ok && event_.has_session()); }
  void OnDone(const grpc::Status&) override { done_.set_value(); }
  bool WaitForSnapshot() { return snapshot_.get_future().get(); }

 private:
  grpc::ClientContext context_;
  v1::WatchSessionRequest request_;
  v1::SessionEvent event_;
  std::promise<bool> snapshot_;
  std::promise<void> done_;
};

TEST_F(ValidationTest, AWatcherThatNeverReadsGivesItsSlotBack) {
  options_.sessions.max_watchers_per_session = 1;
  options_.sessions.watch_stall_timeout = absl::Milliseconds(500);
  options_.durability = storage::Durability::kNormal;  // thousands of batches, one at a time
  StartServer();
  const std::string s = NewSession("robot-unread");
  // The watcher's own channel with a small window (no BDP growth): a few KB of events fill it.
  grpc::ChannelArguments args;
  args.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
  args.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 1024);
  args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  auto stalled_channel =
      grpc::CreateCustomChannel(server_->address(), grpc::InsecureChannelCredentials(), args);
  auto stalled_stub = v1::SessionService::NewStub(stalled_channel);
  StalledWatch stalled(stalled_stub.get(), s);
  ASSERT_TRUE(stalled.WaitForSnapshot());
  // It holds the session's one slot.
  v1::WatchSessionRequest req;
  req.set_session_id(s);
  v1::SessionEvent e;
  {
    auto ctx = Ctx();
    auto second = sessions_->WatchSession(ctx.get(), req);
    EXPECT_FALSE(second->Read(&e));
    EXPECT_STATUS(second->Finish(), RESOURCE_EXHAUSTED, "already has 1 watchers");
  }
  // Samples make events: a stillness every 0.25 s of sample time, one or two written a batch
  // (the rest coalesce while a write is out), some 35 bytes each: far more than the window.
  std::vector<v1::SampleBatch> batches;
  for (int64_t seq = 1; seq <= 500; ++seq)
    batches.push_back(RestBatch(s, seq, kBatch, /*with_temp=*/false));
  const grpc::Status streamed = Stream(batches);
  ASSERT_TRUE(streamed.ok()) << streamed.error_message();
  // The server frees the slot once the watch's write has been stuck for watch_stall_timeout: a
  // watcher that reads is admitted then (each attempt a round trip, within a deadline).
  bool admitted = false;
  const auto deadline = system_clock::now() + seconds(30);
  while (!admitted && system_clock::now() < deadline) {
    auto ctx = Ctx();
    auto reader = sessions_->WatchSession(ctx.get(), req);
    if (reader->Read(&e)) {
      admitted = true;
      EXPECT_TRUE(e.has_session());
      ctx->TryCancel();
      reader->Finish();
    } else {
      EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    }
  }
  EXPECT_TRUE(admitted) << "the watch that never reads still holds its slot";
}

// A ReadSamples that reads its first message and no more (a stalled client).
class StalledRead final : public grpc::ClientReadReactor<v1::SampleBatch> {
 public:
  StalledRead(v1::SessionService::Stub* stub, const std::string& session) {
    request_.set_session_id(session);
    context_.set_deadline(system_clock::now() + seconds(120));
    stub->async()->ReadSamples(&context_, &request_, this);
    StartRead(&batch_);
    StartCall();
  }
  // Hangs up, and lets the call end before the reactor goes. (The call's status does not come
  // while messages lie unread: gRPC delivers it after them.)
  ~StalledRead() override {
    context_.TryCancel();
    done_.get_future().wait();
  }
  void OnReadDone(bool ok) override { first_.set_value(ok && batch_.t_s_size() > 0); }
  void OnDone(const grpc::Status&) override { done_.set_value(); }
  bool WaitForFirst() { return first_.get_future().get(); }

 private:
  grpc::ClientContext context_;
  v1::ReadSamplesRequest request_;
  v1::SampleBatch batch_;
  std::promise<bool> first_;
  std::promise<void> done_;
};

// ReadSamples holds a page of the session while its client reads: a client that stops reading
// is cancelled once a write has waited stream_idle_timeout, and its call leaves the server's
// stream count (what max_streams bounds; with a 60 s timeout it is still counted 10 s later);
// a client that reads gets every sample.
TEST_F(ValidationTest, AReaderThatStopsReadingIsCancelled) {
  options_.sessions.stream_idle_timeout = absl::Milliseconds(500);
  options_.durability = storage::Durability::kNormal;  // hundreds of batches, one at a time
  StartServer();
  const std::string s = NewSession("robot-read-stall");
  std::vector<v1::SampleBatch> batches;
  for (int64_t seq = 1; seq <= 200; ++seq)
    batches.push_back(RestBatch(s, seq, kBatch, /*with_temp=*/false));
  const grpc::Status streamed = Stream(batches);
  ASSERT_TRUE(streamed.ok()) << streamed.error_message();
  // 40,000 samples (2.2 MB) against a small window that does not grow: writes stop going out.
  grpc::ChannelArguments args;
  args.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
  args.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 1024);
  args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  auto stalled_channel =
      grpc::CreateCustomChannel(server_->address(), grpc::InsecureChannelCredentials(), args);
  auto stalled_stub = v1::SessionService::NewStub(stalled_channel);
  StalledRead stalled(stalled_stub.get(), s);
  ASSERT_TRUE(stalled.WaitForFirst());
  bool closed = false;
  for (const auto deadline = system_clock::now() + seconds(10);
       !closed && system_clock::now() < deadline;
       std::this_thread::sleep_for(std::chrono::milliseconds(10)))
    closed = server_->open_streams() == 0;
  EXPECT_TRUE(closed) << server_->open_streams() << " streams still open";
  // A reader that reads: every sample, in order.
  v1::ReadSamplesRequest req;
  req.set_session_id(s);
  auto ctx = Ctx();
  auto reader = sessions_->ReadSamples(ctx.get(), req);
  v1::SampleBatch b;
  int64_t samples = 0;
  double last_t = -1;
  while (reader->Read(&b)) {
    samples += b.t_s_size();
    EXPECT_GT(b.t_s(0), last_t);
    last_t = b.t_s(b.t_s_size() - 1);
  }
  EXPECT_TRUE(reader->Finish().ok());
  EXPECT_EQ(samples, 200 * kBatch);
}

// A stream that continues a session holding samples proves it continues the same capture: its
// first batch carries the SHA-256 of the samples it believes stored (SampleBatch.resume_sha256,
// formats/sample_digest.h). Without it, or with another capture's, the stream is refused
// naming both captures, and nothing of the other capture is stored.
TEST_F(ValidationTest, AResumeMustProveItContinuesTheStoredCapture) {
  StartServer();
  const std::string s = NewSession("robot-splice");
  v1::SampleBatch first = RestBatch(s, 1);
  first.set_source("a.csv");
  std::vector<v1::SampleAck> acks;
  ASSERT_TRUE(StreamAsIs({first, RestBatch(s, 2)}, &acks).ok());
  // Another capture: the same times, other values.
  auto other = [&](int64_t seq) {
    v1::SampleBatch b = RestBatch(s, seq);
    for (double& a : *b.mutable_accel()) a += 0.5;
    return b;
  };
  v1::SampleBatch unproven = other(3);
  unproven.set_source("b.csv");
  acks.clear();
  EXPECT_STATUS(StreamAsIs({unproven}, &acks), FAILED_PRECONDITION, "resume_sha256: required");
  v1::SampleBatch wrong = unproven;
  wrong.set_resume_sha256(Digest({other(1), other(2)}));
  const grpc::Status refused = StreamAsIs({wrong}, &acks);
  EXPECT_STATUS(refused, FAILED_PRECONDITION, "'b.csv' does not continue");
  EXPECT_THAT(refused.error_message(), HasSubstr("'a.csv'"));
  EXPECT_THAT(refused.error_message(), HasSubstr("400 samples"));
  EXPECT_TRUE(acks.empty());
  EXPECT_EQ(GetSession(s).samples(), 2 * kBatch);
  EXPECT_EQ(GetSession(s).source(), "a.csv");
  // The same capture resumes, on the proof of its first 400 samples.
  v1::SampleBatch next = RestBatch(s, 3);
  next.set_resume_sha256(Digest({RestBatch(s, 1), RestBatch(s, 2)}));
  ASSERT_TRUE(StreamAsIs({next}, &acks).ok());
  EXPECT_EQ(acks.at(0).samples(), 3 * kBatch);
  EXPECT_EQ(GetSession(s).samples_sha256(),
            Digest({RestBatch(s, 1), RestBatch(s, 2), RestBatch(s, 3)}));
}

// Promote and Rollback write `reason` to the audit log: bounded, like every other free text.
TEST_F(ValidationTest, PromoteAndRollbackReasonsAreCapped) {
  StartServer();
  NewSession("robot-reason");
  auto params = v1::ParameterService::NewStub(channel_);
  v1::PromoteRequest promote;
  promote.set_device_id("robot-reason");
  promote.set_version(1);
  promote.set_reason(std::string(120 << 10, 'x'));
  v1::ParameterSet set;
  EXPECT_STATUS(params->Promote(Ctx().get(), promote, &set), INVALID_ARGUMENT,
                "reason: 122880 bytes, at most 1024");
  v1::RollbackRequest rollback;
  rollback.set_device_id("robot-reason");
  rollback.set_to_version(1);
  rollback.set_reason(std::string(1025, 'y'));
  EXPECT_STATUS(params->Rollback(Ctx().get(), rollback, &set), INVALID_ARGUMENT,
                "reason: 1025 bytes, at most 1024");
  rollback.set_reason(std::string("line one\x01", 9));
  EXPECT_STATUS(params->Rollback(Ctx().get(), rollback, &set), INVALID_ARGUMENT,
                "reason: a control character at byte 9 (U+0001)");
}

// Free text that people read (a reason, a capture's source, a sensor model) refuses the C1
// controls (U+0080-U+009F) as it refuses C0 ones, naming the field, the byte and the character:
// U+0085 is a line break to many readers, U+009B a terminal's CSI (util/text_check.h).
TEST_F(ValidationTest, FreeTextRefusesC1ControlsLikeC0Ones) {
  StartServer();
  const std::string s = NewSession("robot-c1");
  auto params = v1::ParameterService::NewStub(channel_);
  v1::PromoteRequest promote;
  promote.set_device_id("robot-c1");
  promote.set_version(1);
  promote.set_reason("approved\u0085by QA");
  v1::ParameterSet set;
  EXPECT_STATUS(params->Promote(Ctx().get(), promote, &set), INVALID_ARGUMENT,
                "reason: a control character at byte 9 (U+0085)");
  promote.set_reason("tab\tand\nnewline are a paragraph's; \u00e9 is a letter");
  EXPECT_STATUS(params->Promote(Ctx().get(), promote, &set), NOT_FOUND, "");  // past the check

  v1::SampleBatch b = RestBatch(s, 1);
  b.set_source("cap\u009b31m.csv");
  EXPECT_STATUS(StreamAsIs({b}), INVALID_ARGUMENT,
                "source: a control character at byte 4 (U+009B)");
  EXPECT_EQ(GetSession(s).samples(), 0);

  v1::RegisterDeviceRequest reg;
  reg.mutable_device()->set_id("robot-c1-model");
  reg.mutable_device()->set_sensor_model("BMI\u0085088");
  reg.mutable_device()->set_nominal_rate_hz(kRateHz);
  reg.mutable_device()->set_accel_unit("m/s^2");
  reg.mutable_device()->set_gyro_unit("rad/s");
  v1::Device d;
  EXPECT_STATUS(devices_->RegisterDevice(Ctx().get(), reg, &d), INVALID_ARGUMENT,
                "device.sensor_model: a control character at byte 4 (U+0085)");
  reg.mutable_device()->set_sensor_model("BMI\x1b[2J088");
  EXPECT_STATUS(devices_->RegisterDevice(Ctx().get(), reg, &d), INVALID_ARGUMENT,
                "device.sensor_model: a control character at byte 4 (U+001B)");
}

// GetSolveJob's job_id is "solve-<n>", n a positive integer as SolveSession returns it: any
// other form is INVALID_ARGUMENT naming it (the proto's contract), and only a well-formed id of
// no job is NOT_FOUND. "solve--1" used to go to storage as -1 and come back NOT_FOUND.
TEST_F(ValidationTest, GetSolveJobRefusesMalformedIds) {
  StartServer();
  v1::SolveJob job;
  v1::GetSolveJobRequest get;
  const std::vector<std::string> malformed = {"solve--1",
                                              "solve-",
                                              "solve-0",
                                              "solve-007",
                                              "solve- 7",
                                              "solve-+7",
                                              "solve-7 ",
                                              "solve-7x",
                                              "solve-1.0",
                                              "SOLVE-7",
                                              "job-7",
                                              "solve-99999999999999999999",
                                              std::string("solve-7\0", 8)};
  for (const std::string& bad : malformed) {
    get.set_job_id(bad);
    const grpc::Status st = sessions_->GetSolveJob(Ctx().get(), get, &job);
    EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT)
        << bad << ": " << st.error_message();
    EXPECT_THAT(st.error_message(), HasSubstr("is not a solve job id (\"solve-<n>\", n a "
                                              "positive integer"))
        << bad;
  }
  get.set_job_id("solve--1");
  EXPECT_STATUS(sessions_->GetSolveJob(Ctx().get(), get, &job), INVALID_ARGUMENT,
                "job_id: 'solve--1' is not a solve job id");
  get.set_job_id("solve-" + std::string(1000, '9'));  // echoed cut short
  const grpc::Status long_id = sessions_->GetSolveJob(Ctx().get(), get, &job);
  EXPECT_EQ(long_id.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_LT(long_id.error_message().size(), 200u) << long_id.error_message();
  get.set_job_id("");
  EXPECT_STATUS(sessions_->GetSolveJob(Ctx().get(), get, &job), INVALID_ARGUMENT,
                "job_id: required");
  get.set_job_id("solve-999");
  EXPECT_STATUS(sessions_->GetSolveJob(Ctx().get(), get, &job), NOT_FOUND, "");

  // A job SolveSession returned is found by its id.
  const std::string s = NewSession("robot-job");
  ASSERT_TRUE(Stream({RestBatch(s, 1)}).ok());
  v1::SolveSessionRequest solve;
  solve.set_session_id(s);
  v1::SolveJob started;
  ASSERT_TRUE(sessions_->SolveSession(Ctx().get(), solve, &started).ok());
  get.set_job_id(started.id());
  grpc::Status found = sessions_->GetSolveJob(Ctx().get(), get, &job);
  EXPECT_TRUE(found.ok()) << started.id() << ": " << found.error_message();
  EXPECT_EQ(job.session_id(), s);
}

// A bad rostopic is echoed as it was sent: the path scrubber (which hides the server's files)
// leaves request fields alone ("/imu0 raw" used to come back as "<path> raw").
TEST_F(ValidationTest, ABadRostopicIsNamedAsSent) {
  StartServer();
  NewSession("robot-topic");
  auto params = v1::ParameterService::NewStub(channel_);
  v1::ExportRequest req;
  req.set_device_id("robot-topic");
  req.set_format("kalibr");
  req.set_rostopic("/imu0 raw");
  v1::ExportResponse out;
  EXPECT_STATUS(params->Export(Ctx().get(), req, &out), INVALID_ARGUMENT,
                "rostopic: \"/imu0 raw\" is not a ROS 2 topic name: character 6");
  req.set_rostopic("../x.db");
  EXPECT_STATUS(params->Export(Ctx().get(), req, &out), INVALID_ARGUMENT,
                "rostopic: \"../x.db\" is not a ROS 2 topic name");
}

// The SDK sets a deadline on its stream too: a stream that outlives it ends DEADLINE_EXCEEDED
// and the upload gives up after its retry time rather than waiting for ever.
TEST_F(ValidationTest, UploaderStreamsHaveADeadline) {
  StartServer();
  const std::string s = NewSession("robot-deadline");
  sdk::SampleColumns cols;
  const v1::SampleBatch b = RestBatch(s, 1);
  cols.t_s.assign(b.t_s().begin(), b.t_s().end());
  cols.accel.assign(b.accel().begin(), b.accel().end());
  cols.gyro.assign(b.gyro().begin(), b.gyro().end());
  sdk::UploadOptions o;
  o.batch_samples = 10;
  // No retry: a retry would find the batch the server stored before the client's deadline hit
  // (the deadline ends the client's call, not the server's write) and finish the upload OK.
  o.retry_for = absl::ZeroDuration();
  o.initial_backoff = absl::Milliseconds(1);
  o.stream_deadline = absl::Microseconds(1);
  sdk::Uploader uploader(channel_, o);
  const absl::Status st = uploader.Upload(s, cols).status();
  EXPECT_TRUE(absl::IsDeadlineExceeded(st)) << st;
}

// ---- Prometheus metrics (server/metrics.h), scraped over HTTP as Prometheus would.

// GET http://127.0.0.1:port/metrics (HTTP/1.0: the server closes when done); the body.
std::string Scrape(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return "socket failed";
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  std::string reply;
  if (::connect(fd, reinterpret_cast<const sockaddr*>(&addr), sizeof(addr)) == 0) {
    const std::string request = "GET /metrics HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n";
    if (::send(fd, request.data(), request.size(), 0) == static_cast<ssize_t>(request.size())) {
      char buf[4096];
      for (ssize_t n; (n = ::recv(fd, buf, sizeof(buf), 0)) > 0;)
        reply.append(buf, static_cast<size_t>(n));
    }
  }
  ::close(fd);
  const size_t body = reply.find("\r\n\r\n");
  return body == std::string::npos ? "no HTTP reply: " + reply : reply.substr(body + 4);
}

// The value of the sample line `series` ("name{labels}" as exposed), NaN when absent.
double Sample(const std::string& text, const std::string& series) {
  size_t at = 0;
  while ((at = text.find(series + " ", at)) != std::string::npos) {
    if (at == 0 || text[at - 1] == '\n') return std::stod(text.substr(at + series.size() + 1));
    at += series.size();
  }
  return std::numeric_limits<double>::quiet_NaN();
}

class MetricsTest : public ValidationTest {
 protected:
  void SetUp() override {
    ValidationTest::SetUp();
    options_.metrics_listen = "127.0.0.1:0";
  }
};

// What a replica did shows in its scrape: calls by method and code, the samples received and
// acknowledged (a retransmission acknowledged again but stored once), the write transactions,
// the open watchers, and a solve by its outcome once it has run.
TEST_F(MetricsTest, AScrapeCountsCallsSamplesTransactionsWatchersAndSolves) {
  StartServer();
  ASSERT_GT(server_->metrics_port(), 0);
  const std::string s = NewSession("robot-metrics");
  std::vector<v1::SampleBatch> batches = {RestBatch(s, 1), RestBatch(s, 2), RestBatch(s, 3)};
  ASSERT_TRUE(Stream(batches).ok());
  ASSERT_TRUE(Stream({RestBatch(s, 3)}).ok());  // a retransmission: acknowledged, not stored
  v1::GetSessionRequest missing;
  missing.set_session_id("s-none");
  v1::Session out;
  EXPECT_FALSE(sessions_->GetSession(Ctx().get(), missing, &out).ok());
  v1::WatchSessionRequest watch;
  watch.set_session_id(s);
  auto watch_ctx = Ctx();
  auto watcher = sessions_->WatchSession(watch_ctx.get(), watch);
  v1::SessionEvent snapshot;
  ASSERT_TRUE(watcher->Read(&snapshot));  // the watcher holds its slot now

  std::string text = Scrape(server_->metrics_port());
  ASSERT_THAT(text, HasSubstr("# TYPE imucal_rpc_total counter"));
  EXPECT_EQ(Sample(text, "imucal_rpc_total{code=\"OK\",method=\"/imucal.v1.DeviceService/"
                         "RegisterDevice\"}"),
            1);
  EXPECT_EQ(Sample(text, "imucal_rpc_total{code=\"NOT_FOUND\",method=\"/imucal.v1.SessionService/"
                         "GetSession\"}"),
            1);
  EXPECT_EQ(Sample(text, "imucal_rpc_total{code=\"OK\",method=\"/imucal.v1.SessionService/"
                         "StreamSamples\"}"),
            2);
  EXPECT_EQ(Sample(text, "imucal_rpc_duration_seconds_count{method=\"/imucal.v1.SessionService/"
                         "CreateSession\"}"),
            1);
  EXPECT_EQ(Sample(text, "imucal_samples_received_total"), 4 * kBatch);
  EXPECT_EQ(Sample(text, "imucal_samples_acknowledged_total"), 3 * kBatch);
  EXPECT_EQ(Sample(server_->metrics()->Text(), "imucal_samples_acknowledged_total"), 3 * kBatch);
  EXPECT_GE(Sample(text, "imucal_db_transaction_duration_seconds_count{op=\"AppendBatch\"}"), 1);
  EXPECT_EQ(Sample(text, "imucal_watchers_open"), 1);
  EXPECT_EQ(Sample(text, "imucal_sample_streams_open"), 0);
  EXPECT_EQ(Sample(text, "imucal_sessions_in_memory"), 1);
  EXPECT_EQ(Sample(text, "imucal_solve_queue_depth"), 0);
  watch_ctx->TryCancel();
  watcher->Finish();

  // A rest alone cannot be solved: the solve runs and is refused. Shutdown lets it finish; the
  // endpoint serves until the server object goes.
  v1::SolveSessionRequest solve;
  solve.set_session_id(s);
  v1::SolveJob job;
  ASSERT_TRUE(sessions_->SolveSession(Ctx().get(), solve, &job).ok());
  server_->Shutdown();
  text = Scrape(server_->metrics_port());
  EXPECT_EQ(Sample(text, "imucal_solve_duration_seconds_count{outcome=\"refused\"}"), 1) << text;
  EXPECT_GE(Sample(text, "imucal_db_transaction_duration_seconds_count{op=\"FailSolve\"}"), 1);
}

// Solves waiting for a thread are the queue's depth (no solve threads: they stay queued).
TEST_F(MetricsTest, QueuedSolvesAreTheQueueDepth) {
  options_.sessions.solve_threads = 0;
  StartServer();
  for (int i = 0; i < 2; ++i) {
    const std::string s = NewSession("robot-queued-" + std::to_string(i));
    ASSERT_TRUE(Stream({RestBatch(s, 1)}).ok());
    v1::SolveSessionRequest req;
    req.set_session_id(s);
    v1::SolveJob job;
    ASSERT_TRUE(sessions_->SolveSession(Ctx().get(), req, &job).ok());
  }
  EXPECT_EQ(Sample(Scrape(server_->metrics_port()), "imucal_solve_queue_depth"), 2);
}

// An address it cannot serve metrics on is refused at start, naming the option.
TEST_F(MetricsTest, AMetricsAddressInUseIsRefusedAtStart) {
  StartServer();
  ServerOptions second = options_;
  second.db_path = dir_.File("other.db");
  second.metrics_listen = "127.0.0.1:" + std::to_string(server_->metrics_port());
  absl::StatusOr<std::unique_ptr<Server>> other = Server::Start(second);
  ASSERT_FALSE(other.ok());
  EXPECT_THAT(std::string(other.status().message()), HasSubstr("metrics_listen"));
  EXPECT_THAT(std::string(other.status().message()), HasSubstr("the port is in use"));
  // An address that is not HOST:PORT is named as such, whatever the HTTP server would say.
  for (const std::string bad : {"nonsense", "127.0.0.1:99999", ":9464", "127.0.0.1:port"}) {
    second.metrics_listen = bad;
    other = Server::Start(second);
    ASSERT_FALSE(other.ok()) << bad;
    EXPECT_EQ(other.status().code(), absl::StatusCode::kInvalidArgument) << other.status();
    EXPECT_THAT(std::string(other.status().message()),
                HasSubstr("expected HOST:PORT with a port from 0 to 65535"));
    EXPECT_THAT(std::string(other.status().message()), HasSubstr("'" + bad + "'"));
  }
}

}  // namespace
}  // namespace imucal::server
