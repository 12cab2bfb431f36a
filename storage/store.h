// imucal's durable state: devices, sessions and their raw sample batches, poses, solves,
// parameter versions and the audit log, in one SQLite file (schema: migrations.cc), or in a
// PostgreSQL database that several servers share.
//
// Backends (db.h): Store::Open takes a file path (SQLite, the embedded default) or a
// postgresql:// URL. Both run the same SQL with the same semantics: durable acks, one open
// session per device, one active version per device, immutable versions numbered in storage,
// audit in the same transaction. What differs is said below as "SQLite:" and "PostgreSQL:".
//
// Durability: the file is in WAL mode with synchronous=FULL by default. A commit appends its
// pages to the -wal file and, under FULL, fsyncs it before COMMIT returns; only then is a batch
// acknowledged, so an acknowledged batch survives the server being killed (SIGKILL, crash, OOM
// kill) and also an OS crash or power cut: what the API promises ("acknowledged only after it
// is committed to disk"). synchronous=NORMAL would skip that fsync (it syncs only at
// checkpoints): still safe against a killed process, since the data is in the OS page cache,
// and never corrupt, but an OS crash or power cut could roll back the last acknowledged
// commits. The group commit (AppendBatchAsync: every stream's batches that arrive during a
// commit share the next one) pays one fsync per group, not per batch: FULL adds about one
// fsync to each ack's latency, not a limit on throughput (README "Durability and load" has the
// figures). Durability::kNormal remains for stores whose last commits a power cut may take
// (benchmarks of the CPU path, scratch files).
// PostgreSQL: a commit returns once PostgreSQL has flushed it to its write-ahead log
// (synchronous_commit = on), whatever Durability says.
//
// Threads: a Store is safe to share. Writes go through one connection, serialised by a mutex,
// each call in one BEGIN IMMEDIATE transaction (which also serialises writers in other
// processes on the same file); AppendBatchAsync's groups are written by a committer thread.
// Once AppendBatchAsync is used, WAL checkpoints no longer run inside commits (SQLite's automatic
// checkpoint is off for the writer): a checkpoint thread runs PASSIVE checkpoints on a
// connection of its own when the WAL has grown by kCheckpointPages pages, or every second, so no
// stream's ack waits for one. Reads use a small pool of read-only connections: WAL lets them
// run concurrently with each other and with the writer, each seeing the latest committed state
// when its statement starts, so GetActive never waits behind an ingest commit.
// PostgreSQL: the same writer connection and read pool, but write transactions are SERIALIZABLE
// and those of other servers run side by side; one that conflicts with another is run again
// (InTransaction, store_internal.h). The version number is still assigned inside the
// transaction that inserts it, so two servers never hand out the same one.
//
// Errors: NotFound for a missing device/session/version; InvalidArgument for malformed input;
// FailedPrecondition for a call the current state does not allow (the message says why and
// what would); AlreadyExists for a duplicate id; Unavailable when the file is locked or cannot
// be used; DataLoss for a corrupt file. Messages may contain ids and the file path, never SQL;
// the server caps them at its boundary.
//
// Audit: every mutating call writes its audit entry in the same transaction, except AppendBatch:
// a batch is data, not an action, and is its own record; a row per batch (10,000 a second at
// full ingest) would bury the actions the log is for.
#ifndef IMUCAL_STORAGE_STORE_H_
#define IMUCAL_STORAGE_STORE_H_

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "storage/types.h"
#include "util/db.h"

namespace imucal::sql {
class SqliteConnection;  // util/sqlite_db.h: SQLite stays out of this header
}  // namespace imucal::sql

namespace imucal::storage {

class PgListener;        // pg_db.h

// PRAGMA synchronous in WAL mode: see the header comment.
enum class Durability { kNormal, kFull };

struct StoreOptions {
  Durability durability = Durability::kFull;  // see the header comment
  int read_connections = 4;                   // the read pool; at least 1
  absl::Duration busy_timeout = absl::Seconds(5);
  std::function<absl::Time()> clock{};  // for tests; absl::Now when empty
  // Called after every commit that changes a device's active version (an activating AddVersion
  // or FinishSolve, Promote, Rollback), with the device id, on the committing thread; must be
  // quick and must not call back into the store. For caches of the active version.
  std::function<void(std::string_view device_id)> on_active_change{};
  // Called after every write transaction (committed or not) with its operation ("AppendBatch",
  // "FinishSolve", ...) and how long it took from BEGIN, the wait for the write lock included;
  // on the writing thread; must be quick and must not call back into the store. For metrics.
  std::function<void(std::string_view op, absl::Duration took)> on_transaction{};
};

// Paging is by key: pass the last item of a page to get the next one. Every member has a
// default initializer so that designated initializers ({.limit = 100}) compile warning-free.
struct SessionQuery {
  std::string device_id{};              // empty = every device
  std::optional<SessionState> state{};  // empty = any state
  std::string after_id{};  // sessions created after this one (InvalidArgument if unknown)
  int limit = 0;           // 0 = no limit
};

struct VersionQuery {
  int after_version = 0;
  int limit = 0;                // 0 = no limit
  bool with_documents = false;  // load params_json and report_json (kilobytes each)
};

struct AuditQuery {
  std::string target{};  // exact target, e.g. DeviceTarget("robot-7"); empty = every target
  int64_t after_id = 0;  // paging: entries with id > after_id
  int limit = 1000;
};

class Store {
 public:
  // Opens `path` (a file: ":memory:" cannot be shared by the pool), creating it if needed,
  // switches it to WAL and applies pending migrations. A postgresql:// URL opens that
  // database instead (it must exist; the tables are created by the migrations).
  static absl::StatusOr<std::unique_ptr<Store>> Open(const std::string& path,
                                                     StoreOptions options = {});
  ~Store();
  sql::Dialect dialect() const;  // which backend
  // A trivial query on a reader: OK when the database answers (a PostgreSQL connection that
  // broke is opened again first), else its status (Unavailable when it cannot be reached).
  absl::Status Ping();
  Store(const Store&) = delete;
  Store& operator=(const Store&) = delete;

  // ---- Devices. CreateDevice registers a device and returns it as stored (created_at and
  // active_version of the argument are ignored). Robots register at every boot, so the same
  // metadata again returns the existing device (no-op, not audited); different metadata under
  // a taken id is AlreadyExists naming the field.
  absl::StatusOr<Device> CreateDevice(const Device& device, std::string_view actor);
  absl::StatusOr<Device> GetDevice(std::string_view id);
  // By id, those after `after_id`; limit 0 = all.
  absl::StatusOr<std::vector<Device>> ListDevices(std::string_view after_id = "", int limit = 0);

  // ---- Sessions. CreateSession uses `id`, `device_id`, `protocol` and `gravity_m_s2` (an
  // empty id gets a generated one, "s-" and 32 hex digits) and returns the open session.
  // FailedPrecondition naming the open session if the device already has one.
  absl::StatusOr<Session> CreateSession(const Session& session, std::string_view actor);
  absl::StatusOr<Session> GetSession(std::string_view id);
  // Oldest first. NotFound if query.device_id names no device.
  absl::StatusOr<std::vector<Session>> ListSessions(const SessionQuery& query = {});
  // Moves a session along the transitions of types.h; FailedPrecondition for any other.
  absl::StatusOr<Session> SetSessionState(std::string_view id, SessionState state,
                                          std::string_view actor);
  // Names the capture an open session holds (Session::source) before its first batch is
  // stored; FailedPrecondition once it holds samples or is closed. Not audited: it comes with
  // the data, like a batch.
  absl::Status SetSessionSource(std::string_view id, std::string_view source);

  // ---- Raw samples. Stores batch `seq` (EncodeSamples() bytes) of an open session and
  // returns the acknowledgement. Batches are numbered 1, 2, 3, ...:
  //   seq == last + 1              committed (durable, see above), then acknowledged: seq
  //   seq <= last, same payload    a retransmission: no-op, acknowledges `last` again (even if
  //                                the session has closed since)
  //   seq <= last, other payload   InvalidArgument
  //   seq > last + 1               FailedPrecondition naming the expected seq (a robot resumes
  //                                from GetSession().last_acked_seq + 1)
  // InvalidArgument for a payload that does not decode, is empty, or does not start after the
  // previous batch's last sample (time increases across batches too); FailedPrecondition if
  // the session is not open.
  absl::StatusOr<BatchAck> AppendBatch(std::string_view session_id, int64_t seq,
                                       std::string_view payload);
  // Group commit: AppendBatch, asynchronously, with the same checks and answers. Batches
  // submitted while a commit runs are written together in the next transaction (one COMMIT, and
  // under kFull one WAL sync, for many streams). `done` runs once that transaction committed
  // (the batch is durable, as above) or failed, on the store's committer thread (or at once, on
  // the caller's, for a malformed batch); it must be quick and may call the store.
  void AppendBatchAsync(std::string session_id, int64_t seq, std::string payload,
                        std::function<void(absl::StatusOr<BatchAck>)> done);
  // The session's batches with seq > after_seq, in seq order.
  absl::StatusOr<std::vector<SampleBatch>> ReadBatches(std::string_view session_id,
                                                       int64_t after_seq = 0);
  // One page of ReadBatches, for reading a long session without holding it all: the batches
  // after `after_seq` in seq order, at most `max_batches` of them and, after the first (always
  // returned whole), only while the page's samples stay within `max_samples`. Empty after the
  // last batch. NotFound for an unknown session; InvalidArgument for after_seq < 0 or a max < 1.
  absl::StatusOr<std::vector<SampleBatch>> ReadBatchPage(std::string_view session_id,
                                                         int64_t after_seq, int64_t max_batches,
                                                         int64_t max_samples);

  // ---- Poses: replaces the session's pose list (indexes must be 0..n-1 in order).
  absl::Status PutPoses(std::string_view session_id, const std::vector<Pose>& poses,
                        std::string_view actor);
  absl::StatusOr<std::vector<Pose>> ListPoses(std::string_view session_id);
  // The online segmentation's poses and pair verdicts as they are judged: each pose is written
  // by (session, index), each pair by (session, pose_a, pose_b), replacing a row already there
  // (a replay after a restart rewrites the same rows). Not audited: data, like a batch.
  absl::Status SavePoses(std::string_view session_id, const std::vector<Pose>& poses,
                         const std::vector<PosePair>& pairs = {});
  absl::StatusOr<std::vector<PosePair>> ListPairs(std::string_view session_id);  // by pose_a

  // ---- Solves: the unit of work that turns a session's raw data into a parameter version.
  // StartSolve moves the session to `solving` (from open, solved or failed) and records a
  // running solve. FinishSolve adds the version (as AddVersion, its session and device taken
  // from the solve), marks the solve succeeded and the session solved, atomically. FailSolve
  // marks the solve failed with its error and report (the capture could not determine a
  // calibration; a poor calibration is a version with verdict fail, not a failed solve) and
  // moves the session to `next` (failed, or open to collect more poses).
  // Setting a solving session's state by hand (SetSessionState) fails its running solve.
  // `claim`: the server that runs it and its lease (types.h SolveClaim).
  // `seed`: the calibration's (Solve::seed), kept so that a server that runs it again after its
  // first server stopped gets the same result.
  absl::StatusOr<Solve> StartSolve(std::string_view session_id, std::string_view actor,
                                   const SolveClaim& claim = {}, uint64_t seed = 1);
  // Extends the lease of every running solve `owner` claimed to `until`; how many it extended.
  absl::StatusOr<int> RenewSolveLeases(std::string_view owner, absl::Time until);
  // Running solves nobody is running: those whose lease ended before `now` (their server stopped
  // renewing it), and those claimed by `restarted` when not empty (a server that has just
  // started asks for its previous life's: they cannot be running). Another live server's
  // solves are not listed.
  absl::StatusOr<std::vector<Solve>> ListOrphanedSolves(absl::Time now,
                                                        std::string_view restarted = "");
  // Takes over a running solve whose lease ended before `now` (its server stopped renewing it):
  // the oldest such, now claimed for `claim` with its attempts counted up, or nullopt when there
  // is none. Each goes to exactly one claimer, however many servers ask at once (PostgreSQL:
  // SELECT ... FOR UPDATE SKIP LOCKED; SQLite: the write lock). Audited as solve.claim. The
  // claimer runs the solve again from the session's stored samples, with its seed.
  absl::StatusOr<std::optional<Solve>> ClaimLapsedSolve(absl::Time now, const SolveClaim& claim);
  // Ends the leases of the running solves `owner` claimed, at once: a server that has just
  // started gives up its previous life's claims (that life cannot be running them), so that
  // they are claimed again without waiting for their leases. Audited as solve.release; how many.
  absl::StatusOr<int> ReleaseSolveClaims(std::string_view owner);
  // `owner`, when given, must still hold the solve's claim (FailedPrecondition naming the holder
  // otherwise): a server whose lease lapsed while it solved cannot end a solve another has
  // claimed since, so the version is written once.
  absl::StatusOr<ParamVersion> FinishSolve(int64_t solve_id, const ParamVersion& version,
                                           std::string_view actor,
                                           const RenderVersion& render = nullptr,
                                           std::string_view owner = {});
  absl::StatusOr<Solve> FailSolve(int64_t solve_id, std::string_view error,
                                  std::string_view report_json, std::string_view actor,
                                  SessionState next = SessionState::kFailed,
                                  std::string_view owner = {});
  absl::StatusOr<Solve> GetSolve(int64_t solve_id);
  absl::StatusOr<std::vector<Solve>> ListSolves(std::string_view session_id);  // oldest first
  // Every solve still running: after a restart these are orphans that the server re-runs or
  // fails (their sessions stay `solving` until then).
  absl::StatusOr<std::vector<Solve>> ListRunningSolves();

  // ---- Stream claims: one open sample stream per device across the servers sharing the
  // database (schema migration 7; types.h StreamClaim). A server takes the device's claim when
  // a stream of it opens, renews it every third of its lease while the stream is open, and
  // gives it up when the stream ends. A claim whose lease has lapsed (its server was killed, or
  // could not reach the database for longer than the lease) may be taken by another holder.
  // ClaimStream returns the claim as it stands afterwards: `holder`'s when it took it (or held
  // it already: the lease and session are updated), another's while that one's lease runs.
  absl::StatusOr<StreamClaim> ClaimStream(std::string_view device_id, std::string_view holder,
                                          std::string_view session_id, absl::Time until);
  // The device's claim while its lease runs (a server streams the device); nullopt when there
  // is none or it has lapsed.
  absl::StatusOr<std::optional<StreamClaim>> GetStreamClaim(std::string_view device_id);
  // Extends every claim `holder` holds to `until`; the devices whose claims it still holds.
  absl::StatusOr<std::vector<std::string>> RenewStreamClaims(std::string_view holder,
                                                             absl::Time until);
  // Gives up `holder`'s claim of the device (nothing when another holds it now).
  absl::Status ReleaseStreamClaim(std::string_view device_id, std::string_view holder);
  // Gives up every claim of holders named "<replica_id> ...": a server that has just started
  // gives up its previous life's (that life's streams cannot be open), so that its robots do
  // not wait for those leases. How many.
  absl::StatusOr<int> ReleaseStreamClaimsOfReplica(std::string_view replica_id);

  // ---- Parameter versions.
  // Adds the next version of `version.device_id` (1, 2, 3, ... assigned atomically). Uses
  // device_id, session_id (optional; must be that device's), params_json, report_json,
  // verdict, accel_rms, provenance and state: kCandidate, or kActive when it passed the quality
  // gates (it becomes active at once and the previous active version is superseded).
  // `render`, when given, writes the documents once the number is known (RenderVersion).
  // Audited as version.add, with `reason` (free text, as Promote's) when given.
  absl::StatusOr<ParamVersion> AddVersion(const ParamVersion& version, std::string_view actor,
                                          const RenderVersion& render = nullptr,
                                          std::string_view reason = "");
  // Candidate -> active; the previous active version becomes superseded. Promoting the active
  // version is a no-op; any other state is FailedPrecondition (use Rollback for older ones).
  absl::StatusOr<ParamVersion> Promote(std::string_view device_id, int version,
                                       std::string_view actor, std::string_view reason = "");
  // Makes any version older than the active one active again (whatever its state: it is the
  // technician's explicit choice); the active one becomes superseded. FailedPrecondition if the
  // device has no active version or `to_version` is not older than it.
  absl::StatusOr<ParamVersion> Rollback(std::string_view device_id, int to_version,
                                        std::string_view actor, std::string_view reason = "");
  // Candidate -> rejected; `reason` goes to the audit log (as it does for Promote, Rollback).
  absl::StatusOr<ParamVersion> Reject(std::string_view device_id, int version,
                                      std::string_view actor, std::string_view reason);
  // The hot path (a robot fetching its parameters): one prepared, indexed lookup on a pooled
  // read connection. report_json is NOT loaded (left empty): use GetVersion for the report.
  // NotFound if the device has no active version (or does not exist).
  absl::StatusOr<ParamVersion> GetActive(std::string_view device_id);
  absl::StatusOr<ParamVersion> GetVersion(std::string_view device_id, int version);
  // The device's versions, oldest first; without params/report JSON unless asked.
  absl::StatusOr<std::vector<ParamVersion>> ListVersions(std::string_view device_id,
                                                         const VersionQuery& query = {});

  // ---- Audit log. AppendAudit is for actions outside storage (e.g. a robot fetched its
  // parameters); `id` and `time` are assigned. ListAudit is in id (= time) order.
  absl::StatusOr<AuditEntry> AppendAudit(const AuditEntry& entry);
  absl::StatusOr<std::vector<AuditEntry>> ListAudit(const AuditQuery& query = {});
  // The devices whose active version may have changed (a version added, promoted or rolled
  // back) in the commits after audit entry `after_id`, by any process sharing the database,
  // and the last entry read: pass it as after_id next time (at most 1000 entries are read per
  // call; the rest next time). after_id < 0: no devices, only the current last entry. For the
  // caches of another server (a server's own commits reach it through on_active_change).
  struct ActiveChanges {
    std::vector<std::string> devices;
    int64_t last_id = 0;
  };
  absl::StatusOr<ActiveChanges> ActiveChangesSince(int64_t after_id);
  // PostgreSQL only: what other servers sharing the database commit, as it commits
  // (LISTEN/NOTIFY, on a connection of its own):
  //   on_active: a device's active version changed (any store's commit, this one's included;
  //     channel imucal_active, payload the device id);
  //   on_session: another store stored a batch of a session or changed its state (channel
  //     imucal_session, payload "<origin> <session id>"; this store's own are left out);
  //   on_token: a token was created, changed or deleted, by anyone (channel imucal_token,
  //     payload the token's id; a trigger sends it, so SQL typed by hand is told too);
  //   on_gap: some may have been missed (the listening connection broke: once when it does,
  //     once when listening resumes); drop everything cached then.
  // All run on the listener's thread and must be quick. Once per store; FailedPrecondition on
  // SQLite (use ActiveChangesSince there).
  struct ChangeHandlers {
    std::function<void(std::string_view device_id)> on_active;
    std::function<void(std::string_view session_id)> on_session;
    std::function<void(int64_t token_id)> on_token;
    std::function<void()> on_gap;
  };
  absl::Status ListenForChanges(ChangeHandlers handlers);
  void StopListening();  // no handler runs once it returns

 private:
  class ReadLease;
  Store(StoreOptions options, std::unique_ptr<sql::Connection> writer,
        std::unique_ptr<sql::SqliteConnection> checkpointer,
        std::vector<std::unique_ptr<sql::Connection>> readers);
  static absl::StatusOr<std::unique_ptr<Store>> OpenPostgres(const std::string& url,
                                                             StoreOptions options);

  absl::Time Now() const;
  absl::StatusOr<ParamVersion> NotifyIfActive(absl::StatusOr<ParamVersion> version);
  ReadLease AcquireReader();
  void ReleaseReader(sql::Connection* conn);

  StoreOptions options_;
  std::mutex write_mu_;
  std::unique_ptr<sql::Connection> writer_;  // guarded by write_mu_

  // Group commit (AppendBatchAsync) and background WAL checkpoints; both threads start with
  // the first AppendBatchAsync (a store that only writes synchronously keeps SQLite's automatic
  // checkpoint) and stop in the destructor after the submitted batches.
  struct PendingAppend;
  static constexpr int kCheckpointPages = 4096;  // 16 MiB of WAL at 4 KiB pages
  void StartBackgroundThreads();
  void CommitLoop();
  void CheckpointLoop();
  std::once_flag threads_started_;
  std::mutex commit_mu_;
  std::condition_variable commit_cv_;
  std::condition_variable checkpoint_cv_;
  std::vector<PendingAppend> pending_;  // guarded by commit_mu_
  bool stopping_ = false;               // guarded by commit_mu_
  std::atomic<int> wal_pages_{0};       // WAL pages written since the last checkpoint
  std::thread committer_;
  std::thread checkpoint_thread_;
  // Its own connection: never waits for writes. Null on PostgreSQL.
  std::unique_ptr<sql::SqliteConnection> checkpointer_;

  // Declared after writer_ so they close first (the writer, last out, checkpoints the WAL).
  std::vector<std::unique_ptr<sql::Connection>> readers_;
  std::mutex readers_mu_;
  std::condition_variable reader_free_;
  std::vector<sql::Connection*> free_readers_;  // guarded by readers_mu_

  std::string location_;  // the file or URL it was opened on
  std::string origin_;    // PostgreSQL: its name in the notifications it sends (ConnectionOptions)
  // Declared last: stops (and stops calling back) before anything else goes.
  std::unique_ptr<PgListener> listener_;
};

}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_STORE_H_
