// Thin RAII layer over the SQLite C API, with absl statuses instead of result codes.
//
// - `Statement`: move-only, owns one sqlite3_stmt (finalised by unique_ptr). Binds copy their
//   argument (SQLITE_TRANSIENT). A bind error is kept and returned by the next Step().
// - `Connection`: one sqlite3 handle plus its prepared statements, each prepared once and
//   reused (`Prepare` returns a `ScopedStatement` that resets it when it goes out of scope).
//   A Connection is not thread-safe: one thread at a time (Store guards them).
// - `Transaction`: BEGIN IMMEDIATE; the destructor rolls back unless Commit() ran.
// - `ReadRows`, `ReadRow`, `RunStatement`: a whole statement in one call (prepare, bind the
//   parameters in order, step, map each row with one function per row type). Every query of
//   the store goes through them, so a SELECT is its SQL, its parameters and its row mapper.
//
// SQL is always a constant; values are bound, never concatenated into it.
//
// SQLite result codes map to absl codes as follows (SqliteStatus):
//   BUSY, LOCKED                       -> Unavailable (another writer holds the lock: retry)
//   CONSTRAINT_UNIQUE, _PRIMARYKEY     -> AlreadyExists
//   other CONSTRAINT (FOREIGNKEY, CHECK, NOTNULL, ...) -> FailedPrecondition
//   CORRUPT, NOTADB                    -> DataLoss
//   FULL, NOMEM                        -> ResourceExhausted
//   CANTOPEN, PERM, READONLY, IOERR    -> Unavailable (the file cannot be used right now)
//   TOOBIG                             -> InvalidArgument
//   INTERRUPT                          -> Cancelled
//   anything else (ERROR, MISUSE, RANGE, ...) -> Internal
#ifndef IMUCAL_STORAGE_SQLITE_DB_H_
#define IMUCAL_STORAGE_SQLITE_DB_H_

#include <sqlite3.h>

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

namespace imucal::storage {

// `context` says what was being done ("AppendBatch"); `db` (may be null) supplies the message.
absl::Status SqliteStatus(int extended_code, std::string_view context, sqlite3* db);

class Statement {
 public:
  Statement() = default;
  static absl::StatusOr<Statement> Prepare(sqlite3* db, std::string_view sql);

  Statement(Statement&&) noexcept = default;
  Statement& operator=(Statement&&) noexcept = default;
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;

  // Parameters are 1-based, as in SQLite (?1, ?2, ...).
  void BindInt64(int index, int64_t value);
  void BindDouble(int index, double value);  // NaN binds NULL (SQLite would store NULL anyway)
  void BindText(int index, std::string_view value);
  void BindBlob(int index, std::string_view value);
  void BindNull(int index);

  // One step: true when a row is ready, false when the statement is done.
  absl::StatusOr<bool> Step();
  // Runs a statement that returns no rows (or ignores them) to completion.
  absl::Status Run();

  // Columns are 0-based. NULL reads as 0, NaN, "" respectively.
  int64_t ColumnInt64(int column) const;
  double ColumnDouble(int column) const;
  std::string ColumnText(int column) const;
  std::string ColumnBlob(int column) const;
  std::string_view ColumnBlobView(int column) const;  // valid until the next Step/Reset
  bool ColumnIsNull(int column) const;

  // Ready to run again: resets, clears bindings and any pending bind error.
  void Reset();

  sqlite3_stmt* get() const { return stmt_.get(); }

 private:
  struct Finalizer {
    void operator()(sqlite3_stmt* stmt) const { sqlite3_finalize(stmt); }
  };
  void NoteBind(int rc);

  std::unique_ptr<sqlite3_stmt, Finalizer> stmt_;
  sqlite3* db_ = nullptr;
  int bind_error_ = SQLITE_OK;
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
  // PRAGMA synchronous = FULL instead of NORMAL (store.h explains the choice).
  bool synchronous_full = false;
  absl::Duration busy_timeout = absl::Seconds(5);
};

class Connection {
 public:
  // Opens (creating unless read_only) and applies the per-connection settings: foreign_keys=ON,
  // busy_timeout, synchronous. journal_mode=WAL is a property of the file, set by
  // Store::Open through the writer connection.
  static absl::StatusOr<std::unique_ptr<Connection>> Open(const std::string& path,
                                                          const ConnectionOptions& options);
  ~Connection();
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;

  // The statement for `sql`, prepared on first use and cached for the connection's lifetime.
  // Internal if the same statement is already lent out (a nested use would clobber it).
  absl::StatusOr<ScopedStatement> Prepare(std::string_view sql);

  // Runs a constant script of one or more statements without parameters (schema, PRAGMA).
  absl::Status Exec(const char* sql);

  sqlite3* db() const { return db_; }

  // Told of each transaction run on this connection (InTransaction, store_internal.h): its
  // operation and duration. Empty: nobody is.
  std::function<void(std::string_view op, absl::Duration took)> on_transaction;

 private:
  explicit Connection(sqlite3* db) : db_(db) {}

  struct Cached {
    Statement stmt;
    bool in_use = false;
  };
  // Looked up by the SQL text without building a std::string on the hot path.
  struct SqlHash {
    using is_transparent = void;
    size_t operator()(std::string_view sql) const noexcept {
      return std::hash<std::string_view>{}(sql);
    }
  };
  sqlite3* db_;
  // Node-based: pointers to the values stay valid as the map grows.
  std::unordered_map<std::string, Cached, SqlHash, std::equal_to<>> cache_;
};

class Transaction {
 public:
  // BEGIN IMMEDIATE: takes the write lock now (waiting up to busy_timeout), so a transaction
  // never fails half-way because another connection wrote first.
  static absl::StatusOr<Transaction> Begin(Connection& conn);

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

// A parameter bound as a BLOB (text binds as TEXT).
struct SqlBlob {
  std::string_view bytes;
};

namespace sqlite_internal {

template <typename T>
struct IsOptional : std::false_type {};
template <typename T>
struct IsOptional<std::optional<T>> : std::true_type {};

template <typename T>
struct IsStatusOr : std::false_type {};
template <typename T>
struct IsStatusOr<absl::StatusOr<T>> : std::true_type {};

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

}  // namespace sqlite_internal

// Binds `params` to ?1, ?2, ... in order: integers (bool as 0/1) as INTEGER, floating point as
// REAL, anything convertible to std::string_view as TEXT, SqlBlob as BLOB, and std::nullopt or
// an empty std::optional as NULL.
template <typename... Params>
void BindAll(Statement& st, const Params&... params) {
  int index = 0;
  (sqlite_internal::BindOne(st, ++index, params), ...);
}

// What a row mapper returns: `T` from a mapper `T(const Statement&)` or
// `absl::StatusOr<T>(const Statement&)` (for rows that can be invalid, e.g. an enum name that
// does not parse).
template <typename MapRow>
using MappedRow =
    typename sqlite_internal::Unwrapped<std::invoke_result_t<MapRow&, const Statement&>>::type;

namespace sqlite_internal {

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

}  // namespace sqlite_internal

// Row mappers for one-column queries (an id, a count, a PRAGMA's answer).
inline int64_t FirstColumnInt64(const Statement& st) { return st.ColumnInt64(0); }
inline std::string FirstColumnText(const Statement& st) { return st.ColumnText(0); }

// Runs the SELECT `sql` with `params` (see BindAll) and maps every row with `map_row`, in the
// statement's order. The first failing step or mapping is the result (errors from SQLite are
// mapped by SqliteStatus, in Statement::Step).
template <typename MapRow, typename... Params>
absl::StatusOr<std::vector<MappedRow<MapRow>>> ReadRows(Connection& conn, std::string_view sql,
                                                        MapRow&& map_row, const Params&... params) {
  absl::StatusOr<ScopedStatement> st = sqlite_internal::PrepareBound(conn, sql, params...);
  if (!st.ok()) return st.status();
  std::vector<MappedRow<MapRow>> rows;
  for (;;) {
    absl::StatusOr<bool> row = (*st)->Step();
    if (!row.ok()) return row.status();
    if (!*row) return rows;
    absl::StatusOr<MappedRow<MapRow>> mapped = sqlite_internal::MapCurrent(map_row, **st);
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
  absl::StatusOr<ScopedStatement> st = sqlite_internal::PrepareBound(conn, sql, params...);
  if (!st.ok()) return st.status();
  absl::StatusOr<bool> row = (*st)->Step();
  if (!row.ok()) return row.status();
  if (!*row) return std::nullopt;
  absl::StatusOr<MappedRow<MapRow>> mapped = sqlite_internal::MapCurrent(map_row, **st);
  if (!mapped.ok()) return mapped.status();
  return std::optional<MappedRow<MapRow>>(*std::move(mapped));
}

// Runs a statement that returns no rows (INSERT, UPDATE, DELETE) with `params` (see BindAll).
template <typename... Params>
absl::Status RunStatement(Connection& conn, std::string_view sql, const Params&... params) {
  absl::StatusOr<ScopedStatement> st = sqlite_internal::PrepareBound(conn, sql, params...);
  if (!st.ok()) return st.status();
  return (*st)->Run();
}

}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_SQLITE_DB_H_
