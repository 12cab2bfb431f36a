// Every long-lived call (StreamSamples, WatchSession) is registered here from the moment it
// opens until it ends, so that the server can bound what callers that do not stream cost it:
//   - at most `max_streams` on the server and `max_per_caller` per caller (a token, or a
//     robot's client certificate), counted from the moment a stream opens, not from its first
//     batch; one beyond either is refused RESOURCE_EXHAUSTED at once;
//   - the server's places are shared fairly: when it is full, a new stream from a caller with
//     fewer streams than the caller with the most takes the place of one of that caller's
//     silent streams (added `silent`: a StreamSamples that has not sent its first batch, see
//     Heard), which is told to end (Stream::Revoke, RESOURCE_EXHAUSTED). Silent streams from
//     some callers, however many, cannot lock out a robot with a token of its own;
//   - a revoked token's streams end at once (Authorizer::RevokeToken calls RevokeToken here),
//     and a stream that was authorised just before the revocation is refused when it registers;
//   - each stream keeps a deadline of its own (its first batch, the next batch after an ack, a
//     write that does not go out because its client stopped reading), which a sweeper thread
//     checks every `tick`; a stream past it is told to end (Stream::Expire).
// A stream that opened before a cap was reached is never ended for the cap, except a silent
// one, for the fair share above.
//
// Memory: a flood of streams leaves glibc's arenas holding what the streams used (hundreds of
// MB after 30,000 streams) though it is free; after `trim_after_ends` streams have ended the
// sweeper gives it back to the system (malloc_trim), at most once per `trim_interval`.
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
#include <set>
#include <string>
#include <thread>
#include <unordered_map>
#include <unordered_set>
#include <utility>

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
    int trim_after_ends = 1000;              // 0: never trim
    absl::Duration trim_interval = absl::Seconds(10);
  };

  explicit StreamRegistry(Options options);
  ~StreamRegistry();  // stops the sweeper; every stream must have been removed
  StreamRegistry(const StreamRegistry&) = delete;
  StreamRegistry& operator=(const StreamRegistry&) = delete;

  // Registers `stream` for `caller` ("token:7", "cert:robot-3"; empty: counted for the server
  // only, e.g. in insecure mode) made with token `token_id` (0: none). RESOURCE_EXHAUSTED past
  // a cap, naming it; UNAUTHENTICATED when the token has been revoked. `silent`: the stream
  // may give its place to a caller with fewer streams until Heard (a StreamSamples before its
  // first batch).
  absl::Status Add(const std::shared_ptr<Stream>& stream, const std::string& caller,
                   int64_t token_id, bool silent = false);
  // The stream has been heard from (its first batch came): it keeps its place from now on.
  void Heard(const Stream* stream);
  // Unregisters (a no-op for a stream that is not registered).
  void Remove(const Stream* stream);
  // Ends every stream made with the token (Stream::Revoke) and refuses it from now on.
  void RevokeToken(int64_t token_id, const grpc::Status& status);

  size_t size();
  int64_t trims();  // how many times the sweeper has given memory back

 private:
  struct Entry {
    std::weak_ptr<Stream> stream;
    std::string caller;
    int64_t token_id = 0;
    bool giving_way = false;  // told to end for another caller's stream; no longer counted
  };
  struct Caller {
    int held = 0;                              // streams registered
    std::unordered_set<const Stream*> silent;  // those that may give their place
  };
  // Frees a place for `caller`, who holds `held` streams: marks giving way a silent stream of
  // the caller with the most streams, if that is more than `held`, and sets `gives_way` to it
  // (to be told, without the lock). False when no place could be freed.
  bool TakePlaceLocked(const std::string& caller, int held, std::shared_ptr<Stream>* gives_way);
  // Keeps by_held_ in step with a caller whose `held` or `silent` changed (`held_before`,
  // `had_silent`: what they were).
  void ReindexLocked(const std::string& caller, const Caller& now, int held_before,
                     bool had_silent);
  void Sweep();

  const Options options_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::unordered_map<const Stream*, Entry> streams_;  // guarded by mu_
  size_t giving_way_ = 0;                             // guarded by mu_: entries giving way
  std::unordered_map<std::string, Caller> per_caller_;  // guarded by mu_; callers with streams
  // Callers with a silent stream by how many streams they hold (the most last); guarded by mu_.
  std::set<std::pair<int, std::string>> by_held_;
  std::unordered_set<int64_t> revoked_;  // guarded by mu_
  bool stopping_ = false;                // guarded by mu_
  int64_t ended_since_trim_ = 0;         // guarded by mu_
  int64_t trims_ = 0;                    // guarded by mu_
  std::thread sweeper_;
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_STREAM_REGISTRY_H_
