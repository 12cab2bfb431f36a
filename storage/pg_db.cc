#include "storage/pg_db.h"

#include <libpq-fe.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include <bit>
#include <charconv>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <type_traits>
#include <cctype>
#include <vector>

#include "util/str_util.h"

namespace imucal::storage {
namespace {

// Type OIDs (PostgreSQL's pg_type.dat; stable across versions).
constexpr Oid kBoolOid = 16;
constexpr Oid kByteaOid = 17;
constexpr Oid kInt8Oid = 20;
constexpr Oid kInt2Oid = 21;
constexpr Oid kInt4Oid = 23;
constexpr Oid kFloat4Oid = 700;
constexpr Oid kFloat8Oid = 701;
constexpr Oid kTextOid = 25;

// The store's ?N parameters as $N, outside quoted text and names.
absl::StatusOr<std::string> DollarParameters(std::string_view sql) {
  std::string out;
  out.reserve(sql.size());
  char quote = 0;
  for (size_t i = 0; i < sql.size(); ++i) {
    const char c = sql[i];
    if (quote != 0) {
      if (c == quote) quote = 0;
      out += c;
      continue;
    }
    if (c == '\'' || c == '"') {
      quote = c;
    } else if (c == '?') {
      if (i + 1 >= sql.size() || sql[i + 1] < '0' || sql[i + 1] > '9') {
        return absl::InternalError(Cat("SQL for PostgreSQL: an unnumbered '?' in: ", sql));
      }
      out += '$';
      continue;
    }
    out += c;
  }
  return out;
}

// Big-endian integers of a binary result.
template <typename T>
T ReadBig(const char* p) {
  using U = std::make_unsigned_t<T>;
  U v = 0;
  for (size_t i = 0; i < sizeof(T); ++i) v = static_cast<U>((v << 8) | static_cast<unsigned char>(p[i]));
  return static_cast<T>(v);
}

std::string_view StripTrailingNewline(std::string_view message) {
  while (!message.empty() && (message.back() == '\n' || message.back() == ' ')) message.remove_suffix(1);
  return message;
}

enum class Kind { kBegin, kCommit, kRollback, kOther };

Kind KindOf(std::string_view sql) {
  if (sql.starts_with("BEGIN")) return Kind::kBegin;
  if (sql == "COMMIT") return Kind::kCommit;
  if (sql == "ROLLBACK") return Kind::kRollback;
  return Kind::kOther;
}

struct ResultDeleter {
  void operator()(PGresult* r) const { PQclear(r); }
};
using Result = std::unique_ptr<PGresult, ResultDeleter>;

class PgStatement final : public sql::Statement {
 public:
  PgStatement(PgConnection* conn, std::string sql, Kind kind)
      : conn_(conn), sql_(std::move(sql)), kind_(kind) {}

  void BindInt64(int index, int64_t value) override {
    if (Param* p = At(index)) *p = Param{std::to_string(value), kInt8Oid, 0, false};
  }
  void BindDouble(int index, double value) override {
    if (std::isnan(value)) return BindNull(index);
    Param* p = At(index);
    if (p == nullptr) return;
    std::string text;
    if (std::isinf(value)) {
      text = value > 0 ? "Infinity" : "-Infinity";
    } else {
      char buf[32];
      const auto [end, ec] = std::to_chars(buf, buf + sizeof buf, value);  // shortest exact
      text.assign(buf, end);
    }
    *p = Param{std::move(text), kFloat8Oid, 0, false};
  }
  void BindText(int index, std::string_view value) override {
    if (value.find('\0') != std::string_view::npos) {
      NoteBindError(absl::InvalidArgumentError(
          Cat("parameter ", index, ": PostgreSQL text cannot hold a NUL byte")));
      return;
    }
    if (Param* p = At(index)) *p = Param{std::string(value), kTextOid, 0, false};
  }
  void BindBlob(int index, std::string_view value) override {
    if (Param* p = At(index)) *p = Param{std::string(value), kByteaOid, 1, false};
  }
  void BindNull(int index) override {
    if (Param* p = At(index)) *p = Param{std::string(), 0, 0, true};
  }

  absl::StatusOr<bool> Step() override {
    if (!bind_error_.ok()) return bind_error_;
    if (!result_) {
      absl::Status s = Execute();
      if (!s.ok()) return s;
      row_ = -1;
    }
    ++row_;
    return row_ < PQntuples(result_.get());
  }

  int64_t ColumnInt64(int column) const override {
    if (ColumnIsNull(column)) return 0;
    const char* v = PQgetvalue(result_.get(), row_, column);
    switch (PQftype(result_.get(), column)) {
      case kInt8Oid:
        return ReadBig<int64_t>(v);
      case kInt4Oid:
        return ReadBig<int32_t>(v);
      case kInt2Oid:
        return ReadBig<int16_t>(v);
      case kBoolOid:
        return v[0] != 0 ? 1 : 0;
      case kFloat4Oid:
      case kFloat8Oid:
        return static_cast<int64_t>(ColumnDouble(column));
      default:
        return std::strtoll(ColumnText(column).c_str(), nullptr, 10);
    }
  }
  double ColumnDouble(int column) const override {
    if (ColumnIsNull(column)) return std::numeric_limits<double>::quiet_NaN();
    const char* v = PQgetvalue(result_.get(), row_, column);
    switch (PQftype(result_.get(), column)) {
      case kFloat8Oid:
        return std::bit_cast<double>(ReadBig<uint64_t>(v));
      case kFloat4Oid:
        return std::bit_cast<float>(ReadBig<uint32_t>(v));
      case kInt8Oid:
      case kInt4Oid:
      case kInt2Oid:
      case kBoolOid:
        return static_cast<double>(ColumnInt64(column));
      default:
        return std::strtod(ColumnText(column).c_str(), nullptr);
    }
  }
  std::string ColumnText(int column) const override {
    switch (PQftype(result_.get(), column)) {
      case kInt8Oid:
      case kInt4Oid:
      case kInt2Oid:
      case kBoolOid:
        return ColumnIsNull(column) ? std::string() : std::to_string(ColumnInt64(column));
      default:
        return std::string(ColumnBlobView(column));  // text-like types come as their bytes
    }
  }
  std::string_view ColumnBlobView(int column) const override {
    if (ColumnIsNull(column)) return std::string_view();
    return std::string_view(PQgetvalue(result_.get(), row_, column),
                            static_cast<size_t>(PQgetlength(result_.get(), row_, column)));
  }
  bool ColumnIsNull(int column) const override {
    return PQgetisnull(result_.get(), row_, column) != 0;
  }

  void Reset() override {
    result_.reset();
    params_.clear();
    bind_error_ = absl::OkStatus();
  }

 private:
  struct Param {
    std::string value;
    Oid type = 0;  // 0: the server infers it
    int format = 0;
    bool null = true;
  };

  Param* At(int index) {
    if (index < 1 || index > 65535) {
      NoteBindError(absl::InvalidArgumentError(Cat("parameter index ", index, " out of range")));
      return nullptr;
    }
    if (params_.size() < static_cast<size_t>(index)) params_.resize(index);
    return &params_[index - 1];
  }
  void NoteBindError(absl::Status s) {
    if (bind_error_.ok()) bind_error_ = std::move(s);
  }

  // A server restart (or a failover) breaks every connection; the first statement after it
  // finds out. When running it again is safe (PgConnection::MayRetryAfterReconnect), it runs
  // once more on a new connection, so that the restart costs the caller nothing.
  absl::Status Execute() {
    absl::Status s = ExecuteOnce();
    if (!s.ok() && PQstatus(conn_->conn()) != CONNECTION_OK &&
        conn_->MayRetryAfterReconnect(kind_ == Kind::kBegin)) {
      s = ExecuteOnce();
    }
    return s;
  }

  absl::Status ExecuteOnce() {
    PGconn* pg = conn_->conn();
    if (kind_ == Kind::kRollback && PQstatus(pg) != CONNECTION_OK) {
      // The server rolled the transaction back when the connection broke.
      conn_->NoteTransactionEnded();
      return absl::OkStatus();
    }
    if (absl::Status s = conn_->EnsureConnected(); !s.ok()) return s;
    pg = conn_->conn();
    const int n = static_cast<int>(params_.size());
    if (name_.empty() || generation_ != conn_->generation()) {
      std::vector<Oid> types(n);
      for (int i = 0; i < n; ++i) types[i] = params_[i].type;
      std::string name = conn_->NextStatementName();
      Result prepared(PQprepare(pg, name.c_str(), sql_.c_str(), n, types.data()));
      if (absl::Status s = Check(prepared.get(), "prepare"); !s.ok()) return s;
      name_ = std::move(name);
      generation_ = conn_->generation();
    }
    std::vector<const char*> values(n);
    std::vector<int> lengths(n), formats(n);
    for (int i = 0; i < n; ++i) {
      values[i] = params_[i].null ? nullptr : params_[i].value.c_str();
      lengths[i] = static_cast<int>(params_[i].value.size());
      formats[i] = params_[i].format;
    }
    Result result(PQexecPrepared(pg, name_.c_str(), n, values.data(), lengths.data(),
                                 formats.data(), /*resultFormat=*/1));
    absl::Status s = Check(result.get(), "step");
    if (kind_ == Kind::kCommit || kind_ == Kind::kRollback) {
      if (s.ok() || PQtransactionStatus(pg) == PQTRANS_IDLE) conn_->NoteTransactionEnded();
    }
    if (!s.ok()) return s;
    if (kind_ == Kind::kBegin) conn_->NoteTransactionStarted();
    result_ = std::move(result);
    return absl::OkStatus();
  }

  absl::Status Check(const PGresult* r, std::string_view what) {
    const ExecStatusType st = r == nullptr ? PGRES_FATAL_ERROR : PQresultStatus(r);
    if (st == PGRES_COMMAND_OK || st == PGRES_TUPLES_OK) return absl::OkStatus();
    const char* sqlstate = r == nullptr ? nullptr : PQresultErrorField(r, PG_DIAG_SQLSTATE);
    // The primary message only: DETAIL and HINT speak of PostgreSQL's internals.
    const char* primary = r == nullptr ? nullptr : PQresultErrorField(r, PG_DIAG_MESSAGE_PRIMARY);
    const char* message = primary != nullptr ? primary : PQerrorMessage(conn_->conn());
    return conn_->StatementError(what, sqlstate, message);
  }

  PgConnection* conn_;
  const std::string sql_;  // with $N parameters
  const Kind kind_;
  std::string name_;  // the server-side prepared statement, empty until prepared
  uint64_t generation_ = 0;
  std::vector<Param> params_;
  absl::Status bind_error_;
  Result result_;
  int row_ = -1;
};

}  // namespace

absl::StatusCode PgCode(std::string_view sqlstate) {
  if (sqlstate == "23505") return absl::StatusCode::kAlreadyExists;
  if (sqlstate == "40001" || sqlstate == "40P01") return absl::StatusCode::kAborted;
  if (sqlstate == "55P03" || sqlstate == "57P01" || sqlstate == "57P02" || sqlstate == "57P03")
    return absl::StatusCode::kUnavailable;
  if (sqlstate == "57014") return absl::StatusCode::kCancelled;
  if (sqlstate == "XX001" || sqlstate == "XX002") return absl::StatusCode::kDataLoss;
  const std::string_view cls = sqlstate.substr(0, 2);
  if (cls == "23") return absl::StatusCode::kFailedPrecondition;
  if (cls == "08") return absl::StatusCode::kUnavailable;
  if (cls == "57") return absl::StatusCode::kUnavailable;  // admin shutdown, crash, cannot connect now
  if (cls == "53") return absl::StatusCode::kResourceExhausted;
  if (cls == "22") return absl::StatusCode::kInvalidArgument;
  return absl::StatusCode::kInternal;
}

absl::StatusOr<std::unique_ptr<PgConnection>> PgConnection::Open(
    const std::string& url, const sql::ConnectionOptions& options) {
  // dbname last: the URL's own settings override these defaults.
  const char* keywords[] = {"connect_timeout", "application_name", "dbname", nullptr};
  const char* values[] = {"10", "imucald", url.c_str(), nullptr};
  PGconn* pg = PQconnectdbParams(keywords, values, /*expand_dbname=*/1);
  if (pg == nullptr) return absl::ResourceExhaustedError("libpq could not allocate a connection");
  if (PQstatus(pg) != CONNECTION_OK) {
    absl::Status status = sql::FromDatabase(
        absl::UnavailableError(Cat("cannot connect to ", sql::RedactedLocation(url), ": ",
                                   StripTrailingNewline(PQerrorMessage(pg)))));
    PQfinish(pg);
    return status;
  }
  std::string settings = Cat(
      "SET lock_timeout = '", absl::ToInt64Milliseconds(options.busy_timeout),
      "ms'; SET synchronous_commit = on; SET client_min_messages = warning; SET TIME ZONE 'UTC';");
  if (options.read_only) settings += " SET default_transaction_read_only = on;";
  if (!options.origin.empty()) {
    for (char c : options.origin) {
      if (!std::isalnum(static_cast<unsigned char>(c))) {
        PQfinish(pg);
        return absl::InvalidArgumentError("origin: letters and digits only");
      }
    }
    settings += Cat(" SET imucal.origin = '", options.origin, "';");
  }
  std::unique_ptr<PgConnection> conn(new PgConnection(pg, std::move(settings), options.read_only));
  if (absl::Status s = conn->ApplySettings(); !s.ok()) return s;
  return conn;
}

PgConnection::~PgConnection() {
  ForgetStatements();
  PQfinish(conn_);
}

absl::Status PgConnection::ApplySettings() { return Exec(settings_.c_str()); }

bool PgConnection::InOpenTransaction() const { return txn_open_; }

void PgConnection::NoteTransactionStarted() {
  txn_open_ = true;
  txn_error_ = absl::OkStatus();
}

void PgConnection::NoteTransactionEnded() {
  txn_open_ = false;
  txn_error_ = absl::OkStatus();
}

absl::Status PgConnection::CommitBlocker() const {
  if (PQtransactionStatus(conn_) != PQTRANS_INERROR) return absl::OkStatus();
  if (!txn_error_.ok()) return txn_error_;
  return absl::AbortedError("an earlier statement of the transaction failed");
}

absl::Status PgConnection::EnsureConnected() {
  if (PQstatus(conn_) == CONNECTION_OK) return absl::OkStatus();
  if (txn_open_) {
    // Never carry on in autocommit what was meant to be one transaction.
    return sql::FromDatabase(
        absl::UnavailableError("the connection to PostgreSQL broke during a transaction"));
  }
  PQreset(conn_);
  if (PQstatus(conn_) != CONNECTION_OK) {
    return sql::FromDatabase(absl::UnavailableError(
        Cat("cannot reconnect to PostgreSQL: ", StripTrailingNewline(PQerrorMessage(conn_)))));
  }
  ++generation_;  // the server forgot every prepared statement
  return ApplySettings();
}

absl::Status PgConnection::StatementError(std::string_view context, const char* sqlstate,
                                          std::string_view message) {
  const std::string_view state = sqlstate != nullptr ? sqlstate : "";
  if (state == "25P02" && !txn_error_.ok()) return txn_error_;  // the transaction's real error
  absl::StatusCode code = PgCode(state);
  if (state.empty() && PQstatus(conn_) != CONNECTION_OK) code = absl::StatusCode::kUnavailable;
  absl::Status status =
      sql::FromDatabase(absl::Status(code, Cat(context, ": ", StripTrailingNewline(message))));
  if (txn_open_ && txn_error_.ok()) txn_error_ = status;
  return status;
}

std::string PgConnection::NextStatementName() { return Cat("imucal_", ++next_statement_); }

absl::Status PgConnection::Exec(const char* sql) {
  if (absl::Status s = EnsureConnected(); !s.ok()) return s;
  Result r(PQexec(conn_, sql));
  const ExecStatusType st = r == nullptr ? PGRES_FATAL_ERROR : PQresultStatus(r.get());
  if (st == PGRES_COMMAND_OK || st == PGRES_TUPLES_OK) return absl::OkStatus();
  const char* sqlstate = r == nullptr ? nullptr : PQresultErrorField(r.get(), PG_DIAG_SQLSTATE);
  return StatementError("exec", sqlstate,
                        r != nullptr ? PQresultErrorMessage(r.get()) : PQerrorMessage(conn_));
}

absl::StatusOr<std::unique_ptr<sql::Statement>> PgConnection::NewStatement(std::string_view sql) {
  absl::StatusOr<std::string> pg_sql = DollarParameters(sql);
  if (!pg_sql.ok()) return pg_sql.status();
  return std::unique_ptr<sql::Statement>(new PgStatement(this, *std::move(pg_sql), KindOf(sql)));
}

// ---- PgListener ------------------------------------------------------------------------------

absl::StatusOr<std::unique_ptr<PgListener>> PgListener::Start(const std::string& url,
                                                             std::vector<std::string> channels,
                                                             OnNotify on_notify,
                                                             std::function<void()> on_gap) {
  std::unique_ptr<PgListener> l(new PgListener());
  l->url_ = url;
  l->channels_ = std::move(channels);
  l->on_notify_ = std::move(on_notify);
  l->on_gap_ = std::move(on_gap);
  l->wake_fd_ = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  if (l->wake_fd_ < 0) return absl::InternalError(Cat("eventfd: ", std::strerror(errno)));
  if (absl::Status s = l->Connect(); !s.ok()) return s;  // the first time, the caller hears
  l->thread_ = std::thread([p = l.get()] { p->Run(); });
  return l;
}

PgListener::~PgListener() {
  stop_.store(true);
  if (wake_fd_ >= 0) {
    const uint64_t one = 1;
    (void)!::write(wake_fd_, &one, sizeof one);
  }
  if (thread_.joinable()) thread_.join();
  if (conn_ != nullptr) PQfinish(conn_);
  if (wake_fd_ >= 0) ::close(wake_fd_);
}

absl::Status PgListener::Connect() {
  if (conn_ != nullptr) PQfinish(conn_);
  const char* keywords[] = {"connect_timeout", "application_name", "dbname", nullptr};
  const char* values[] = {"10", "imucald-listener", url_.c_str(), nullptr};
  conn_ = PQconnectdbParams(keywords, values, /*expand_dbname=*/1);
  if (conn_ == nullptr || PQstatus(conn_) != CONNECTION_OK) {
    return sql::FromDatabase(
        absl::UnavailableError(Cat("listen: cannot connect to ", sql::RedactedLocation(url_), ": ",
                                   StripTrailingNewline(conn_ ? PQerrorMessage(conn_) : ""))));
  }
  std::string sql;
  for (const std::string& channel : channels_) {
    char* quoted = PQescapeIdentifier(conn_, channel.c_str(), channel.size());
    if (quoted == nullptr) return absl::InternalError("listen: cannot quote the channel name");
    sql += Cat("LISTEN ", quoted, ";");
    PQfreemem(quoted);
  }
  Result r(PQexec(conn_, sql.c_str()));
  if (r == nullptr || PQresultStatus(r.get()) != PGRES_COMMAND_OK) {
    return sql::FromDatabase(
        absl::UnavailableError(Cat("listen: ", StripTrailingNewline(PQerrorMessage(conn_)))));
  }
  return absl::OkStatus();
}

void PgListener::Run() {
  bool listening = true;
  while (!stop_.load()) {
    if (!listening) {
      // Every second until the server answers again; then whatever was missed is a gap.
      pollfd wake{wake_fd_, POLLIN, 0};
      if (::poll(&wake, 1, 1000) > 0 || stop_.load()) return;
      if (!Connect().ok()) continue;
      listening = true;
      on_gap_();
      continue;
    }
    pollfd fds[2] = {{PQsocket(conn_), POLLIN, 0}, {wake_fd_, POLLIN, 0}};
    if (::poll(fds, 2, 1000) < 0 && errno != EINTR) continue;
    if (stop_.load() || (fds[1].revents & POLLIN) != 0) return;
    if (PQconsumeInput(conn_) == 0 || PQstatus(conn_) != CONNECTION_OK) {
      listening = false;
      on_gap_();
      continue;
    }
    while (PGnotify* n = PQnotifies(conn_)) {
      on_notify_(n->relname != nullptr ? std::string_view(n->relname) : std::string_view(),
                 n->extra != nullptr ? std::string_view(n->extra) : std::string_view());
      PQfreemem(n);
    }
  }
}

}  // namespace imucal::storage
