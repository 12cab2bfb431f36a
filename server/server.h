// imucald's gRPC server: the four services (devices, sessions, parameters, admin), the health
// service and reflection over one Store (SQLite or PostgreSQL). Start() binds and serves;
// Shutdown() stops accepting calls, lets in-flight calls and queued solves finish (up to
// `drain_deadline`), and returns.
#ifndef IMUCAL_SERVER_SERVER_H_
#define IMUCAL_SERVER_SERVER_H_

#include <condition_variable>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "grpcpp/grpcpp.h"
#include "server/admin_service.h"
#include "server/auth.h"
#include "server/database_health.h"
#include "server/device_service.h"
#include "server/metrics.h"
#include "server/parameter_service.h"
#include "server/session_service.h"
#include "server/tls.h"
#include "server/token_watch.h"
#include "storage/store.h"
#include "storage/tokens.h"

namespace imucal::server {

struct ServerOptions {
  std::string listen = "127.0.0.1:50051";  // "host:port"; port 0 picks a free one
  std::string db_path = "imucal.db";
  SessionServiceOptions sessions;
  absl::Duration drain_deadline = absl::Seconds(30);
  // Largest request message taken (gRPC answers RESOURCE_EXHAUSTED above it). 4 MiB, gRPC's
  // default, said out loud: a batch at IngestLimits::max_batch_samples is about 1.1 MB.
  int max_receive_message_bytes = 4 << 20;
  // The server pings a connection idle for keepalive_time and closes it when a ping is not
  // answered within keepalive_timeout: the streams of a robot that lost power or network end
  // then, and its device's stream slot is free again (within 40 s by default).
  absl::Duration keepalive_time = absl::Seconds(30);
  absl::Duration keepalive_timeout = absl::Seconds(10);
  // PRAGMA synchronous of the store (storage/store.h weighs kFull against kNormal).
  storage::Durability durability = storage::StoreOptions().durability;
  bool log_rpcs = false;  // log each RPC's completion (server/log.h); imucald turns it on
  // The listener (server/tls.h): TLS with the server's certificate, robots' client certificates
  // verified against client_ca_path when set; or, with `insecure`, plaintext on a loopback
  // address only, and then no authentication (every caller is the local admin, server/auth.h).
  ListenerSecurity security;
  // With TLS, when no valid admin token exists (a new database), Start creates the first admin
  // token and writes its secret to this file (mode 0600); empty: "<db_path>.admin-token".
  std::string admin_token_file;
  DenialAuditLimits deny_audit;  // how many audit rows refused calls may write (server/auth.h)
  // How often the server reads the database for active-version changes other servers sharing
  // it made (Store::ActiveChangesSince), dropping those devices from its fetch cache: a promote
  // or rollback through one server is answered by every other within about this long. Zero:
  // never (one server alone on its database; its own changes are seen at once regardless).
  // SQLite only: on PostgreSQL every server hears of each change as it commits (LISTEN/NOTIFY,
  // Store::ListenForActiveChanges), and this is not used.
  absl::Duration active_cache_sync = absl::Milliseconds(250);
  // How often the server pings its database (server/database_health.h): health answers
  // NOT_SERVING from the first ping that cannot reach it until one does again.
  absl::Duration database_ping = absl::Seconds(1);
  // "HOST:PORT" to serve Prometheus metrics on (http://HOST:PORT/metrics, server/metrics.h);
  // port 0 picks a free one; empty: no metrics kept.
  std::string metrics_listen;
};

class Server {
 public:
  static absl::StatusOr<std::unique_ptr<Server>> Start(const ServerOptions& options);
  ~Server();  // Shutdown()

  int port() const { return port_; }
  std::string address() const;  // "host:port" with the selected port
  void Shutdown();
  void Wait() { server_->Wait(); }
  // The file Start wrote the first admin token to; empty when it created none.
  const std::string& admin_token_written() const { return admin_token_written_; }
  // Whether the database answers the server's pings (server/database_health.h).
  bool database_up() const { return database_->up(); }
  // Sessions whose live state is in memory (SessionHub::LiveSessions): what bounds the
  // server's memory per session.
  size_t live_sessions() const;
  // StreamSamples, WatchSession and ReadSamples calls open now (what max_streams bounds).
  size_t open_streams() const;
  // Solve jobs GetSolveJob answers from memory (bounded: SessionServiceOptions).
  size_t solve_jobs_in_memory() const;
  // The metrics endpoint's port (0 without one), and the metrics themselves (null without).
  int metrics_port() const { return metrics_ == nullptr ? 0 : metrics_->port(); }
  Metrics* metrics() const { return metrics_.get(); }
  // The active-parameters fetch cache (tests: to know a device's answer is held).
  const ActiveParamCache* active_cache() const { return active_cache_.get(); }

 private:
  Server() = default;
  // Until Shutdown, on background_: renews this server's solve claims every lease / 3 and fails
  // others' lapsed ones; every `sync` (if positive), SyncActiveCache.
  void Background(const std::string& replica_id, absl::Duration lease, absl::Duration sync);
  // The health service's answer for every service (DatabaseHealth's changes).
  void SetServing(bool serving);
  void RenewLeases(const std::string& replica_id, absl::Duration lease);
  // Start's steps, in its order. The active_cache_sync to poll with (zero on PostgreSQL, which
  // tells of changes as they commit), from the audit log's present end.
  absl::StatusOr<absl::Duration> StartCacheSync(absl::Duration sync);
  // The token store (with TLS; the first admin token on a new database) and the Authorizer.
  absl::Status StartAuth(const ServerOptions& options);
  // The four services, the token watch, PostgreSQL's change listener and the database's health.
  absl::Status StartServices(const ServerOptions& options, const SessionServiceOptions& sessions);
  // PostgreSQL: other replicas' commits, told to the fetch cache, the watched sessions and the
  // token watch.
  absl::Status ListenForChanges();
  // Binds the listener and serves the services.
  absl::Status Serve(const ServerOptions& options,
                     const std::shared_ptr<grpc::ServerCredentials>& credentials);

 public:
  // Drops from the fetch cache the devices whose active version changed in the database since
  // the last call (another server's promote, rollback or solve). Runs every active_cache_sync;
  // public so that a test can run it at a known moment.
  void SyncActiveCache();

 private:

  std::string host_;
  int port_ = 0;
  absl::Duration drain_deadline_;
  std::unique_ptr<Metrics> metrics_;  // before store_ and the services: they report to it
  std::shared_ptr<ActiveParamCache> active_cache_;  // before store_: it outlives the store
  std::unique_ptr<storage::Store> store_;
  std::unique_ptr<storage::TokenStore> tokens_;
  std::unique_ptr<Authorizer> auth_;  // after store_ and tokens_, before the services
  std::unique_ptr<AdminServiceImpl> admin_;
  std::string admin_token_written_;
  std::unique_ptr<DeviceServiceImpl> devices_;
  std::unique_ptr<SessionServiceImpl> sessions_;
  std::unique_ptr<TokenWatch> token_watch_;  // after auth_ and sessions_: it calls both
  std::unique_ptr<ParameterServiceImpl> parameters_;
  std::unique_ptr<grpc::Server> server_;
  // After server_ (its health follows the database); shared with the metrics' gauge.
  std::shared_ptr<DatabaseHealth> database_;
  std::mutex health_mu_;
  bool shut_down_ = false;  // guarded by health_mu_ (read unlocked by Shutdown's own thread)
  std::mutex background_mu_;
  std::condition_variable background_cv_;
  bool background_stop_ = false;  // guarded by background_mu_
  std::mutex sync_mu_;            // one SyncActiveCache at a time
  int64_t synced_audit_id_ = 0;   // guarded by sync_mu_: the last audit entry read
  std::thread background_;
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_SERVER_H_
