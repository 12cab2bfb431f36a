// Who may do what: the bearer-token check every imucald RPC makes before it does anything.
//
// Authentication. A call carries `authorization: Bearer <secret>` (the SDK and the CLI send it
// as gRPC call credentials, which gRPC sends only over TLS). The secret's SHA-256 names a row
// of the token table (storage/tokens.h). No token, a malformed header, an unknown or a revoked
// token: UNAUTHENTICATED. A robot may instead present a client certificate signed by the
// server's client CA (ServerOptions::client_ca_path): its common name is the device it acts
// for, as a robot token's device is. When a call has both, the token decides, and a robot
// token for another device than the certificate's is PERMISSION_DENIED.
//
// Authorisation. kRpcRules (auth.cc) is the one table of which role may call which RPC; robots
// are confined to their own device: the handler names the device a call touches (the request's
// device, or the session's) and a robot token bound to another one gets PERMISSION_DENIED. The
// health service and reflection are not checked (they tell nothing about the fleet).
//
// Cost. The hot path (GetActiveParameters) hashes the secret (SHA-256, about a microsecond)
// and finds the principal in an in-memory cache keyed by that hash, under a shared lock; the
// token table is read only on a miss. Revoking through the server drops the token's entries at
// once, remembers the id (a lookup that read the table just before the revocation cannot put
// it back), and ends the calls still open with it (the revocation listener: the server's open
// streams and watches). A change made elsewhere (another server sharing the database, a tool,
// SQL typed by hand) reaches TokenChanged through the server's TokenWatch (server/
// token_watch.h) within about a second, which does the same; an entry also expires after
// `cache_ttl`, the bound if that watch could not read the database (streams check their token
// at every batch).
// Unknown secrets are remembered too (a bounded set), so a client retrying a bad token does
// not read the table on every call.
//
// Audit. Every denial is recorded in the audit log (action "auth.deny", target "rpc:<method>",
// the actor naming the token id, the detail the code and the reason), coalesced so that a flood
// cannot fill the log: per (caller, method, code) at most one row per DenialAuditLimits::window,
// and at most `rows_per_s` rows a second overall (a token bucket of `burst`). The caller is the
// token ("token:7", revoked ones too), the device of a client certificate, "bad-token" for any
// secret that is not a valid token, or "no-credentials": a flood of random secrets is one
// caller. A row says how many like denials were coalesced before it; the counts still pending
// are written when the Authorizer is destroyed (server shutdown). So a flood writes at most
// one row per key and window, and never more than `burst` + `rows_per_s` x seconds rows.
//
// Insecure mode (a plaintext loopback listener, ServerOptions::insecure): there are no
// credentials to check; every call acts as the local admin "insecure-local". Only the loopback
// interface can reach such a server (Server::Start refuses anything else).
#ifndef IMUCAL_SERVER_AUTH_H_
#define IMUCAL_SERVER_AUTH_H_

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <shared_mutex>
#include <span>
#include <string>
#include <string_view>
#include <tuple>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/container/flat_hash_set.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "grpcpp/grpcpp.h"
#include "storage/store.h"
#include "storage/tokens.h"

namespace imucal::server {

// Every RPC of imucal.v1 (the index into kRpcRules).
enum class Rpc {
  kRegisterDevice,
  kGetDevice,
  kListDevices,
  kCreateSession,
  kGetSession,
  kListSessions,
  kCancelSession,
  kStreamSamples,
  kWatchSession,
  kListPoses,
  kSolveSession,
  kGetSolveJob,
  kGetReport,
  kReadSamples,
  kGetActiveParameters,
  kGetParameters,
  kListVersions,
  kPromote,
  kRollback,
  kExport,
  kUploadParameters,
  kCreateToken,
  kListTokens,
  kRevokeToken,
  kCount,
};

// One row of the table: the RPC, its gRPC method name, and which roles may call it. A robot is
// only ever allowed for its own device (`robot` true means "for the device its token is bound
// to"; the handler checks the device).
struct RpcRule {
  Rpc rpc;
  std::string_view method;  // "/imucal.v1.DeviceService/RegisterDevice"
  bool robot;
  bool technician;
  bool admin;
  std::string_view why;  // the reason for the row, shown in the matrix test's log
};

// The table, in Rpc order.
std::span<const RpcRule> RpcRules();
const RpcRule& RuleOf(Rpc rpc);
bool RoleMayCall(storage::Role role, Rpc rpc);
// OK when the table has exactly one row per method of the imucal.v1 services, in Rpc order
// (Server::Start checks this: a new RPC cannot be served without a row).
absl::Status CheckRulesCoverServices();

// The authenticated caller of one call.
struct Principal {
  int64_t token_id = 0;  // 0: no token (a client certificate, or insecure mode)
  storage::Role role = storage::Role::kRobot;
  std::string device_id;  // robots: the one device they act for
  std::string actor;      // for the audit log, e.g. "technician token 3 (line-3 laptop)"
};
using PrincipalRef = std::shared_ptr<const Principal>;

// How many audit rows denials may write (see the header comment).
struct DenialAuditLimits {
  absl::Duration window = absl::Seconds(60);  // one row per (caller, RPC, code) per window
  double rows_per_s = 10;                     // the token bucket's rate...
  double burst = 100;                         // ...and size, over all callers
};

struct AuthorizerOptions {
  // false: insecure mode (no checks; every caller is the local admin "insecure-local").
  bool enforce = true;
  // The listener verifies client certificates (a client CA is configured): a robot may then
  // authenticate with one instead of a token.
  bool client_certificates = false;
  absl::Duration cache_ttl = absl::Seconds(30);
  size_t max_unknown_cached = 4096;  // unknown secrets remembered; cleared when full
  DenialAuditLimits deny_audit;
};

class Authorizer {
 public:
  // `store` (audit) and `tokens` outlive the Authorizer; `tokens` may be null when !enforce.
  Authorizer(storage::Store* store, storage::TokenStore* tokens, AuthorizerOptions options = {});
  ~Authorizer();  // writes the suppressed-denial counts still pending
  Authorizer(const Authorizer&) = delete;
  Authorizer& operator=(const Authorizer&) = delete;

  // The caller of `context`, if it is authenticated and its role may call `rpc`:
  // UNAUTHENTICATED / PERMISSION_DENIED otherwise (audited). A robot still has to pass
  // AuthorizeDevice for the device the call touches.
  absl::StatusOr<PrincipalRef> Authorize(const grpc::ServerContextBase& context, Rpc rpc);
  // OK for a technician or admin; for a robot, OK only when `device_id` is its own (audited
  // PERMISSION_DENIED otherwise).
  absl::Status AuthorizeDevice(const grpc::ServerContextBase& context, const Principal& who,
                               Rpc rpc, std::string_view device_id);
  // Both, for calls whose request names the device.
  absl::StatusOr<PrincipalRef> AuthorizeForDevice(const grpc::ServerContextBase& context, Rpc rpc,
                                                  std::string_view device_id);

  // Token management through the cache: Revoke drops the token's cached entries before it
  // returns, so the next call with it is UNAUTHENTICATED. FailedPrecondition in insecure mode
  // (there is no token table to manage).
  absl::StatusOr<storage::NewToken> CreateToken(storage::Role role, std::string_view device_id,
                                                std::string_view label, std::string_view actor);
  absl::StatusOr<storage::Token> RevokeToken(int64_t id, std::string_view actor);
  // Called by RevokeToken, after the revocation is stored, with the token's id and why: the
  // server ends the calls still open with it. Set once, before the server serves.
  void SetRevocationListener(std::function<void(int64_t id, const std::string& why)> listener) {
    on_revoke_ = std::move(listener);
  }
  absl::StatusOr<std::vector<storage::Token>> ListTokens(bool include_revoked);
  // Token `id` was changed by someone else (TokenWatch): it is read again and, revoked or
  // deleted, handled as RevokeToken handles it (cache, revocation listener); otherwise its
  // cached entries are dropped, to be read again. Reads the table: not on an RPC thread.
  void TokenChanged(int64_t id);
  // Drops every cached token (changes may have been missed): the next call reads the table.
  void ForgetCachedTokens();

  // Audit rows written for denials so far, and denials suppressed (coalesced) so far.
  int64_t denial_rows_written() const;
  int64_t denials_suppressed() const;

 private:
  struct CacheEntry {
    PrincipalRef principal;  // null: the token is revoked
    int64_t revoked_id = 0;
    std::string revoked_reason;
    absl::Time expires;
  };
  // Who a denial is logged under.
  struct Caller {
    std::string key;    // "token:7", "cert:robot-3", "bad-token", "no-credentials"
    std::string actor;  // the audit row's actor
  };
  struct DenyState {
    absl::Time window_start;
    int64_t suppressed = 0;
    std::string actor;
    std::string last_reason;
  };

  // On failure, *caller says who was refused.
  absl::StatusOr<PrincipalRef> Authenticate(const grpc::ServerContextBase& context, Caller* caller);
  // *revoked_id: the id of a revoked token (0 otherwise).
  absl::StatusOr<PrincipalRef> FromToken(std::string_view secret, int64_t* revoked_id);
  absl::StatusOr<PrincipalRef> FromClientCertificate(const grpc::ServerContextBase& context);
  // Records a denial (coalesced, see the header comment) and returns it.
  absl::Status Deny(Caller caller, Rpc rpc, absl::Status denial);
  static Caller CallerOf(const Principal& who);
  void WriteDenialRow(const std::string& actor, Rpc rpc, const absl::Status& denial,
                      int64_t suppressed_before);

  storage::Store* store_;
  storage::TokenStore* tokens_;
  AuthorizerOptions options_;
  PrincipalRef insecure_principal_;

  std::function<void(int64_t id, const std::string& why)> on_revoke_;

  std::shared_mutex cache_mu_;
  absl::flat_hash_map<std::string, CacheEntry> cache_;  // by SHA-256; guarded by cache_mu_
  absl::flat_hash_map<std::string, bool> unknown_;      // hashes of unknown secrets; cache_mu_
  // Tokens revoked through this server (ids: a few per revocation ever made); cache_mu_.
  absl::flat_hash_set<int64_t> revoked_ids_;

  mutable std::mutex deny_mu_;
  // (caller key, rpc, code) -> its coalescing state; guarded by deny_mu_. Bounded: callers are
  // tokens (a table row each), device certificates, "bad-token" and "no-credentials".
  std::map<std::tuple<std::string, int, int>, DenyState> deny_;
  double deny_tokens_;              // the token bucket; guarded by deny_mu_
  absl::Time deny_refilled_at_;     // guarded by deny_mu_
  int64_t denial_rows_ = 0;         // guarded by deny_mu_
  int64_t denials_suppressed_ = 0;  // guarded by deny_mu_
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_AUTH_H_
