#include "util/sqlite_db.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "util/str_util.h"

namespace imucal::sql {
namespace {

absl::StatusCode CodeFor(int extended_code) {
  switch (extended_code) {
    case SQLITE_CONSTRAINT_UNIQUE:
    case SQLITE_CONSTRAINT_PRIMARYKEY:
      return absl::StatusCode::kAlreadyExists;
    default:
      break;
  }
  switch (extended_code & 0xff) {
    case SQLITE_BUSY:
    case SQLITE_LOCKED:
      return absl::StatusCode::kUnavailable;
    case SQLITE_CONSTRAINT:
      return absl::StatusCode::kFailedPrecondition;
    case SQLITE_CORRUPT:
    case SQLITE_NOTADB:
      return absl::StatusCode::kDataLoss;
    case SQLITE_FULL:
    case SQLITE_NOMEM:
      return absl::StatusCode::kResourceExhausted;
    case SQLITE_CANTOPEN:
    case SQLITE_PERM:
    case SQLITE_READONLY:
    case SQLITE_IOERR:
      return absl::StatusCode::kUnavailable;
    case SQLITE_TOOBIG:
      return absl::StatusCode::kInvalidArgument;
    case SQLITE_INTERRUPT:
      return absl::StatusCode::kCancelled;
    default:
      return absl::StatusCode::kInternal;
  }
}

}  // namespace

absl::Status SqliteStatus(int extended_code, std::string_view context, sqlite3* db) {
  // sqlite3_errmsg describes the connection's latest failure, which is this one when the caller
  // passes the code it just got; without a connection, the generic text for the code.
  const char* what = db != nullptr ? sqlite3_errmsg(db) : sqlite3_errstr(extended_code);
  return FromDatabase(absl::Status(CodeFor(extended_code), Cat(context, ": ", what)));
}

// ---- Statement -------------------------------------------------------------------------------

absl::StatusOr<std::unique_ptr<SqliteStatement>> SqliteStatement::Prepare(sqlite3* db,
                                                                          std::string_view sql) {
  if (sql.size() > static_cast<size_t>(std::numeric_limits<int>::max())) {
    return absl::InvalidArgumentError("SQL text too long");
  }
  sqlite3_stmt* raw = nullptr;
  // PERSISTENT: the statement lives as long as the connection (Connection caches it).
  const int rc = sqlite3_prepare_v3(db, sql.data(), static_cast<int>(sql.size()),
                                    SQLITE_PREPARE_PERSISTENT, &raw, nullptr);
  if (rc != SQLITE_OK) {
    sqlite3_finalize(raw);
    return SqliteStatus(rc, "prepare", db);
  }
  if (raw == nullptr) return absl::InternalError("prepare: empty SQL");
  std::unique_ptr<SqliteStatement> stmt(new SqliteStatement());
  stmt->stmt_.reset(raw);
  stmt->db_ = db;
  return stmt;
}

void SqliteStatement::NoteBind(int rc) {
  if (rc != SQLITE_OK && bind_error_ == SQLITE_OK) bind_error_ = rc;
}

void SqliteStatement::BindInt64(int index, int64_t value) {
  NoteBind(sqlite3_bind_int64(stmt_.get(), index, value));
}

void SqliteStatement::BindDouble(int index, double value) {
  if (std::isnan(value)) {
    BindNull(index);
    return;
  }
  NoteBind(sqlite3_bind_double(stmt_.get(), index, value));
}

void SqliteStatement::BindText(int index, std::string_view value) {
  NoteBind(sqlite3_bind_text64(stmt_.get(), index, value.data(), value.size(), SQLITE_TRANSIENT,
                               SQLITE_UTF8));
}

void SqliteStatement::BindBlob(int index, std::string_view value) {
  // A zero-length blob needs a non-null pointer, or SQLite binds NULL.
  static constexpr char kEmpty = 0;
  const char* data = value.empty() ? &kEmpty : value.data();
  NoteBind(sqlite3_bind_blob64(stmt_.get(), index, data, value.size(), SQLITE_TRANSIENT));
}

void SqliteStatement::BindNull(int index) { NoteBind(sqlite3_bind_null(stmt_.get(), index)); }

absl::StatusOr<bool> SqliteStatement::Step() {
  if (bind_error_ != SQLITE_OK) return SqliteStatus(bind_error_, "bind", nullptr);
  const int rc = sqlite3_step(stmt_.get());
  if (rc == SQLITE_ROW) return true;
  if (rc == SQLITE_DONE) return false;
  return SqliteStatus(rc, "step", db_);
}

int64_t SqliteStatement::ColumnInt64(int column) const {
  return sqlite3_column_int64(stmt_.get(), column);
}

double SqliteStatement::ColumnDouble(int column) const {
  if (ColumnIsNull(column)) return std::numeric_limits<double>::quiet_NaN();
  return sqlite3_column_double(stmt_.get(), column);
}

std::string SqliteStatement::ColumnText(int column) const {
  const unsigned char* text = sqlite3_column_text(stmt_.get(), column);
  if (text == nullptr) return std::string();
  return std::string(reinterpret_cast<const char*>(text),
                     static_cast<size_t>(sqlite3_column_bytes(stmt_.get(), column)));
}

std::string_view SqliteStatement::ColumnBlobView(int column) const {
  const void* data = sqlite3_column_blob(stmt_.get(), column);
  if (data == nullptr) return std::string_view();
  return std::string_view(static_cast<const char*>(data),
                          static_cast<size_t>(sqlite3_column_bytes(stmt_.get(), column)));
}

bool SqliteStatement::ColumnIsNull(int column) const {
  return sqlite3_column_type(stmt_.get(), column) == SQLITE_NULL;
}

void SqliteStatement::Reset() {
  sqlite3_reset(stmt_.get());
  sqlite3_clear_bindings(stmt_.get());
  bind_error_ = SQLITE_OK;
}

// ---- Connection ------------------------------------------------------------------------------

absl::StatusOr<std::unique_ptr<SqliteConnection>> SqliteConnection::Open(
    const std::string& path, const ConnectionOptions& options) {
  if (sqlite3_threadsafe() == 0) {
    return absl::FailedPreconditionError("SQLite was built without thread support");
  }
  // NOMUTEX: a Connection is used by one thread at a time (Store guards it), so SQLite's own
  // per-connection mutex would only cost time.
  const int flags =
      (options.read_only ? SQLITE_OPEN_READONLY : SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE) |
      SQLITE_OPEN_NOMUTEX;
  sqlite3* db = nullptr;
  const int rc = sqlite3_open_v2(path.c_str(), &db, flags, nullptr);
  if (rc != SQLITE_OK) {
    absl::Status status = SqliteStatus(rc, Cat("open ", path), db);
    sqlite3_close_v2(db);
    return status;
  }
  sqlite3_extended_result_codes(db, 1);
  std::unique_ptr<SqliteConnection> conn(new SqliteConnection(db));
  const auto timeout_ms = absl::ToInt64Milliseconds(options.busy_timeout);
  sqlite3_busy_timeout(db, static_cast<int>(std::min<int64_t>(timeout_ms, 1 << 30)));
  if (absl::Status s = conn->Exec("PRAGMA foreign_keys = ON"); !s.ok()) return s;
  const char* sync =
      options.synchronous_full ? "PRAGMA synchronous = FULL" : "PRAGMA synchronous = NORMAL";
  if (absl::Status s = conn->Exec(sync); !s.ok()) return s;
  return conn;
}

SqliteConnection::~SqliteConnection() {
  ForgetStatements();  // finalise every statement before closing
  sqlite3_close_v2(db_);
}

absl::StatusOr<std::unique_ptr<Statement>> SqliteConnection::NewStatement(std::string_view sql) {
  absl::StatusOr<std::unique_ptr<SqliteStatement>> stmt = SqliteStatement::Prepare(db_, sql);
  if (!stmt.ok()) return stmt.status();
  return std::unique_ptr<Statement>(*std::move(stmt));
}

absl::Status SqliteConnection::Exec(const char* sql) {
  char* message = nullptr;
  const int rc = sqlite3_exec(db_, sql, nullptr, nullptr, &message);
  if (rc == SQLITE_OK) return absl::OkStatus();
  absl::Status status =
      FromDatabase(absl::Status(SqliteStatus(rc, "exec", nullptr).code(),
                                Cat("exec: ", message != nullptr ? message : sqlite3_errstr(rc))));
  sqlite3_free(message);
  return status;
}

}  // namespace imucal::sql
