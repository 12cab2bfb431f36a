// ParamClient and LoadOrFetch: against an in-process fake ParameterService (checksums, NOT_FOUND,
// if_not_version), an address where nothing listens (boot from the cache), and the real imucald
// when it is built.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>

#include "absl/strings/str_cat.h"
#include "client/sdk/client.h"
#include "client/sdk/grpc_status.h"
#include "client/sdk/uploader.h"
#include "core/simulator.h"
#include "formats/crc32c.h"
#include "formats/params_json.h"
#include "grpcpp/grpcpp.h"
#include "tests/client/fake_services.h"
#include "tests/client/imucald_process.h"

namespace imucal::sdk {
namespace {

namespace fs = std::filesystem;
namespace pb = imucal::v1;

pb::ParameterSet MakeSet(const std::string& device, int version) {
  core::ParamSet p;
  p.device = device;
  p.version = version;
  p.accel.bias = Eigen::Vector3d(0.1, 0.2, 0.3);
  pb::ParameterSet set;
  set.set_device_id(device);
  set.set_version(version);
  set.set_state(pb::VERSION_STATE_ACTIVE);
  set.set_json(formats::ParamSetToJson(p));
  set.set_crc32c(formats::Crc32c(set.json()));
  return set;
}

std::string Unreachable() { return absl::StrCat("127.0.0.1:", testing_util::FreeLoopbackPort()); }

class ParamClientTest : public testing::Test {
 protected:
  ParamClientTest() : server_({&service_}) {}
  void SetUp() override {
    dir_ = fs::path(testing::TempDir()) /
           absl::StrCat("imucal_param_client_test_",
                        testing::UnitTest::GetInstance()->current_test_info()->name(), "_",
                        ::getpid());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    cache_ = (dir_ / "params.cache").string();
  }
  void TearDown() override { fs::remove_all(dir_); }

  ParamClient Client() { return *ParamClient::Create(server_.address()); }

  testing_util::FakeParameterService service_;
  testing_util::FakeServer server_;
  fs::path dir_;
  std::string cache_;
};

TEST_F(ParamClientTest, FetchActiveParsesAndChecks) {
  service_.SetActive(MakeSet("robot-1", 3));
  ParamClient client = Client();
  absl::StatusOr<LoadedParams> p = client.FetchActive("robot-1", absl::Seconds(5));
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_EQ(p->stored.version, 3);
  EXPECT_EQ(p->params.accel.bias, Eigen::Vector3d(0.1, 0.2, 0.3));
}

TEST_F(ParamClientTest, ChecksumMismatchIsDataLoss) {
  pb::ParameterSet set = MakeSet("robot-1", 3);
  set.set_crc32c(set.crc32c() ^ 0x100);
  service_.SetActive(set);
  ParamClient client = Client();
  absl::Status s = client.FetchActive("robot-1", absl::Seconds(5)).status();
  EXPECT_TRUE(absl::IsDataLoss(s)) << s;
}

TEST_F(ParamClientTest, NotFoundKeepsTheServersMessage) {
  ParamClient client = Client();
  absl::Status s = client.FetchActive("robot-9", absl::Seconds(5)).status();
  EXPECT_TRUE(absl::IsNotFound(s)) << s;
  EXPECT_NE(s.message().find("robot-9 has no active parameter set"), std::string::npos) << s;
}

TEST_F(ParamClientTest, EmptyTargetIsInvalidArgument) {
  EXPECT_TRUE(absl::IsInvalidArgument(ParamClient::Create("").status()));
}

TEST_F(ParamClientTest, UnreachableServerIsUnavailableOrDeadline) {
  ParamClient client = *ParamClient::Create(Unreachable());
  absl::Status s = client.FetchActive("robot-1", absl::Milliseconds(300)).status();
  EXPECT_TRUE(IsUnreachable(s)) << s;
}

TEST_F(ParamClientTest, LoadOrFetchUpdatesTheCacheThenBootsFromIt) {
  service_.SetActive(MakeSet("robot-1", 3));
  ParamClient online = Client();
  absl::StatusOr<BootParams> boot = LoadOrFetch(online, "robot-1", cache_, absl::Seconds(5));
  ASSERT_TRUE(boot.ok()) << boot.status();
  EXPECT_FALSE(boot->from_cache);
  EXPECT_EQ(boot->loaded.stored.version, 3);
  ASSERT_TRUE(LoadParamCache(cache_).ok());

  ParamClient offline = *ParamClient::Create(Unreachable());
  boot = LoadOrFetch(offline, "robot-1", cache_, absl::Milliseconds(300));
  ASSERT_TRUE(boot.ok()) << boot.status();
  EXPECT_TRUE(boot->from_cache);
  EXPECT_EQ(boot->loaded.stored.version, 3);
  EXPECT_NE(boot->note.find("unreachable"), std::string::npos) << boot->note;
}

TEST_F(ParamClientTest, UnchangedVersionUsesTheCacheWithoutTheJson) {
  service_.SetActive(MakeSet("robot-1", 3));
  ParamClient client = Client();
  ASSERT_TRUE(LoadOrFetch(client, "robot-1", cache_, absl::Seconds(5)).ok());
  absl::StatusOr<BootParams> boot = LoadOrFetch(client, "robot-1", cache_, absl::Seconds(5));
  ASSERT_TRUE(boot.ok()) << boot.status();
  EXPECT_FALSE(boot->from_cache);
  EXPECT_NE(boot->note.find("unchanged"), std::string::npos) << boot->note;
  EXPECT_EQ(boot->loaded.params.accel.bias, Eigen::Vector3d(0.1, 0.2, 0.3));

  service_.SetActive(MakeSet("robot-1", 4));  // a new version replaces the cached one
  boot = LoadOrFetch(client, "robot-1", cache_, absl::Seconds(5));
  ASSERT_TRUE(boot.ok()) << boot.status();
  EXPECT_EQ(boot->loaded.stored.version, 4);
  EXPECT_EQ(LoadParamCache(cache_)->stored.version, 4);
}

TEST_F(ParamClientTest, CorruptCacheAndUnreachableServerNamesBoth) {
  service_.SetActive(MakeSet("robot-1", 3));
  ParamClient online = Client();
  ASSERT_TRUE(LoadOrFetch(online, "robot-1", cache_, absl::Seconds(5)).ok());
  {
    std::fstream f(cache_, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(-5, std::ios::end);
    f.put('#');
  }
  ParamClient offline = *ParamClient::Create(Unreachable());
  absl::Status s = LoadOrFetch(offline, "robot-1", cache_, absl::Milliseconds(300)).status();
  EXPECT_TRUE(IsUnreachable(s)) << s;
  EXPECT_NE(s.message().find("unreachable"), std::string::npos) << s;
  EXPECT_NE(s.message().find("checksum mismatch"), std::string::npos) << s;
}

TEST_F(ParamClientTest, CacheOfAnotherDeviceIsNotUsed) {
  service_.SetActive(MakeSet("robot-1", 3));
  ParamClient online = Client();
  ASSERT_TRUE(LoadOrFetch(online, "robot-1", cache_, absl::Seconds(5)).ok());
  ParamClient offline = *ParamClient::Create(Unreachable());
  absl::Status s = LoadOrFetch(offline, "robot-2", cache_, absl::Milliseconds(300)).status();
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find("robot-1"), std::string::npos) << s;
}

TEST_F(ParamClientTest, ServerAnswerWinsOverTheCache) {
  service_.SetActive(MakeSet("robot-1", 3));
  ParamClient client = Client();
  ASSERT_TRUE(LoadOrFetch(client, "robot-1", cache_, absl::Seconds(5)).ok());
  // The server answers NOT_FOUND for another device: no fallback to a cache.
  EXPECT_TRUE(absl::IsNotFound(LoadOrFetch(client, "robot-2", cache_, absl::Seconds(5)).status()));
}

// ---- against the real server: register, simulate, upload, solve, fetch ----

TEST(ParamClientImucaldTest, FetchesTheActiveSetAfterASolve) {
  if (!testing_util::kHaveImucald) GTEST_SKIP() << "imucald is not built yet";
  const fs::path dir =
      fs::path(testing::TempDir()) / absl::StrCat("imucal_param_client_e2e_", ::getpid());
  fs::remove_all(dir);
  fs::create_directories(dir);
  auto server = testing_util::ImucaldProcess::Start(dir.string());
  ASSERT_TRUE(server.ok()) << server.status();
  auto channel = (*server)->NewChannel();

  ParamClient client(channel);
  absl::Status none = client.FetchActive("robot-e2e", absl::Seconds(5)).status();
  EXPECT_TRUE(absl::IsNotFound(none)) << none;

  auto devices = pb::DeviceService::NewStub(channel);
  auto sessions = pb::SessionService::NewStub(channel);
  {
    grpc::ClientContext c;
    pb::RegisterDeviceRequest reg;
    reg.mutable_device()->set_id("robot-e2e");
    reg.mutable_device()->set_nominal_rate_hz(200);
    reg.mutable_device()->set_accel_unit("m/s^2");
    reg.mutable_device()->set_gyro_unit("rad/s");
    pb::Device d;
    ASSERT_TRUE(devices->RegisterDevice(&c, reg, &d).ok());
  }
  pb::Session session;
  {
    grpc::ClientContext c;
    pb::CreateSessionRequest req;
    req.set_device_id("robot-e2e");
    req.set_protocol(pb::PROTOCOL_SIX_FACE);
    ASSERT_TRUE(sessions->CreateSession(&c, req, &session).ok());
  }
  core::SimOptions sim;
  sim.seed = 3;
  auto capture = core::Simulate(sim);
  ASSERT_TRUE(capture.ok());
  Uploader uploader(channel);
  ASSERT_TRUE(uploader.Upload(session.id(), capture->capture).ok());
  pb::SolveJob job;
  {
    grpc::ClientContext c;
    pb::SolveSessionRequest req;
    req.set_session_id(session.id());
    grpc::Status s = sessions->SolveSession(&c, req, &job);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  // Wait for the job through the session's event stream (bounded by the deadline).
  {
    grpc::ClientContext c;
    c.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    pb::WatchSessionRequest req;
    req.set_session_id(session.id());
    auto watch = sessions->WatchSession(&c, req);
    pb::SessionEvent event;
    while (watch->Read(&event)) {
      if (event.has_solve() && event.solve().id() == job.id() &&
          (event.solve().state() == pb::JOB_STATE_DONE ||
           event.solve().state() == pb::JOB_STATE_FAILED)) {
        job = event.solve();
        break;
      }
    }
    c.TryCancel();
  }
  ASSERT_EQ(job.state(), pb::JOB_STATE_DONE) << job.error();
  if (!job.activated()) {
    // The server's gates decide what activates by itself (e.g. only a pass):
    // a technician's promotion makes the version active either way.
    auto params = pb::ParameterService::NewStub(channel);
    grpc::ClientContext c;
    pb::PromoteRequest req;
    req.set_device_id("robot-e2e");
    req.set_version(job.version());
    req.set_reason("test");
    pb::ParameterSet promoted;
    grpc::Status s = params->Promote(&c, req, &promoted);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }
  absl::StatusOr<LoadedParams> p = client.FetchActive("robot-e2e", absl::Seconds(5));
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_EQ(p->stored.version, job.version());
  const std::string cache = (dir / "params.cache").string();
  absl::StatusOr<BootParams> boot = LoadOrFetch(client, "robot-e2e", cache, absl::Seconds(5));
  ASSERT_TRUE(boot.ok()) << boot.status();
  EXPECT_TRUE(LoadParamCache(cache).ok());
  server->reset();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace imucal::sdk
