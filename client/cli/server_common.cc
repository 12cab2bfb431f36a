#include "client/cli/server_common.h"

#include <chrono>
#include <cstdio>
#include <cstdlib>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "client/cli/commands.h"
#include "client/sdk/client.h"
#include "google/protobuf/util/json_util.h"
#include "google/protobuf/util/time_util.h"

namespace imucal::cli {

namespace pb = imucal::v1;

std::string ServerAddress(const Args& args) {
  if (auto s = args.Get("server"); s && !s->empty()) return *s;
  if (const char* env = std::getenv("IMUCAL_SERVER"); env != nullptr && *env != '\0') return env;
  return kDefaultServer;
}

Server Connect(const Args& args) {
  Server s;
  s.address = ServerAddress(args);
  s.channel = sdk::MakeChannel(s.address);
  s.devices = pb::DeviceService::NewStub(s.channel);
  s.sessions = pb::SessionService::NewStub(s.channel);
  s.params = pb::ParameterService::NewStub(s.channel);
  return s;
}

std::unique_ptr<grpc::ClientContext> CallContext(double timeout_s) {
  auto context = std::make_unique<grpc::ClientContext>();
  context->set_deadline(std::chrono::system_clock::now() +
                        std::chrono::milliseconds(static_cast<int64_t>(timeout_s * 1000)));
  return context;
}

grpc::Status GetSession(const Server& server, const std::string& session_id,
                        pb::Session* session) {
  pb::GetSessionRequest req;
  req.set_session_id(session_id);
  return server.sessions->GetSession(CallContext().get(), req, session);
}

grpc::Status CreateSession(const Server& server, const std::string& device_id,
                           pb::Protocol protocol, double gravity_m_s2, pb::Session* session) {
  pb::CreateSessionRequest req;
  req.set_device_id(device_id);
  req.set_protocol(protocol);
  req.set_gravity_m_s2(gravity_m_s2);
  return server.sessions->CreateSession(CallContext().get(), req, session);
}

int RpcError(const Server& server, const absl::Status& status) {
  if (status.code() == absl::StatusCode::kUnavailable ||
      status.code() == absl::StatusCode::kDeadlineExceeded) {
    std::fprintf(stderr, "imucal: server %s unreachable: %s\n", server.address.c_str(),
                 std::string(status.message()).c_str());
    return kExitUnavailable;
  }
  return ReportError(status);
}

int RpcError(const Server& server, const grpc::Status& status) {
  return RpcError(server, absl::Status(static_cast<absl::StatusCode>(status.error_code()),
                                       status.error_message()));
}

int UsageError(const std::string& message, const char* help) {
  std::fprintf(stderr, "imucal: %s\n\n%s", message.c_str(), help);
  return kExitUsage;
}

std::string ProtocolName(pb::Protocol protocol) {
  switch (protocol) {
    case pb::PROTOCOL_SIX_FACE:
      return "six-face";
    case pb::PROTOCOL_POSITIONS:
      return "positions";
    case pb::PROTOCOL_FREE:
      return "free";
    default:
      return "auto";
  }
}

absl::StatusOr<pb::Protocol> ParseProtocol(const std::string& name) {
  if (name == "six-face") return pb::PROTOCOL_SIX_FACE;
  if (name == "positions") return pb::PROTOCOL_POSITIONS;
  if (name == "free") return pb::PROTOCOL_FREE;
  if (name == "auto") return pb::PROTOCOL_UNSPECIFIED;
  return absl::InvalidArgumentError(
      absl::StrCat("--protocol: '", name, "' is not six-face, positions, free or auto"));
}

namespace {
// "SESSION_STATE_OPEN" -> "open".
std::string EnumWord(const std::string& name, size_t prefix) {
  return name.size() > prefix ? absl::AsciiStrToLower(name.substr(prefix)) : "unknown";
}
}  // namespace

std::string SessionStateName(pb::SessionState state) {
  return EnumWord(pb::SessionState_Name(state), sizeof("SESSION_STATE_") - 1);
}
std::string JobStateName(pb::JobState state) {
  return EnumWord(pb::JobState_Name(state), sizeof("JOB_STATE_") - 1);
}
std::string VersionStateName(pb::VersionState state) {
  return EnumWord(pb::VersionState_Name(state), sizeof("VERSION_STATE_") - 1);
}

std::string TimeText(const google::protobuf::Timestamp& t) {
  if (t.seconds() == 0 && t.nanos() == 0) return "-";
  return google::protobuf::util::TimeUtil::ToString(t);
}

std::string ProtoJson(const google::protobuf::Message& message) {
  google::protobuf::util::JsonPrintOptions options;
  options.add_whitespace = true;
  options.preserve_proto_field_names = true;
  options.always_print_primitive_fields = true;
  std::string out;
  (void)google::protobuf::util::MessageToJsonString(message, &out, options);
  return out;
}

}  // namespace imucal::cli
