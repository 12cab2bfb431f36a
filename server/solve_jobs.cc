#include "server/solve_jobs.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/escaping.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/strip.h"
#include "absl/time/clock.h"
#include "formats/params_json.h"
#include "formats/report_json.h"
#include "server/convert.h"
#include "server/log.h"
#include "server/parameter_upload.h"
#include "server/status_util.h"
#include "storage/sample_codec.h"
#include "util/str_util.h"

namespace imucal::server {
namespace {

constexpr char kJobPrefix[] = "solve-";
constexpr char kServerActor[] = "imucald";  // the audit's actor for what the server does itself

// A SolveJob.id: "solve-<n>", n the solve's id as the server writes it, a positive decimal
// integer without sign, spaces or leading zeros (absl::SimpleAtoi alone took "solve--1" and
// "solve- 7", which then went to storage and came back NOT_FOUND). At most 18 digits: int64.
absl::StatusOr<int64_t> ParseJobId(const std::string& job_id) {
  if (job_id.empty()) return absl::InvalidArgumentError("job_id: required");
  absl::string_view digits = job_id;
  const bool well_formed =
      absl::ConsumePrefix(&digits, kJobPrefix) && !digits.empty() && digits.size() <= 18 &&
      digits[0] != '0' &&
      std::all_of(digits.begin(), digits.end(), [](char c) { return c >= '0' && c <= '9'; });
  int64_t id = 0;
  if (!well_formed || !absl::SimpleAtoi(digits, &id)) {
    // The id as sent, escaped (it may hold anything) and cut to a readable length.
    const std::string shown = absl::CHexEscape(job_id.substr(0, 64));
    return EchoesRequest(absl::InvalidArgumentError(
        absl::StrCat("job_id: '", shown, job_id.size() > 64 ? "...' " : "' ",
                     "is not a solve job id (\"solve-<n>\", n a positive integer, as SolveSession "
                     "returns it)")));
  }
  return id;
}

// A refused solve's error: the refusal's name (core/calibrate/report.h) and core's description
// of the capture and of what to record.
std::string RefusalMessage(const core::CalibrationReport& report) {
  if (!report.refusal) return "the capture cannot support a calibration";
  return Cat("the capture cannot support a calibration (",
             core::RefusalReasonName(report.refusal->reason), "): ", report.refusal->message);
}

// The session's stored batches as a core::Capture in the device's units. What the capture
// had to leave out is said in `warnings` (it goes into the report).
absl::StatusOr<core::Capture> LoadCapture(storage::Store& store, const LiveSession& live,
                                          std::vector<std::string>* warnings) {
  absl::StatusOr<std::vector<storage::SampleBatch>> batches = store.ReadBatches(live.id);
  if (!batches.ok()) return batches.status();
  std::vector<storage::ImuSample> samples;
  for (const storage::SampleBatch& b : *batches)
    if (absl::Status s = storage::DecodeSamplesInto(b.payload, &samples); !s.ok()) return s;
  core::Capture cap;
  cap.device = live.device.id;
  absl::StatusOr<core::AccelUnit> au = core::ParseAccelUnit(live.device.accel_unit);
  absl::StatusOr<core::GyroUnit> gu = core::ParseGyroUnit(live.device.gyro_unit);
  if (!au.ok()) return au.status();
  if (!gu.ok()) return gu.status();
  cap.accel_unit = *au;
  cap.gyro_unit = *gu;
  cap.gravity_m_s2 = live.gravity_m_s2;
  cap.rate_hz = live.device.nominal_rate_hz;
  const bool has_temp = !samples.empty() && !std::isnan(samples.front().temp);
  cap.t_s.reserve(samples.size());
  cap.accel.reserve(samples.size());
  cap.gyro.reserve(samples.size());
  for (const storage::ImuSample& x : samples) {
    cap.t_s.push_back(x.t_s);
    cap.accel.emplace_back(x.accel[0], x.accel[1], x.accel[2]);
    cap.gyro.emplace_back(x.gyro[0], x.gyro[1], x.gyro[2]);
    if (has_temp) cap.temp.push_back(std::isnan(x.temp) ? 0.0 : x.temp);
  }
  // Batches with and without temperature may mix (a robot whose sensor driver dropped the
  // channel for a while): then the capture has none, and the report says so, since temperature
  // effects can then not be tested.
  size_t without = 0;
  for (const storage::ImuSample& x : samples) without += std::isnan(x.temp) ? 1 : 0;
  if (without > 0 && without < samples.size()) {
    cap.temp.clear();
    warnings->push_back(absl::StrFormat(
        "temperature left out of the solve: %d of the session's %d samples came in batches "
        "without temp_c, and a capture has temperature for every sample or none; temperature "
        "effects were not tested. Send temp_c in every batch (or in none)",
        static_cast<int>(without), static_cast<int>(samples.size())));
  }
  return cap;
}

v1::JobState ToJobState(storage::SolveState state) {
  switch (state) {
    case storage::SolveState::kRunning:
      return v1::JOB_STATE_RUNNING;
    case storage::SolveState::kSucceeded:
      return v1::JOB_STATE_DONE;
    case storage::SolveState::kFailed:
      return v1::JOB_STATE_FAILED;
  }
  return v1::JOB_STATE_UNSPECIFIED;
}

}  // namespace

SolveJobs::SolveJobs(storage::Store* store, SessionHub* hub, const SessionServiceOptions& options,
                     SessionProtoFn session_proto, OpenStreamsFn open_streams)
    : store_(store),
      hub_(hub),
      options_(options),
      session_proto_(std::move(session_proto)),
      open_streams_(std::move(open_streams)),
      pool_(options.solve_threads, options.solve_queue_limit) {}

std::string SolveJobs::JobId(int64_t solve_id) { return absl::StrCat(kJobPrefix, solve_id); }

SolveJobs::Task SolveJobs::TaskOf(const storage::Solve& solve) {
  Task task;
  task.solve_id = solve.id;
  task.job_id = JobId(solve.id);
  task.session_id = solve.session_id;
  task.seed = solve.seed;
  task.actor = solve.actor;
  return task;
}

size_t SolveJobs::in_memory() {
  std::lock_guard lock(jobs_mu_);
  return jobs_.size();
}

absl::StatusOr<v1::SolveJob> SolveJobs::Start(const std::string& actor,
                                              const std::shared_ptr<LiveSession>& live,
                                              const v1::SolveSessionRequest& request) {
  if (!pool_.Reserve()) {
    return absl::ResourceExhaustedError(
        "the solve queue is full; retry in a minute (GetSolveJob shows running jobs)");
  }
  // A robot still uploading into the session: solving now would end its stream and leave the
  // rest of its capture unstored (the guide waits for Session.open_streams to fall to 0).
  if (const int open = open_streams_(request.session_id(), live->device.id);
      open > 0 && !request.force()) {
    pool_.Release();
    return absl::FailedPreconditionError(absl::StrCat(
        "session ", request.session_id(), " has ", open, " sample stream", open == 1 ? "" : "s",
        " open (device ", live->device.id,
        " is still uploading into it): a solve now would end the upload and leave the rest of "
        "the capture unstored; solve once the stream has ended (Session.open_streams is 0), or "
        "force the solve (SolveSessionRequest.force, imucal solve --force)"));
  }
  absl::StatusOr<storage::Solve> solve;
  std::vector<LiveEvent> last_pose;
  {
    std::lock_guard lock(live->mu);  // no batch lands after the solve has started
    solve = store_->StartSolve(request.session_id(), actor,
                               {options_.replica_id, absl::Now() + options_.solve_lease},
                               request.seed() == 0 ? 1 : request.seed());
    if (solve.ok()) {
      FlushSegment(*live, &last_pose);  // the final hold is a pose
      std::vector<storage::Pose> poses;
      std::vector<storage::PosePair> pairs;
      ToRows(last_pose, &poses, &pairs);
      store_->SavePoses(request.session_id(), poses, pairs).IgnoreError();  // as in IngestBatch
    }
  }
  if (!solve.ok()) {
    pool_.Release();
    return solve.status();
  }
  hub_->Reopen(live);
  for (const v1::SessionEvent& e : SessionHub::ToEvents(last_pose)) hub_->Publish(*live, e);
  return Queue(TaskOf(*solve), *live);
}

v1::SolveJob SolveJobs::Queue(const Task& task, LiveSession& live) {
  v1::SolveJob job;
  job.set_id(task.job_id);
  job.set_session_id(task.session_id);
  job.set_state(v1::JOB_STATE_QUEUED);
  Update(job);
  PublishSession(task.session_id, live);
  pool_.Submit([this, task] { Run(task); });
  return job;
}

void SolveJobs::Run(const Task& task) {
  const absl::Time started = absl::Now();
  v1::SolveJob job;
  job.set_id(task.job_id);
  job.set_session_id(task.session_id);
  job.set_state(v1::JOB_STATE_RUNNING);
  Update(job);
  absl::StatusOr<std::shared_ptr<LiveSession>> live = hub_->Get(task.session_id);
  absl::Status failure = live.ok() ? Solve(task, **live, &job) : live.status();
  if (job.state() != v1::JOB_STATE_DONE && job.state() != v1::JOB_STATE_FAILED) {
    if (failure.ok()) failure = absl::InternalError("solve ended without a result");
    job.set_state(v1::JOB_STATE_FAILED);
    job.set_error(ClientMessage(failure));
    store_
        ->FailSolve(task.solve_id, job.error(), /*report_json=*/"", task.actor,
                    storage::SessionState::kFailed, options_.replica_id)
        .IgnoreError();
  }
  Update(job);
  CountSolve(job, absl::Now() - started);
  if (!live.ok()) return;
  PublishSession(task.session_id, **live);
  hub_->CloseSession(**live);
}

absl::Status SolveJobs::Solve(const Task& task, const LiveSession& live, v1::SolveJob* job) {
  std::vector<std::string> load_warnings;
  absl::StatusOr<core::Capture> capture = LoadCapture(*store_, live, &load_warnings);
  if (!capture.ok()) return capture.status();
  core::CalibrateOptions options;
  options.protocol = ToProtocolKind(live.protocol);
  options.seed = task.seed;
  absl::StatusOr<core::CalibrationReport> report = core::Calibrate(*capture, options);
  if (!report.ok()) return report.status();
  for (std::string& w : load_warnings) report->warnings.push_back(std::move(w));
  report->device = live.device.id;
  if (report->verdict == core::Verdict::kRefused) return StoreRefusal(task, *report, job);
  return StoreVersion(task, live, options, *report, job);
}

// The capture cannot determine even bias and scale: no version. The report (the poses found,
// why each interval is unusable) is kept with the failed solve, and the session goes back to
// open, its samples untouched, so that more poses can be recorded into it.
absl::Status SolveJobs::StoreRefusal(const Task& task, const core::CalibrationReport& report,
                                     v1::SolveJob* job) {
  const std::string error = RefusalMessage(report);
  absl::StatusOr<storage::Solve> failed =
      store_->FailSolve(task.solve_id, error, formats::ReportToJson(report), task.actor,
                        storage::SessionState::kOpen, options_.replica_id);
  if (!failed.ok()) return failed.status();
  job->set_state(v1::JOB_STATE_FAILED);
  job->set_error(ScrubMessage(error));
  SetVerdict(core::Verdict::kRefused, job);
  return absl::OkStatus();
}

absl::Status SolveJobs::StoreVersion(const Task& task, const LiveSession& live,
                                     const core::CalibrateOptions& options,
                                     core::CalibrationReport& report, v1::SolveJob* job) {
  report.params.device = live.device.id;
  report.params.source_session = task.session_id;
  report.params.software = "imucald " IMUCAL_VERSION;
  storage::ParamVersion version;
  version.device_id = live.device.id;
  version.session_id = task.session_id;
  version.verdict = ToStorage(report.verdict);
  version.accel_rms = report.residual.accel_rms_m_s2;
  version.state = ActivationOf(report.verdict);
  version.provenance = absl::StrFormat("imucald %s; protocol %s; seed %d", IMUCAL_VERSION,
                                       core::ProtocolKindName(options.protocol), options.seed);
  // The number is the store's, assigned in the transaction that writes the version: the
  // documents are written there, so another server on the same database cannot take it.
  absl::StatusOr<storage::ParamVersion> stored = store_->FinishSolve(
      task.solve_id, version, task.actor,
      [&](int number, std::string* params_json, std::string* report_json) {
        report.params.version = number;
        *params_json = formats::ParamSetToJson(report.params);
        *report_json = formats::ReportToJson(report);
        return absl::OkStatus();
      },
      options_.replica_id);
  if (!stored.ok()) return stored.status();
  job->set_state(v1::JOB_STATE_DONE);
  job->set_version(stored->version);
  SetVerdict(report.verdict, job);
  job->set_activated(stored->state == storage::VersionState::kActive);
  return absl::OkStatus();
}

void SolveJobs::CountSolve(const v1::SolveJob& job, absl::Duration took) {
  if (metrics_ == nullptr) return;
  metrics_->ObserveSolve(job.state() == v1::JOB_STATE_DONE           ? "done"
                         : job.verdict_kind() == v1::VERDICT_REFUSED ? "refused"
                                                                     : "failed",
                         took);
}

void SolveJobs::PublishSession(const std::string& session_id, LiveSession& live) {
  if (absl::StatusOr<v1::Session> s = session_proto_(session_id); s.ok()) {
    v1::SessionEvent e = Stamped();
    *e.mutable_session() = *std::move(s);
    hub_->Publish(live, e);
  }
}

absl::Status SolveJobs::Get(const std::string& job_id, v1::SolveJob* response) {
  absl::StatusOr<int64_t> solve_id = ParseJobId(job_id);
  if (!solve_id.ok()) return solve_id.status();
  {
    std::lock_guard lock(jobs_mu_);
    if (auto it = jobs_.find(job_id); it != jobs_.end()) {
      *response = it->second;
      return absl::OkStatus();
    }
  }
  // A job of an earlier server run, or of another server's: from storage.
  absl::StatusOr<storage::Solve> solve = store_->GetSolve(*solve_id);
  if (!solve.ok()) return solve.status();
  return FromStore(*solve, response);
}

absl::Status SolveJobs::FromStore(const storage::Solve& solve, v1::SolveJob* job) {
  job->set_id(JobId(solve.id));
  job->set_session_id(solve.session_id);
  job->set_state(ToJobState(solve.state));
  job->set_error(ScrubMessage(solve.error));
  job->set_version(solve.version);
  if (solve.version > 0) {
    absl::StatusOr<storage::Session> session = store_->GetSession(solve.session_id);
    if (!session.ok()) return session.status();
    absl::StatusOr<storage::ParamVersion> v = store_->GetVersion(session->device_id, solve.version);
    if (!v.ok()) return v.status();
    SetVerdict(ToCore(v->verdict), job);
    job->set_activated(v->state != storage::VersionState::kCandidate);
  } else if (solve.state == storage::SolveState::kFailed && !solve.report_json.empty()) {
    // Only a refusal keeps a report with a failed solve (StoreRefusal).
    SetVerdict(core::Verdict::kRefused, job);
  }
  return absl::OkStatus();
}

absl::StatusOr<int> SolveJobs::ResumeLapsed(std::string_view restarted) {
  if (!restarted.empty()) {
    if (absl::Status s = store_->ReleaseSolveClaims(restarted).status(); !s.ok()) return s;
  }
  int resumed = 0;
  while (pool_.Reserve()) {
    const absl::Time now = absl::Now();
    absl::StatusOr<std::optional<storage::Solve>> claimed =
        store_->ClaimLapsedSolve(now, {options_.replica_id, now + options_.solve_lease});
    if (!claimed.ok() || !claimed->has_value()) {
      pool_.Release();
      if (!claimed.ok()) return claimed.status();
      return resumed;
    }
    const storage::Solve& solve = **claimed;
    absl::StatusOr<std::shared_ptr<LiveSession>> live = hub_->Get(solve.session_id);
    if (solve.attempts > options_.max_solve_attempts || !live.ok()) {
      pool_.Release();
      const std::string error =
          live.ok() ? Cat("the solve was started ", solve.attempts - 1,
                          " times and each time its server stopped before it ended; solve the "
                          "session again (the server's log may say why)")
                    : Cat("the session cannot be loaded to solve it again: ",
                          ClientMessage(live.status()));
      if (absl::Status s = FailAndReopen(solve.id, error); !s.ok()) return s;
      if (live.ok()) hub_->CloseSession(**live);
      if (metrics_ != nullptr) metrics_->CountSolveTakenOver("given_up");
      continue;
    }
    Log(LogLevel::kInfo, "solve_resumed",
        {{"solve", solve.id}, {"session", solve.session_id}, {"attempt", solve.attempts}});
    hub_->Reopen(*live);
    Queue(TaskOf(solve), **live);
    if (metrics_ != nullptr) metrics_->CountSolveTakenOver("rerun");
    ++resumed;
  }
  return resumed;
}

absl::Status SolveJobs::FailAndReopen(int64_t solve_id, const std::string& error) {
  // Open again, so that the technician can solve it again; a session whose device has opened
  // its next session meanwhile cannot reopen (one open session per device): it is left failed,
  // from where it can be solved again too.
  absl::StatusOr<storage::Solve> failed =
      store_->FailSolve(solve_id, error, /*report_json=*/"", kServerActor,
                        storage::SessionState::kOpen, options_.replica_id);
  if (absl::IsFailedPrecondition(failed.status())) {
    failed = store_->FailSolve(solve_id, error, /*report_json=*/"", kServerActor,
                               storage::SessionState::kFailed, options_.replica_id);
  }
  return failed.status();
}

void SolveJobs::Update(const v1::SolveJob& job) {
  {
    std::lock_guard lock(jobs_mu_);
    jobs_[job.id()] = job;
    // Finished jobs stay a while for GetSolveJob, within bounds; storage answers after.
    if (job.state() == v1::JOB_STATE_DONE || job.state() == v1::JOB_STATE_FAILED) {
      const absl::Time now = absl::Now();
      finished_jobs_.emplace_back(job.id(), now);
      while (!finished_jobs_.empty() &&
             (finished_jobs_.size() > options_.finished_jobs_kept ||
              finished_jobs_.front().second < now - options_.finished_job_ttl)) {
        jobs_.erase(finished_jobs_.front().first);
        finished_jobs_.pop_front();
      }
    }
  }
  // Only watchers of a session in memory can hear of it: nothing is loaded to tell them.
  std::shared_ptr<LiveSession> live = hub_->Find(job.session_id());
  if (live == nullptr) return;
  v1::SessionEvent e = Stamped();
  *e.mutable_solve() = job;
  hub_->Publish(*live, e);
}

}  // namespace imucal::server
