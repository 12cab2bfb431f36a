// Who may do what, through the real server: an in-process imucald serving TLS with certificates
// made at test time (the openssl CLI, into a temp dir), tokens made through AdminService, and
// every RPC of the API called by every kind of caller. The expected outcome of each cell comes
// from the one table in server/auth.cc (RpcRules()); the test prints the matrix it observed.
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "client/cli/commands.h"
#include "client/cli/server_common.h"
#include "client/sdk/client.h"
#include "core/capture.h"
#include "grpcpp/generic/generic_stub.h"
#include "grpcpp/grpcpp.h"
#include "gtest/gtest.h"
#include "importers/imucal_csv.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/auth.h"
#include "server/server.h"
#include "server/tls.h"
#include "storage/store.h"

namespace imucal::server {
namespace {

namespace fs = std::filesystem;
using grpc::StatusCode;

constexpr char kDeviceA[] = "robot-A";
constexpr char kDeviceB[] = "robot-B";

// A CA for the server's certificate, another for robots' client certificates, and one
// certificate per robot (common name = device id), all valid for two days.
constexpr char kMakeCertsScript[] = R"sh(
set -e
cd "$1"
ca() {
  openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days 2 \
    -keyout "$1.key" -out "$1.pem" -subj "/CN=$2" 2>/dev/null
}
leaf() {
  openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes \
    -keyout "$1.key" -out "$1.csr" -subj "/CN=$3" 2>/dev/null
  printf '%b' "$4" > "$1.ext"
  openssl x509 -req -in "$1.csr" -CA "$2.pem" -CAkey "$2.key" -CAcreateserial -days 2 \
    -out "$1.pem" -extfile "$1.ext" 2>/dev/null
}
ca ca "imucal test CA"
ca robot-ca "imucal test robot CA"
ca other-ca "some other CA"
leaf server ca localhost "subjectAltName=DNS:localhost,IP:127.0.0.1\nextendedKeyUsage=serverAuth\n"
leaf robot-A robot-ca robot-A "extendedKeyUsage=clientAuth\n"
leaf robot-B robot-ca robot-B "extendedKeyUsage=clientAuth\n"
)sh";

std::string ReadText(const fs::path& path) {
  std::ifstream in(path);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

std::string Trimmed(std::string s) {
  while (!s.empty() && (s.back() == '\n' || s.back() == ' ')) s.pop_back();
  return s;
}

// The kinds of caller in the matrix's columns.
enum class Who {
  kNoToken,
  kBadToken,    // well-formed, but no such token
  kRevoked,     // a technician token, revoked
  kRobotA,      // robot token bound to robot-A
  kRobotBForA,  // robot token bound to robot-B, reaching for robot-A's data
  kTechnician,
  kAdmin,
  kCertA,      // robot-A's client certificate, no token
  kCertBForA,  // robot-B's client certificate, reaching for robot-A's data
};

struct Column {
  Who who;
  std::string name;
  std::shared_ptr<grpc::Channel> channel;
  std::string audit_actor;  // what the audit row of its denials names
};

bool Allowed(Who who, const RpcRule& rule) {
  switch (who) {
    case Who::kRobotA:
    case Who::kCertA:
      return rule.robot;
    case Who::kTechnician:
      return rule.technician;
    case Who::kAdmin:
      return rule.admin;
    default:
      return false;  // unauthenticated, or a robot reaching for another device
  }
}

StatusCode DenialCode(Who who) {
  return who == Who::kNoToken || who == Who::kBadToken || who == Who::kRevoked
             ? StatusCode::UNAUTHENTICATED
             : StatusCode::PERMISSION_DENIED;
}

bool IsDenial(StatusCode code) {
  return code == StatusCode::UNAUTHENTICATED || code == StatusCode::PERMISSION_DENIED;
}

std::string CodeName(StatusCode code) {
  switch (code) {
    case StatusCode::OK:
      return "OK";
    case StatusCode::UNAUTHENTICATED:
      return "UNAUTH";
    case StatusCode::PERMISSION_DENIED:
      return "DENIED";
    case StatusCode::NOT_FOUND:
      return "NOT_FOUND";
    case StatusCode::INVALID_ARGUMENT:
      return "INVALID";
    case StatusCode::FAILED_PRECONDITION:
      return "PRECOND";
    case StatusCode::ALREADY_EXISTS:
      return "EXISTS";
    case StatusCode::RESOURCE_EXHAUSTED:
      return "EXHAUSTED";
    case StatusCode::UNAVAILABLE:
      return "UNAVAIL";
    default:
      return std::to_string(static_cast<int>(code));
  }
}

std::unique_ptr<grpc::ClientContext> Ctx() {
  auto c = std::make_unique<grpc::ClientContext>();
  c->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  return c;
}

class AuthTest : public testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::path(testing::TempDir()) /
           ("auth_test_" + std::to_string(::getpid()) + "_" +
            testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    const fs::path script = dir_ / "make_certs.sh";
    std::ofstream(script) << kMakeCertsScript;
    const std::string command = "sh '" + script.string() + "' '" + dir_.string() + "'";
    ASSERT_EQ(std::system(command.c_str()), 0) << "openssl could not make the certificates";
    options_.listen = "127.0.0.1:0";
    options_.db_path = (dir_ / "imucal.db").string();
    options_.security.tls_cert_path = (dir_ / "server.pem").string();
    options_.security.tls_key_path = (dir_ / "server.key").string();
    options_.security.client_ca_path = (dir_ / "robot-ca.pem").string();
  }
  void TearDown() override {
    server_.reset();
    fs::remove_all(dir_);
  }

  void StartServer() {
    absl::StatusOr<std::unique_ptr<Server>> server = Server::Start(options_);
    ASSERT_TRUE(server.ok()) << server.status();
    server_ = *std::move(server);
  }

  std::string Pem(const std::string& name) { return ReadText(dir_ / (name + ".pem")); }

  // A TLS channel trusting the test CA, with a token and/or a client certificate.
  std::shared_ptr<grpc::Channel> Channel(const std::string& token, const std::string& client = "") {
    sdk::ClientOptions o;
    o.ca_cert_pem = Pem("ca");
    o.bearer_token = token;
    if (!client.empty()) {
      o.client_cert_pem = Pem(client);
      o.client_key_pem = ReadText(dir_ / (client + ".key"));
    }
    EXPECT_TRUE(sdk::ValidateClientOptions(o).ok());
    return sdk::MakeChannel(server_->address(), o);
  }

  std::string AdminSecret() {
    EXPECT_FALSE(server_->admin_token_written().empty());
    return Trimmed(ReadText(server_->admin_token_written()));
  }

  v1::CreateTokenResponse CreateToken(const std::string& admin, v1::Role role,
                                      const std::string& device, const std::string& label) {
    auto stub = v1::AdminService::NewStub(Channel(admin));
    v1::CreateTokenRequest req;
    req.set_role(role);
    req.set_device_id(device);
    req.set_label(label);
    v1::CreateTokenResponse out;
    grpc::Status s = stub->CreateToken(Ctx().get(), req, &out);
    EXPECT_TRUE(s.ok()) << s.error_message();
    return out;
  }

  void Revoke(const std::string& admin, int64_t id) {
    auto stub = v1::AdminService::NewStub(Channel(admin));
    v1::RevokeTokenRequest req;
    req.set_id(id);
    v1::Token out;
    grpc::Status s = stub->RevokeToken(Ctx().get(), req, &out);
    ASSERT_TRUE(s.ok()) << s.error_message();
  }

  std::vector<storage::AuditEntry> Denials() {
    auto store = storage::Store::Open(options_.db_path);
    EXPECT_TRUE(store.ok()) << store.status();
    storage::AuditQuery q;
    q.limit = 100000;
    auto all = (*store)->ListAudit(q);
    EXPECT_TRUE(all.ok()) << all.status();
    std::vector<storage::AuditEntry> out;
    for (const storage::AuditEntry& e : *all)
      if (e.action == "auth.deny") out.push_back(e);
    return out;
  }

  fs::path dir_;
  ServerOptions options_;
  std::unique_ptr<Server> server_;
};

// robot-A and robot-B registered, an open session of robot-A, an active version of robot-A.
struct Fleet {
  std::string session_a;
  storage::Device device_a;
};

Fleet MakeFleet(const std::string& db_path) {
  Fleet fleet;
  auto store = storage::Store::Open(db_path);
  EXPECT_TRUE(store.ok()) << store.status();
  for (const char* id : {kDeviceA, kDeviceB}) {
    storage::Device d;
    d.id = id;
    d.sensor_model = "test IMU";
    d.nominal_rate_hz = 100;
    d.accel_unit = "m/s^2";
    d.gyro_unit = "rad/s";
    EXPECT_TRUE((*store)->CreateDevice(d, "test").ok());
    if (d.id == kDeviceA) fleet.device_a = d;
  }
  storage::Session s;
  s.device_id = kDeviceA;
  s.protocol = "six-face";
  s.gravity_m_s2 = 9.80665;
  auto session = (*store)->CreateSession(s, "test");
  EXPECT_TRUE(session.ok()) << session.status();
  fleet.session_a = session->id;
  storage::ParamVersion v;
  v.device_id = kDeviceA;
  v.params_json = "{\"format\": \"imucal-params v1\"}";
  v.report_json = "{}";
  v.verdict = storage::Verdict::kPass;
  v.provenance = "test";
  v.state = storage::VersionState::kActive;
  EXPECT_TRUE((*store)->AddVersion(v, "test").ok());
  return fleet;
}

// One call of `rpc` on `channel`, aimed at robot-A's data; the status it ended with.
grpc::Status Call(Rpc rpc, const std::shared_ptr<grpc::Channel>& channel, const Fleet& fleet,
                  int64_t spare_token_id) {
  auto devices = v1::DeviceService::NewStub(channel);
  auto sessions = v1::SessionService::NewStub(channel);
  auto params = v1::ParameterService::NewStub(channel);
  auto admin = v1::AdminService::NewStub(channel);
  switch (rpc) {
    case Rpc::kRegisterDevice: {
      v1::RegisterDeviceRequest r;  // the same metadata again: a no-op when allowed
      v1::Device* d = r.mutable_device();
      d->set_id(fleet.device_a.id);
      d->set_sensor_model(fleet.device_a.sensor_model);
      d->set_nominal_rate_hz(fleet.device_a.nominal_rate_hz);
      d->set_accel_unit(fleet.device_a.accel_unit);
      d->set_gyro_unit(fleet.device_a.gyro_unit);
      v1::Device out;
      return devices->RegisterDevice(Ctx().get(), r, &out);
    }
    case Rpc::kGetDevice: {
      v1::GetDeviceRequest r;
      r.set_device_id(kDeviceA);
      v1::Device out;
      return devices->GetDevice(Ctx().get(), r, &out);
    }
    case Rpc::kListDevices: {
      v1::ListDevicesResponse out;
      return devices->ListDevices(Ctx().get(), v1::ListDevicesRequest(), &out);
    }
    case Rpc::kCreateSession: {
      v1::CreateSessionRequest r;
      r.set_device_id(kDeviceA);
      v1::Session out;
      return sessions->CreateSession(Ctx().get(), r, &out);
    }
    case Rpc::kGetSession: {
      v1::GetSessionRequest r;
      r.set_session_id(fleet.session_a);
      v1::Session out;
      return sessions->GetSession(Ctx().get(), r, &out);
    }
    case Rpc::kListSessions: {
      v1::ListSessionsRequest r;
      r.set_device_id(kDeviceA);
      v1::ListSessionsResponse out;
      return sessions->ListSessions(Ctx().get(), r, &out);
    }
    case Rpc::kCancelSession: {
      v1::CancelSessionRequest r;
      r.set_session_id(fleet.session_a);
      v1::Session out;
      return sessions->CancelSession(Ctx().get(), r, &out);
    }
    case Rpc::kStreamSamples: {
      auto ctx = Ctx();
      auto stream = sessions->StreamSamples(ctx.get());
      v1::SampleBatch b;
      b.set_session_id(fleet.session_a);
      b.set_seq(1);
      b.add_t_s(0.0);
      for (double x : {0.0, 0.0, 9.81}) b.add_accel(x);
      for (double x : {0.0, 0.0, 0.0}) b.add_gyro(x);
      stream->Write(b);
      stream->WritesDone();
      v1::SampleAck ack;
      while (stream->Read(&ack)) {
      }
      return stream->Finish();
    }
    case Rpc::kWatchSession: {
      // Allowed: the snapshot arrives, then the test hangs up.
      auto ctx = Ctx();
      v1::WatchSessionRequest r;
      r.set_session_id(fleet.session_a);
      auto reader = sessions->WatchSession(ctx.get(), r);
      v1::SessionEvent event;
      if (reader->Read(&event)) {
        ctx->TryCancel();
        reader->Finish().ok();
        return grpc::Status::OK;
      }
      return reader->Finish();
    }
    case Rpc::kListPoses: {
      v1::ListPosesRequest r;
      r.set_session_id(fleet.session_a);
      v1::ListPosesResponse out;
      return sessions->ListPoses(Ctx().get(), r, &out);
    }
    case Rpc::kSolveSession: {
      v1::SolveSessionRequest r;
      r.set_session_id(fleet.session_a);
      v1::SolveJob out;
      return sessions->SolveSession(Ctx().get(), r, &out);
    }
    case Rpc::kGetSolveJob: {
      v1::GetSolveJobRequest r;
      r.set_job_id("solve-999");
      v1::SolveJob out;
      return sessions->GetSolveJob(Ctx().get(), r, &out);
    }
    case Rpc::kGetReport: {
      v1::GetReportRequest r;
      r.set_session_id(fleet.session_a);
      v1::Report out;
      return sessions->GetReport(Ctx().get(), r, &out);
    }
    case Rpc::kReadSamples: {
      // Allowed: the session holds no samples, so the stream ends OK with none.
      auto ctx = Ctx();
      v1::ReadSamplesRequest r;
      r.set_session_id(fleet.session_a);
      auto reader = sessions->ReadSamples(ctx.get(), r);
      v1::SampleBatch batch;
      while (reader->Read(&batch)) {
      }
      return reader->Finish();
    }
    case Rpc::kGetActiveParameters: {
      v1::GetActiveParametersRequest r;
      r.set_device_id(kDeviceA);
      v1::ParameterSet out;
      return params->GetActiveParameters(Ctx().get(), r, &out);
    }
    case Rpc::kGetParameters: {
      v1::GetParametersRequest r;
      r.set_device_id(kDeviceA);
      r.set_version(1);
      v1::ParameterSet out;
      return params->GetParameters(Ctx().get(), r, &out);
    }
    case Rpc::kListVersions: {
      v1::ListVersionsRequest r;
      r.set_device_id(kDeviceA);
      v1::ListVersionsResponse out;
      return params->ListVersions(Ctx().get(), r, &out);
    }
    case Rpc::kPromote: {
      v1::PromoteRequest r;
      r.set_device_id(kDeviceA);
      r.set_version(1);
      v1::ParameterSet out;
      return params->Promote(Ctx().get(), r, &out);
    }
    case Rpc::kRollback: {
      v1::RollbackRequest r;
      r.set_device_id(kDeviceA);
      r.set_to_version(1);
      v1::ParameterSet out;
      return params->Rollback(Ctx().get(), r, &out);
    }
    case Rpc::kExport: {
      v1::ExportRequest r;
      r.set_device_id(kDeviceA);
      r.set_format("json");
      v1::ExportResponse out;
      return params->Export(Ctx().get(), r, &out);
    }
    case Rpc::kUploadParameters: {
      // Not a parameter set: the matrix checks who may call, not what the call does.
      v1::UploadParametersRequest r;
      r.set_device_id(kDeviceA);
      r.set_json("{}");
      v1::UploadParametersResponse out;
      return params->UploadParameters(Ctx().get(), r, &out);
    }
    case Rpc::kCreateToken: {
      v1::CreateTokenRequest r;
      r.set_role(v1::ROLE_TECHNICIAN);
      r.set_label("made by the matrix");
      v1::CreateTokenResponse out;
      return admin->CreateToken(Ctx().get(), r, &out);
    }
    case Rpc::kListTokens: {
      v1::ListTokensResponse out;
      return admin->ListTokens(Ctx().get(), v1::ListTokensRequest(), &out);
    }
    case Rpc::kRevokeToken: {
      v1::RevokeTokenRequest r;
      r.set_id(spare_token_id);
      v1::Token out;
      return admin->RevokeToken(Ctx().get(), r, &out);
    }
    case Rpc::kCount:
      break;
  }
  return grpc::Status(StatusCode::INTERNAL, "no call for this RPC in the test");
}

TEST(AuthRules, TheTableCoversEveryRpcOfTheApi) {
  absl::Status s = CheckRulesCoverServices();
  EXPECT_TRUE(s.ok()) << s;
  // Admin may do everything a technician may; a robot never more than a technician, except
  // registering itself.
  for (const RpcRule& rule : RpcRules()) {
    EXPECT_TRUE(!rule.technician || rule.admin) << rule.method;
    EXPECT_TRUE(!rule.robot || rule.technician || rule.rpc == Rpc::kRegisterDevice) << rule.method;
  }
}

TEST_F(AuthTest, EveryRpcTimesEveryCallerGetsWhatTheTableSays) {
  const Fleet fleet = MakeFleet(options_.db_path);
  options_.deny_audit.burst = 100000;  // one audit row per denied cell, none coalesced
  StartServer();
  const std::string admin = AdminSecret();
  const v1::CreateTokenResponse robot_a = CreateToken(admin, v1::ROLE_ROBOT, kDeviceA, "A");
  const v1::CreateTokenResponse robot_b = CreateToken(admin, v1::ROLE_ROBOT, kDeviceB, "B");
  const v1::CreateTokenResponse tech = CreateToken(admin, v1::ROLE_TECHNICIAN, "", "bench 1");
  const v1::CreateTokenResponse revoked = CreateToken(admin, v1::ROLE_TECHNICIAN, "", "gone");
  const v1::CreateTokenResponse spare = CreateToken(admin, v1::ROLE_TECHNICIAN, "", "spare");
  Revoke(admin, revoked.token().id());
  const std::string bad = "imucal_0123456789abcdef0123456789abcdef0123456789abcdef0123456789abcdef";
  auto token_actor = [](const v1::CreateTokenResponse& t) {
    return "token " + std::to_string(t.token().id());
  };
  std::vector<Column> columns = {
      {Who::kNoToken, "no token", Channel(""), "anonymous"},
      {Who::kBadToken, "bad token", Channel(bad), "unknown token"},
      {Who::kRevoked, "revoked", Channel(revoked.secret()),
       "revoked token " + std::to_string(revoked.token().id())},
      {Who::kRobotA, "robot A", Channel(robot_a.secret()), token_actor(robot_a)},
      {Who::kRobotBForA, "robot B->A", Channel(robot_b.secret()), token_actor(robot_b)},
      {Who::kTechnician, "technician", Channel(tech.secret()), token_actor(tech)},
      {Who::kAdmin, "admin", Channel(admin), "admin (token 1"},
      {Who::kCertA, "cert A", Channel("", "robot-A"), "robot robot-A (client certificate)"},
      {Who::kCertBForA, "cert B->A", Channel("", "robot-B"), "robot robot-B (client certificate)"},
  };

  struct Denied {
    std::string method, code, actor;
  };
  std::vector<Denied> denied;
  std::string table = "RPC                  ";
  for (const Column& c : columns) table += " | " + c.name + std::string(10 - c.name.size(), ' ');
  table += "\n";
  int cells = 0;
  for (const RpcRule& rule : RpcRules()) {
    std::string row(rule.method.substr(rule.method.rfind('/') + 1));
    row.resize(21, ' ');
    for (const Column& c : columns) {
      const grpc::Status status = Call(rule.rpc, c.channel, fleet, spare.token().id());
      ++cells;
      const bool allowed = Allowed(c.who, rule);
      if (allowed) {
        EXPECT_FALSE(IsDenial(status.error_code()))
            << rule.method << " by " << c.name << ": " << status.error_message();
      } else {
        EXPECT_EQ(status.error_code(), DenialCode(c.who))
            << rule.method << " by " << c.name << ": " << status.error_message();
        denied.push_back({std::string(rule.method),
                          DenialCode(c.who) == StatusCode::UNAUTHENTICATED ? "UNAUTHENTICATED"
                                                                           : "PERMISSION_DENIED",
                          c.audit_actor});
      }
      std::string cell = CodeName(status.error_code());
      cell.resize(10, ' ');
      row += " | " + cell;
    }
    table += row + "\n";
  }
  EXPECT_EQ(cells, static_cast<int>(Rpc::kCount) * static_cast<int>(columns.size()));
  std::printf(
      "RPC x caller matrix (%d calls; OK or a non-auth error = allowed; UNAUTH / DENIED "
      "= refused):\n%s",
      cells, table.c_str());

  // Every refused call left its row in the audit log: the method, the code and the caller.
  server_.reset();
  const std::vector<storage::AuditEntry> rows = Denials();
  for (const Denied& d : denied) {
    bool found = false;
    for (const storage::AuditEntry& e : rows) {
      found |= e.target == "rpc:" + d.method && e.detail.rfind(d.code, 0) == 0 &&
               e.actor.find(d.actor) != std::string::npos;
    }
    EXPECT_TRUE(found) << "no audit row for " << d.method << " " << d.code << " by " << d.actor;
  }
  EXPECT_EQ(rows.size(), denied.size());
  std::printf("%zu denials, %zu audit rows; e.g. %s | %s | %s\n", denied.size(), rows.size(),
              rows.empty() ? "" : rows.back().actor.c_str(),
              rows.empty() ? "" : rows.back().target.c_str(),
              rows.empty() ? "" : rows.back().detail.c_str());
}

TEST_F(AuthTest, AFloodOfBadTokensWritesTwoAuditRows) {
  MakeFleet(options_.db_path);
  StartServer();  // the default limits: one row per caller, method and code per minute
  auto params = v1::ParameterService::NewStub(
      Channel("imucal_ffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffffff"));
  constexpr int kCalls = 500;
  for (int i = 0; i < kCalls; ++i) {
    v1::GetActiveParametersRequest r;
    r.set_device_id(kDeviceA);
    v1::ParameterSet out;
    ASSERT_EQ(params->GetActiveParameters(Ctx().get(), r, &out).error_code(),
              StatusCode::UNAUTHENTICATED);
  }
  server_.reset();  // writes the count still pending
  std::vector<storage::AuditEntry> rows = Denials();
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_EQ(rows[0].target, "rpc:/imucal.v1.ParameterService/GetActiveParameters");
  EXPECT_EQ(rows[0].detail, "UNAUTHENTICATED: unknown token");
  EXPECT_NE(rows[1].detail.find(std::to_string(kCalls - 1) + " like denials not logged"),
            std::string::npos)
      << rows[1].detail;
  std::printf("%d refused calls -> %zu audit rows: \"%s\" then \"%s\"\n", kCalls, rows.size(),
              rows[0].detail.c_str(), rows[1].detail.c_str());
}

TEST_F(AuthTest, RevokingATokenRefusesItsNextCall) {
  StartServer();
  const std::string admin = AdminSecret();
  const v1::CreateTokenResponse tech = CreateToken(admin, v1::ROLE_TECHNICIAN, "", "laptop");
  EXPECT_EQ(tech.secret().size(), 7u + 64u);
  auto devices = v1::DeviceService::NewStub(Channel(tech.secret()));
  v1::ListDevicesResponse out;
  ASSERT_TRUE(devices->ListDevices(Ctx().get(), v1::ListDevicesRequest(), &out).ok());  // cached
  Revoke(admin, tech.token().id());
  grpc::Status s = devices->ListDevices(Ctx().get(), v1::ListDevicesRequest(), &out);
  EXPECT_EQ(s.error_code(), StatusCode::UNAUTHENTICATED);
  EXPECT_NE(s.error_message().find("revoked"), std::string::npos) << s.error_message();
  // The list shows it revoked; the secret is never listed.
  auto admin_stub = v1::AdminService::NewStub(Channel(admin));
  v1::ListTokensRequest all;
  all.set_include_revoked(true);
  v1::ListTokensResponse tokens;
  ASSERT_TRUE(admin_stub->ListTokens(Ctx().get(), all, &tokens).ok());
  ASSERT_EQ(tokens.tokens_size(), 2);
  EXPECT_TRUE(tokens.tokens(1).has_revoked_at());
  EXPECT_EQ(tokens.tokens(1).DebugString().find(tech.secret()), std::string::npos);
  ASSERT_TRUE(admin_stub->ListTokens(Ctx().get(), v1::ListTokensRequest(), &tokens).ok());
  EXPECT_EQ(tokens.tokens_size(), 1);  // only the valid ones by default
}

// "Revokes a token at once" holds for calls already open: a sample stream and a watch made with
// the token end UNAUTHENTICATED when it is revoked, without waiting for their next message,
// and a batch the robot writes after that is not acknowledged (nor stored).
TEST_F(AuthTest, RevokingATokenEndsItsOpenStreamsAndWatches) {
  StartServer();
  const std::string admin = AdminSecret();
  const v1::CreateTokenResponse robot = CreateToken(admin, v1::ROLE_ROBOT, kDeviceA, "robot A");
  const v1::CreateTokenResponse tech = CreateToken(admin, v1::ROLE_TECHNICIAN, "", "guide");
  auto admin_channel = Channel(admin);
  v1::RegisterDeviceRequest reg;
  reg.mutable_device()->set_id(kDeviceA);
  reg.mutable_device()->set_sensor_model("test IMU");
  reg.mutable_device()->set_nominal_rate_hz(100);
  reg.mutable_device()->set_accel_unit("m/s^2");
  reg.mutable_device()->set_gyro_unit("rad/s");
  v1::Device device;
  ASSERT_TRUE(
      v1::DeviceService::NewStub(admin_channel)->RegisterDevice(Ctx().get(), reg, &device).ok());
  auto admin_sessions = v1::SessionService::NewStub(admin_channel);
  v1::CreateSessionRequest create;
  create.set_device_id(kDeviceA);
  v1::Session session;
  ASSERT_TRUE(admin_sessions->CreateSession(Ctx().get(), create, &session).ok());
  auto batch = [&](int64_t seq) {
    v1::SampleBatch b;
    b.set_session_id(session.id());
    b.set_seq(seq);
    for (int i = 0; i < 10; ++i) {
      b.add_t_s(static_cast<double>((seq - 1) * 10 + i) / 100);
      for (double x : {0.0, 0.0, 9.81}) b.add_accel(x);
      for (double x : {0.0, 0.0, 0.0}) b.add_gyro(x);
    }
    return b;
  };

  auto robot_sessions = v1::SessionService::NewStub(Channel(robot.secret()));
  auto stream_ctx = Ctx();
  auto stream = robot_sessions->StreamSamples(stream_ctx.get());
  ASSERT_TRUE(stream->Write(batch(1)));
  v1::SampleAck ack;
  ASSERT_TRUE(stream->Read(&ack));
  EXPECT_EQ(ack.last_acked_seq(), 1);
  auto watch_ctx = Ctx();
  v1::WatchSessionRequest watch_req;
  watch_req.set_session_id(session.id());
  auto watch =
      v1::SessionService::NewStub(Channel(tech.secret()))->WatchSession(watch_ctx.get(), watch_req);
  v1::SessionEvent event;
  ASSERT_TRUE(watch->Read(&event));  // the snapshot: the watch is open
  EXPECT_TRUE(event.has_session());

  Revoke(admin, robot.token().id());
  Revoke(admin, tech.token().id());
  // Both calls end at once, the robot having sent nothing more.
  EXPECT_FALSE(stream->Read(&ack));
  const grpc::Status ended = stream->Finish();
  EXPECT_EQ(ended.error_code(), StatusCode::UNAUTHENTICATED) << ended.error_message();
  EXPECT_NE(ended.error_message().find("revoked"), std::string::npos) << ended.error_message();
  while (watch->Read(&event)) {
  }
  const grpc::Status watch_end = watch->Finish();
  EXPECT_EQ(watch_end.error_code(), StatusCode::UNAUTHENTICATED) << watch_end.error_message();
  // Another stream with the revoked token is refused, and the batch never stored.
  auto again_ctx = Ctx();
  auto again = robot_sessions->StreamSamples(again_ctx.get());
  v1::SampleBatch second = batch(2);
  again->Write(second);
  EXPECT_FALSE(again->Read(&ack));
  EXPECT_EQ(again->Finish().error_code(), StatusCode::UNAUTHENTICATED);
  v1::GetSessionRequest get;
  get.set_session_id(session.id());
  ASSERT_TRUE(admin_sessions->GetSession(Ctx().get(), get, &session).ok());
  EXPECT_EQ(session.last_acked_seq(), 1);
  EXPECT_EQ(session.samples(), 10);
}

// One token may hold at most max_streams_per_token streams (StreamSamples and WatchSession
// together), counted from the moment a stream opens, not from its first batch: a robot (or a
// stolen token) cannot open thousands of silent streams. Other tokens are not affected.
TEST_F(AuthTest, ATokenHoldsAtMostItsShareOfStreams) {
  options_.sessions.max_streams_per_token = 2;
  options_.sessions.first_batch_timeout = absl::Seconds(3);
  StartServer();
  const std::string admin = AdminSecret();
  const v1::CreateTokenResponse robot = CreateToken(admin, v1::ROLE_ROBOT, kDeviceA, "robot A");
  auto robot_sessions = v1::SessionService::NewStub(Channel(robot.secret()));
  std::vector<std::unique_ptr<grpc::ClientContext>> contexts;
  std::vector<std::unique_ptr<grpc::ClientReaderWriter<v1::SampleBatch, v1::SampleAck>>> streams;
  for (int i = 0; i < 3; ++i) {
    contexts.push_back(Ctx());
    streams.push_back(robot_sessions->StreamSamples(contexts.back().get()));
  }
  // Two hold their place until the server ends them for silence, whichever third is refused
  // at once.
  const std::string token_id = std::to_string(robot.token().id());
  int refused = 0, ended = 0;
  for (auto& stream : streams) {
    v1::SampleAck ack;
    EXPECT_FALSE(stream->Read(&ack));
    const grpc::Status st = stream->Finish();
    if (st.error_code() == StatusCode::RESOURCE_EXHAUSTED) {
      ++refused;
      EXPECT_NE(st.error_message().find("token " + token_id + " already has 2 streams open"),
                std::string::npos)
          << st.error_message();
    } else {
      ++ended;
      EXPECT_EQ(st.error_code(), StatusCode::DEADLINE_EXCEEDED) << st.error_message();
    }
  }
  EXPECT_EQ(ended, 2);
  EXPECT_EQ(refused, 1);
}

// A sample stream that sends nothing, as a flood's are: it only hears how it ends.
class SilentStream final : public grpc::ClientBidiReactor<v1::SampleBatch, v1::SampleAck> {
 public:
  struct Ends {
    std::mutex mu;
    std::condition_variable cv;
    std::vector<grpc::Status> statuses;  // guarded by mu
  };
  SilentStream(v1::SessionService::Stub* stub, Ends* ends) : ends_(ends) {
    context_.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    stub->async()->StreamSamples(&context_, this);
    StartRead(&ack_);
    StartCall();
  }
  void HangUp() { context_.TryCancel(); }
  void OnReadDone(bool ok) override {
    if (ok) StartRead(&ack_);
  }
  void OnDone(const grpc::Status& status) override {
    std::lock_guard lock(ends_->mu);
    ends_->statuses.push_back(status);
    ends_->cv.notify_all();
  }

 private:
  Ends* ends_;
  grpc::ClientContext context_;
  v1::SampleAck ack_;
};

// The server's places are shared fairly (server/stream_registry.h): silent streams from many
// tokens fill the server (max_streams), each token within its share, and a robot with a token
// of its own still streams: its stream takes the place of a silent one of the token with the
// most, which is told why. (Before, the robot was refused until the flood's streams timed out.)
TEST_F(AuthTest, ARobotStreamsThroughAFloodOfSilentStreamsFromManyTokens) {
  options_.sessions.max_streams = 12;
  options_.sessions.max_streams_per_token = 4;
  StartServer();
  const std::string admin = AdminSecret();
  const v1::CreateTokenResponse robot = CreateToken(admin, v1::ROLE_ROBOT, kDeviceA, "robot A");
  auto admin_channel = Channel(admin);
  v1::RegisterDeviceRequest reg;
  reg.mutable_device()->set_id(kDeviceA);
  reg.mutable_device()->set_sensor_model("test IMU");
  reg.mutable_device()->set_nominal_rate_hz(100);
  reg.mutable_device()->set_accel_unit("m/s^2");
  reg.mutable_device()->set_gyro_unit("rad/s");
  v1::Device device;
  ASSERT_TRUE(
      v1::DeviceService::NewStub(admin_channel)->RegisterDevice(Ctx().get(), reg, &device).ok());
  v1::CreateSessionRequest create;
  create.set_device_id(kDeviceA);
  v1::Session session;
  ASSERT_TRUE(v1::SessionService::NewStub(admin_channel)
                  ->CreateSession(Ctx().get(), create, &session)
                  .ok());

  // Six flood tokens, four streams each: twelve hold the server's places, twelve are refused.
  constexpr int kFloodTokens = 6, kPerToken = 4;
  std::vector<std::unique_ptr<v1::SessionService::Stub>> flood_stubs;
  for (int t = 0; t < kFloodTokens; ++t) {
    const v1::CreateTokenResponse flood =
        CreateToken(admin, v1::ROLE_ROBOT, kDeviceB, "flood " + std::to_string(t));
    flood_stubs.push_back(v1::SessionService::NewStub(Channel(flood.secret())));
  }
  SilentStream::Ends ends;
  std::vector<std::unique_ptr<SilentStream>> flood;
  for (int i = 0; i < kPerToken; ++i)
    for (auto& stub : flood_stubs)
      flood.push_back(std::make_unique<SilentStream>(stub.get(), &ends));
  const int refused = kFloodTokens * kPerToken - options_.sessions.max_streams;
  {
    std::unique_lock lock(ends.mu);
    ASSERT_TRUE(ends.cv.wait_for(lock, std::chrono::seconds(30), [&] {
      return static_cast<int>(ends.statuses.size()) >= refused;
    }));
    for (const grpc::Status& st : ends.statuses)
      EXPECT_EQ(st.error_code(), StatusCode::RESOURCE_EXHAUSTED) << st.error_message();
  }
  // The places the refused and replaced streams held are free once they have ended on the
  // server too (bounded polling: the registry has nothing to wait on).
  for (auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
       server_->open_streams() != static_cast<size_t>(options_.sessions.max_streams) &&
       std::chrono::steady_clock::now() < deadline;)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  ASSERT_EQ(server_->open_streams(), static_cast<size_t>(options_.sessions.max_streams));

  // The robot streams into its session, and its batch is acknowledged.
  auto robot_sessions = v1::SessionService::NewStub(Channel(robot.secret()));
  auto stream_ctx = Ctx();
  auto stream = robot_sessions->StreamSamples(stream_ctx.get());
  v1::SampleBatch batch;
  batch.set_session_id(session.id());
  batch.set_seq(1);
  for (int i = 0; i < 10; ++i) {
    batch.add_t_s(static_cast<double>(i) / 100);
    for (double x : {0.0, 0.0, 9.81}) batch.add_accel(x);
    for (double x : {0.0, 0.0, 0.0}) batch.add_gyro(x);
  }
  ASSERT_TRUE(stream->Write(batch));
  v1::SampleAck ack;
  ASSERT_TRUE(stream->Read(&ack)) << stream->Finish().error_message();
  EXPECT_EQ(ack.last_acked_seq(), 1);
  stream->WritesDone();
  EXPECT_FALSE(stream->Read(&ack));
  const grpc::Status robot_end = stream->Finish();
  EXPECT_TRUE(robot_end.ok()) << robot_end.error_message();
  {
    // One flood stream gave its place, and was told why.
    std::unique_lock lock(ends.mu);
    ASSERT_TRUE(ends.cv.wait_for(lock, std::chrono::seconds(10),
                                 [&] { return static_cast<int>(ends.statuses.size()) > refused; }));
    const grpc::Status& replaced = ends.statuses[static_cast<size_t>(refused)];
    EXPECT_EQ(replaced.error_code(), StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_NE(replaced.error_message().find("its place went to a caller with fewer streams"),
              std::string::npos)
        << replaced.error_message();
  }
  for (auto& s : flood) s->HangUp();
  std::unique_lock lock(ends.mu);
  ends.cv.wait(lock, [&] { return ends.statuses.size() == flood.size(); });
}

TEST_F(AuthTest, TheFirstAdminTokenIsWrittenOnceToAPrivateFile) {
  StartServer();
  const std::string path = server_->admin_token_written();
  ASSERT_EQ(path, options_.db_path + ".admin-token");
  struct stat st {};
  ASSERT_EQ(::stat(path.c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
  const std::string admin = AdminSecret();
  auto stub = v1::AdminService::NewStub(Channel(admin));
  v1::ListTokensResponse tokens;
  ASSERT_TRUE(stub->ListTokens(Ctx().get(), v1::ListTokensRequest(), &tokens).ok());
  ASSERT_EQ(tokens.tokens_size(), 1);
  EXPECT_EQ(tokens.tokens(0).role(), v1::ROLE_ADMIN);
  // A restart finds a token and makes none.
  server_.reset();
  StartServer();
  EXPECT_TRUE(server_->admin_token_written().empty());
  EXPECT_EQ(Trimmed(ReadText(path)), admin);
}

TEST_F(AuthTest, TheHealthServiceNeedsNoToken) {
  StartServer();
  auto channel = Channel("");
  grpc::GenericStub stub(channel);
  // grpc.health.v1.Health/Check with an empty request (all services).
  grpc::Slice empty("");  // HealthCheckRequest{service: ""} is zero bytes
  grpc::ByteBuffer request(&empty, 1);
  grpc::ByteBuffer response;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  std::mutex mu;
  std::condition_variable cv;
  bool done = false;
  grpc::Status status;
  stub.UnaryCall(&ctx, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request, &response,
                 [&](grpc::Status s) {
                   std::lock_guard lock(mu);
                   status = s;
                   done = true;
                   cv.notify_one();
                 });
  std::unique_lock lock(mu);
  cv.wait(lock, [&] { return done; });
  EXPECT_TRUE(status.ok()) << status.error_message();
}

TEST_F(AuthTest, APlaintextClientCannotTalkToTheTlsServer) {
  StartServer();
  const std::string admin = AdminSecret();
  auto plain = v1::DeviceService::NewStub(
      grpc::CreateChannel(server_->address(), grpc::InsecureChannelCredentials()));
  v1::ListDevicesResponse out;
  grpc::Status s = plain->ListDevices(Ctx().get(), v1::ListDevicesRequest(), &out);
  EXPECT_EQ(s.error_code(), StatusCode::UNAVAILABLE) << s.error_message();
  // Nor a TLS client that does not trust the server's CA, even with a valid token.
  sdk::ClientOptions wrong_ca;
  wrong_ca.ca_cert_pem = Pem("other-ca");
  wrong_ca.bearer_token = admin;
  auto untrusting = v1::DeviceService::NewStub(sdk::MakeChannel(server_->address(), wrong_ca));
  s = untrusting->ListDevices(Ctx().get(), v1::ListDevicesRequest(), &out);
  EXPECT_EQ(s.error_code(), StatusCode::UNAVAILABLE) << s.error_message();
  // And the SDK refuses to send a token without TLS.
  sdk::ClientOptions plaintext_token;
  plaintext_token.bearer_token = admin;
  EXPECT_TRUE(absl::IsInvalidArgument(sdk::ValidateClientOptions(plaintext_token)));
  EXPECT_TRUE(absl::IsInvalidArgument(
      sdk::ParamClient::Create(server_->address(), plaintext_token).status()));
}

// Replicas share one certificate; a client given all their addresses checks it against the
// first address's host (gRPC would check it against the whole list), or against the name it is
// told. Calls go round-robin to those that answer, and on to the other when one stops.
TEST_F(AuthTest, AClientGivenSeveralTlsReplicasReachesThemAndMovesOnWhenOneStops) {
  StartServer();
  const std::string admin = AdminSecret();
  ServerOptions b_options = options_;
  b_options.sessions.replica_id = "replica-b";
  absl::StatusOr<std::unique_ptr<Server>> b = Server::Start(b_options);
  ASSERT_TRUE(b.ok()) << b.status();
  const std::string target = absl::StrCat("ipv4:", server_->address(), ",", (*b)->address());
  EXPECT_EQ(sdk::FirstListedHost(target), "127.0.0.1");
  EXPECT_EQ(sdk::FirstListedHost("ipv6:[::1]:50051,[::1]:50052"), "::1");
  EXPECT_EQ(sdk::FirstListedHost("ipv4:10.0.0.1:50051"), "");
  EXPECT_EQ(sdk::FirstListedHost("dns:///imucal.internal:50051"), "");
  auto list_devices = [&](const sdk::ClientOptions& o) {
    auto stub = v1::DeviceService::NewStub(sdk::MakeChannel(target, o));
    v1::ListDevicesResponse out;
    return stub->ListDevices(Ctx().get(), v1::ListDevicesRequest(), &out);
  };
  sdk::ClientOptions o;
  o.ca_cert_pem = Pem("ca");
  o.bearer_token = admin;
  grpc::Status s = list_devices(o);
  EXPECT_TRUE(s.ok()) << s.error_message();
  o.tls_server_name = "localhost";  // the certificate's DNS name
  s = list_devices(o);
  EXPECT_TRUE(s.ok()) << s.error_message();
  o.tls_server_name = "elsewhere.example";  // not the certificate's
  EXPECT_EQ(list_devices(o).error_code(), StatusCode::UNAVAILABLE);

  o.tls_server_name.clear();
  auto stub = v1::DeviceService::NewStub(sdk::MakeChannel(target, o));
  v1::ListDevicesResponse out;
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(stub->ListDevices(Ctx().get(), {}, &out).ok());
  server_.reset();  // the first replica stops; the channel's next calls find the other
  auto ctx = Ctx();
  ctx->set_wait_for_ready(true);
  s = stub->ListDevices(ctx.get(), {}, &out);
  EXPECT_TRUE(s.ok()) << s.error_message();
}

TEST_F(AuthTest, TheSdkFetchesItsDeviceParametersWithARobotToken) {
  MakeFleet(options_.db_path);
  StartServer();
  const std::string admin = AdminSecret();
  const v1::CreateTokenResponse robot = CreateToken(admin, v1::ROLE_ROBOT, kDeviceA, "");
  sdk::ClientOptions o;
  o.ca_cert_pem = Pem("ca");
  o.bearer_token = robot.secret();
  absl::StatusOr<sdk::ParamClient> client = sdk::ParamClient::Create(server_->address(), o);
  ASSERT_TRUE(client.ok()) << client.status();
  bool unchanged = false;
  // The stored document is not a full parameter set: the fetch gets past the server (its crc
  // checked) and fails only at parsing, with InvalidArgument.
  absl::StatusOr<sdk::LoadedParams> a =
      client->FetchActiveIfChanged(kDeviceA, 0, absl::Seconds(10), &unchanged);
  EXPECT_TRUE(absl::IsInvalidArgument(a.status())) << a.status();
  absl::StatusOr<sdk::LoadedParams> same =
      client->FetchActiveIfChanged(kDeviceA, 1, absl::Seconds(10), &unchanged);
  EXPECT_TRUE(same.ok()) << same.status();
  EXPECT_TRUE(unchanged);
  absl::StatusOr<sdk::LoadedParams> b =
      client->FetchActiveIfChanged(kDeviceB, 0, absl::Seconds(10), &unchanged);
  EXPECT_TRUE(absl::IsPermissionDenied(b.status())) << b.status();
}

TEST_F(AuthTest, InsecureIsRefusedOffLoopbackAndTlsNeedsItsFiles) {
  ServerOptions o;
  o.db_path = options_.db_path;
  o.security.insecure = true;
  o.listen = "0.0.0.0:0";
  absl::StatusOr<std::unique_ptr<Server>> s = Server::Start(o);
  ASSERT_TRUE(absl::IsInvalidArgument(s.status())) << s.status();
  EXPECT_NE(s.status().message().find("loopback"), std::string::npos) << s.status();
  o.listen = "[::1]:0";
  s = Server::Start(o);
  ASSERT_TRUE(s.ok()) << s.status();
  {
    // Loopback plaintext checks no tokens, and has none to manage.
    auto admin = v1::AdminService::NewStub(
        grpc::CreateChannel((*s)->address(), grpc::InsecureChannelCredentials()));
    v1::ListTokensResponse tokens;
    EXPECT_EQ(admin->ListTokens(Ctx().get(), v1::ListTokensRequest(), &tokens).error_code(),
              StatusCode::FAILED_PRECONDITION);
    auto devices = v1::DeviceService::NewStub(
        grpc::CreateChannel((*s)->address(), grpc::InsecureChannelCredentials()));
    v1::ListDevicesResponse out;
    EXPECT_TRUE(devices->ListDevices(Ctx().get(), v1::ListDevicesRequest(), &out).ok());
  }
  s->reset();
  o.security.insecure = false;
  s = Server::Start(o);
  ASSERT_TRUE(absl::IsInvalidArgument(s.status()));
  EXPECT_NE(s.status().message().find("tls_cert"), std::string::npos) << s.status();
  o.security.tls_cert_path = options_.security.tls_cert_path;
  o.security.tls_key_path = (dir_ / "robot-A.key").string();
  s = Server::Start(o);
  ASSERT_TRUE(absl::IsInvalidArgument(s.status()));
  EXPECT_NE(s.status().message().find("does not belong"), std::string::npos) << s.status();
  for (const char* host : {"127.0.0.1", "127.3.2.1", "::1", "[::1]", "localhost"})
    EXPECT_TRUE(IsLoopbackHost(host)) << host;
  for (const char* host : {"0.0.0.0", "", "[::]", "10.0.0.1", "calib.fleet", "128.0.0.1"})
    EXPECT_FALSE(IsLoopbackHost(host)) << host;
}

TEST_F(AuthTest, TheCliManagesTokens) {
  StartServer();
  const std::string address = server_->address();
  // Connection flags anywhere on the line; a token without a CA is refused before any call.
  std::vector<std::string> argv = {"imucal", "--token", "imucal_x", "devices", "--server", address};
  absl::Status s = cli::TakeConnectionFlags(&argv);
  EXPECT_TRUE(absl::IsInvalidArgument(s)) << s;
  EXPECT_NE(s.message().find("TLS"), std::string::npos) << s;
  const std::string admin_file = server_->admin_token_written();
  argv = {"imucal",
          "devices",
          "--ca-cert",
          (dir_ / "ca.pem").string(),
          "--server",
          address,
          "--token-file=" + admin_file};
  ASSERT_TRUE(cli::TakeConnectionFlags(&argv).ok());
  EXPECT_EQ(argv, (std::vector<std::string>{"imucal", "devices", "--server", address}));
  EXPECT_EQ(cli::ConnectionOptions().bearer_token, AdminSecret());

  const std::string robot_file = (dir_ / "robot.token").string();
  ASSERT_EQ(cli::RunAdmin({"--server", address, "token", "create", "--role", "robot", "--device",
                           kDeviceA, "--out", robot_file}),
            cli::kExitOk);
  struct stat st {};
  ASSERT_EQ(::stat(robot_file.c_str(), &st), 0);
  EXPECT_EQ(st.st_mode & 0777, 0600u);
  const std::string robot = Trimmed(ReadText(robot_file));
  auto params = v1::ParameterService::NewStub(Channel(robot));
  v1::GetActiveParametersRequest mine;
  mine.set_device_id(kDeviceA);
  v1::ParameterSet out;
  EXPECT_EQ(params->GetActiveParameters(Ctx().get(), mine, &out).error_code(),
            StatusCode::NOT_FOUND);  // allowed: robot-A has no parameters yet
  testing::internal::CaptureStdout();
  ASSERT_EQ(cli::RunAdmin({"--server", address, "token", "list", "--json"}), cli::kExitOk);
  const std::string listed = testing::internal::GetCapturedStdout();
  EXPECT_NE(listed.find("\"device_id\": \"robot-A\""), std::string::npos) << listed;
  EXPECT_EQ(listed.find(robot), std::string::npos) << "a secret was listed";
  EXPECT_EQ(cli::RunAdmin({"--server", address, "token", "revoke", "2"}), cli::kExitOk);
  EXPECT_EQ(params->GetActiveParameters(Ctx().get(), mine, &out).error_code(),
            StatusCode::UNAUTHENTICATED);
  // Usage errors and a refused role have their exit codes.
  EXPECT_EQ(cli::RunAdmin({"--server", address, "token", "create", "--role", "robot"}),
            cli::kExitUsage);
  sdk::ClientOptions as_robot = cli::ConnectionOptions();
  as_robot.bearer_token = robot;
  cli::SetConnectionOptions(as_robot);
  EXPECT_EQ(cli::RunAdmin({"--server", address, "token", "list"}), cli::kExitDenied);
  cli::SetConnectionOptions(sdk::ClientOptions());
}

// The README's walkthrough: the guide (a technician) opens robot-A's session, and the robot
// runs `imucal upload FILE --device robot-A` with its own token. What upload needs of the device
// (its units, its open session) the robot may read of its own device, and of no other.
TEST_F(AuthTest, ARobotUploadsIntoItsOpenSessionWithTheCli) {
  const Fleet fleet = MakeFleet(options_.db_path);  // robot-A's open, empty session
  StartServer();
  const std::string admin = AdminSecret();
  const std::string robot = CreateToken(admin, v1::ROLE_ROBOT, kDeviceA, "A").secret();
  // 2 s of a robot at rest at robot-A's 100 Hz, in its registered units (m/s^2, rad/s).
  core::Capture capture;
  for (int i = 0; i < 200; ++i) {
    capture.t_s.push_back(i / 100.0);
    capture.accel.emplace_back(0.01, -0.02, 9.81);
    capture.gyro.emplace_back(1e-3, -1e-3, 2e-3);
  }
  const std::string file = (dir_ / "rest.csv").string();
  ASSERT_TRUE(importers::WriteImucalCsvFile(capture, file).ok());

  sdk::ClientOptions as_robot;
  as_robot.ca_cert_pem = Pem("ca");
  as_robot.bearer_token = robot;
  cli::SetConnectionOptions(as_robot);
  const std::string address = server_->address();
  testing::internal::CaptureStdout();
  testing::internal::CaptureStderr();
  const int uploaded = cli::RunUpload({"--server", address, file, "--device", kDeviceA});
  const std::string out = testing::internal::GetCapturedStdout();
  const std::string err = testing::internal::GetCapturedStderr();
  EXPECT_EQ(uploaded, cli::kExitOk) << out << err;
  EXPECT_NE(out.find("streaming into robot-A's open session " + fleet.session_a), std::string::npos)
      << out;
  EXPECT_NE(out.find("uploaded 200 samples"), std::string::npos) << out;

  // Another device's data stays out of reach, through the CLI and through the API.
  testing::internal::CaptureStderr();
  EXPECT_EQ(cli::RunUpload({"--server", address, file, "--device", kDeviceB}), cli::kExitDenied);
  EXPECT_NE(testing::internal::GetCapturedStderr().find(
                "robot robot-A may act only for its own device, not 'robot-B'"),
            std::string::npos);
  auto devices = v1::DeviceService::NewStub(Channel(robot));
  v1::GetDeviceRequest other;
  other.set_device_id(kDeviceB);
  v1::Device device;
  EXPECT_EQ(devices->GetDevice(Ctx().get(), other, &device).error_code(),
            StatusCode::PERMISSION_DENIED);
  other.set_device_id("robot-nonexistent");  // no hint whether it exists
  EXPECT_EQ(devices->GetDevice(Ctx().get(), other, &device).error_code(),
            StatusCode::PERMISSION_DENIED);
  auto sessions = v1::SessionService::NewStub(Channel(robot));
  v1::ListSessionsRequest list;
  v1::ListSessionsResponse listed;
  const grpc::Status every = sessions->ListSessions(Ctx().get(), list, &listed);
  EXPECT_EQ(every.error_code(), StatusCode::PERMISSION_DENIED);
  EXPECT_EQ(every.error_message(),
            "robot robot-A may act only for its own device: name it (device_id 'robot-A')");
  list.set_device_id(kDeviceB);
  EXPECT_EQ(sessions->ListSessions(Ctx().get(), list, &listed).error_code(),
            StatusCode::PERMISSION_DENIED);
  list.set_device_id(kDeviceA);
  ASSERT_TRUE(sessions->ListSessions(Ctx().get(), list, &listed).ok());
  ASSERT_EQ(listed.sessions_size(), 1);
  EXPECT_EQ(listed.sessions(0).samples(), 200);

  // With no open session, the robot is told who opens one rather than only "denied".
  auto admin_sessions = v1::SessionService::NewStub(Channel(admin));
  v1::CancelSessionRequest cancel;
  cancel.set_session_id(fleet.session_a);
  v1::Session cancelled;
  ASSERT_TRUE(admin_sessions->CancelSession(Ctx().get(), cancel, &cancelled).ok());
  testing::internal::CaptureStdout();
  testing::internal::CaptureStderr();
  EXPECT_EQ(cli::RunUpload({"--server", address, file, "--device", kDeviceA}), cli::kExitDenied);
  testing::internal::GetCapturedStdout();
  EXPECT_NE(testing::internal::GetCapturedStderr().find(
                "robot-A has no open session to stream into, and this token may not open one: a "
                "technician opens it (imucal guide --device robot-A"),
            std::string::npos);
  cli::SetConnectionOptions(sdk::ClientOptions());
}

}  // namespace
}  // namespace imucal::server
