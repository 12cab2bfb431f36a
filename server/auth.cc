#include "server/auth.h"

#include <algorithm>
#include <regex>
#include <set>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "google/protobuf/descriptor.h"
#include "imucal/v1/imucal.pb.h"
#include "server/log.h"
#include "util/str_util.h"

namespace imucal::server {
namespace {

using storage::Role;

// Which role may call which RPC: {rpc, method, robot, technician, admin, why}. Robots only
// ever for the device their token or certificate is bound to; the handler names the device the
// call touches. README "Security" shows this table.
constexpr RpcRule kRpcRules[] = {
    {Rpc::kRegisterDevice, "/imucal.v1.DeviceService/RegisterDevice", true, false, true,
     "admin registers devices; a robot re-registers itself at every boot (its own id only)"},
    {Rpc::kGetDevice, "/imucal.v1.DeviceService/GetDevice", true, true, true,
     "technicians read devices; a robot reads its own (imucal upload checks the capture's "
     "units against it)"},
    {Rpc::kListDevices, "/imucal.v1.DeviceService/ListDevices", false, true, true,
     "technicians read devices"},
    {Rpc::kCreateSession, "/imucal.v1.SessionService/CreateSession", false, true, true,
     "the technician opens a session (guide, upload)"},
    {Rpc::kGetSession, "/imucal.v1.SessionService/GetSession", true, true, true,
     "a robot's uploader reads its session to resume"},
    {Rpc::kListSessions, "/imucal.v1.SessionService/ListSessions", true, true, true,
     "technicians list sessions; a robot lists its own device's (imucal upload joins the "
     "session the guide opened)"},
    {Rpc::kCancelSession, "/imucal.v1.SessionService/CancelSession", false, true, true,
     "sessions are the technician's"},
    {Rpc::kStreamSamples, "/imucal.v1.SessionService/StreamSamples", true, true, true,
     "a robot streams into its own sessions; a technician uploads a recorded capture"},
    {Rpc::kWatchSession, "/imucal.v1.SessionService/WatchSession", false, true, true,
     "the guide follows a session"},
    {Rpc::kListPoses, "/imucal.v1.SessionService/ListPoses", false, true, true,
     "the guide lists the poses"},
    {Rpc::kSolveSession, "/imucal.v1.SessionService/SolveSession", false, true, true,
     "the technician solves"},
    {Rpc::kGetSolveJob, "/imucal.v1.SessionService/GetSolveJob", false, true, true,
     "the technician follows the solve"},
    {Rpc::kGetReport, "/imucal.v1.SessionService/GetReport", false, true, true,
     "the technician reads the report"},
    {Rpc::kReadSamples, "/imucal.v1.SessionService/ReadSamples", false, true, true,
     "the technician analyses a session's stored samples (imucal noise --session), as the "
     "report; a robot has its own samples and resumes from GetSession"},
    {Rpc::kGetActiveParameters, "/imucal.v1.ParameterService/GetActiveParameters", true, true, true,
     "a robot fetches its own active parameters at startup (the hot path)"},
    {Rpc::kGetParameters, "/imucal.v1.ParameterService/GetParameters", true, true, true,
     "a robot may fetch a version of its own parameters"},
    {Rpc::kListVersions, "/imucal.v1.ParameterService/ListVersions", false, true, true,
     "the technician reviews versions"},
    {Rpc::kPromote, "/imucal.v1.ParameterService/Promote", false, true, true,
     "the technician decides which version is active"},
    {Rpc::kRollback, "/imucal.v1.ParameterService/Rollback", false, true, true,
     "the technician decides which version is active"},
    {Rpc::kExport, "/imucal.v1.ParameterService/Export", false, true, true,
     "the technician exports for other tools"},
    {Rpc::kUploadParameters, "/imucal.v1.ParameterService/UploadParameters", false, true, true,
     "the technician ships a parameter set made offline (imucal learn), as a new version"},
    {Rpc::kCreateToken, "/imucal.v1.AdminService/CreateToken", false, false, true,
     "tokens are the admin's"},
    {Rpc::kListTokens, "/imucal.v1.AdminService/ListTokens", false, false, true,
     "tokens are the admin's"},
    {Rpc::kRevokeToken, "/imucal.v1.AdminService/RevokeToken", false, false, true,
     "tokens are the admin's"},
};
static_assert(std::size(kRpcRules) == static_cast<size_t>(Rpc::kCount),
              "kRpcRules needs one row per Rpc");

constexpr char kSecretPrefix[] = "imucal_";
constexpr size_t kSecretHexDigits = 64;

std::string_view MethodShortName(Rpc rpc) {
  std::string_view m = RuleOf(rpc).method;
  return m.substr(m.rfind('/') + 1);
}

std::string WhoMay(const RpcRule& rule) {
  std::string out;
  auto add = [&out](std::string_view role) {
    if (!out.empty()) out += ", ";
    out += role;
  };
  if (rule.robot) add("robot (own device)");
  if (rule.technician) add("technician");
  if (rule.admin) add("admin");
  return out;
}

// "imucal_" and 64 lowercase hex digits: anything else cannot be a token, and is refused
// without a look at the table.
bool WellFormedSecret(std::string_view secret) {
  if (secret.size() != sizeof(kSecretPrefix) - 1 + kSecretHexDigits) return false;
  if (!absl::StartsWith(absl::string_view(secret.data(), secret.size()), kSecretPrefix))
    return false;
  return std::all_of(secret.begin() + sizeof(kSecretPrefix) - 1, secret.end(),
                     [](char c) { return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'); });
}

bool ValidDeviceId(std::string_view id) {
  static const std::regex kId("[A-Za-z0-9._-]{1,64}");
  return std::regex_match(id.begin(), id.end(), kId);
}

std::string ActorOfToken(const storage::Token& t) {
  std::string actor = t.role == Role::kRobot ? Cat("robot ", t.device_id, " (token ", t.id)
                                             : Cat(storage::RoleName(t.role), " (token ", t.id);
  if (!t.label.empty()) AppendTo(&actor, ", ", t.label);
  actor += ")";
  return actor;
}

}  // namespace

std::span<const RpcRule> RpcRules() { return kRpcRules; }

const RpcRule& RuleOf(Rpc rpc) { return kRpcRules[static_cast<size_t>(rpc)]; }

bool RoleMayCall(Role role, Rpc rpc) {
  const RpcRule& rule = RuleOf(rpc);
  switch (role) {
    case Role::kRobot:
      return rule.robot;
    case Role::kTechnician:
      return rule.technician;
    case Role::kAdmin:
      return rule.admin;
  }
  return false;
}

absl::Status CheckRulesCoverServices() {
  for (size_t i = 0; i < std::size(kRpcRules); ++i) {
    if (static_cast<size_t>(kRpcRules[i].rpc) != i)
      return absl::InternalError(Cat("kRpcRules row ", i, " is out of Rpc order"));
  }
  std::set<std::string> methods;
  const google::protobuf::FileDescriptor* file = v1::Device::descriptor()->file();
  for (int s = 0; s < file->service_count(); ++s) {
    const google::protobuf::ServiceDescriptor* service = file->service(s);
    for (int m = 0; m < service->method_count(); ++m)
      methods.insert(Cat("/", service->full_name(), "/", service->method(m)->name()));
  }
  for (const RpcRule& rule : kRpcRules) {
    if (methods.erase(std::string(rule.method)) != 1)
      return absl::InternalError(Cat("kRpcRules names ", rule.method, ", which is not an RPC"));
  }
  if (!methods.empty())
    return absl::InternalError(Cat("the RPC ", *methods.begin(), " has no row in kRpcRules"));
  return absl::OkStatus();
}

Authorizer::Authorizer(storage::Store* store, storage::TokenStore* tokens,
                       AuthorizerOptions options)
    : store_(store),
      tokens_(tokens),
      options_(options),
      deny_tokens_(options.deny_audit.burst),
      deny_refilled_at_(absl::Now()) {
  auto local = std::make_shared<Principal>();
  local->role = Role::kAdmin;
  local->actor = "insecure-local";
  insecure_principal_ = std::move(local);
}

Authorizer::~Authorizer() {
  // The coalesced denials no later row reported.
  std::lock_guard lock(deny_mu_);
  for (const auto& [key, state] : deny_) {
    if (state.suppressed == 0) continue;
    storage::AuditEntry e;
    e.actor = state.actor;
    e.action = "auth.deny";
    e.target = Cat("rpc:", RuleOf(static_cast<Rpc>(std::get<1>(key))).method);
    e.detail = Cat(state.suppressed, " like denials not logged since ",
                   absl::FormatTime(absl::RFC3339_sec, state.window_start, absl::UTCTimeZone()),
                   " (coalesced); the last: ", state.last_reason);
    store_->AppendAudit(e).IgnoreError();
  }
}

absl::StatusOr<PrincipalRef> Authorizer::Authorize(const grpc::ServerContextBase& context,
                                                   Rpc rpc) {
  if (!options_.enforce) return insecure_principal_;
  Caller caller;
  absl::StatusOr<PrincipalRef> who = Authenticate(context, &caller);
  if (!who.ok()) {
    if (absl::IsUnauthenticated(who.status()) || absl::IsPermissionDenied(who.status()))
      return Deny(std::move(caller), rpc, who.status());
    return who.status();
  }
  if (!RoleMayCall((*who)->role, rpc)) {
    return Deny(CallerOf(**who), rpc,
                absl::PermissionDeniedError(Cat("a ", storage::RoleName((*who)->role),
                                                " may not call ", MethodShortName(rpc),
                                                " (allowed: ", WhoMay(RuleOf(rpc)), ")")));
  }
  return who;
}

absl::Status Authorizer::AuthorizeDevice(const grpc::ServerContextBase& /*context*/,
                                         const Principal& who, Rpc rpc,
                                         std::string_view device_id) {
  if (who.role != Role::kRobot || who.device_id == device_id) return absl::OkStatus();
  // An empty device: a request that may name none (ListSessions of every device).
  return Deny(
      CallerOf(who), rpc,
      absl::PermissionDeniedError(
          device_id.empty()
              ? Cat("robot ", who.device_id,
                    " may act only for its own device: name it (device_id '", who.device_id, "')")
              : Cat("robot ", who.device_id, " may act only for its own device, not '", device_id,
                    "'")));
}

absl::StatusOr<PrincipalRef> Authorizer::AuthorizeForDevice(const grpc::ServerContextBase& context,
                                                            Rpc rpc, std::string_view device_id) {
  absl::StatusOr<PrincipalRef> who = Authorize(context, rpc);
  if (!who.ok()) return who;
  if (absl::Status s = AuthorizeDevice(context, **who, rpc, device_id); !s.ok()) return s;
  return who;
}

absl::StatusOr<PrincipalRef> Authorizer::Authenticate(const grpc::ServerContextBase& context,
                                                      Caller* caller) {
  const auto& metadata = context.client_metadata();
  auto header = metadata.find("authorization");
  *caller = {"no-credentials", Cat("anonymous (", context.peer(), ")")};
  if (header == metadata.end()) {
    if (options_.client_certificates) {
      absl::StatusOr<PrincipalRef> cert = FromClientCertificate(context);
      if (!cert.ok() || *cert != nullptr) return cert;
    }
    return absl::UnauthenticatedError(
        "no credentials: send 'authorization: Bearer <token>' (imucal --token-file F or "
        "--token T, or the SDK's ClientOptions::bearer_token)");
  }
  std::string_view value(header->second.data(), header->second.size());
  *caller = {"bad-token", Cat("unknown token (", context.peer(), ")")};
  constexpr std::string_view kScheme = "bearer ";
  if (value.size() <= kScheme.size() ||
      !absl::EqualsIgnoreCase(absl::string_view(value.data(), kScheme.size()),
                              absl::string_view(kScheme.data(), kScheme.size()))) {
    return absl::UnauthenticatedError("authorization: expected 'Bearer <token>'");
  }
  int64_t revoked_id = 0;
  absl::StatusOr<PrincipalRef> who = FromToken(value.substr(kScheme.size()), &revoked_id);
  if (revoked_id != 0)
    *caller = {Cat("token:", revoked_id),
               Cat("revoked token ", revoked_id, " (", context.peer(), ")")};
  if (!who.ok()) return who;
  *caller = CallerOf(**who);
  if (!options_.client_certificates || (*who)->role != Role::kRobot) return who;
  // A robot with both: the certificate and the token must name the same device.
  absl::StatusOr<PrincipalRef> cert = FromClientCertificate(context);
  if (!cert.ok()) return cert.status();
  if (*cert != nullptr && (*cert)->device_id != (*who)->device_id) {
    return absl::PermissionDeniedError(Cat("the client certificate is for device ",
                                           (*cert)->device_id, " but token ", (*who)->token_id,
                                           " for device ", (*who)->device_id));
  }
  return who;
}

absl::StatusOr<PrincipalRef> Authorizer::FromToken(std::string_view secret, int64_t* revoked_id) {
  if (!WellFormedSecret(secret))
    return absl::UnauthenticatedError("not an imucal token (expected imucal_ and 64 hex digits)");
  const storage::TokenHash hash = storage::HashTokenSecret(secret);
  std::string key(reinterpret_cast<const char*>(hash.data()), hash.size());
  const absl::Time now = absl::Now();
  {
    std::shared_lock lock(cache_mu_);
    if (auto it = cache_.find(key); it != cache_.end() && it->second.expires > now) {
      if (it->second.principal == nullptr) {
        *revoked_id = it->second.revoked_id;
        return absl::UnauthenticatedError(it->second.revoked_reason);
      }
      return it->second.principal;
    }
    if (unknown_.contains(key)) return absl::UnauthenticatedError("unknown token");
  }
  absl::StatusOr<storage::Token> token = tokens_->Lookup(hash);
  if (absl::IsNotFound(token.status())) {
    std::unique_lock lock(cache_mu_);
    if (unknown_.size() >= options_.max_unknown_cached) unknown_.clear();
    unknown_.emplace(std::move(key), true);
    return absl::UnauthenticatedError("unknown token");
  }
  if (!token.ok()) {
    // The database out of reach: a token this server knew valid stays so until it answers
    // (a revocation needs the database too), so robots keep fetching their parameters.
    std::shared_lock lock(cache_mu_);
    if (auto it = cache_.find(key); absl::IsUnavailable(token.status()) && it != cache_.end() &&
                                    it->second.principal != nullptr)
      return it->second.principal;
    return absl::UnavailableError("the token table cannot be read; retry");
  }
  CacheEntry entry;
  entry.expires = now + options_.cache_ttl;
  std::unique_lock lock(cache_mu_);
  // Read before a revocation through this server committed, the row still says valid: the
  // revoked id, noted before the revocation cleared the cache, says otherwise.
  if (!token->revoked() && revoked_ids_.contains(token->id)) token->revoked_at = now;
  if (token->revoked()) {
    entry.revoked_id = token->id;
    entry.revoked_reason =
        Cat("token ", token->id, " was revoked at ",
            absl::FormatTime(absl::RFC3339_sec, *token->revoked_at, absl::UTCTimeZone()));
  } else {
    auto p = std::make_shared<Principal>();
    p->token_id = token->id;
    p->role = token->role;
    p->device_id = token->device_id;
    p->actor = ActorOfToken(*token);
    entry.principal = std::move(p);
  }
  CacheEntry& stored = cache_[key] = std::move(entry);
  if (stored.principal == nullptr) {
    *revoked_id = stored.revoked_id;
    return absl::UnauthenticatedError(stored.revoked_reason);
  }
  return stored.principal;
}

absl::StatusOr<PrincipalRef> Authorizer::FromClientCertificate(
    const grpc::ServerContextBase& context) {
  std::shared_ptr<const grpc::AuthContext> auth = context.auth_context();
  if (auth == nullptr || !auth->IsPeerAuthenticated()) return PrincipalRef();
  // gRPC verified the certificate against the client CA during the handshake (a certificate
  // that does not verify ends the connection): its common name is the device.
  std::vector<grpc::string_ref> names = auth->FindPropertyValues("x509_common_name");
  if (names.empty()) return PrincipalRef();
  const std::string device(names.front().data(), names.front().size());
  if (!ValidDeviceId(device)) {
    return absl::UnauthenticatedError(
        "the client certificate's common name is not a device id ([A-Za-z0-9._-]{1,64})");
  }
  auto p = std::make_shared<Principal>();
  p->role = Role::kRobot;
  p->device_id = device;
  p->actor = Cat("robot ", device, " (client certificate)");
  return PrincipalRef(std::move(p));
}

Authorizer::Caller Authorizer::CallerOf(const Principal& who) {
  return {who.token_id != 0 ? Cat("token:", who.token_id) : Cat("cert:", who.device_id), who.actor};
}

absl::Status Authorizer::Deny(Caller caller, Rpc rpc, absl::Status denial) {
  std::string& actor = caller.actor;
  const std::string reason(denial.message());
  int64_t suppressed_before = 0;
  bool write = false;
  {
    std::lock_guard lock(deny_mu_);
    const absl::Time now = absl::Now();
    const DenialAuditLimits& limits = options_.deny_audit;
    deny_tokens_ =
        std::min(limits.burst,
                 deny_tokens_ + absl::ToDoubleSeconds(now - deny_refilled_at_) * limits.rows_per_s);
    deny_refilled_at_ = now;
    DenyState& state =
        deny_[{std::move(caller.key), static_cast<int>(rpc), static_cast<int>(denial.code())}];
    const bool new_window =
        state.window_start == absl::Time() || now - state.window_start >= limits.window;
    if (new_window && deny_tokens_ >= 1) {
      deny_tokens_ -= 1;
      write = true;
      suppressed_before = state.suppressed;
      state.suppressed = 0;
      state.window_start = now;
      ++denial_rows_;
    } else {
      ++state.suppressed;
      ++denials_suppressed_;
    }
    state.actor = actor;
    state.last_reason = reason;
  }
  if (write) WriteDenialRow(actor, rpc, denial, suppressed_before);
  return denial;
}

void Authorizer::WriteDenialRow(const std::string& actor, Rpc rpc, const absl::Status& denial,
                                int64_t suppressed_before) {
  storage::AuditEntry e;
  e.actor = actor;
  e.action = "auth.deny";
  e.target = Cat("rpc:", RuleOf(rpc).method);
  e.detail = Cat(absl::StatusCodeToString(denial.code()), ": ", denial.message());
  if (suppressed_before > 0)
    AppendTo(&e.detail, " (", suppressed_before, " like denials before this one were coalesced)");
  // A denial must not fail the call for another reason: an audit write that fails (the disk is
  // full) loses the row, not the answer.
  store_->AppendAudit(e).IgnoreError();
}

static absl::Status NoTokensWhenInsecure() {
  return absl::FailedPreconditionError(
      "this server runs insecure (plaintext, loopback only) and uses no tokens; serve TLS "
      "(tls_cert, tls_key) to manage them");
}

absl::StatusOr<std::vector<storage::Token>> Authorizer::ListTokens(bool include_revoked) {
  if (tokens_ == nullptr) return NoTokensWhenInsecure();
  return tokens_->List(include_revoked);
}

absl::StatusOr<storage::NewToken> Authorizer::CreateToken(storage::Role role,
                                                          std::string_view device_id,
                                                          std::string_view label,
                                                          std::string_view actor) {
  if (tokens_ == nullptr) return NoTokensWhenInsecure();
  absl::StatusOr<storage::NewToken> created = tokens_->Create(role, device_id, label, actor);
  if (created.ok()) {
    std::unique_lock lock(cache_mu_);
    unknown_.clear();  // in case this secret was ever tried (2^-256, but cheap to be exact)
  }
  return created;
}

absl::StatusOr<storage::Token> Authorizer::RevokeToken(int64_t id, std::string_view actor) {
  if (tokens_ == nullptr) return NoTokensWhenInsecure();
  absl::StatusOr<storage::Token> revoked = tokens_->Revoke(id, actor);
  if (!revoked.ok()) return revoked;
  {
    std::unique_lock lock(cache_mu_);
    revoked_ids_.insert(id);
    absl::erase_if(cache_, [id](const auto& kv) {
      return kv.second.principal != nullptr && kv.second.principal->token_id == id;
    });
  }
  if (on_revoke_) {
    const absl::Time at = revoked->revoked_at.value_or(absl::Now());
    on_revoke_(id, Cat("token ", id, " was revoked at ",
                       absl::FormatTime(absl::RFC3339_sec, at, absl::UTCTimeZone())));
  }
  return revoked;
}

void Authorizer::TokenChanged(int64_t id) {
  if (tokens_ == nullptr) return;
  absl::StatusOr<storage::Token> token = tokens_->Get(id);
  const bool deleted = absl::IsNotFound(token.status());
  const bool revoked = deleted || (token.ok() && token->revoked());
  {
    std::unique_lock lock(cache_mu_);
    // Noted before the entries go, as in RevokeToken: a lookup that read the row before the
    // change cannot put the token back.
    if (revoked) revoked_ids_.insert(id);
    absl::erase_if(cache_, [id](const auto& kv) {
      return kv.second.principal != nullptr && kv.second.principal->token_id == id;
    });
    if (token.ok() && !revoked) unknown_.clear();  // a new token: its secret is known now
  }
  if (!token.ok() && !deleted) {
    // Unreadable now: the entries are gone, so the next call with it reads the table again.
    Log(LogLevel::kWarning, "token_recheck",
        {{"token_id", id}, {"error", std::string(token.status().message())}});
    return;
  }
  if (!revoked || !on_revoke_) return;
  on_revoke_(id, deleted ? Cat("token ", id, " was deleted")
                         : Cat("token ", id, " was revoked at ",
                               absl::FormatTime(absl::RFC3339_sec, *token->revoked_at,
                                                absl::UTCTimeZone())));
}

void Authorizer::ForgetCachedTokens() {
  std::unique_lock lock(cache_mu_);
  cache_.clear();
  unknown_.clear();
}

int64_t Authorizer::denial_rows_written() const {
  std::lock_guard lock(deny_mu_);
  return denial_rows_;
}

int64_t Authorizer::denials_suppressed() const {
  std::lock_guard lock(deny_mu_);
  return denials_suppressed_;
}

}  // namespace imucal::server
