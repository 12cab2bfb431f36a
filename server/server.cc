#include "server/server.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <optional>
#include <string_view>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/synchronization/mutex.h"
#include "grpcpp/ext/proto_server_reflection_plugin.h"
#include "grpcpp/health_check_service_interface.h"
#include "server/log.h"

namespace imucal::server {
namespace {

constexpr char kStartupActor[] = "imucald";
// How often a server on SQLite reads the token change log (TokenWatch): the bound on how long a
// token revoked by another process still works here.
constexpr absl::Duration kTokenPoll = absl::Milliseconds(250);

// Who this server is to the others sharing its database: the host and the listen address.
std::string DefaultReplicaId(const std::string& listen) {
  char host[256] = {};
  if (::gethostname(host, sizeof(host) - 1) != 0) host[0] = '\0';
  return absl::StrCat(host[0] != '\0' ? host : "localhost", "/", listen);
}

// Writes the first admin token's secret to `path`, readable by its owner only (0600 even if
// the file existed with other permissions), and synced: the operator's only copy.
absl::Status WriteSecretFile(const std::string& path, const std::string& secret) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_NOFOLLOW | O_CLOEXEC, 0600);
  if (fd < 0) {
    return absl::UnavailableError(
        absl::StrCat("admin_token_file: cannot write ", path, ": ", std::strerror(errno)));
  }
  const std::string line = secret + "\n";
  const bool ok = ::fchmod(fd, 0600) == 0 &&
                  ::write(fd, line.data(), line.size()) == static_cast<ssize_t>(line.size()) &&
                  ::fsync(fd) == 0;
  const int err = errno;
  ::close(fd);
  if (!ok) {
    return absl::UnavailableError(
        absl::StrCat("admin_token_file: cannot write ", path, ": ", std::strerror(err)));
  }
  return absl::OkStatus();
}

// With TLS and no valid admin token (a new database, or every admin token revoked): the first
// admin token, so that an operator can create the others (imucal admin token create). Returns the
// file written, or "" when there were tokens already. A token whose file could not be written is
// revoked again.
absl::StatusOr<std::string> BootstrapAdminToken(storage::TokenStore& tokens,
                                                const ServerOptions& options) {
  if (options.admin_token_file.empty() && sql::IsPostgresUrl(options.db_path)) {
    // No file beside a PostgreSQL database: unless an admin token exists, the operator names
    // one (several replicas share the database; the first to start writes the token).
    absl::StatusOr<std::vector<storage::Token>> valid = tokens.List(/*include_revoked=*/false);
    if (!valid.ok()) return valid.status();
    for (const storage::Token& t : *valid)
      if (t.role == storage::Role::kAdmin) return std::string();
    return absl::FailedPreconditionError(
        "admin_token_file: a PostgreSQL database has no file beside it to hold the first admin "
        "token; name one (--admin-token-file)");
  }
  absl::StatusOr<std::optional<storage::NewToken>> first =
      tokens.CreateFirstAdmin("bootstrap", kStartupActor);
  if (!first.ok()) return first.status();
  if (!first->has_value()) return std::string();
  const std::string path = options.admin_token_file.empty() ? options.db_path + ".admin-token"
                                                            : options.admin_token_file;
  if (absl::Status s = WriteSecretFile(path, (*first)->secret); !s.ok()) {
    tokens.Revoke((*first)->token.id, kStartupActor).IgnoreError();
    return s;
  }
  Log(LogLevel::kWarning, "admin_token_created",
      {{"token_id", (*first)->token.id},
       {"file", path},
       {"note",
        "the first admin token; create the others with imucal admin token create, "
        "then keep this file safe or revoke the token"}});
  return path;
}

// A zero timeout would end every stream at once, a zero cap refuse them all.
absl::Status CheckStreamLimits(const SessionServiceOptions& o) {
  for (const auto& [name, d] : {std::pair{"first_batch_timeout", o.first_batch_timeout},
                                std::pair{"stream_idle_timeout", o.stream_idle_timeout},
                                std::pair{"watch_stall_timeout", o.watch_stall_timeout}}) {
    if (d <= absl::ZeroDuration())
      return absl::InvalidArgumentError(absl::StrCat(name, ": must be longer than 0"));
  }
  if (o.max_streams < 1 || o.max_streams_per_token < 1)
    return absl::InvalidArgumentError("max_streams, max_streams_per_token: must be 1 or more");
  return absl::OkStatus();
}

// The store, telling the fetch cache of every change of a device's active version, whichever
// service made it, and timing its transactions into `metrics` (null: none kept).
absl::StatusOr<std::unique_ptr<storage::Store>> OpenStore(
    const ServerOptions& options, const std::shared_ptr<ActiveParamCache>& cache,
    Metrics* metrics) {
  storage::StoreOptions store_options;
  store_options.durability = options.durability;
  store_options.on_active_change = [cache](std::string_view device_id) {
    cache->Invalidate(device_id);
  };
  if (metrics != nullptr) {
    store_options.on_transaction = [metrics](std::string_view op, absl::Duration took) {
      metrics->ObserveDbTransaction(op, took);
    };
  }
  return storage::Store::Open(options.db_path, store_options);
}

// The solves' and streams' leases, and the database's pings.
absl::Status CheckLeases(const SessionServiceOptions& sessions, const ServerOptions& options) {
  if (sessions.solve_lease <= absl::ZeroDuration())
    return absl::InvalidArgumentError("solve_lease: must be positive");
  if (sessions.stream_lease < absl::Milliseconds(30))
    return absl::InvalidArgumentError("stream_lease: must be at least 30ms");
  if (sessions.max_solve_attempts < 1)
    return absl::InvalidArgumentError("max_solve_attempts: must be at least 1");
  if (options.database_ping <= absl::ZeroDuration())
    return absl::InvalidArgumentError("database_ping: must be longer than 0");
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::unique_ptr<Server>> Server::Start(const ServerOptions& options) {
  // Debian's absl is built with Mutex deadlock detection on (a debug aid that updates a global
  // lock-order graph on every lock of gRPC's mutexes): 5-10% of a parameter fetch's server CPU
  // under load (perf). The server's own locks are std::mutex; turn it off for the process.
  absl::SetMutexDeadlockDetectionMode(absl::OnDeadlockCycle::kIgnore);
  const size_t colon = options.listen.rfind(':');
  if (colon == std::string::npos) return absl::InvalidArgumentError("listen: expected host:port");
  if (absl::Status s = CheckStreamLimits(options.sessions); !s.ok()) return s;
  if (absl::Status s = CheckRulesCoverServices(); !s.ok()) return s;
  absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> credentials =
      ListenerCredentials(options.listen, options.security);
  if (!credentials.ok()) return credentials.status();
  auto cache = std::make_shared<ActiveParamCache>();
  std::unique_ptr<Metrics> metrics;
  if (!options.metrics_listen.empty()) {
    absl::StatusOr<std::unique_ptr<Metrics>> started = Metrics::Start(options.metrics_listen);
    if (!started.ok()) return started.status();
    metrics = *std::move(started);
  }
  absl::StatusOr<std::unique_ptr<storage::Store>> store = OpenStore(options, cache, metrics.get());
  if (!store.ok()) return store.status();
  SessionServiceOptions sessions = options.sessions;
  if (sessions.replica_id.empty()) sessions.replica_id = DefaultReplicaId(options.listen);
  if (absl::Status s = CheckLeases(sessions, options); !s.ok()) return s;

  std::unique_ptr<Server> s(new Server());
  s->host_ = options.listen.substr(0, colon);
  s->drain_deadline_ = options.drain_deadline;
  s->metrics_ = std::move(metrics);
  s->active_cache_ = std::move(cache);
  s->store_ = *std::move(store);
  absl::StatusOr<absl::Duration> cache_sync = s->StartCacheSync(options.active_cache_sync);
  if (!cache_sync.ok()) return cache_sync.status();
  if (absl::Status st = s->StartAuth(options); !st.ok()) return st;
  if (absl::Status st = s->StartServices(options, sessions); !st.ok()) return st;

  // Solves this server was running when it stopped (killed, crashed), and those of servers
  // sharing the database whose claim has lapsed, are queued to run again before the first call
  // is taken: a client that finds the server up finds them claimed (or, out of attempts, failed).
  absl::StatusOr<int> resumed = s->sessions_->ResumeLapsedSolves(sessions.replica_id);
  if (!resumed.ok()) return resumed.status();
  if (*resumed > 0)
    Log(LogLevel::kInfo, "solves_resumed",
        {{"replica_id", sessions.replica_id}, {"solves", *resumed}});

  if (absl::Status st = s->Serve(options, *credentials); !st.ok()) return st;
  s->database_->Start();
  s->background_ =
      std::thread([server = s.get(), id = sessions.replica_id, lease = sessions.solve_lease,
                   sync = *cache_sync] { server->Background(id, lease, sync); });
  return s;
}

absl::StatusOr<absl::Duration> Server::StartCacheSync(absl::Duration sync) {
  // Other servers' changes from now on, heard before anything can be fetched into the cache, so
  // that a change committed between a fill and the first sync is not missed. PostgreSQL tells
  // every server of each commit as it happens (LISTEN/NOTIFY); on SQLite each server reads the
  // audit log every active_cache_sync (SQLite's commits are serial, so its ids follow commit
  // order; PostgreSQL's do not, which is why it is not polled).
  // (PostgreSQL: the listener starts in StartServices, once the session service that it also
  // tells exists, still before the server takes its first call.)
  if (store_->dialect() == sql::Dialect::kPostgres) return absl::ZeroDuration();
  absl::StatusOr<storage::Store::ActiveChanges> synced = store_->ActiveChangesSince(-1);
  if (!synced.ok()) return synced.status();
  synced_audit_id_ = synced->last_id;
  return sync;
}

absl::Status Server::StartAuth(const ServerOptions& options) {
  // Who may do what (server/auth.h). Insecure mode checks nothing: it is loopback-only.
  AuthorizerOptions auth_options;
  auth_options.enforce = !options.security.insecure;
  auth_options.client_certificates = !options.security.client_ca_path.empty();
  auth_options.deny_audit = options.deny_audit;
  if (auth_options.enforce) {
    absl::StatusOr<std::unique_ptr<storage::TokenStore>> tokens =
        storage::TokenStore::Open(options.db_path);
    if (!tokens.ok()) return tokens.status();
    tokens_ = *std::move(tokens);
    absl::StatusOr<std::string> written = BootstrapAdminToken(*tokens_, options);
    if (!written.ok()) return written.status();
    admin_token_written_ = *std::move(written);
  } else {
    Log(LogLevel::kWarning, "insecure_listener",
        {{"listen", options.listen},
         {"note", "plaintext and no authentication: every caller is the local admin"}});
  }
  auth_ = std::make_unique<Authorizer>(store_.get(), tokens_.get(), auth_options);
  return absl::OkStatus();
}

absl::Status Server::StartServices(const ServerOptions& options,
                                   const SessionServiceOptions& sessions) {
  admin_ = std::make_unique<AdminServiceImpl>(auth_.get());
  devices_ = std::make_unique<DeviceServiceImpl>(store_.get(), auth_.get());
  sessions_ = std::make_unique<SessionServiceImpl>(store_.get(), sessions, auth_.get());
  if (metrics_ != nullptr) sessions_->SetMetrics(metrics_.get());
  // A revoked token's open streams and watches end at once, not at their next message.
  auth_->SetRevocationListener([sessions = sessions_.get()](int64_t id, const std::string& why) {
    sessions->RevokeStreams(id, why);
  });
  // Tokens changed elsewhere (another server, a tool, SQL by hand): PostgreSQL's trigger tells
  // the listener below; on SQLite the change log is read every kTokenPoll.
  if (tokens_ != nullptr) {
    const bool postgres = store_->dialect() == sql::Dialect::kPostgres;
    absl::StatusOr<std::unique_ptr<TokenWatch>> watch =
        TokenWatch::Start(auth_.get(), tokens_.get(), postgres ? absl::ZeroDuration() : kTokenPoll);
    if (!watch.ok()) return watch.status();
    token_watch_ = *std::move(watch);
  }
  if (store_->dialect() == sql::Dialect::kPostgres) {
    if (absl::Status listening = ListenForChanges(); !listening.ok()) return listening;
  }
  // The database's reachability: the server's health follows it (set once the server runs).
  database_ =
      std::make_shared<DatabaseHealth>([store = store_.get()] { return store->Ping(); },
                                       [this](bool up) { SetServing(up); }, options.database_ping);
  if (metrics_ != nullptr) {
    metrics_->SetGauge("imucal_database_up",
                       "1 while the server reaches its database (its pings answer), 0 while "
                       "it cannot (health NOT_SERVING, fetches answered from the cache)",
                       [database = database_] { return database->up() ? 1.0 : 0.0; });
  }
  parameters_ = std::make_unique<ParameterServiceImpl>(store_.get(), active_cache_.get(),
                                                       auth_.get(), database_.get());
  return absl::OkStatus();
}

absl::Status Server::ListenForChanges() {
  // Other replicas' commits: promotes and rollbacks empty the fetch cache's entry; a batch or
  // a state change of a session that someone watches here is told to its watchers.
  ActiveParamCache* c = active_cache_.get();
  SessionServiceImpl* live = sessions_.get();
  storage::Store::ChangeHandlers handlers;
  handlers.on_active = [c](std::string_view device_id) { c->Invalidate(device_id); };
  handlers.on_session = [live](std::string_view session_id) {
    live->SessionChangedElsewhere(session_id);
  };
  TokenWatch* tokens = token_watch_.get();  // null in insecure mode
  handlers.on_token = [tokens](int64_t id) {
    if (tokens != nullptr) tokens->Changed(id);
  };
  handlers.on_gap = [c, live, tokens] {
    c->Clear();
    live->RefreshWatchedSessions();
    if (tokens != nullptr) tokens->Gap();
    Log(LogLevel::kWarning, "change_notifications_gap",
        {{"note",
          "the database's change notifications were interrupted: fetch cache emptied, "
          "watched sessions read again"}});
  };
  return store_->ListenForChanges(std::move(handlers));
}

absl::Status Server::Serve(const ServerOptions& options,
                           const std::shared_ptr<grpc::ServerCredentials>& credentials) {
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(options.listen, credentials, &port_);
  builder.SetMaxReceiveMessageSize(options.max_receive_message_bytes);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIME_MS,
                             static_cast<int>(absl::ToInt64Milliseconds(options.keepalive_time)));
  builder.AddChannelArgument(
      GRPC_ARG_KEEPALIVE_TIMEOUT_MS,
      static_cast<int>(absl::ToInt64Milliseconds(options.keepalive_timeout)));
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_PERMIT_WITHOUT_CALLS, 1);
  // Keep pinging a stream that carries no data (a robot silent between batches): gRPC stops
  // after 2 pings without data by default, and a dead peer would then go unnoticed.
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MAX_PINGS_WITHOUT_DATA, 0);
  builder.RegisterService(devices_.get());
  builder.RegisterService(sessions_.get());
  builder.RegisterService(parameters_.get());
  builder.RegisterService(admin_.get());
  std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> creators;
  if (options.log_rpcs) creators.push_back(NewRpcLogInterceptorFactory());
  if (metrics_ != nullptr) creators.push_back(metrics_->NewInterceptorFactory());
  if (!creators.empty()) builder.experimental().SetInterceptorCreators(std::move(creators));
  server_ = builder.BuildAndStart();
  if (server_ == nullptr || port_ == 0) {
    return absl::UnavailableError(absl::StrCat("cannot listen on ", options.listen));
  }
  return absl::OkStatus();
}

void Server::Background(const std::string& replica_id, absl::Duration lease,
                        absl::Duration sync) {
  absl::Time next_lease = absl::Now() + lease / 3;
  absl::Time next_sync = sync > absl::ZeroDuration() ? absl::Now() + sync : absl::InfiniteFuture();
  std::unique_lock lock(background_mu_);
  while (!background_stop_) {
    background_cv_.wait_until(lock, absl::ToChronoTime(std::min(next_lease, next_sync)),
                              [this] { return background_stop_; });
    if (background_stop_) break;
    lock.unlock();
    const absl::Time now = absl::Now();
    if (now >= next_sync) {
      SyncActiveCache();
      next_sync = now + sync;
    }
    if (now >= next_lease) {
      RenewLeases(replica_id, lease);
      next_lease = now + lease / 3;
    }
    lock.lock();
  }
}

void Server::SyncActiveCache() {
  std::lock_guard lock(sync_mu_);
  absl::StatusOr<storage::Store::ActiveChanges> changes =
      store_->ActiveChangesSince(synced_audit_id_);
  if (!changes.ok()) {
    Log(LogLevel::kWarning, "active_cache_sync",
        {{"error", std::string(changes.status().message())}});
    return;
  }
  for (const std::string& device : changes->devices) active_cache_->Invalidate(device);
  synced_audit_id_ = changes->last_id;
}

void Server::RenewLeases(const std::string& replica_id, absl::Duration lease) {
  // Ours first: a slow sweep must not let our own claims lapse.
  absl::Status renewed = store_->RenewSolveLeases(replica_id, absl::Now() + lease).status();
  absl::StatusOr<int> resumed = sessions_->ResumeLapsedSolves();
  if (!renewed.ok() || !resumed.ok()) {
    Log(LogLevel::kWarning, "solve_leases",
        {{"replica_id", replica_id},
         {"error", std::string(!renewed.ok() ? renewed.message() : resumed.status().message())}});
  } else if (*resumed > 0) {
    Log(LogLevel::kInfo, "solves_resumed", {{"replica_id", replica_id}, {"solves", *resumed}});
  }
}

Server::~Server() {
  // Before anything the notifications reach (the session service) goes.
  if (store_ != nullptr) store_->StopListening();
  Shutdown();
}

void Server::SetServing(bool serving) {
  std::lock_guard lock(health_mu_);
  if (shut_down_ || server_ == nullptr) return;
  // Every service and the server as a whole (""), which --health-check and load balancers ask.
  server_->GetHealthCheckService()->SetServingStatus(serving);
}

size_t Server::live_sessions() const { return sessions_->live_sessions(); }
size_t Server::open_streams() const { return sessions_->open_streams(); }
size_t Server::solve_jobs_in_memory() const { return sessions_->solve_jobs_in_memory(); }

std::string Server::address() const { return absl::StrCat(host_, ":", port_); }

void Server::Shutdown() {
  if (database_ != nullptr) database_->Stop();  // no health change from here on
  {
    std::lock_guard lock(health_mu_);
    if (shut_down_ || server_ == nullptr) return;
    shut_down_ = true;
  }
  // New calls are refused at once; in-flight ones get until the deadline, then are cancelled.
  server_->GetHealthCheckService()->Shutdown();
  server_->Shutdown(std::chrono::system_clock::now() + absl::ToChronoMilliseconds(drain_deadline_));
  server_->Wait();
  sessions_->DrainSolves();  // queued solves finish and store their results
  {
    std::lock_guard lock(background_mu_);
    background_stop_ = true;
  }
  background_cv_.notify_all();
  if (background_.joinable()) background_.join();
}

}  // namespace imucal::server
