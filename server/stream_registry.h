// Every long-lived call (StreamSamples, WatchSession) is registered here from the moment it
// opens until it ends, so that the server can bound what callers that do not stream cost it:
//   - at most `max_streams` on the server and `max_per_caller` per caller (a token, or a
//     robot's client certificate), counted from the moment a stream opens, not from its first
//     batch; one beyond either is refused RESOURCE_EXHAUSTED at once;
//   - a revoked token's streams end at once (Authorizer::RevokeToken calls RevokeToken here),
//     and a stream that was authorised just before the revocation is refused when it registers;
//   - each stream keeps a deadline of its own (its first batch, the next batch after an ack, a
//     write that does not go out because its client stopped reading), which a sweeper thread
//     checks every `tick`; a stream past it is told to end (Stream::Expire).
// A stream that opened before a cap was reached is never ended for the cap.
//
// Threads: Add, Remove and RevokeToken from any thread; Revoke and Expire are called without
// the registry's lock held, on a strong reference taken under it, so a stream may end (and
// Remove itself) meanwhile: it must then ignore the call.
#ifndef IMUCAL_SERVER_STREAM_REGISTRY_H_
#define IMUCAL_SERVER_STREAM_REGISTRY_H_

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <unordered_map>
#include <unordered_set>

#include "absl/status/status.h"
#include "absl/time/time.h"
#include "grpcpp/support/status.h"

namespace imucal::server {

class StreamRegistry {
 public:
  // What a registered call implements.
  class Stream {
   public:
    virtual ~Stream() = default;
    // The caller's token was revoked: end with `status` as soon as the call allows (at once
    // while it waits for its client). Must return quickly.
    virtual void Revoke(const grpc::Status& status) = 0;
    // deadline() had passed at `now` when the sweeper looked; the stream checks again under its
    // own lock (it may have moved on since) and ends. Must return quickly.
    virtual void Expire(absl::Time now) = 0;

    // The time by which the stream must have moved on; InfiniteFuture: none (the server is the
    // one working: storing a batch, loading the session).
    void SetDeadline(absl::Time deadline) {
      deadline_us_.store(deadline == absl::InfiniteFuture() ? kNever : absl::ToUnixMicros(deadline),
                         std::memory_order_relaxed);
    }
    bool PastDeadline(absl::Time now) const {
      return deadline_us_.load(std::memory_order_relaxed) <= absl::ToUnixMicros(now);
    }

   private:
    static constexpr int64_t kNever = INT64_MAX;
    std::atomic<int64_t> deadline_us_{kNever};
  };

  struct Options {
    int max_streams = 10000;
    int max_per_caller = 16;
    absl::Duration tick = absl::Seconds(1);  // how often deadlines are checked
  };

  explicit StreamRegistry(Options options);
  ~StreamRegistry();  // stops the sweeper; every stream must have been removed
  StreamRegistry(const StreamRegistry&) = delete;
  StreamRegistry& operator=(const StreamRegistry&) = delete;

  // Registers `stream` for `caller` ("token:7", "cert:robot-3"; empty: counted for the server
  // only, e.g. in insecure mode) made with token `token_id` (0: none). RESOURCE_EXHAUSTED past
  // a cap, naming it; UNAUTHENTICATED when the token has been revoked.
  absl::Status Add(const std::shared_ptr<Stream>& stream, const std::string& caller,
                   int64_t token_id);
  // Unregisters (a no-op for a stream that is not registered).
  void Remove(const Stream* stream);
  // Ends every stream made with the token (Stream::Revoke) and refuses it from now on.
  void RevokeToken(int64_t token_id, const grpc::Status& status);

  size_t size();

 private:
  struct Entry {
    std::weak_ptr<Stream> stream;
    std::string caller;
    int64_t token_id = 0;
  };
  void Sweep();

  const Options options_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::unordered_map<const Stream*, Entry> streams_;  // guarded by mu_
  std::unordered_map<std::string, int> per_caller_;   // guarded by mu_; callers with streams
  std::unordered_set<int64_t> revoked_;               // guarded by mu_
  bool stopping_ = false;                             // guarded by mu_
  std::thread sweeper_;
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_STREAM_REGISTRY_H_
