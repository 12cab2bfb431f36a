// imucald's gRPC server: the three services, the health service and reflection over one
// Store. Start() binds and serves; Shutdown() stops accepting calls, lets in-flight calls and
// queued solves finish (up to `drain_deadline`), and returns.
#ifndef IMUCAL_SERVER_SERVER_H_
#define IMUCAL_SERVER_SERVER_H_

#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "grpcpp/grpcpp.h"
#include "server/services.h"
#include "storage/store.h"

namespace imucal::server {

struct ServerOptions {
  std::string listen = "127.0.0.1:50051";  // "host:port"; port 0 picks a free one
  std::string db_path = "imucal.db";
  SessionServiceOptions sessions;
  absl::Duration drain_deadline = absl::Seconds(30);
};

class Server {
 public:
  static absl::StatusOr<std::unique_ptr<Server>> Start(const ServerOptions& options);
  ~Server();  // Shutdown()

  int port() const { return port_; }
  std::string address() const;  // "host:port" with the selected port
  void Shutdown();
  void Wait() { server_->Wait(); }

 private:
  Server() = default;

  std::string host_;
  int port_ = 0;
  absl::Duration drain_deadline_;
  std::shared_ptr<ActiveParamCache> active_cache_;  // before store_: it outlives the store
  std::unique_ptr<storage::Store> store_;
  std::unique_ptr<DeviceServiceImpl> devices_;
  std::unique_ptr<SessionServiceImpl> sessions_;
  std::unique_ptr<ParameterServiceImpl> parameters_;
  std::unique_ptr<grpc::Server> server_;
  bool shut_down_ = false;
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_SERVER_H_
