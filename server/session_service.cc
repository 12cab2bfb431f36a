#include "server/session_service.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/escaping.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/strip.h"
#include "absl/time/clock.h"
#include "core/calibrate/calibrate.h"
#include "formats/params_json.h"
#include "formats/report_json.h"
#include "server/convert.h"
#include "server/log.h"
#include "server/session_streams.h"
#include "server/unary.h"
#include "storage/sample_codec.h"
#include "util/str_util.h"

namespace imucal::server {
namespace {

constexpr char kJobPrefix[] = "solve-";
constexpr char kServerActor[] = "imucald";  // the audit's actor for what the server does itself

// Sessions are loaded (every stored batch decoded and replayed) on threads of their own, off
// gRPC's: two, as many as this machine's cores, since a load is CPU work. Waiting loads are
// bounded; beyond, the call is RESOURCE_EXHAUSTED.
constexpr int kLoaderThreads = 2;
constexpr size_t kLoaderQueueLimit = 4096;

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

absl::Status LoadersFull() {
  return absl::ResourceExhaustedError("too many sessions are being loaded; retry in a moment");
}

// Deadlines are checked a few times per the shortest timeout, at least every second.
StreamRegistry::Options RegistryOptions(const SessionServiceOptions& o) {
  StreamRegistry::Options r;
  r.max_streams = o.max_streams;
  r.max_per_caller = o.max_streams_per_token;
  const absl::Duration shortest =
      std::min({o.first_batch_timeout, o.stream_idle_timeout, o.watch_stall_timeout});
  r.tick = std::clamp(shortest / 4, absl::Milliseconds(10), absl::Seconds(1));
  return r;
}

// A refused solve's error: the refusal's name (core/calibrate/report.h) and core's description
// of the capture and of what to record.
std::string RefusalMessage(const core::CalibrationReport& report) {
  if (!report.refusal) return "the capture cannot support a calibration";
  return Cat("the capture cannot support a calibration (",
             core::RefusalReasonName(report.refusal->reason), "): ", report.refusal->message);
}

absl::Status RequireSession(const std::string& session_id) {
  return session_id.empty() ? absl::InvalidArgumentError("session_id: required") : absl::OkStatus();
}

v1::SessionEvent Stamped() {
  v1::SessionEvent e;
  ToTimestamp(absl::Now(), e.mutable_time());
  return e;
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

SessionServiceImpl::SessionServiceImpl(storage::Store* store, SessionServiceOptions options,
                                       Authorizer* auth)
    : store_(store),
      auth_(auth),
      options_(options),
      hub_(store),
      stream_claims_(store, options.replica_id, options.stream_lease),
      registry_(RegistryOptions(options)),
      pool_(options.solve_threads, options.solve_queue_limit),
      loaders_(kLoaderThreads, kLoaderQueueLimit) {
  env_.store = store_;
  env_.hub = &hub_;
  env_.options = &options_;
  env_.auth = auth_;
  env_.registry = &registry_;
  env_.device_slots = &stream_slots_;
  env_.device_claims = &stream_claims_;
  env_.watcher_slots = &watcher_slots_;
  env_.session_streams = &session_streams_;
  env_.defer = [this](std::function<void()> work) { return Defer(std::move(work)); };
  env_.session_proto = [this](const std::string& id) { return SessionProto(id); };
}

SessionServiceImpl::~SessionServiceImpl() {
  loaders_.Shutdown();
  pool_.Shutdown();
}

size_t SessionServiceImpl::solve_jobs_in_memory() {
  std::lock_guard lock(jobs_mu_);
  return jobs_.size();
}

int SessionServiceImpl::OpenStreams(const std::string& session_id, const std::string& device_id) {
  if (const int here = session_streams_.Held(session_id); here > 0) return here;
  // Another server sharing the database may stream it: the device's live claim says so.
  absl::StatusOr<std::optional<storage::StreamClaim>> claim = store_->GetStreamClaim(device_id);
  return claim.ok() && *claim && (*claim)->session_id == session_id &&
                 (*claim)->holder != stream_claims_.holder()
             ? 1
             : 0;
}

void SessionServiceImpl::RevokeStreams(int64_t token_id, const std::string& why) {
  registry_.RevokeToken(token_id, grpc::Status(grpc::StatusCode::UNAUTHENTICATED, why));
}

bool SessionServiceImpl::Defer(std::function<void()> work) {
  if (!loaders_.Reserve()) return false;
  loaders_.Submit(std::move(work));
  return true;
}

grpc::ServerUnaryReactor* SessionServiceImpl::WithLiveSession(
    grpc::CallbackServerContext* context, const std::string& session_id,
    std::function<absl::Status(const std::shared_ptr<LiveSession>& live)> work) {
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  if (std::shared_ptr<LiveSession> live = hub_.Find(session_id)) {
    reactor->Finish(ToGrpcStatus(work(live)));
    return reactor;
  }
  const bool queued = Defer([this, reactor, session_id, work = std::move(work)] {
    absl::StatusOr<std::shared_ptr<LiveSession>> live = hub_.Get(session_id);
    reactor->Finish(ToGrpcStatus(live.ok() ? work(*live) : live.status()));
  });
  if (!queued) reactor->Finish(ToGrpcStatus(LoadersFull()));
  return reactor;
}

absl::StatusOr<v1::Session> SessionServiceImpl::SessionProto(const std::string& session_id) {
  absl::StatusOr<v1::Session> out = SessionProtoWithoutJob(session_id);
  if (!out.ok() || out->state() != v1::SESSION_STATE_SOLVING) return out;
  absl::StatusOr<std::vector<storage::Solve>> solves = store_->ListSolves(session_id);
  if (!solves.ok()) return solves.status();
  for (const storage::Solve& solve : *solves)
    if (solve.state == storage::SolveState::kRunning)
      out->set_solve_job_id(absl::StrCat(kJobPrefix, solve.id));
  return out;
}

absl::StatusOr<v1::Session> SessionServiceImpl::SessionProtoWithoutJob(
    const std::string& session_id) {
  absl::StatusOr<storage::Session> session = store_->GetSession(session_id);
  if (!session.ok()) return session.status();
  // A session in memory gives its live count (and, open, the digest of its samples). One that
  // is not is answered from its stored poses, never loaded here: loading decodes every stored
  // batch, so reading old sessions would cost seconds and grow memory.
  std::shared_ptr<LiveSession> live = hub_.Find(session_id);
  if (live == nullptr) {
    v1::Session out = ToProto(*session, -1);
    out.set_open_streams(OpenStreams(session_id, session->device_id));
    return out;
  }
  // Unless this server holds the device's stream (then it stored every batch), another server
  // may have stored batches since it last looked: read through (a query that finds nothing,
  // usually), so that every server shows the session as the database holds it.
  if (!stream_claims_.HeldHere(live->device.id)) {
    std::vector<v1::SessionEvent> caught_up;
    {
      std::lock_guard lock(live->mu);
      absl::StatusOr<std::vector<v1::SessionEvent>> events = hub_.CatchUpLocked(*live);
      if (!events.ok()) return events.status();
      caught_up = *std::move(events);
    }
    for (const v1::SessionEvent& e : caught_up) hub_.Publish(*live, e);
  }
  std::lock_guard lock(live->mu);
  v1::Session out = ToProto(*session, live->segmenter->poses_accepted());
  out.set_open_streams(OpenStreams(session_id, session->device_id));
  if (session->state == storage::SessionState::kOpen) {
    // The samples, last batch and digest the session has taken in, all three as of one moment:
    // a batch whose commit has not been acknowledged yet shows in none of them (storage may be
    // a batch ahead), so a client resuming from them resumes consistently.
    out.set_samples(live->samples);
    out.set_last_acked_seq(live->last_acked_seq);
    out.set_samples_sha256(live->digest.Sha256());
  }
  return out;
}

grpc::ServerUnaryReactor* SessionServiceImpl::CreateSession(grpc::CallbackServerContext* context,
                                                            const v1::CreateSessionRequest* request,
                                                            v1::Session* response) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kCreateSession);
  if (!who.ok()) return FinishUnary(context, who.status());
  // validate
  absl::Status valid = absl::OkStatus();
  if (request->device_id().empty()) valid = absl::InvalidArgumentError("device_id: required");
  if (!v1::Protocol_IsValid(request->protocol()))
    valid = absl::InvalidArgumentError("protocol: unknown protocol");
  const double g = request->gravity_m_s2() == 0 ? core::kStandardGravity : request->gravity_m_s2();
  if (!(g >= 9.7 && g <= 9.9))
    valid = absl::InvalidArgumentError("gravity_m_s2: local gravity must be in 9.7..9.9 m/s^2");
  if (!valid.ok()) return FinishUnary(context, valid);
  // convert, call
  storage::Session wanted;
  wanted.device_id = request->device_id();
  wanted.protocol = ProtocolName(request->protocol());
  wanted.gravity_m_s2 = g;
  absl::StatusOr<storage::Session> created = store_->CreateSession(wanted, (*who)->actor);
  if (!created.ok()) return FinishUnary(context, created.status());
  // convert back
  *response = ToProto(*created);
  return FinishUnary(context, absl::OkStatus());
}

grpc::ServerUnaryReactor* SessionServiceImpl::GetSession(grpc::CallbackServerContext* context,
                                                         const v1::GetSessionRequest* request,
                                                         v1::Session* response) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kGetSession);
  if (!who.ok()) return FinishUnary(context, who.status());
  if (absl::Status s = RequireSession(request->session_id()); !s.ok())
    return FinishUnary(context, s);
  absl::StatusOr<storage::Session> stored = store_->GetSession(request->session_id());
  if (!stored.ok()) return FinishUnary(context, stored.status());
  // A robot reads only its own device's sessions (its uploader resumes from them).
  if (absl::Status s = auth_->AuthorizeDevice(*context, **who, Rpc::kGetSession, stored->device_id);
      !s.ok())
    return FinishUnary(context, s);
  const std::string id = request->session_id();
  // An open session is brought into memory (its robot is streaming, or about to after a
  // restart, and its digest is wanted to resume); others are answered from storage.
  if (stored->state != storage::SessionState::kOpen || hub_.Find(id) != nullptr) {
    absl::StatusOr<v1::Session> session = SessionProto(id);
    if (session.ok()) *response = *std::move(session);
    return FinishUnary(context, session.status());
  }
  return WithLiveSession(context, id, [this, id, response](const auto&) {
    absl::StatusOr<v1::Session> session = SessionProto(id);
    if (session.ok()) *response = *std::move(session);
    return session.status();
  });
}

grpc::ServerUnaryReactor* SessionServiceImpl::ListSessions(grpc::CallbackServerContext* context,
                                                           const v1::ListSessionsRequest* request,
                                                           v1::ListSessionsResponse* response) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kListSessions);
  if (!who.ok()) return FinishUnary(context, who.status());
  // A robot lists only its own device's sessions: it must name its device.
  if (absl::Status s =
          auth_->AuthorizeDevice(*context, **who, Rpc::kListSessions, request->device_id());
      !s.ok())
    return FinishUnary(context, s);
  std::optional<storage::SessionState> state;
  if (request->state() != v1::SESSION_STATE_UNSPECIFIED) {
    absl::StatusOr<storage::SessionState> s = FromProto(request->state());
    if (!s.ok()) return FinishUnary(context, s.status());
    state = *s;
  }
  absl::StatusOr<int> size = PageSize(request->page_size(), 1000);
  if (!size.ok()) return FinishUnary(context, size.status());
  storage::SessionQuery query;
  query.device_id = request->device_id();
  query.state = state;
  query.after_id = request->page_token();
  query.limit = *size + 1;  // one more: whether there is a next page
  absl::StatusOr<std::vector<storage::Session>> sessions = store_->ListSessions(query);
  if (!sessions.ok()) return FinishUnary(context, sessions.status());
  const bool more = sessions->size() > static_cast<size_t>(*size);
  if (more) sessions->pop_back();
  for (const storage::Session& s : *sessions)
    // The live count when it is ahead of the stored one (a pose whose row is not stored yet),
    // the stored count when another server stored poses this one has not read.
    *response->add_sessions() =
        ToProto(s, std::max(hub_.PeekPosesAccepted(s.id), s.poses_accepted));
  if (more) response->set_next_page_token(sessions->back().id);
  return FinishUnary(context, absl::OkStatus());
}

grpc::ServerUnaryReactor* SessionServiceImpl::CancelSession(grpc::CallbackServerContext* context,
                                                            const v1::CancelSessionRequest* request,
                                                            v1::Session* response) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kCancelSession);
  if (!who.ok()) return FinishUnary(context, who.status());
  if (absl::Status s = RequireSession(request->session_id()); !s.ok())
    return FinishUnary(context, s);
  // The state from storage first: a closed session is refused without being loaded.
  absl::StatusOr<storage::Session> stored = store_->GetSession(request->session_id());
  if (!stored.ok()) return FinishUnary(context, stored.status());
  if (stored->state != storage::SessionState::kOpen) {
    return FinishUnary(context, absl::FailedPreconditionError(absl::StrCat(
                                    "session ", stored->id, " is ",
                                    std::string(storage::SessionStateName(stored->state)),
                                    ": only an open session can be cancelled")));
  }
  const std::string actor = (*who)->actor;
  return WithLiveSession(context, stored->id,
                         [this, actor, response](const std::shared_ptr<LiveSession>& live) {
                           return DoCancel(actor, live, response);
                         });
}

absl::Status SessionServiceImpl::DoCancel(const std::string& actor,
                                          const std::shared_ptr<LiveSession>& live,
                                          v1::Session* response) {
  absl::StatusOr<storage::Session> cancelled;
  {
    std::lock_guard lock(live->mu);  // no batch is half ingested while it closes
    cancelled = store_->SetSessionState(live->id, storage::SessionState::kCancelled, actor);
  }
  if (!cancelled.ok()) return cancelled.status();
  absl::StatusOr<v1::Session> proto = SessionProto(live->id);
  if (!proto.ok()) return proto.status();
  v1::SessionEvent e = Stamped();
  *e.mutable_session() = *proto;
  hub_.Publish(*live, e);
  hub_.CloseSession(*live);
  *response = *std::move(proto);
  return absl::OkStatus();
}

absl::Status SessionServiceImpl::DoListPoses(const v1::ListPosesRequest& request,
                                             v1::ListPosesResponse* response) {
  if (absl::Status s = RequireSession(request.session_id()); !s.ok()) return s;
  absl::StatusOr<std::vector<storage::Pose>> poses = store_->ListPoses(request.session_id());
  if (!poses.ok()) return poses.status();
  absl::StatusOr<std::vector<storage::PosePair>> pairs = store_->ListPairs(request.session_id());
  if (!pairs.ok()) return pairs.status();
  for (const storage::Pose& p : *poses) {
    v1::PoseEvent* out = response->add_poses();
    out->set_index(p.index);
    out->set_accepted(p.used);
    out->set_reason(p.reason);
    out->set_face(p.face);
    out->set_t_start_s(p.t_start_s);
    out->set_t_end_s(p.t_end_s);
  }
  // Stored by (pose_a, pose_b); completed in the order of pose_b.
  std::stable_sort(pairs->begin(), pairs->end(),
                   [](const auto& a, const auto& b) { return a.pose_b < b.pose_b; });
  for (const storage::PosePair& p : *pairs) {
    v1::PairVerdict* out = response->add_pairs();
    out->set_pose_a(p.pose_a);
    out->set_pose_b(p.pose_b);
    out->set_ok(p.ok);
    out->set_face(p.face);
    out->set_rotation_deg(p.rotation_deg);
    out->set_tilt_deg(p.tilt_deg);
    out->set_reason(p.reason);
  }
  return absl::OkStatus();
}

grpc::ServerUnaryReactor* SessionServiceImpl::ListPoses(grpc::CallbackServerContext* context,
                                                        const v1::ListPosesRequest* request,
                                                        v1::ListPosesResponse* response) {
  if (absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kListPoses); !who.ok())
    return FinishUnary(context, who.status());
  return FinishUnary(context, DoListPoses(*request, response));
}

// ---- Solves.

absl::Status SessionServiceImpl::DoSolve(const std::string& actor,
                                         const std::shared_ptr<LiveSession>& live,
                                         const v1::SolveSessionRequest& request,
                                         v1::SolveJob* response) {
  if (!pool_.Reserve()) {
    return absl::ResourceExhaustedError(
        "the solve queue is full; retry in a minute (GetSolveJob shows running jobs)");
  }
  // A robot still uploading into the session: solving now would end its stream and leave the
  // rest of its capture unstored (the guide waits for Session.open_streams to fall to 0).
  if (const int open = OpenStreams(request.session_id(), live->device.id);
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
  hub_.Reopen(live);
  for (const v1::SessionEvent& e : SessionHub::ToEvents(last_pose)) hub_.Publish(*live, e);
  SolveTask task;
  task.solve_id = solve->id;
  task.job_id = absl::StrCat(kJobPrefix, solve->id);
  task.session_id = request.session_id();
  task.seed = solve->seed;
  task.actor = actor;
  *response = Queue(task, *live);
  return absl::OkStatus();
}

v1::SolveJob SessionServiceImpl::Queue(const SolveTask& task, LiveSession& live) {
  v1::SolveJob job;
  job.set_id(task.job_id);
  job.set_session_id(task.session_id);
  job.set_state(v1::JOB_STATE_QUEUED);
  UpdateJob(job);
  if (absl::StatusOr<v1::Session> s = SessionProto(task.session_id); s.ok()) {
    v1::SessionEvent e = Stamped();
    *e.mutable_session() = *std::move(s);
    hub_.Publish(live, e);
  }
  pool_.Submit([this, task] { RunSolve(task); });
  return job;
}

absl::StatusOr<int> SessionServiceImpl::ResumeLapsedSolves(std::string_view restarted) {
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
    absl::StatusOr<std::shared_ptr<LiveSession>> live = hub_.Get(solve.session_id);
    if (solve.attempts > options_.max_solve_attempts || !live.ok()) {
      pool_.Release();
      const std::string error =
          live.ok() ? Cat("the solve was started ", solve.attempts - 1,
                          " times and each time its server stopped before it ended; solve the "
                          "session again (the server's log may say why)")
                    : Cat("the session cannot be loaded to solve it again: ",
                          ClientMessage(live.status()));
      if (absl::Status s = FailAndReopen(solve.id, error); !s.ok()) return s;
      if (live.ok()) hub_.CloseSession(**live);
      if (env_.metrics != nullptr) env_.metrics->CountSolveTakenOver("given_up");
      continue;
    }
    Log(LogLevel::kInfo, "solve_resumed",
        {{"solve", solve.id}, {"session", solve.session_id}, {"attempt", solve.attempts}});
    hub_.Reopen(*live);
    SolveTask task;
    task.solve_id = solve.id;
    task.job_id = absl::StrCat(kJobPrefix, solve.id);
    task.session_id = solve.session_id;
    task.seed = solve.seed;
    task.actor = solve.actor;
    Queue(task, **live);
    if (env_.metrics != nullptr) env_.metrics->CountSolveTakenOver("rerun");
    ++resumed;
  }
  return resumed;
}

absl::Status SessionServiceImpl::FailAndReopen(int64_t solve_id, const std::string& error) {
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

void SessionServiceImpl::UpdateJob(const v1::SolveJob& job) {
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
  std::shared_ptr<LiveSession> live = hub_.Find(job.session_id());
  if (live == nullptr) return;
  v1::SessionEvent e = Stamped();
  *e.mutable_solve() = job;
  hub_.Publish(*live, e);
}

void SessionServiceImpl::SetMetrics(Metrics* metrics) {
  env_.metrics = metrics;
  metrics->SetGauge("imucal_sessions_in_memory",
                    "sessions whose live state (segmentation, pairs) this server holds",
                    [this] { return static_cast<double>(hub_.LiveSessions()); });
  metrics->SetGauge("imucal_streams_open",
                    "StreamSamples, WatchSession and ReadSamples calls open (max_streams)",
                    [this] { return static_cast<double>(registry_.size()); });
  metrics->SetGauge("imucal_sample_streams_open", "StreamSamples calls holding a device's slot",
                    [this] { return static_cast<double>(stream_slots_.Total()); });
  metrics->SetGauge("imucal_watchers_open", "WatchSession calls holding a session's slot",
                    [this] { return static_cast<double>(watcher_slots_.Total()); });
  metrics->SetGauge("imucal_solve_queue_depth", "solves waiting for a solve thread",
                    [this] { return static_cast<double>(pool_.queued()); });
  metrics->SetGauge("imucal_session_loads_queued",
                    "sessions waiting to be loaded (their stored batches replayed)",
                    [this] { return static_cast<double>(loaders_.queued()); });
}

void SessionServiceImpl::RunSolve(const SolveTask& task) {
  const absl::Time started = absl::Now();
  v1::SolveJob job;
  job.set_id(task.job_id);
  job.set_session_id(task.session_id);
  job.set_state(v1::JOB_STATE_RUNNING);
  UpdateJob(job);
  absl::StatusOr<std::shared_ptr<LiveSession>> live = hub_.Get(task.session_id);
  absl::Status failure = live.status();
  if (failure.ok()) {
    // read -> decode -> calibrate -> JSON -> store (the version becomes active if it passes).
    std::vector<std::string> load_warnings;
    absl::StatusOr<core::Capture> capture = LoadCapture(*store_, **live, &load_warnings);
    core::CalibrateOptions options;
    options.protocol = ToProtocolKind((*live)->protocol);
    options.seed = task.seed;
    absl::StatusOr<core::CalibrationReport> report =
        capture.ok() ? core::Calibrate(*capture, options)
                     : absl::StatusOr<core::CalibrationReport>(capture.status());
    if (report.ok() && report->verdict == core::Verdict::kRefused) {
      // The capture cannot determine even bias and scale: no version. The report (the poses
      // found, why each interval is unusable) is kept with the failed solve, and the session
      // goes back to open, its samples untouched, so that more poses can be recorded into it.
      for (std::string& w : load_warnings) report->warnings.push_back(std::move(w));
      report->device = (*live)->device.id;
      const std::string error = RefusalMessage(*report);
      absl::StatusOr<storage::Solve> failed =
          store_->FailSolve(task.solve_id, error, formats::ReportToJson(*report), task.actor,
                            storage::SessionState::kOpen, options_.replica_id);
      if (failed.ok()) {
        job.set_state(v1::JOB_STATE_FAILED);
        job.set_error(ScrubMessage(error));
        job.set_verdict(std::string(core::VerdictName(core::Verdict::kRefused)));
      } else {
        failure = failed.status();
      }
    } else if (report.ok()) {
      for (std::string& w : load_warnings) report->warnings.push_back(std::move(w));
      report->device = (*live)->device.id;
      report->params.device = (*live)->device.id;
      report->params.source_session = task.session_id;
      report->params.software = "imucald " IMUCAL_VERSION;
      storage::ParamVersion version;
      version.device_id = (*live)->device.id;
      version.session_id = task.session_id;
      version.verdict = ToStorage(report->verdict);
      version.accel_rms = report->residual.accel_rms_m_s2;
      // The quality gate: only a passing solve becomes active on its own.
      version.state = report->verdict == core::Verdict::kPass ? storage::VersionState::kActive
                                                              : storage::VersionState::kCandidate;
      version.provenance = absl::StrFormat("imucald %s; protocol %s; seed %d", IMUCAL_VERSION,
                                           core::ProtocolKindName(options.protocol), options.seed);
      // The number is the store's, assigned in the transaction that writes the version: the
      // documents are written there, so another server on the same database cannot take it.
      absl::StatusOr<storage::ParamVersion> stored = store_->FinishSolve(
          task.solve_id, version, task.actor,
          [&](int number, std::string* params_json, std::string* report_json) {
            report->params.version = number;
            *params_json = formats::ParamSetToJson(report->params);
            *report_json = formats::ReportToJson(*report);
            return absl::OkStatus();
          },
          options_.replica_id);
      if (stored.ok()) {
        job.set_state(v1::JOB_STATE_DONE);
        job.set_version(stored->version);
        job.set_verdict(std::string(core::VerdictName(report->verdict)));
        job.set_activated(stored->state == storage::VersionState::kActive);
      } else {
        failure = stored.status();
      }
    } else {
      failure = report.status();
    }
  }
  if (job.state() != v1::JOB_STATE_DONE && job.state() != v1::JOB_STATE_FAILED) {
    if (failure.ok()) failure = absl::InternalError("solve ended without a result");
    job.set_state(v1::JOB_STATE_FAILED);
    job.set_error(ClientMessage(failure));
    store_->FailSolve(task.solve_id, job.error(), /*report_json=*/"", task.actor,
                      storage::SessionState::kFailed, options_.replica_id)
        .IgnoreError();
  }
  UpdateJob(job);
  if (env_.metrics != nullptr) {
    env_.metrics->ObserveSolve(job.state() == v1::JOB_STATE_DONE ? "done"
                               : job.verdict() == core::VerdictName(core::Verdict::kRefused)
                                   ? "refused"
                                   : "failed",
                               absl::Now() - started);
  }
  if (!live.ok()) return;
  if (absl::StatusOr<v1::Session> s = SessionProto(task.session_id); s.ok()) {
    v1::SessionEvent e = Stamped();
    *e.mutable_session() = *std::move(s);
    hub_.Publish(**live, e);
  }
  hub_.CloseSession(**live);
}

grpc::ServerUnaryReactor* SessionServiceImpl::SolveSession(grpc::CallbackServerContext* context,
                                                           const v1::SolveSessionRequest* request,
                                                           v1::SolveJob* response) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kSolveSession);
  if (!who.ok()) return FinishUnary(context, who.status());
  if (absl::Status s = RequireSession(request->session_id()); !s.ok())
    return FinishUnary(context, s);
  // The state from storage first: a session that cannot be solved is refused without loading.
  absl::StatusOr<storage::Session> stored = store_->GetSession(request->session_id());
  if (!stored.ok()) return FinishUnary(context, stored.status());
  if (stored->state == storage::SessionState::kCancelled ||
      stored->state == storage::SessionState::kSolving) {
    return FinishUnary(
        context, absl::FailedPreconditionError(absl::StrCat(
                     "session ", stored->id, " is ",
                     std::string(storage::SessionStateName(stored->state)), ": ",
                     stored->state == storage::SessionState::kCancelled
                         ? "a cancelled session cannot be solved"
                         : "a solve is already running (Session.solve_job_id names its job; "
                           "GetSolveJob or WatchSession follow it)")));
  }
  const std::string actor = (*who)->actor;
  return WithLiveSession(
      context, stored->id,
      [this, actor, request, response](const std::shared_ptr<LiveSession>& live) {
        return DoSolve(actor, live, *request, response);
      });
}

absl::Status SessionServiceImpl::DoGetSolveJob(const v1::GetSolveJobRequest& request,
                                               v1::SolveJob* response) {
  absl::StatusOr<int64_t> solve_id = ParseJobId(request.job_id());
  if (!solve_id.ok()) return solve_id.status();
  {
    std::lock_guard lock(jobs_mu_);
    if (auto it = jobs_.find(request.job_id()); it != jobs_.end()) {
      *response = it->second;
      return absl::OkStatus();
    }
  }
  // A job of an earlier server run, or of another server's: from storage.
  absl::StatusOr<storage::Solve> solve = store_->GetSolve(*solve_id);
  if (!solve.ok()) return solve.status();
  return JobFromStore(*solve, response);
}

absl::Status SessionServiceImpl::JobFromStore(const storage::Solve& solve, v1::SolveJob* job) {
  job->set_id(absl::StrCat(kJobPrefix, solve.id));
  job->set_session_id(solve.session_id);
  job->set_state(ToJobState(solve.state));
  job->set_error(ScrubMessage(solve.error));
  job->set_version(solve.version);
  if (solve.version > 0) {
    absl::StatusOr<storage::Session> session = store_->GetSession(solve.session_id);
    if (!session.ok()) return session.status();
    absl::StatusOr<storage::ParamVersion> v = store_->GetVersion(session->device_id, solve.version);
    if (!v.ok()) return v.status();
    job->set_verdict(std::string(storage::VerdictName(v->verdict)));
    job->set_activated(v->state != storage::VersionState::kCandidate);
  } else if (solve.state == storage::SolveState::kFailed && !solve.report_json.empty()) {
    // Only a refusal keeps a report with a failed solve (RunSolve).
    job->set_verdict(std::string(core::VerdictName(core::Verdict::kRefused)));
  }
  return absl::OkStatus();
}

void SessionServiceImpl::SessionChangedElsewhere(std::string_view session_id) {
  // Watched or not: a session in memory here is read again, so that GetSession, the session
  // list and later watches show what the other server stored.
  std::shared_ptr<LiveSession> live = hub_.Find(session_id);
  if (live == nullptr) return;
  if (live->refresh_pending.exchange(true)) return;              // one is queued already
  if (!Defer([this, live] { Refresh(live); })) {
    live->refresh_pending = false;
    Log(LogLevel::kWarning, "session_refresh_dropped",
        {{"session", live->id}, {"note", "the session loaders are full"}});
  }
}

void SessionServiceImpl::RefreshWatchedSessions() {
  for (const std::shared_ptr<LiveSession>& live : hub_.WatchedSessions())
    SessionChangedElsewhere(live->id);
}

void SessionServiceImpl::Refresh(const std::shared_ptr<LiveSession>& live) {
  live->refresh_pending = false;  // a change from now on queues another refresh
  std::vector<v1::SessionEvent> events;
  {
    std::lock_guard lock(live->mu);
    absl::StatusOr<std::vector<v1::SessionEvent>> caught_up = hub_.CatchUpLocked(*live);
    if (!caught_up.ok()) {
      Log(LogLevel::kWarning, "session_refresh",
          {{"session", live->id}, {"error", std::string(caught_up.status().message())}});
      return;
    }
    events = *std::move(caught_up);
  }
  for (const v1::SessionEvent& e : events) hub_.Publish(*live, e);
  absl::StatusOr<v1::Session> session = SessionProto(live->id);
  if (!session.ok()) return;
  const v1::SessionState state = session->state();
  {
    std::lock_guard lock(live->mu);
    if (live->refreshed_state == state) return;
    live->refreshed_state = state;
  }
  if (state != v1::SESSION_STATE_OPEN) {  // a solve began or ended there: its job
    absl::StatusOr<std::vector<storage::Solve>> solves = store_->ListSolves(live->id);
    v1::SolveJob job;
    if (solves.ok() && !solves->empty() && JobFromStore(solves->back(), &job).ok()) {
      v1::SessionEvent e = Stamped();
      *e.mutable_solve() = job;
      hub_.Publish(*live, e);
    }
  }
  v1::SessionEvent e = Stamped();
  *e.mutable_session() = *std::move(session);
  hub_.Publish(*live, e);
  if (state != v1::SESSION_STATE_OPEN && state != v1::SESSION_STATE_SOLVING)
    hub_.CloseSession(*live);  // solved, failed or cancelled there: the watch ends, as here
}

grpc::ServerUnaryReactor* SessionServiceImpl::GetSolveJob(grpc::CallbackServerContext* context,
                                                          const v1::GetSolveJobRequest* request,
                                                          v1::SolveJob* response) {
  if (absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kGetSolveJob); !who.ok())
    return FinishUnary(context, who.status());
  return FinishUnary(context, DoGetSolveJob(*request, response));
}

absl::Status SessionServiceImpl::DoGetReport(const v1::GetReportRequest& request,
                                             v1::Report* response) {
  if (absl::Status s = RequireSession(request.session_id()); !s.ok()) return s;
  absl::StatusOr<storage::Session> session = store_->GetSession(request.session_id());
  if (!session.ok()) return session.status();
  absl::StatusOr<std::vector<storage::Solve>> solves = store_->ListSolves(request.session_id());
  if (!solves.ok()) return solves.status();
  // The latest solve that wrote a report: a version's, or a refusal's kept with its failed solve.
  const storage::Solve* latest = nullptr;
  for (const storage::Solve& s : *solves)
    if (s.version > 0 || !s.report_json.empty()) latest = &s;
  if (latest == nullptr) {
    return absl::NotFoundError(
        absl::StrCat("session ", request.session_id(), " has no solved report yet"));
  }
  if (latest->version == 0) {
    response->set_json(latest->report_json);
    return absl::OkStatus();
  }
  absl::StatusOr<storage::ParamVersion> v = store_->GetVersion(session->device_id, latest->version);
  if (!v.ok()) return v.status();
  response->set_json(v->report_json);
  return absl::OkStatus();
}

grpc::ServerUnaryReactor* SessionServiceImpl::GetReport(grpc::CallbackServerContext* context,
                                                        const v1::GetReportRequest* request,
                                                        v1::Report* response) {
  if (absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kGetReport); !who.ok())
    return FinishUnary(context, who.status());
  return FinishUnary(context, DoGetReport(*request, response));
}

grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer>* SessionServiceImpl::StreamSamples(
    grpc::CallbackServerContext* context) {
  return StartStreamSamples(env_, context);
}

grpc::ServerWriteReactor<v1::SessionEvent>* SessionServiceImpl::WatchSession(
    grpc::CallbackServerContext* context, const v1::WatchSessionRequest* request) {
  return StartWatchSession(env_, context, *request);
}

grpc::ServerWriteReactor<v1::SampleBatch>* SessionServiceImpl::ReadSamples(
    grpc::CallbackServerContext* context, const v1::ReadSamplesRequest* request) {
  return StartReadSamples(env_, context, *request);
}

}  // namespace imucal::server
