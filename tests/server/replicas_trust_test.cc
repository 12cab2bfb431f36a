// What servers sharing one database must agree on as it happens (issue 26), on a real
// PostgreSQL (tests/pg_test_cluster.h) and real gRPC servers on loopback ports:
//   - a token revoked through one replica, or by SQL typed straight into the database, ends the
//     token's open stream on another replica and is refused there for new calls within 1 s
//     (in-process TLS servers: tokens need TLS); on SQLite, SQL from another process is
//     honoured within the same bound;
//   - one open sample stream per device across replicas: a second replica refuses the device's
//     stream while the first holds it, takes it at once when that stream ends, and after the
//     holder is SIGKILLed once its claim's lease (--stream-lease) lapses (imucald processes);
//   - a replica that read a session before its upload went through another answers GetSession
//     and ListSessions as the database holds the session.
// The figures (how long each took) are printed; the bounds asserted are the ones promised.
#include <signal.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "client/sdk/client.h"
#include "client/sdk/uploader.h"
#include "core/simulator.h"
#include "grpcpp/grpcpp.h"
#include "gtest/gtest.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/server.h"
#include "storage/pg_db.h"
#include "tests/client/imucald_process.h"
#include "tests/pg_test_cluster.h"
#include "tests/server/daemon_clients.h"
#include "util/sqlite_db.h"

namespace imucal::server {
namespace {

namespace fs = std::filesystem;
namespace pb = ::imucal::v1;
using Clock = std::chrono::steady_clock;
using grpc::StatusCode;
using testing_util::ImucaldProcess;

constexpr char kDevice[] = "robot-A";
// The promise: a revocation anywhere is honoured everywhere within this.
constexpr auto kRevocationBound = std::chrono::milliseconds(1000);

// The server's certificate for "localhost" / 127.0.0.1, from a CA made at test time.
constexpr char kMakeCertsScript[] = R"sh(
set -e
cd "$1"
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days 2 \
  -keyout ca.key -out ca.pem -subj "/CN=imucal test CA" 2>/dev/null
openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes \
  -keyout server.key -out server.csr -subj "/CN=localhost" 2>/dev/null
printf 'subjectAltName=DNS:localhost,IP:127.0.0.1\nextendedKeyUsage=serverAuth\n' > server.ext
openssl x509 -req -in server.csr -CA ca.pem -CAkey ca.key -CAcreateserial -days 2 \
  -out server.pem -extfile server.ext 2>/dev/null
)sh";

std::string ReadText(const fs::path& path) {
  std::ifstream in(path);
  std::ostringstream text;
  text << in.rdbuf();
  std::string s = text.str();
  while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
  return s;
}

std::unique_ptr<grpc::ClientContext> Ctx() {
  auto c = std::make_unique<grpc::ClientContext>();
  c->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  return c;
}

double MsSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// Batch `seq` of a resting 100 Hz robot: 10 samples.
pb::SampleBatch Batch(const std::string& session, int64_t seq) {
  pb::SampleBatch b;
  b.set_session_id(session);
  b.set_seq(seq);
  for (int i = 0; i < 10; ++i) {
    b.add_t_s(static_cast<double>((seq - 1) * 10 + i) / 100);
    for (double x : {0.0, 0.0, 9.81}) b.add_accel(x);
    for (double x : {0.0, 0.0, 0.0}) b.add_gyro(x);
  }
  return b;
}

// A robot streaming batches back to back on its own thread until its stream ends; when it
// ended, and how.
class RobotStream {
 public:
  RobotStream(std::shared_ptr<grpc::Channel> channel, std::string session)
      : stub_(pb::SessionService::NewStub(std::move(channel))), session_(std::move(session)) {
    context_.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    stream_ = stub_->StreamSamples(&context_);
    thread_ = std::thread([this] { Run(); });
  }
  ~RobotStream() {
    context_.TryCancel();
    thread_.join();
  }

  // Waits until at least `n` batches are acknowledged (false: the stream ended first).
  bool WaitForAcks(int64_t n) {
    std::unique_lock lock(mu_);
    cv_.wait_for(lock, std::chrono::seconds(20), [&] { return ended_ || acked_ >= n; });
    return acked_ >= n;
  }
  // Waits at most `timeout` for the stream to end; when it did, or nullopt.
  std::optional<Clock::time_point> WaitForEnd(std::chrono::milliseconds timeout) {
    std::unique_lock lock(mu_);
    if (!cv_.wait_for(lock, timeout, [&] { return ended_; })) return std::nullopt;
    return ended_at_;
  }
  int64_t acked() {
    std::lock_guard lock(mu_);
    return acked_;
  }
  grpc::Status status() {
    std::lock_guard lock(mu_);
    return status_;
  }

 private:
  void Run() {
    pb::SampleAck ack;
    for (int64_t seq = 1;; ++seq) {
      if (!stream_->Write(Batch(session_, seq)) || !stream_->Read(&ack)) break;
      std::lock_guard lock(mu_);
      acked_ = ack.last_acked_seq();
      cv_.notify_all();
    }
    const Clock::time_point at = Clock::now();
    grpc::Status status = stream_->Finish();
    std::lock_guard lock(mu_);
    ended_ = true;
    ended_at_ = at;
    status_ = status;
    cv_.notify_all();
  }

  std::unique_ptr<pb::SessionService::Stub> stub_;
  std::string session_;
  grpc::ClientContext context_;
  std::unique_ptr<grpc::ClientReaderWriter<pb::SampleBatch, pb::SampleAck>> stream_;
  std::mutex mu_;
  std::condition_variable cv_;
  int64_t acked_ = 0;   // guarded by mu_
  bool ended_ = false;  // guarded by mu_
  Clock::time_point ended_at_;
  grpc::Status status_;
  std::thread thread_;
};

// Calls `call` until it answers UNAUTHENTICATED (at most `timeout`); how long that took, or
// nullopt.
std::optional<double> MsUntilRefused(const std::function<grpc::Status()>& call,
                                     Clock::time_point since, std::chrono::milliseconds timeout) {
  while (Clock::now() - since < timeout) {
    const grpc::Status s = call();
    if (s.error_code() == StatusCode::UNAUTHENTICATED) return MsSince(since);
    EXPECT_TRUE(s.ok()) << s.error_code() << " " << s.error_message();
  }
  return std::nullopt;
}

// TLS servers with tokens, on one database (a PostgreSQL URL or a SQLite file).
class TokenReplicasTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::path(::testing::TempDir()) /
           absl::StrCat("replicas_trust_", ::getpid(), "_",
                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    std::ofstream(dir_ / "make_certs.sh") << kMakeCertsScript;
    ASSERT_EQ(std::system(
                  absl::StrCat("sh '", (dir_ / "make_certs.sh").string(), "' '", dir_.string(), "'")
                      .c_str()),
              0)
        << "openssl could not make the certificates";
  }
  void TearDown() override {
    servers_.clear();
    db_.reset();
    fs::remove_all(dir_);
  }

  void StartServers(const std::string& db, int n) {
    for (int i = 1; i <= n; ++i) {
      ServerOptions o;
      o.listen = "127.0.0.1:0";
      o.db_path = db;
      o.security.tls_cert_path = (dir_ / "server.pem").string();
      o.security.tls_key_path = (dir_ / "server.key").string();
      o.admin_token_file = (dir_ / "admin-token").string();
      o.sessions.replica_id = absl::StrCat("r", i);
      absl::StatusOr<std::unique_ptr<Server>> server = Server::Start(o);
      ASSERT_TRUE(server.ok()) << "replica " << i << ": " << server.status();
      servers_.push_back(*std::move(server));
    }
    admin_ = ReadText(dir_ / "admin-token");
  }

  std::shared_ptr<grpc::Channel> Channel(const Server& server, const std::string& token) {
    sdk::ClientOptions o;
    o.ca_cert_pem = ReadText(dir_ / "ca.pem") + "\n";
    o.bearer_token = token;
    return sdk::MakeChannel(server.address(), o);
  }

  // A robot token for kDevice, the device registered and a session open: through servers_[0].
  void ProvisionRobot() {
    auto admin = Channel(*servers_[0], admin_);
    pb::CreateTokenRequest create;
    create.set_role(pb::ROLE_ROBOT);
    create.set_device_id(kDevice);
    create.set_label("robot A");
    pb::CreateTokenResponse token;
    grpc::Status s = pb::AdminService::NewStub(admin)->CreateToken(Ctx().get(), create, &token);
    ASSERT_TRUE(s.ok()) << s.error_message();
    robot_ = token.secret();
    robot_id_ = token.token().id();
    const pb::RegisterDeviceRequest reg = testing_util::SimDeviceRequest(kDevice);
    pb::Device device;
    s = pb::DeviceService::NewStub(admin)->RegisterDevice(Ctx().get(), reg, &device);
    ASSERT_TRUE(s.ok()) << s.error_message();
    pb::CreateSessionRequest open;
    open.set_device_id(kDevice);
    pb::Session session;
    s = pb::SessionService::NewStub(admin)->CreateSession(Ctx().get(), open, &session);
    ASSERT_TRUE(s.ok()) << s.error_message();
    session_ = session.id();
  }

  // A new call with the robot's token through `server`: GetDevice of its own device.
  std::function<grpc::Status()> RobotCall(const Server& server) {
    auto stub = std::shared_ptr<pb::DeviceService::Stub>(
        pb::DeviceService::NewStub(Channel(server, robot_)));
    return [stub] {
      pb::GetDeviceRequest req;
      req.set_device_id(kDevice);
      pb::Device out;
      return stub->GetDevice(Ctx().get(), req, &out);
    };
  }

  // With the robot streaming through servers_[1] and its calls answered (and cached) by every
  // server, `revoke` revokes the token somewhere; the stream and new calls on every server must
  // end within kRevocationBound of it.
  void ExpectRevocationHonouredEverywhere(const std::string& how,
                                          const std::function<void()>& revoke) {
    std::vector<std::function<grpc::Status()>> calls;
    for (const auto& server : servers_) {
      calls.push_back(RobotCall(*server));
      const grpc::Status s = calls.back()();  // the token is now in each server's cache
      ASSERT_TRUE(s.ok()) << s.error_message();
    }
    RobotStream stream(Channel(*servers_[1], robot_), session_);
    ASSERT_TRUE(stream.WaitForAcks(3)) << stream.status().error_message();

    const Clock::time_point revoked = Clock::now();
    revoke();
    const double revoke_ms = MsSince(revoked);
    const int64_t acked_at_revoke = stream.acked();
    const std::optional<Clock::time_point> ended = stream.WaitForEnd(std::chrono::seconds(5));
    ASSERT_TRUE(ended.has_value()) << how << ": the stream on replica 2 was still open 5 s after "
                                   << "the revocation (" << stream.acked() << " batches acked)";
    const double stream_ms = std::chrono::duration<double, std::milli>(*ended - revoked).count();
    EXPECT_EQ(stream.status().error_code(), StatusCode::UNAUTHENTICATED)
        << stream.status().error_message();
    EXPECT_LE(stream_ms, kRevocationBound.count()) << how << ": the stream on replica 2";
    std::string refused;
    for (size_t i = 0; i < calls.size(); ++i) {
      const std::optional<double> ms =
          MsUntilRefused(calls[i], revoked, std::chrono::milliseconds(5000));
      ASSERT_TRUE(ms.has_value()) << how << ": replica " << i + 1
                                  << " still takes the token's calls 5 s after the revocation";
      EXPECT_LE(*ms, kRevocationBound.count()) << how << ": new calls on replica " << i + 1;
      absl::StrAppend(&refused, i == 0 ? "" : ", ", "replica ", i + 1, " ", absl::SixDigits(*ms),
                      " ms");
    }
    std::printf(
        "[ revoke   ] %s (the call took %.1f ms): the stream on replica 2 ended after "
        "%.1f ms (%lld batches acked after the revocation began); new calls refused "
        "by %s (each measured from the revocation's start)\n",
        how.c_str(), revoke_ms, stream_ms, static_cast<long long>(stream.acked() - acked_at_revoke),
        refused.c_str());
    std::fflush(stdout);
  }

  fs::path dir_;
  std::unique_ptr<testing_util::PgTestDatabase> db_;
  std::vector<std::unique_ptr<Server>> servers_;
  std::string admin_, robot_, session_;
  int64_t robot_id_ = 0;
};

TEST_F(TokenReplicasTest, ATokenRevokedThroughOneReplicaIsRefusedByEveryReplicaWithinASecond) {
  auto db = testing_util::PgTestDatabase::Create();
  ASSERT_TRUE(db.ok()) << db.status();
  db_ = *std::move(db);
  ASSERT_NO_FATAL_FAILURE(StartServers(db_->url(), 3));
  ASSERT_NO_FATAL_FAILURE(ProvisionRobot());
  ExpectRevocationHonouredEverywhere("revoked through replica 1", [&] {
    pb::RevokeTokenRequest req;
    req.set_id(robot_id_);
    pb::Token out;
    const grpc::Status s = pb::AdminService::NewStub(Channel(*servers_[0], admin_))
                               ->RevokeToken(Ctx().get(), req, &out);
    ASSERT_TRUE(s.ok()) << s.error_message();
  });
}

TEST_F(TokenReplicasTest, ATokenRevokedBySqlInPostgresIsRefusedByEveryReplicaWithinASecond) {
  auto db = testing_util::PgTestDatabase::Create();
  ASSERT_TRUE(db.ok()) << db.status();
  db_ = *std::move(db);
  ASSERT_NO_FATAL_FAILURE(StartServers(db_->url(), 3));
  ASSERT_NO_FATAL_FAILURE(ProvisionRobot());
  auto conn = storage::PgConnection::Open(db_->url(), {});
  ASSERT_TRUE(conn.ok()) << conn.status();
  ExpectRevocationHonouredEverywhere("revoked by SQL in PostgreSQL", [&] {
    const std::string sql =
        absl::StrCat("UPDATE tokens SET revoked_at_us = ", absl::ToUnixMicros(absl::Now()),
                     " WHERE id = ", robot_id_);
    ASSERT_TRUE((*conn)->Exec(sql.c_str()).ok());
  });
}

// Two servers on one SQLite file, the token revoked by another connection to the file (as the
// sqlite3 shell would): honoured by both within the bound (they read the change log every
// 250 ms).
TEST_F(TokenReplicasTest, ATokenRevokedBySqlInSqliteIsRefusedWithinASecond) {
  const std::string file = (dir_ / "imucal.db").string();
  ASSERT_NO_FATAL_FAILURE(StartServers(file, 2));
  ASSERT_NO_FATAL_FAILURE(ProvisionRobot());
  auto conn = sql::SqliteConnection::Open(file, {});
  ASSERT_TRUE(conn.ok()) << conn.status();
  ExpectRevocationHonouredEverywhere("revoked by SQL in SQLite", [&] {
    const std::string sql =
        absl::StrCat("UPDATE tokens SET revoked_at_us = ", absl::ToUnixMicros(absl::Now()),
                     " WHERE id = ", robot_id_);
    ASSERT_TRUE((*conn)->Exec(sql.c_str()).ok());
  });
}

// imucald processes on one PostgreSQL (plaintext on loopback: these are not about tokens).
class ClaimReplicasTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!testing_util::kHaveImucald) GTEST_SKIP() << "imucald is not built yet";
    auto db = testing_util::PgTestDatabase::Create();
    ASSERT_TRUE(db.ok()) << db.status();
    db_ = *std::move(db);
    for (int r = 1; r <= 2; ++r) {
      auto replica = ImucaldProcess::StartOnDatabase(
          db_->url(),
          {"--replica-id", absl::StrCat("r", r), "--log-level", "warning", "--stream-lease", "2s"});
      ASSERT_TRUE(replica.ok()) << "replica " << r << ": " << replica.status();
      replicas_.push_back(*std::move(replica));
    }
  }
  void TearDown() override {
    replicas_.clear();
    db_.reset();
  }

  std::string OpenSession() {
    auto channel = replicas_[0]->NewChannel();
    const pb::RegisterDeviceRequest reg = testing_util::SimDeviceRequest(kDevice);
    pb::Device d;
    grpc::Status s = pb::DeviceService::NewStub(channel)->RegisterDevice(Ctx().get(), reg, &d);
    EXPECT_TRUE(s.ok()) << s.error_message();
    pb::CreateSessionRequest create;
    create.set_device_id(kDevice);
    create.set_protocol(pb::PROTOCOL_SIX_FACE);
    pb::Session session;
    s = pb::SessionService::NewStub(channel)->CreateSession(Ctx().get(), create, &session);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return session.id();
  }

  std::unique_ptr<testing_util::PgTestDatabase> db_;
  std::vector<std::unique_ptr<ImucaldProcess>> replicas_;
};

// A stream of the session from batch 1 (a repeat of a stored batch is compared and acked).
struct OpenStream {
  OpenStream(const ImucaldProcess& replica, const std::string& session)
      : stub(pb::SessionService::NewStub(replica.NewChannel())) {
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
    stream = stub->StreamSamples(&context);
    pb::SampleAck ack;
    if (stream->Write(Batch(session, 1)) && stream->Read(&ack)) {
      acked = true;
    } else {
      status = stream->Finish();
    }
  }
  grpc::Status Close() {
    stream->WritesDone();
    return stream->Finish();
  }
  std::unique_ptr<pb::SessionService::Stub> stub;
  grpc::ClientContext context;
  std::unique_ptr<grpc::ClientReaderWriter<pb::SampleBatch, pb::SampleAck>> stream;
  bool acked = false;
  grpc::Status status;  // when not acked: why
};

TEST_F(ClaimReplicasTest, ADeviceStreamsThroughOneReplicaAtATime) {
  const std::string session = OpenSession();
  ASSERT_FALSE(session.empty());
  // Replica 1 has the device's stream: replica 2 refuses another, as one server would.
  auto first = std::make_unique<OpenStream>(*replicas_[0], session);
  ASSERT_TRUE(first->acked) << first->status.error_message();
  {
    OpenStream second(*replicas_[1], session);
    EXPECT_FALSE(second.acked) << "a second stream of the device, on replica 2, was accepted";
    EXPECT_EQ(second.status.error_code(), StatusCode::RESOURCE_EXHAUSTED)
        << second.status.error_message();
    EXPECT_NE(second.status.error_message().find("another server"), std::string::npos)
        << second.status.error_message();
  }
  // The stream ends: replica 2 takes the device at once.
  ASSERT_TRUE(first->Close().ok());
  first.reset();
  auto taken = std::make_unique<OpenStream>(*replicas_[1], session);
  ASSERT_TRUE(taken->acked) << "replica 2 after replica 1's stream ended: "
                            << taken->status.error_message();
  {
    OpenStream again(*replicas_[0], session);
    EXPECT_FALSE(again.acked) << "replica 1 accepted a stream while replica 2 holds the device";
    EXPECT_EQ(again.status.error_code(), StatusCode::RESOURCE_EXHAUSTED)
        << again.status.error_message();
  }
  // Replica 2 is killed holding the device: replica 1 refuses it until the claim's lease (2 s)
  // lapses, then takes it.
  const Clock::time_point killed = Clock::now();
  replicas_[1]->Stop(SIGKILL);
  int refused = 0;
  std::unique_ptr<OpenStream> after;
  while (Clock::now() - killed < std::chrono::seconds(20)) {
    after = std::make_unique<OpenStream>(*replicas_[0], session);
    if (after->acked) break;
    ASSERT_EQ(after->status.error_code(), StatusCode::RESOURCE_EXHAUSTED)
        << after->status.error_message();
    ++refused;
  }
  const double ms = MsSince(killed);
  ASSERT_TRUE(after != nullptr && after->acked) << "replica 1 never took the killed one's device";
  EXPECT_GE(refused, 1) << "refused while the killed replica's lease ran";
  EXPECT_LE(ms, 2000 + 2000) << "taken within the lease (2 s) and a generous margin";
  std::printf(
      "[ claims   ] replica 2 SIGKILLed holding the device: replica 1 took it after "
      "%.0f ms (--stream-lease 2s; %d attempts refused meanwhile)\n",
      ms, refused);
  std::fflush(stdout);
}

// Replica 2 reads the session (and keeps it in memory) before the robot uploads through
// replica 1: replica 2 then answers GetSession and ListSessions as the database holds it.
TEST_F(ClaimReplicasTest, AReplicaThatReadASessionBeforeItsUploadShowsItAsStored) {
  const std::string session = OpenSession();
  ASSERT_FALSE(session.empty());
  auto stale = pb::SessionService::NewStub(replicas_[1]->NewChannel());
  pb::GetSessionRequest get;
  get.set_session_id(session);
  pb::Session before;
  ASSERT_TRUE(stale->GetSession(Ctx().get(), get, &before).ok());
  EXPECT_EQ(before.samples(), 0);

  core::SimOptions sim;
  sim.seed = 3;
  absl::StatusOr<core::SimResult> simulated = core::Simulate(sim);
  ASSERT_TRUE(simulated.ok()) << simulated.status();
  sdk::UploadOptions o;
  o.batch_samples = 200;
  absl::StatusOr<sdk::UploadResult> uploaded =
      sdk::Uploader(replicas_[0]->NewChannel(), o).Upload(session, simulated->capture);
  ASSERT_TRUE(uploaded.ok()) << uploaded.status();

  pb::Session where_streamed, elsewhere;
  ASSERT_TRUE(pb::SessionService::NewStub(replicas_[0]->NewChannel())
                  ->GetSession(Ctx().get(), get, &where_streamed)
                  .ok());
  ASSERT_TRUE(stale->GetSession(Ctx().get(), get, &elsewhere).ok());
  EXPECT_EQ(where_streamed.samples(), static_cast<int64_t>(simulated->capture.size()));
  ASSERT_GE(where_streamed.poses_accepted(), 6);
  EXPECT_EQ(elsewhere.samples(), where_streamed.samples());
  EXPECT_EQ(elsewhere.last_acked_seq(), where_streamed.last_acked_seq());
  EXPECT_EQ(elsewhere.poses_accepted(), where_streamed.poses_accepted());
  EXPECT_EQ(elsewhere.samples_sha256(), where_streamed.samples_sha256());

  pb::ListSessionsRequest list;
  list.set_device_id(kDevice);
  pb::ListSessionsResponse listed;
  ASSERT_TRUE(stale->ListSessions(Ctx().get(), list, &listed).ok());
  ASSERT_EQ(listed.sessions_size(), 1);
  EXPECT_EQ(listed.sessions(0).samples(), where_streamed.samples());
  EXPECT_EQ(listed.sessions(0).poses_accepted(), where_streamed.poses_accepted());
  std::printf(
      "[ stale    ] replica 2, which read the session first, shows %lld samples and "
      "%d poses, as replica 1 (%lld, %d)\n",
      static_cast<long long>(elsewhere.samples()), elsewhere.poses_accepted(),
      static_cast<long long>(where_streamed.samples()), where_streamed.poses_accepted());
}

}  // namespace
}  // namespace imucal::server
