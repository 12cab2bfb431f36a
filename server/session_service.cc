#include "server/session_service.h"

#include <algorithm>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "core/capture.h"
#include "server/convert.h"
#include "server/log.h"
#include "server/session_streams.h"
#include "server/unary.h"

namespace imucal::server {
namespace {

// Sessions are loaded (every stored batch decoded and replayed) on threads of their own, off
// gRPC's: two, as many as this machine's cores, since a load is CPU work. Waiting loads are
// bounded; beyond, the call is RESOURCE_EXHAUSTED.
constexpr int kLoaderThreads = 2;
constexpr size_t kLoaderQueueLimit = 4096;

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

absl::Status RequireSession(const std::string& session_id) {
  return session_id.empty() ? absl::InvalidArgumentError("session_id: required") : absl::OkStatus();
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
      solves_(
          store, &hub_, options_, [this](const std::string& id) { return SessionProto(id); },
          [this](const std::string& session_id, const std::string& device_id) {
            return OpenStreams(session_id, device_id);
          }),
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
  solves_.Shutdown();
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
      out->set_solve_job_id(SolveJobs::JobId(solve.id));
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

void SessionServiceImpl::SetMetrics(Metrics* metrics) {
  env_.metrics = metrics;
  solves_.SetMetrics(metrics);
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
                    [this] { return static_cast<double>(solves_.queued()); });
  metrics->SetGauge("imucal_session_loads_queued",
                    "sessions waiting to be loaded (their stored batches replayed)",
                    [this] { return static_cast<double>(loaders_.queued()); });
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
        absl::StatusOr<v1::SolveJob> job = solves_.Start(actor, live, *request);
        if (job.ok()) *response = *std::move(job);
        return job.status();
      });
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
    if (solves.ok() && !solves->empty() && solves_.FromStore(solves->back(), &job).ok()) {
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
  return FinishUnary(context, solves_.Get(request->job_id(), response));
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
