#include "server/server.h"

#include <chrono>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/synchronization/mutex.h"
#include "grpcpp/ext/proto_server_reflection_plugin.h"
#include "grpcpp/health_check_service_interface.h"

namespace imucal::server {
namespace {

constexpr char kOrphanedSolveError[] =
    "the server stopped during this solve; solve the session again";
constexpr char kStartupActor[] = "imucald";

}  // namespace

absl::StatusOr<std::unique_ptr<Server>> Server::Start(const ServerOptions& options) {
  // Debian's absl is built with Mutex deadlock detection on (a debug aid that updates a global
  // lock-order graph on every lock of gRPC's mutexes): 5-10% of a parameter fetch's server CPU
  // under load (perf). The server's own locks are std::mutex; turn it off for the process.
  absl::SetMutexDeadlockDetectionMode(absl::OnDeadlockCycle::kIgnore);
  const size_t colon = options.listen.rfind(':');
  if (colon == std::string::npos)
    return absl::InvalidArgumentError("listen: expected host:port");
  // The fetch cache hears of every change of a device's active version from the store itself,
  // whichever service made it.
  auto cache = std::make_shared<ActiveParamCache>();
  storage::StoreOptions store_options;
  store_options.on_active_change = [cache](std::string_view device_id) {
    cache->Invalidate(device_id);
  };
  absl::StatusOr<std::unique_ptr<storage::Store>> store =
      storage::Store::Open(options.db_path, store_options);
  if (!store.ok()) return store.status();
  // Solves still running were orphaned by a server that stopped (killed, crashed) mid-solve:
  // nothing will finish them, and their sessions would stay `solving` for ever. Fail them and
  // reopen their sessions so that the technician can solve again.
  absl::StatusOr<std::vector<storage::Solve>> orphans = (*store)->ListRunningSolves();
  if (!orphans.ok()) return orphans.status();
  for (const storage::Solve& solve : *orphans) {
    absl::StatusOr<storage::Solve> failed = (*store)->FailSolve(
        solve.id, kOrphanedSolveError, /*report_json=*/"", kStartupActor,
        storage::SessionState::kOpen);
    if (!failed.ok()) return failed.status();
  }

  std::unique_ptr<Server> s(new Server());
  s->host_ = options.listen.substr(0, colon);
  s->drain_deadline_ = options.drain_deadline;
  s->active_cache_ = std::move(cache);
  s->store_ = *std::move(store);
  s->devices_ = std::make_unique<DeviceServiceImpl>(s->store_.get());
  s->sessions_ = std::make_unique<SessionServiceImpl>(s->store_.get(), options.sessions);
  s->parameters_ = std::make_unique<ParameterServiceImpl>(s->store_.get(), s->active_cache_.get());

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(options.listen, grpc::InsecureServerCredentials(), &s->port_);
  builder.RegisterService(s->devices_.get());
  builder.RegisterService(s->sessions_.get());
  builder.RegisterService(s->parameters_.get());
  s->server_ = builder.BuildAndStart();
  if (s->server_ == nullptr || s->port_ == 0) {
    return absl::UnavailableError(absl::StrCat("cannot listen on ", options.listen));
  }
  return s;
}

Server::~Server() { Shutdown(); }

std::string Server::address() const { return absl::StrCat(host_, ":", port_); }

void Server::Shutdown() {
  if (shut_down_ || server_ == nullptr) return;
  shut_down_ = true;
  // New calls are refused at once; in-flight ones get until the deadline, then are cancelled.
  server_->GetHealthCheckService()->Shutdown();
  server_->Shutdown(std::chrono::system_clock::now() +
                    absl::ToChronoMilliseconds(drain_deadline_));
  server_->Wait();
  sessions_->DrainSolves();  // queued solves finish and store their results
}

}  // namespace imucal::server
