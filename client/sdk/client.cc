#include "client/sdk/client.h"

#include <arpa/inet.h>
#include <netinet/in.h>

#include <algorithm>
#include <fstream>
#include <sstream>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "client/sdk/grpc_status.h"
#include "grpcpp/grpcpp.h"

namespace imucal::sdk {

namespace {

absl::StatusOr<std::string> ReadFile(const std::string& what, const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::InvalidArgumentError(absl::StrCat(what, ": cannot read ", path));
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

}  // namespace

absl::StatusOr<ClientOptions> ClientOptionsFromFiles(const std::string& ca_cert_path,
                                                     const std::string& token_path,
                                                     const std::string& client_cert_path,
                                                     const std::string& client_key_path) {
  ClientOptions options;
  struct File {
    const char* what;
    const std::string& path;
    std::string* out;
  };
  for (const File& f : {File{"CA certificate", ca_cert_path, &options.ca_cert_pem},
                        File{"client certificate", client_cert_path, &options.client_cert_pem},
                        File{"client key", client_key_path, &options.client_key_pem}}) {
    if (f.path.empty()) continue;
    absl::StatusOr<std::string> text = ReadFile(f.what, f.path);
    if (!text.ok()) return text.status();
    *f.out = *std::move(text);
  }
  if (!token_path.empty()) {
    absl::StatusOr<std::string> token = ReadTokenFile(token_path);
    if (!token.ok()) return token.status();
    options.bearer_token = *std::move(token);
  }
  if (absl::Status s = ValidateClientOptions(options); !s.ok()) return s;
  return options;
}

absl::StatusOr<std::string> ReadTokenFile(const std::string& path) {
  absl::StatusOr<std::string> text = ReadFile("token file", path);
  if (!text.ok()) return text.status();
  std::string token(absl::StripAsciiWhitespace(*text));
  if (token.empty())
    return absl::InvalidArgumentError(absl::StrCat("token file: ", path, " is empty"));
  return token;
}

absl::Status ValidateClientOptions(const ClientOptions& options) {
  if (options.credentials) return absl::OkStatus();
  if (options.ca_cert_pem.empty() && !options.bearer_token.empty())
    return absl::InvalidArgumentError(
        "a bearer token is sent only over TLS: give the CA certificate of the server too");
  if (options.ca_cert_pem.empty() && !options.client_cert_pem.empty())
    return absl::InvalidArgumentError("a client certificate needs TLS: give the CA certificate");
  if (options.client_cert_pem.empty() != options.client_key_pem.empty())
    return absl::InvalidArgumentError("a client certificate and its key go together");
  return absl::OkStatus();
}

absl::Status CheckTarget(std::string_view target_view) {
  const std::string target(target_view);  // (this absl's string_view is not std's)
  const auto bad = [&](const std::string& why) {
    return absl::InvalidArgumentError(absl::StrCat("server address '", target, "': ", why));
  };
  if (target.empty()) return bad("empty");
  if (target.find_first_of(" \t\n") != std::string_view::npos) return bad("contains a space");
  for (const auto& [scheme, family] : {std::pair{std::string("ipv4:"), AF_INET},
                                       std::pair{std::string("ipv6:"), AF_INET6}}) {
    if (!target.starts_with(scheme)) continue;
    const std::vector<std::string> items =
        absl::StrSplit(target.substr(scheme.size()), ',', absl::AllowEmpty());
    for (const std::string& item : items) {
      const size_t colon = item.rfind(':');
      std::string host(item.substr(0, colon == std::string::npos ? 0 : colon));
      if (family == AF_INET6 && host.size() > 2 && host.front() == '[' && host.back() == ']')
        host = host.substr(1, host.size() - 2);
      int port = 0;
      unsigned char address[sizeof(in6_addr)];
      if (colon == std::string::npos ||
          !absl::SimpleAtoi(item.substr(colon + 1), &port) || port < 1 || port > 65535 ||
          ::inet_pton(family, host.c_str(), address) != 1) {
        return bad(absl::StrCat(
            "'", item, "' is not ", family == AF_INET ? "IPV4:PORT" : "[IPV6]:PORT",
            " (an ", scheme.substr(0, 4), ": list takes IP addresses, e.g. ",
            family == AF_INET ? "ipv4:10.0.0.1:50051,10.0.0.2:50051"
                              : "ipv6:[fd00::1]:50051,[fd00::2]:50051",
            "; a host name goes in dns:///NAME:PORT)"));
      }
    }
  }
  return absl::OkStatus();
}

std::string FirstListedHost(std::string_view target) {
  for (std::string_view scheme : {"ipv4:", "ipv6:"}) {
    if (!target.starts_with(scheme)) continue;
    const std::string_view list = target.substr(scheme.size());
    if (list.find(',') == std::string_view::npos) return "";  // one address: gRPC's own
    const std::string_view first = list.substr(0, list.find(','));
    if (first.starts_with('[')) return std::string(first.substr(1, first.find(']') - 1));
    return std::string(first.substr(0, first.rfind(':')));
  }
  return "";
}

std::shared_ptr<grpc::Channel> MakeChannel(const std::string& target,
                                           const ClientOptions& options) {
  // gRPC's own reconnect backoff (1 s, x1.6 per attempt, up to 120 s) would leave a robot
  // unconnected for up to two minutes after a server restart; capped at
  // max_reconnect_backoff, the channel tries every few seconds at most, so a call waiting for
  // it (wait-for-ready, as the Uploader's are) goes out soon after the server is back. (Not
  // GRPC_ARG_MIN_RECONNECT_BACKOFF_MS: gRPC takes that as each attempt's minimum time to
  // connect, 20 s by default, which a slow link's TLS handshake needs.)
  grpc::ChannelArguments args;
  const int max_ms = static_cast<int>(absl::ToInt64Milliseconds(options.max_reconnect_backoff));
  args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, std::min(max_ms, 250));
  args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, max_ms);
  // Several replicas behind the target (an address list, or a name that resolves to several):
  // gRPC's round_robin spreads the calls over those that answer and leaves out one that dies;
  // a call that was on it fails UNAVAILABLE and its retry goes to another. One address: the
  // same as pick_first.
  args.SetLoadBalancingPolicyName("round_robin");
  auto channel = [&](const std::shared_ptr<grpc::ChannelCredentials>& credentials) {
    return grpc::CreateCustomChannel(target, credentials, args);
  };
  if (options.credentials) return channel(options.credentials);
  if (options.ca_cert_pem.empty() || !ValidateClientOptions(options).ok())
    return channel(grpc::InsecureChannelCredentials());
  // gRPC checks the certificate against the target's authority, which for an address list is
  // the whole list: name one host instead.
  if (const std::string name = options.tls_server_name.empty() ? FirstListedHost(target)
                                                               : options.tls_server_name;
      !name.empty()) {
    args.SetSslTargetNameOverride(name);
  }
  grpc::SslCredentialsOptions tls;
  tls.pem_root_certs = options.ca_cert_pem;
  tls.pem_cert_chain = options.client_cert_pem;
  tls.pem_private_key = options.client_key_pem;
  std::shared_ptr<grpc::ChannelCredentials> credentials = grpc::SslCredentials(tls);
  // The token rides on every call as call credentials: "authorization: Bearer <token>".
  if (!options.bearer_token.empty()) {
    credentials = grpc::CompositeChannelCredentials(
        credentials, grpc::AccessTokenCredentials(options.bearer_token));
  }
  return channel(credentials);
}

StoredParams FromProto(const imucal::v1::ParameterSet& set) {
  return StoredParams{set.device_id(), set.version(), set.crc32c(), set.json()};
}

absl::StatusOr<ParamClient> ParamClient::Create(const std::string& target,
                                                const ClientOptions& options) {
  if (target.empty()) return absl::InvalidArgumentError("server address is empty");
  if (absl::Status s = ValidateClientOptions(options); !s.ok()) return s;
  return ParamClient(MakeChannel(target, options));
}

ParamClient::ParamClient(std::shared_ptr<grpc::Channel> channel)
    : channel_(std::move(channel)), stub_(imucal::v1::ParameterService::NewStub(channel_)) {}

absl::StatusOr<LoadedParams> ParamClient::FetchActive(const std::string& device,
                                                      absl::Duration deadline) {
  bool unchanged = false;
  return FetchActiveIfChanged(device, 0, deadline, &unchanged);
}

absl::StatusOr<LoadedParams> ParamClient::FetchActiveIfChanged(const std::string& device,
                                                               int known_version,
                                                               absl::Duration deadline,
                                                               bool* unchanged) {
  *unchanged = false;
  grpc::ClientContext context;
  context.set_deadline(absl::ToChronoTime(absl::Now() + deadline));
  imucal::v1::GetActiveParametersRequest request;
  request.set_device_id(device);
  request.set_if_not_version(known_version);
  imucal::v1::ParameterSet response;
  if (grpc::Status s = stub_->GetActiveParameters(&context, request, &response); !s.ok())
    return FromGrpcStatus(s);
  if (known_version > 0 && response.version() == known_version && response.json().empty()) {
    *unchanged = true;
    return LoadedParams{};
  }
  if (response.device_id().empty()) response.set_device_id(device);
  return ParseStoredParams(FromProto(response));
}

absl::StatusOr<BootParams> LoadOrFetch(ParamClient& client, const std::string& device,
                                       const std::string& cache_path, absl::Duration deadline) {
  absl::StatusOr<LoadedParams> cached = LoadParamCache(cache_path);
  const bool cache_usable = cached.ok() && cached->stored.device_id == device;
  bool unchanged = false;
  absl::StatusOr<LoadedParams> fetched = client.FetchActiveIfChanged(
      device, cache_usable ? cached->stored.version : 0, deadline, &unchanged);
  if (fetched.ok() && unchanged) {
    return BootParams{*std::move(cached), false,
                      absl::StrFormat("parameters %s v%d: the server's active version, unchanged "
                                      "since the cached copy",
                                      device, cached->stored.version)};
  }
  if (fetched.ok()) {
    BootParams boot{*std::move(fetched), false, ""};
    boot.note =
        absl::StrFormat("parameters %s v%d from the server", device, boot.loaded.stored.version);
    if (absl::Status s = SaveParamCache(cache_path, boot.loaded.stored); !s.ok())
      absl::StrAppend(&boot.note, "; the cache could not be updated: ", s.message());
    return boot;
  }
  if (!IsUnreachable(fetched.status())) return fetched.status();
  if (cache_usable) {
    BootParams boot{*std::move(cached), true, ""};
    boot.note =
        absl::StrFormat("parameters %s v%d from the cache %s: the server was unreachable (%s)",
                        device, boot.loaded.stored.version, cache_path, fetched.status().message());
    return boot;
  }
  const std::string cache_problem =
      cached.ok() ? absl::StrFormat("the cache holds device '%s'", cached->stored.device_id)
                  : std::string(cached.status().message());
  return absl::Status(fetched.status().code(),
                      absl::StrCat("no parameters: the server was unreachable (",
                                   fetched.status().message(), ") and ", cache_problem));
}

}  // namespace imucal::sdk
