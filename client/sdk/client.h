// The robot SDK's network part: fetching the active parameter set from the calibration service
// and booting from the local cache when the service cannot be reached. Robots that only apply
// parameters link imucal::sdk alone; this (imucal::sdk_client) brings in gRPC.
//
// Typical startup (see client/examples/robot_startup.cc):
//   sdk::ClientOptions tls = *sdk::ClientOptionsFromFiles("/etc/imu/ca.pem", "/etc/imu/token");
//   auto client = sdk::ParamClient::Create("calib.fleet:50051", tls);
//   auto boot = sdk::LoadOrFetch(*client, "robot-0042", "/var/lib/imu/params.cache",
//                                absl::Seconds(2));
//   auto corrector = sdk::Corrector::Create(boot->loaded.params);
#ifndef IMUCAL_CLIENT_SDK_CLIENT_H_
#define IMUCAL_CLIENT_SDK_CLIENT_H_

#include <memory>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "client/sdk/param_cache.h"
#include "imucal/v1/imucal.grpc.pb.h"

namespace grpc {
class Channel;
class ChannelCredentials;
}  // namespace grpc

namespace imucal::sdk {

// How to reach the service. imucald serves TLS and wants a bearer token on every call (README
// "Security"); only a server started with `insecure` (loopback, tests) takes plaintext.
struct ClientOptions {
  // PEM of the CA that signed the server's certificate. Empty: plaintext.
  std::string ca_cert_pem;
  // Optional mutual TLS: the robot's certificate (common name = its device id) and key, PEM.
  // The server accepts it in place of a token when it trusts the certificate's CA.
  std::string client_cert_pem;
  std::string client_key_pem;
  // Sent as "authorization: Bearer <token>" on every call of the channel (gRPC call
  // credentials, which gRPC sends only over TLS: a token needs ca_cert_pem).
  std::string bearer_token;
  // The name the server's certificate must hold. Empty: the host of the address dialled, or,
  // for a list of replicas ("ipv4:10.0.0.1:50051,10.0.0.2:50051"), of its first address (the
  // replicas share one certificate, README "Scaling out").
  std::string tls_server_name;
  // Overrides all of the above when set (e.g. credentials a test builds).
  std::shared_ptr<grpc::ChannelCredentials> credentials;
  // The longest the channel waits between attempts to (re)connect (gRPC's default is 120 s;
  // each wait is jittered by +-20%). After the server comes back, a call waiting for the
  // channel goes out within about this long; while it is down, each robot tries a connection
  // this often. The Uploader's retry policy (uploader.h) counts on it.
  absl::Duration max_reconnect_backoff = absl::Seconds(2);
};

// InvalidArgument naming what is wrong with a gRPC target that gRPC itself would only log about
// (and then fail every call): a space, or an "ipv4:"/"ipv6:" list whose items are not IP:PORT
// (host names go in "dns:///NAME:PORT"). Other targets are left to gRPC's resolver.
absl::Status CheckTarget(std::string_view target);

// The host of the first address of an "ipv4:" or "ipv6:" list of several ("10.0.0.1" of
// "ipv4:10.0.0.1:50051,10.0.0.2:50051"); empty for any other target.
std::string FirstListedHost(std::string_view target);

// Reads the PEM files and the token (a file holding the secret; surrounding whitespace is
// dropped). Empty paths are left out. InvalidArgument naming the file that cannot be read.
absl::StatusOr<ClientOptions> ClientOptionsFromFiles(const std::string& ca_cert_path,
                                                     const std::string& token_path,
                                                     const std::string& client_cert_path = "",
                                                     const std::string& client_key_path = "");

// The secret in a token file (surrounding whitespace dropped); InvalidArgument when the file
// cannot be read or is empty.
absl::StatusOr<std::string> ReadTokenFile(const std::string& path);

// InvalidArgument for options that cannot work: a token or a client certificate without TLS
// (ca_cert_pem), a client certificate without its key or the other way round.
absl::Status ValidateClientOptions(const ClientOptions& options);

// Creates a channel to `target` ("host:port", any gRPC target URI). The channel connects
// lazily: an unreachable server shows up in the first call, not here. Options that fail
// ValidateClientOptions give a plaintext channel without the token, whose calls the server
// refuses: check them first (ParamClient::Create does).
std::shared_ptr<grpc::Channel> MakeChannel(const std::string& target,
                                           const ClientOptions& options = {});

// Converts a received ParameterSet to the SDK's plain form.
StoredParams FromProto(const imucal::v1::ParameterSet& set);

class ParamClient {
 public:
  // InvalidArgument for an empty target or options that fail ValidateClientOptions.
  static absl::StatusOr<ParamClient> Create(const std::string& target,
                                            const ClientOptions& options = {});
  explicit ParamClient(std::shared_ptr<grpc::Channel> channel);

  // GetActiveParameters for `device` with a deadline. The JSON is checked against the server's
  // crc32c (DataLoss on a mismatch) and parsed (InvalidArgument if it does not parse). Errors
  // from the server keep its code and message: NOT_FOUND when the device has no active set,
  // UNAVAILABLE / DEADLINE_EXCEEDED when the server could not be reached in time.
  absl::StatusOr<LoadedParams> FetchActive(const std::string& device, absl::Duration deadline);

  // As FetchActive, sending if_not_version = known_version (0: none). When the server answers
  // with the header only (the active version is still known_version), sets *unchanged and
  // returns an empty LoadedParams: the caller's copy is current.
  absl::StatusOr<LoadedParams> FetchActiveIfChanged(const std::string& device, int known_version,
                                                    absl::Duration deadline, bool* unchanged);

 private:
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<imucal::v1::ParameterService::Stub> stub_;
};

// What LoadOrFetch booted with.
struct BootParams {
  LoadedParams loaded;
  bool from_cache = false;  // true: the server was unreachable, these are the cached ones
  // One sentence for the robot's log: where the parameters came from and why; when the cache
  // could not be updated, that too.
  std::string note;
};

// Fetches the active set with `deadline` and, on success, updates the cache at `cache_path`
// (a failure to write the cache is reported in `note`, not an error). When the server is
// unreachable (UNAVAILABLE or DEADLINE_EXCEEDED) it boots with the cached set instead, if the
// cache is valid and for the same device, and says so in `note`. Any other server answer
// (NOT_FOUND: no active set; a checksum mismatch) is returned as it is: the server is
// authoritative when it answers. When neither works, the error names both causes.
absl::StatusOr<BootParams> LoadOrFetch(ParamClient& client, const std::string& device,
                                       const std::string& cache_path, absl::Duration deadline);

}  // namespace imucal::sdk

#endif  // IMUCAL_CLIENT_SDK_CLIENT_H_
