// ParameterService of imucal/v1/imucal.proto on the callback API: the robots' fetch of their
// active parameters (the hot path, answered from ActiveParamCache), and the versions'
// history, promotion, rollback, export, and the upload of a parameter set made offline. Store calls
// are short transactions (SQLite or PostgreSQL, storage/store.h) run inline.
#ifndef IMUCAL_SERVER_PARAMETER_SERVICE_H_
#define IMUCAL_SERVER_PARAMETER_SERVICE_H_

#include <memory>
#include <string>
#include <string_view>

#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/active_cache.h"
#include "server/auth.h"
#include "server/convert.h"
#include "server/database_health.h"
#include "storage/store.h"

namespace imucal::server {

// GetActiveParameters, the hot path, is a raw method: its responses come pre-serialised from
// the ActiveParamCache; the other methods are ordinary callback methods.
using ParameterServiceBase = v1::ParameterService::WithRawCallbackMethod_GetActiveParameters<
    v1::ParameterService::WithCallbackMethod_GetParameters<
        v1::ParameterService::WithCallbackMethod_ListVersions<
            v1::ParameterService::WithCallbackMethod_Promote<
                v1::ParameterService::WithCallbackMethod_Rollback<
                    v1::ParameterService::WithCallbackMethod_Export<
                        v1::ParameterService::WithCallbackMethod_UploadParameters<
                            v1::ParameterService::Service>>>>>>>;

class ParameterServiceImpl final : public ParameterServiceBase {
 public:
  // `cache` (not owned, outlives the service) is invalidated by the store's on_active_change;
  // `auth` checks each caller (server/auth.h): not owned, outlives the service.
  // `database` (optional, outlives the service): while it says the database is down,
  // GetActiveParameters answers from the cache, marked served_from_cache.
  ParameterServiceImpl(storage::Store* store, ActiveParamCache* cache, Authorizer* auth,
                       const DatabaseHealth* database = nullptr)
      : store_(store), cache_(cache), auth_(auth), database_(database) {}
  grpc::ServerUnaryReactor* GetActiveParameters(grpc::CallbackServerContext* context,
                                                const grpc::ByteBuffer* request,
                                                grpc::ByteBuffer* response) override;
  grpc::ServerUnaryReactor* GetParameters(grpc::CallbackServerContext* context,
                                          const v1::GetParametersRequest* request,
                                          v1::ParameterSet* response) override;
  grpc::ServerUnaryReactor* ListVersions(grpc::CallbackServerContext* context,
                                         const v1::ListVersionsRequest* request,
                                         v1::ListVersionsResponse* response) override;
  grpc::ServerUnaryReactor* Promote(grpc::CallbackServerContext* context,
                                    const v1::PromoteRequest* request,
                                    v1::ParameterSet* response) override;
  grpc::ServerUnaryReactor* Rollback(grpc::CallbackServerContext* context,
                                     const v1::RollbackRequest* request,
                                     v1::ParameterSet* response) override;
  grpc::ServerUnaryReactor* Export(grpc::CallbackServerContext* context,
                                   const v1::ExportRequest* request,
                                   v1::ExportResponse* response) override;
  grpc::ServerUnaryReactor* UploadParameters(grpc::CallbackServerContext* context,
                                             const v1::UploadParametersRequest* request,
                                             v1::UploadParametersResponse* response) override;

 private:
  absl::Status DoExport(const v1::ExportRequest& request, v1::ExportResponse* response);
  // validate -> parse and judge (server/parameter_upload.h) -> store as the next version.
  absl::Status DoUpload(const v1::UploadParametersRequest& request, std::string_view actor,
                        v1::UploadParametersResponse* response);
  // The cached responses of the device's active version, filled from the store on a miss; the
  // last known ones (`from_cache` set) when the database cannot be reached.
  absl::StatusOr<std::shared_ptr<const ActiveParamCache::Entry>> ActiveEntry(
      const std::string& device_id, bool* from_cache);
  storage::Store* store_;
  ActiveParamCache* cache_;
  Authorizer* auth_;
  const DatabaseHealth* database_;
  ParamCrcCache crc_cache_;  // the CRC, once per version
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_PARAMETER_SERVICE_H_
