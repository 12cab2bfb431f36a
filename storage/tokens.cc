#include "storage/tokens.h"

#include <openssl/evp.h>
#include <openssl/rand.h>

#include <regex>
#include <utility>

#include "storage/migrations.h"
#include "storage/pg_db.h"
#include "storage/status_macros.h"
#include "storage/store_internal.h"
#include "storage/types.h"
#include "util/sqlite_db.h"
#include "util/str_util.h"
#include "util/text_check.h"

namespace imucal::storage {
namespace {

constexpr char kSecretPrefix[] = "imucal_";
constexpr size_t kSecretBytes = 32;  // 256 bits
constexpr size_t kMaxLabel = 256;

constexpr char kInsertToken[] =
    "INSERT INTO tokens (secret_sha256, role, device_id, label, created_at_us) "
    "VALUES (?1, ?2, ?3, ?4, ?5) RETURNING id";
constexpr char kSelectTokenById[] =
    "SELECT id, role, device_id, label, created_at_us, revoked_at_us FROM tokens WHERE id = ?1";
constexpr char kSelectTokenByHash[] =
    "SELECT id, role, device_id, label, created_at_us, revoked_at_us FROM tokens "
    "WHERE secret_sha256 = ?1";
constexpr char kSelectTokens[] =
    "SELECT id, role, device_id, label, created_at_us, revoked_at_us FROM tokens "
    "WHERE ?1 <> 0 OR revoked_at_us IS NULL ORDER BY id";
constexpr char kCountValidAdmins[] =
    "SELECT COUNT(*) FROM tokens WHERE role = 'admin' AND revoked_at_us IS NULL";
constexpr char kSelectTokenChanges[] =
    "SELECT id, token_id FROM token_changes WHERE id > ?1 ORDER BY id LIMIT 1000";
constexpr char kSelectLastTokenChange[] = "SELECT COALESCE(MAX(id), 0) FROM token_changes";
constexpr char kRevokeToken[] =
    "UPDATE tokens SET revoked_at_us = ?2 WHERE id = ?1 AND revoked_at_us IS NULL";

// Now, to the microsecond as stored, so that a returned token equals the one read back.
absl::Time Now() { return absl::FromUnixMicros(Micros(absl::Now())); }

absl::StatusOr<Token> ReadToken(const sql::Statement& st) {
  Token t;
  t.id = st.ColumnInt64(0);
  absl::StatusOr<Role> role = ParseRole(st.ColumnText(1));
  if (!role.ok()) return absl::DataLossError(Cat("token ", t.id, ": ", role.status().message()));
  t.role = *role;
  t.device_id = st.ColumnText(2);
  t.label = st.ColumnText(3);
  t.created_at = absl::FromUnixMicros(st.ColumnInt64(4));
  if (!st.ColumnIsNull(5)) t.revoked_at = absl::FromUnixMicros(st.ColumnInt64(5));
  return t;
}

absl::Status ValidateNewToken(Role role, std::string_view device_id, std::string_view label) {
  static const std::regex kDeviceId("[A-Za-z0-9._-]{1,64}");
  if (role == Role::kRobot) {
    if (!std::regex_match(device_id.begin(), device_id.end(), kDeviceId))
      return absl::InvalidArgumentError(
          "device_id: a robot token is bound to one device; must match [A-Za-z0-9._-]{1,64}");
  } else if (!device_id.empty()) {
    return absl::InvalidArgumentError(
        Cat("device_id: only robot tokens are bound to a device, not ", RoleName(role), " tokens"));
  }
  if (label.size() > kMaxLabel)
    return absl::InvalidArgumentError(Cat("label: at most ", kMaxLabel, " characters"));
  // Shown in `imucal admin token list` and the audit's actor: no control character, C0 or C1.
  if (std::optional<UnreadableChar> bad = FindUnreadableChar(label))
    return absl::InvalidArgumentError(bad->Message("label"));
  return absl::OkStatus();
}

absl::StatusOr<std::string> NewSecret() {
  unsigned char bytes[kSecretBytes];
  if (RAND_bytes(bytes, sizeof bytes) != 1)
    return absl::UnavailableError("the random generator failed (OpenSSL RAND_bytes)");
  static constexpr char kHex[] = "0123456789abcdef";
  std::string secret = kSecretPrefix;
  for (unsigned char b : bytes) {
    secret.push_back(kHex[b >> 4]);
    secret.push_back(kHex[b & 15]);
  }
  return secret;
}

std::string_view HashView(const TokenHash& hash) {
  return std::string_view(reinterpret_cast<const char*>(hash.data()), hash.size());
}

// The audit entry of a change to token `token_id`, in the change's transaction.
absl::Status AuditToken(sql::Connection& conn, std::string_view actor, std::string_view action,
                        int64_t token_id, std::string_view detail) {
  return InsertAudit(conn, absl::Now(), actor, action, TokenTarget(token_id), detail);
}

absl::StatusOr<Token> SelectById(sql::Connection& conn, int64_t id) {
  IMUCAL_ASSIGN_OR_RETURN(std::optional<Token> token,
                          sql::ReadRow(conn, kSelectTokenById, ReadToken, id));
  if (!token) return absl::NotFoundError(Cat("token ", id, " does not exist"));
  return *std::move(token);
}

}  // namespace

std::string_view RoleName(Role role) {
  switch (role) {
    case Role::kRobot:
      return "robot";
    case Role::kTechnician:
      return "technician";
    case Role::kAdmin:
      return "admin";
  }
  return "unknown";
}

absl::StatusOr<Role> ParseRole(std::string_view name) {
  if (name == "robot") return Role::kRobot;
  if (name == "technician") return Role::kTechnician;
  if (name == "admin") return Role::kAdmin;
  return absl::InvalidArgumentError(Cat("role: '", name, "' is not robot, technician or admin"));
}

TokenHash HashTokenSecret(std::string_view secret) {
  TokenHash hash{};
  unsigned int size = 0;
  // EVP_Digest with SHA-256 cannot fail on a valid buffer; a zero hash would match no row.
  EVP_Digest(secret.data(), secret.size(), hash.data(), &size, EVP_sha256(), nullptr);
  return hash;
}

std::string TokenTarget(int64_t id) { return Cat("token:", id); }

TokenStore::TokenStore(std::unique_ptr<sql::Connection> conn) : conn_(std::move(conn)) {}
TokenStore::~TokenStore() = default;

absl::StatusOr<std::unique_ptr<TokenStore>> TokenStore::Open(const std::string& path,
                                                             absl::Duration busy_timeout) {
  sql::ConnectionOptions options;
  options.busy_timeout = busy_timeout;
  const std::string op = Cat("open tokens of ", sql::RedactedLocation(path));
  if (absl::Status s = sql::CheckLocation(path); !s.ok()) return s;
  std::unique_ptr<sql::Connection> conn;
  if (sql::IsPostgresUrl(path)) {
    absl::StatusOr<std::unique_ptr<PgConnection>> pg = PgConnection::Open(path, options);
    if (!pg.ok()) return Annotate(op, pg.status());
    conn = *std::move(pg);
  } else {
    absl::StatusOr<std::unique_ptr<sql::SqliteConnection>> lite =
        sql::SqliteConnection::Open(path, options);
    if (!lite.ok()) return Annotate(op, lite.status());
    // WAL, as Store::Open sets it (a property of the file), so that readers never block a write.
    if (absl::Status s = (*lite)->Exec("PRAGMA journal_mode = WAL"); !s.ok())
      return Annotate(op, s);
    conn = *std::move(lite);
  }
  if (absl::Status s = Migrate(*conn); !s.ok()) return Annotate(op, s);
  return std::unique_ptr<TokenStore>(new TokenStore(std::move(conn)));
}

absl::StatusOr<NewToken> TokenStore::InsertLocked(Role role, std::string_view device_id,
                                                  std::string_view label, std::string_view actor) {
  IMUCAL_RETURN_IF_ERROR(ValidateNewToken(role, device_id, label));
  IMUCAL_ASSIGN_OR_RETURN(std::string secret, NewSecret());
  NewToken out;
  out.token.role = role;
  out.token.device_id = std::string(device_id);
  out.token.label = std::string(label);
  out.token.created_at = Now();
  std::optional<std::string_view> bound_device;  // NULL for the roles bound to no device
  if (role == Role::kRobot) bound_device = device_id;
  IMUCAL_ASSIGN_OR_RETURN(
      std::optional<int64_t> id,
      sql::ReadRow(*conn_, kInsertToken, sql::FirstColumnInt64,
                   sql::SqlBlob{HashView(HashTokenSecret(secret))}, RoleName(role), bound_device,
                   label, Micros(out.token.created_at)));
  if (!id) return absl::InternalError("INSERT ... RETURNING id returned no row");
  out.token.id = *id;
  std::string detail = Cat("role ", RoleName(role));
  if (role == Role::kRobot) AppendTo(&detail, ", device ", device_id);
  if (!label.empty()) AppendTo(&detail, ", label '", label, "'");
  IMUCAL_RETURN_IF_ERROR(AuditToken(*conn_, actor, "token.create", out.token.id, detail));
  out.secret = std::move(secret);
  return out;
}

absl::StatusOr<NewToken> TokenStore::Create(Role role, std::string_view device_id,
                                            std::string_view label, std::string_view actor) {
  std::lock_guard lock(mu_);
  return InTransaction("CreateToken", *conn_, [&](sql::Connection&) {
    return InsertLocked(role, device_id, label, actor);
  });
}

absl::StatusOr<std::optional<NewToken>> TokenStore::CreateFirstAdmin(std::string_view label,
                                                                     std::string_view actor) {
  std::lock_guard lock(mu_);
  return InTransaction(
      "CreateFirstAdmin", *conn_,
      [&](sql::Connection& conn) -> absl::StatusOr<std::optional<NewToken>> {
        IMUCAL_ASSIGN_OR_RETURN(std::optional<int64_t> count,
                                sql::ReadRow(conn, kCountValidAdmins, sql::FirstColumnInt64));
        if (count.value_or(0) > 0) return std::nullopt;
        IMUCAL_ASSIGN_OR_RETURN(NewToken created, InsertLocked(Role::kAdmin, "", label, actor));
        return created;
      });
}

absl::StatusOr<std::vector<Token>> TokenStore::List(bool include_revoked) {
  std::lock_guard lock(mu_);
  return Annotate("ListTokens", sql::ReadRows(*conn_, kSelectTokens, ReadToken, include_revoked));
}

absl::StatusOr<Token> TokenStore::Revoke(int64_t id, std::string_view actor) {
  std::lock_guard lock(mu_);
  return InTransaction("RevokeToken", *conn_, [&](sql::Connection& conn) -> absl::StatusOr<Token> {
    IMUCAL_ASSIGN_OR_RETURN(Token token, SelectById(conn, id));
    if (token.revoked()) return token;  // already revoked: nothing to do or to audit
    token.revoked_at = Now();
    IMUCAL_RETURN_IF_ERROR(sql::RunStatement(conn, kRevokeToken, id, Micros(*token.revoked_at)));
    std::string detail = Cat("role ", RoleName(token.role));
    if (token.role == Role::kRobot) AppendTo(&detail, ", device ", token.device_id);
    IMUCAL_RETURN_IF_ERROR(AuditToken(conn, actor, "token.revoke", id, detail));
    return token;
  });
}

absl::StatusOr<Token> TokenStore::Lookup(const TokenHash& hash) {
  std::lock_guard lock(mu_);
  IMUCAL_ASSIGN_OR_RETURN(
      std::optional<Token> token,
      Annotate("LookupToken",
               sql::ReadRow(*conn_, kSelectTokenByHash, ReadToken, sql::SqlBlob{HashView(hash)})));
  if (!token) return absl::NotFoundError("no such token");
  return *std::move(token);
}

absl::StatusOr<Token> TokenStore::Get(int64_t id) {
  std::lock_guard lock(mu_);
  return Annotate("GetToken", SelectById(*conn_, id));
}

absl::StatusOr<TokenStore::Changes> TokenStore::ChangesSince(int64_t after_id) {
  std::lock_guard lock(mu_);
  Changes out;
  out.last_id = after_id;
  if (after_id < 0) {
    IMUCAL_ASSIGN_OR_RETURN(std::optional<int64_t> last,
                            Annotate("TokenChanges", sql::ReadRow(*conn_, kSelectLastTokenChange,
                                                                  sql::FirstColumnInt64)));
    out.last_id = last.value_or(0);
    return out;
  }
  struct Change {
    int64_t id = 0;
    int64_t token_id = 0;
  };
  IMUCAL_ASSIGN_OR_RETURN(
      std::vector<Change> changes,
      Annotate("TokenChanges", sql::ReadRows(
                                   *conn_, kSelectTokenChanges,
                                   [](const sql::Statement& st) -> absl::StatusOr<Change> {
                                     return Change{st.ColumnInt64(0), st.ColumnInt64(1)};
                                   },
                                   after_id)));
  for (const Change& c : changes) {
    out.token_ids.push_back(c.token_id);
    out.last_id = c.id;
  }
  return out;
}

}  // namespace imucal::storage
