// SessionService of imucal/v1/imucal.proto on the callback API: a robot's calibration
// sessions, from creation through the sample stream to the solve. Unary handlers validate ->
// convert -> call -> convert -> finish, with short store transactions (SQLite or PostgreSQL,
// storage/store.h) run inline; a session's live state is loaded off the RPC threads; solves are
// SolveJobs' (server/solve_jobs.h); the three streaming calls are reactors (no thread per
// stream, server/stream_reactor.h).
#ifndef IMUCAL_SERVER_SESSION_SERVICE_H_
#define IMUCAL_SERVER_SESSION_SERVICE_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <utility>

#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/auth.h"
#include "server/metrics.h"
#include "server/session_hub.h"
#include "server/session_options.h"
#include "server/solve_jobs.h"
#include "server/solve_pool.h"
#include "server/stream_claims.h"
#include "server/stream_reactor.h"
#include "server/stream_registry.h"
#include "server/stream_slots.h"
#include "storage/store.h"

namespace imucal::server {

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
                                        v1::SessionService::WithCallbackMethod_ReadSamples<
                                            v1::SessionService::Service>>>>>>>>>>>;

class SessionServiceImpl final : public SessionServiceBase {
 public:
  // `auth` checks each caller (server/auth.h): not owned, outlives the service.
  SessionServiceImpl(storage::Store* store, SessionServiceOptions options, Authorizer* auth);
  ~SessionServiceImpl() override;
  size_t live_sessions() { return hub_.LiveSessions(); }  // SessionHub::LiveSessions
  size_t open_streams() { return registry_.size(); }      // the streaming calls
  // StreamSamples streams of the session open now (Session.open_streams), from their first
  // batch until they end: this server's, or 1 while another server sharing the database holds
  // the device's stream claim for the session. The one place that says it: a solve waits on it
  // (SolveSession).
  int OpenStreams(const std::string& session_id, const std::string& device_id);
  size_t solve_jobs_in_memory() { return solves_.in_memory(); }
  // Counts samples and solves into `metrics` (which must outlive the service) and gives it
  // the sessions', streams' and queue's gauges. Called before serving.
  void SetMetrics(Metrics* metrics);
  // Ends the open streams and watches of a token that was just revoked (Authorizer::RevokeToken
  // calls it), and refuses the token's streams from now on.
  void RevokeStreams(int64_t token_id, const std::string& why);

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
  // Pages the stored batches out of storage, one message at a time (read_reactor.cc).
  grpc::ServerWriteReactor<v1::SampleBatch>* ReadSamples(
      grpc::CallbackServerContext* context, const v1::ReadSamplesRequest* request) override;

  // Claims the solves whose server stopped (their lease lapsed; with `restarted`, this server's
  // previous life's too) and queues them to run again, while the solve queue has room; fails
  // one started max_solve_attempts times already. Returns how many it queued. The server calls
  // it at start and with every lease renewal.
  absl::StatusOr<int> ResumeLapsedSolves(std::string_view restarted = "") {
    return solves_.ResumeLapsed(restarted);
  }

  // Another server sharing the database stored a batch of the session or changed its state
  // (Store::ListenForChanges; called on the listener's thread, so quick). When the session is
  // watched here, it is read again off that thread, and its watchers get what changed: the
  // poses and pairs of the new batches, the session's new state and its solve's job, and the
  // end of the watch when the session closed. Watchers on any replica follow a session whose
  // robot streams, or whose solve runs, on another.
  void SessionChangedElsewhere(std::string_view session_id);
  // Every watched session, read again: change notifications may have been missed.
  void RefreshWatchedSessions();

  // Stops taking solves and finishes the queued ones (graceful shutdown, after the server's).
  void DrainSolves() {
    loaders_.Shutdown();
    solves_.Shutdown();
  }

 private:
  // Runs `work` with the session's live state and finishes the call with its status: at once
  // when the session is in memory, else on the session loaders after loading it (decoding and
  // replaying every stored batch: seconds for millions of samples, never on an RPC thread).
  grpc::ServerUnaryReactor* WithLiveSession(
      grpc::CallbackServerContext* context, const std::string& session_id,
      std::function<absl::Status(const std::shared_ptr<LiveSession>& live)> work);
  bool Defer(std::function<void()> work);  // on the session loaders; false when full
  absl::Status DoCancel(const std::string& actor, const std::shared_ptr<LiveSession>& live,
                        v1::Session* response);
  void Refresh(const std::shared_ptr<LiveSession>& live);  // SessionChangedElsewhere's work
  absl::Status DoGetReport(const v1::GetReportRequest& request, v1::Report* response);
  absl::Status DoListPoses(const v1::ListPosesRequest& request, v1::ListPosesResponse* response);
  absl::StatusOr<v1::Session> SessionProto(const std::string& session_id);
  absl::StatusOr<v1::Session> SessionProtoWithoutJob(const std::string& session_id);

  storage::Store* store_;
  Authorizer* auth_;
  const SessionServiceOptions options_;
  SessionHub hub_;
  StreamSlots stream_slots_;     // StreamSamples per device
  StreamClaims stream_claims_;   // ...and across the servers sharing the database
  StreamSlots watcher_slots_;    // WatchSession per session
  StreamSlots session_streams_;  // StreamSamples per session: OpenStreams
  StreamRegistry registry_;  // every open StreamSamples, WatchSession and ReadSamples
  StreamEnv env_;
  SolveJobs solves_;   // its solve threads use the members above
  SolvePool loaders_;  // last: loads sessions off the RPC threads (WithLiveSession, streams)
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_SESSION_SERVICE_H_
