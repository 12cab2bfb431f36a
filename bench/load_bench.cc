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

// Batch `seq` (1-based) of `per` samples: samples [(seq-1)*per, seq*per) of the replayed
// capture, started at `offset` samples (robots start at different points of the capture).
void FillBatch(const Columns& col, int per, int64_t seq, int64_t offset, v1::SampleBatch* b) {
  b->clear_t_s();
  b->clear_accel();
  b->clear_gyro();
  b->clear_temp_c();
  b->set_seq(seq);
  const int64_t first = offset + (seq - 1) * per;
  for (int j = 0; j < per; ++j) {
    const int64_t g = first + j;
    const size_t i = static_cast<size_t>(g % static_cast<int64_t>(col.n));
    const double shift = static_cast<double>(g / static_cast<int64_t>(col.n)) * col.lap_s;
    b->add_t_s(col.t[i] + shift);
    b->add_temp_c(col.temp[i]);
    for (int k = 0; k < 3; ++k) {
      b->add_accel(col.accel[3 * i + k]);
      b->add_gyro(col.gyro[3 * i + k]);
    }
  }
}

// ---- Results shared by every reactor.
struct Stats {
  std::mutex mu;
  std::condition_variable cv;
  std::vector<double> ack_us, fetch_us, event_us;  // guarded by mu
  std::map<std::string, int64_t> errors;           // "what CODE" -> count; guarded by mu
  std::string first_error;                         // guarded by mu
  int64_t acked_batches = 0, acked_samples = 0, sent_batches = 0, late_sends = 0;
  int64_t max_behind = 0;  // most batches a robot was behind its schedule
  int64_t events = 0, fetches_sent = 0, fetches_done = 0, fetch_bytes = 0;
  int robots_running = 0, watchers_running = 0, fetches_in_flight = 0;  // guarded by mu

  void Error(const std::string& what, const grpc::Status& s) {
    errors[absl::StrCat(what, " ", std::string(imucal::server::CodeName(s.error_code())))]++;
    if (first_error.empty()) first_error = absl::StrCat(what, ": ", s.error_message());
  }
};

// One robot: a StreamSamples stream; Due() (from the pacer) queues the next batch, written
// as soon as the previous write is done. Latency: StartWrite of seq -> the ack covering seq.
class Robot final : public grpc::ClientBidiReactor<v1::SampleBatch, v1::SampleAck> {
 public:
  Robot(Stats* stats, const Columns* col, int per, v1::SessionService::Stub* stub,
        std::string session_id, int64_t offset)
      : stats_(stats),
        col_(col),
        per_(per),
        stub_(stub),
        session_id_(std::move(session_id)),
        offset_(offset) {
    ack_us_.reserve(1 << 12);
  }

  void Start() {
    stub_->async()->StreamSamples(&context_, this);
    StartRead(&ack_);
    StartCall();
  }

  // The pacer's tick for this robot: one more batch is due.
  void Due() {
    std::lock_guard lock(mu_);
    if (stopping_) return;
    ++due_;
    if (writing_) ++late_;
    max_behind_ = std::max(max_behind_, due_);
    MaybeWriteLocked();
  }

  // At the deadline: no more batches; half-close once the last write is done.
  void Stop() {
    std::lock_guard lock(mu_);
    stopping_ = true;
    due_ = 0;
    MaybeWriteLocked();
  }

  void OnWriteDone(bool ok) override {
    std::lock_guard lock(mu_);
    writing_ = false;
    if (ok) MaybeWriteLocked();
  }

  void OnReadDone(bool ok) override {
    if (!ok) return;  // the server finished: OnDone follows
    const Clock::time_point now = Clock::now();
    {
      std::lock_guard lock(mu_);
      while (!sent_at_.empty() && first_unacked_ <= ack_.last_acked_seq()) {
        ack_us_.push_back(1e6 * Seconds(now - sent_at_.front()));
        sent_at_.pop_front();
        ++first_unacked_;
        ++acked_batches_;
      }
      acked_samples_ = ack_.samples();
    }
    StartRead(&ack_);
  }

  void OnDone(const grpc::Status& status) override {
    std::lock_guard lock(stats_->mu);
    if (!status.ok()) stats_->Error("StreamSamples", status);
    stats_->ack_us.insert(stats_->ack_us.end(), ack_us_.begin(), ack_us_.end());
    stats_->acked_batches += acked_batches_;
    stats_->acked_samples += acked_samples_;
    stats_->sent_batches += next_seq_ - 1;
    stats_->late_sends += late_;
    stats_->max_behind = std::max(stats_->max_behind, max_behind_);
    --stats_->robots_running;
    stats_->cv.notify_all();
  }

 private:
  void MaybeWriteLocked() {
    if (writing_ || writes_done_) return;
    if (due_ == 0) {
      if (stopping_) {
        writes_done_ = true;
        StartWritesDone();
      }
      return;
    }
    --due_;
    if (next_seq_ == 1)
      batch_.set_session_id(session_id_);
    else
      batch_.clear_session_id();
    FillBatch(*col_, per_, next_seq_, offset_, &batch_);
    sent_at_.push_back(Clock::now());
    ++next_seq_;
    writing_ = true;
    StartWrite(&batch_);
  }

  Stats* stats_;
  const Columns* col_;
  int per_;
  v1::SessionService::Stub* stub_;
  std::string session_id_;
  int64_t offset_;
  grpc::ClientContext context_;
  v1::SampleAck ack_;  // the read path only

  std::mutex mu_;
  v1::SampleBatch batch_;  // guarded by mu_; untouched while a write is in flight
  bool writing_ = false, writes_done_ = false, stopping_ = false;
  int64_t due_ = 0, late_ = 0, max_behind_ = 0;
  int64_t next_seq_ = 1, first_unacked_ = 1;
  std::deque<Clock::time_point> sent_at_;  // batches first_unacked_, first_unacked_ + 1, ...
  int64_t acked_batches_ = 0, acked_samples_ = 0;
  std::vector<double> ack_us_;
};

// A technician following a session: WatchSession until cancelled at the end.
class Watcher final : public grpc::ClientReadReactor<v1::SessionEvent> {
 public:
  Watcher(Stats* stats, v1::SessionService::Stub* stub, const std::string& session_id)
      : stats_(stats) {
    request_.set_session_id(session_id);
    stub->async()->WatchSession(&context_, &request_, this);
  }
  void Start() {
    StartRead(&event_);
    StartCall();
  }
  void Stop() {
    stopped_ = true;
    context_.TryCancel();
  }

  void OnReadDone(bool ok) override {
    if (!ok) return;
    const absl::Time sent =
        absl::FromUnixSeconds(event_.time().seconds()) + absl::Nanoseconds(event_.time().nanos());
    delays_us_.push_back(absl::ToDoubleMicroseconds(absl::Now() - sent));
    StartRead(&event_);
  }

  void OnDone(const grpc::Status& status) override {
    std::lock_guard lock(stats_->mu);
    if (!status.ok() && !(stopped_ && status.error_code() == grpc::StatusCode::CANCELLED))
      stats_->Error("WatchSession", status);
    stats_->events += static_cast<int64_t>(delays_us_.size());
    stats_->event_us.insert(stats_->event_us.end(), delays_us_.begin(), delays_us_.end());
    --stats_->watchers_running;
    stats_->cv.notify_all();
  }

 private:
  Stats* stats_;
  grpc::ClientContext context_;
  v1::WatchSessionRequest request_;
  v1::SessionEvent event_;
  std::atomic<bool> stopped_{false};
  std::vector<double> delays_us_;  // the reactor's reads are serialised
};

// One robot's startup fetch: GetActiveParameters, deletes itself when done.
class Fetch {
 public:
  static void Send(Stats* stats, v1::ParameterService::Stub* stub, const std::string& device) {
    auto* f = new Fetch(stats);
    f->request_.set_device_id(device);
    f->context_.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    f->start_ = Clock::now();
    stub->async()->GetActiveParameters(&f->context_, &f->request_, &f->response_,
                                       [f](grpc::Status s) { f->Done(s); });
  }

 private:
  explicit Fetch(Stats* stats) : stats_(stats) {}
  void Done(const grpc::Status& status) {
    const double us = 1e6 * Seconds(Clock::now() - start_);
    {
      std::lock_guard lock(stats_->mu);
      if (status.ok()) {
        stats_->fetch_us.push_back(us);
        stats_->fetch_bytes += static_cast<int64_t>(response_.json().size());
      } else {
        stats_->Error("GetActiveParameters", status);
      }
      ++stats_->fetches_done;
      --stats_->fetches_in_flight;
      stats_->cv.notify_all();
    }
    delete this;
  }

  Stats* stats_;
  grpc::ClientContext context_;
  v1::GetActiveParametersRequest request_;
  v1::ParameterSet response_;
  Clock::time_point start_;
};

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
  auto device = [](const std::string& id) {
    imucal::storage::Device d;
    d.id = id;
    d.sensor_model = "MPU-6050";
    d.nominal_rate_hz = 200;
    d.accel_unit = "m/s^2";
    d.gyro_unit = "rad/s";
    return d;
  };
  auto check = [](const absl::Status& s, const char* what) {
    if (s.ok()) return;
    std::fprintf(stderr, "%s: %s\n", what, std::string(s.message()).c_str());
    std::exit(1);
  };
  std::vector<std::string> sessions;
  for (int i = 0; i < flags.robots; ++i) {
    check((*store)->CreateDevice(device(RobotId(i)), "bench").status(), "CreateDevice");
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
    check((*store)->CreateDevice(device(FleetId(i)), "bench").status(), "CreateDevice");
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

  // --tls: a certificate for 127.0.0.1 and imucald's flags to serve it (replacing --insecure).
  // Every simulated robot and watcher shares the one admin token: the per-token stream cap is
  // raised to hold them all (a fleet gives each robot its own token).
  Flags run_flags = flags;
  const std::string cert = dir + "/server.crt";
  const std::string token_file = dir + "/admin-token";
  if (flags.tls) {
    const std::vector<std::string> tls = TlsServerArgs(dir, token_file);
    if (tls.empty()) {
      std::fprintf(stderr, "--tls: the openssl CLI could not make a certificate\n");
      return 1;
    }
    std::erase(run_flags.server_args, std::string("--insecure"));
    run_flags.server_args.insert(run_flags.server_args.end(), tls.begin(), tls.end());
    run_flags.server_args.push_back(
        absl::StrCat("--max-streams-per-token=", flags.robots + flags.watchers));
  }

  // Fork before any gRPC object exists in this process.
  const std::string listen = absl::StrCat("127.0.0.1:", FreeLoopbackPort());
  const pid_t server =
      StartImucald(run_flags.imucald, db, listen, run_flags.server_args, flags.server_cpu);
  PinToCpu(flags.client_cpu);
  // imucald writes its first admin token before it listens: once a TLS connection (without
  // the token, which is a per-call credential) is up, the file is there.
  std::shared_ptr<grpc::ChannelCredentials> credentials = grpc::InsecureChannelCredentials();
  if (flags.tls) {
    std::ifstream cert_in(cert);
    grpc::SslCredentialsOptions ssl;
    ssl.pem_root_certs.assign(std::istreambuf_iterator<char>(cert_in),
                              std::istreambuf_iterator<char>());
    auto probe = grpc::CreateChannel(listen, grpc::SslCredentials(ssl));
    std::string token;
    if (probe->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(60))) {
      std::ifstream in(token_file);
      std::getline(in, token);
    }
    if (token.empty()) {
      std::fprintf(stderr, "--tls: imucald did not come up with an admin token in %s\n",
                   token_file.c_str());
      kill(server, SIGKILL);
      waitpid(server, nullptr, 0);
      return 1;
    }
    credentials = grpc::CompositeChannelCredentials(grpc::SslCredentials(ssl),
                                                    grpc::AccessTokenCredentials(token));
  }
  std::vector<std::shared_ptr<grpc::Channel>> channels;
  for (int i = 0; i < flags.channels; ++i) {
    grpc::ChannelArguments args;
    args.SetInt("imucal.bench.channel", i);  // distinct args: a connection per channel
    args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
    channels.push_back(grpc::CreateCustomChannel(listen, credentials, args));
  }
  for (auto& ch : channels) {
    if (!ch->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(60))) {
      std::fprintf(stderr, "imucald did not listen on %s\n", listen.c_str());
      kill(server, SIGKILL);
      waitpid(server, nullptr, 0);
      return 1;
    }
  }
  const int64_t rss_idle_kb = ProcStatusKb(server, "VmRSS");
  std::vector<std::unique_ptr<v1::SessionService::Stub>> session_stubs;
  std::vector<std::unique_ptr<v1::ParameterService::Stub>> param_stubs;
  for (auto& ch : channels) {
    session_stubs.push_back(v1::SessionService::NewStub(ch));
    param_stubs.push_back(v1::ParameterService::NewStub(ch));
  }

  Stats stats;
  std::vector<std::unique_ptr<Robot>> robots;
  std::mt19937_64 rng(1);
  for (int i = 0; i < flags.robots; ++i) {
    robots.push_back(std::make_unique<Robot>(
        &stats, &col, per, session_stubs[static_cast<size_t>(i) % channels.size()].get(),
        sessions[static_cast<size_t>(i)], static_cast<int64_t>(rng() % col.n)));
  }
  std::vector<std::unique_ptr<Watcher>> watchers;
  for (int i = 0; i < flags.watchers; ++i) {
    watchers.push_back(std::make_unique<Watcher>(
        &stats, session_stubs[static_cast<size_t>(i) % channels.size()].get(),
        sessions[static_cast<size_t>(i)]));
  }
  stats.robots_running = flags.robots;
  stats.watchers_running = flags.watchers;

  const std::string load_before = LoadAvg();
  const double cli0 = SelfCpuS(), srv0 = ProcCpuS(server);
  const std::map<std::string, ThreadTimes> threads0 = ThreadCpuS(server);
  const Clock::time_point t0 = Clock::now();
  for (auto& w : watchers) w->Start();
  for (auto& r : robots) r->Start();

  // The pacer: a 1 ms tick. Robot i is due at t0 + (i mod batch_ms) ms + k * batch_ms (phases
  // spread over the period); fetches go out at fetch_rate, device after device.
  int64_t peak_rss_kb = 0;
  int64_t fetch_index = 0, fetches_skipped = 0;
  const int64_t ticks = static_cast<int64_t>(flags.seconds * 1000);
  constexpr int kMaxFetchesInFlight = 5000;
  double pacer_late_ms = 0;
  for (int64_t tick = 0; tick < ticks; ++tick) {
    const Clock::time_point at = t0 + std::chrono::milliseconds(tick);
    std::this_thread::sleep_until(at);  // the schedule itself
    pacer_late_ms = std::max(pacer_late_ms, 1e3 * Seconds(Clock::now() - at));
    for (int i = static_cast<int>(tick % flags.batch_ms); i < flags.robots; i += flags.batch_ms)
      robots[static_cast<size_t>(i)]->Due();
    const int64_t fetch_due = static_cast<int64_t>(flags.fetch_rate * (tick + 1) / 1000.0);
    for (; flags.devices > 0 && fetch_index < fetch_due; ++fetch_index) {
      {
        std::lock_guard lock(stats.mu);
        if (stats.fetches_in_flight >= kMaxFetchesInFlight) {
          ++fetches_skipped;
          continue;
        }
        ++stats.fetches_in_flight;
        ++stats.fetches_sent;
      }
      Fetch::Send(&stats, param_stubs[static_cast<size_t>(fetch_index) % param_stubs.size()].get(),
                  FleetId(static_cast<int>(fetch_index % flags.devices)));
    }
    if (tick % 250 == 0) peak_rss_kb = std::max(peak_rss_kb, ProcStatusKb(server, "VmRSS"));
  }
  const Clock::time_point t_end = Clock::now();
  for (auto& r : robots) r->Stop();
  {
    std::unique_lock lock(stats.mu);
    stats.cv.wait(lock, [&] { return stats.robots_running == 0 && stats.fetches_in_flight == 0; });
  }
  const double drain_s = Seconds(Clock::now() - t_end);
  for (auto& w : watchers) w->Stop();
  {
    std::unique_lock lock(stats.mu);
    stats.cv.wait(lock, [&] { return stats.watchers_running == 0; });
  }
  const double wall = Seconds(Clock::now() - t0);
  const double cli_cpu = SelfCpuS() - cli0, srv_cpu = ProcCpuS(server) - srv0;
  const std::map<std::string, ThreadTimes> threads1 = ThreadCpuS(server);
  const int64_t hwm_kb = ProcStatusKb(server, "VmHWM");
  peak_rss_kb = std::max(peak_rss_kb, ProcStatusKb(server, "VmRSS"));
  robots.clear();
  watchers.clear();
  session_stubs.clear();
  param_stubs.clear();
  channels.clear();
  kill(server, SIGTERM);
  int status = 0;
  waitpid(server, &status, 0);

  const double run_s = flags.seconds;
  const int64_t offered_batches =
      static_cast<int64_t>(flags.robots) * static_cast<int64_t>(run_s * 1000 / flags.batch_ms);
  std::printf("\nrun %.1f s + drain %.2f s (wall %.1f s); load before %s, after %s\n", run_s,
              drain_s, wall, load_before.c_str(), LoadAvg().c_str());
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
      pacer_late_ms);
  PrintLatency("ack (send -> ack)", stats.ack_us);
  std::printf("fetch: %lld sent (%lld skipped: %d in flight), %lld done, %.0f/s, %.1f KB avg\n",
              static_cast<long long>(stats.fetches_sent), static_cast<long long>(fetches_skipped),
              kMaxFetchesInFlight, static_cast<long long>(stats.fetches_done),
              stats.fetches_done / run_s,
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
  std::printf(
      "imucald pid %d: cpu %.0f%% of one core (client %.0f%%), memory VmHWM %.1f MB "
      "(RSS idle %.1f MB, peak sampled %.1f MB); exit status %d\n",
      static_cast<int>(server), 100 * srv_cpu / wall, 100 * cli_cpu / wall, hwm_kb / 1e3,
      rss_idle_kb / 1e3, peak_rss_kb / 1e3, WIFEXITED(status) ? WEXITSTATUS(status) : -1);
  struct Row {
    double cpu_s, wait_s;
    std::string name;
  };
  std::vector<Row> by_cpu;
  for (const auto& [name, t] : threads1) {
    const auto it = threads0.find(name);
    const ThreadTimes t0_times = it == threads0.end() ? ThreadTimes() : it->second;
    by_cpu.push_back({t.cpu_s - t0_times.cpu_s, t.wait_s - t0_times.wait_s, name});
  }
  std::sort(by_cpu.begin(), by_cpu.end(),
            [](const Row& a, const Row& b) { return a.cpu_s > b.cpu_s; });
  std::printf(
      "  busiest server threads (name/tid: %% of the run on a CPU, %% runnable but "
      "waiting for a CPU):\n   ");
  for (size_t i = 0; i < by_cpu.size() && i < 6; ++i)
    std::printf(" %s %.0f%% (+%.0f%% waiting)", by_cpu[i].name.c_str(),
                100 * by_cpu[i].cpu_s / wall, 100 * by_cpu[i].wait_s / wall);
  std::printf("\n");
  std::vector<double> acks = stats.ack_us;
  const double ack_p99_ms = Percentile(acks, 0.99) / 1e3;
  const bool kept_up = stats.errors.empty() && stats.acked_batches == stats.sent_batches &&
                       stats.sent_batches >= offered_batches - flags.robots &&
                       ack_p99_ms < flags.batch_ms && stats.max_behind <= 1;
  std::printf(
      "kept up: %s (every batch acknowledged, no errors, ack p99 %.1f ms < %d ms, no "
      "robot behind by more than one batch)\n",
      kept_up ? "yes" : "NO", ack_p99_ms, flags.batch_ms);
  std::error_code ec;
  if (flags.keep) {
    std::printf("kept %s\n", dir.c_str());
  } else {
    std::filesystem::remove_all(dir, ec);
  }
  return kept_up ? 0 : 3;
}
