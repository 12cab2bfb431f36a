#include "client/cli/server_common.h"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <optional>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "client/cli/commands.h"
#include "client/sdk/client.h"
#include "client/sdk/grpc_status.h"
#include "google/protobuf/util/json_util.h"
#include "google/protobuf/util/time_util.h"

namespace imucal::cli {

namespace pb = imucal::v1;

std::string ServerAddress(const Args& args) { return ServerAddress(args.Get("server")); }

std::string ServerAddress(const std::optional<std::string>& server_flag) {
  if (server_flag && !server_flag->empty()) return *server_flag;
  if (const char* env = std::getenv("IMUCAL_SERVER"); env != nullptr && *env != '\0') return env;
  return kDefaultServer;
}

namespace {

sdk::ClientOptions& ConnectionSettings() {
  static sdk::ClientOptions* settings = new sdk::ClientOptions();
  return *settings;
}

// The value of `name` (--name V or --name=V) at argv[*i], advancing *i past it; nullopt when
// argv[*i] is another argument.
absl::StatusOr<std::optional<std::string>> FlagValue(const std::vector<std::string>& argv,
                                                     size_t* i, const std::string& name) {
  const std::string& arg = argv[*i];
  if (arg == name) {
    if (*i + 1 >= argv.size())
      return absl::InvalidArgumentError(absl::StrCat(name, " needs a value"));
    *i += 1;
    return std::optional<std::string>(argv[*i]);
  }
  if (arg.rfind(name + "=", 0) == 0) return std::optional<std::string>(arg.substr(name.size() + 1));
  return std::optional<std::string>();
}

std::string Env(const char* name) {
  const char* value = std::getenv(name);
  return value == nullptr ? std::string() : std::string(value);
}

}  // namespace

absl::Status TakeConnectionFlags(std::vector<std::string>* argv) {
  // --server stays for the command; a target that gRPC would only log about (and then fail
  // every call) is refused here, naming what is wrong.
  bool server_given = false;
  for (size_t i = 0; i < argv->size(); ++i) {
    const std::string& arg = (*argv)[i];
    std::optional<std::string> server;
    if (arg == "--server" && i + 1 < argv->size()) server = (*argv)[i + 1];
    if (arg.rfind("--server=", 0) == 0) server = arg.substr(9);
    if (!server) continue;
    server_given = true;
    if (absl::Status s = sdk::CheckTarget(*server); !s.ok()) return s;
  }
  if (const std::string env = Env("IMUCAL_SERVER"); !server_given && !env.empty()) {
    if (absl::Status s = sdk::CheckTarget(env); !s.ok())
      return absl::InvalidArgumentError(absl::StrCat("$IMUCAL_SERVER: ", s.message()));
  }
  std::string token, token_file, ca_cert, tls_name;
  std::vector<std::string> kept;
  for (size_t i = 0; i < argv->size(); ++i) {
    bool taken = false;
    for (auto [name, out] : {std::pair{"--token", &token}, std::pair{"--token-file", &token_file},
                             std::pair{"--ca-cert", &ca_cert},
                             std::pair{"--tls-server-name", &tls_name}}) {
      absl::StatusOr<std::optional<std::string>> value = FlagValue(*argv, &i, name);
      if (!value.ok()) return value.status();
      if (!value->has_value()) continue;
      if (value->value().empty()) return absl::InvalidArgumentError(absl::StrCat(name, ": empty"));
      *out = **value;
      taken = true;
      break;
    }
    if (!taken) kept.push_back((*argv)[i]);
  }
  if (!token.empty() && !token_file.empty())
    return absl::InvalidArgumentError("--token and --token-file: give one of them");
  // The environment fills in what the command line left out.
  if (token.empty() && token_file.empty()) {
    token = Env("IMUCAL_TOKEN");
    if (token.empty()) token_file = Env("IMUCAL_TOKEN_FILE");
  }
  if (ca_cert.empty()) ca_cert = Env("IMUCAL_CA_CERT");
  if (tls_name.empty()) tls_name = Env("IMUCAL_TLS_SERVER_NAME");
  absl::StatusOr<sdk::ClientOptions> options = sdk::ClientOptionsFromFiles(ca_cert, token_file);
  if (!options.ok()) return options.status();
  if (!token.empty()) options->bearer_token = token;
  if (!tls_name.empty() && options->ca_cert_pem.empty())
    return absl::InvalidArgumentError("--tls-server-name: only with TLS (--ca-cert)");
  options->tls_server_name = tls_name;
  if (absl::Status s = sdk::ValidateClientOptions(*options); !s.ok()) {
    return absl::InvalidArgumentError(absl::StrCat(
        s.message(), " (--ca-cert PEM or $IMUCAL_CA_CERT, with --token-file / --token)"));
  }
  ConnectionSettings() = *std::move(options);
  *argv = std::move(kept);
  return absl::OkStatus();
}

const sdk::ClientOptions& ConnectionOptions() { return ConnectionSettings(); }
void SetConnectionOptions(sdk::ClientOptions options) { ConnectionSettings() = std::move(options); }

Server Connect(const Args& args) { return ConnectWith(ServerAddress(args), ConnectionSettings()); }

Server ConnectWith(const std::string& address, const sdk::ClientOptions& options) {
  Server s;
  s.address = address;
  s.channel = sdk::MakeChannel(s.address, options);
  s.devices = pb::DeviceService::NewStub(s.channel);
  s.sessions = pb::SessionService::NewStub(s.channel);
  s.params = pb::ParameterService::NewStub(s.channel);
  s.admin = pb::AdminService::NewStub(s.channel);
  return s;
}

std::unique_ptr<grpc::ClientContext> CallContext(double timeout_s) {
  auto context = std::make_unique<grpc::ClientContext>();
  context->set_deadline(std::chrono::system_clock::now() +
                        std::chrono::milliseconds(static_cast<int64_t>(timeout_s * 1000)));
  return context;
}

grpc::Status GetSession(const Server& server, const std::string& session_id, pb::Session* session) {
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
  if (sdk::IsDatabaseUnavailable(status)) {  // the server answered: it is not unreachable
    std::fprintf(stderr, "imucal: server %s is up, but %s; retry later\n", server.address.c_str(),
                 sdk::kDatabaseUnavailableMessage);
    return kExitUnavailable;
  }
  if (status.code() == absl::StatusCode::kUnavailable ||
      status.code() == absl::StatusCode::kDeadlineExceeded) {
    std::fprintf(stderr, "imucal: server %s unreachable: %s\n", server.address.c_str(),
                 std::string(status.message()).c_str());
    return kExitUnavailable;
  }
  if (status.code() == absl::StatusCode::kUnauthenticated ||
      status.code() == absl::StatusCode::kPermissionDenied) {
    std::fprintf(stderr, "imucal: server %s refused the call: %s\n", server.address.c_str(),
                 std::string(status.message()).c_str());
    return kExitDenied;
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
    case pb::PROTOCOL_FERRARIS:
      return "ferraris";
    default:
      return "auto";
  }
}

absl::StatusOr<pb::Protocol> ParseProtocol(const std::string& name) {
  if (name == "six-face") return pb::PROTOCOL_SIX_FACE;
  if (name == "positions") return pb::PROTOCOL_POSITIONS;
  if (name == "free") return pb::PROTOCOL_FREE;
  if (name == "ferraris") return pb::PROTOCOL_FERRARIS;
  if (name == "auto") return pb::PROTOCOL_UNSPECIFIED;
  return absl::InvalidArgumentError(
      absl::StrCat("--protocol: '", name, "' is not six-face, positions, free, ferraris or auto"));
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

std::optional<core::Verdict> VerdictOf(pb::Verdict kind, std::string_view text) {
  switch (kind) {
    case pb::VERDICT_PASS:
      return core::Verdict::kPass;
    case pb::VERDICT_WARN:
      return core::Verdict::kWarn;
    case pb::VERDICT_FAIL:
      return core::Verdict::kFail;
    case pb::VERDICT_REFUSED:
      return core::Verdict::kRefused;
    default:
      return core::ParseVerdict(text);
  }
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
