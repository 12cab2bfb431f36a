// The streaming RPCs of SessionService as callback reactors (no thread per stream), on one base
// that owns the life they share: StreamSamples (ingest_reactor.cc), WatchSession
// (watch_reactor.cc) and ReadSamples (read_reactor.cc); session_streams.h starts them.
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
#ifndef IMUCAL_SERVER_STREAM_REACTOR_H_
#define IMUCAL_SERVER_STREAM_REACTOR_H_

#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/auth.h"
#include "server/metrics.h"
#include "server/session_hub.h"
#include "server/session_options.h"
#include "server/status_util.h"
#include "server/stream_claims.h"
#include "server/stream_registry.h"
#include "server/stream_slots.h"
#include "storage/store.h"

namespace imucal::server {

// What the stream reactors use of the service.
struct StreamEnv {
  storage::Store* store = nullptr;
  SessionHub* hub = nullptr;
  const SessionServiceOptions* options = nullptr;
  Authorizer* auth = nullptr;
  StreamRegistry* registry = nullptr;
  StreamSlots* device_slots = nullptr;     // StreamSamples per device
  StreamClaims* device_claims = nullptr;   // StreamSamples per device across servers
  StreamSlots* watcher_slots = nullptr;    // WatchSession per session
  StreamSlots* session_streams = nullptr;  // StreamSamples per session (OpenStreams)
  // Runs `work` on the session loaders, off the RPC threads; false when their queue is full.
  std::function<bool(std::function<void()> work)> defer;
  // The session as GetSession answers it, without loading it (SessionServiceImpl).
  std::function<absl::StatusOr<v1::Session>(const std::string& session_id)> session_proto;
  Metrics* metrics = nullptr;  // null: none kept
};

// The registry's key for who made the call: a token, or a robot's client certificate; "" in
// insecure mode (no caller to count).
std::string CallerKey(const Principal& who);

// What a streaming call holds whatever its messages: the service, the call's context and
// caller, the reactor's lock and whether Finish was called, and the guard of the context.
class StreamCall : public StreamRegistry::Stream {
 protected:
  StreamCall(const StreamEnv& env, grpc::CallbackServerContext* context, PrincipalRef who)
      : env_(env), context_(context), who_(std::move(who)) {}

  // Registers the call, `self`, with the registry for its caller (StreamRegistry::Add).
  absl::Status Register(const std::shared_ptr<StreamRegistry::Stream>& self, bool silent);
  // OnDone's first step: the context is going, and the call leaves the registry (a no-op for a
  // call that never entered it).
  void MarkDone();
  // Cancels the call unless OnDone has begun. Called without mu_ (OnCancel may run inline).
  void CancelCall();

  const StreamEnv& env_;
  grpc::CallbackServerContext* const context_;  // the call's; valid until OnDone
  const PrincipalRef who_;

  std::mutex mu_;
  bool finished_ = false;  // guarded by mu_: Finish was called

 private:
  std::mutex ctx_mu_;
  bool done_ = false;  // guarded by ctx_mu_: OnDone has begun, context_ is going
};

// The life of a streaming reactor: made and owned by Create until OnDone, registered by Start,
// finished once. `Derived` (final) is the reactor; `GrpcReactor` its gRPC reactor type
// (grpc::ServerBidiReactor<...>, grpc::ServerWriteReactor<...>).
template <typename Derived, typename GrpcReactor>
class StreamReactor : public GrpcReactor,
                      public StreamCall,
                      public std::enable_shared_from_this<Derived> {
 public:
  // The reactor of a call, started (Start) and owned by itself until OnDone; the handler
  // returns it.
  template <typename... Args>
  static GrpcReactor* Create(Args&&... args) {
    auto reactor = std::make_shared<Derived>(std::forward<Args>(args)...);
    StreamReactor* raw = reactor.get();
    raw->self_ = std::move(reactor);
    raw->Start();
    return static_cast<Derived*>(raw);
  }

  void OnDone() final {
    MarkDone();
    Released();
    std::shared_ptr<Derived> last = std::move(self_);  // may delete this on return
  }

 protected:
  using StreamCall::StreamCall;

  // Called once, by Create: Registered(), then the call's first step.
  virtual void Start() = 0;
  // OnDone's own step, once the call has left the registry.
  virtual void Released() {}
  // FinishLocked's own step, before Finish: what the call holds goes now, not when gRPC lets
  // go of the reactor.
  virtual void FinishingLocked() {}

  // Registers the call with the registry; refused (a cap, a revoked token), it ends at once
  // and this returns false. `silent`: see StreamRegistry::Add.
  bool Registered(bool silent = false) {
    absl::Status added = Register(this->shared_from_this(), silent);
    if (added.ok()) return true;
    End(ToGrpcStatus(added));
    return false;
  }

  void End(const grpc::Status& status) {
    std::lock_guard lock(mu_);
    FinishLocked(status);
  }

  void FinishLocked(const grpc::Status& status) {
    if (finished_) return;
    finished_ = true;
    SetDeadline(absl::InfiniteFuture());
    FinishingLocked();
    this->Finish(status);
  }

 private:
  std::shared_ptr<Derived> self_;  // from Create to OnDone
};

// A call refused before it starts (its caller may not make it, or named nothing).
template <typename GrpcReactor>
class FailedCall final : public GrpcReactor {
 public:
  explicit FailedCall(const grpc::Status& status) { this->Finish(status); }
  void OnDone() override { delete this; }
};

// A server-streaming reactor of one session (WatchSession, ReadSamples): one message in
// flight; a write that has not gone out within `write_timeout` (its client stopped reading)
// cancels the call. A cancelled or revoked call ends at once, or when its write in flight
// completes: that write may still succeed after OnCancel (its bytes were already with the
// transport), and the call would otherwise wait for a message that never comes.
template <typename Derived, typename Message>
class SessionWriter : public StreamReactor<Derived, grpc::ServerWriteReactor<Message>> {
  using Base = StreamReactor<Derived, grpc::ServerWriteReactor<Message>>;

 public:
  // The handler's reactor: refused at once when the caller may not make `rpc` or names no
  // session.
  static grpc::ServerWriteReactor<Message>* Open(const StreamEnv& env,
                                                 grpc::CallbackServerContext* context, Rpc rpc,
                                                 const std::string& session_id) {
    using Failed = FailedCall<grpc::ServerWriteReactor<Message>>;
    absl::StatusOr<PrincipalRef> who = env.auth->Authorize(*context, rpc);
    if (!who.ok()) return new Failed(ToGrpcStatus(who.status()));
    if (session_id.empty())
      return new Failed(grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "session_id: required"));
    return Base::Create(env, context, *std::move(who), session_id);
  }

  void OnWriteDone(bool ok) override {
    std::lock_guard lock(this->mu_);
    writing_ = false;
    this->SetDeadline(absl::InfiniteFuture());
    WrittenLocked();
    if (!ok) {
      this->FinishLocked(
          grpc::Status(grpc::StatusCode::CANCELLED, absl::StrCat("the ", reader_, " went away")));
      return;
    }
    WriteNextLocked();
  }

  void OnCancel() override {
    std::lock_guard lock(this->mu_);
    cancelled_ = true;
    CancelledLocked();
    WriteNextLocked();
  }

  void Revoke(const grpc::Status& status) override {
    std::lock_guard lock(this->mu_);
    if (this->finished_) return;
    revoked_ = status;
    RevokedLocked();
    WriteNextLocked();  // at once, or when the write in flight completes
  }

  void Expire(absl::Time now) override {
    {
      std::lock_guard lock(this->mu_);
      if (this->finished_ || !writing_ || !this->PastDeadline(now)) return;
    }
    this->CancelCall();  // the write then fails
  }

 protected:
  // `reader` names the client in the status of a failed write ("the watcher went away").
  SessionWriter(const StreamEnv& env, grpc::CallbackServerContext* context, PrincipalRef who,
                std::string session_id, absl::Duration write_timeout, const char* reader)
      : Base(env, context, std::move(who)),
        session_id_(std::move(session_id)),
        write_timeout_(write_timeout),
        reader_(reader) {}

  // The next message to write (valid until its write completes); null: none now.
  virtual const Message* NextLocked() = 0;
  // With no next message: whether the call waits for more (true) or ends OK (false).
  virtual bool MoreToComeLocked() { return false; }
  // Hooks, under mu_: the write in flight completed; OnCancel; Revoke.
  virtual void WrittenLocked() {}
  virtual void CancelledLocked() {}
  virtual void RevokedLocked() {}

  // Writes the next message, or ends the call: cancelled, revoked, or nothing more to come.
  void WriteNextLocked() {
    if (this->finished_ || writing_) return;
    if (cancelled_) {
      this->FinishLocked(grpc::Status(grpc::StatusCode::CANCELLED, "cancelled"));
      return;
    }
    if (revoked_) {
      this->FinishLocked(*revoked_);
      return;
    }
    const Message* next = NextLocked();
    if (next == nullptr) {
      // A no-op when an error has finished the call.
      if (!MoreToComeLocked()) this->FinishLocked(grpc::Status::OK);
      return;
    }
    writing_ = true;
    this->SetDeadline(absl::Now() + write_timeout_);
    this->StartWrite(next);
  }

  const std::string session_id_;
  bool writing_ = false;                 // guarded by mu_
  bool cancelled_ = false;               // guarded by mu_
  std::optional<grpc::Status> revoked_;  // guarded by mu_

 private:
  const absl::Duration write_timeout_;
  const char* const reader_;
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_STREAM_REACTOR_H_
