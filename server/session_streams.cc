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
class IngestReactor final : public grpc::ServerBidiReactor<v1::SampleBatch, v1::SampleAck> {
 public:
  IngestReactor(storage::Store* store, SessionHub* hub) : store_(store), hub_(hub) {
    StartRead(&batch_);
  }

  void OnReadDone(bool ok) override {
    if (!ok) {  // the robot closed its side: everything read has been acknowledged
      Finish(grpc::Status::OK);
      return;
    }
    if (absl::Status s = Submit(); !s.ok()) Finish(ToGrpcStatus(s));
  }

  void OnWriteDone(bool ok) override {
    if (!ok) {
      Finish(grpc::Status(grpc::StatusCode::UNAVAILABLE, "the stream broke while acknowledging"));
      return;
    }
    StartRead(&batch_);
  }

  void OnDone() override { delete this; }

 private:
  // validate -> convert -> store (asynchronously; OnStored continues).
  absl::Status Submit() {
    if (session_id_.empty()) {
      if (batch_.session_id().empty())
        return absl::InvalidArgumentError("session_id: required in the first batch of a stream");
      session_id_ = batch_.session_id();
    } else if (!batch_.session_id().empty() && batch_.session_id() != session_id_) {
      return absl::InvalidArgumentError(absl::StrCat(
          "session_id: the stream is for session ", session_id_, ", not ", batch_.session_id()));
    }
    if (live_ == nullptr) {
      absl::StatusOr<std::shared_ptr<LiveSession>> live = hub_->Get(session_id_);
      if (!live.ok()) return live.status();
      live_ = *std::move(live);
    }
    absl::StatusOr<PreparedBatch> prepared;
    {
      std::lock_guard lock(live_->mu);
      prepared = PrepareBatch(*live_, batch_);
    }
    if (!prepared.ok()) return prepared.status();
    prepared_ = *std::move(prepared);
    store_->AppendBatchAsync(session_id_, prepared_.seq, std::move(prepared_.payload),
                             [this](absl::StatusOr<storage::BatchAck> ack) {
                               OnStored(std::move(ack));
                             });
    return absl::OkStatus();
  }

  // Durable (or refused): segment, tell the watchers, acknowledge.
  void OnStored(absl::StatusOr<storage::BatchAck> stored) {
    if (!stored.ok()) {
      Finish(ToGrpcStatus(stored.status()));
      return;
    }
    IngestResult result;
    {
      std::lock_guard lock(live_->mu);
      result = CompleteBatch(*store_, *live_, prepared_, *stored);
    }
    prepared_ = PreparedBatch();
    for (const v1::SessionEvent& e : result.events) hub_->Publish(*live_, e);
    ack_ = std::move(result.ack);
    StartWrite(&ack_);
  }

  storage::Store* store_;
  SessionHub* hub_;
  std::string session_id_;
  std::shared_ptr<LiveSession> live_;
  v1::SampleBatch batch_;
  PreparedBatch prepared_;
  v1::SampleAck ack_;
};

// WatchSession: a snapshot, then the session's events as they are published. The hub pushes
// into a bounded queue that this reactor drains with one write at a time; a slow watcher gets
// its stillness updates coalesced and, when far behind, loses the oldest events, but never
// slows ingest.
class WatchReactor final : public grpc::ServerWriteReactor<v1::SessionEvent>, public Watcher {
 public:
  static constexpr size_t kMaxQueued = 256;

  WatchReactor(SessionHub* hub, std::shared_ptr<LiveSession> live, v1::Session snapshot,
               bool six_face_next, const core::NextPoseUpdate& next)
      : hub_(hub), live_(std::move(live)) {
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

  void OnCancel() override {
    std::lock_guard lock(mu_);
    if (!writing_) FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "cancelled"));
  }

  void OnDone() override {
    hub_->RemoveWatcher(*live_, this);
    delete this;
  }

 private:
  void WriteNextLocked() {
    if (finished_ || writing_) return;
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
  std::shared_ptr<LiveSession> live_;
  std::mutex mu_;
  std::deque<v1::SessionEvent> queue_;  // guarded by mu_; the front is being written
  bool writing_ = false;                // guarded by mu_
  bool closing_ = false;                // guarded by mu_
  bool finished_ = false;               // guarded by mu_
};

// A stream that fails before it starts.
class FailedWriter final : public grpc::ServerWriteReactor<v1::SessionEvent> {
 public:
  explicit FailedWriter(const grpc::Status& status) { Finish(status); }
  void OnDone() override { delete this; }
};

}  // namespace

grpc::ServerBidiReactor<v1::SampleBatch, v1::SampleAck>* SessionServiceImpl::StreamSamples(
    grpc::CallbackServerContext* /*context*/) {
  return new IngestReactor(store_, &hub_);
}

grpc::ServerWriteReactor<v1::SessionEvent>* SessionServiceImpl::WatchSession(
    grpc::CallbackServerContext* /*context*/, const v1::WatchSessionRequest* request) {
  if (request->session_id().empty())
    return new FailedWriter(grpc::Status(grpc::StatusCode::INVALID_ARGUMENT,
                                         "session_id: required"));
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
  auto* reactor = new WatchReactor(&hub_, *live, *std::move(snapshot), guide, next);
  reactor->Attach();
  return reactor;
}

}  // namespace imucal::server
