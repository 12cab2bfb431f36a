#include "server/metrics.h"

#include <mutex>
#include <sstream>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "prometheus/collectable.h"
#include "prometheus/counter.h"
#include "prometheus/family.h"
#include "prometheus/histogram.h"
#include "prometheus/registry.h"
#include "prometheus/text_serializer.h"
#include "server/log.h"

namespace imucal::server {
namespace {

// Seconds, from a fetch answered from memory (~50 us) to a solve of a long capture (minutes).
// Built once: every call's observation passes them (Family::Add uses them only for a new label
// set), and the fetch hot path should not build a vector per call.
const prometheus::Histogram::BucketBoundaries& LatencyBuckets() {
  static const prometheus::Histogram::BucketBoundaries kBuckets = {
      0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1,
      0.25,   0.5,     1,      2.5,   5,      10,    30,   60,    300};
  return kBuckets;
}

}  // namespace

struct Metrics::Families {
  explicit Families(prometheus::Registry& r)
      : rpc_total(prometheus::BuildCounter()
                      .Name("imucal_rpc_total")
                      .Help("gRPC calls completed, by method and status code")
                      .Register(r)),
        rpc_seconds(prometheus::BuildHistogram()
                        .Name("imucal_rpc_duration_seconds")
                        .Help("gRPC call duration, start to status sent (a stream's whole life)")
                        .Register(r)),
        samples(prometheus::BuildCounter()
                    .Name("imucal_samples_received_total")
                    .Help("samples in batches read off StreamSamples streams")
                    .Register(r)
                    .Add({})),
        acked(prometheus::BuildCounter()
                  .Name("imucal_samples_acknowledged_total")
                  .Help("samples made durable and acknowledged (a retransmission counts once)")
                  .Register(r)
                  .Add({})),
        solve_seconds(prometheus::BuildHistogram()
                          .Name("imucal_solve_duration_seconds")
                          .Help("a solve's run (its wait in the queue excluded), by outcome")
                          .Register(r)),
        solves_taken_over(prometheus::BuildCounter()
                              .Name("imucal_solves_taken_over_total")
                              .Help("solves whose server stopped, claimed by this one: run "
                                    "again (rerun), or failed after max_solve_attempts "
                                    "(given_up)")
                              .Register(r)),
        db_seconds(prometheus::BuildHistogram()
                       .Name("imucal_db_transaction_duration_seconds")
                       .Help("write transactions from BEGIN to COMMIT (the wait for the write "
                             "lock included), by store operation")
                       .Register(r)) {}

  prometheus::Family<prometheus::Counter>& rpc_total;
  prometheus::Family<prometheus::Histogram>& rpc_seconds;
  prometheus::Counter& samples;
  prometheus::Counter& acked;
  prometheus::Family<prometheus::Histogram>& solve_seconds;
  prometheus::Family<prometheus::Counter>& solves_taken_over;
  prometheus::Family<prometheus::Histogram>& db_seconds;
};

// Gauges read at scrape time, from the server's own counts: nothing to keep in step.
class Metrics::Gauges final : public prometheus::Collectable {
 public:
  void Set(const std::string& name, const std::string& help, std::function<double()> read) {
    std::lock_guard lock(mu_);
    for (Gauge& g : gauges_) {
      if (g.name == name) {
        g.help = help;
        g.read = std::move(read);
        return;
      }
    }
    gauges_.push_back({name, help, std::move(read)});
  }

  std::vector<prometheus::MetricFamily> Collect() const override {
    std::lock_guard lock(mu_);
    std::vector<prometheus::MetricFamily> out;
    for (const Gauge& g : gauges_) {
      prometheus::MetricFamily f;
      f.name = g.name;
      f.help = g.help;
      f.type = prometheus::MetricType::Gauge;
      prometheus::ClientMetric m;
      m.gauge.value = g.read();
      f.metric.push_back(std::move(m));
      out.push_back(std::move(f));
    }
    return out;
  }

 private:
  struct Gauge {
    std::string name, help;
    std::function<double()> read;
  };
  mutable std::mutex mu_;
  std::vector<Gauge> gauges_;  // guarded by mu_
};

Metrics::Metrics()
    : registry_(std::make_shared<prometheus::Registry>()),
      families_(std::make_unique<Families>(*registry_)),
      gauges_(std::make_shared<Gauges>()) {}

Metrics::~Metrics() = default;

absl::StatusOr<std::unique_ptr<Metrics>> Metrics::Start(const std::string& listen,
                                                        const MetricsHttpLimits& limits) {
  std::unique_ptr<Metrics> m(new Metrics());
  if (listen.empty()) return m;
  absl::StatusOr<std::unique_ptr<MetricsHttpEndpoint>> endpoint = MetricsHttpEndpoint::Start(
      listen, [metrics = m.get()] { return metrics->Text(); }, limits);
  if (!endpoint.ok()) return endpoint.status();
  m->endpoint_ = *std::move(endpoint);
  return m;
}

void Metrics::ObserveRpc(std::string_view method, grpc::StatusCode code, absl::Duration duration) {
  const std::string m(method);
  families_->rpc_total.Add({{"method", m}, {"code", std::string(CodeName(code))}}).Increment();
  families_->rpc_seconds.Add({{"method", m}}, LatencyBuckets())
      .Observe(absl::ToDoubleSeconds(duration));
}

void Metrics::CountSamplesReceived(int64_t samples) {
  families_->samples.Increment(static_cast<double>(samples));
}

void Metrics::CountSamplesAcknowledged(int64_t samples) {
  families_->acked.Increment(static_cast<double>(samples));
}

void Metrics::ObserveSolve(std::string_view outcome, absl::Duration duration) {
  families_->solve_seconds.Add({{"outcome", std::string(outcome)}}, LatencyBuckets())
      .Observe(absl::ToDoubleSeconds(duration));
}

void Metrics::CountSolveTakenOver(std::string_view outcome) {
  families_->solves_taken_over.Add({{"outcome", std::string(outcome)}}).Increment();
}

void Metrics::ObserveDbTransaction(std::string_view op, absl::Duration duration) {
  families_->db_seconds.Add({{"op", std::string(op)}}, LatencyBuckets())
      .Observe(absl::ToDoubleSeconds(duration));
}

void Metrics::SetGauge(const std::string& name, const std::string& help,
                       std::function<double()> read) {
  gauges_->Set(name, help, std::move(read));
}

std::string Metrics::Text() const {
  std::vector<prometheus::MetricFamily> families = registry_->Collect();
  for (prometheus::MetricFamily& f : gauges_->Collect()) families.push_back(std::move(f));
  std::ostringstream out;
  prometheus::TextSerializer().Serialize(out, families);
  return out.str();
}

namespace {

// One per call: the status is known at PRE_SEND_STATUS.
class MetricsInterceptor final : public grpc::experimental::Interceptor {
 public:
  MetricsInterceptor(Metrics* metrics, grpc::experimental::ServerRpcInfo* info)
      : metrics_(metrics), info_(info), start_(absl::Now()) {}

  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    if (methods->QueryInterceptionHookPoint(
            grpc::experimental::InterceptionHookPoints::PRE_SEND_STATUS)) {
      metrics_->ObserveRpc(info_->method(), methods->GetSendStatus().error_code(),
                           absl::Now() - start_);
    }
    methods->Proceed();
  }

 private:
  Metrics* metrics_;
  grpc::experimental::ServerRpcInfo* info_;
  absl::Time start_;
};

class MetricsInterceptorFactory final
    : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  explicit MetricsInterceptorFactory(Metrics* metrics) : metrics_(metrics) {}
  grpc::experimental::Interceptor* CreateServerInterceptor(
      grpc::experimental::ServerRpcInfo* info) override {
    return new MetricsInterceptor(metrics_, info);
  }

 private:
  Metrics* metrics_;
};

}  // namespace

std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>
Metrics::NewInterceptorFactory() {
  return std::make_unique<MetricsInterceptorFactory>(this);
}

}  // namespace imucal::server
