// What clients that hold the server's resources without using them cost imucald: the real
// binary in its own process on loopback (its memory is its own), RSS from /proc/PID/status.
//
//   --case=silent-streams: --tokens robot tokens (default 1; TLS, as a fleet runs) open
//     --streams sample streams between them, round robin (default 30,000, over --channels
//     connections), that never send a batch. Reported: imucald's RSS idle, its peak while they
//     are open, how many were refused at once (max_streams, max_streams_per_token), how many
//     the server ended for silence within --wait seconds (first_batch_timeout), its RSS then,
//     and after the client hung up on the rest: 2 s after, and --settle seconds after (the
//     server gives memory back after a flood at most every 10 s, server/stream_registry.h).
//   --case=closed-cancels: a session of --samples samples (default 10,000,000, streamed through
//     the API in 20,000-sample batches, then cancelled), imucald restarted on the file, and
//     --calls CancelSession calls on it (then a StreamSamples and a SolveSession on it): each
//     call's time, its answer and imucald's RSS after it. Before the fix the first call decoded
//     and replayed the whole session into memory and kept it there.
//
//   ninja -C build bench/misuse_bench imucald
//   build/bench/misuse_bench [--case=all|silent-streams|closed-cancels] [--streams=30000]
//                            [--tokens=1] [--channels=8] [--wait=40] [--settle=15]
//                            [--samples=10000000] [--calls=5]
//                            [--imucald=PATH] [--keep]
// --imucald=PATH measures another build (e.g. one from before the limits, for a "before"
// column); it is run with --listen, --db, and the TLS flags or --insecure only. Not part of
// ctest.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "bench/bench_flags.h"
#include "bench/service_bench_util.h"
#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/log.h"

namespace {

namespace v1 = imucal::v1;
using namespace imucal::bench;  // Clock, Seconds, StartImucald, ProcStatusKb, ...

struct Flags {
  std::string which = "all";
  int streams = 30000;
  int tokens = 1;
  int channels = 8;
  double settle_s = 15;
  double wait_s = 40;  // first_batch_timeout (30 s) and the sweeper's tick, with a margin
  int64_t samples = 10'000'000;
  int calls = 5;
  std::string imucald = IMUCAL_IMUCALD_PATH;
  bool keep = false;
};

Flags ParseFlags(int argc, char** argv) {
  Flags f;
  CLI::App app{
      "What clients that hold imucald's resources without using them cost it: silent sample "
      "streams, and cancels of a closed session of many samples.",
      "misuse_bench"};
  app.add_option("--case", f.which, "which case to run")
      ->check(CLI::IsMember({"all", "silent-streams", "closed-cancels"}));
  app.add_option("--streams", f.streams, "silent-streams: sample streams that never send a batch");
  app.add_option("--tokens", f.tokens,
                 "silent-streams: robot tokens the streams are spread over (at least 1)");
  app.add_option("--settle", f.settle_s,
                 "silent-streams: seconds after the hang-up to measure RSS again");
  app.add_option("--channels", f.channels,
                 "silent-streams: connections the streams are spread over (at least 1)");
  app.add_option("--wait", f.wait_s,
                 "silent-streams: seconds to wait for the server to end them for silence");
  app.add_option("--samples", f.samples, "closed-cancels: samples in the session");
  app.add_option("--calls", f.calls, "closed-cancels: CancelSession calls on it");
  app.add_option("--imucald", f.imucald,
                 "the imucald binary to run (another build, e.g. one from before the limits)");
  app.add_flag("--keep", f.keep, "keep the temp directory");
  imucal::bench::ParseBenchFlags(app, argc, argv);
  f.channels = std::max(1, f.channels);
  f.tokens = std::max(1, f.tokens);
  return f;
}

double Mb(int64_t kb) { return static_cast<double>(kb) / 1024.0; }

void Die(const std::string& what, pid_t server) {
  std::fprintf(stderr, "%s\n", what.c_str());
  if (server > 0) {
    kill(server, SIGKILL);
    waitpid(server, nullptr, 0);
  }
  std::exit(1);
}

// ---- silent streams ----------------------------------------------------------------------

// A sample stream that never sends: it only waits to hear how it ends.
class SilentStream final : public grpc::ClientBidiReactor<v1::SampleBatch, v1::SampleAck> {
 public:
  struct Tally {
    std::mutex mu;
    std::condition_variable cv;
    std::map<grpc::StatusCode, int> ended;  // by code; guarded by mu
    int done = 0;                           // guarded by mu
  };
  SilentStream(v1::SessionService::Stub* stub, const std::shared_ptr<grpc::CallCredentials>& token,
               Tally* tally)
      : tally_(tally) {
    context_.set_credentials(token);
    stub->async()->StreamSamples(&context_, this);
    StartRead(&ack_);
    StartCall();
  }
  void HangUp() { context_.TryCancel(); }
  void OnReadDone(bool ok) override {
    if (ok) StartRead(&ack_);
  }
  void OnDone(const grpc::Status& status) override {
    std::lock_guard lock(tally_->mu);
    ++tally_->ended[status.error_code()];
    ++tally_->done;
    tally_->cv.notify_all();
  }

 private:
  Tally* tally_;
  grpc::ClientContext context_;
  v1::SampleAck ack_;
};

// imucald with TLS on a fresh database in `dir`, and the fleet's side of it: `flags.tokens`
// robot tokens (made with its admin token), which go with each call, and `flags.channels`
// connections the robots share.
struct TlsFleet {
  pid_t server = -1;
  std::vector<std::shared_ptr<grpc::CallCredentials>> tokens;
  std::vector<std::shared_ptr<grpc::Channel>> channels;
  std::vector<std::unique_ptr<v1::SessionService::Stub>> stubs;
};

TlsFleet StartTlsFleet(const Flags& flags, const std::string& dir) {
  const std::string db = dir + "/silent.db", token_file = dir + "/admin-token";
  const std::vector<std::string> tls = TlsServerArgs(dir, token_file);
  if (tls.empty()) Die("the openssl CLI could not make a certificate", -1);
  const int port = FreeLoopbackPort();
  const std::string listen = absl::StrCat("127.0.0.1:", port);
  TlsFleet fleet;
  fleet.server = StartImucald(flags.imucald, db, listen, tls, -1, dir + "/imucald.log");
  const grpc::SslCredentialsOptions ssl = TrustBenchCertificate(dir);
  const std::optional<std::string> admin = AwaitAdminToken(listen, ssl, token_file);
  if (!admin) Die("imucald did not come up", fleet.server);
  auto admin_stub = v1::AdminService::NewStub(grpc::CreateChannel(
      listen, grpc::CompositeChannelCredentials(grpc::SslCredentials(ssl),
                                                grpc::AccessTokenCredentials(*admin))));
  for (int t = 0; t < flags.tokens; ++t) {
    v1::CreateTokenRequest create;
    create.set_role(v1::ROLE_ROBOT);
    create.set_device_id(absl::StrCat("misuse-robot-", t));
    create.set_label("misuse bench");
    v1::CreateTokenResponse robot;
    grpc::ClientContext ctx;
    if (grpc::Status s = admin_stub->CreateToken(&ctx, create, &robot); !s.ok())
      Die("CreateToken: " + s.error_message(), fleet.server);
    fleet.tokens.push_back(grpc::AccessTokenCredentials(robot.secret()));
  }
  auto robot_creds = grpc::SslCredentials(ssl);
  for (int i = 0; i < flags.channels; ++i) {
    fleet.channels.push_back(BenchChannel(listen, robot_creds, i));
    if (!fleet.channels.back()->WaitForConnected(std::chrono::system_clock::now() +
                                                 std::chrono::seconds(30)))
      Die("a robot channel did not connect", fleet.server);
    fleet.stubs.push_back(v1::SessionService::NewStub(fleet.channels.back()));
  }
  return fleet;
}

// What SilentStreams measured; memory in kB.
struct SilentFigures {
  double open_s = 0;
  int64_t rss_idle = 0, peak = 0, rss_after_wait = 0, rss_after_hangup = 0, rss_settled = 0;
  int64_t hwm = 0;
  int refused_early = -1;
  std::map<grpc::StatusCode, int> by_server;  // the streams the server ended, by code
  int ended_by_server = 0;
};

void PrintSilentStreams(const Flags& flags, const SilentFigures& f) {
  std::printf("silent streams: %d opened in %.1f s by %d robot token(s) over %d connections (%s)\n",
              flags.streams, f.open_s, flags.tokens, flags.channels, flags.imucald.c_str());
  std::printf("  imucald RSS idle %.1f MB, peak with the streams %.1f MB (VmHWM %.1f MB)\n",
              Mb(f.rss_idle), Mb(f.peak), Mb(f.hwm));
  std::printf("  refused at once (RESOURCE_EXHAUSTED): %d\n", std::max(f.refused_early, 0));
  std::printf("  ended by the server within %.0f s:", flags.wait_s);
  if (f.by_server.empty()) std::printf(" none");
  for (const auto& [code, n] : f.by_server)
    std::printf(" %s=%d", std::string(imucal::server::CodeName(code)).c_str(), n);
  std::printf(" (%d of %d)\n", f.ended_by_server, flags.streams);
  std::printf("  imucald RSS after %.0f s %.1f MB; after the client hung up on the rest %.1f MB\n",
              flags.wait_s, Mb(f.rss_after_wait), Mb(f.rss_after_hangup));
  std::printf("  imucald RSS after the flood, no stream open: %.1f MB (%.0f s after the hang-up)\n",
              Mb(f.rss_settled), flags.settle_s);
}

int SilentStreams(const Flags& flags, const std::string& dir) {
  TlsFleet fleet = StartTlsFleet(flags, dir);
  const pid_t server = fleet.server;
  SilentFigures f;
  f.rss_idle = ProcStatusKb(server, "VmRSS");

  SilentStream::Tally tally;
  std::vector<std::unique_ptr<SilentStream>> streams;
  const Clock::time_point t0 = Clock::now();
  for (int i = 0; i < flags.streams; ++i)
    streams.push_back(std::make_unique<SilentStream>(
        fleet.stubs[static_cast<size_t>(i) % fleet.stubs.size()].get(),
        fleet.tokens[static_cast<size_t>(i) % fleet.tokens.size()], &tally));
  f.open_s = Seconds(Clock::now() - t0);
  while (Seconds(Clock::now() - t0) < flags.wait_s) {
    std::this_thread::sleep_for(std::chrono::milliseconds(250));  // the sampling period
    f.peak = std::max(f.peak, ProcStatusKb(server, "VmRSS"));
    if (f.refused_early < 0 && Seconds(Clock::now() - t0) > f.open_s + 5) {
      std::lock_guard lock(tally.mu);
      const auto it = tally.ended.find(grpc::StatusCode::RESOURCE_EXHAUSTED);
      f.refused_early = it == tally.ended.end() ? 0 : it->second;
    }
  }
  f.rss_after_wait = ProcStatusKb(server, "VmRSS");
  {
    std::lock_guard lock(tally.mu);
    f.by_server = tally.ended;
  }
  for (const auto& [code, n] : f.by_server) f.ended_by_server += n;
  for (auto& s : streams) s->HangUp();
  {
    std::unique_lock lock(tally.mu);
    tally.cv.wait(lock, [&] { return tally.done == flags.streams; });
  }
  const Clock::time_point hung_up = Clock::now();
  std::this_thread::sleep_for(std::chrono::seconds(2));  // lets imucald free what it held
  f.rss_after_hangup = ProcStatusKb(server, "VmRSS");
  std::this_thread::sleep_for(std::chrono::duration<double>(
      std::max(0.0, flags.settle_s - Seconds(Clock::now() - hung_up))));
  f.rss_settled = ProcStatusKb(server, "VmRSS");
  f.hwm = ProcStatusKb(server, "VmHWM");
  streams.clear();
  fleet.stubs.clear();
  fleet.channels.clear();
  kill(server, SIGTERM);
  waitpid(server, nullptr, 0);
  PrintSilentStreams(flags, f);
  return 0;
}

// ---- cancels of a closed session ---------------------------------------------------------

// A device and a session of `samples` samples (a robot at rest, 200 Hz, 20,000 a batch)
// streamed through `stub`'s server and then cancelled; returns the session's id. Through the
// API, not storage::Store, so that any imucald build can be measured on a file of its own
// schema.
std::string StreamClosedSession(v1::DeviceService::Stub* devices, v1::SessionService::Stub* stub,
                                int64_t samples, pid_t server) {
  auto deadline = [] {
    auto c = std::make_unique<grpc::ClientContext>();
    c->set_deadline(std::chrono::system_clock::now() + std::chrono::minutes(10));
    return c;
  };
  v1::RegisterDeviceRequest reg;
  reg.mutable_device()->set_id("misuse-closed");
  reg.mutable_device()->set_sensor_model("sim");
  reg.mutable_device()->set_nominal_rate_hz(200);
  reg.mutable_device()->set_accel_unit("m/s^2");
  reg.mutable_device()->set_gyro_unit("rad/s");
  v1::Device device;
  if (grpc::Status s = devices->RegisterDevice(deadline().get(), reg, &device); !s.ok())
    Die("RegisterDevice: " + s.error_message(), server);
  v1::CreateSessionRequest create;
  create.set_device_id("misuse-closed");
  v1::Session session;
  if (grpc::Status s = stub->CreateSession(deadline().get(), create, &session); !s.ok())
    Die("CreateSession: " + s.error_message(), server);
  constexpr int64_t kBatch = 20000;
  auto ctx = deadline();
  auto stream = stub->StreamSamples(ctx.get());
  int64_t seq = 0;
  for (int64_t first = 0; first < samples; first += kBatch) {
    v1::SampleBatch b;
    b.set_session_id(session.id());
    b.set_seq(++seq);
    for (int64_t k = first; k < std::min(samples, first + kBatch); ++k) {
      const double x = static_cast<double>(k);
      b.add_t_s(x / 200);
      for (double v : {0.01 * std::sin(x), -0.02 * std::cos(x), 9.80665 + 0.01 * std::sin(3 * x)})
        b.add_accel(v);
      for (double v : {1e-3 * std::cos(x), -1e-3 * std::sin(2 * x), 2e-3}) b.add_gyro(v);
    }
    v1::SampleAck ack;
    if (!stream->Write(b) || !stream->Read(&ack)) break;
  }
  stream->WritesDone();
  if (grpc::Status s = stream->Finish(); !s.ok())
    Die("StreamSamples: " + s.error_message(), server);
  v1::CancelSessionRequest cancel;
  cancel.set_session_id(session.id());
  v1::Session cancelled;
  if (grpc::Status s = stub->CancelSession(deadline().get(), cancel, &cancelled); !s.ok())
    Die("CancelSession: " + s.error_message(), server);
  return session.id();
}

int ClosedCancels(const Flags& flags, const std::string& dir) {
  const std::string db = dir + "/closed.db";
  const int port = FreeLoopbackPort();
  const std::string listen = absl::StrCat("127.0.0.1:", port);
  const std::string log = dir + "/imucald.log";
  pid_t server = StartImucald(flags.imucald, db, listen, {"--insecure"}, -1, log);
  std::string session;
  {
    auto channel = grpc::CreateChannel(listen, grpc::InsecureChannelCredentials());
    if (!channel->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(60)))
      Die("imucald did not come up", server);
    const Clock::time_point p0 = Clock::now();
    session =
        StreamClosedSession(v1::DeviceService::NewStub(channel).get(),
                            v1::SessionService::NewStub(channel).get(), flags.samples, server);
    std::printf("closed session: %lld samples streamed and the session cancelled in %.1f s\n",
                static_cast<long long>(flags.samples), Seconds(Clock::now() - p0));
  }
  // A fresh server on the file: what it holds is what the calls below make it load.
  kill(server, SIGTERM);
  waitpid(server, nullptr, 0);
  server = StartImucald(flags.imucald, db, listen, {"--insecure"}, -1, log);
  auto channel = grpc::CreateChannel(listen, grpc::InsecureChannelCredentials());
  if (!channel->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(60)))
    Die("imucald did not come up again", server);
  auto stub = v1::SessionService::NewStub(channel);
  std::printf("  imucald (%s) RSS idle %.1f MB\n", flags.imucald.c_str(),
              Mb(ProcStatusKb(server, "VmRSS")));
  std::printf("  %-14s %10s  %-20s %12s\n", "call", "time", "answer", "RSS after");
  auto row = [&](const std::string& what, const Clock::time_point& start, const grpc::Status& s) {
    const double ms = 1e3 * Seconds(Clock::now() - start);
    std::printf("  %-14s %7.1f ms  %-20s %9.1f MB\n", what.c_str(), ms,
                std::string(imucal::server::CodeName(s.error_code())).c_str(),
                Mb(ProcStatusKb(server, "VmRSS")));
  };
  auto deadline = [] {
    auto c = std::make_unique<grpc::ClientContext>();
    c->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    return c;
  };
  for (int i = 1; i <= flags.calls; ++i) {
    v1::CancelSessionRequest req;
    req.set_session_id(session);
    v1::Session out;
    const Clock::time_point t = Clock::now();
    const grpc::Status s = stub->CancelSession(deadline().get(), req, &out);
    row(absl::StrCat("CancelSession ", i), t, s);
  }
  {
    auto ctx = deadline();
    const Clock::time_point t = Clock::now();
    auto stream = stub->StreamSamples(ctx.get());
    v1::SampleBatch b;
    b.set_session_id(session);
    b.set_seq(flags.samples / 20000 + 2);
    b.add_t_s(1e9);
    for (double x : {0.0, 0.0, 9.81}) b.add_accel(x);
    for (double x : {0.0, 0.0, 0.0}) b.add_gyro(x);
    stream->Write(b);
    stream->WritesDone();
    v1::SampleAck ack;
    while (stream->Read(&ack)) {
    }
    row("StreamSamples", t, stream->Finish());
  }
  {
    v1::SolveSessionRequest req;
    req.set_session_id(session);
    v1::SolveJob job;
    const Clock::time_point t = Clock::now();
    const grpc::Status s = stub->SolveSession(deadline().get(), req, &job);
    row("SolveSession", t, s);
  }
  std::printf("  imucald VmHWM %.1f MB\n", Mb(ProcStatusKb(server, "VmHWM")));
  stub.reset();
  channel.reset();
  kill(server, SIGTERM);
  waitpid(server, nullptr, 0);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const Flags flags = ParseFlags(argc, argv);
  char tmpl[] = "/tmp/imucal-misuse-bench-XXXXXX";
  if (mkdtemp(tmpl) == nullptr) {
    std::perror("mkdtemp");
    return 1;
  }
  const std::string dir = tmpl;
  std::printf("imucal misuse bench, %ld cores, load %s\n", sysconf(_SC_NPROCESSORS_ONLN),
              LoadAvg().c_str());
  int status = 0;
  if (flags.which == "all" || flags.which == "silent-streams") status |= SilentStreams(flags, dir);
  if (flags.which == "all" || flags.which == "closed-cancels") status |= ClosedCancels(flags, dir);
  std::error_code ec;
  if (flags.keep) {
    std::printf("kept %s\n", dir.c_str());
  } else {
    std::filesystem::remove_all(dir, ec);
  }
  return status;
}
