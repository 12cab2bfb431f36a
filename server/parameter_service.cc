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

grpc::ServerUnaryReactor* ParameterServiceImpl::GetActiveParameters(
    grpc::CallbackServerContext* context, const v1::GetActiveParametersRequest* request,
    v1::ParameterSet* response) {
  if (absl::Status s = RequireDevice(request->device_id()); !s.ok())
    return FinishUnary(context, s);
  // The hot path: one indexed lookup.
  absl::StatusOr<storage::ParamVersion> active = store_->GetActive(request->device_id());
  if (absl::IsNotFound(active.status())) {
    return FinishUnary(context, absl::NotFoundError(absl::StrCat(
                                    "device '", request->device_id(),
                                    "' has no active parameter set (or is not registered)")));
  }
  if (!active.ok()) return FinishUnary(context, active.status());
  const bool unchanged =
      request->if_not_version() != 0 && request->if_not_version() == active->version;
  *response = ToProto(*active, /*with_json=*/!unchanged, &crc_cache_);
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
    return absl::UnimplementedError(
        absl::StrCat("format: ", request.format(), " comes with the ecosystem issue"));
  if (request.format() != "json")
    return absl::InvalidArgumentError("format: must be \"json\", \"kalibr\" or \"openvins\"");
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
