#include "server/parameter_service.h"

#include <cmath>
#include <optional>
#include <string>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "core/export.h"
#include "formats/params_json.h"
#include "server/convert.h"
#include "server/parameter_upload.h"
#include "server/unary.h"
#include "util/text_check.h"

namespace imucal::server {
namespace {

absl::Status RequireDevice(const std::string& device_id) {
  return device_id.empty() ? absl::InvalidArgumentError("device_id: required") : absl::OkStatus();
}

absl::Status RequireVersion(int version, const char* field) {
  return version >= 1 ? absl::OkStatus()
                      : absl::InvalidArgumentError(absl::StrCat(field, ": must be 1 or more"));
}

// Promote's and Rollback's `reason` goes into the audit log: free text, but a paragraph at
// most (a 120 KB one was once stored), and no control characters, C0 or C1, but tab and newline
// (a log reader's terminal would interpret them; util/text_check.h).
constexpr size_t kMaxReasonBytes = 1024;

absl::Status ValidateReason(const std::string& reason) {
  if (reason.size() > kMaxReasonBytes) {
    return absl::InvalidArgumentError(
        absl::StrCat("reason: ", reason.size(), " bytes, at most ", kMaxReasonBytes));
  }
  if (std::optional<UnreadableChar> bad = FindUnreadableChar(reason, "\t\n"))
    return absl::InvalidArgumentError(bad->Message("reason"));
  return absl::OkStatus();
}

// The export request's options; a 0 (or empty) field means "not given".
absl::StatusOr<core::ExportOptions> ExportOptionsOf(const v1::ExportRequest& r) {
  core::ExportOptions o;
  if (!r.rostopic().empty()) {
    // Written into the YAML as is: a request field, so INVALID_ARGUMENT here rather than the
    // exporter's refusal of the stored version.
    // Its message quotes the topic as sent ("/imu0 raw"): not a path of the server's.
    if (absl::Status s = core::ValidateRosTopic(r.rostopic()); !s.ok()) return EchoesRequest(s);
    o.rostopic = r.rostopic();
  }
  struct Field {
    const char* name;
    double value;
    double* out;
  };
  for (const Field& f :
       {Field{"update_rate_hz", r.update_rate_hz(), &o.update_rate_hz},
        Field{"accel_noise_density", r.accel_noise_density(), &o.accel_noise_density},
        Field{"accel_random_walk", r.accel_random_walk(), &o.accel_random_walk},
        Field{"gyro_noise_density", r.gyro_noise_density(), &o.gyro_noise_density},
        Field{"gyro_random_walk", r.gyro_random_walk(), &o.gyro_random_walk}}) {
    if (f.value == 0) continue;
    if (!(std::isfinite(f.value) && f.value > 0))
      return absl::InvalidArgumentError(
          absl::StrCat(f.name, ": must be a positive finite number (0: not given)"));
    *f.out = f.value;
  }
  if (r.openvins_model() == "rpng") {
    o.openvins_model = core::OpenVinsModel::kRpng;
  } else if (!r.openvins_model().empty() && r.openvins_model() != "kalibr") {
    return absl::InvalidArgumentError(absl::StrCat("openvins_model: unknown model \"",
                                                   r.openvins_model(), "\" (kalibr or rpng)"));
  }
  return o;
}

// An uploaded document is at most what a request may carry (ServerOptions'
// max_receive_message_bytes default); a parameter set with a 448-sample filter is ~100 KB.
constexpr size_t kMaxUploadJsonBytes = 4 << 20;

absl::Status ValidateUpload(const v1::UploadParametersRequest& r) {
  if (absl::Status s = RequireDevice(r.device_id()); !s.ok()) return s;
  if (r.json().empty()) return absl::InvalidArgumentError("json: required");
  if (r.json().size() > kMaxUploadJsonBytes) {
    return absl::InvalidArgumentError(
        absl::StrCat("json: ", r.json().size(), " bytes, at most ", kMaxUploadJsonBytes));
  }
  return ValidateReason(r.reason());
}

// A ParameterSet with served_from_cache only, serialised once.
const grpc::Slice& FromCacheSlice() {
  static const grpc::Slice* slice = [] {
    v1::ParameterSet marked;
    marked.set_served_from_cache(true);
    return new grpc::Slice(marked.SerializeAsString());
  }();
  return *slice;
}

}  // namespace

absl::StatusOr<std::shared_ptr<const ActiveParamCache::Entry>> ParameterServiceImpl::ActiveEntry(
    const std::string& device_id, bool* from_cache) {
  // While the database cannot be reached, the version the server last knew, said to be that.
  const bool database_down = database_ != nullptr && !database_->up();
  *from_cache = database_down;
  if (std::shared_ptr<const ActiveParamCache::Entry> hit = cache_->Find(device_id)) return hit;
  std::shared_ptr<const ActiveParamCache::Entry> last_known = cache_->FindLastKnown(device_id);
  if (database_down && last_known != nullptr) return last_known;
  const uint64_t generation = cache_->generation();  // before the read: see active_cache.h
  absl::StatusOr<storage::ParamVersion> active = store_->GetActive(device_id);
  if (absl::IsNotFound(active.status())) {
    return absl::NotFoundError(absl::StrCat(
        "device '", device_id, "' has no active parameter set (or is not registered)"));
  }
  if (absl::IsUnavailable(active.status()) && last_known != nullptr) {
    *from_cache = true;  // the outage began before the monitor's next ping
    return last_known;
  }
  *from_cache = false;
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
  // The hot path: check the token (a cached lookup, server/auth.h), parse the small request,
  // answer from the cache (a reference-counted slice, nothing serialised); a miss reads the
  // store once (one indexed lookup) and fills it.
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kGetActiveParameters);
  if (!who.ok()) return FinishUnary(context, who.status());
  v1::GetActiveParametersRequest req;
  {
    grpc::ByteBuffer copy(*request);  // Deserialize consumes its buffer
    if (grpc::Status s =
            grpc::SerializationTraits<v1::GetActiveParametersRequest>::Deserialize(&copy, &req);
        !s.ok())
      return FinishUnary(context,
                         absl::InvalidArgumentError("request: not a GetActiveParametersRequest"));
  }
  if (absl::Status s = RequireDevice(req.device_id()); !s.ok()) return FinishUnary(context, s);
  if (absl::Status s =
          auth_->AuthorizeDevice(*context, **who, Rpc::kGetActiveParameters, req.device_id());
      !s.ok())
    return FinishUnary(context, s);
  bool from_cache = false;
  absl::StatusOr<std::shared_ptr<const ActiveParamCache::Entry>> entry =
      ActiveEntry(req.device_id(), &from_cache);
  if (!entry.ok()) return FinishUnary(context, entry.status());
  const bool unchanged = req.if_not_version() != 0 && req.if_not_version() == (*entry)->version;
  // Two serialised messages one after the other parse as one with the fields of both: the
  // cached answer, then served_from_cache when it is set.
  grpc::Slice slices[2] = {unchanged ? (*entry)->header : (*entry)->full, FromCacheSlice()};
  *response = grpc::ByteBuffer(slices, from_cache ? 2 : 1);
  return FinishUnary(context, absl::OkStatus());
}

grpc::ServerUnaryReactor* ParameterServiceImpl::GetParameters(
    grpc::CallbackServerContext* context, const v1::GetParametersRequest* request,
    v1::ParameterSet* response) {
  if (absl::StatusOr<PrincipalRef> who =
          auth_->AuthorizeForDevice(*context, Rpc::kGetParameters, request->device_id());
      !who.ok())
    return FinishUnary(context, who.status());
  absl::Status valid = RequireDevice(request->device_id());
  if (valid.ok()) valid = RequireVersion(request->version(), "version");
  if (!valid.ok()) return FinishUnary(context, valid);
  absl::StatusOr<storage::ParamVersion> v =
      store_->GetVersion(request->device_id(), request->version());
  if (!v.ok()) return FinishUnary(context, v.status());
  *response = ToProto(*v, /*with_json=*/true, &crc_cache_);
  return FinishUnary(context, absl::OkStatus());
}

grpc::ServerUnaryReactor* ParameterServiceImpl::ListVersions(grpc::CallbackServerContext* context,
                                                             const v1::ListVersionsRequest* request,
                                                             v1::ListVersionsResponse* response) {
  if (absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kListVersions); !who.ok())
    return FinishUnary(context, who.status());
  if (absl::Status s = RequireDevice(request->device_id()); !s.ok()) return FinishUnary(context, s);
  absl::StatusOr<int> size = PageSize(request->page_size(), 1000);
  if (!size.ok()) return FinishUnary(context, size.status());
  storage::VersionQuery query;
  if (!request->page_token().empty() &&
      !absl::SimpleAtoi(request->page_token(), &query.after_version))
    return FinishUnary(context,
                       absl::InvalidArgumentError("page_token: not a token of this listing"));
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
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kPromote);
  if (!who.ok()) return FinishUnary(context, who.status());
  absl::Status valid = RequireDevice(request->device_id());
  if (valid.ok()) valid = RequireVersion(request->version(), "version");
  if (valid.ok()) valid = ValidateReason(request->reason());
  if (!valid.ok()) return FinishUnary(context, valid);
  absl::StatusOr<storage::ParamVersion> v =
      store_->Promote(request->device_id(), request->version(), (*who)->actor, request->reason());
  if (!v.ok()) return FinishUnary(context, v.status());
  *response = ToProto(*v, /*with_json=*/true, &crc_cache_);
  return FinishUnary(context, absl::OkStatus());
}

grpc::ServerUnaryReactor* ParameterServiceImpl::Rollback(grpc::CallbackServerContext* context,
                                                         const v1::RollbackRequest* request,
                                                         v1::ParameterSet* response) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kRollback);
  if (!who.ok()) return FinishUnary(context, who.status());
  absl::Status valid = RequireDevice(request->device_id());
  if (valid.ok()) valid = RequireVersion(request->to_version(), "to_version");
  if (valid.ok()) valid = ValidateReason(request->reason());
  if (!valid.ok()) return FinishUnary(context, valid);
  absl::StatusOr<storage::ParamVersion> v = store_->Rollback(
      request->device_id(), request->to_version(), (*who)->actor, request->reason());
  if (!v.ok()) return FinishUnary(context, v.status());
  *response = ToProto(*v, /*with_json=*/true, &crc_cache_);
  return FinishUnary(context, absl::OkStatus());
}

absl::Status ParameterServiceImpl::DoExport(const v1::ExportRequest& request,
                                            v1::ExportResponse* response) {
  if (absl::Status s = RequireDevice(request.device_id()); !s.ok()) return s;
  if (request.version() < 0) return absl::InvalidArgumentError("version: must be 0 or more");
  std::optional<core::ExportFormat> format;  // empty: json
  if (request.format() != "json") {
    absl::StatusOr<core::ExportFormat> f = core::ParseExportFormat(request.format());
    if (!f.ok()) {
      return absl::InvalidArgumentError(
          absl::StrCat("format: unknown format \"", request.format(),
                       "\" (json, kalibr, kalibr-intrinsics or openvins)"));
    }
    format = *f;
  }
  absl::StatusOr<core::ExportOptions> options = ExportOptionsOf(request);
  if (!options.ok()) return options.status();
  absl::StatusOr<storage::ParamVersion> v =
      request.version() == 0 ? store_->GetActive(request.device_id())
                             : store_->GetVersion(request.device_id(), request.version());
  if (!v.ok()) return v.status();
  const std::string stem = absl::StrCat(v->device_id, "-v", v->version);
  if (!format) {
    response->set_content(v->params_json);
    response->set_filename(absl::StrCat(stem, ".imucal-params.json"));
    return absl::OkStatus();
  }
  absl::StatusOr<core::ParamSet> params = formats::ParamSetFromJson(v->params_json);
  if (!params.ok()) {
    return absl::InternalError(absl::StrCat("version ", v->version, " of ", v->device_id,
                                            " does not parse: ", params.status().message()));
  }
  // The failures are the version's (raw counts, a noise figure missing): FailedPrecondition,
  // with core's message naming what to supply.
  absl::StatusOr<std::string> text = core::ExportParams(*params, *format, *options);
  if (!text.ok()) {
    return absl::Status(text.status().code() == absl::StatusCode::kInvalidArgument
                            ? absl::StatusCode::kFailedPrecondition
                            : text.status().code(),
                        absl::StrCat("version ", v->version, ": ", text.status().message()));
  }
  response->set_content(*std::move(text));
  response->set_filename(
      absl::StrCat(stem, *format == core::ExportFormat::kOpenVins    ? ".kalibr_imu_chain.yaml"
                         : *format == core::ExportFormat::kKalibrImu ? ".imu.yaml"
                                                                     : ".imu-intrinsics.yaml"));
  for (std::string& note : core::ExportNotes(*params, *format, *options))
    response->add_notes(std::move(note));
  return absl::OkStatus();
}

grpc::ServerUnaryReactor* ParameterServiceImpl::Export(grpc::CallbackServerContext* context,
                                                       const v1::ExportRequest* request,
                                                       v1::ExportResponse* response) {
  if (absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kExport); !who.ok())
    return FinishUnary(context, who.status());
  return FinishUnary(context, DoExport(*request, response));
}

}  // namespace imucal::server

namespace imucal::server {

absl::Status ParameterServiceImpl::DoUpload(const v1::UploadParametersRequest& request,
                                            std::string_view actor,
                                            v1::UploadParametersResponse* response) {
  if (absl::Status s = ValidateUpload(request); !s.ok()) return s;
  absl::StatusOr<storage::Device> device = store_->GetDevice(request.device_id());
  if (!device.ok()) return device.status();
  // Its messages name the document's own JSON paths and values, and the device: the client's.
  absl::StatusOr<core::ParamSet> params = ParseUploadedParams(request.json(), *device);
  if (!params.ok()) return EchoesRequest(params.status());
  const core::VerdictResult verdict = JudgeUploadedParams(*params);
  storage::ParamVersion version;
  version.device_id = device->id;
  version.verdict = ToStorage(verdict.verdict);
  version.accel_rms = params->quality_accel_rms_m_s2;
  version.state = ActivationOf(verdict.verdict);
  version.provenance = UploadProvenance(*params, actor);
  // The number is the store's, written into the document in the transaction that assigns it.
  absl::StatusOr<storage::ParamVersion> stored = store_->AddVersion(
      version, actor,
      [&](int number, std::string* params_json, std::string*) {
        params->version = number;
        *params_json = formats::ParamSetToJson(*params);
        return absl::OkStatus();
      },
      request.reason());
  if (!stored.ok()) return stored.status();
  *response->mutable_version() = ToProto(*stored, /*with_json=*/true, &crc_cache_);
  for (const std::string& reason : verdict.reasons) response->add_reasons(reason);
  return absl::OkStatus();
}

grpc::ServerUnaryReactor* ParameterServiceImpl::UploadParameters(
    grpc::CallbackServerContext* context, const v1::UploadParametersRequest* request,
    v1::UploadParametersResponse* response) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kUploadParameters);
  if (!who.ok()) return FinishUnary(context, who.status());
  return FinishUnary(context, DoUpload(*request, (*who)->actor, response));
}

}  // namespace imucal::server
