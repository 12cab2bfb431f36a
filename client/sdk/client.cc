#include "client/sdk/client.h"

#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/sdk/grpc_status.h"
#include "grpcpp/grpcpp.h"

namespace imucal::sdk {

std::shared_ptr<grpc::Channel> MakeChannel(const std::string& target,
                                           const ClientOptions& options) {
  auto credentials = options.credentials ? options.credentials : grpc::InsecureChannelCredentials();
  return grpc::CreateChannel(target, credentials);
}

StoredParams FromProto(const imucal::v1::ParameterSet& set) {
  return StoredParams{set.device_id(), set.version(), set.crc32c(), set.json()};
}

absl::StatusOr<ParamClient> ParamClient::Create(const std::string& target,
                                                const ClientOptions& options) {
  if (target.empty()) return absl::InvalidArgumentError("server address is empty");
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
