// API tokens: bearer secrets, each with a role, stored as the SHA-256 of the secret (schema
// migration 3). The secret itself is returned once, by Create, and never stored.
//
// A secret is "imucal_" followed by 64 hex digits: 256 bits from OpenSSL's RAND_bytes (the
// prefix lets secret scanners and people recognise one). Because the secret is uniformly random
// and long, its plain SHA-256 is as hard to invert as guessing the secret; no salt or slow KDF
// is needed (those protect low-entropy passwords), and a lookup is one index probe.
//
// Roles (server/auth.cc says which RPCs each may call):
//   robot       bound to one device: streams its samples, fetches its parameters
//   technician  sessions, guide, solve, report, parameter versions; reads devices
//   admin       everything a technician may, plus registering devices and managing tokens
//
// Threads: a TokenStore is safe to share; its calls are serialised on one connection of its own
// (tokens change rarely, and the server caches lookups). Writes are BEGIN IMMEDIATE
// transactions, so they interleave safely with a Store's on the same file; each writes its
// audit_log row in the same transaction.
#ifndef IMUCAL_STORAGE_TOKENS_H_
#define IMUCAL_STORAGE_TOKENS_H_

#include <array>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"

namespace imucal::sql {
class Connection;  // util/db.h
}  // namespace imucal::sql

namespace imucal::storage {

enum class Role { kRobot, kTechnician, kAdmin };
std::string_view RoleName(Role role);  // "robot", "technician", "admin"
absl::StatusOr<Role> ParseRole(std::string_view name);

// SHA-256 of a token's secret: what the table stores and the server's cache is keyed by.
using TokenHash = std::array<unsigned char, 32>;
TokenHash HashTokenSecret(std::string_view secret);

struct Token {
  int64_t id = 0;  // assigned by the store: 1, 2, 3, ...
  Role role = Role::kRobot;
  std::string device_id;  // robot tokens: the device they act for; empty for the other roles
  std::string label;      // who or what holds it ("line-3 laptop"), free text
  absl::Time created_at;
  std::optional<absl::Time> revoked_at;  // set once revoked; a revoked token authenticates nothing
  bool revoked() const { return revoked_at.has_value(); }
};

// A token just created, with its secret: shown to its holder once.
struct NewToken {
  Token token;
  std::string secret;
};

// Audit targets of tokens: "token:<id>".
std::string TokenTarget(int64_t id);

class TokenStore {
 public:
  // Opens `path` (creating it if needed) and applies pending migrations, as Store::Open does;
  // both may be open on the same file at once.
  static absl::StatusOr<std::unique_ptr<TokenStore>> Open(
      const std::string& path, absl::Duration busy_timeout = absl::Seconds(5));
  ~TokenStore();
  TokenStore(const TokenStore&) = delete;
  TokenStore& operator=(const TokenStore&) = delete;

  // A new token. InvalidArgument naming the field: a robot token needs a device_id
  // ([A-Za-z0-9._-]{1,64}), the other roles take none; a label is at most 256 printable
  // characters. Audited as "token.create" by `actor`.
  absl::StatusOr<NewToken> Create(Role role, std::string_view device_id, std::string_view label,
                                  std::string_view actor);
  // The first admin token, created only when no valid (unrevoked) admin token exists: on a new
  // database, or after every admin token was revoked (the way back in when the admin secrets
  // are lost). Checked and inserted in one transaction, so two servers starting on one file
  // make one. nullopt when there is a valid admin token.
  absl::StatusOr<std::optional<NewToken>> CreateFirstAdmin(std::string_view label,
                                                           std::string_view actor);
  // Every token, oldest first (revoked ones too when asked).
  absl::StatusOr<std::vector<Token>> List(bool include_revoked = true);
  // Revokes token `id` for good; NotFound for an unknown id. Revoking a revoked token again
  // returns it unchanged (not audited again). Audited as "token.revoke".
  absl::StatusOr<Token> Revoke(int64_t id, std::string_view actor);
  // The token whose secret hashes to `hash`, revoked or not (the caller tells them apart);
  // NotFound when there is none.
  absl::StatusOr<Token> Lookup(const TokenHash& hash);
  // Token `id`, revoked or not; NotFound when there is none (never was, or deleted).
  absl::StatusOr<Token> Get(int64_t id);

  // The tokens changed (created, revoked, edited or deleted, by any process: triggers log each
  // change to the table, schema migration 7) after change `after_id`, in the order logged, and
  // the last change read: pass it as after_id next time. after_id < 0: no tokens, only the
  // last change. A server reads this to honour what it did not do itself.
  struct Changes {
    std::vector<int64_t> token_ids;
    int64_t last_id = 0;
  };
  absl::StatusOr<Changes> ChangesSince(int64_t after_id);

 private:
  explicit TokenStore(std::unique_ptr<sql::Connection> conn);
  absl::StatusOr<NewToken> InsertLocked(Role role, std::string_view device_id,
                                        std::string_view label, std::string_view actor);

  std::mutex mu_;
  std::unique_ptr<sql::Connection> conn_;  // guarded by mu_
};

}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_TOKENS_H_
