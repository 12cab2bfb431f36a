// The load test: a bounded, self-stopping run on loopback against the real imucald
// binary (its own process, so its CPU and memory are its own) of
//   - R robots streaming at 200 Hz, paced: each sends a batch every --batch-ms (default 500 ms,
//     100 samples; at 100 ms, 10,000 batches/s, this 2-core machine falls behind: README
//     "Durability and load") with the samples of that period (200 Hz timestamps, a simulated
//     six-face capture replayed), one StreamSamples stream per robot, batches sent on
//     schedule whether or not the previous ack has come back (as the SDK's Uploader does,
//     with its window of batches in flight);
//   - W technicians following the first W robots' sessions (WatchSession streams);
//   - startup fetches from F devices (GetActiveParameters, each device's active version
//     prepared beforehand): devices boot at --fetch-rate per second, in device order, looping
//     over the fleet for the whole run; each fetch is sent at its time (open loop).
// It measures the ingest throughput, p50/p99/max latency of acks (send -> the ack covering the
// batch) and of fetches, the watchers' event delay (server event time -> received), errors by
// gRPC code, late sends (a robot whose previous batch is still being written when the next is
// due: the transport pushed back), the server's CPU per thread and its peak memory (VmHWM of
// /proc/PID/status), and says whether the server kept up.
//
//   ninja -C build bench/load_bench imucald
//   build/bench/load_bench [--robots=1000] [--batch-ms=500] [--rate-hz=200] [--watchers=20]
//                          [--devices=10000] [--fetch-rate=1000] [--seconds=60] [--channels=8]
//                          [--imucald=PATH] [--server-args="--insecure ..."] [--keep]
//                          [--server-cpu=N] [--client-cpu=N] [--tls]
// (--server-args: imucald's other flags, default --insecure: plaintext on loopback; e.g. add
// --durability=normal or --log-rpcs=false to compare.)
// --tls: as production runs it: a throwaway certificate for 127.0.0.1 (the openssl CLI),
// imucald with --tls-cert/--tls-key and its bootstrap admin token, and every call of the bench
// over TLS with that token as its bearer token (checked, hashed and looked up on every call;
// one token for all callers, so the server's token cache holds one entry).
//
// Setup (not measured): a fresh SQLite file populated through storage::Store (synchronous=
// NORMAL for the setup only: it is scratch until the server opens it with its own, FULL,
// setting), the robots' devices and open sessions, and --devices devices with one active
// version each (a ~2 KB parameter document). Then imucald is started on it (fork + exec, a
// free loopback port) and the load runs for --seconds; at the deadline every robot half-closes
// its stream and the run waits for the last acks (the drain is reported). Not part of ctest.
//
// "Kept up": every batch acknowledged, no errors, ack p99 under one batch period and no
// robot fell behind its schedule by more than one batch.
//
// The clients (robots, watchers, fetches: gRPC callback reactors) are in load_bench_clients.h.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "bench/bench_flags.h"
#include "bench/load_bench_clients.h"
#include "bench/service_bench_util.h"
#include "core/params.h"
#include "core/simulator.h"
#include "formats/params_json.h"
#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/log.h"
#include "storage/store.h"

namespace {

namespace v1 = imucal::v1;
using namespace imucal::bench;  // Clock, Seconds, Percentile, ProcCpuS, ... (service_bench_util.h)

struct Flags {
  int robots = 1000;
  int batch_ms = 500;
  double rate_hz = 200;
  int watchers = 20;
  int devices = 10000;
  double fetch_rate = 1000;  // fetches per second
  double seconds = 60;
  int channels = 8;
  std::string imucald = IMUCAL_IMUCALD_PATH;
  // imucald's flags besides --listen and --db: plaintext on loopback (no TLS, no tokens).
  std::vector<std::string> server_args = {"--insecure"};
  bool keep = false;
  bool tls = false;
  int server_cpu = -1;
  int client_cpu = -1;
};

Flags ParseFlags(int argc, char** argv) {
  Flags f;
  std::string server_args = absl::StrJoin(f.server_args, " ");
  CLI::App app{
      "The load test: robots streaming, technicians watching sessions and fleet startup "
      "fetches against the imucald binary on loopback, for a bounded time.",
      "load_bench"};
  app.add_option("--robots", f.robots, "robots, one StreamSamples stream each");
  app.add_option("--batch-ms", f.batch_ms, "ms between a robot's batches (at least 1)");
  app.add_option("--rate-hz", f.rate_hz, "samples per second per robot");
  app.add_option("--watchers", f.watchers, "WatchSession streams, on the first robots' sessions");
  app.add_option("--devices", f.devices, "fleet devices with an active version, fetched in turn");
  app.add_option("--fetch-rate", f.fetch_rate, "startup fetches per second");
  app.add_option("--seconds", f.seconds, "seconds of load (then the drain)");
  app.add_option("--channels", f.channels,
                 "HTTP/2 connections the calls are spread over (at least 1)");
  app.add_option("--imucald", f.imucald, "the imucald binary to run");
  app.add_option("--server-args", server_args,
                 "imucald's flags besides --listen and --db, space-separated, in one word "
                 "(e.g. --server-args=\"--insecure --durability=normal\")");
  app.add_flag("--keep", f.keep, "keep the temp directory");
  app.add_flag("--tls", f.tls,
               "TLS and a bearer token on every call, as production runs it (replaces "
               "--insecure)");
  app.add_option("--server-cpu", f.server_cpu, "pin imucald to this core (-1: no pinning)");
  app.add_option("--client-cpu", f.client_cpu, "pin this client to this core (-1: no pinning)");
  imucal::bench::ParseBenchFlags(app, argc, argv);
  f.server_args = absl::StrSplit(server_args, ' ', absl::SkipEmpty());
  f.batch_ms = std::max(1, f.batch_ms);
  f.channels = std::max(1, f.channels);
  const int per_batch = static_cast<int>(f.rate_hz * f.batch_ms / 1000.0 + 0.5);
  if (f.robots < 0 || f.devices < 0 || f.watchers < 0 || f.watchers > f.robots || per_batch < 1 ||
      f.seconds <= 0 || f.fetch_rate < 0) {
    std::fprintf(stderr,
                 "bad flags: need 0 <= watchers <= robots, devices >= 0, seconds > 0, "
                 "rate_hz * batch_ms >= 1 sample\n");
    std::exit(2);
  }
  return f;
}

std::string RobotId(int i) { return absl::StrFormat("load-robot-%05d", i); }
std::string FleetId(int i) { return absl::StrFormat("fleet-%05d", i); }

// ---- Samples: a simulated six-face capture as columns, replayed lap after lap.
Columns RobotColumns(double rate_hz) {
  imucal::core::SimOptions o;
  o.seed = 7;
  o.rate_hz = rate_hz;
  return MakeColumns(o);
}

// ---- Setup: robots' devices and sessions, the fleet's devices with an active version each.
std::vector<std::string> Populate(const Flags& flags, const std::string& path) {
  imucal::storage::StoreOptions options;
  options.durability = imucal::storage::Durability::kNormal;  // scratch until imucald opens it
  absl::StatusOr<std::unique_ptr<imucal::storage::Store>> store =
      imucal::storage::Store::Open(path, options);
  if (!store.ok()) {
    std::fprintf(stderr, "open: %s\n", std::string(store.status().message()).c_str());
    std::exit(1);
  }
  auto check = [](const absl::Status& s, const char* what) {
    if (s.ok()) return;
    std::fprintf(stderr, "%s: %s\n", what, std::string(s.message()).c_str());
    std::exit(1);
  };
  std::vector<std::string> sessions;
  for (int i = 0; i < flags.robots; ++i) {
    check((*store)->CreateDevice(BenchDevice(RobotId(i)), "bench").status(), "CreateDevice");
    imucal::storage::Session s;
    s.device_id = RobotId(i);
    s.protocol = "six-face";
    absl::StatusOr<imucal::storage::Session> created = (*store)->CreateSession(s, "bench");
    check(created.status(), "CreateSession");
    sessions.push_back(created->id);
  }
  imucal::core::ParamSet p;  // a realistic document: the fields a solve fills, ~2 KB of JSON
  p.accel.bias = Eigen::Vector3d(0.31, -0.12, 0.27);
  p.accel.scale = Eigen::Vector3d(1.004, 0.997, 1.011);
  p.accel.tri_angles = Eigen::Vector3d(0.002, -0.001, 0.003);
  p.gyro.matrix = Eigen::Matrix3d::Identity() * 1.01;
  p.gyro.bias = Eigen::Vector3d(0.004, -0.002, 0.006);
  p.gyro_calibrated = true;
  p.stderrs.accel.bias = Eigen::Vector3d::Constant(1e-4);
  p.stderrs.gyro_bias = Eigen::Vector3d::Constant(1e-5);
  p.software = "imucal (load bench)";
  for (int i = 0; i < flags.devices; ++i) {
    check((*store)->CreateDevice(BenchDevice(FleetId(i)), "bench").status(), "CreateDevice");
    p.device = FleetId(i);
    p.version = 1;
    imucal::storage::ParamVersion v;
    v.device_id = FleetId(i);
    v.params_json = imucal::formats::ParamSetToJson(p);
    v.report_json = "{\"format\":\"imucal-report v1\"}";
    v.verdict = imucal::storage::Verdict::kPass;
    v.accel_rms = 0.004;
    v.state = imucal::storage::VersionState::kActive;
    v.provenance = "load bench";
    check((*store)->AddVersion(v, "bench").status(), "AddVersion");
  }
  return sessions;
}

// Per thread of `pid`, keyed "name/tid": seconds on a CPU and seconds runnable but waiting for
// one (/proc/PID/task/TID/schedstat: run time and run-queue wait, in ns).
struct ThreadTimes {
  double cpu_s = 0, wait_s = 0;
};
std::map<std::string, ThreadTimes> ThreadCpuS(pid_t pid) {
  std::map<std::string, ThreadTimes> out;
  std::error_code ec;
  for (const auto& e :
       std::filesystem::directory_iterator("/proc/" + std::to_string(pid) + "/task", ec)) {
    std::ifstream comm(e.path() / "comm");
    std::string name;
    std::getline(comm, name);
    std::ifstream schedstat(e.path() / "schedstat");
    double run_ns = 0, wait_ns = 0;
    if (!(schedstat >> run_ns >> wait_ns)) continue;
    out[absl::StrCat(name, "/", e.path().filename().string())] = {run_ns / 1e9, wait_ns / 1e9};
  }
  return out;
}

void PrintLatency(const char* what, std::vector<double>& us) {
  const size_t n = us.size();
  const double mx = us.empty() ? 0 : *std::max_element(us.begin(), us.end());
  const double p50 = Percentile(us, 0.50), p99 = Percentile(us, 0.99);
  std::printf("  %-34s n=%-9zu p50 %8.2f ms   p99 %8.2f ms   max %8.2f ms\n", what, n, p50 / 1e3,
              p99 / 1e3, mx / 1e3);
}

// imucald's flags besides --listen and --db. --tls: a certificate for 127.0.0.1 and the flags
// to serve it (replacing --insecure); every simulated robot and watcher shares the one admin
// token, so the per-token stream cap is raised to hold them all (a fleet gives each robot its
// own token). nullopt when the openssl CLI could not make the certificate.
std::optional<std::vector<std::string>> ServerArgs(const Flags& flags, const std::string& dir) {
  std::vector<std::string> args = flags.server_args;
  if (!flags.tls) return args;
  const std::vector<std::string> tls = TlsServerArgs(dir, dir + "/admin-token");
  if (tls.empty()) {
    std::fprintf(stderr, "--tls: the openssl CLI could not make a certificate\n");
    return std::nullopt;
  }
  std::erase(args, std::string("--insecure"));
  args.insert(args.end(), tls.begin(), tls.end());
  args.push_back(absl::StrCat("--max-streams-per-token=", flags.robots + flags.watchers));
  return args;
}

// The credentials of every call: plaintext, or with --tls the certificate's and imucald's first
// admin token. nullptr when imucald did not come up with the token.
std::shared_ptr<grpc::ChannelCredentials> CallCredentials(const Flags& flags,
                                                          const std::string& dir,
                                                          const std::string& listen) {
  if (!flags.tls) return grpc::InsecureChannelCredentials();
  const std::string token_file = dir + "/admin-token";
  const grpc::SslCredentialsOptions ssl = TrustBenchCertificate(dir);
  const std::optional<std::string> token = AwaitAdminToken(listen, ssl, token_file);
  if (!token || token->empty()) {
    std::fprintf(stderr, "--tls: imucald did not come up with an admin token in %s\n",
                 token_file.c_str());
    return nullptr;
  }
  return grpc::CompositeChannelCredentials(grpc::SslCredentials(ssl),
                                           grpc::AccessTokenCredentials(*token));
}

// `flags.channels` connections to imucald at `listen`, each connected; empty when it did not
// listen within 60 s.
std::vector<std::shared_ptr<grpc::Channel>> ConnectChannels(
    const Flags& flags, const std::string& listen,
    const std::shared_ptr<grpc::ChannelCredentials>& credentials) {
  std::vector<std::shared_ptr<grpc::Channel>> channels;
  for (int i = 0; i < flags.channels; ++i) channels.push_back(BenchChannel(listen, credentials, i));
  for (auto& ch : channels) {
    if (!ch->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(60))) {
      std::fprintf(stderr, "imucald did not listen on %s\n", listen.c_str());
      return {};
    }
  }
  return channels;
}

void KillImucald(pid_t server) {
  kill(server, SIGKILL);
  waitpid(server, nullptr, 0);
}

// The clients: one robot per session, watchers on the first robots' sessions, and the fleet's
// fetches; spread over the channels.
struct Clients {
  std::vector<std::unique_ptr<v1::SessionService::Stub>> session_stubs;
  std::vector<std::unique_ptr<v1::ParameterService::Stub>> param_stubs;
  std::vector<std::unique_ptr<Robot>> robots;
  std::vector<std::unique_ptr<Watcher>> watchers;
};

Clients MakeClients(const Flags& flags, int per, const Columns& col,
                    const std::vector<std::string>& sessions,
                    const std::vector<std::shared_ptr<grpc::Channel>>& channels, Stats* stats) {
  Clients c;
  for (auto& ch : channels) {
    c.session_stubs.push_back(v1::SessionService::NewStub(ch));
    c.param_stubs.push_back(v1::ParameterService::NewStub(ch));
  }
  std::mt19937_64 rng(1);
  for (int i = 0; i < flags.robots; ++i) {
    c.robots.push_back(std::make_unique<Robot>(
        stats, &col, per, c.session_stubs[static_cast<size_t>(i) % channels.size()].get(),
        sessions[static_cast<size_t>(i)], static_cast<int64_t>(rng() % col.n)));
  }
  for (int i = 0; i < flags.watchers; ++i) {
    c.watchers.push_back(std::make_unique<Watcher>(
        stats, c.session_stubs[static_cast<size_t>(i) % channels.size()].get(),
        sessions[static_cast<size_t>(i)]));
  }
  stats->robots_running = flags.robots;
  stats->watchers_running = flags.watchers;
  return c;
}

constexpr int kMaxFetchesInFlight = 5000;

// What the pacer saw of itself and of imucald.
struct PacerFigures {
  int64_t peak_rss_kb = 0;
  int64_t fetches_skipped = 0;
  double late_ms = 0;  // the most a tick started after its time
};

// The pacer: a 1 ms tick from t0 for --seconds. Robot i is due at t0 + (i mod batch_ms) ms +
// k * batch_ms (phases spread over the period); fetches go out at fetch_rate, device after
// device. Samples imucald's RSS every 250 ms.
PacerFigures Pace(const Flags& flags, Clock::time_point t0, Clients& clients, Stats* stats,
                  pid_t server) {
  PacerFigures f;
  int64_t fetch_index = 0;
  const int64_t ticks = static_cast<int64_t>(flags.seconds * 1000);
  for (int64_t tick = 0; tick < ticks; ++tick) {
    const Clock::time_point at = t0 + std::chrono::milliseconds(tick);
    std::this_thread::sleep_until(at);  // the schedule itself
    f.late_ms = std::max(f.late_ms, 1e3 * Seconds(Clock::now() - at));
    for (int i = static_cast<int>(tick % flags.batch_ms); i < flags.robots; i += flags.batch_ms)
      clients.robots[static_cast<size_t>(i)]->Due();
    const int64_t fetch_due = static_cast<int64_t>(flags.fetch_rate * (tick + 1) / 1000.0);
    for (; flags.devices > 0 && fetch_index < fetch_due; ++fetch_index) {
      {
        std::lock_guard lock(stats->mu);
        if (stats->fetches_in_flight >= kMaxFetchesInFlight) {
          ++f.fetches_skipped;
          continue;
        }
        ++stats->fetches_in_flight;
        ++stats->fetches_sent;
      }
      Fetch::Send(
          stats,
          clients.param_stubs[static_cast<size_t>(fetch_index) % clients.param_stubs.size()].get(),
          FleetId(static_cast<int>(fetch_index % flags.devices)));
    }
    if (tick % 250 == 0) f.peak_rss_kb = std::max(f.peak_rss_kb, ProcStatusKb(server, "VmRSS"));
  }
  return f;
}

// A run's figures besides Stats.
struct RunFigures {
  PacerFigures pacer;
  std::string load_before;
  double drain_s = 0, wall_s = 0, cli_cpu_s = 0, srv_cpu_s = 0;
  std::map<std::string, ThreadTimes> threads0, threads1;
  int64_t hwm_kb = 0;
};

// The load from start to the drain: robots and watchers started, paced for --seconds, robots
// half-closed at the deadline and their last acks (and the fetches in flight) waited for, then
// the watchers cancelled.
RunFigures RunLoad(const Flags& flags, Clients& clients, Stats* stats, pid_t server) {
  RunFigures r;
  r.load_before = LoadAvg();
  const double cli0 = SelfCpuS(), srv0 = ProcCpuS(server);
  r.threads0 = ThreadCpuS(server);
  const Clock::time_point t0 = Clock::now();
  for (auto& w : clients.watchers) w->Start();
  for (auto& robot : clients.robots) robot->Start();
  r.pacer = Pace(flags, t0, clients, stats, server);
  const Clock::time_point t_end = Clock::now();
  for (auto& robot : clients.robots) robot->Stop();
  {
    std::unique_lock lock(stats->mu);
    stats->cv.wait(lock,
                   [&] { return stats->robots_running == 0 && stats->fetches_in_flight == 0; });
  }
  r.drain_s = Seconds(Clock::now() - t_end);
  for (auto& w : clients.watchers) w->Stop();
  {
    std::unique_lock lock(stats->mu);
    stats->cv.wait(lock, [&] { return stats->watchers_running == 0; });
  }
  r.wall_s = Seconds(Clock::now() - t0);
  r.cli_cpu_s = SelfCpuS() - cli0;
  r.srv_cpu_s = ProcCpuS(server) - srv0;
  r.threads1 = ThreadCpuS(server);
  r.hwm_kb = ProcStatusKb(server, "VmHWM");
  r.pacer.peak_rss_kb = std::max(r.pacer.peak_rss_kb, ProcStatusKb(server, "VmRSS"));
  return r;
}

// The traffic's lines: ingest, fetches, watches, errors.
void PrintTraffic(const Flags& flags, Stats& stats, const RunFigures& r, int64_t offered_batches) {
  const double run_s = flags.seconds;
  std::printf("\nrun %.1f s + drain %.2f s (wall %.1f s); load before %s, after %s\n", run_s,
              r.drain_s, r.wall_s, r.load_before.c_str(), LoadAvg().c_str());
  std::printf(
      "ingest: %lld batches sent of %lld scheduled, %lld acknowledged (%lld samples): "
      "%.0f batches/s, %.0f samples/s\n",
      static_cast<long long>(stats.sent_batches), static_cast<long long>(offered_batches),
      static_cast<long long>(stats.acked_batches), static_cast<long long>(stats.acked_samples),
      stats.acked_batches / run_s, stats.acked_samples / run_s);
  std::printf(
      "  late sends (previous batch still being written) %lld, most batches a robot "
      "was behind %lld; pacer late by up to %.1f ms\n",
      static_cast<long long>(stats.late_sends), static_cast<long long>(stats.max_behind),
      r.pacer.late_ms);
  PrintLatency("ack (send -> ack)", stats.ack_us);
  std::printf("fetch: %lld sent (%lld skipped: %d in flight), %lld done, %.0f/s, %.1f KB avg\n",
              static_cast<long long>(stats.fetches_sent),
              static_cast<long long>(r.pacer.fetches_skipped), kMaxFetchesInFlight,
              static_cast<long long>(stats.fetches_done), stats.fetches_done / run_s,
              stats.fetch_us.empty()
                  ? 0.0
                  : stats.fetch_bytes / 1e3 / static_cast<double>(stats.fetch_us.size()));
  PrintLatency("GetActiveParameters", stats.fetch_us);
  std::printf("watch: %lld events to %d watchers\n", static_cast<long long>(stats.events),
              flags.watchers);
  PrintLatency("event delay (server time -> client)", stats.event_us);
  std::printf("errors:");
  if (stats.errors.empty()) std::printf(" none");
  for (const auto& [what, n] : stats.errors)
    std::printf(" %s=%lld", what.c_str(), static_cast<long long>(n));
  std::printf("\n");
  if (!stats.first_error.empty()) std::printf("  first: %s\n", stats.first_error.c_str());
}

// The busiest six of imucald's threads over the run.
void PrintBusiestThreads(const RunFigures& r) {
  struct Row {
    double cpu_s, wait_s;
    std::string name;
  };
  std::vector<Row> by_cpu;
  for (const auto& [name, t] : r.threads1) {
    const auto it = r.threads0.find(name);
    const ThreadTimes t0_times = it == r.threads0.end() ? ThreadTimes() : it->second;
    by_cpu.push_back({t.cpu_s - t0_times.cpu_s, t.wait_s - t0_times.wait_s, name});
  }
  std::sort(by_cpu.begin(), by_cpu.end(),
            [](const Row& a, const Row& b) { return a.cpu_s > b.cpu_s; });
  std::printf(
      "  busiest server threads (name/tid: %% of the run on a CPU, %% runnable but "
      "waiting for a CPU):\n   ");
  for (size_t i = 0; i < by_cpu.size() && i < 6; ++i)
    std::printf(" %s %.0f%% (+%.0f%% waiting)", by_cpu[i].name.c_str(),
                100 * by_cpu[i].cpu_s / r.wall_s, 100 * by_cpu[i].wait_s / r.wall_s);
  std::printf("\n");
}

// Prints the results and whether imucald kept up (see the header comment).
bool Report(const Flags& flags, Stats& stats, const RunFigures& r, pid_t server,
            int64_t rss_idle_kb, int exit_status) {
  const int64_t offered_batches = static_cast<int64_t>(flags.robots) *
                                  static_cast<int64_t>(flags.seconds * 1000 / flags.batch_ms);
  PrintTraffic(flags, stats, r, offered_batches);
  std::printf(
      "imucald pid %d: cpu %.0f%% of one core (client %.0f%%), memory VmHWM %.1f MB "
      "(RSS idle %.1f MB, peak sampled %.1f MB); exit status %d\n",
      static_cast<int>(server), 100 * r.srv_cpu_s / r.wall_s, 100 * r.cli_cpu_s / r.wall_s,
      r.hwm_kb / 1e3, rss_idle_kb / 1e3, r.pacer.peak_rss_kb / 1e3,
      WIFEXITED(exit_status) ? WEXITSTATUS(exit_status) : -1);
  PrintBusiestThreads(r);
  std::vector<double> acks = stats.ack_us;
  const double ack_p99_ms = Percentile(acks, 0.99) / 1e3;
  const bool kept_up = stats.errors.empty() && stats.acked_batches == stats.sent_batches &&
                       stats.sent_batches >= offered_batches - flags.robots &&
                       ack_p99_ms < flags.batch_ms && stats.max_behind <= 1;
  std::printf(
      "kept up: %s (every batch acknowledged, no errors, ack p99 %.1f ms < %d ms, no "
      "robot behind by more than one batch)\n",
      kept_up ? "yes" : "NO", ack_p99_ms, flags.batch_ms);
  return kept_up;
}

}  // namespace

int main(int argc, char** argv) {
  const Flags flags = ParseFlags(argc, argv);
  const int per = static_cast<int>(flags.rate_hz * flags.batch_ms / 1000.0 + 0.5);
  char tmpl[] = "/tmp/imucal-load-bench-XXXXXX";
  if (mkdtemp(tmpl) == nullptr) {
    std::perror("mkdtemp");
    return 1;
  }
  const std::string dir = tmpl, db = dir + "/load.db";
  std::printf(
      "imucal load bench: %d robots x %.0f Hz (a %d-sample batch every %d ms), %d "
      "watchers, %d fleet devices fetched at %.0f/s, %.0f s, %d channel(s), %ld cores\n",
      flags.robots, flags.rate_hz, per, flags.batch_ms, flags.watchers, flags.devices,
      flags.fetch_rate, flags.seconds, flags.channels, sysconf(_SC_NPROCESSORS_ONLN));
  const Clock::time_point setup0 = Clock::now();
  const std::vector<std::string> sessions = Populate(flags, db);
  const Columns col = RobotColumns(flags.rate_hz);
  std::printf("setup: %zu sessions, %d devices with an active version in %.1f s; load %s\n",
              sessions.size(), flags.devices, Seconds(Clock::now() - setup0), LoadAvg().c_str());
  const std::optional<std::vector<std::string>> server_args = ServerArgs(flags, dir);
  if (!server_args) return 1;

  // Fork before any gRPC object exists in this process.
  const std::string listen = absl::StrCat("127.0.0.1:", FreeLoopbackPort());
  const pid_t server = StartImucald(flags.imucald, db, listen, *server_args, flags.server_cpu);
  PinToCpu(flags.client_cpu);
  const std::shared_ptr<grpc::ChannelCredentials> credentials = CallCredentials(flags, dir, listen);
  if (credentials == nullptr) return KillImucald(server), 1;
  std::vector<std::shared_ptr<grpc::Channel>> channels =
      ConnectChannels(flags, listen, credentials);
  if (channels.empty()) return KillImucald(server), 1;
  const int64_t rss_idle_kb = ProcStatusKb(server, "VmRSS");

  Stats stats;
  Clients clients = MakeClients(flags, per, col, sessions, channels, &stats);
  const RunFigures run = RunLoad(flags, clients, &stats, server);
  clients = Clients();
  channels.clear();
  kill(server, SIGTERM);
  int status = 0;
  waitpid(server, &status, 0);

  const bool kept_up = Report(flags, stats, run, server, rss_idle_kb, status);
  std::error_code ec;
  if (flags.keep) {
    std::printf("kept %s\n", dir.c_str());
  } else {
    std::filesystem::remove_all(dir, ec);
  }
  return kept_up ? 0 : 3;
}
