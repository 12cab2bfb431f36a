// ParameterService.UploadParameters end to end (issue 27): an in-process imucald on a loopback
// port, on SQLite and on PostgreSQL. A parameter set with a learnt dynamic gyro block is uploaded
// as a new version, activated by the solves' rule, fetched by the robot SDK (and its cache) and
// applied by sdk::Stream equal to the offline application; the refusals name the field.
#include <chrono>
#include <cmath>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "client/sdk/client.h"
#include "client/sdk/corrector.h"
#include "core/correction.h"
#include "core/dynamic_gyro.h"
#include "core/dynamic_gyro_state.h"
#include "core/params.h"
#include "formats/params_json.h"
#include "grpcpp/grpcpp.h"
#include "gtest/gtest.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/server.h"
#include "tests/pg_test_cluster.h"
#include "tests/test_dir.h"

namespace imucal::server {
namespace {

constexpr char kDevice[] = "robot-27";
constexpr double kRateHz = 200.0;
constexpr uint64_t kSeed = 2701;

core::ParamSet LearntParams(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(-0.01, 0.01);
  core::ParamSet p;
  p.device = kDevice;
  p.gyro.bias = Eigen::Vector3d(u(rng), u(rng), u(rng));
  p.gyro.accel_coupling = Eigen::Matrix3d::Constant(2e-4);
  p.gyro_calibrated = true;
  p.quality_accel_rms_m_s2 = 0.004;
  p.software = "imucal learn (test)";
  core::DynamicGyro b;
  b.rate_hz = kRateHz;
  b.delay_s = 0.0026;
  b.odd_rate = Eigen::Vector3d(1e-3, -2e-3, 5e-4);
  b.taps = 29;
  b.dilation = 16;
  for (int i = 0; i < 18 * b.taps; ++i) b.weights.push_back(u(rng));
  b.envelope.max_abs_rate_rad_s = Eigen::Vector3d::Constant(8.0);
  b.envelope.max_abs_accel_m_s2 = Eigen::Vector3d::Constant(40.0);
  b.training = {{"room1", "aa11", 140.0, 1.7, 0.6}, {"room3", "bb22", 120.0, 1.5, 0.8}};
  b.gate_reason = "held out: learnt 0.7 deg against static 1.6 deg";
  p.dynamic_gyro = b;
  return p;
}

class UploadTest : public testing::TestWithParam<bool> {
 protected:
  void SetUp() override {
    options_.listen = "127.0.0.1:0";
    options_.security.insecure = true;  // plaintext on loopback: auth_matrix_test covers roles
    if (GetParam()) {
      absl::StatusOr<std::unique_ptr<testing_util::PgTestDatabase>> db =
          testing_util::PgTestDatabase::Create();
      ASSERT_TRUE(db.ok()) << db.status();
      pg_ = *std::move(db);
      options_.db_path = pg_->url();
    } else {
      options_.db_path = dir_.File("imucal.db");
    }
    absl::StatusOr<std::unique_ptr<Server>> server = Server::Start(options_);
    ASSERT_TRUE(server.ok()) << server.status();
    server_ = *std::move(server);
    channel_ = grpc::CreateChannel(server_->address(), grpc::InsecureChannelCredentials());
    params_ = v1::ParameterService::NewStub(channel_);
    v1::RegisterDeviceRequest req;
    req.mutable_device()->set_id(kDevice);
    req.mutable_device()->set_sensor_model("bmi160");
    req.mutable_device()->set_nominal_rate_hz(kRateHz);
    req.mutable_device()->set_accel_unit("m/s^2");
    req.mutable_device()->set_gyro_unit("rad/s");
    v1::Device out;
    grpc::Status s = v1::DeviceService::NewStub(channel_)->RegisterDevice(Ctx().get(), req, &out);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }

  static std::unique_ptr<grpc::ClientContext> Ctx() {
    auto ctx = std::make_unique<grpc::ClientContext>();
    ctx->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(20));
    return ctx;
  }

  grpc::Status Upload(const std::string& json, v1::UploadParametersResponse* out,
                      const std::string& device = kDevice) {
    v1::UploadParametersRequest req;
    req.set_device_id(device);
    req.set_json(json);
    req.set_reason("learnt on rooms 1/3/5");
    return params_->UploadParameters(Ctx().get(), req, out);
  }

  testing_util::TestDir dir_{"upload_test"};  // first: outlives the server that uses it
  std::unique_ptr<testing_util::PgTestDatabase> pg_;
  ServerOptions options_;
  std::unique_ptr<Server> server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::ParameterService::Stub> params_;
};

// The robot's side: the SDK fetches the active set, boots from it (writing its cache), and its
// Stream applies the block as the offline loop does.
void ExpectRobotAppliesIt(const std::string& address, const core::ParamSet& uploaded,
                          const std::string& cache_path) {
  absl::StatusOr<sdk::ParamClient> client = sdk::ParamClient::Create(address);
  ASSERT_TRUE(client.ok()) << client.status();
  absl::StatusOr<sdk::BootParams> boot =
      sdk::LoadOrFetch(*client, kDevice, cache_path, absl::Seconds(10));
  ASSERT_TRUE(boot.ok()) << boot.status();
  EXPECT_FALSE(boot->from_cache);
  const core::ParamSet& fetched = boot->loaded.params;
  ASSERT_TRUE(fetched.dynamic_gyro.has_value());
  EXPECT_EQ(fetched.dynamic_gyro->weights, uploaded.dynamic_gyro->weights);
  EXPECT_EQ(fetched.dynamic_gyro->training.size(), 2u);
  absl::StatusOr<sdk::Corrector> corrector = sdk::Corrector::Create(fetched);
  ASSERT_TRUE(corrector.ok()) << corrector.status();
  absl::StatusOr<sdk::Stream> stream = corrector->NewStream(kRateHz);
  ASSERT_TRUE(stream.ok()) << stream.status();
  // Offline, from what was uploaded (not what was fetched): the block survived the trip.
  const core::SampleCorrection offline(uploaded, 0.0);
  core::DynamicGyroState state(*uploaded.dynamic_gyro);
  std::mt19937_64 rng(kSeed);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  double worst = 0.0;
  for (int k = 0; k < 3000; ++k) {
    sdk::RawSample raw;
    raw.t_s = k / kRateHz;
    for (int i = 0; i < 3; ++i) {
      raw.accel[i] = 3.0 * u(rng);
      raw.gyro[i] = u(rng);
    }
    sdk::CalibratedSample out;
    stream->Apply(raw, &out);
    const core::CorrectedSample c =
        offline.Apply(Eigen::Vector3d(raw.accel[0], raw.accel[1], raw.accel[2]),
                      Eigen::Vector3d(raw.gyro[0], raw.gyro[1], raw.gyro[2]), raw.temp_c, raw.t_s);
    Eigen::Vector3d w;
    state.Step(c.gyro_rad_s, c.accel_m_s2, &w);
    for (int i = 0; i < 3; ++i) worst = std::max(worst, std::abs(out.gyro_rad_s[i] - w(i)));
  }
  EXPECT_LE(worst, 1e-12);
}

TEST_P(UploadTest, ALearntBlockIsStoredActivatedFetchedAndApplied) {
  std::mt19937_64 rng(kSeed);
  const core::ParamSet learnt = LearntParams(rng);
  v1::UploadParametersResponse out;
  grpc::Status s = Upload(formats::ParamSetToJson(learnt), &out);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(out.version().version(), 1);
  EXPECT_EQ(out.version().state(), v1::VERSION_STATE_ACTIVE);
  EXPECT_EQ(out.version().verdict_kind(), v1::VERDICT_PASS);
  EXPECT_TRUE(out.reasons().empty());
  // Stored as read, with the number assigned.
  core::ParamSet numbered = learnt;
  numbered.version = 1;
  EXPECT_EQ(out.version().json(), formats::ParamSetToJson(numbered));

  v1::GetActiveParametersRequest active;
  active.set_device_id(kDevice);
  v1::ParameterSet fetched;
  s = params_->GetActiveParameters(Ctx().get(), active, &fetched);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(fetched.version(), 1);
  EXPECT_EQ(fetched.json(), out.version().json());
  ASSERT_NO_FATAL_FAILURE(
      ExpectRobotAppliesIt(server_->address(), learnt, dir_.File("params.cache")));

  // The robot's cache keeps the block: with the server gone, it boots from it.
  server_->Shutdown();
  absl::StatusOr<sdk::ParamClient> client = sdk::ParamClient::Create(server_->address());
  ASSERT_TRUE(client.ok());
  absl::StatusOr<sdk::BootParams> boot =
      sdk::LoadOrFetch(*client, kDevice, dir_.File("params.cache"), absl::Milliseconds(300));
  ASSERT_TRUE(boot.ok()) << boot.status();
  EXPECT_TRUE(boot->from_cache);
  ASSERT_TRUE(boot->loaded.params.dynamic_gyro.has_value());
  EXPECT_EQ(boot->loaded.params.dynamic_gyro->weights, learnt.dynamic_gyro->weights);
}

TEST_P(UploadTest, ABlockWithoutHeldOutProofIsACandidateWithTheReason) {
  std::mt19937_64 rng(kSeed);
  const core::ParamSet learnt = LearntParams(rng);
  v1::UploadParametersResponse first;
  ASSERT_TRUE(Upload(formats::ParamSetToJson(learnt), &first).ok());
  core::ParamSet unproven = learnt;
  for (core::DynamicGyroRecording& r : unproven.dynamic_gyro->training) {
    r.aoe_static_deg = std::nan("");
  }
  v1::UploadParametersResponse out;
  grpc::Status s = Upload(formats::ParamSetToJson(unproven), &out);
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(out.version().version(), 2);
  EXPECT_EQ(out.version().state(), v1::VERSION_STATE_CANDIDATE);
  EXPECT_EQ(out.version().verdict_kind(), v1::VERDICT_FAIL);
  ASSERT_FALSE(out.reasons().empty());
  EXPECT_EQ(out.reasons(0).rfind("dynamic_gyro: no recording it was held out of", 0), 0u)
      << out.reasons(0);
  // A block worse than the static model held out: fail too.
  core::ParamSet worse = learnt;
  worse.dynamic_gyro->training[0].aoe_learnt_deg = 3.0;
  ASSERT_TRUE(Upload(formats::ParamSetToJson(worse), &out).ok());
  EXPECT_EQ(out.version().state(), v1::VERSION_STATE_CANDIDATE);
  // learn's own gate (core::motion::JudgeHeldOut), with its figures.
  EXPECT_EQ(out.reasons(0).rfind("dynamic_gyro: refused: ", 0), 0u) << out.reasons(0);
  EXPECT_NE(out.reasons(0).find("leave-one-recording-out AOE"), std::string::npos);
  // The active version is still the proven one; a technician may still promote.
  v1::GetActiveParametersRequest active;
  active.set_device_id(kDevice);
  v1::ParameterSet fetched;
  ASSERT_TRUE(params_->GetActiveParameters(Ctx().get(), active, &fetched).ok());
  EXPECT_EQ(fetched.version(), 1);
  v1::PromoteRequest promote;
  promote.set_device_id(kDevice);
  promote.set_version(2);
  ASSERT_TRUE(params_->Promote(Ctx().get(), promote, &fetched).ok());
  EXPECT_EQ(fetched.state(), v1::VERSION_STATE_ACTIVE);
}

TEST_P(UploadTest, RefusalsNameTheField) {
  std::mt19937_64 rng(kSeed);
  const core::ParamSet learnt = LearntParams(rng);
  struct Case {
    std::string json;
    std::string device;
    grpc::StatusCode code;
    std::string message;  // its start
  };
  core::ParamSet other = learnt;
  other.device = "robot-99";
  core::ParamSet in_g = learnt;
  in_g.accel_unit = core::AccelUnit::kG;
  core::ParamSet in_deg = learnt;
  in_deg.gyro_unit = core::GyroUnit::kDegPerSecond;
  core::ParamSet short_weights = learnt;
  short_weights.dynamic_gyro->weights.pop_back();
  const Case cases[] = {
      {formats::ParamSetToJson(other), kDevice, grpc::StatusCode::INVALID_ARGUMENT,
       "device: \"robot-99\" but the upload is for device robot-27"},
      {formats::ParamSetToJson(in_g), kDevice, grpc::StatusCode::INVALID_ARGUMENT,
       "accel.input_unit: \"g\" but device robot-27 delivers \"m/s^2\""},
      {formats::ParamSetToJson(in_deg), kDevice, grpc::StatusCode::INVALID_ARGUMENT,
       "gyro.input_unit: \"deg/s\" but device robot-27 delivers \"rad/s\""},
      {formats::ParamSetToJson(short_weights), kDevice, grpc::StatusCode::INVALID_ARGUMENT,
       "dynamic_gyro.weights: 521 values but taps*18 = 522 expected"},
      {"{\"format\": \"imucal-params v1\"}", kDevice, grpc::StatusCode::INVALID_ARGUMENT,
       "accel: missing"},
      {"", kDevice, grpc::StatusCode::INVALID_ARGUMENT, "json: required"},
      {formats::ParamSetToJson(learnt), "robot-unknown", grpc::StatusCode::NOT_FOUND, ""},
  };
  for (const Case& c : cases) {
    v1::UploadParametersResponse out;
    grpc::Status s = Upload(c.json, &out, c.device);
    EXPECT_EQ(s.error_code(), c.code) << c.message << ": " << s.error_message();
    EXPECT_EQ(s.error_message().rfind(c.message, 0), 0u) << s.error_message();
  }
  // Nothing was stored.
  v1::ListVersionsRequest list;
  list.set_device_id(kDevice);
  v1::ListVersionsResponse versions;
  ASSERT_TRUE(params_->ListVersions(Ctx().get(), list, &versions).ok());
  EXPECT_EQ(versions.versions_size(), 0);
}

// A static document made offline (no block) keeps its bytes, and is judged by the same gates:
// without a residual figure it is incomplete, so a candidate.
TEST_P(UploadTest, AStaticDocumentIsJudgedByTheSameGates) {
  core::ParamSet p;
  p.device = "";  // not stated: taken as the request's
  p.gyro_calibrated = true;
  p.quality_accel_rms_m_s2 = std::nan("");
  v1::UploadParametersResponse out;
  ASSERT_TRUE(Upload(formats::ParamSetToJson(p), &out).ok());
  EXPECT_EQ(out.version().state(), v1::VERSION_STATE_CANDIDATE);
  EXPECT_EQ(out.version().verdict_kind(), v1::VERDICT_WARN);
  core::ParamSet stored = p;
  stored.device = kDevice;
  stored.version = 1;
  EXPECT_EQ(out.version().json(), formats::ParamSetToJson(stored));
  EXPECT_EQ(out.version().json().find("dynamic_gyro"), std::string::npos);
}

INSTANTIATE_TEST_SUITE_P(Backends, UploadTest, testing::Values(false, true),
                         [](const testing::TestParamInfo<bool>& info) {
                           return info.param ? "Postgres" : "Sqlite";
                         });

}  // namespace
}  // namespace imucal::server
