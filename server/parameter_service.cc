#include <string>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "server/convert.h"
#include "server/services.h"
#include "server/unary.h"

namespace imucal::server {
namespace {

absl::Status RequireDevice(const std::string& device_id) {
  return device_id.empty() ? absl::InvalidArgumentError("device_id: required") : absl::OkStatus();
}

absl::Status RequireVersion(int version, const char* field) {
  return version >= 1 ? absl::OkStatus()
                      : absl::InvalidArgumentError(absl::StrCat(field, ": must be 1 or more"));
}

}  // namespace

absl::StatusOr<std::shared_ptr<const ActiveParamCache::Entry>> ParameterServiceImpl::ActiveEntry(
    const std::string& device_id) {
  if (std::shared_ptr<const ActiveParamCache::Entry> hit = cache_->Find(device_id)) return hit;
  const uint64_t generation = cache_->generation();  // before the read: see active_cache.h
  absl::StatusOr<storage::ParamVersion> active = store_->GetActive(device_id);
  if (absl::IsNotFound(active.status())) {
    return absl::NotFoundError(absl::StrCat(
        "device '", device_id, "' has no active parameter set (or is not registered)"));
  }
  if (!active.ok()) return active.status();
  auto entry = std::make_shared<ActiveParamCache::Entry>();
  entry->version = active->version;
  entry->full = grpc::Slice(ToProto(*active, /*with_json=*/true, &crc_cache_).SerializeAsString());
  entry->header = grpc::Slice(ToProto(*active, /*with_json=*/false).SerializeAsString());
  cache_->Insert(device_id, entry, generation);
  return entry;
}

grpc::ServerUnaryReactor* ParameterServiceImpl::GetActiveParameters(
    grpc::CallbackServerContext* context, const grpc::ByteBuffer* request,
    grpc::ByteBuffer* response) {
  // The hot path: parse the small request, answer from the cache (a reference-counted slice,
  // nothing serialised); a miss reads the store once (one indexed lookup) and fills it.
  v1::GetActiveParametersRequest req;
  {
    grpc::ByteBuffer copy(*request);  // Deserialize consumes its buffer
    if (grpc::Status s =
            grpc::SerializationTraits<v1::GetActiveParametersRequest>::Deserialize(&copy, &req);
        !s.ok())
      return FinishUnary(context, absl::InvalidArgumentError("request: not a GetActiveParametersRequest"));
  }
  if (absl::Status s = RequireDevice(req.device_id()); !s.ok()) return FinishUnary(context, s);
  absl::StatusOr<std::shared_ptr<const ActiveParamCache::Entry>> entry = ActiveEntry(req.device_id());
  if (!entry.ok()) return FinishUnary(context, entry.status());
  const bool unchanged = req.if_not_version() != 0 && req.if_not_version() == (*entry)->version;
  grpc::Slice slice = unchanged ? (*entry)->header : (*entry)->full;
  *response = grpc::ByteBuffer(&slice, 1);
  return FinishUnary(context, absl::OkStatus());
}

grpc::ServerUnaryReactor* ParameterServiceImpl::GetParameters(
    grpc::CallbackServerContext* context, const v1::GetParametersRequest* request,
    v1::ParameterSet* response) {
  absl::Status valid = RequireDevice(request->device_id());
  if (valid.ok()) valid = RequireVersion(request->version(), "version");
  if (!valid.ok()) return FinishUnary(context, valid);
  absl::StatusOr<storage::ParamVersion> v =
      store_->GetVersion(request->device_id(), request->version());
  if (!v.ok()) return FinishUnary(context, v.status());
  *response = ToProto(*v, /*with_json=*/true, &crc_cache_);
  return FinishUnary(context, absl::OkStatus());
}

grpc::ServerUnaryReactor* ParameterServiceImpl::ListVersions(
    grpc::CallbackServerContext* context, const v1::ListVersionsRequest* request,
    v1::ListVersionsResponse* response) {
  if (absl::Status s = RequireDevice(request->device_id()); !s.ok())
    return FinishUnary(context, s);
  absl::StatusOr<int> size = PageSize(request->page_size(), 1000);
  if (!size.ok()) return FinishUnary(context, size.status());
  storage::VersionQuery query;
  if (!request->page_token().empty() && !absl::SimpleAtoi(request->page_token(), &query.after_version))
    return FinishUnary(context, absl::InvalidArgumentError("page_token: not a token of this listing"));
  query.limit = *size + 1;  // one more: whether there is a next page
  absl::StatusOr<std::vector<storage::ParamVersion>> versions =
      store_->ListVersions(request->device_id(), query);
  if (!versions.ok()) return FinishUnary(context, versions.status());
  const bool more = versions->size() > static_cast<size_t>(*size);
  if (more) versions->pop_back();
  for (const storage::ParamVersion& v : *versions)
    *response->add_versions() = ToProto(v, /*with_json=*/false);
  if (more) response->set_next_page_token(absl::StrCat(versions->back().version));
  return FinishUnary(context, absl::OkStatus());
}

grpc::ServerUnaryReactor* ParameterServiceImpl::Promote(grpc::CallbackServerContext* context,
                                                        const v1::PromoteRequest* request,
                                                        v1::ParameterSet* response) {
  absl::Status valid = RequireDevice(request->device_id());
  if (valid.ok()) valid = RequireVersion(request->version(), "version");
  if (!valid.ok()) return FinishUnary(context, valid);
  absl::StatusOr<storage::ParamVersion> v =
      store_->Promote(request->device_id(), request->version(), ActorOf(*context),
                      request->reason());
  if (!v.ok()) return FinishUnary(context, v.status());
  *response = ToProto(*v, /*with_json=*/true, &crc_cache_);
  return FinishUnary(context, absl::OkStatus());
}

grpc::ServerUnaryReactor* ParameterServiceImpl::Rollback(grpc::CallbackServerContext* context,
                                                         const v1::RollbackRequest* request,
                                                         v1::ParameterSet* response) {
  absl::Status valid = RequireDevice(request->device_id());
  if (valid.ok()) valid = RequireVersion(request->to_version(), "to_version");
  if (!valid.ok()) return FinishUnary(context, valid);
  absl::StatusOr<storage::ParamVersion> v =
      store_->Rollback(request->device_id(), request->to_version(), ActorOf(*context),
                       request->reason());
  if (!v.ok()) return FinishUnary(context, v.status());
  *response = ToProto(*v, /*with_json=*/true, &crc_cache_);
  return FinishUnary(context, absl::OkStatus());
}

absl::Status ParameterServiceImpl::DoExport(const v1::ExportRequest& request,
                                            v1::ExportResponse* response) {
  if (absl::Status s = RequireDevice(request.device_id()); !s.ok()) return s;
  if (request.version() < 0) return absl::InvalidArgumentError("version: must be 0 or more");
  if (request.format() == "kalibr" || request.format() == "openvins")
    return absl::UnimplementedError(absl::StrCat(
        "format: export to ", request.format(),
        " is not supported yet (the kalibr and openvins conversions come later); the supported "
        "format is \"json\" (imucal-params v1)"));
  if (request.format() != "json")
    return absl::InvalidArgumentError(absl::StrCat(
        "format: unknown format \"", request.format(),
        "\"; the supported format is \"json\" (\"kalibr\" and \"openvins\" are not supported yet)"));
  absl::StatusOr<storage::ParamVersion> v =
      request.version() == 0 ? store_->GetActive(request.device_id())
                             : store_->GetVersion(request.device_id(), request.version());
  if (!v.ok()) return v.status();
  response->set_content(v->params_json);
  response->set_filename(absl::StrCat(v->device_id, "-v", v->version, ".imucal-params.json"));
  return absl::OkStatus();
}

grpc::ServerUnaryReactor* ParameterServiceImpl::Export(grpc::CallbackServerContext* context,
                                                       const v1::ExportRequest* request,
                                                       v1::ExportResponse* response) {
  return FinishUnary(context, DoExport(*request, response));
}

}  // namespace imucal::server
