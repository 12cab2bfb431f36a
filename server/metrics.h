// Prometheus metrics of one imucald (one replica of a fleet's servers), kept with prometheus-cpp
// (Debian's prometheus-cpp-dev). Served in the text exposition format at
// http://<metrics_listen>/metrics when ServerOptions::metrics_listen is set, by the endpoint of
// server/metrics_http.h (which says what it answers to anything else); scraped per replica.
//
// What is measured (names are the exported ones; units are in the names):
//   imucal_rpc_total{method,code}                    calls completed, by gRPC status code
//   imucal_rpc_duration_seconds{method}              histogram, call start to status sent
//                                                    (a stream's whole life for streams)
//   imucal_samples_received_total                    samples in batches read off streams
//   imucal_samples_acknowledged_total                samples made durable and acknowledged
//                                                    (a retransmitted batch counts once)
//   imucal_solve_duration_seconds{outcome}           histogram, a solve's run (not its wait)
//   imucal_db_transaction_duration_seconds{op}       histogram, a write transaction from BEGIN
//                                                    (its wait for the write lock included)
//   gauges read at each scrape (SetGauge): open sessions, open streams, watchers, queued solves,
//   and imucal_database_up (1 while the server reaches its database, 0 while it cannot:
//   server/database_health.h).
//
// Thread-safe: every method may be called from any thread.
#ifndef IMUCAL_SERVER_METRICS_H_
#define IMUCAL_SERVER_METRICS_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "grpcpp/support/server_interceptor.h"
#include "grpcpp/support/status.h"
#include "server/metrics_http.h"

namespace prometheus {
class Registry;
}  // namespace prometheus

namespace imucal::server {

class Metrics {
 public:
  // `listen` "HOST:PORT" (port 0 picks a free one) serves /metrics over HTTP; empty: no
  // endpoint (Text() still gives what a scrape would). InvalidArgument when `listen` is not
  // HOST:PORT, Unavailable when it cannot listen there (MetricsHttpEndpoint::Start).
  static absl::StatusOr<std::unique_ptr<Metrics>> Start(const std::string& listen,
                                                        const MetricsHttpLimits& limits = {});
  ~Metrics();
  Metrics(const Metrics&) = delete;
  Metrics& operator=(const Metrics&) = delete;

  int port() const { return endpoint_ == nullptr ? 0 : endpoint_->port(); }  // 0 without one

  void ObserveRpc(std::string_view method, grpc::StatusCode code, absl::Duration duration);
  void CountSamplesReceived(int64_t samples);
  void CountSamplesAcknowledged(int64_t samples);
  // outcome: "done" (a version stored), "refused" (the capture cannot be solved), "failed".
  void ObserveSolve(std::string_view outcome, absl::Duration duration);
  // outcome: "rerun" (claimed from a server that stopped, queued to run again), "given_up"
  // (claimed after max_solve_attempts starts, and failed).
  void CountSolveTakenOver(std::string_view outcome);
  void ObserveDbTransaction(std::string_view op, absl::Duration duration);
  // A gauge whose value `read` gives at each scrape (quick, any thread, no blocking calls).
  void SetGauge(const std::string& name, const std::string& help, std::function<double()> read);

  // The text a scrape returns now.
  std::string Text() const;

  // Counts every call's completion (ObserveRpc); for grpc::ServerBuilder.
  std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>
  NewInterceptorFactory();

 private:
  struct Families;
  class Gauges;
  Metrics();

  std::shared_ptr<prometheus::Registry> registry_;
  std::unique_ptr<Families> families_;
  std::shared_ptr<Gauges> gauges_;
  std::unique_ptr<MetricsHttpEndpoint> endpoint_;  // last: stops serving before the rest goes
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_METRICS_H_
