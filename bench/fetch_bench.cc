// Active-parameters fetch (the robot-startup hot path): ParameterService.GetActiveParameters for
// random devices against a fleet-sized store (SQLite, or PostgreSQL with one or more servers).
//
//   ninja -C build-perf fetch_bench
//   build-perf/bench/fetch_bench [--devices=10000] [--versions=10] [--seconds=3]
//                                [--callers=1,64] [--channels=1]
//                                [--db=PATH|postgresql://... (populated if it holds no fleet,
//                                 reused if it holds this one)]
//                                [--replicas=1] [--keep]
//                                [--warm] [--server-cpu=N] [--client-cpu=N]
//
// --warm fetches every device once before the rows (a fleet whose robots have all booted since
// the server started: the server's response cache holds every device); without it the first
// row also measures the cache's misses. --server-cpu / --client-cpu pin the forked server(s) and
// this load client to one core each (sched_setaffinity), so that on a 2-core machine they do
// not compete for the same core.
//
// --db=postgresql://... keeps the fleet in that PostgreSQL database (deploy/pg-throwaway.sh
// start prints one), and --replicas=R forks R servers on it (replica_id bench-1..R, README
// "Several servers on one database"). --channels is then per server: connection k goes to
// server k % R, caller i uses connection i % (R * channels), so the callers are spread evenly
// and each server has its own fetch cache to fill (--warm warms every server's). db_cpu is the
// PostgreSQL cluster's CPU (its postmaster and every process under it); "-" for SQLite, whose
// reads are in the server's CPU.
//
// Reuse: a SQLite --db PATH is reused if the file exists. A PostgreSQL database is reused if it
// holds this fleet (the last device, with version `versions` active), populated if it holds no
// device, and refused otherwise. Population is one transaction per Store call, 110,000 of them
// for 10,000 devices x 10 versions: on this 2-core machine 1.8 min on SQLite (devices 36 s at
// 275/s, each commit fsynced; versions 74 s) and 1.8 min on a throwaway PostgreSQL at fsync=off
// (devices 4 s, versions 103 s at 970/s: a SERIALIZABLE transaction of several round trips
// each); a PostgreSQL that fsyncs would be slower. Populate once and pass the same --db again.
//
// 1. Populates the store through storage::Store (no direct SQL): `devices` devices,
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
// 3. Store::GetActive in-process (no gRPC), one thread: the database's part of the latency
//    (SQLite in this process; PostgreSQL: a round trip to its backend on loopback).
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
  int replicas = 1;  // servers on the database
};

Flags ParseFlags(int argc, char** argv) {
  Flags f;
  CLI::App app{
      "Active-parameters fetch (GetActiveParameters) for random devices against a fleet-sized "
      "store (SQLite or PostgreSQL), from one or more forked servers.",
      "fetch_bench"};
  app.add_option("--devices", f.devices, "devices in the store");
  app.add_option("--versions", f.versions, "parameter versions per device (the last active)");
  app.add_option("--seconds", f.seconds, "seconds per row");
  app.add_option("--callers", f.callers, "calls in flight, one row each, comma-separated")
      ->delimiter(',')
      ->check(CLI::Range(1, std::numeric_limits<int>::max()).description("POSITIVE"));
  app.add_option("--channels", f.channels,
                 "HTTP/2 connections per server the callers are spread over (at least 1)");
  app.add_option("--db", f.db,
                 "the store, a SQLite file or a postgresql:// URL: populated if it holds no "
                 "fleet, reused if it holds this one (default: a fresh SQLite file in a temp "
                 "directory)");
  app.add_option("--replicas", f.replicas,
                 "servers forked on the database, callers spread over them")
      ->check(CLI::Range(1, 64));
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

std::unique_ptr<imucal::storage::Store> OpenStore(const std::string& db) {
  absl::StatusOr<std::unique_ptr<imucal::storage::Store>> store = imucal::storage::Store::Open(db);
  if (!store.ok()) {
    std::fprintf(stderr, "open %s: %s\n", imucal::sql::RedactedLocation(db).c_str(),
                 std::string(store.status().message()).c_str());
    std::exit(1);
  }
  return *std::move(store);
}

// Whether the PostgreSQL database at `url` must be populated: false if it holds this fleet,
// true if it holds no device; exits if it holds something else.
bool PostgresNeedsFleet(const Flags& flags, const std::string& url) {
  std::unique_ptr<imucal::storage::Store> store = OpenStore(url);
  absl::StatusOr<imucal::storage::Device> last = store->GetDevice(DeviceId(flags.devices - 1));
  if (last.ok() && last->active_version == flags.versions) return false;
  absl::StatusOr<std::vector<imucal::storage::Device>> any = store->ListDevices("", 1);
  if (!last.ok() && absl::IsNotFound(last.status()) && any.ok() && any->empty()) return true;
  std::fprintf(stderr,
               "%s holds devices, but not this fleet (%s with version %d active): use an empty "
               "database, or the --devices and --versions it was populated with\n",
               imucal::sql::RedactedLocation(url).c_str(), DeviceId(flags.devices - 1).c_str(),
               flags.versions);
  std::exit(1);
}

void Populate(const Flags& flags, const std::string& path) {
  std::unique_ptr<imucal::storage::Store> store = OpenStore(path);
  std::mt19937_64 rng(1);
  // A stand-in for the version's "imucal-report v1" document (same row, not read by GetActive).
  const std::string report_json =
      "{\"format\":\"imucal-report v1\",\"padding\":\"" + std::string(8000, 'x') + "\"}";
  const Clock::time_point t0 = Clock::now();
  size_t json_bytes = 0;
  for (int i = 0; i < flags.devices; ++i) {
    if (absl::StatusOr<imucal::storage::Device> s =
            store->CreateDevice(BenchDevice(DeviceId(i)), "bench");
        !s.ok()) {
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
      if (absl::StatusOr<imucal::storage::ParamVersion> s = store->AddVersion(pv, "bench");
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
    device_ = static_cast<int>(rng_() % static_cast<uint64_t>(run_->devices));
    request_.set_device_id(DeviceId(device_));
    request_.set_if_not_version(run_->if_not_version ? run_->active_version[device_] : 0);
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
    } else if (response_.device_id() != request_.device_id() ||
               response_.version() != run_->active_version[device_]) {
      // An answer for another device or version (a stale cache): counted as an error.
      ++errors_;
      if (first_error_.empty())
        first_error_ = absl::StrCat("asked for ", request_.device_id(), " (active version ",
                                    run_->active_version[device_], "), got ", response_.device_id(),
                                    " version ", response_.version());
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
  int device_ = 0;  // of the call in flight
  v1::GetActiveParametersRequest request_;
  v1::ParameterSet response_;
  Clock::time_point start_;
  std::vector<double> latencies_;
  int64_t errors_ = 0;
  std::string first_error_;
  int64_t bytes_ = 0;
};

// One row; db_cpu < 0: not measured ("-"). `split`: each server's CPU, printed below the row
// when there are several.
void PrintRow(const char* what, int callers, std::vector<double>& lat, double wall_s,
              int64_t errors, double cli_cpu, double srv_cpu, double db_cpu,
              const std::string& load, const std::vector<double>& split = {}) {
  const double mx = lat.empty() ? 0 : *std::max_element(lat.begin(), lat.end());
  const size_t n = lat.size();
  const double p50 = Percentile(lat, 0.5), p99 = Percentile(lat, 0.99),
               p999 = Percentile(lat, 0.999);
  const std::string db = db_cpu < 0 ? "-" : absl::StrFormat("%.0f%%", 100 * db_cpu / wall_s);
  std::printf("%-25s %7d %9zu %10.0f %8.3f %8.3f %8.3f %8.2f %6lld %7.0f%% %7.0f%% %7s  %s\n", what,
              callers, n, static_cast<double>(n) / wall_s, p50 / 1e3, p99 / 1e3, p999 / 1e3,
              mx / 1e3, static_cast<long long>(errors), 100 * cli_cpu / wall_s,
              100 * srv_cpu / wall_s, db.c_str(), load.c_str());
  if (split.size() > 1) {
    std::string line;
    for (double cpu : split)
      absl::StrAppend(&line, " ", absl::StrFormat("%.0f%%", 100 * cpu / wall_s));
    std::printf("%-25s srv_cpu per server:%s\n", "", line.c_str());
  }
  std::fflush(stdout);
}

// The database to fetch from: --db as it is, or populated first (a fresh SQLite file in a temp
// directory, `*dir`, when --db is empty). Prints what it is.
std::string PrepareDb(const Flags& flags, std::string* dir) {
  std::string db = flags.db;
  const bool pg = imucal::sql::IsPostgresUrl(db);
  const bool populate =
      pg ? PostgresNeedsFleet(flags, db) : db.empty() || !std::filesystem::exists(db);
  if (populate) {
    if (db.empty()) {
      char tmpl[] = "/tmp/imucal-fetch-bench-XXXXXX";
      if (mkdtemp(tmpl) == nullptr) std::exit(1);
      *dir = tmpl;
      db = *dir + "/fetch.db";
    }
    std::printf("populating %s (load %s)\n", DescribeDb(db).c_str(), LoadAvg().c_str());
    std::fflush(stdout);  // before Populate's progress lines on stderr
    Populate(flags, db);
  } else {
    std::printf("reusing %s\n", DescribeDb(db).c_str());
  }
  std::error_code ec;
  if (!pg)
    std::printf("db size %.1f MB\n", static_cast<double>(std::filesystem::file_size(db, ec)) / 1e6);
  std::printf("\n");
  return db;
}

// Each server's cache (channel s goes to server s): connect, and one call per 10th device
// (touches a share of the pages), or every device with --warm. False when a call failed.
bool WarmUp(const Flags& flags, size_t servers,
            const std::vector<std::unique_ptr<v1::ParameterService::Stub>>& stubs) {
  for (size_t server = 0; server < servers; ++server) {
    for (int i = 0; i < flags.devices; i += flags.warm ? 1 : 10) {
      v1::GetActiveParametersRequest req;
      req.set_device_id(DeviceId(i));
      v1::ParameterSet out;
      grpc::ClientContext c;
      grpc::Status s = stubs[server]->GetActiveParameters(&c, req, &out);
      if (!s.ok()) {
        std::fprintf(stderr, "warm-up %s on server %zu: %s\n", req.device_id().c_str(), server + 1,
                     s.error_message().c_str());
        return false;
      }
    }
  }
  return true;
}

// The CPU meters of a row: this client, each server, the database's cluster (when local).
struct CpuMeters {
  const std::vector<Child>* servers;
  const std::optional<PostgresCpu>* pg_cpu;
  bool db_measured() const { return pg_cpu->has_value(); }
  double DbCpuS() const { return db_measured() ? (*pg_cpu)->CpuS() : 0.0; }
};

// One row of RPCs: `callers` chains for --seconds, asking for the full document or (if_not)
// with if_not_version set to the active one. Returns its errors.
int64_t RpcRow(const Flags& flags, const CpuMeters& cpu, bool if_not, int callers,
               const std::vector<std::unique_ptr<v1::ParameterService::Stub>>& stubs) {
  Run run;
  run.devices = flags.devices;
  run.if_not_version = if_not;
  // The active version per device (the last one added): what every answer must carry, and the
  // if_not_version of the "unchanged" rows.
  run.active_version.assign(static_cast<size_t>(flags.devices), flags.versions);
  run.running = callers;
  std::vector<std::unique_ptr<Chain>> chains;
  for (int i = 0; i < callers; ++i) {
    chains.push_back(std::make_unique<Chain>(&run, 1000 + i,
                                             stubs[static_cast<size_t>(i) % stubs.size()].get()));
  }
  const std::string load = LoadAvg();
  const double cli0 = SelfCpuS(), db0 = cpu.DbCpuS();
  const std::vector<double> srv0 = ServersCpuS(*cpu.servers);
  const Clock::time_point t0 = Clock::now();
  run.deadline = t0 + std::chrono::microseconds(static_cast<int64_t>(flags.seconds * 1e6));
  for (auto& chain : chains) chain->Next();
  {
    std::unique_lock lock(run.mu);
    run.cv.wait(lock, [&] { return run.running == 0; });
  }
  const double wall = Seconds(Clock::now() - t0);
  std::vector<double> srv = ServersCpuS(*cpu.servers);
  for (size_t i = 0; i < srv.size(); ++i) srv[i] -= srv0[i];
  PrintRow(if_not ? "GetActive (unchanged)" : "GetActive (full)", callers, run.latencies_us, wall,
           run.errors, SelfCpuS() - cli0, Sum(srv), cpu.db_measured() ? cpu.DbCpuS() - db0 : -1,
           load, srv);
  if (run.errors > 0) std::fprintf(stderr, "  first error: %s\n", run.first_error.c_str());
  return run.errors;
}

// The rows through the servers; their errors, or -1 when the warm-up failed.
int64_t RpcRows(const Flags& flags, const std::string& db, const CpuMeters& cpu) {
  const std::vector<Child>& servers = *cpu.servers;
  const std::vector<std::shared_ptr<grpc::Channel>> channels =
      RoundRobinChannels(servers, flags.channels);
  std::vector<std::unique_ptr<v1::ParameterService::Stub>> stubs;
  for (const auto& channel : channels) stubs.push_back(v1::ParameterService::NewStub(channel));
  if (!WarmUp(flags, servers.size(), stubs)) return -1;
  std::string pids;
  for (const Child& child : servers) absl::StrAppend(&pids, pids.empty() ? "" : ",", child.pid);
  const bool pg = imucal::sql::IsPostgresUrl(db);
  std::printf(
      "GetActiveParameters, random device of %d, %.1f s per row, %d server(s) (pid %s) on %s, "
      "%d channel(s) per server, %s, server cpu %d, client cpu %d (-1: any)%s:\n",
      flags.devices, flags.seconds, static_cast<int>(servers.size()), pids.c_str(),
      DescribeDb(db).c_str(), flags.channels,
      flags.warm ? "every device fetched once before" : "a tenth fetched before", flags.server_cpu,
      flags.client_cpu,
      !pg                 ? ""
      : cpu.db_measured() ? "; db_cpu = the PostgreSQL cluster's"
                          : "; PostgreSQL not local: no db_cpu");
  std::printf("%-25s %7s %9s %10s %8s %8s %8s %8s %6s %8s %8s %7s  %s\n", "call", "callers",
              "calls", "calls/s", "p50_ms", "p99_ms", "p999_ms", "max_ms", "errors", "cli_cpu",
              "srv_cpu", "db_cpu", "loadavg(before)");
  int64_t errors = 0;  // failed calls and wrong answers, over the rows
  for (int if_not : {0, 1}) {
    for (int c : flags.callers) errors += RpcRow(flags, cpu, if_not != 0, c, stubs);
  }
  if (errors > 0)
    std::printf("errors: %lld (first errors on stderr)\n", static_cast<long long>(errors));
  return errors;
}

// The database's part alone: Store::GetActive in this process, one thread (SQLite in this
// process; PostgreSQL a round trip to its backend).
void StoreRow(const Flags& flags, const std::string& db, const CpuMeters& cpu) {
  absl::StatusOr<std::unique_ptr<imucal::storage::Store>> store = imucal::storage::Store::Open(db);
  if (!store.ok()) return;
  std::mt19937_64 rng(5);
  std::vector<double> lat;
  const std::string load = LoadAvg();
  const double cli0 = SelfCpuS(), db0 = cpu.DbCpuS();
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
  PrintRow("Store::GetActive (no rpc)", 1, lat, wall, 0, SelfCpuS() - cli0, 0,
           cpu.db_measured() ? cpu.DbCpuS() - db0 : -1, load);
}

}  // namespace

int main(int argc, char** argv) {
  const Flags flags = ParseFlags(argc, argv);
  std::string dir;
  const std::string db = PrepareDb(flags, &dir);
  const bool pg = imucal::sql::IsPostgresUrl(db);
  std::vector<Child> servers =
      ForkServers(db, flags.replicas, flags.server_cpu, flags.metrics ? "127.0.0.1:0" : "");
  PinToCpu(flags.client_cpu);  // after the fork: the servers keep their own core
  const std::optional<PostgresCpu> pg_cpu = pg ? PostgresCpu::Find(db) : std::nullopt;
  const CpuMeters cpu{&servers, &pg_cpu};
  const int64_t errors = RpcRows(flags, db, cpu);
  StopServers(servers);
  if (errors < 0) return 1;
  StoreRow(flags, db, cpu);
  std::error_code ec;
  if (!dir.empty() && !flags.keep)
    std::filesystem::remove_all(dir, ec);
  else if (!dir.empty())
    std::printf("kept %s\n", dir.c_str());
  return errors == 0 ? 0 : 1;
}
