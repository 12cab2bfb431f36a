// The PostgreSQL backend of the database layer (db.h), through libpq: for several imucald
// servers sharing one database.
//
// - SQL is the store's common SQL: ?N parameters become $N when a statement is first run.
// - A statement is prepared on the server (PQprepare) when it first runs, with the types of that
//   run's parameters (integers int8, floating point float8, text text, blobs bytea, NULL left
//   for the server to infer: CAST a parameter that may be NULL where nothing else fixes its
//   type), and reused for the connection's life.
// - Parameters go as text (blobs as binary); results come back binary and are read by column
//   type (bool, int2/4/8, float4/8, text-like, bytea).
// - Write transactions are SERIALIZABLE; PostgreSQL's serialization failures and deadlocks are
//   Aborted, which InTransaction (store_internal.h) answers by running the transaction again.
// - A connection that breaks (the server restarted, the network dropped) is Unavailable for the
//   call under way and is reset before the next one.
//
// SQLSTATE classes map to absl codes: 23505 AlreadyExists; other 23 (integrity)
// FailedPrecondition; 40001, 40P01 Aborted; 55P03 (lock_timeout), 08 (connection), 57P01-03
// (shutdown) Unavailable; 53 (resources) ResourceExhausted; 22 (data) InvalidArgument; 57014
// (cancelled) Cancelled; XX001, XX002 (corruption) DataLoss; anything else Internal.
#ifndef IMUCAL_STORAGE_PG_DB_H_
#define IMUCAL_STORAGE_PG_DB_H_

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "util/db.h"

typedef struct pg_conn PGconn;

namespace imucal::storage {

// The absl code for a SQLSTATE (above).
absl::StatusCode PgCode(std::string_view sqlstate);

class PgConnection final : public sql::Connection {
 public:
  // Connects to `url` (a libpq connection URL) and applies the per-connection settings:
  // lock_timeout from busy_timeout, synchronous_commit on, read-only transactions if asked.
  static absl::StatusOr<std::unique_ptr<PgConnection>> Open(const std::string& url,
                                                            const sql::ConnectionOptions& options);
  ~PgConnection() override;

  sql::Dialect dialect() const override { return sql::Dialect::kPostgres; }
  absl::Status Exec(const char* sql) override;
  const char* BeginSql(sql::Isolation isolation) const override {
    return isolation == sql::Isolation::kReadCommitted ? "BEGIN ISOLATION LEVEL READ COMMITTED"
                                                       : "BEGIN ISOLATION LEVEL SERIALIZABLE";
  }
  bool InOpenTransaction() const override;
  absl::Status CommitBlocker() const override;

  PGconn* conn() const { return conn_; }
  // Before each statement: reconnects (and forgets the prepared statements) if the connection
  // broke. Unavailable if it cannot.
  absl::Status EnsureConnected();
  // The error of a failed statement: remembered as the open transaction's first error, which
  // is what a later statement of the doomed transaction reports (not PostgreSQL's "current
  // transaction is aborted").
  absl::Status StatementError(std::string_view context, const char* sqlstate,
                              std::string_view message);
  // A name for the next server-side prepared statement.
  std::string NextStatementName();
  // Bumped at each reconnect: statements prepared before it must be prepared again.
  uint64_t generation() const { return generation_; }
  // BEGIN ran, or COMMIT / ROLLBACK ended the transaction (also when the connection broke).
  void NoteTransactionStarted();
  void NoteTransactionEnded();

 protected:
  absl::StatusOr<std::unique_ptr<sql::Statement>> NewStatement(std::string_view sql) override;

 private:
  PgConnection(PGconn* conn, std::string settings, bool read_only)
      : conn_(conn), settings_(std::move(settings)), read_only_(read_only) {}
  absl::Status ApplySettings();

 public:
  // A statement that found the connection broken may run again on a new one: outside a
  // transaction, a BEGIN (nothing has started) or any statement of a read-only connection.
  bool MayRetryAfterReconnect(bool is_begin) const {
    return !txn_open_ && (is_begin || read_only_);
  }

 private:
  PGconn* conn_;
  std::string settings_;  // the SET script run after every (re)connect
  bool read_only_ = false;
  bool txn_open_ = false;
  absl::Status txn_error_;  // the open transaction's first error
  uint64_t generation_ = 0;
  int next_statement_ = 0;
};

// LISTEN on some channels, on a connection of its own, in a thread of its own. `on_notify` gets
// each notification's channel and payload as it arrives (PostgreSQL delivers a NOTIFY when its
// transaction commits, to every listening session, in commit order). `on_gap` is called when
// notifications may have been missed: when the connection breaks, and again once listening has
// resumed (it reconnects every second until it can). Both run on the listener's thread and must
// be quick.
class PgListener {
 public:
  using OnNotify = std::function<void(std::string_view channel, std::string_view payload)>;
  static absl::StatusOr<std::unique_ptr<PgListener>> Start(const std::string& url,
                                                           std::vector<std::string> channels,
                                                           OnNotify on_notify,
                                                           std::function<void()> on_gap);
  ~PgListener();  // stops listening; joins the thread
  PgListener(const PgListener&) = delete;
  PgListener& operator=(const PgListener&) = delete;

 private:
  PgListener() = default;
  void Run();
  absl::Status Connect();

  std::string url_;
  std::vector<std::string> channels_;
  OnNotify on_notify_;
  std::function<void()> on_gap_;
  PGconn* conn_ = nullptr;  // the listener thread's once started
  int wake_fd_ = -1;        // an eventfd: the destructor's "stop now"
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_PG_DB_H_
