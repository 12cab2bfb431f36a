// The in-memory side of sessions: per-session live state (last sample time, counts, the online
// segmenter) and the fan-out of SessionEvents to WatchSession streams.
//
// Fan-out never blocks ingest: Publish hands each watcher the event under a short lock and the
// watcher queues it (coalescing stillness updates, dropping the oldest when it falls far
// behind); the watcher's own gRPC writes drain its queue.
//
// Live state is rebuilt from storage the first time a session is touched after a restart (its
// stored batches are decoded and replayed through the segmenter and the pair tracker, without
// publishing; poses or verdicts missing from storage are stored then), so samples, poses, pair
// verdicts, the guidance and resume points survive a server restart. That load takes seconds
// for millions of samples: the service runs it off the RPC threads, and only for sessions that
// need their live state (open ones, and those being solved); closed ones are answered from
// storage.
#ifndef IMUCAL_SERVER_SESSION_HUB_H_
#define IMUCAL_SERVER_SESSION_HUB_H_

#include <cstdint>
#include <atomic>
#include <deque>
#include <future>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "core/online_segmenter.h"
#include "formats/sample_digest.h"
#include "imucal/v1/imucal.pb.h"
#include "server/convert.h"
#include "server/pair_tracker.h"
#include "storage/sample_codec.h"
#include "storage/store.h"

namespace imucal::server {

// A WatchSession stream as the hub sees it. Both calls must return quickly.
class Watcher {
 public:
  virtual ~Watcher() = default;
  virtual void Push(const v1::SessionEvent& event) = 0;
  virtual void Close() = 0;  // no more events: end the stream after the queued ones
};

struct LiveSession {
  // Guards everything below but the watchers. Held across one batch's ingest (validate,
  // store, segment) so that two streams of one session serialise.
  std::mutex mu;
  std::string id;
  storage::Device device;
  v1::Protocol protocol = v1::PROTOCOL_UNSPECIFIED;
  double gravity_m_s2 = core::kStandardGravity;
  int64_t last_acked_seq = 0;
  int64_t samples = 0;  // stored in the session (IngestLimits::max_session_samples bounds it)
  double last_t_s = std::numeric_limits<double>::quiet_NaN();  // NaN: no sample yet
  std::unique_ptr<core::OnlineSegmenter> segmenter;
  std::unique_ptr<PairTracker> pairs;  // six-face pair verdicts while streaming
  // The SHA-256 of the stored samples so far (formats/sample_digest.h), and the name of the
  // capture they came from.
  formats::SampleDigest digest;
  std::string source;
  // The digest after each of the last kProofHistory batches, oldest first: a stream that starts
  // at batch n proves the samples of batches 1..n-1, and n - 1 may be behind the last stored
  // batch (batches in flight on a stream the robot dropped land after it read GetSession).
  struct Proof {
    int64_t seq = 0;      // the batch after which...
    int64_t samples = 0;  // ...the session held this many samples...
    std::string sha256;   // ...whose digest was this
  };
  static constexpr size_t kProofHistory = 64;  // far more than a client keeps in flight (8)
  std::deque<Proof> proofs;

  // What watchers here were last told of the session's state by a refresh after another
  // server's change (SessionServiceImpl::Refresh; 0: nothing yet).
  int refreshed_state = 0;
  // A refresh is queued and has not begun: more notifications need no other.
  std::atomic<bool> refresh_pending{false};

  std::mutex watchers_mu;
  std::vector<Watcher*> watchers;  // guarded by watchers_mu
  bool closed = false;             // guarded by watchers_mu: watchers added now end at once
};

// What samples caused, in order: the segmenter's events and the six-face pair verdicts (each
// right after the pose that completed its pair).
struct LiveEvent {
  enum class Kind { kSegmenter, kPair };
  Kind kind = Kind::kSegmenter;
  core::SegmenterEvent segmenter;
  core::PairCheck pair;
  // After a pose: the progress as it stood then (with its pair verdicts), not at the end of the
  // batch, whose later poses must not make the protocol look complete early.
  v1::SessionEvent progress;
};

// Feeds `samples` through the session's segmenter and pair tracker (the caller holds `mu`).
// When the pair that completed a face fails its check, the segmenter wants that face's turned
// placement again (OnlineSegmenter::RedoTurn) and the next-pose guidance says why.
void Segment(LiveSession& session, const std::vector<storage::ImuSample>& samples,
             std::vector<LiveEvent>* events);
// Ends the current still run (the session is closing for a solve): its pose, if any.
void FlushSegment(LiveSession& session, std::vector<LiveEvent>* events);
// Notes the session's digest, just updated with batch `seq`, after which it holds `samples`
// samples, in `proofs` (the caller holds `mu`).
void RecordProof(LiveSession& session, int64_t seq, int64_t samples);
// The digest after batch `seq`, if it is among the last kProofHistory; null otherwise.
const LiveSession::Proof* ProofAfter(const LiveSession& session, int64_t seq);

// The poses and pair verdicts among `events`, as storage rows.
void ToRows(const std::vector<LiveEvent>& events, std::vector<storage::Pose>* poses,
            std::vector<storage::PosePair>* pairs);

// An event stamped now (SessionEvent.time), for the caller to say what happened.
v1::SessionEvent Stamped();

class SessionHub {
 public:
  explicit SessionHub(storage::Store* store) : store_(store) {}
  // Takes each live session's locks once before freeing it: a batch still being segmented or
  // published (on the store's committer thread) finishes first. The server has drained its calls by
  // then; the lock also shows that order to ThreadSanitizer, which cannot see it through gRPC.
  ~SessionHub();

  // The session's live state, loading it from storage on first use (slow: not on an RPC
  // thread). Concurrent loads of one session share one. A session that is neither open nor
  // being solved is returned but not kept (Reopen keeps it for a re-solve).
  absl::StatusOr<std::shared_ptr<LiveSession>> Get(std::string_view session_id);
  // The session's live state if it is in memory, else null; never loads.
  std::shared_ptr<LiveSession> Find(std::string_view session_id);
  // The online segmenter's accepted poses if the session is live in memory, else -1.
  int PeekPosesAccepted(std::string_view session_id);
  // Sessions whose live state is in memory: the open ones touched since the start, and those
  // being solved. Closed sessions are forgotten when they close and are never loaded to be read.
  size_t LiveSessions();
  // Live sessions with at least one watcher.
  std::vector<std::shared_ptr<LiveSession>> WatchedSessions();
  static bool Watched(LiveSession& session);

  // Brings `live` (its mu held) up to the batches stored since it was last fed: another server
  // sharing the database took the session's stream meanwhile (its robot was sent there) and
  // stored them. Returns their events (the same as that server's), to publish once mu is
  // released. Nothing to do, and no events, when this server stored every batch.
  absl::StatusOr<std::vector<v1::SessionEvent>> CatchUpLocked(LiveSession& live);

  void Publish(LiveSession& session, const v1::SessionEvent& event);
  void AddWatcher(LiveSession& session, Watcher* watcher);
  void RemoveWatcher(LiveSession& session, Watcher* watcher);
  // Ends every watcher's stream (the session closed) and forgets the live state.
  void CloseSession(LiveSession& session);
  // A closed (solved or failed) session is being solved again: it is kept in memory until it
  // closes again, and watchers may follow it.
  void Reopen(const std::shared_ptr<LiveSession>& session);

  // Converts live events to SessionEvents (each pose followed by its Progress).
  static std::vector<v1::SessionEvent> ToEvents(const std::vector<LiveEvent>& events);
  static v1::PairVerdict ToProto(const core::PairCheck& pair);
  static v1::SessionEvent ProgressEvent(const LiveSession& session);
  static v1::SessionEvent NextPoseEvent(const core::NextPoseUpdate& next);

 private:
  absl::StatusOr<std::shared_ptr<LiveSession>> Load(std::string_view session_id);
  // Feeds stored batches to `live`: segmentation, digest, counts, proofs.
  static absl::Status Replay(LiveSession& live, const std::vector<storage::SampleBatch>& batches,
                             std::vector<LiveEvent>* events);

  using Loaded = absl::StatusOr<std::shared_ptr<LiveSession>>;

  storage::Store* store_;
  std::mutex mu_;
  std::map<std::string, std::shared_ptr<LiveSession>, std::less<>> sessions_;  // guarded by mu_
  std::map<std::string, std::shared_future<Loaded>, std::less<>> loading_;     // guarded by mu_
};

core::OnlineSegmenterOptions SegmenterOptionsFor(const storage::Device& device,
                                                 v1::Protocol protocol);

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_SESSION_HUB_H_
