// What the server commands (device_commands.cc, session_commands.cc, solve_command.cc,
// upload_command.cc, report_command.cc, params_commands.cc, export_command.cc, guide.cc) share:
// the server address, stubs, per-call deadlines, gRPC errors -> message and exit code, the
// connection flags' help, the solve that `solve` and `upload --solve` run, and small
// formatting helpers.
#ifndef IMUCAL_CLIENT_CLI_SERVER_COMMON_H_
#define IMUCAL_CLIENT_CLI_SERVER_COMMON_H_

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "client/cli/args.h"
#include "client/sdk/client.h"
#include "core/calibrate/verdict.h"
#include "google/protobuf/timestamp.pb.h"
#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"

namespace imucal::cli {

inline constexpr char kDefaultServer[] = "127.0.0.1:50051";

// The end of each server command's --help: the connection flags and the exit codes.
inline constexpr char kServerFlagHelp[] =
    "  --server ADDR     the calibration service (default $IMUCAL_SERVER, else 127.0.0.1:50051);\n"
    "                    replicas: ipv4:IP:PORT,IP:PORT or dns:///NAME:PORT (calls spread\n"
    "                    round-robin over those that answer)\n"
    "  --ca-cert PEM     CA of the server's TLS certificate (default $IMUCAL_CA_CERT)\n"
    "  --tls-server-name N   the name the certificate holds (default: the host dialled)\n"
    "  --token-file F | --token T   bearer token (default $IMUCAL_TOKEN_FILE, $IMUCAL_TOKEN)\n"
    "exit codes: 0 ok, 1 usage, 2 bad input or unknown id, 3 the state forbids it (e.g. not\n"
    "            enough poses yet), 4 verdict fail, 5 internal, 6 server unreachable,\n"
    "            7 the server refused the token or its role\n";

// --server, else $IMUCAL_SERVER, else kDefaultServer.
std::string ServerAddress(const Args& args);
std::string ServerAddress(const std::optional<std::string>& server_flag);

// The stubs of one channel to the server.
struct Server {
  std::string address;
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<imucal::v1::DeviceService::Stub> devices;
  std::unique_ptr<imucal::v1::SessionService::Stub> sessions;
  std::unique_ptr<imucal::v1::ParameterService::Stub> params;
  std::unique_ptr<imucal::v1::AdminService::Stub> admin;
};
// To ServerAddress(args) with the TLS and token settings TakeConnectionFlags kept (commands.h).
Server Connect(const Args& args);
// To `address` with explicit settings (the demo's robot, which has a token of its own).
Server ConnectWith(const std::string& address, const sdk::ClientOptions& options);
// The settings Connect uses; SetConnectionOptions replaces them (tests).
const sdk::ClientOptions& ConnectionOptions();
void SetConnectionOptions(sdk::ClientOptions options);

// A context for a unary call: deadline 30 s (`--timeout S` where a command offers it).
std::unique_ptr<grpc::ClientContext> CallContext(double timeout_s = 30.0);

// The session calls every command needs, with CallContext()'s deadline.
grpc::Status GetSession(const Server& server, const std::string& session_id,
                        imucal::v1::Session* session);
// gravity_m_s2 0: the server's default (9.80665).
grpc::Status CreateSession(const Server& server, const std::string& device_id,
                           imucal::v1::Protocol protocol, double gravity_m_s2,
                           imucal::v1::Session* session);

// Starts a solve of `session` and, if `wait`, polls the job until it finishes (at most
// timeout_s; with wait, a solve already running is followed). Prints the job (JSON with
// as_json) and returns the exit code: the verdict's when waited for (solve_command.cc).
int SolveAndMaybeWait(const Server& server, const std::string& session, uint64_t seed, bool wait,
                      double timeout_s, bool as_json, bool force = false);

// Every page of a listing: (stub->*list)(context, request, &page) with CallContext()'s deadline,
// 1000 entries a page, from the first page until one comes back without a next_page_token;
// `take` gets each page (a Response&, to move its entries out). The first error, else OK.
template <typename Stub, typename Request, typename Response, typename Take>
grpc::Status ForEachPage(Stub* stub,
                         grpc::Status (Stub::*list)(grpc::ClientContext*, const Request&,
                                                    Response*),
                         Request request, Take take) {
  request.set_page_size(1000);
  do {
    Response page;
    auto ctx = CallContext();
    if (grpc::Status s = (stub->*list)(ctx.get(), request, &page); !s.ok()) return s;
    take(page);
    request.set_page_token(page.next_page_token());
  } while (!request.page_token().empty());
  return grpc::Status::OK;
}

// Prints "imucal: <the server's message>" (for an unreachable server: which address; for a
// server whose database is unavailable: that the server is up, and that) to stderr
// and returns the exit code: kExitUnavailable for UNAVAILABLE / DEADLINE_EXCEEDED, kExitBadInput
// for INVALID_ARGUMENT / NOT_FOUND / ALREADY_EXISTS, kExitUndetermined for FAILED_PRECONDITION,
// kExitDenied for UNAUTHENTICATED / PERMISSION_DENIED, kExitInternal otherwise.
int RpcError(const Server& server, const grpc::Status& status);
// The same for an absl::Status that came from an RPC (same code numbers).
int RpcError(const Server& server, const absl::Status& status);

// Prints "imucal: message\n\nhelp" and returns kExitUsage.
int UsageError(const std::string& message, const char* help);

// Proto enums and times in a technician's words.
std::string ProtocolName(imucal::v1::Protocol protocol);  // "six-face", "positions", "free", "auto"
absl::StatusOr<imucal::v1::Protocol> ParseProtocol(const std::string& name);
std::string SessionStateName(imucal::v1::SessionState state);  // "open", "solving", ...
std::string JobStateName(imucal::v1::JobState state);
std::string VersionStateName(imucal::v1::VersionState state);
// A job's or version's verdict: its verdict_kind, else (a server from before that field) its
// text; nullopt when neither names one.
std::optional<core::Verdict> VerdictOf(imucal::v1::Verdict kind, std::string_view text);
std::string TimeText(const google::protobuf::Timestamp& t);  // RFC 3339, "-" when unset
// A message as JSON with the .proto field names (for --json of listings).
std::string ProtoJson(const google::protobuf::Message& message);

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_SERVER_COMMON_H_
