// The three streaming RPCs of SessionService as callback reactors (no thread per stream):
// StreamSamples, WatchSession and ReadSamples.
//
// All are registered with the service's StreamRegistry for their whole life (server/
// stream_registry.h): counted against max_streams and max_streams_per_token from the moment they
// open, ended at once when their token is revoked, and ended when they stop moving (a deadline
// each keeps there). A reactor is owned by a shared_ptr that it drops in OnDone, so that the
// registry's sweeper and the session loader can hold it for the length of a call.
//
// Locking: a reactor's mu_ guards its state; gRPC operations (StartRead, StartWrite, Finish)
// are started under it (their reactions never run inline, the reactors not being inlineable).
// TryCancel is called without mu_ (OnCancel may run inline and takes it), under ctx_mu_, which
// OnDone takes first: the call's context is valid while ctx_mu_ is held and done_ is false.
#include <algorithm>
#include <cmath>
#include <deque>
#include <iterator>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "formats/sample_digest.h"
#include "server/ingest.h"
#include "server/session_service.h"
#include "server/status_util.h"
#include "storage/sample_codec.h"
#include "util/text_check.h"

namespace imucal::server {
namespace {

constexpr size_t kMaxSourceBytes = 256;

// The registry's key for who made the call: a token, or a robot's client certificate; "" in
// insecure mode (no caller to count).
std::string CallerKey(const Principal& who) {
  if (who.token_id != 0) return absl::StrCat("token:", who.token_id);
  if (!who.device_id.empty()) return absl::StrCat("cert:", who.device_id);
  return "";
}

std::string Seconds(absl::Duration d) { return absl::StrCat(absl::ToDoubleSeconds(d), " s"); }

// SampleBatch.source: a name for a person to read in messages (a file name, the robot's capture
// label), so short and printable: no control character, C0 or C1 (util/text_check.h).
absl::Status ValidateSource(const std::string& source) {
  if (source.size() > kMaxSourceBytes) {
    return absl::InvalidArgumentError(
        absl::StrCat("source: ", source.size(), " bytes, at most ", kMaxSourceBytes));
  }
  if (std::optional<UnreadableChar> bad = FindUnreadableChar(source))
    return absl::InvalidArgumentError(bad->Message("source"));
  return absl::OkStatus();
}

std::string Named(const std::string& source) {
  return source.empty() ? "an unnamed capture" : absl::StrCat("'", source, "'");
}

// StreamSamples: read a batch, store it, ack it, read the next. One batch in flight per
// stream, so reads and writes never overlap; any error ends the stream with its status after
// everything acknowledged before it is stored. The store's group commit stores the batch: the
// ack (and the batch's segmentation) follows on the store's committer thread once the
// transaction holding it, shared with other streams' batches, has committed.
//
// Backpressure: the next StartRead follows the ack's OnWriteDone, which follows the commit, so
// the server holds one batch per stream; what the robot writes meanwhile waits in HTTP/2 flow
// control (the stream's window), and the robot's Write blocks once that is full.
//
// The method is raw: the reactor parses each batch itself, so that bytes that are not a
// SampleBatch get INVALID_ARGUMENT (the generated reader reports a failed parse as the end of
// the stream). Each batch is checked against the caller's token again (a revocation through
// another process is seen within the token cache's lifetime). The first batch names the
// session: its state is read from storage before anything else (a closed session is refused
// without being loaded); a session not in memory is loaded off the RPC threads; a session that
// holds samples is continued only by a stream that proves it continues the same capture
// (SampleBatch.resume_sha256). The stream holds one of its device's slots
// (max_streams_per_device) from its first batch until it ends or is cancelled.
class IngestReactor final : public grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer>,
                            public StreamRegistry::Stream,
                            public std::enable_shared_from_this<IngestReactor> {
 public:
  // `who` may call StreamSamples (Authorize passed); a robot still only for its own device's
  // sessions, checked at the first batch (which names the session).
  IngestReactor(const StreamEnv& env, grpc::CallbackServerContext* context, PrincipalRef who)
      : env_(env), context_(context), who_(std::move(who)) {}

  // Registers the stream and reads its first batch, or ends it at once (a cap, a revoked
  // token). Called once, by the handler, on a reactor owned by `self`.
  void Start(std::shared_ptr<IngestReactor> self) {
    self_ = std::move(self);
    // Silent until its first batch: its place may go to a caller with fewer streams meanwhile.
    absl::Status added = env_.registry->Add(shared_from_this(), CallerKey(*who_), who_->token_id,
                                            /*silent=*/true);
    std::lock_guard lock(mu_);
    if (!added.ok()) {
      FinishLocked(ToGrpcStatus(added));
      return;
    }
    registered_ = true;
    if (pending_end_) {  // revoked between Add and here
      FinishLocked(*pending_end_);
      return;
    }
    ReadLocked(/*first=*/true);
  }

  void OnReadDone(bool ok) override {
    {
      std::lock_guard lock(mu_);
      if (finished_) return;  // ended (revoked, timed out) while the read was pending
      state_ = State::kBusy;
      SetDeadline(absl::InfiniteFuture());
      if (!ok) {  // the robot closed its side: everything read has been acknowledged
        FinishLocked(grpc::Status::OK);
        return;
      }
      if (first_read_) env_.registry->Heard(this);  // it keeps its place from now on
    }
    if (absl::Status s = Submit(); !s.ok()) End(ToGrpcStatus(s));
  }

  void OnWriteDone(bool ok) override {
    std::lock_guard lock(mu_);
    if (finished_) return;
    SetDeadline(absl::InfiniteFuture());
    if (!ok) {
      FinishLocked(
          grpc::Status(grpc::StatusCode::UNAVAILABLE, "the stream broke while acknowledging"));
    } else if (pending_end_) {
      FinishLocked(*pending_end_);
    } else {
      ReadLocked(/*first=*/false);
    }
  }

  // The robot went away (or its deadline passed): the device may stream again at once.
  void OnCancel() override { ReleaseSlot(); }

  void OnDone() override {
    {
      std::lock_guard lock(ctx_mu_);
      done_ = true;
    }
    if (registered_) env_.registry->Remove(this);
    ReleaseSlot();
    std::shared_ptr<IngestReactor> last = std::move(self_);  // may delete this on return
  }

  void Revoke(const grpc::Status& status) override {
    std::lock_guard lock(mu_);
    if (finished_) return;
    if (state_ == State::kReading) {
      FinishLocked(status);  // the pending read then completes, not ok
    } else {
      pending_end_ = status;  // after the batch being stored or acknowledged
    }
  }

  void Expire(absl::Time now) override {
    {
      std::lock_guard lock(mu_);
      if (finished_ || !PastDeadline(now)) return;
      if (state_ == State::kReading) {
        FinishLocked(grpc::Status(
            grpc::StatusCode::DEADLINE_EXCEEDED,
            first_read_
                ? absl::StrCat("no batch within ", Seconds(env_.options->first_batch_timeout),
                               " of the stream's start (first_batch_timeout): open a stream when "
                               "there are samples to send")
                : absl::StrCat("no batch within ", Seconds(env_.options->stream_idle_timeout),
                               " of the last ack (stream_idle_timeout); resume from "
                               "GetSession().last_acked_seq + 1 on a new stream")));
        return;
      }
      if (state_ != State::kWriting) return;
    }
    // The ack has not gone out: the robot stopped reading. Only cancelling ends the call then
    // (a status would wait behind the write); its slot is free at once (OnCancel).
    std::lock_guard lock(ctx_mu_);
    if (!done_) context_->TryCancel();
  }

 private:
  enum class State { kReading, kBusy, kWriting };

  // The first read waits first_batch_timeout for the robot; the others stream_idle_timeout.
  void ReadLocked(bool first) {
    state_ = State::kReading;
    first_read_ = first;
    SetDeadline(absl::Now() +
                (first ? env_.options->first_batch_timeout : env_.options->stream_idle_timeout));
    StartRead(&request_);
  }

  // parse -> validate -> (the first batch: session state, load, continuation) -> store
  // (asynchronously; OnStored continues).
  absl::Status Submit() {
    // The token may have been revoked since the last batch (by another process: the cache
    // sees it within its lifetime; through this server the registry ended the stream already).
    if (absl::StatusOr<PrincipalRef> again = env_.auth->Authorize(*context_, Rpc::kStreamSamples);
        !again.ok())
      return again.status();
    batch_.Clear();
    ++messages_;
    const size_t bytes = request_.Length();
    if (!grpc::SerializationTraits<v1::SampleBatch>::Deserialize(&request_, &batch_).ok()) {
      return absl::InvalidArgumentError(
          absl::StrCat("message ", messages_, " of the stream (after batch ", last_seq_,
                       "): ", bytes, " bytes that are not a SampleBatch (malformed protobuf)"));
    }
    if (live_ != nullptr) {
      if (!batch_.session_id().empty() && batch_.session_id() != session_id_) {
        return absl::InvalidArgumentError(absl::StrCat("session_id: the stream is for session ",
                                                       session_id_, ", not ", batch_.session_id()));
      }
      return Store();
    }
    if (batch_.session_id().empty())
      return absl::InvalidArgumentError("session_id: required in the first batch of a stream");
    session_id_ = batch_.session_id();
    // The session's state from storage first: a closed session is refused without loading it.
    absl::StatusOr<storage::Session> stored = env_.store->GetSession(session_id_);
    if (!stored.ok()) return stored.status();
    if (absl::Status s =
            env_.auth->AuthorizeDevice(*context_, *who_, Rpc::kStreamSamples, stored->device_id);
        !s.ok())
      return s;
    if (stored->state != storage::SessionState::kOpen) {
      return absl::FailedPreconditionError(absl::StrCat(
          "session ", session_id_, " is ", std::string(storage::SessionStateName(stored->state)),
          ": it takes no more samples"));
    }
    if (std::shared_ptr<LiveSession> live = env_.hub->Find(session_id_)) return FirstBatch(live);
    // Loading replays every stored batch (seconds for millions of samples): not on this thread.
    std::shared_ptr<IngestReactor> self = shared_from_this();
    const bool queued = env_.defer([self] {
      absl::StatusOr<std::shared_ptr<LiveSession>> live = self->env_.hub->Get(self->session_id_);
      absl::Status s = live.ok() ? self->FirstBatch(*live) : live.status();
      if (!s.ok()) self->End(ToGrpcStatus(s));
    });
    if (!queued)
      return absl::ResourceExhaustedError("too many sessions are being loaded; retry in a moment");
    return absl::OkStatus();
  }

  // The stream's first batch, its session in memory: the device's slot, the proof that the
  // stream continues the capture the session holds, then the batch.
  absl::Status FirstBatch(std::shared_ptr<LiveSession> live) {
    {
      std::lock_guard lock(mu_);
      if (pending_end_) {  // revoked while the session loaded
        FinishLocked(*pending_end_);
        return absl::OkStatus();
      }
    }
    live_ = std::move(live);
    if (absl::Status s = AcquireSlot(); !s.ok()) return s;
    if (absl::Status s = ValidateSource(batch_.source()); !s.ok()) return s;
    std::vector<v1::SessionEvent> caught_up;
    {
      std::lock_guard lock(live_->mu);
      // The robot may have streamed through another server since this one last saw the
      // session (several servers share the database): what that server stored comes first.
      absl::StatusOr<std::vector<v1::SessionEvent>> events = env_.hub->CatchUpLocked(*live_);
      if (!events.ok()) return events.status();
      caught_up = *std::move(events);
      if (absl::Status s = CheckContinuationLocked(); !s.ok()) return s;
    }
    for (const v1::SessionEvent& e : caught_up) env_.hub->Publish(*live_, e);
    return Store();
  }

  // A session that holds samples takes a new stream only from the same capture: a stream that
  // starts at batch n > 1 proves, with resume_sha256, that batches 1..n-1 are what it sent
  // before (a stream from batch 1 needs no proof: each stored batch it repeats is compared
  // byte for byte). An empty session records the stream's source, for later streams' messages.
  absl::Status CheckContinuationLocked() {
    LiveSession& live = *live_;
    if (live.samples == 0) {
      if (!batch_.source().empty() && batch_.source() != live.source) {
        if (absl::Status s = env_.store->SetSessionSource(live.id, batch_.source()); !s.ok())
          return s;
        live.source = batch_.source();
      }
      return absl::OkStatus();
    }
    const int64_t before = batch_.seq() - 1;
    // From batch 1, or past the last stored batch (a gap, which PrepareBatch names).
    if (before <= 0 || before > live.last_acked_seq) return absl::OkStatus();
    const LiveSession::Proof* proof = ProofAfter(live, before);
    if (proof == nullptr) {
      return absl::FailedPreconditionError(absl::StrCat(
          "seq: the stream starts at batch ", batch_.seq(), ", more than ",
          LiveSession::kProofHistory, " batches behind session ", live.id, "'s last stored batch ",
          live.last_acked_seq, "; resume from ", live.last_acked_seq + 1));
    }
    if (batch_.resume_sha256() == proof->sha256) return absl::OkStatus();
    if (batch_.resume_sha256().empty()) {
      return EchoesRequest(absl::FailedPreconditionError(
          absl::StrCat("resume_sha256: required to continue session ", live.id, " at batch ",
                       batch_.seq(), ": send the SHA-256 of the ", proof->samples,
                       " samples of batches 1..", before, " (", Named(live.source),
                       "; imucal.proto, SampleBatch.resume_sha256) to show that the "
                       "stream continues that capture")));
    }
    return EchoesRequest(absl::FailedPreconditionError(absl::StrCat(
        Named(batch_.source()), " does not continue ", Named(live.source), ", whose first ",
        proof->samples, " samples session ", live.id, " holds: their SHA-256 is ",
        formats::HexPrefix(proof->sha256, 16), "..., this stream's for its first ", proof->samples,
        " samples is ", formats::HexPrefix(batch_.resume_sha256(), 16),
        "...; continue with the same capture, or cancel the session and start a new one")));
  }

  // validate against the session -> convert -> store (asynchronously).
  absl::Status Store() {
    if (absl::Status s = CheckClaim(); !s.ok()) return s;
    absl::StatusOr<PreparedBatch> prepared;
    {
      std::lock_guard lock(live_->mu);
      prepared = PrepareBatch(*live_, batch_, env_.options->ingest);
    }
    if (!prepared.ok()) return prepared.status();
    prepared_ = *std::move(prepared);
    if (env_.metrics != nullptr)
      env_.metrics->CountSamplesReceived(static_cast<int64_t>(prepared_.samples.size()));
    env_.store->AppendBatchAsync(
        session_id_, prepared_.seq, std::move(prepared_.payload),
        [this](absl::StatusOr<storage::BatchAck> ack) { OnStored(std::move(ack)); });
    return absl::OkStatus();
  }

  // Durable (or refused): segment, tell the watchers, acknowledge (unless the token was revoked
  // meanwhile: the batch is stored, the robot is not told).
  void OnStored(absl::StatusOr<storage::BatchAck> stored) {
    if (!stored.ok()) {
      End(ToGrpcStatus(stored.status()));
      return;
    }
    IngestResult result;
    int64_t new_samples = 0;
    {
      std::lock_guard lock(live_->mu);
      const int64_t before = live_->samples;
      result = CompleteBatch(*env_.store, *live_, prepared_, *stored);
      new_samples = live_->samples - before;
    }
    if (env_.metrics != nullptr && new_samples > 0)
      env_.metrics->CountSamplesAcknowledged(new_samples);
    prepared_ = PreparedBatch();
    for (const v1::SessionEvent& e : result.events) env_.hub->Publish(*live_, e);
    bool own_buffer = false;
    std::lock_guard lock(mu_);
    last_seq_ = result.ack.last_acked_seq();
    if (finished_) return;
    if (pending_end_) {
      FinishLocked(*pending_end_);
      return;
    }
    response_.Clear();
    if (grpc::Status s = grpc::SerializationTraits<v1::SampleAck>::Serialize(result.ack, &response_,
                                                                             &own_buffer);
        !s.ok()) {
      FinishLocked(s);
      return;
    }
    state_ = State::kWriting;
    SetDeadline(absl::Now() + env_.options->stream_idle_timeout);
    StartWrite(&response_);
  }

  void End(const grpc::Status& status) {
    std::lock_guard lock(mu_);
    FinishLocked(status);
  }

  // The slots are free before the status leaves: a robot that sees its stream end may open the
  // next one at once, within the device's and the server's caps (the registry's Remove is a
  // no-op for a stream that never registered, and OnDone's is then one too).
  void FinishLocked(const grpc::Status& status) {
    if (finished_) return;
    finished_ = true;
    SetDeadline(absl::InfiniteFuture());
    ReleaseSlot();
    env_.registry->Remove(this);
    Finish(status);
  }

  // The device's slot here, then its claim across the servers sharing the database, and the
  // session's count of open streams (Session.open_streams, which holds off a solve until the
  // stream ends).
  absl::Status AcquireSlot() {
    std::lock_guard lock(slot_mu_);
    const std::string& device = live_->device.id;
    if (!env_.device_slots->TryAcquire(device, env_.options->max_streams_per_device)) {
      return absl::ResourceExhaustedError(absl::StrCat(
          "device ", device, " already has ", env_.options->max_streams_per_device,
          " sample stream(s) open, the most a device may have; end it (or wait for the server "
          "to see that it broke) and resume from GetSession().last_acked_seq + 1"));
    }
    if (absl::Status s = env_.device_claims->Acquire(device, session_id_); !s.ok()) {
      env_.device_slots->Release(device);
      return s;
    }
    slot_device_ = device;
    env_.session_streams->TryAcquire(session_id_, std::numeric_limits<int>::max());
    slot_session_ = session_id_;
    return absl::OkStatus();
  }

  void ReleaseSlot() {
    std::lock_guard lock(slot_mu_);
    if (slot_device_.empty()) return;
    env_.device_slots->Release(slot_device_);
    env_.device_claims->Release(slot_device_);
    env_.session_streams->Release(slot_session_);
    slot_device_.clear();
    slot_session_.clear();
  }

  // Another server took the device's claim (this one's renewal came too late): the stream
  // ends, as it would have been refused there.
  absl::Status CheckClaim() {
    if (env_.device_claims->Held(live_->device.id)) return absl::OkStatus();
    return absl::ResourceExhaustedError(absl::StrCat(
        "another server took device ", live_->device.id,
        "'s sample stream (this server could not renew its claim in time); resume from "
        "GetSession().last_acked_seq + 1"));
  }

  const StreamEnv& env_;
  grpc::CallbackServerContext* context_;  // the call's; valid until OnDone
  PrincipalRef who_;
  std::shared_ptr<IngestReactor> self_;  // from Start to OnDone
  bool registered_ = false;              // set before the first read, read in OnDone

  // Touched by one reaction at a time (a read, the load, the store's callback follow each
  // other), not by Revoke or Expire.
  std::string session_id_;
  std::shared_ptr<LiveSession> live_;
  int64_t messages_ = 0;  // read on this stream, for error messages
  grpc::ByteBuffer request_;
  v1::SampleBatch batch_;
  PreparedBatch prepared_;

  std::mutex mu_;
  State state_ = State::kBusy;               // guarded by mu_
  bool first_read_ = true;                   // guarded by mu_: reading the stream's first batch
  bool finished_ = false;                    // guarded by mu_: Finish was called
  std::optional<grpc::Status> pending_end_;  // guarded by mu_: revoked while busy
  int64_t last_seq_ = 0;                     // guarded by mu_; the last acknowledged seq
  grpc::ByteBuffer response_;                // guarded by mu_

  std::mutex ctx_mu_;
  bool done_ = false;  // guarded by ctx_mu_: OnDone has begun, context_ is going

  std::mutex slot_mu_;
  std::string slot_device_;   // guarded by slot_mu_; empty when no slot is held
  std::string slot_session_;  // guarded by slot_mu_; the session counted with the slot
};

// WatchSession: a snapshot, then the session's events as they are published. The hub pushes
// into a bounded queue that this reactor drains with one write at a time; a slow watcher gets
// its stillness updates coalesced and, when far behind, loses the oldest events, but never
// slows ingest. A watcher whose write has not gone out for watch_stall_timeout (its client
// stopped reading) is cancelled, its slot freed. A closed session that is not in memory gets
// its snapshot from storage and the end of the stream, without being loaded; an open one not
// in memory is loaded off the RPC threads first.
class WatchReactor final : public grpc::ServerWriteReactor<v1::SessionEvent>,
                           public Watcher,
                           public StreamRegistry::Stream,
                           public std::enable_shared_from_this<WatchReactor> {
 public:
  static constexpr size_t kMaxQueued = 256;

  WatchReactor(const StreamEnv& env, grpc::CallbackServerContext* context, PrincipalRef who,
               std::string session_id)
      : env_(env), context_(context), who_(std::move(who)), session_id_(std::move(session_id)) {}

  // Called once, by the handler, on a reactor owned by `self`.
  void Start(std::shared_ptr<WatchReactor> self) {
    self_ = std::move(self);
    if (absl::Status s = env_.registry->Add(shared_from_this(), CallerKey(*who_), who_->token_id);
        !s.ok()) {
      End(ToGrpcStatus(s));
      return;
    }
    registered_ = true;
    if (std::shared_ptr<LiveSession> live = env_.hub->Find(session_id_)) {
      Begin(std::move(live));
      return;
    }
    absl::StatusOr<v1::Session> snapshot = env_.session_proto(session_id_);
    if (!snapshot.ok()) {
      End(ToGrpcStatus(snapshot.status()));
      return;
    }
    // Closed: what it was, then the end. A solving session is followed to its solve's end,
    // wherever that runs (this server, or another one sharing the database: ListenForChanges).
    if (snapshot->state() != v1::SESSION_STATE_OPEN &&
        snapshot->state() != v1::SESSION_STATE_SOLVING) {
      std::lock_guard lock(mu_);
      queue_.push_back(SnapshotEvent(*std::move(snapshot)));
      closing_ = true;
      WriteNextLocked();
      return;
    }
    std::shared_ptr<WatchReactor> me = shared_from_this();
    const bool queued = env_.defer([me] {
      absl::StatusOr<std::shared_ptr<LiveSession>> live = me->env_.hub->Get(me->session_id_);
      if (live.ok()) {
        me->Begin(*std::move(live));
      } else {
        me->End(ToGrpcStatus(live.status()));
      }
    });
    if (!queued) {
      End(grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                       "too many sessions are being loaded; retry in a moment"));
    }
  }

  void Push(const v1::SessionEvent& event) override {
    std::lock_guard lock(mu_);
    if (finished_ || closing_ || revoked_) return;
    if (event.has_stillness() && !queue_.empty() && queue_.back().has_stillness() &&
        !(writing_ && queue_.size() == 1)) {
      queue_.back() = event;  // coalesce: only the latest stillness matters
    } else {
      if (queue_.size() >= kMaxQueued) DropOldestLocked();
      queue_.push_back(event);
    }
    WriteNextLocked();
  }

  void Close() override {
    std::lock_guard lock(mu_);
    closing_ = true;
    WriteNextLocked();
  }

  void OnWriteDone(bool ok) override {
    std::lock_guard lock(mu_);
    writing_ = false;
    SetDeadline(absl::InfiniteFuture());
    queue_.pop_front();
    if (!ok) {
      FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "the watcher went away"));
      return;
    }
    WriteNextLocked();
  }

  // The slot is free as soon as the watcher is known gone, not when the last write drains: a
  // watcher that cancels may be followed by another at once.
  void OnCancel() override {
    std::lock_guard lock(mu_);
    cancelled_ = true;
    ReleaseSlotLocked();
    WriteNextLocked();
  }

  void OnDone() override {
    {
      std::lock_guard lock(ctx_mu_);
      done_ = true;
    }
    if (registered_) env_.registry->Remove(this);
    std::shared_ptr<LiveSession> live;
    {
      std::lock_guard lock(mu_);
      ReleaseSlotLocked();
      live = live_;
    }
    if (live != nullptr) env_.hub->RemoveWatcher(*live, this);
    std::shared_ptr<WatchReactor> last = std::move(self_);  // may delete this on return
  }

  void Revoke(const grpc::Status& status) override {
    std::lock_guard lock(mu_);
    if (finished_) return;
    revoked_ = status;
    // What is queued is not sent; a write in flight completes first.
    while (queue_.size() > (writing_ ? 1u : 0u)) queue_.pop_back();
    WriteNextLocked();
  }

  void Expire(absl::Time now) override {
    {
      std::lock_guard lock(mu_);
      if (finished_ || !writing_ || !PastDeadline(now)) return;
    }
    std::lock_guard lock(ctx_mu_);
    if (!done_) context_->TryCancel();  // OnCancel frees the slot; the write then fails
  }

 private:
  static v1::SessionEvent SnapshotEvent(v1::Session snapshot) {
    v1::SessionEvent e;
    ToTimestamp(absl::Now(), e.mutable_time());
    *e.mutable_session() = std::move(snapshot);
    return e;
  }

  // The session is in memory: a watcher slot, the snapshot and the guidance, then its events.
  void Begin(std::shared_ptr<LiveSession> live) {
    absl::StatusOr<v1::Session> snapshot = env_.session_proto(session_id_);
    if (!snapshot.ok()) {
      End(ToGrpcStatus(snapshot.status()));
      return;
    }
    core::NextPoseUpdate next;
    {
      std::lock_guard lock(live->mu);
      next = live->segmenter->CurrentNextPose();
    }
    if (!env_.watcher_slots->TryAcquire(session_id_, env_.options->max_watchers_per_session)) {
      End(grpc::Status(
          grpc::StatusCode::RESOURCE_EXHAUSTED,
          absl::StrCat("session ", session_id_, " already has ",
                       env_.options->max_watchers_per_session, " watchers, the most it may have")));
      return;
    }
    {
      std::lock_guard lock(mu_);
      slot_held_ = true;
      live_ = live;
      if (finished_ || cancelled_) {
        ReleaseSlotLocked();
        WriteNextLocked();
        return;
      }
      const bool guide = snapshot->state() == v1::SESSION_STATE_OPEN;
      queue_.push_back(SnapshotEvent(*std::move(snapshot)));
      if (guide) queue_.push_back(SessionHub::NextPoseEvent(next));
      WriteNextLocked();
    }
    env_.hub->AddWatcher(*live, this);  // after this, events flow
  }

  void End(const grpc::Status& status) {
    std::lock_guard lock(mu_);
    FinishLocked(status);
  }

  void ReleaseSlotLocked() {
    if (!slot_held_) return;
    slot_held_ = false;
    env_.watcher_slots->Release(session_id_);
  }

  // Writes the next event, or ends the call. A cancelled watch ends here, at once or when its
  // write in flight completes: that write may still succeed after OnCancel (its bytes were
  // already with the transport), and the watch would otherwise wait, slot held, for an event
  // that never comes. A revoked one ends the same way, with its status.
  void WriteNextLocked() {
    if (finished_ || writing_) return;
    if (cancelled_) {
      FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "cancelled"));
      return;
    }
    if (revoked_) {
      FinishLocked(*revoked_);
      return;
    }
    if (!queue_.empty()) {
      writing_ = true;
      SetDeadline(absl::Now() + env_.options->watch_stall_timeout);
      StartWrite(&queue_.front());
      return;
    }
    if (closing_) FinishLocked(grpc::Status::OK);
  }

  void FinishLocked(const grpc::Status& status) {
    if (finished_) return;
    finished_ = true;
    SetDeadline(absl::InfiniteFuture());
    ReleaseSlotLocked();
    Finish(status);
  }

  // The front may be being written: never drop it. Stillness and progress go first.
  void DropOldestLocked() {
    const size_t first = writing_ ? 1 : 0;
    for (size_t i = first; i < queue_.size(); ++i) {
      if (queue_[i].has_stillness() || queue_[i].has_progress()) {
        queue_.erase(queue_.begin() + static_cast<long>(i));
        return;
      }
    }
    if (queue_.size() > first) queue_.erase(queue_.begin() + static_cast<long>(first));
  }

  const StreamEnv& env_;
  grpc::CallbackServerContext* context_;  // the call's; valid until OnDone
  PrincipalRef who_;
  const std::string session_id_;
  std::shared_ptr<WatchReactor> self_;  // from Start to OnDone
  bool registered_ = false;             // set in Start, read in OnDone

  std::mutex mu_;
  std::shared_ptr<LiveSession> live_;    // guarded by mu_; null until Begin
  std::deque<v1::SessionEvent> queue_;   // guarded by mu_; the front is being written
  bool writing_ = false;                 // guarded by mu_
  bool closing_ = false;                 // guarded by mu_
  bool finished_ = false;                // guarded by mu_
  bool cancelled_ = false;               // guarded by mu_
  bool slot_held_ = false;               // guarded by mu_
  std::optional<grpc::Status> revoked_;  // guarded by mu_

  std::mutex ctx_mu_;
  bool done_ = false;  // guarded by ctx_mu_: OnDone has begun, context_ is going
};

// ReadSamples: the session's stored batches, paged out of storage (Store::ReadBatchPage) as
// the client reads them, one message in flight: the server holds one page of stored payloads
// (at most kPageSamples samples past its first batch) and one decoded batch, whatever the
// session's length. The end is the session's last stored batch when the call started (an open
// session may grow meanwhile). A client that reads no message for stream_idle_timeout is
// cancelled. Storage is read on the thread of the write that finished, as unary handlers read it:
// a page is a short read of the file.
class ReadReactor final : public grpc::ServerWriteReactor<v1::SampleBatch>,
                          public StreamRegistry::Stream,
                          public std::enable_shared_from_this<ReadReactor> {
 public:
  static constexpr int64_t kMaxMessageSamples = 10000;  // 0.6 MB with temperature
  static constexpr int64_t kPageBatches = 256;
  static constexpr int64_t kPageSamples = 20000;

  ReadReactor(const StreamEnv& env, grpc::CallbackServerContext* context, PrincipalRef who,
              std::string session_id)
      : env_(env), context_(context), who_(std::move(who)), session_id_(std::move(session_id)) {}

  // Called once, by the handler, on a reactor owned by `self`.
  void Start(std::shared_ptr<ReadReactor> self) {
    self_ = std::move(self);
    if (absl::Status s = env_.registry->Add(shared_from_this(), CallerKey(*who_), who_->token_id);
        !s.ok()) {
      End(ToGrpcStatus(s));
      return;
    }
    registered_ = true;
    absl::StatusOr<storage::Session> session = env_.store->GetSession(session_id_);
    if (!session.ok()) {
      End(ToGrpcStatus(session.status()));
      return;
    }
    std::lock_guard lock(mu_);
    end_seq_ = session->last_acked_seq;
    WriteNextLocked();
  }

  void OnWriteDone(bool ok) override {
    std::lock_guard lock(mu_);
    writing_ = false;
    SetDeadline(absl::InfiniteFuture());
    if (!ok) {
      FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "the reader went away"));
      return;
    }
    WriteNextLocked();
  }

  void OnCancel() override {
    std::lock_guard lock(mu_);
    cancelled_ = true;
    WriteNextLocked();
  }

  void OnDone() override {
    {
      std::lock_guard lock(ctx_mu_);
      done_ = true;
    }
    if (registered_) env_.registry->Remove(this);
    std::shared_ptr<ReadReactor> last = std::move(self_);  // may delete this on return
  }

  void Revoke(const grpc::Status& status) override {
    std::lock_guard lock(mu_);
    if (finished_) return;
    revoked_ = status;
    WriteNextLocked();  // at once, or when the write in flight completes
  }

  void Expire(absl::Time now) override {
    {
      std::lock_guard lock(mu_);
      if (finished_ || !writing_ || !PastDeadline(now)) return;
    }
    std::lock_guard lock(ctx_mu_);
    if (!done_) context_->TryCancel();  // the write then fails
  }

 private:
  void End(const grpc::Status& status) {
    std::lock_guard lock(mu_);
    FinishLocked(status);
  }

  void FinishLocked(const grpc::Status& status) {
    if (finished_) return;
    finished_ = true;
    SetDeadline(absl::InfiniteFuture());
    // What is held goes now, not when gRPC lets go of the reactor.
    page_.clear();
    samples_.clear();
    samples_.shrink_to_fit();
    Finish(status);
  }

  // Makes the next message: the next (at most kMaxMessageSamples) samples of the current
  // batch, decoding the page's next batch or reading the next page when needed. false: no
  // samples are left (or an error ended the call).
  bool NextMessageLocked() {
    while (offset_ >= samples_.size()) {
      if (page_.empty()) {
        if (after_seq_ >= end_seq_) return false;
        absl::StatusOr<std::vector<storage::SampleBatch>> page = env_.store->ReadBatchPage(
            session_id_, after_seq_, std::min(kPageBatches, end_seq_ - after_seq_), kPageSamples);
        if (!page.ok()) {
          FinishLocked(ToGrpcStatus(page.status()));
          return false;
        }
        if (page->empty()) return false;
        after_seq_ = page->back().seq;
        page_.assign(std::make_move_iterator(page->begin()), std::make_move_iterator(page->end()));
      }
      storage::SampleBatch batch = std::move(page_.front());
      page_.pop_front();
      samples_.clear();
      if (absl::Status s = storage::DecodeSamplesInto(batch.payload, &samples_); !s.ok()) {
        FinishLocked(ToGrpcStatus(absl::DataLossError(
            absl::StrCat("session ", session_id_, " batch ", batch.seq, ": ", s.message()))));
        return false;
      }
      offset_ = 0;
      seq_ = batch.seq;
    }
    const size_t n = std::min(samples_.size() - offset_, static_cast<size_t>(kMaxMessageSamples));
    const bool temp = !std::isnan(samples_[offset_].temp);  // a batch has it for all or none
    message_.Clear();
    message_.set_session_id(session_id_);
    message_.set_seq(seq_);
    message_.mutable_t_s()->Reserve(static_cast<int>(n));
    message_.mutable_accel()->Reserve(static_cast<int>(3 * n));
    message_.mutable_gyro()->Reserve(static_cast<int>(3 * n));
    if (temp) message_.mutable_temp_c()->Reserve(static_cast<int>(n));
    for (size_t i = offset_; i < offset_ + n; ++i) {
      const storage::ImuSample& x = samples_[i];
      message_.add_t_s(x.t_s);
      for (int k = 0; k < 3; ++k) message_.add_accel(x.accel[k]);
      for (int k = 0; k < 3; ++k) message_.add_gyro(x.gyro[k]);
      if (temp) message_.add_temp_c(x.temp);
    }
    offset_ += n;
    return true;
  }

  // Writes the next message, or ends the call: cancelled, revoked, or every sample sent.
  void WriteNextLocked() {
    if (finished_ || writing_) return;
    if (cancelled_) {
      FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "cancelled"));
      return;
    }
    if (revoked_) {
      FinishLocked(*revoked_);
      return;
    }
    if (!NextMessageLocked()) {
      FinishLocked(grpc::Status::OK);  // a no-op when an error has finished the call
      return;
    }
    writing_ = true;
    SetDeadline(absl::Now() + env_.options->stream_idle_timeout);
    StartWrite(&message_);
  }

  const StreamEnv& env_;
  grpc::CallbackServerContext* context_;  // the call's; valid until OnDone
  PrincipalRef who_;
  const std::string session_id_;
  std::shared_ptr<ReadReactor> self_;  // from Start to OnDone
  bool registered_ = false;            // set in Start, read in OnDone

  std::mutex mu_;
  int64_t end_seq_ = 0;                      // guarded by mu_: the last batch to send
  int64_t after_seq_ = 0;                    // guarded by mu_: the last batch read from storage
  std::deque<storage::SampleBatch> page_;    // guarded by mu_: read, not yet decoded
  std::vector<storage::ImuSample> samples_;  // guarded by mu_: the batch being sent
  size_t offset_ = 0;                        // guarded by mu_: its first sample not yet sent
  int64_t seq_ = 0;                          // guarded by mu_: its seq
  v1::SampleBatch message_;                  // guarded by mu_; the one being written
  bool writing_ = false;                     // guarded by mu_
  bool finished_ = false;                    // guarded by mu_
  bool cancelled_ = false;                   // guarded by mu_
  std::optional<grpc::Status> revoked_;      // guarded by mu_

  std::mutex ctx_mu_;
  bool done_ = false;  // guarded by ctx_mu_: OnDone has begun, context_ is going
};

// A call refused before it starts (its caller may not make it).
class FailedStream final : public grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer> {
 public:
  explicit FailedStream(const grpc::Status& status) { Finish(status); }
  void OnDone() override { delete this; }
};

template <typename Message>
class FailedWriter final : public grpc::ServerWriteReactor<Message> {
 public:
  explicit FailedWriter(const grpc::Status& status) { this->Finish(status); }
  void OnDone() override { delete this; }
};

}  // namespace

grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer>* SessionServiceImpl::StreamSamples(
    grpc::CallbackServerContext* context) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kStreamSamples);
  if (!who.ok()) return new FailedStream(ToGrpcStatus(who.status()));
  auto reactor = std::make_shared<IngestReactor>(env_, context, *std::move(who));
  IngestReactor* raw = reactor.get();
  raw->Start(std::move(reactor));
  return raw;
}

grpc::ServerWriteReactor<v1::SessionEvent>* SessionServiceImpl::WatchSession(
    grpc::CallbackServerContext* context, const v1::WatchSessionRequest* request) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kWatchSession);
  if (!who.ok()) return new FailedWriter<v1::SessionEvent>(ToGrpcStatus(who.status()));
  if (request->session_id().empty())
    return new FailedWriter<v1::SessionEvent>(
        grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "session_id: required"));
  auto reactor =
      std::make_shared<WatchReactor>(env_, context, *std::move(who), request->session_id());
  WatchReactor* raw = reactor.get();
  raw->Start(std::move(reactor));
  return raw;
}

grpc::ServerWriteReactor<v1::SampleBatch>* SessionServiceImpl::ReadSamples(
    grpc::CallbackServerContext* context, const v1::ReadSamplesRequest* request) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kReadSamples);
  if (!who.ok()) return new FailedWriter<v1::SampleBatch>(ToGrpcStatus(who.status()));
  if (request->session_id().empty())
    return new FailedWriter<v1::SampleBatch>(
        grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "session_id: required"));
  auto reactor =
      std::make_shared<ReadReactor>(env_, context, *std::move(who), request->session_id());
  ReadReactor* raw = reactor.get();
  raw->Start(std::move(reactor));
  return raw;
}

}  // namespace imucal::server
