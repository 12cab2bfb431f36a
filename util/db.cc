#include "util/db.h"

#include <algorithm>
#include <cctype>

#include "absl/strings/cord.h"
#include "util/str_util.h"

namespace imucal::sql {

bool IsPostgresUrl(std::string_view location) {
  return location.starts_with("postgresql://") || location.starts_with("postgres://");
}

std::string RedactedLocation(std::string_view location) {
  std::string out(location);
  // scheme://user:password@host... -> scheme://user:***@host... (any scheme: a mistyped one is
  // reported too, and must not show the password either)
  // (Also "scheme:user:password@host", the "//" forgotten.)
  size_t start = std::string::npos;
  if (const size_t scheme = out.find("://"); scheme != std::string::npos) {
    start = scheme + 3;
  } else if (const size_t colon = out.find(':');
             colon != std::string::npos && colon > 0 &&
             std::all_of(out.begin(), out.begin() + colon,
                         [](char c) { return std::isalnum(static_cast<unsigned char>(c)); })) {
    start = out.find_first_not_of('/', colon + 1);
  }
  if (start != std::string::npos) {
    const size_t at = out.find('@', start);
    const size_t slash = out.find('/', start);
    const size_t colon = out.find(':', start);
    if (at != std::string::npos && (slash == std::string::npos || at < slash) &&
        colon != std::string::npos && colon < at) {
      out.replace(colon + 1, at - colon - 1, "***");
    }
  }
  // password=secret, in a URL's query (?password=...&...) or a key=value connection string.
  constexpr std::string_view kKey = "password=";
  for (size_t p = 0;;) {
    std::string lower = out;
    for (char& c : lower) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    p = lower.find(kKey, p);
    if (p == std::string::npos) break;
    const size_t value = p + kKey.size();
    size_t end = out.find_first_of("& ", value);
    if (end == std::string::npos) end = out.size();
    out.replace(value, end - value, "***");
    p = value + 3;
  }
  return out;
}

absl::Status CheckLocation(std::string_view location) {
  if (IsPostgresUrl(location)) return absl::OkStatus();
  std::string lower(location.substr(0, std::min<size_t>(location.size(), 16)));
  for (char& c : lower) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (location.find("://") == std::string_view::npos && !lower.starts_with("postgres"))
    return absl::OkStatus();
  return absl::InvalidArgumentError(Cat("'", RedactedLocation(location),
                                        "' is neither a SQLite file path nor a PostgreSQL URL "
                                        "(postgresql://USER[:PASSWORD]@HOST[:PORT]/DB)"));
}

absl::Status FromDatabase(absl::Status status) {
  if (!status.ok()) status.SetPayload(kDatabaseErrorPayload, absl::Cord("1"));
  return status;
}

bool IsFromDatabase(const absl::Status& status) {
  return status.GetPayload(kDatabaseErrorPayload).has_value();
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

}  // namespace imucal::sql
