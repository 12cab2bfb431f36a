// The solves of SessionService, from SolveSession to the stored version: starting one (the
// session's last pose flushed, the solve claimed in the store), the job table GetSolveJob
// answers from, and the SolvePool that runs them. A run loads the session's stored samples,
// calibrates them (core::Calibrate), and stores either the version, active on its own only when
// it passes (the activation policy), or the refusal with its report, the session reopened to
// take more poses; it counts the solve in the metrics and tells the session's watchers each
// step of the job. Solves whose server stopped are taken over (ResumeLapsed).
#ifndef IMUCAL_SERVER_SOLVE_JOBS_H_
#define IMUCAL_SERVER_SOLVE_JOBS_H_

#include <cstddef>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "core/calibrate/calibrate.h"
#include "imucal/v1/imucal.pb.h"
#include "server/metrics.h"
#include "server/session_hub.h"
#include "server/session_options.h"
#include "server/solve_pool.h"
#include "storage/store.h"

namespace imucal::server {

class SolveJobs {
 public:
  // The session as GetSession answers it, without loading it (SessionServiceImpl).
  using SessionProtoFn = std::function<absl::StatusOr<v1::Session>(const std::string& session_id)>;
  // The session's open StreamSamples streams (SessionServiceImpl::OpenStreams).
  using OpenStreamsFn =
      std::function<int(const std::string& session_id, const std::string& device_id)>;

  // `store`, `hub` and `options` are the service's and outlive the jobs.
  SolveJobs(storage::Store* store, SessionHub* hub, const SessionServiceOptions& options,
            SessionProtoFn session_proto, OpenStreamsFn open_streams);
  SolveJobs(const SolveJobs&) = delete;
  SolveJobs& operator=(const SolveJobs&) = delete;

  // A SolveJob.id: "solve-<n>", n the solve's id in the store.
  static std::string JobId(int64_t solve_id);

  // Counts solves into `metrics` (which must outlive the jobs). Called before serving.
  void SetMetrics(Metrics* metrics) { metrics_ = metrics; }

  // SolveSession, its session in memory: refused while the solve queue is full, or while a
  // robot still streams into the session (unless `force`d); else the session's last hold is
  // flushed as a pose, the solve started in the store (the session `solving`), and the job
  // queued.
  absl::StatusOr<v1::SolveJob> Start(const std::string& actor,
                                     const std::shared_ptr<LiveSession>& live,
                                     const v1::SolveSessionRequest& request);

  // GetSolveJob: the job as held in memory (queued, running, or finished lately), else as
  // stored (a job of an earlier run of the server, or of another server's).
  absl::Status Get(const std::string& job_id, v1::SolveJob* job);
  // A solve as GetSolveJob reports it, from storage.
  absl::Status FromStore(const storage::Solve& solve, v1::SolveJob* job);

  // Claims the solves whose server stopped (their lease lapsed; with `restarted`, this server's
  // previous life's too) and queues them to run again, while the solve queue has room; fails
  // one started max_solve_attempts times already. Returns how many it queued.
  absl::StatusOr<int> ResumeLapsed(std::string_view restarted = "");

  size_t in_memory();                         // jobs Get answers from memory
  size_t queued() { return pool_.queued(); }  // solves waiting for a solve thread
  void Shutdown() { pool_.Shutdown(); }       // stops taking solves, finishes the queued

 private:
  struct Task {
    int64_t solve_id = 0;
    std::string job_id;
    std::string session_id;
    uint64_t seed = 1;
    std::string actor;
  };
  static Task TaskOf(const storage::Solve& solve);

  // Announces the job queued (to Get and the session's watchers) and submits it on a
  // reservation of pool_.
  v1::SolveJob Queue(const Task& task, LiveSession& live);
  // A solve thread's work: the job from running to done or failed.
  void Run(const Task& task);
  // read -> decode -> calibrate -> store: the job's outcome into `job`; an error before one
  // was stored is returned.
  absl::Status Solve(const Task& task, const LiveSession& live, v1::SolveJob* job);
  absl::Status StoreRefusal(const Task& task, const core::CalibrationReport& report,
                            v1::SolveJob* job);
  absl::Status StoreVersion(const Task& task, const LiveSession& live,
                            const core::CalibrateOptions& options, core::CalibrationReport& report,
                            v1::SolveJob* job);
  // Fails a solve this server has claimed and reopens its session (failed, when the device has
  // another open session).
  absl::Status FailAndReopen(int64_t solve_id, const std::string& error);
  // Records a job's new state and tells the session's watchers.
  void Update(const v1::SolveJob& job);
  // Tells the session's watchers its new state.
  void PublishSession(const std::string& session_id, LiveSession& live);
  void CountSolve(const v1::SolveJob& job, absl::Duration took);

  storage::Store* const store_;
  SessionHub* const hub_;
  const SessionServiceOptions& options_;
  const SessionProtoFn session_proto_;
  const OpenStreamsFn open_streams_;
  Metrics* metrics_ = nullptr;  // null: none kept
  std::mutex jobs_mu_;
  std::map<std::string, v1::SolveJob> jobs_;  // guarded by jobs_mu_
  // Finished jobs in jobs_, oldest first, with when they finished; guarded by jobs_mu_.
  std::deque<std::pair<std::string, absl::Time>> finished_jobs_;
  SolvePool pool_;  // last: its workers use the members above
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_SOLVE_JOBS_H_
