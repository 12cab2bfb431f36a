// Active-parameters fetch (the robot-startup hot path): ParameterService.GetActiveParameters for
// random devices against a fleet-sized SQLite store.
//
//   ninja -C build-perf fetch_bench
//   build-perf/bench/fetch_bench [--devices=10000] [--versions=10] [--seconds=3]
//                                [--callers=1,64] [--channels=1]
//                                [--db=PATH (populated there if missing, reused if present)]
//                                [--keep]
//                                [--warm] [--server-cpu=N] [--client-cpu=N]
//
// --warm fetches every device once before the rows (a fleet whose robots have all booted since
// the server started: the server's response cache holds every device); without it the first
// row also measures the cache's misses. --server-cpu / --client-cpu pin the forked server and
// this load client to one core each (sched_setaffinity), so that on a 2-core machine they do
// not compete for the same core.
//
// 1. Populates a fresh SQLite file through storage::Store (no direct SQL): `devices` devices,
//    `versions` parameter versions each (the last one active, the others superseded). Each
//    version carries a ~2 KB "imucal-params v1" document (formats::ParamSetToJson of a
//    realistic, per-version random parameter set with stderrs and effects) and an ~8 KB report_json
//    stand-in (the same row holds both; GetActive reads only params_json). The Store has no
//    bulk API, so this is one transaction per call (CreateDevice, AddVersion with its audit row).
// 2. Starts imucal::server::Server on that file in a forked child (127.0.0.1:0) and, from this
//    process, keeps C calls in flight (gRPC callback API, C chains of one call each) for
//    `seconds`, each for a uniformly random device; the latency of every call is recorded.
//    Rows: C = each of --callers, full fetch, and the same with if_not_version = the active
//    version (the robot's "unchanged?" check: header only).
// 3. Store::GetActive in-process (no gRPC), one thread: the SQLite part of the latency.
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <mutex>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "bench/bench_flags.h"
#include "bench/service_bench_util.h"
#include "core/params.h"
#include "formats/params_json.h"
#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/server.h"
#include "storage/store.h"

namespace {

namespace v1 = imucal::v1;
using namespace imucal::bench;  // Clock, Seconds, ForkServer, ... (service_bench_util.h)

struct Flags {
  int devices = 10000;
  int versions = 10;
  double seconds = 3.0;
  std::vector<int> callers = {1, 64};
  std::string db;
  int channels = 1;  // HTTP/2 connections the callers are spread over
  bool keep = false;
  bool warm = false;
  int server_cpu = -1;
  int client_cpu = -1;
  bool metrics = false;
};

Flags ParseFlags(int argc, char** argv) {
  Flags f;
  CLI::App app{
      "Active-parameters fetch (GetActiveParameters) for random devices against a fleet-sized "
      "SQLite store, from a forked server.",
      "fetch_bench"};
  app.add_option("--devices", f.devices, "devices in the store");
  app.add_option("--versions", f.versions, "parameter versions per device (the last active)");
  app.add_option("--seconds", f.seconds, "seconds per row");
  app.add_option("--callers", f.callers, "calls in flight, one row each, comma-separated")
      ->delimiter(',')
      ->check(CLI::Range(1, std::numeric_limits<int>::max()).description("POSITIVE"));
  app.add_option("--channels", f.channels,
                 "HTTP/2 connections the callers are spread over (at least 1)");
  app.add_option("--db", f.db,
                 "the store: populated there if missing, reused if present "
                 "(default: a fresh one in a temp directory)");
  app.add_flag("--keep", f.keep, "keep the temp directory");
  app.add_flag("--warm", f.warm, "fetch every device once before the rows (a warm cache)");
  app.add_option("--server-cpu", f.server_cpu, "pin the server to this core (-1: no pinning)");
  app.add_option("--client-cpu", f.client_cpu, "pin this client to this core (-1: no pinning)");
  app.add_flag("--metrics", f.metrics,
               "the server keeps Prometheus metrics (every call intercepted and counted)");
  imucal::bench::ParseBenchFlags(app, argc, argv);
  f.channels = std::max(1, f.channels);
  return f;
}

std::string DeviceId(int i) { return absl::StrFormat("robot-%05d", i); }

// A realistic parameter set: magnitudes of core/simulator.h's RandomTruth, random per version.
imucal::core::ParamSet RandomParams(std::mt19937_64& rng, const std::string& device, int version) {
  std::normal_distribution<double> n(0.0, 1.0);
  auto vec = [&](double sigma, double mean = 0.0) {
    return Eigen::Vector3d(mean + sigma * n(rng), mean + sigma * n(rng), mean + sigma * n(rng));
  };
  imucal::core::ParamSet p;
  p.device = device;
  p.version = version;
  p.created_at = "2025-03-14T09:26:53Z";
  p.accel.bias = vec(0.05 * 9.80665);
  p.accel.scale = vec(0.01, 1.0);
  p.accel.tri_angles = vec(0.003);
  p.accel.frame_angles = vec(0.01);
  p.accel.quadratic = vec(3e-5);
  p.gyro.matrix = Eigen::Matrix3d::Identity();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) p.gyro.matrix(i, j) += (i == j ? 0.015 : 0.003) * n(rng);
  p.gyro.bias = vec(0.5 * 3.14159265358979 / 180);
  p.gyro_calibrated = true;
  p.stderrs.accel.bias = vec(1e-4).cwiseAbs();
  p.stderrs.accel.scale = vec(1e-5).cwiseAbs();
  p.stderrs.accel.tri_angles = vec(1e-5).cwiseAbs();
  p.stderrs.accel.frame_angles = vec(1e-5).cwiseAbs();
  p.stderrs.accel.quadratic = vec(1e-6).cwiseAbs();
  p.stderrs.gyro_matrix = Eigen::Matrix3d::Constant(2e-4);
  p.stderrs.gyro_bias = vec(1e-5).cwiseAbs();
  for (int axis = 0; axis < 3; ++axis) {
    imucal::core::Effect e;
    e.sensor = imucal::core::Sensor::kGyro;
    e.axis = axis;
    e.regressor = "temperature";
    e.coefficient = 1e-4 * n(rng);
    e.std_error = 3e-6;
    e.error_before = 0.0021;
    e.error_after = 0.0017;
    e.evidence = "held-out residual drops 19% with the warm-up temperature";
    p.effects.push_back(e);
  }
  p.quality_accel_rms_m_s2 = 0.004 + 0.001 * std::abs(n(rng));
  p.quality_gyro_static_rms_rad_s = 0.0009;
  p.source_session = absl::StrFormat("s-%032x", rng());
  p.software = "imucal 0.1.0 (bench)";
  return p;
}

void Populate(const Flags& flags, const std::string& path) {
  absl::StatusOr<std::unique_ptr<imucal::storage::Store>> store =
      imucal::storage::Store::Open(path);
  if (!store.ok()) {
    std::fprintf(stderr, "open: %s\n", std::string(store.status().message()).c_str());
    std::exit(1);
  }
  std::mt19937_64 rng(1);
  // A stand-in for the version's "imucal-report v1" document (same row, not read by GetActive).
  const std::string report_json =
      "{\"format\":\"imucal-report v1\",\"padding\":\"" + std::string(8000, 'x') + "\"}";
  const Clock::time_point t0 = Clock::now();
  size_t json_bytes = 0;
  for (int i = 0; i < flags.devices; ++i) {
    imucal::storage::Device d;
    d.id = DeviceId(i);
    d.sensor_model = "MPU-6050";
    d.nominal_rate_hz = 200;
    d.accel_unit = "m/s^2";
    d.gyro_unit = "rad/s";
    if (absl::StatusOr<imucal::storage::Device> s = (*store)->CreateDevice(d, "bench"); !s.ok()) {
      std::fprintf(stderr, "CreateDevice: %s\n", std::string(s.status().message()).c_str());
      std::exit(1);
    }
  }
  const double devices_s = Seconds(Clock::now() - t0);
  const Clock::time_point t1 = Clock::now();
  for (int v = 1; v <= flags.versions; ++v) {
    for (int i = 0; i < flags.devices; ++i) {
      imucal::storage::ParamVersion pv;
      pv.device_id = DeviceId(i);
      pv.params_json = imucal::formats::ParamSetToJson(RandomParams(rng, pv.device_id, v));
      json_bytes += pv.params_json.size();
      pv.report_json = report_json;
      pv.verdict = imucal::storage::Verdict::kPass;
      pv.accel_rms = 0.004;
      pv.state = imucal::storage::VersionState::kActive;
      pv.provenance = "imucal 0.1.0; bsas seed 1; six-face";
      if (absl::StatusOr<imucal::storage::ParamVersion> s = (*store)->AddVersion(pv, "bench");
          !s.ok()) {
        std::fprintf(stderr, "AddVersion: %s\n", std::string(s.status().message()).c_str());
        std::exit(1);
      }
    }
    std::fprintf(stderr, "  populated versions up to %d (%.1f s)\n", v, Seconds(Clock::now() - t1));
  }
  const double versions_s = Seconds(Clock::now() - t1);
  const int64_t total = static_cast<int64_t>(flags.devices) * flags.versions;
  std::printf(
      "populated %d devices in %.1f s (%.0f/s), %lld versions in %.1f s (%.0f/s); "
      "params_json %.0f bytes on average\n",
      flags.devices, devices_s, flags.devices / devices_s, static_cast<long long>(total),
      versions_s, static_cast<double>(total) / versions_s,
      static_cast<double>(json_bytes) / static_cast<double>(total));
}

// One chain of calls: each completion records its latency and issues the next call.
struct Run {
  std::vector<v1::ParameterService::Stub*> stubs;
  int devices = 0;
  bool if_not_version = false;
  std::vector<int> active_version;  // per device, for if_not_version
  Clock::time_point deadline;
  std::mutex mu;
  std::condition_variable cv;
  int running = 0;
  int64_t errors = 0;
  std::string first_error;
  std::vector<double> latencies_us;
  int64_t bytes = 0;
};

class Chain {
 public:
  Chain(Run* run, uint64_t seed, v1::ParameterService::Stub* stub)
      : run_(run), stub_(stub), rng_(seed) {
    latencies_.reserve(1 << 16);
  }
  void Next() {
    context_ = std::make_unique<grpc::ClientContext>();
    context_->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    const int d = static_cast<int>(rng_() % static_cast<uint64_t>(run_->devices));
    request_.set_device_id(DeviceId(d));
    request_.set_if_not_version(run_->if_not_version ? run_->active_version[d] : 0);
    start_ = Clock::now();
    stub_->async()->GetActiveParameters(context_.get(), &request_, &response_,
                                        [this](grpc::Status s) { Done(std::move(s)); });
  }

 private:
  void Done(grpc::Status status) {
    const Clock::time_point now = Clock::now();
    latencies_.push_back(1e6 * Seconds(now - start_));
    if (!status.ok()) {
      ++errors_;
      if (first_error_.empty()) first_error_ = status.error_message();
    }
    bytes_ += static_cast<int64_t>(response_.json().size());
    if (now < run_->deadline) {
      Next();
      return;
    }
    std::lock_guard lock(run_->mu);
    run_->latencies_us.insert(run_->latencies_us.end(), latencies_.begin(), latencies_.end());
    run_->errors += errors_;
    if (run_->first_error.empty()) run_->first_error = first_error_;
    run_->bytes += bytes_;
    if (--run_->running == 0) run_->cv.notify_all();
  }

  Run* run_;
  v1::ParameterService::Stub* stub_;
  std::mt19937_64 rng_;
  std::unique_ptr<grpc::ClientContext> context_;
  v1::GetActiveParametersRequest request_;
  v1::ParameterSet response_;
  Clock::time_point start_;
  std::vector<double> latencies_;
  int64_t errors_ = 0;
  std::string first_error_;
  int64_t bytes_ = 0;
};

void PrintRow(const char* what, int callers, std::vector<double>& lat, double wall_s,
              int64_t errors, double cli_cpu, double srv_cpu, const std::string& load) {
  const double mx = lat.empty() ? 0 : *std::max_element(lat.begin(), lat.end());
  const size_t n = lat.size();
  const double p50 = Percentile(lat, 0.5), p99 = Percentile(lat, 0.99),
               p999 = Percentile(lat, 0.999);
  std::printf("%-22s %7d %9zu %10.0f %8.3f %8.3f %8.3f %8.2f %6lld %7.0f%% %7.0f%%  %s\n", what,
              callers, n, static_cast<double>(n) / wall_s, p50 / 1e3, p99 / 1e3, p999 / 1e3,
              mx / 1e3, static_cast<long long>(errors), 100 * cli_cpu / wall_s,
              100 * srv_cpu / wall_s, load.c_str());
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  const Flags flags = ParseFlags(argc, argv);
  std::string dir;
  std::string db = flags.db;
  if (db.empty() || !std::filesystem::exists(db)) {
    char tmpl[] = "/tmp/imucal-fetch-bench-XXXXXX";
    if (mkdtemp(tmpl) == nullptr) return 1;
    dir = tmpl;
    if (db.empty()) db = dir + "/fetch.db";
    std::printf("populating %s (load %s)\n", db.c_str(), LoadAvg().c_str());
    Populate(flags, db);
  } else {
    std::printf("reusing %s\n", db.c_str());
  }
  std::error_code ec;
  std::printf("db size %.1f MB\n\n", static_cast<double>(std::filesystem::file_size(db, ec)) / 1e6);

  // The active version per device (the last one added): for the if_not_version rows.
  std::vector<int> active(static_cast<size_t>(flags.devices), flags.versions);

  Child child = ForkServer(db, flags.server_cpu, flags.metrics ? "127.0.0.1:0" : "");
  PinToCpu(flags.client_cpu);  // after the fork: the server keeps its own core
  {
    std::vector<std::unique_ptr<v1::ParameterService::Stub>> stubs;
    for (int i = 0; i < flags.channels; ++i) {
      grpc::ChannelArguments args;
      args.SetInt("imucal.bench.channel", i);  // distinct args: a connection per channel
      args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
      stubs.push_back(v1::ParameterService::NewStub(grpc::CreateCustomChannel(
          absl::StrCat("127.0.0.1:", child.port), grpc::InsecureChannelCredentials(), args)));
    }
    v1::ParameterService::Stub* stub = stubs[0].get();
    // Warm-up: connect, and one call per 10th device (touches a share of the pages), or every
    // device with --warm.
    for (int i = 0; i < flags.devices; i += flags.warm ? 1 : 10) {
      v1::GetActiveParametersRequest req;
      req.set_device_id(DeviceId(i));
      v1::ParameterSet out;
      grpc::ClientContext c;
      grpc::Status s = stub->GetActiveParameters(&c, req, &out);
      if (!s.ok()) {
        std::fprintf(stderr, "warm-up %s: %s\n", req.device_id().c_str(),
                     s.error_message().c_str());
        return 1;
      }
    }
    std::printf(
        "GetActiveParameters, random device of %d, %.1f s per row, %d channel(s), "
        "server pid %d, %s, server cpu %d, client cpu %d (-1: any):\n",
        flags.devices, flags.seconds, flags.channels, static_cast<int>(child.pid),
        flags.warm ? "every device fetched once before" : "a tenth fetched before",
        flags.server_cpu, flags.client_cpu);
    std::printf("%-22s %7s %9s %10s %8s %8s %8s %8s %6s %8s %8s  %s\n", "call", "callers", "calls",
                "calls/s", "p50_ms", "p99_ms", "p999_ms", "max_ms", "errors", "cli_cpu", "srv_cpu",
                "loadavg(before)");
    for (int if_not : {0, 1}) {
      for (int c : flags.callers) {
        Run run;
        run.devices = flags.devices;
        run.if_not_version = if_not != 0;
        run.active_version = active;
        run.running = c;
        std::vector<std::unique_ptr<Chain>> chains;
        for (int i = 0; i < c; ++i) {
          chains.push_back(std::make_unique<Chain>(
              &run, 1000 + i, stubs[static_cast<size_t>(i) % stubs.size()].get()));
        }
        const std::string load = LoadAvg();
        const double cli0 = SelfCpuS(), srv0 = ProcCpuS(child.pid);
        const Clock::time_point t0 = Clock::now();
        run.deadline = t0 + std::chrono::microseconds(static_cast<int64_t>(flags.seconds * 1e6));
        for (auto& chain : chains) chain->Next();
        {
          std::unique_lock lock(run.mu);
          run.cv.wait(lock, [&] { return run.running == 0; });
        }
        const double wall = Seconds(Clock::now() - t0);
        PrintRow(if_not ? "GetActive (unchanged)" : "GetActive (full)", c, run.latencies_us, wall,
                 run.errors, SelfCpuS() - cli0, ProcCpuS(child.pid) - srv0, load);
        if (run.errors > 0) std::fprintf(stderr, "  first error: %s\n", run.first_error.c_str());
      }
    }
  }
  StopServer(child);

  // The SQLite part alone: Store::GetActive in this process, one thread.
  {
    absl::StatusOr<std::unique_ptr<imucal::storage::Store>> store =
        imucal::storage::Store::Open(db);
    if (store.ok()) {
      std::mt19937_64 rng(5);
      std::vector<double> lat;
      const std::string load = LoadAvg();
      const double cli0 = SelfCpuS();
      const Clock::time_point t0 = Clock::now();
      while (Seconds(Clock::now() - t0) < flags.seconds) {
        const std::string id = DeviceId(static_cast<int>(rng() % flags.devices));
        const Clock::time_point s = Clock::now();
        absl::StatusOr<imucal::storage::ParamVersion> v = (*store)->GetActive(id);
        lat.push_back(1e6 * Seconds(Clock::now() - s));
        if (!v.ok()) {
          std::fprintf(stderr, "GetActive: %s\n", std::string(v.status().message()).c_str());
          break;
        }
      }
      const double wall = Seconds(Clock::now() - t0);
      PrintRow("Store::GetActive (no rpc)", 1, lat, wall, 0, SelfCpuS() - cli0, 0, load);
    }
  }
  if (!dir.empty() && !flags.keep)
    std::filesystem::remove_all(dir, ec);
  else if (!dir.empty())
    std::printf("kept %s\n", dir.c_str());
  return 0;
}
