// What the files of the SQLite store (store.cc and store_<table>.cc, one per banner of store.h)
// share: time and error conventions, the transaction wrapper, the lookups and writes that one
// table's calls make on another's, and the Store's private types. TokenStore (tokens.cc) writes
// its audit rows and transactions through it too. Private to storage/*.cc; the library's API is
// store.h.
//
// Each shared lookup or write is defined in the file of the table it touches (named below), so
// a table's SQL lives in one file.
#ifndef IMUCAL_STORAGE_STORE_INTERNAL_H_
#define IMUCAL_STORAGE_STORE_INTERNAL_H_

#include <cstdint>
#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "storage/sample_codec.h"
#include "storage/status_macros.h"
#include "storage/store.h"
#include "storage/types.h"
#include "util/db.h"
#include "util/str_util.h"

namespace imucal::storage {

// ---- Conventions -----------------------------------------------------------------------------

// Times are stored as integer microseconds since the Unix epoch.
inline int64_t Micros(absl::Time t) { return absl::ToUnixMicros(t); }
inline absl::Time FromMicros(int64_t us) { return absl::FromUnixMicros(us); }

// The API's "no limit" is 0; SQL's, on both backends, a LIMIT no table reaches.
inline int64_t SqlLimit(int limit) {
  return limit > 0 ? limit : std::numeric_limits<int64_t>::max();
}

// An optional text column: NULL when empty.
inline std::optional<std::string_view> NullIfEmpty(std::string_view value) {
  if (value.empty()) return std::nullopt;
  return value;
}

// A stored enum name that does not parse means the file was tampered with.
template <typename T>
absl::StatusOr<T> FromColumn(absl::StatusOr<T> parsed) {
  if (!parsed.ok()) return absl::DataLossError(parsed.status().message());
  return parsed;
}

inline absl::Status NonEmpty(std::string_view value, std::string_view what) {
  if (value.empty()) return absl::InvalidArgumentError(Cat(what, " is empty"));
  return absl::OkStatus();
}

inline const absl::Status& StatusOf(const absl::Status& s) { return s; }
template <typename T>
const absl::Status& StatusOf(const absl::StatusOr<T>& s) {
  return s.status();
}

// How often InTransaction runs a transaction that a concurrent one aborted.
inline constexpr int kTransactionAttempts = 12;

// Before attempt `attempt` + 1: a random pause of up to 2^attempt ms (at most 256 ms), so that
// the transactions that collided do not collide again.
void PauseBeforeRetry(int attempt);

// Runs `body(conn)` in one write transaction (Transaction, db.h), committing only if it
// succeeds. `body` returns absl::Status or absl::StatusOr<T>; errors are prefixed with `op`
// (WithContext, status_macros.h).
// A transaction that the backend aborts because it conflicted with a concurrent one (Aborted:
// PostgreSQL's serialization failures and deadlocks, when several servers share the database)
// runs again from the start, up to kTransactionAttempts times; so `body` must be safe to run
// again: it reads and writes through `conn` and returns what it found, and anything it collects
// outside is reset at its start.
// The connection's on_transaction hears of it once, committed or not, the retries included.
template <typename F>
std::invoke_result_t<F, sql::Connection&> InTransaction(
    std::string_view op, sql::Connection& conn, F&& body,
    sql::Isolation isolation = sql::Isolation::kSerializable) {
  const absl::Time start = conn.on_transaction ? absl::Now() : absl::InfinitePast();
  const auto told = [&](auto result) {
    if (conn.on_transaction) conn.on_transaction(op, absl::Now() - start);
    return result;
  };
  for (int attempt = 1;; ++attempt) {
    absl::Status failed;
    {
      absl::StatusOr<sql::Transaction> txn = sql::Transaction::Begin(conn, isolation);
      if (!txn.ok()) return told(WithContext(op, txn.status()));
      auto result = body(conn);
      if (result.ok()) {
        failed = txn->Commit();
        if (failed.ok()) return told(std::move(result));
      } else {
        failed = StatusOf(result);
      }
    }  // rolled back here unless committed
    if (!absl::IsAborted(failed) || attempt >= kTransactionAttempts) {
      return told(WithContext(op, failed));
    }
    PauseBeforeRetry(attempt);
  }
}

// ---- Shared lookups and writes, inside the caller's transaction or read lease ----------------

// store_devices.cc. NotFound naming the device.
absl::StatusOr<Device> LoadDevice(sql::Connection& conn, std::string_view id);

// PostgreSQL's notification channels (Store::ListenForChanges).
inline constexpr char kActiveChannel[] = "imucal_active";
inline constexpr char kSessionChannel[] = "imucal_session";
// Sent by the tokens table's trigger (schema migration 7) at each change; payload the token id.
inline constexpr char kTokenChannel[] = "imucal_token";
// PostgreSQL: tells the other servers' listeners that the session changed, when (and if) the
// transaction commits; payload "<origin> <session id>" (ConnectionOptions::origin). Nothing on
// SQLite. Several in one transaction arrive as one.
absl::Status AnnounceSession(sql::Connection& conn, std::string_view session_id);

// store_sessions.cc. NotFound naming the session.
absl::StatusOr<Session> LoadSession(sql::Connection& conn, std::string_view id);
absl::Status CheckSessionExists(sql::Connection& conn, std::string_view id);
// Moves `session` to `to` (checking the transition of types.h and the one-open-session rule)
// and audits it.
absl::Status ChangeSessionState(sql::Connection& conn, const Session& session, SessionState to,
                                std::string_view actor, absl::Time now);

// store_solves.cc. Fails the session's running solve, if any, with `error`.
absl::Status AbandonRunningSolve(sql::Connection& conn, std::string_view session_id, absl::Time now,
                                 std::string_view error);

// store_versions.cc. AddVersion's checks and insert (activating it if v.state is kActive),
// the documents written by `render` (if given) once the number is assigned; `reason` (may be
// empty) ends the audit row's detail.
absl::StatusOr<ParamVersion> InsertVersion(sql::Connection& conn, const ParamVersion& v,
                                           std::string_view actor, absl::Time now,
                                           const RenderVersion& render,
                                           std::string_view reason = "");

// store_audit.cc. One audit_log row.
absl::Status InsertAudit(sql::Connection& conn, absl::Time time, std::string_view actor,
                         std::string_view action, std::string_view target, std::string_view detail);

// ---- The Store's private types ---------------------------------------------------------------

// A read connection from the pool, returned to it on destruction.
class Store::ReadLease {
 public:
  ReadLease(Store* store, sql::Connection* conn) : store_(store), conn_(conn) {}
  ReadLease(const ReadLease&) = delete;
  ReadLease& operator=(const ReadLease&) = delete;
  ~ReadLease() { store_->ReleaseReader(conn_); }
  sql::Connection& conn() const { return *conn_; }

 private:
  Store* store_;
  sql::Connection* conn_;
};

// A batch waiting for the committer thread (store_samples.cc), already checked (CheckBatch).
struct Store::PendingAppend {
  std::string session_id;
  int64_t seq = 0;
  std::string payload;
  EncodedBatchInfo info;
  std::function<void(absl::StatusOr<BatchAck>)> done;
};

}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_STORE_INTERNAL_H_
