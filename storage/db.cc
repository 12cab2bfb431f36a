#include "storage/db.h"

#include "util/str_util.h"

namespace imucal::storage {

bool IsPostgresUrl(std::string_view location) {
  return location.starts_with("postgresql://") || location.starts_with("postgres://");
}

std::string RedactedLocation(std::string_view location) {
  if (!IsPostgresUrl(location)) return std::string(location);
  // scheme://user:password@host... -> scheme://user:***@host...
  const size_t scheme_end = location.find("://") + 3;
  const size_t at = location.find('@', scheme_end);
  if (at == std::string_view::npos) return std::string(location);
  const size_t colon = location.find(':', scheme_end);
  if (colon == std::string_view::npos || colon > at) return std::string(location);
  return Cat(location.substr(0, colon + 1), "***", location.substr(at));
}

absl::Status Statement::Run() {
  for (;;) {
    absl::StatusOr<bool> row = Step();
    if (!row.ok()) return row.status();
    if (!*row) return absl::OkStatus();
  }
}

ScopedStatement::~ScopedStatement() {
  if (stmt_ != nullptr) stmt_->Reset();
  if (in_use_ != nullptr) *in_use_ = false;
}

Connection::~Connection() = default;

absl::StatusOr<ScopedStatement> Connection::Prepare(std::string_view sql) {
  auto it = cache_.find(sql);
  if (it == cache_.end()) {
    absl::StatusOr<std::unique_ptr<Statement>> stmt = NewStatement(sql);
    if (!stmt.ok()) return stmt.status();
    it = cache_.emplace(std::string(sql), Cached{*std::move(stmt), false}).first;
  }
  Cached& cached = it->second;
  if (cached.in_use) return absl::InternalError("statement already in use on this connection");
  cached.in_use = true;
  return ScopedStatement(cached.stmt.get(), &cached.in_use);
}

bool Connection::ForgetStatements() {
  for (const auto& [sql, cached] : cache_)
    if (cached.in_use) return false;
  cache_.clear();
  return true;
}

// ---- Transaction -----------------------------------------------------------------------------

absl::StatusOr<Transaction> Transaction::Begin(Connection& conn, Isolation isolation) {
  absl::StatusOr<ScopedStatement> begin = conn.Prepare(conn.BeginSql(isolation));
  if (!begin.ok()) return begin.status();
  if (absl::Status s = (*begin)->Run(); !s.ok()) return s;
  return Transaction(&conn);
}

absl::Status Transaction::Commit() {
  if (conn_ == nullptr) return absl::InternalError("transaction already finished");
  // A doomed transaction stays open and the destructor rolls it back.
  if (absl::Status s = conn_->CommitBlocker(); !s.ok()) return s;
  {
    absl::StatusOr<ScopedStatement> commit = conn_->Prepare("COMMIT");
    if (!commit.ok()) return commit.status();
    // On failure the transaction stays open and the destructor rolls it back.
    if (absl::Status s = (*commit)->Run(); !s.ok()) return s;
  }
  conn_ = nullptr;
  return absl::OkStatus();
}

Transaction::~Transaction() {
  // The backend may already have rolled back by itself (SQLite after FULL, IOERR, NOMEM...).
  if (conn_ == nullptr || !conn_->InOpenTransaction()) return;
  if (absl::StatusOr<ScopedStatement> rollback = conn_->Prepare("ROLLBACK"); rollback.ok()) {
    (void)(*rollback)->Run();
  } else {
    (void)conn_->Exec("ROLLBACK");
  }
}

}  // namespace imucal::storage
