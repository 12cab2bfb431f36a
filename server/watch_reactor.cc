// WatchSession, a session's events as they happen: the stream reactor that writes them
// (server/stream_reactor.h has the life it shares with the others).
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "server/convert.h"
#include "server/session_streams.h"
#include "server/status_util.h"
#include "server/stream_reactor.h"

namespace imucal::server {
namespace {

// WatchSession: a snapshot, then the session's events as they are published. The hub pushes
// into a bounded queue that this reactor drains with one write at a time; a slow watcher gets
// its stillness updates coalesced and, when far behind, loses the oldest events, but never
// slows ingest. A watcher whose write has not gone out for watch_stall_timeout (its client
// stopped reading) is cancelled, its slot freed. A closed session that is not in memory gets
// its snapshot from storage and the end of the stream, without being loaded; an open one not
// in memory is loaded off the RPC threads first.
class WatchReactor final : public SessionWriter<WatchReactor, v1::SessionEvent>, public Watcher {
 public:
  static constexpr size_t kMaxQueued = 256;

  WatchReactor(const StreamEnv& env, grpc::CallbackServerContext* context, PrincipalRef who,
               std::string session_id)
      : SessionWriter(env, context, std::move(who), std::move(session_id),
                      env.options->watch_stall_timeout, "watcher") {}

  void Start() override {
    if (!Registered()) return;
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

 private:
  const v1::SessionEvent* NextLocked() override {
    return queue_.empty() ? nullptr : &queue_.front();
  }
  bool MoreToComeLocked() override { return !closing_; }
  void WrittenLocked() override { queue_.pop_front(); }

  // The slot is free as soon as the watcher is known gone, not when the last write drains: a
  // watcher that cancels may be followed by another at once.
  void CancelledLocked() override { ReleaseSlotLocked(); }

  // What is queued is not sent; a write in flight completes first.
  void RevokedLocked() override {
    while (queue_.size() > (writing_ ? 1u : 0u)) queue_.pop_back();
  }

  void FinishingLocked() override { ReleaseSlotLocked(); }

  void Released() override {
    std::shared_ptr<LiveSession> live;
    {
      std::lock_guard lock(mu_);
      ReleaseSlotLocked();
      live = live_;
    }
    if (live != nullptr) env_.hub->RemoveWatcher(*live, this);
  }

  static v1::SessionEvent SnapshotEvent(v1::Session snapshot) {
    v1::SessionEvent e = Stamped();
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

  void ReleaseSlotLocked() {
    if (!slot_held_) return;
    slot_held_ = false;
    env_.watcher_slots->Release(session_id_);
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

  std::shared_ptr<LiveSession> live_;   // guarded by mu_; null until Begin
  std::deque<v1::SessionEvent> queue_;  // guarded by mu_; the front is being written
  bool closing_ = false;                // guarded by mu_
  bool slot_held_ = false;              // guarded by mu_
};

}  // namespace

grpc::ServerWriteReactor<v1::SessionEvent>* StartWatchSession(
    const StreamEnv& env, grpc::CallbackServerContext* context,
    const v1::WatchSessionRequest& request) {
  return WatchReactor::Open(env, context, Rpc::kWatchSession, request.session_id());
}

}  // namespace imucal::server
