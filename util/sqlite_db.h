// The SQLite backend of the database layer (db.h): the embedded default, one file in WAL mode.
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
#ifndef IMUCAL_UTIL_SQLITE_DB_H_
#define IMUCAL_UTIL_SQLITE_DB_H_

#include <sqlite3.h>

#include <memory>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "util/db.h"

namespace imucal::sql {

// `context` says what was being done ("AppendBatch"); `db` (may be null) supplies the message.
absl::Status SqliteStatus(int extended_code, std::string_view context, sqlite3* db);

class SqliteStatement final : public Statement {
 public:
  static absl::StatusOr<std::unique_ptr<SqliteStatement>> Prepare(sqlite3* db,
                                                                  std::string_view sql);

  void BindInt64(int index, int64_t value) override;
  void BindDouble(int index, double value) override;  // NaN binds NULL (SQLite stores NULL)
  void BindText(int index, std::string_view value) override;
  void BindBlob(int index, std::string_view value) override;
  void BindNull(int index) override;
  absl::StatusOr<bool> Step() override;
  int64_t ColumnInt64(int column) const override;
  double ColumnDouble(int column) const override;
  std::string ColumnText(int column) const override;
  std::string_view ColumnBlobView(int column) const override;
  bool ColumnIsNull(int column) const override;
  void Reset() override;

  sqlite3_stmt* get() const { return stmt_.get(); }

 private:
  struct Finalizer {
    void operator()(sqlite3_stmt* stmt) const { sqlite3_finalize(stmt); }
  };
  SqliteStatement() = default;
  void NoteBind(int rc);

  std::unique_ptr<sqlite3_stmt, Finalizer> stmt_;
  sqlite3* db_ = nullptr;
  int bind_error_ = SQLITE_OK;
};

class SqliteConnection final : public Connection {
 public:
  // Opens (creating unless read_only) and applies the per-connection settings: foreign_keys=ON,
  // busy_timeout, synchronous. journal_mode=WAL is a property of the file, set by
  // Store::Open through the writer connection.
  static absl::StatusOr<std::unique_ptr<SqliteConnection>> Open(const std::string& path,
                                                                const ConnectionOptions& options);
  ~SqliteConnection() override;

  Dialect dialect() const override { return Dialect::kSqlite; }
  absl::Status Exec(const char* sql) override;
  const char* BeginSql(Isolation) const override { return "BEGIN IMMEDIATE"; }
  bool InOpenTransaction() const override { return sqlite3_get_autocommit(db_) == 0; }

  sqlite3* db() const { return db_; }

 protected:
  absl::StatusOr<std::unique_ptr<Statement>> NewStatement(std::string_view sql) override;

 private:
  explicit SqliteConnection(sqlite3* db) : db_(db) {}
  sqlite3* db_;
};

}  // namespace imucal::sql

#endif  // IMUCAL_UTIL_SQLITE_DB_H_
