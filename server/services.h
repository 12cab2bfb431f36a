// The three gRPC services of imucal/v1/imucal.proto on the callback API. Handlers read
// validate -> convert -> call -> convert -> finish; store calls are short SQLite transactions
// run inline, solves run in the SolvePool, streams are reactors (no thread per stream).
#ifndef IMUCAL_SERVER_SERVICES_H_
#define IMUCAL_SERVER_SERVICES_H_

#include <cstdint>
#include <map>
#include <mutex>
#include <string>

#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/active_cache.h"
#include "server/auth.h"
#include "server/convert.h"
#include "server/session_hub.h"
#include "server/solve_pool.h"
#include "server/stream_slots.h"
#include "server/validate.h"
#include "storage/store.h"

namespace imucal::server {

// Every service checks its caller with an Authorizer (server/auth.h): not owned, outlives it.

// Pages are by key (the store's paging): the token is the key of a page's last item. Returns
// the page size to use (0 means 100; at most `max_page_size`).
absl::StatusOr<int> PageSize(int page_size, int max_page_size);

class DeviceServiceImpl final : public v1::DeviceService::CallbackService {
 public:
  DeviceServiceImpl(storage::Store* store, Authorizer* auth) : store_(store), auth_(auth) {}
  grpc::ServerUnaryReactor* RegisterDevice(grpc::CallbackServerContext* context,
                                           const v1::RegisterDeviceRequest* request,
                                           v1::Device* response) override;
  grpc::ServerUnaryReactor* GetDevice(grpc::CallbackServerContext* context,
                                      const v1::GetDeviceRequest* request,
                                      v1::Device* response) override;
  grpc::ServerUnaryReactor* ListDevices(grpc::CallbackServerContext* context,
                                        const v1::ListDevicesRequest* request,
                                        v1::ListDevicesResponse* response) override;

 private:
  absl::Status DoRegister(const grpc::CallbackServerContext& context,
                          const v1::RegisterDeviceRequest& request, v1::Device* response);
  storage::Store* store_;
  Authorizer* auth_;
};

// GetActiveParameters, the hot path, is a raw method: its responses come pre-serialised from
// the ActiveParamCache; the other methods are ordinary callback methods.
using ParameterServiceBase = v1::ParameterService::WithRawCallbackMethod_GetActiveParameters<
    v1::ParameterService::WithCallbackMethod_GetParameters<
        v1::ParameterService::WithCallbackMethod_ListVersions<
            v1::ParameterService::WithCallbackMethod_Promote<
                v1::ParameterService::WithCallbackMethod_Rollback<
                    v1::ParameterService::WithCallbackMethod_Export<
                        v1::ParameterService::Service>>>>>>;

class ParameterServiceImpl final : public ParameterServiceBase {
 public:
  // `cache` (not owned, outlives the service) is invalidated by the store's on_active_change.
  ParameterServiceImpl(storage::Store* store, ActiveParamCache* cache, Authorizer* auth)
      : store_(store), cache_(cache), auth_(auth) {}
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

 private:
  absl::Status DoExport(const v1::ExportRequest& request, v1::ExportResponse* response);
  // The cached responses of the device's active version, filled from the store on a miss.
  absl::StatusOr<std::shared_ptr<const ActiveParamCache::Entry>> ActiveEntry(
      const std::string& device_id);
  storage::Store* store_;
  ActiveParamCache* cache_;
  Authorizer* auth_;
  ParamCrcCache crc_cache_;  // the CRC, once per version
};

struct SessionServiceOptions {
  int solve_threads = 2;
  size_t solve_queue_limit = 16;  // solves waiting for a worker; RESOURCE_EXHAUSTED beyond
  IngestLimits ingest;            // samples per batch and per session (server/validate.h)
  // Concurrent StreamSamples per device (RESOURCE_EXHAUSTED beyond); a stream holds its slot
  // from its first batch until it ends (a dead peer is found by keepalive, see ServerOptions).
  int max_streams_per_device = 1;
  int max_watchers_per_session = 16;  // concurrent WatchSession streams (RESOURCE_EXHAUSTED)
};

// StreamSamples is a raw method (ByteBuffers in and out): a batch that is not a SampleBatch
// then gets INVALID_ARGUMENT, where the generated reader would end the stream as if the robot
// had closed it (gRPC reports a failed parse as a failed read).
using SessionServiceBase = v1::SessionService::WithRawCallbackMethod_StreamSamples<
    v1::SessionService::WithCallbackMethod_CreateSession<
        v1::SessionService::WithCallbackMethod_GetSession<
            v1::SessionService::WithCallbackMethod_ListSessions<
                v1::SessionService::WithCallbackMethod_CancelSession<
                    v1::SessionService::WithCallbackMethod_WatchSession<
                        v1::SessionService::WithCallbackMethod_ListPoses<
                            v1::SessionService::WithCallbackMethod_SolveSession<
                                v1::SessionService::WithCallbackMethod_GetSolveJob<
                                    v1::SessionService::WithCallbackMethod_GetReport<
                                        v1::SessionService::Service>>>>>>>>>>;

class SessionServiceImpl final : public SessionServiceBase {
 public:
  SessionServiceImpl(storage::Store* store, SessionServiceOptions options, Authorizer* auth);
  ~SessionServiceImpl() override;
  size_t live_sessions() { return hub_.LiveSessions(); }  // SessionHub::LiveSessions

  grpc::ServerUnaryReactor* CreateSession(grpc::CallbackServerContext* context,
                                          const v1::CreateSessionRequest* request,
                                          v1::Session* response) override;
  grpc::ServerUnaryReactor* GetSession(grpc::CallbackServerContext* context,
                                       const v1::GetSessionRequest* request,
                                       v1::Session* response) override;
  grpc::ServerUnaryReactor* ListSessions(grpc::CallbackServerContext* context,
                                         const v1::ListSessionsRequest* request,
                                         v1::ListSessionsResponse* response) override;
  grpc::ServerUnaryReactor* CancelSession(grpc::CallbackServerContext* context,
                                          const v1::CancelSessionRequest* request,
                                          v1::Session* response) override;
  grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer>* StreamSamples(
      grpc::CallbackServerContext* context) override;
  grpc::ServerWriteReactor<v1::SessionEvent>* WatchSession(
      grpc::CallbackServerContext* context, const v1::WatchSessionRequest* request) override;
  grpc::ServerUnaryReactor* ListPoses(grpc::CallbackServerContext* context,
                                      const v1::ListPosesRequest* request,
                                      v1::ListPosesResponse* response) override;
  grpc::ServerUnaryReactor* SolveSession(grpc::CallbackServerContext* context,
                                         const v1::SolveSessionRequest* request,
                                         v1::SolveJob* response) override;
  grpc::ServerUnaryReactor* GetSolveJob(grpc::CallbackServerContext* context,
                                        const v1::GetSolveJobRequest* request,
                                        v1::SolveJob* response) override;
  grpc::ServerUnaryReactor* GetReport(grpc::CallbackServerContext* context,
                                      const v1::GetReportRequest* request,
                                      v1::Report* response) override;

  // Stops taking solves and finishes the queued ones (graceful shutdown, after the server's).
  void DrainSolves() { pool_.Shutdown(); }

 private:
  struct SolveTask {
    int64_t solve_id = 0;
    std::string job_id;
    std::string session_id;
    uint64_t seed = 1;
    std::string actor;
  };
  absl::Status DoSolve(const grpc::CallbackServerContext& context,
                       const v1::SolveSessionRequest& request, v1::SolveJob* response);
  absl::Status DoGetSolveJob(const v1::GetSolveJobRequest& request, v1::SolveJob* response);
  absl::Status DoGetReport(const v1::GetReportRequest& request, v1::Report* response);
  absl::Status DoListPoses(const v1::ListPosesRequest& request, v1::ListPosesResponse* response);
  void RunSolve(const SolveTask& task);
  // Records a job's new state and tells the session's watchers.
  void UpdateJob(const v1::SolveJob& job);
  absl::StatusOr<v1::Session> SessionProto(const std::string& session_id);

  storage::Store* store_;
  Authorizer* auth_;
  const SessionServiceOptions options_;
  SessionHub hub_;
  StreamSlots stream_slots_;   // StreamSamples per device
  StreamSlots watcher_slots_;  // WatchSession per session
  std::mutex jobs_mu_;
  std::map<std::string, v1::SolveJob> jobs_;  // guarded by jobs_mu_
  // Serialises "predict the next version number, store the version": the params JSON carries
  // its version, so the number must be known before the version is stored.
  std::mutex version_mu_;
  SolvePool pool_;  // last: its workers use the members above
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_SERVICES_H_
