// imucal::sql, the database layer, the same for its two backends: SQLite (util/sqlite_db.h, the
// embedded default, also what the ROS 2 bag reader opens a .db3 with) and PostgreSQL
// (storage/pg_db.h, for several servers sharing one database). In util so that reading an
// SQLite file needs no service store.
//
// - `Statement`: one prepared statement; binds copy their argument, a bind error is kept and
//   returned by the next Step().
// - `Connection`: one database connection plus its prepared statements, each prepared once and
//   reused (`Prepare` returns a `ScopedStatement` that resets it when it goes out of scope). A
//   Connection is not thread-safe: one thread at a time (Store guards them).
// - `Transaction`: the backend's write transaction (SQLite: BEGIN IMMEDIATE, one writer at a
//   time; PostgreSQL: BEGIN ISOLATION LEVEL SERIALIZABLE). The destructor rolls back unless
//   Commit() ran.
// - `ReadRows`, `ReadRow`, `RunStatement`: a whole statement in one call (prepare, bind the
//   parameters in order, step, map each row with one function per row type). Every query of the
//   store goes through them, so a SELECT is its SQL, its parameters and its row mapper.
//
// SQL is always a constant; values are bound, never concatenated into it. The store's SQL is
// written once for both backends: parameters are ?1, ?2, ... (rewritten to $1, $2, ... for
// PostgreSQL), upserts are INSERT ... ON CONFLICT, new ids come back through RETURNING, and a
// parameter whose type the statement does not fix is CAST.
//
// Errors of both backends map to the same absl codes:
//   a unique or primary key violated                -> AlreadyExists
//   another constraint (foreign key, check, not null) -> FailedPrecondition
//   another writer holds the lock (SQLite BUSY, PostgreSQL lock_timeout), the database cannot be
//   reached or used right now                       -> Unavailable
//   a concurrent transaction conflicts (PostgreSQL serialization failure or deadlock): run the
//   whole transaction again (InTransaction does)   -> Aborted
//   the file is damaged                             -> DataLoss
//   out of space or memory                          -> ResourceExhausted
//   a value out of range or too big                 -> InvalidArgument
//   anything else                                   -> Internal
#ifndef IMUCAL_UTIL_DB_H_
#define IMUCAL_UTIL_DB_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>
#include <unordered_map>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"

namespace imucal::sql {

enum class Dialect { kSqlite, kPostgres };

// A write transaction's isolation. SQLite's is always serial (one writer at a time).
// PostgreSQL: kSerializable by default; kReadCommitted for a transaction that takes the row
// locks it needs itself (SELECT ... FOR NO KEY UPDATE) and so must not be aborted for the
// predicate conflicts SERIALIZABLE would see between unrelated rows (sample appends of many
// streams through several servers).
enum class Isolation { kSerializable, kReadCommitted };

// "postgresql://..." or "postgres://..." (libpq's URL forms): the PostgreSQL backend.
// Anything else is a SQLite file path.
bool IsPostgresUrl(std::string_view location);

// `location` without the password of a PostgreSQL URL, for logs and errors.
std::string RedactedLocation(std::string_view location);

// Every error made from the database's own text (libpq's and PostgreSQL's messages, SQLite's)
// carries this payload. Those messages are for the operator: they name the database's host and
// port, its constraints, the statement's context. The server's boundary (server/status_util.h)
// gives a client a fixed message in their place ("the calibration service's database is
// unavailable") and writes the detail to its log. Status wrappers keep the payload
// (WithOperation copies every payload).
inline constexpr char kDatabaseErrorPayload[] = "imucal.storage/database-error";
absl::Status FromDatabase(absl::Status status);
bool IsFromDatabase(const absl::Status& status);

// InvalidArgument when `location` looks like a URL (it has "scheme://", or begins "postgres")
// but is not one IsPostgresUrl takes: a mistyped URL would otherwise be a new SQLite file named
// after it. The message shows it without its password and says what is expected.
absl::Status CheckLocation(std::string_view location);

class Statement {
 public:
  virtual ~Statement() = default;
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;

  // Parameters are 1-based (?1, ?2, ...).
  virtual void BindInt64(int index, int64_t value) = 0;
  virtual void BindDouble(int index, double value) = 0;  // NaN binds NULL
  virtual void BindText(int index, std::string_view value) = 0;
  virtual void BindBlob(int index, std::string_view value) = 0;
  virtual void BindNull(int index) = 0;

  // One step: true when a row is ready, false when the statement is done.
  virtual absl::StatusOr<bool> Step() = 0;
  // Runs a statement that returns no rows (or ignores them) to completion.
  absl::Status Run();

  // Columns are 0-based. NULL reads as 0, NaN, "" respectively.
  virtual int64_t ColumnInt64(int column) const = 0;
  virtual double ColumnDouble(int column) const = 0;
  virtual std::string ColumnText(int column) const = 0;
  std::string ColumnBlob(int column) const { return std::string(ColumnBlobView(column)); }
  virtual std::string_view ColumnBlobView(int column) const = 0;  // valid until Step/Reset
  virtual bool ColumnIsNull(int column) const = 0;

  // Ready to run again: resets, clears bindings and any pending bind error.
  virtual void Reset() = 0;

 protected:
  Statement() = default;
};

// A cached statement lent by a Connection; resets it on destruction so that no read
// transaction stays open behind a half-stepped SELECT.
class ScopedStatement {
 public:
  explicit ScopedStatement(Statement* stmt, bool* in_use) : stmt_(stmt), in_use_(in_use) {}
  ScopedStatement(ScopedStatement&& other) noexcept
      : stmt_(std::exchange(other.stmt_, nullptr)),
        in_use_(std::exchange(other.in_use_, nullptr)) {}
  ScopedStatement& operator=(ScopedStatement&&) = delete;
  ScopedStatement(const ScopedStatement&) = delete;
  ScopedStatement& operator=(const ScopedStatement&) = delete;
  ~ScopedStatement();

  Statement* operator->() const { return stmt_; }
  Statement& operator*() const { return *stmt_; }

 private:
  Statement* stmt_;
  bool* in_use_;
};

struct ConnectionOptions {
  bool read_only = false;
  // SQLite: PRAGMA synchronous = FULL instead of NORMAL (store.h explains the choice).
  // PostgreSQL commits are always synchronous (synchronous_commit = on).
  bool synchronous_full = false;
  // How long a statement waits for another writer's lock before Unavailable (SQLite
  // busy_timeout, PostgreSQL lock_timeout).
  absl::Duration busy_timeout = absl::Seconds(5);
  // PostgreSQL: the name of the Store that owns the connection, set as imucal.origin and sent
  // with the session notifications it commits (store.h ListenForChanges), so that a listener
  // can tell its own from other servers'. Letters and digits only.
  std::string origin;
};

class Connection {
 public:
  virtual ~Connection();
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;

  virtual Dialect dialect() const = 0;

  // The statement for `sql`, prepared on first use and cached for the connection's lifetime.
  // Internal if the same statement is already lent out (a nested use would clobber it).
  absl::StatusOr<ScopedStatement> Prepare(std::string_view sql);

  // Runs a constant script of one or more statements without parameters (schema, settings).
  virtual absl::Status Exec(const char* sql) = 0;

  // The backend's side of Transaction (see above): the statement that begins one.
  virtual const char* BeginSql(Isolation isolation) const = 0;
  // Whether a transaction is open on the connection (the backend may have rolled it back).
  virtual bool InOpenTransaction() const = 0;
  // Before COMMIT: the error that already doomed the open transaction, if any (PostgreSQL turns
  // the COMMIT of a failed transaction into a silent ROLLBACK).
  virtual absl::Status CommitBlocker() const { return absl::OkStatus(); }

  // Told of each transaction run on this connection (InTransaction, store_internal.h): its
  // operation and duration. Empty: nobody is.
  std::function<void(std::string_view op, absl::Duration took)> on_transaction;

 protected:
  Connection() = default;
  virtual absl::StatusOr<std::unique_ptr<Statement>> NewStatement(std::string_view sql) = 0;
  // Forgets every cached statement (after the backend lost them, e.g. a reconnect). False, and
  // nothing forgotten, while one is lent out.
  bool ForgetStatements();

 private:
  struct Cached {
    std::unique_ptr<Statement> stmt;
    bool in_use = false;
  };
  // Looked up by the SQL text without building a std::string on the hot path.
  struct SqlHash {
    using is_transparent = void;
    size_t operator()(std::string_view sql) const noexcept {
      return std::hash<std::string_view>{}(sql);
    }
  };
  // Node-based: pointers to the values stay valid as the map grows.
  std::unordered_map<std::string, Cached, SqlHash, std::equal_to<>> cache_;
};

class Transaction {
 public:
  // Begins the backend's write transaction (Connection::BeginSql). SQLite's BEGIN IMMEDIATE
  // takes the write lock now (waiting up to busy_timeout), so a transaction never fails
  // half-way because another connection wrote first; PostgreSQL's SERIALIZABLE transactions run
  // side by side and one that conflicts fails with Aborted.
  static absl::StatusOr<Transaction> Begin(Connection& conn,
                                           Isolation isolation = Isolation::kSerializable);

  Transaction(Transaction&& other) noexcept : conn_(std::exchange(other.conn_, nullptr)) {}
  Transaction& operator=(Transaction&&) = delete;
  Transaction(const Transaction&) = delete;
  Transaction& operator=(const Transaction&) = delete;
  ~Transaction();  // rolls back unless committed

  absl::Status Commit();

 private:
  explicit Transaction(Connection* conn) : conn_(conn) {}
  Connection* conn_;  // null once committed or rolled back
};

// ---- Whole statements ------------------------------------------------------------------------

// A parameter bound as a BLOB / bytea (text binds as TEXT).
struct SqlBlob {
  std::string_view bytes;
};

namespace db_internal {

template <typename T>
struct IsOptional : std::false_type {};
template <typename T>
struct IsOptional<std::optional<T>> : std::true_type {};

template <typename T>
struct Unwrapped {
  using type = T;
};
template <typename T>
struct Unwrapped<absl::StatusOr<T>> {
  using type = T;
};

template <typename T>
void BindOne(Statement& st, int index, const T& value) {
  if constexpr (std::is_same_v<T, std::nullopt_t>) {
    st.BindNull(index);
  } else if constexpr (IsOptional<T>::value) {
    if (value) {
      BindOne(st, index, *value);
    } else {
      st.BindNull(index);
    }
  } else if constexpr (std::is_same_v<T, bool>) {
    st.BindInt64(index, value ? 1 : 0);
  } else if constexpr (std::is_integral_v<T>) {
    st.BindInt64(index, value);
  } else if constexpr (std::is_floating_point_v<T>) {
    st.BindDouble(index, value);
  } else if constexpr (std::is_same_v<T, SqlBlob>) {
    st.BindBlob(index, value.bytes);
  } else {
    static_assert(std::is_convertible_v<const T&, std::string_view>,
                  "a parameter is an integer, a floating point number, text, SqlBlob or NULL "
                  "(an enum binds by its stored name)");
    st.BindText(index, value);
  }
}

}  // namespace db_internal

// Binds `params` to ?1, ?2, ... in order: integers (bool as 0/1) as INTEGER / BIGINT, floating
// point as REAL / DOUBLE PRECISION, anything convertible to std::string_view as TEXT, SqlBlob
// as BLOB / bytea, and std::nullopt or an empty std::optional as NULL.
template <typename... Params>
void BindAll(Statement& st, const Params&... params) {
  int index = 0;
  (db_internal::BindOne(st, ++index, params), ...);
}

// What a row mapper returns: `T` from a mapper `T(const Statement&)` or
// `absl::StatusOr<T>(const Statement&)` (for rows that can be invalid, e.g. an enum name that
// does not parse).
template <typename MapRow>
using MappedRow =
    typename db_internal::Unwrapped<std::invoke_result_t<MapRow&, const Statement&>>::type;

namespace db_internal {

// The statement for `sql` on `conn`, with `params` bound.
template <typename... Params>
absl::StatusOr<ScopedStatement> PrepareBound(Connection& conn, std::string_view sql,
                                             const Params&... params) {
  absl::StatusOr<ScopedStatement> st = conn.Prepare(sql);
  if (st.ok()) BindAll(**st, params...);
  return st;
}

// `map_row` applied to the current row, as a StatusOr either way.
template <typename MapRow>
absl::StatusOr<MappedRow<MapRow>> MapCurrent(MapRow& map_row, const Statement& st) {
  return map_row(st);
}

}  // namespace db_internal

// Row mappers for one-column queries (an id, a count, a setting).
inline int64_t FirstColumnInt64(const Statement& st) { return st.ColumnInt64(0); }
inline std::string FirstColumnText(const Statement& st) { return st.ColumnText(0); }

// Runs the SELECT `sql` with `params` (see BindAll) and maps every row with `map_row`, in the
// statement's order. The first failing step or mapping is the result.
template <typename MapRow, typename... Params>
absl::StatusOr<std::vector<MappedRow<MapRow>>> ReadRows(Connection& conn, std::string_view sql,
                                                        MapRow&& map_row, const Params&... params) {
  absl::StatusOr<ScopedStatement> st = db_internal::PrepareBound(conn, sql, params...);
  if (!st.ok()) return st.status();
  std::vector<MappedRow<MapRow>> rows;
  for (;;) {
    absl::StatusOr<bool> row = (*st)->Step();
    if (!row.ok()) return row.status();
    if (!*row) return rows;
    absl::StatusOr<MappedRow<MapRow>> mapped = db_internal::MapCurrent(map_row, **st);
    if (!mapped.ok()) return mapped.status();
    rows.push_back(*std::move(mapped));
  }
}

// As ReadRows, for a query of at most one row of interest: its first row, or nullopt if it
// returns none. The mapper runs while the row is current, so it may compare a column view.
template <typename MapRow, typename... Params>
absl::StatusOr<std::optional<MappedRow<MapRow>>> ReadRow(Connection& conn, std::string_view sql,
                                                         MapRow&& map_row,
                                                         const Params&... params) {
  absl::StatusOr<ScopedStatement> st = db_internal::PrepareBound(conn, sql, params...);
  if (!st.ok()) return st.status();
  absl::StatusOr<bool> row = (*st)->Step();
  if (!row.ok()) return row.status();
  if (!*row) return std::nullopt;
  absl::StatusOr<MappedRow<MapRow>> mapped = db_internal::MapCurrent(map_row, **st);
  if (!mapped.ok()) return mapped.status();
  return std::optional<MappedRow<MapRow>>(*std::move(mapped));
}

// Runs a statement that returns no rows (INSERT, UPDATE, DELETE) with `params` (see BindAll).
template <typename... Params>
absl::Status RunStatement(Connection& conn, std::string_view sql, const Params&... params) {
  absl::StatusOr<ScopedStatement> st = db_internal::PrepareBound(conn, sql, params...);
  if (!st.ok()) return st.status();
  return (*st)->Run();
}

}  // namespace imucal::sql

#endif  // IMUCAL_UTIL_DB_H_
