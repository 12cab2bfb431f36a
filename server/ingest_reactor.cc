// StreamSamples, the robots' upload: the stream reactor that stores each batch and
// acknowledges it (server/stream_reactor.h has the life it shares with the others).
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
#include "server/session_streams.h"
#include "server/status_util.h"
#include "server/stream_reactor.h"
#include "util/text_check.h"

namespace imucal::server {
namespace {

constexpr size_t kMaxSourceBytes = 256;

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
class IngestReactor final
    : public StreamReactor<IngestReactor,
                           grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer>> {
 public:
  // `who` may call StreamSamples (Authorize passed); a robot still only for its own device's
  // sessions, checked at the first batch (which names the session).
  IngestReactor(const StreamEnv& env, grpc::CallbackServerContext* context, PrincipalRef who)
      : StreamReactor(env, context, std::move(who)) {}

  // Registers the stream and reads its first batch, or ends it at once (a cap, a revoked
  // token).
  void Start() override {
    // Silent until its first batch: its place may go to a caller with fewer streams meanwhile.
    if (!Registered(/*silent=*/true)) return;
    std::lock_guard lock(mu_);
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

  void Released() override { ReleaseSlot(); }

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
    CancelCall();
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

  // The slots are free before the status leaves: a robot that sees its stream end may open the
  // next one at once, within the device's and the server's caps (the registry's Remove is a
  // no-op for a stream that never registered, and OnDone's is then one too).
  void FinishingLocked() override {
    ReleaseSlot();
    env_.registry->Remove(this);
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

  // Touched by one reaction at a time (a read, the load, the store's callback follow each
  // other), not by Revoke or Expire.
  std::string session_id_;
  std::shared_ptr<LiveSession> live_;
  int64_t messages_ = 0;  // read on this stream, for error messages
  grpc::ByteBuffer request_;
  v1::SampleBatch batch_;
  PreparedBatch prepared_;

  State state_ = State::kBusy;               // guarded by mu_
  bool first_read_ = true;                   // guarded by mu_: reading the stream's first batch
  std::optional<grpc::Status> pending_end_;  // guarded by mu_: revoked while busy
  int64_t last_seq_ = 0;                     // guarded by mu_; the last acknowledged seq
  grpc::ByteBuffer response_;                // guarded by mu_

  std::mutex slot_mu_;
  std::string slot_device_;   // guarded by slot_mu_; empty when no slot is held
  std::string slot_session_;  // guarded by slot_mu_; the session counted with the slot
};

}  // namespace

grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer>* StartStreamSamples(
    const StreamEnv& env, grpc::CallbackServerContext* context) {
  absl::StatusOr<PrincipalRef> who = env.auth->Authorize(*context, Rpc::kStreamSamples);
  if (!who.ok()) {
    return new FailedCall<grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer>>(
        ToGrpcStatus(who.status()));
  }
  return IngestReactor::Create(env, context, *std::move(who));
}

}  // namespace imucal::server
