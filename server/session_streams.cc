// The two streaming RPCs of SessionService as callback reactors (no thread per stream).
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "server/ingest.h"
#include "server/services.h"
#include "server/status_util.h"

namespace imucal::server {
namespace {

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
// the stream). The stream holds one of its device's slots (max_streams_per_device) from its
// first batch until it ends or is cancelled.
class IngestReactor final : public grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer> {
 public:
  // `who` may call StreamSamples (Authorize passed); a robot still only for its own device's
  // sessions, checked at the first batch (which names the session).
  IngestReactor(storage::Store* store, SessionHub* hub, const SessionServiceOptions& options,
                StreamSlots* slots, Authorizer* auth, const grpc::CallbackServerContext* context,
                PrincipalRef who)
      : store_(store),
        hub_(hub),
        options_(options),
        slots_(slots),
        auth_(auth),
        context_(context),
        who_(std::move(who)) {
    StartRead(&request_);
  }

  void OnReadDone(bool ok) override {
    if (!ok) {  // the robot closed its side: everything read has been acknowledged
      End(grpc::Status::OK);
      return;
    }
    if (absl::Status s = Submit(); !s.ok()) End(ToGrpcStatus(s));
  }

  void OnWriteDone(bool ok) override {
    if (!ok) {
      End(grpc::Status(grpc::StatusCode::UNAVAILABLE, "the stream broke while acknowledging"));
      return;
    }
    StartRead(&request_);
  }

  // The robot went away (or its deadline passed): the device may stream again at once.
  void OnCancel() override { ReleaseSlot(); }

  void OnDone() override {
    ReleaseSlot();
    delete this;
  }

 private:
  // parse -> validate -> convert -> store (asynchronously; OnStored continues).
  absl::Status Submit() {
    batch_.Clear();
    ++messages_;
    const size_t bytes = request_.Length();
    if (!grpc::SerializationTraits<v1::SampleBatch>::Deserialize(&request_, &batch_).ok()) {
      return absl::InvalidArgumentError(
          absl::StrCat("message ", messages_, " of the stream (after batch ", last_seq_,
                       "): ", bytes, " bytes that are not a SampleBatch (malformed protobuf)"));
    }
    if (session_id_.empty()) {
      if (batch_.session_id().empty())
        return absl::InvalidArgumentError("session_id: required in the first batch of a stream");
      session_id_ = batch_.session_id();
    } else if (!batch_.session_id().empty() && batch_.session_id() != session_id_) {
      return absl::InvalidArgumentError(absl::StrCat("session_id: the stream is for session ",
                                                     session_id_, ", not ", batch_.session_id()));
    }
    if (live_ == nullptr) {
      absl::StatusOr<std::shared_ptr<LiveSession>> live = hub_->Get(session_id_);
      if (!live.ok()) return live.status();
      if (absl::Status s =
              auth_->AuthorizeDevice(*context_, *who_, Rpc::kStreamSamples, (*live)->device.id);
          !s.ok())
        return s;
      live_ = *std::move(live);
      if (absl::Status s = AcquireSlot(); !s.ok()) return s;
    }
    absl::StatusOr<PreparedBatch> prepared;
    {
      std::lock_guard lock(live_->mu);
      prepared = PrepareBatch(*live_, batch_, options_.ingest);
    }
    if (!prepared.ok()) return prepared.status();
    prepared_ = *std::move(prepared);
    store_->AppendBatchAsync(
        session_id_, prepared_.seq, std::move(prepared_.payload),
        [this](absl::StatusOr<storage::BatchAck> ack) { OnStored(std::move(ack)); });
    return absl::OkStatus();
  }

  // Durable (or refused): segment, tell the watchers, acknowledge.
  void OnStored(absl::StatusOr<storage::BatchAck> stored) {
    if (!stored.ok()) {
      End(ToGrpcStatus(stored.status()));
      return;
    }
    IngestResult result;
    {
      std::lock_guard lock(live_->mu);
      result = CompleteBatch(*store_, *live_, prepared_, *stored);
    }
    prepared_ = PreparedBatch();
    for (const v1::SessionEvent& e : result.events) hub_->Publish(*live_, e);
    last_seq_ = result.ack.last_acked_seq();
    bool own_buffer = false;
    response_.Clear();
    if (grpc::Status s = grpc::SerializationTraits<v1::SampleAck>::Serialize(result.ack, &response_,
                                                                             &own_buffer);
        !s.ok()) {
      End(s);
      return;
    }
    StartWrite(&response_);
  }

  // The slot is free before the status leaves: a robot that sees its stream end may open the
  // next one at once.
  void End(const grpc::Status& status) {
    ReleaseSlot();
    Finish(status);
  }

  absl::Status AcquireSlot() {
    std::lock_guard lock(slot_mu_);
    const std::string& device = live_->device.id;
    if (!slots_->TryAcquire(device, options_.max_streams_per_device)) {
      return absl::ResourceExhaustedError(absl::StrCat(
          "device ", device, " already has ", options_.max_streams_per_device,
          " sample stream(s) open, the most a device may have; end it (or wait for the server "
          "to see that it broke) and resume from GetSession().last_acked_seq + 1"));
    }
    slot_device_ = device;
    return absl::OkStatus();
  }

  void ReleaseSlot() {
    std::lock_guard lock(slot_mu_);
    if (slot_device_.empty()) return;
    slots_->Release(slot_device_);
    slot_device_.clear();
  }

  storage::Store* store_;
  SessionHub* hub_;
  const SessionServiceOptions& options_;
  StreamSlots* slots_;
  Authorizer* auth_;
  const grpc::CallbackServerContext* context_;  // the call's; valid until OnDone
  PrincipalRef who_;
  std::string session_id_;
  std::shared_ptr<LiveSession> live_;
  int64_t messages_ = 0;  // read on this stream, for error messages
  int64_t last_seq_ = 0;  // the last acknowledged seq, for error messages
  grpc::ByteBuffer request_;
  grpc::ByteBuffer response_;
  v1::SampleBatch batch_;
  PreparedBatch prepared_;
  std::mutex slot_mu_;
  std::string slot_device_;  // guarded by slot_mu_; empty when no slot is held
};

// WatchSession: a snapshot, then the session's events as they are published. The hub pushes
// into a bounded queue that this reactor drains with one write at a time; a slow watcher gets
// its stillness updates coalesced and, when far behind, loses the oldest events, but never
// slows ingest.
class WatchReactor final : public grpc::ServerWriteReactor<v1::SessionEvent>, public Watcher {
 public:
  static constexpr size_t kMaxQueued = 256;

  // Holds one of the session's watcher slots (taken by the caller), released when the watcher
  // cancels or, at the latest, in OnDone.
  WatchReactor(SessionHub* hub, StreamSlots* slots, std::shared_ptr<LiveSession> live,
               v1::Session snapshot, bool six_face_next, const core::NextPoseUpdate& next)
      : hub_(hub), slots_(slots), live_(std::move(live)) {
    v1::SessionEvent first;
    ToTimestamp(absl::Now(), first.mutable_time());
    *first.mutable_session() = std::move(snapshot);
    queue_.push_back(std::move(first));
    if (six_face_next) queue_.push_back(SessionHub::NextPoseEvent(next));
    std::lock_guard lock(mu_);
    WriteNextLocked();
  }

  // Registers with the hub; after this, events flow. Separate from the constructor so that the
  // hub never sees a half-built reactor.
  void Attach() { hub_->AddWatcher(*live_, this); }

  void Push(const v1::SessionEvent& event) override {
    std::lock_guard lock(mu_);
    if (finished_ || closing_) return;
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
    hub_->RemoveWatcher(*live_, this);
    {
      std::lock_guard lock(mu_);
      ReleaseSlotLocked();
    }
    delete this;
  }

 private:
  void ReleaseSlotLocked() {
    if (!slot_held_) return;
    slot_held_ = false;
    slots_->Release(live_->id);
  }

  // Writes the next event, or ends the call. A cancelled watch ends here, at once or when its
  // write in flight completes: that write may still succeed after OnCancel (its bytes were
  // already with the transport), and the watch would otherwise wait, slot held, for an event
  // that never comes.
  void WriteNextLocked() {
    if (finished_ || writing_) return;
    if (cancelled_) {
      FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "cancelled"));
      return;
    }
    if (!queue_.empty()) {
      writing_ = true;
      StartWrite(&queue_.front());
      return;
    }
    if (closing_) FinishLocked(grpc::Status::OK);
  }

  void FinishLocked(const grpc::Status& status) {
    if (finished_) return;
    finished_ = true;
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

  SessionHub* hub_;
  StreamSlots* slots_;
  std::shared_ptr<LiveSession> live_;
  std::mutex mu_;
  std::deque<v1::SessionEvent> queue_;  // guarded by mu_; the front is being written
  bool writing_ = false;                // guarded by mu_
  bool closing_ = false;                // guarded by mu_
  bool finished_ = false;               // guarded by mu_
  bool cancelled_ = false;              // guarded by mu_
  bool slot_held_ = true;               // guarded by mu_; taken by WatchSession before construction
};

// A stream that fails before it starts.
// A sample stream refused before it starts (its caller may not stream).
class FailedStream final : public grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer> {
 public:
  explicit FailedStream(const grpc::Status& status) { Finish(status); }
  void OnDone() override { delete this; }
};

class FailedWriter final : public grpc::ServerWriteReactor<v1::SessionEvent> {
 public:
  explicit FailedWriter(const grpc::Status& status) { Finish(status); }
  void OnDone() override { delete this; }
};

// A session that is closed and not in memory: its snapshot, then the end of the stream (what
// a watcher of a live session gets when the session closes), without loading it into the hub.
class SnapshotWriter final : public grpc::ServerWriteReactor<v1::SessionEvent> {
 public:
  explicit SnapshotWriter(v1::Session snapshot) {
    ToTimestamp(absl::Now(), event_.mutable_time());
    *event_.mutable_session() = std::move(snapshot);
    StartWriteAndFinish(&event_, grpc::WriteOptions(), grpc::Status::OK);
  }
  void OnDone() override { delete this; }

 private:
  v1::SessionEvent event_;
};

}  // namespace

grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer>* SessionServiceImpl::StreamSamples(
    grpc::CallbackServerContext* context) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kStreamSamples);
  if (!who.ok()) return new FailedStream(ToGrpcStatus(who.status()));
  return new IngestReactor(store_, &hub_, options_, &stream_slots_, auth_, context,
                           *std::move(who));
}

grpc::ServerWriteReactor<v1::SessionEvent>* SessionServiceImpl::WatchSession(
    grpc::CallbackServerContext* context, const v1::WatchSessionRequest* request) {
  if (absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kWatchSession); !who.ok())
    return new FailedWriter(ToGrpcStatus(who.status()));
  if (request->session_id().empty())
    return new FailedWriter(
        grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "session_id: required"));
  // A closed session that is not in memory is not loaded (SessionProto says why).
  if (hub_.PeekPosesAccepted(request->session_id()) < 0) {
    absl::StatusOr<v1::Session> snapshot = SessionProto(request->session_id());
    if (!snapshot.ok()) return new FailedWriter(ToGrpcStatus(snapshot.status()));
    if (snapshot->state() != v1::SESSION_STATE_OPEN)
      return new SnapshotWriter(*std::move(snapshot));
  }
  absl::StatusOr<std::shared_ptr<LiveSession>> live = hub_.Get(request->session_id());
  if (!live.ok()) return new FailedWriter(ToGrpcStatus(live.status()));
  absl::StatusOr<v1::Session> snapshot = SessionProto(request->session_id());
  if (!snapshot.ok()) return new FailedWriter(ToGrpcStatus(snapshot.status()));
  core::NextPoseUpdate next;
  bool guide = false;
  {
    std::lock_guard lock((*live)->mu);
    guide = snapshot->state() == v1::SESSION_STATE_OPEN;
    next = (*live)->segmenter->CurrentNextPose();
  }
  if (!watcher_slots_.TryAcquire(request->session_id(), options_.max_watchers_per_session)) {
    return new FailedWriter(grpc::Status(
        grpc::StatusCode::RESOURCE_EXHAUSTED,
        absl::StrCat("session ", request->session_id(), " already has ",
                     options_.max_watchers_per_session, " watchers, the most it may have")));
  }
  auto* reactor =
      new WatchReactor(&hub_, &watcher_slots_, *live, *std::move(snapshot), guide, next);
  reactor->Attach();
  return reactor;
}

}  // namespace imucal::server
