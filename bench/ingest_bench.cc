// Durable ingest throughput: N simulated robots, each with its own device and session, stream
// SessionService.StreamSamples batches (packed columns, seq 1, 2, ...) to a real imucald server
// over loopback and count what the server acknowledges (acks come after the commit).
//
//   ninja -C build-perf ingest_bench
//   build-perf/bench/ingest_bench [--n=1,100,1000] [--seconds=5] [--batch=200] [--window=1]
//                                 [--channels=4] [--breakdown=1] [--keep]
//                                 [--db=postgresql://...] [--replicas=1]
//                                 [--server-cpu=N] [--client-cpu=N]
// (--server-cpu / --client-cpu pin the forked server(s) and this client to one core each.)
//
// The server runs in a forked child process (imucal::server::Server on 127.0.0.1:0 with a
// SQLite file in a fresh temp dir, or the database --db names), so the client's and the
// server's CPU are measured apart: client = getrusage(self), server = /proc/<child>/stat. The
// client is the gRPC callback API: one ClientBidiReactor per robot, no thread per stream (gRPC's
// own few threads drive them all), streams spread over --channels HTTP/2 connections per
// server. Each robot keeps up to --window batches unacknowledged (the server handles one batch
// of a stream at a time). Each round sends for --seconds, then half-closes every stream and
// waits for the remaining acks: the wall time includes that drain. Ack latency is StartWrite of
// batch seq -> the ack covering seq.
//
// --db=postgresql://... puts the store in that PostgreSQL database (deploy/pg-throwaway.sh start
// prints one) and --replicas=R forks R servers on the same database, replica_id bench-1..R
// (README "Several servers on one database"); connection k goes to server k % R, and robot i
// registers its device, opens its session and streams on connection i % (R * channels), so each
// robot's stream goes to one server and the robots are spread evenly. The device ids carry the
// run's start time, so a database can be used again. db_cpu is the PostgreSQL cluster's CPU
// (its postmaster and every process under it, found through the backend of a connection; "-"
// for SQLite, whose work is in the server's CPU, or a cluster on another machine).
//
// After each round every robot's session is read back through the store (not through a server):
// its stored batches and samples must equal what it had acknowledged (batches 1..last acked seq,
// --batch samples each, which the last ack's sample count must equal too). "lost" counts
// sessions holding fewer or whose ack miscounted (a bug), "extra" those holding more (a batch
// stored whose ack never arrived: only if a stream failed); both are printed per round.
//
// The samples are a simulated six-face capture (200 Hz, temperature on), cut into batches and
// replayed with a time shift per lap, so the server's online segmenter sees realistic motion.
//
// --breakdown runs, in this process and without gRPC, the pieces of one batch's cost: protobuf
// encode/decode of a batch, the server's IngestBatch (validate, encode, SQLite commit, segment)
// and Store::AppendBatch alone (the commit), each single-threaded.
#include <fcntl.h>
#include <signal.h>
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
#include <sstream>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "bench/bench_flags.h"
#include "bench/service_bench_util.h"
#include "core/simulator.h"
#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/ingest.h"
#include "server/server.h"
#include "server/session_hub.h"
#include "storage/sample_codec.h"
#include "storage/store.h"

namespace {

namespace v1 = imucal::v1;
using namespace imucal::bench;  // Clock, Seconds, ForkServer, ... (service_bench_util.h)

struct Flags {
  std::vector<int> ns = {1, 100, 1000};
  double seconds = 5.0;
  int batch = 200;
  int window = 1;
  int channels = 4;
  bool breakdown = true;
  bool keep = false;
  int server_cpu = -1;
  int client_cpu = -1;
  std::string db;    // empty: a SQLite file in the temp directory
  int replicas = 1;  // servers on the database
};

Flags ParseFlags(int argc, char** argv) {
  Flags f;
  CLI::App app{
      "Durable ingest throughput: N simulated robots stream StreamSamples batches to a forked "
      "server over loopback; what the server acknowledges is counted.",
      "ingest_bench"};
  app.add_option("--n", f.ns, "robots (streams), one round each, comma-separated")
      ->delimiter(',')
      ->check(CLI::Range(1, std::numeric_limits<int>::max()).description("POSITIVE"));
  app.add_option("--seconds", f.seconds, "seconds of sending per round (then the drain)");
  app.add_option("--batch", f.batch, "samples per batch");
  app.add_option("--window", f.window, "unacknowledged batches per stream (at least 1)");
  app.add_option("--channels", f.channels,
                 "HTTP/2 connections per server the streams are spread over (at least 1)");
  app.add_option("--breakdown", f.breakdown,
                 "then one batch's cost piece by piece, in process (0: skip it)");
  app.add_flag("--keep", f.keep, "keep the temp directory");
  app.add_option("--server-cpu", f.server_cpu, "pin the server to this core (-1: no pinning)");
  app.add_option("--client-cpu", f.client_cpu, "pin this client to this core (-1: no pinning)");
  app.add_option("--db", f.db,
                 "the database: a postgresql:// URL or a SQLite file (default: a fresh SQLite "
                 "file in the temp directory)");
  app.add_option("--replicas", f.replicas,
                 "servers forked on the database, robots spread over them")
      ->check(CLI::Range(1, 64));
  imucal::bench::ParseBenchFlags(app, argc, argv);
  f.window = std::max(1, f.window);
  f.channels = std::max(1, f.channels);
  return f;
}

// ---- The samples: a simulated six-face capture (bench/service_bench_util.h), lap after lap.
Columns SixFaceColumns() {
  imucal::core::SimOptions o;
  o.protocol = imucal::core::SimProtocol::kSixFace;
  o.seed = 42;
  return MakeColumns(o);
}

// Fills `b` with batch `seq` (1-based) of `batch` samples: the replayed capture's samples
// [(seq-1)*batch, seq*batch), lap by lap.
void FillBatch(const Columns& col, int batch, int64_t seq, v1::SampleBatch* b) {
  b->clear_t_s();
  b->clear_accel();
  b->clear_gyro();
  b->clear_temp_c();
  b->set_seq(seq);
  b->mutable_t_s()->Reserve(batch);
  b->mutable_accel()->Reserve(3 * batch);
  b->mutable_gyro()->Reserve(3 * batch);
  b->mutable_temp_c()->Reserve(batch);
  const int64_t first = (seq - 1) * batch;
  for (int j = 0; j < batch;) {
    const int64_t g = first + j;
    const size_t i = static_cast<size_t>(g % static_cast<int64_t>(col.n));
    const double shift = static_cast<double>(g / static_cast<int64_t>(col.n)) * col.lap_s;
    const int run = static_cast<int>(std::min<size_t>(batch - j, col.n - i));  // up to lap end
    for (int k = 0; k < run; ++k) {
      b->add_t_s(col.t[i + k] + shift);
      b->add_temp_c(col.temp[i + k]);
    }
    b->mutable_accel()->Add(col.accel.begin() + 3 * i, col.accel.begin() + 3 * (i + run));
    b->mutable_gyro()->Add(col.gyro.begin() + 3 * i, col.gyro.begin() + 3 * (i + run));
    j += run;
  }
}

// ---- One round: N robots.
struct Shared {
  const Columns* col = nullptr;
  int batch = 200;
  int window = 1;
  Clock::time_point deadline;
  std::mutex mu;
  std::condition_variable cv;
  int running = 0;                   // guarded by mu
  int failed = 0;                    // guarded by mu
  std::string first_error;           // guarded by mu
  std::vector<double> latencies_us;  // guarded by mu (merged at OnDone)
  int64_t acked_samples = 0;         // guarded by mu
  int64_t acked_batches = 0;         // guarded by mu
  Clock::time_point last_ack;        // guarded by mu
};

class Robot final : public grpc::ClientBidiReactor<v1::SampleBatch, v1::SampleAck> {
 public:
  Robot(Shared* shared, v1::SessionService::Stub* stub, std::string session_id)
      : shared_(shared), stub_(stub), session_id_(std::move(session_id)) {
    sent_at_.resize(static_cast<size_t>(shared_->window) + 1);
    latencies_us_.reserve(4096);
  }

  void Start() {
    stub_->async()->StreamSamples(&context_, this);
    {
      std::lock_guard lock(mu_);
      MaybeWriteLocked();
    }
    StartRead(&ack_);
    StartCall();
  }

  void OnWriteDone(bool ok) override {
    std::lock_guard lock(mu_);
    writing_ = false;
    if (ok) MaybeWriteLocked();
  }

  void OnWritesDoneDone(bool /*ok*/) override {}

  void OnReadDone(bool ok) override {
    if (!ok) return;  // the server finished: OnDone follows
    const Clock::time_point now = Clock::now();
    {
      std::lock_guard lock(mu_);
      for (int64_t s = acked_seq_ + 1; s <= ack_.last_acked_seq(); ++s) {
        latencies_us_.push_back(1e6 * Seconds(now - SentAt(s)));
      }
      acked_batches_ += ack_.last_acked_seq() - acked_seq_;
      acked_seq_ = ack_.last_acked_seq();
      acked_samples_ = ack_.samples();
      last_ack_ = now;
      MaybeWriteLocked();
    }
    StartRead(&ack_);
  }

  // What its last ack counted; read once OnDone ran.
  const std::string& session_id() const { return session_id_; }
  int64_t acked_seq() const { return acked_seq_; }
  int64_t acked_samples() const { return acked_samples_; }

  void OnDone(const grpc::Status& status) override {
    {
      std::lock_guard lock(shared_->mu);
      if (!status.ok()) {
        ++shared_->failed;
        if (shared_->first_error.empty())
          shared_->first_error = absl::StrCat(session_id_, ": gRPC code ", status.error_code(),
                                              ": ", status.error_message());
      }
      shared_->latencies_us.insert(shared_->latencies_us.end(), latencies_us_.begin(),
                                   latencies_us_.end());
      shared_->acked_samples += acked_samples_;
      shared_->acked_batches += acked_batches_;
      shared_->last_ack = std::max(shared_->last_ack, last_ack_);
      --shared_->running;
      shared_->cv.notify_all();  // under the lock: main destroys `shared` once it sees 0
    }
  }

 private:
  Clock::time_point& SentAt(int64_t seq) {
    return sent_at_[static_cast<size_t>(seq % static_cast<int64_t>(sent_at_.size()))];
  }

  void MaybeWriteLocked() {
    if (writing_ || writes_done_) return;
    if (Clock::now() >= shared_->deadline) {
      writes_done_ = true;
      StartWritesDone();
      return;
    }
    if (next_seq_ - 1 - acked_seq_ >= shared_->window) return;
    if (next_seq_ == 1)
      batch_.set_session_id(session_id_);
    else
      batch_.clear_session_id();
    FillBatch(*shared_->col, shared_->batch, next_seq_, &batch_);
    SentAt(next_seq_) = Clock::now();
    ++next_seq_;
    writing_ = true;
    StartWrite(&batch_);
  }

  Shared* shared_;
  v1::SessionService::Stub* stub_;
  std::string session_id_;
  grpc::ClientContext context_;
  v1::SampleAck ack_;  // only the read path touches it

  std::mutex mu_;
  v1::SampleBatch batch_;  // guarded by mu_; not touched while a write is in flight
  bool writing_ = false;
  bool writes_done_ = false;
  int64_t next_seq_ = 1;
  int64_t acked_seq_ = 0;
  int64_t acked_samples_ = 0;
  int64_t acked_batches_ = 0;
  Clock::time_point last_ack_;
  std::vector<Clock::time_point> sent_at_;  // ring, indexed by seq
  std::vector<double> latencies_us_;
};

// The run's start time (ms, hex): in every device id, so that a database (PostgreSQL, a kept
// SQLite file) can hold several runs.
const std::string& RunTag() {
  static const std::string tag = absl::StrFormat("%x", absl::ToUnixMillis(absl::Now()));
  return tag;
}

// Every robot's session as stored against its last ack (see the header comment).
struct StoredCheck {
  int sessions = 0, lost = 0, extra = 0;
  std::string first_problem;
};

StoredCheck CheckStored(imucal::storage::Store& store,
                        const std::vector<std::unique_ptr<Robot>>& robots, int batch) {
  StoredCheck check;
  for (const auto& robot : robots) {
    ++check.sessions;
    // What the robot had acknowledged: batches 1..acked_seq of `batch` samples each, which is
    // also what the server's last ack must have counted.
    const int64_t acked = robot->acked_seq() * batch;
    absl::StatusOr<imucal::storage::Session> stored = store.GetSession(robot->session_id());
    const int64_t seq = stored.ok() ? stored->last_acked_seq : -1;
    const int64_t samples = stored.ok() ? stored->samples : -1;
    if (seq == robot->acked_seq() && samples == acked && robot->acked_samples() == acked) continue;
    if (seq < robot->acked_seq() || samples < acked || robot->acked_samples() != acked)
      ++check.lost;
    else
      ++check.extra;
    if (check.first_problem.empty()) {
      check.first_problem =
          absl::StrCat(robot->session_id(), ": acknowledged batch ", robot->acked_seq(), " (",
                       acked, " samples; the ack said ", robot->acked_samples(), "), stored ",
                       stored.ok() ? absl::StrCat("batch ", seq, " (", samples, " samples)")
                                   : std::string(stored.status().message()));
    }
  }
  return check;
}

struct RoundResult {
  int n = 0;
  double wall_s = 0, samples_per_s = 0, batches_per_s = 0;
  int64_t samples = 0, batches = 0;
  double p50_us = 0, p99_us = 0, max_us = 0;
  double client_cpu_s = 0, server_cpu_s = 0, db_cpu_s = -1;  // -1: not measured
  std::vector<double> replica_cpu_s;                         // per server
  int failed = 0;
  StoredCheck check;
  std::string load;
};

// Setup of a round (not timed): a device and an open session per robot, through the server
// (channel) its stream will go to; the sessions' ids.
std::vector<std::string> OpenSessions(std::vector<std::shared_ptr<grpc::Channel>>& channels, int n,
                                      int round) {
  std::vector<std::string> sessions;
  std::vector<std::unique_ptr<v1::DeviceService::Stub>> device_stubs;
  std::vector<std::unique_ptr<v1::SessionService::Stub>> session_stubs;
  for (auto& ch : channels) {
    device_stubs.push_back(v1::DeviceService::NewStub(ch));
    session_stubs.push_back(v1::SessionService::NewStub(ch));
  }
  for (int i = 0; i < n; ++i) {
    const size_t k = static_cast<size_t>(i) % channels.size();
    auto& devices = device_stubs[k];
    auto& session_stub = session_stubs[k];
    v1::RegisterDeviceRequest req;
    v1::Device* d = req.mutable_device();
    d->set_id(absl::StrCat("bench-", RunTag(), "-r", round, "-n", n, "-", i));
    d->set_sensor_model("MPU-6050");
    d->set_nominal_rate_hz(200);
    d->set_accel_unit("m/s^2");
    d->set_gyro_unit("rad/s");
    v1::Device out;
    grpc::ClientContext c1;
    grpc::Status s = devices->RegisterDevice(&c1, req, &out);
    v1::CreateSessionRequest sreq;
    sreq.set_device_id(d->id());
    sreq.set_protocol(v1::PROTOCOL_SIX_FACE);
    v1::Session session;
    grpc::ClientContext c2;
    if (s.ok()) s = session_stub->CreateSession(&c2, sreq, &session);
    if (!s.ok()) {
      std::fprintf(stderr, "setup: %s\n", s.error_message().c_str());
      std::exit(1);
    }
    sessions.push_back(session.id());
  }
  return sessions;
}

RoundResult RunRound(const Flags& flags, const Columns& col, const std::vector<Child>& servers,
                     const std::optional<PostgresCpu>& pg_cpu, imucal::storage::Store& store,
                     std::vector<std::shared_ptr<grpc::Channel>>& channels, int n, int round) {
  RoundResult r;
  r.n = n;
  const std::vector<std::string> sessions = OpenSessions(channels, n, round);
  std::vector<std::unique_ptr<v1::SessionService::Stub>> stubs;
  for (auto& ch : channels) stubs.push_back(v1::SessionService::NewStub(ch));

  Shared shared;
  shared.col = &col;
  shared.batch = flags.batch;
  shared.window = flags.window;
  shared.running = n;
  std::vector<std::unique_ptr<Robot>> robots;
  for (int i = 0; i < n; ++i) {
    robots.push_back(std::make_unique<Robot>(
        &shared, stubs[static_cast<size_t>(i) % stubs.size()].get(), sessions[i]));
  }
  r.load = LoadAvg();
  const double client_cpu0 = SelfCpuS();
  const std::vector<double> server_cpu0 = ServersCpuS(servers);
  const double db_cpu0 = pg_cpu ? pg_cpu->CpuS() : 0;
  const Clock::time_point start = Clock::now();
  shared.deadline = start + std::chrono::microseconds(static_cast<int64_t>(flags.seconds * 1e6));
  for (auto& robot : robots) robot->Start();
  {
    std::unique_lock lock(shared.mu);
    shared.cv.wait(lock, [&] { return shared.running == 0; });
  }
  const Clock::time_point end = Clock::now();
  r.client_cpu_s = SelfCpuS() - client_cpu0;
  if (pg_cpu) r.db_cpu_s = pg_cpu->CpuS() - db_cpu0;
  r.replica_cpu_s = ServersCpuS(servers);
  for (size_t i = 0; i < servers.size(); ++i) r.replica_cpu_s[i] -= server_cpu0[i];
  r.server_cpu_s = Sum(r.replica_cpu_s);
  r.wall_s = Seconds(end - start);
  r.samples = shared.acked_samples;
  r.batches = shared.acked_batches;
  r.samples_per_s = static_cast<double>(r.samples) / r.wall_s;
  r.batches_per_s = static_cast<double>(r.batches) / r.wall_s;
  r.p50_us = Percentile(shared.latencies_us, 0.50);
  r.p99_us = Percentile(shared.latencies_us, 0.99);
  r.max_us = shared.latencies_us.empty()
                 ? 0
                 : *std::max_element(shared.latencies_us.begin(), shared.latencies_us.end());
  r.failed = shared.failed;
  if (shared.failed > 0) {
    std::fprintf(stderr, "N=%d: %d streams failed, first: %s\n", n, shared.failed,
                 shared.first_error.c_str());
  }
  r.check = CheckStored(store, robots, flags.batch);
  if (!r.check.first_problem.empty()) {
    std::fprintf(stderr,
                 "N=%d: %d sessions hold fewer samples than acknowledged, %d more; first: %s\n", n,
                 r.check.lost, r.check.extra, r.check.first_problem.c_str());
  }
  return r;
}

double ThreadCpuS() {
  rusage u{};
  getrusage(RUSAGE_THREAD, &u);
  return u.ru_utime.tv_sec + u.ru_stime.tv_sec + 1e-6 * (u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

// ---- Breakdown: the pieces of one batch, single-threaded, no gRPC.

// One line of the breakdown: `batches` batches of `per` samples in `s` seconds.
void PrintPerBatch(const char* what, int64_t batches, double s, int per) {
  std::printf("  %-52s %9.1f us/batch %8.0f batches/s %10.0f samples/s\n", what,
              1e6 * s / static_cast<double>(batches), static_cast<double>(batches) / s,
              static_cast<double>(batches * per) / s);
}

// A bench device and an open six-face session for it, straight in the store; the session's id.
std::string NewStoredSession(imucal::storage::Store& store, const std::string& id) {
  (void)store.CreateDevice(BenchDevice(id), "bench");
  imucal::storage::Session s;
  s.device_id = id;
  s.protocol = "six-face";
  return store.CreateSession(s, "bench")->id;
}

// Protobuf: fill + serialize (client side), parse (server side).
void BreakdownProtobuf(const Columns& col, int per) {
  v1::SampleBatch b;
  std::string wire;
  const int k = 20000;
  Clock::time_point t0 = Clock::now();
  for (int i = 1; i <= k; ++i) {
    FillBatch(col, per, i, &b);
    wire.clear();
    b.SerializeToString(&wire);
  }
  PrintPerBatch("client: fill columns + proto serialize", k, Seconds(Clock::now() - t0), per);
  v1::SampleBatch parsed;
  t0 = Clock::now();
  for (int i = 1; i <= k; ++i) parsed.ParseFromString(wire);
  PrintPerBatch("server: proto parse", k, Seconds(Clock::now() - t0), per);
  std::printf("  (wire size %zu bytes per batch, %.1f bytes/sample)\n", wire.size(),
              static_cast<double>(wire.size()) / per);
}

// IngestBatch: the server's whole per-batch work bar gRPC (validate, encode, commit, segment),
// for 2 s. False when it failed.
bool BreakdownIngest(imucal::storage::Store& store, const Columns& col, int per) {
  const std::string sid = NewStoredSession(store, absl::StrCat("breakdown-", RunTag(), "-ingest"));
  imucal::server::SessionHub hub(&store);
  std::shared_ptr<imucal::server::LiveSession> live = *hub.Get(sid);
  v1::SampleBatch b;
  int64_t k = 0;
  double fill_s = 0;
  const Clock::time_point t0 = Clock::now();
  while (Seconds(Clock::now() - t0) < 2.0) {
    const Clock::time_point f0 = Clock::now();
    FillBatch(col, per, k + 1, &b);
    fill_s += Seconds(Clock::now() - f0);
    std::lock_guard lock(live->mu);
    absl::StatusOr<imucal::server::IngestResult> res = imucal::server::IngestBatch(store, *live, b);
    if (!res.ok()) {
      std::fprintf(stderr, "IngestBatch: %s\n", std::string(res.status().message()).c_str());
      return false;
    }
    ++k;
  }
  PrintPerBatch("server: IngestBatch (validate+encode+commit+segment)", k,
                Seconds(Clock::now() - t0) - fill_s, per);
  return true;
}

// The parts of IngestBatch bar the commit: validation + ToSamples + EncodeSamples; segmenter.
void BreakdownIngestParts(const Columns& col, int per) {
  {
    v1::SampleBatch b;
    FillBatch(col, per, 1, &b);
    const int k = 20000;
    Clock::time_point t0 = Clock::now();
    size_t bytes = 0;
    for (int i = 0; i < k; ++i) {
      (void)imucal::server::ValidateBatchColumns(b, "m/s^2", "rad/s");
      (void)imucal::server::ValidateBatchTimes(b, -1.0);
      std::vector<imucal::storage::ImuSample> s = imucal::server::ToSamples(b);
      bytes += imucal::storage::EncodeSamples(s)->size();
    }
    PrintPerBatch("  of which validate + ToSamples + EncodeSamples", k, Seconds(Clock::now() - t0),
                  per);
    std::printf("  (stored payload %.1f bytes/sample)\n",
                static_cast<double>(bytes) / (static_cast<double>(k) * per));
  }
  imucal::core::OnlineSegmenter seg(
      imucal::server::SegmenterOptionsFor(BenchDevice("seg"), v1::PROTOCOL_SIX_FACE));
  std::vector<imucal::core::SegmenterEvent> events;
  const int64_t k = static_cast<int64_t>(col.n) / per;
  Clock::time_point t0 = Clock::now();
  for (int64_t i = 0; i < k * per; ++i) {
    const size_t j = static_cast<size_t>(i);
    seg.Add(col.t[j], Eigen::Vector3d(col.accel[3 * j], col.accel[3 * j + 1], col.accel[3 * j + 2]),
            Eigen::Vector3d(col.gyro[3 * j], col.gyro[3 * j + 1], col.gyro[3 * j + 2]), &events);
  }
  PrintPerBatch("  of which online segmenter", k, Seconds(Clock::now() - t0), per);
}

// Store::AppendBatch alone (the commit), for 2 s or 200,000 batches, and its latency per call.
void BreakdownAppend(imucal::storage::Store& store, const Columns& col, int per) {
  const std::string sid = NewStoredSession(store, absl::StrCat("breakdown-", RunTag(), "-append"));
  v1::SampleBatch b;
  const int64_t k_max = 200000;
  int64_t k = 0;
  double encode_s = 0;
  std::vector<double> lat_us;
  const double cpu0 = ThreadCpuS();
  const Clock::time_point t0 = Clock::now();
  while (k < k_max && Seconds(Clock::now() - t0) < 2.0) {
    const Clock::time_point e0 = Clock::now();
    FillBatch(col, per, k + 1, &b);
    std::string payload = *imucal::storage::EncodeSamples(imucal::server::ToSamples(b));
    const Clock::time_point a0 = Clock::now();
    encode_s += Seconds(a0 - e0);
    absl::StatusOr<imucal::storage::BatchAck> ack = store.AppendBatch(sid, k + 1, payload);
    lat_us.push_back(1e6 * Seconds(Clock::now() - a0));
    if (!ack.ok()) {
      std::fprintf(stderr, "AppendBatch: %s\n", std::string(ack.status().message()).c_str());
      return;
    }
    ++k;
  }
  const double wall = Seconds(Clock::now() - t0), cpu = ThreadCpuS() - cpu0;
  PrintPerBatch("  of which Store::AppendBatch (one commit per batch)", k, wall - encode_s, per);
  double sum = 0;
  for (double x : lat_us) sum += x;
  const double mean = sum / static_cast<double>(lat_us.size());
  const double p50 = Percentile(lat_us, 0.5), p99 = Percentile(lat_us, 0.99),
               p999 = Percentile(lat_us, 0.999);
  std::sort(lat_us.begin(), lat_us.end());
  double slow = 0;  // time spent in calls over 1 ms (WAL checkpoints: write + fsync)
  for (double x : lat_us)
    if (x > 1000) slow += x;
  std::printf(
      "    AppendBatch per call: mean %.0f us, p50 %.0f us, p99 %.0f us, p99.9 %.0f us, "
      "max %.1f ms; calls > 1 ms take %.0f%% of the time; thread cpu %.0f%% of wall\n",
      mean, p50, p99, p999, lat_us.back() / 1e3, 100 * slow / sum, 100 * cpu / wall);
}

void Breakdown(const Flags& flags, const Columns& col, const std::string& db) {
  std::printf("\nBreakdown (one thread, no gRPC), batch = %d samples:\n", flags.batch);
  BreakdownProtobuf(col, flags.batch);
  absl::StatusOr<std::unique_ptr<imucal::storage::Store>> store = imucal::storage::Store::Open(db);
  if (!store.ok()) {
    std::fprintf(stderr, "breakdown store: %s\n", std::string(store.status().message()).c_str());
    return;
  }
  if (!BreakdownIngest(**store, col, flags.batch)) return;
  BreakdownIngestParts(col, flags.batch);
  BreakdownAppend(**store, col, flags.batch);
}

// The header lines: the servers, the database, the batch and round settings.
void PrintSetup(const Flags& flags, const std::vector<Child>& servers, const std::string& db,
                bool sqlite_file, const std::optional<PostgresCpu>& pg_cpu) {
  std::printf("imucal ingest bench: %d server(s) on %s (%s)\n", static_cast<int>(servers.size()),
              DescribeDb(db).c_str(),
              sqlite_file ? "WAL, synchronous=FULL: the Store default"
                          : "synchronous_commit=on: the server's own fsync setting applies");
  for (const Child& child : servers)
    std::printf("  server pid %d on 127.0.0.1:%d\n", static_cast<int>(child.pid), child.port);
  if (!sqlite_file) {
    if (pg_cpu)
      std::printf("  PostgreSQL postmaster pid %d (db_cpu: it and every process under it)\n",
                  static_cast<int>(pg_cpu->postmaster()));
    else
      std::printf("  PostgreSQL not on this machine (or unreachable): db_cpu not measured\n");
  }
  std::printf(
      "batch %d samples (t, accel[3], gyro[3], temp per sample), window %d batch(es) "
      "per stream, %d channel(s) per server, %.1f s per round, %ld cores\n\n",
      flags.batch, flags.window, flags.channels, flags.seconds, sysconf(_SC_NPROCESSORS_ONLN));
}

// A round's row (and each server's CPU below it when there are several).
void PrintRound(const RoundResult& r, size_t servers) {
  const std::string db_cpu =
      r.db_cpu_s < 0 ? "-" : absl::StrFormat("%.0f%%", 100 * r.db_cpu_s / r.wall_s);
  std::printf(
      "%6d %8.2f %11lld %12.0f %10.0f %9.2f %9.2f %9.2f %7.0f%% %7.0f%% %8s %6d %5d %5d  %s\n", r.n,
      r.wall_s, static_cast<long long>(r.samples), r.samples_per_s, r.batches_per_s, r.p50_us / 1e3,
      r.p99_us / 1e3, r.max_us / 1e3, 100 * r.client_cpu_s / r.wall_s,
      100 * r.server_cpu_s / r.wall_s, db_cpu.c_str(), r.failed, r.check.lost, r.check.extra,
      r.load.c_str());
  if (servers > 1) {
    std::string split;
    for (double cpu : r.replica_cpu_s)
      absl::StrAppend(&split, " ", absl::StrFormat("%.0f%%", 100 * cpu / r.wall_s));
    std::printf("%6s srv_cpu per server:%s\n", "", split.c_str());
  }
}

}  // namespace

int main(int argc, char** argv) {
  const Flags flags = ParseFlags(argc, argv);
  char tmpl[] = "/tmp/imucal-ingest-bench-XXXXXX";
  if (mkdtemp(tmpl) == nullptr) {
    std::perror("mkdtemp");
    return 1;
  }
  const std::string dir = tmpl;
  const std::string db = flags.db.empty() ? dir + "/ingest.db" : flags.db;
  const bool sqlite_file = !imucal::sql::IsPostgresUrl(db);
  const Columns col = SixFaceColumns();

  // Fork before any gRPC object exists in this process.
  std::vector<Child> servers = ForkServers(db, flags.replicas, flags.server_cpu);
  PinToCpu(flags.client_cpu);  // after the fork: the servers keep their own core
  const std::optional<PostgresCpu> pg_cpu = sqlite_file ? std::nullopt : PostgresCpu::Find(db);
  // For the check after each round: the database read directly, not through a server.
  absl::StatusOr<std::unique_ptr<imucal::storage::Store>> store = imucal::storage::Store::Open(db);
  if (!store.ok()) {
    std::fprintf(stderr, "open %s: %s\n", imucal::sql::RedactedLocation(db).c_str(),
                 std::string(store.status().message()).c_str());
    StopServers(servers);
    return 1;
  }
  PrintSetup(flags, servers, db, sqlite_file, pg_cpu);

  std::vector<std::shared_ptr<grpc::Channel>> channels =
      RoundRobinChannels(servers, flags.channels);

  std::printf("%6s %8s %11s %12s %10s %9s %9s %9s %8s %8s %8s %6s %5s %5s  %s\n", "N", "wall_s",
              "samples", "samples/s", "batches/s", "p50_ms", "p99_ms", "max_ms", "cli_cpu",
              "srv_cpu", "db_cpu", "failed", "lost", "extra", "loadavg(before)");
  int round = 0;
  int problems = 0;
  for (int n : flags.ns) {
    RoundResult r = RunRound(flags, col, servers, pg_cpu, **store, channels, n, round++);
    PrintRound(r, servers.size());
    std::fflush(stdout);
    problems += r.failed + r.check.lost + r.check.extra;
  }
  channels.clear();
  store->reset();
  StopServers(servers);
  std::error_code ec;
  if (sqlite_file) {
    std::printf("\ndb size after the rounds: %.1f MB (+ WAL)\n",
                static_cast<double>(std::filesystem::file_size(db, ec)) / 1e6);
  }
  // The breakdown's store is the bench's database (a SQLite file of its own by default).
  if (flags.breakdown) Breakdown(flags, col, flags.db.empty() ? dir + "/breakdown.db" : db);
  if (!flags.keep) std::filesystem::remove_all(dir, ec);
  return problems == 0 ? 0 : 1;
}
