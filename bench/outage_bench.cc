// How soon an upload resumes once the server is back: the real imucald in its own process on a
// loopback port, an upload through the SDK's Uploader with its default retry policy over
// sdk::MakeChannel (exactly what a robot and `imucal upload` run), and the server SIGKILLed
// when the upload has its first acknowledgement, kept down for each outage of --outages, then
// started again on the same port and file. Per outage, --runs times:
//   back -> resumed: from the moment the new server accepts connections (polled every 5 ms) to
//                    the upload's next acknowledgement;
//   attempts:        the Uploader's attempts after the first (UploadResult::reconnects);
// and whether the session then holds every sample once (its sample count and SHA-256 against
// the capture's).
//
//   ninja -C build bench/outage_bench imucald
//   build/bench/outage_bench [--outages=0,5,30,60] [--runs=3] [--imucald=PATH]
// Not part of ctest (tests/server/outage_test.cc asserts the upload completes; it times
// nothing).
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "bench/bench_flags.h"
#include "bench/service_bench_util.h"
#include "client/sdk/client.h"
#include "client/sdk/uploader.h"
#include "formats/sample_digest.h"
#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"

namespace {

namespace v1 = imucal::v1;
using namespace imucal::bench;  // Clock, Seconds, StartImucald, Listening, ...

struct Flags {
  std::vector<int> outages_s = {0, 5, 30, 60};
  int runs = 3;
  std::string imucald = IMUCAL_IMUCALD_PATH;
};

Flags ParseFlags(int argc, char** argv) {
  Flags f;
  CLI::App app{
      "How soon an upload through the SDK's Uploader resumes once imucald is back from an "
      "outage.",
      "outage_bench"};
  app.add_option("--outages", f.outages_s, "outages to measure, in seconds, comma-separated")
      ->delimiter(',')
      ->check(CLI::Range(0, std::numeric_limits<int>::max()).description("NONNEGATIVE"));
  app.add_option("--runs", f.runs, "runs per outage (at least 1)");
  app.add_option("--imucald", f.imucald, "the imucald binary to run");
  imucal::bench::ParseBenchFlags(app, argc, argv);
  f.runs = std::max(1, f.runs);
  return f;
}

// A capture of 200,000 samples (1000 s at 200 Hz): long enough that it is still uploading
// after the server comes back.
imucal::sdk::SampleColumns Capture() {
  imucal::sdk::SampleColumns c;
  for (int k = 0; k < 200000; ++k) {
    const double x = k;
    c.t_s.push_back(x / 200);
    for (double v : {0.01 * std::sin(x), -0.02 * std::cos(x), 9.80665 + 0.01 * std::sin(3 * x)})
      c.accel.push_back(v);
    for (double v : {1e-3 * std::cos(x), -1e-3 * std::sin(2 * x), 2e-3}) c.gyro.push_back(v);
    c.temp_c.push_back(25.0 + 1e-4 * x);
  }
  return c;
}

std::string OpenSession(const std::shared_ptr<grpc::Channel>& channel, const std::string& device) {
  v1::RegisterDeviceRequest reg;
  reg.mutable_device()->set_id(device);
  reg.mutable_device()->set_sensor_model("sim");
  reg.mutable_device()->set_nominal_rate_hz(200);
  reg.mutable_device()->set_accel_unit("m/s^2");
  reg.mutable_device()->set_gyro_unit("rad/s");
  v1::Device d;
  grpc::ClientContext c1;
  c1.set_wait_for_ready(true);
  if (!v1::DeviceService::NewStub(channel)->RegisterDevice(&c1, reg, &d).ok()) return "";
  v1::CreateSessionRequest create;
  create.set_device_id(device);
  v1::Session session;
  grpc::ClientContext c2;
  if (!v1::SessionService::NewStub(channel)->CreateSession(&c2, create, &session).ok()) return "";
  return session.id();
}

struct Run {
  double back_to_resumed_s = -1;
  int attempts = 0;
  bool complete = false;
};

Run OneOutage(const Flags& flags, const std::string& dir, int port, int outage_s, int index,
              const imucal::sdk::SampleColumns& capture, pid_t* server) {
  Run run;
  const std::string listen = absl::StrCat("127.0.0.1:", port);
  const std::string db = dir + "/outage.db";
  auto channel = imucal::sdk::MakeChannel(listen);
  const std::string session = OpenSession(channel, absl::StrCat("outage-", outage_s, "-", index));
  if (session.empty()) return run;
  std::mutex mu;
  std::condition_variable cv;
  bool first_ack = false, killed = false;
  std::optional<Clock::time_point> back, resumed;
  imucal::sdk::UploadOptions options;  // the default retry policy is what is measured
  options.batch_samples = 2000;
  options.progress = [&](int64_t acked, int64_t) {
    std::unique_lock lock(mu);
    if (acked == 0) return;
    if (!first_ack) {
      first_ack = true;
      cv.notify_all();
      cv.wait(lock, [&] { return killed; });
      return;
    }
    if (back && !resumed) resumed = Clock::now();
  };
  imucal::sdk::Uploader uploader(channel, options);
  absl::StatusOr<imucal::sdk::UploadResult> result;
  std::thread robot([&] { result = uploader.Upload(session, capture); });
  {
    std::unique_lock lock(mu);
    cv.wait(lock, [&] { return first_ack; });
  }
  kill(*server, SIGKILL);
  waitpid(*server, nullptr, 0);
  {
    std::lock_guard lock(mu);
    killed = true;
  }
  cv.notify_all();
  std::this_thread::sleep_for(std::chrono::seconds(outage_s));  // the outage itself
  *server = StartImucald(flags.imucald, db, listen, {"--insecure"}, -1, dir + "/imucald.log");
  while (!Listening(port)) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  {
    std::lock_guard lock(mu);
    back = Clock::now();
  }
  robot.join();
  if (!result.ok()) {
    std::fprintf(stderr, "  outage %d s, run %d: %s\n", outage_s, index,
                 std::string(result.status().message()).c_str());
    return run;
  }
  run.attempts = result->reconnects;
  {
    std::lock_guard lock(mu);
    if (back && resumed) run.back_to_resumed_s = Seconds(*resumed - *back);
  }
  // Every sample once: the session's count and digest against the capture's.
  v1::GetSessionRequest get;
  get.set_session_id(session);
  v1::Session stored;
  grpc::ClientContext ctx;
  ctx.set_wait_for_ready(true);
  if (v1::SessionService::NewStub(channel)->GetSession(&ctx, get, &stored).ok()) {
    imucal::formats::SampleDigest digest;
    for (int64_t i = 0; i < capture.size(); ++i) {
      const size_t k = static_cast<size_t>(i);
      digest.AddSample(capture.t_s[k], &capture.accel[3 * k], &capture.gyro[3 * k],
                       &capture.temp_c[k]);
    }
    run.complete = stored.samples() == capture.size() && stored.samples_sha256() == digest.Sha256();
  }
  return run;
}

}  // namespace

int main(int argc, char** argv) {
  const Flags flags = ParseFlags(argc, argv);
  char tmpl[] = "/tmp/imucal-outage-bench-XXXXXX";
  if (mkdtemp(tmpl) == nullptr) {
    std::perror("mkdtemp");
    return 1;
  }
  const std::string dir = tmpl;
  const imucal::sdk::SampleColumns capture = Capture();
  const int port = FreeLoopbackPort();
  pid_t server = StartImucald(flags.imucald, dir + "/outage.db", absl::StrCat("127.0.0.1:", port),
                              {"--insecure"});
  while (!Listening(port)) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  std::printf("imucal outage bench: %lld samples per upload, %d runs per outage, %s; load %s\n",
              static_cast<long long>(capture.size()), flags.runs, flags.imucald.c_str(),
              LoadAvg().c_str());
  std::printf(
      "| outage | back -> upload resumed, each run | median | attempts | every sample once |\n");
  std::printf("|---|---|---|---|---|\n");
  int failures = 0;
  for (const int outage_s : flags.outages_s) {
    std::vector<double> times;
    std::string each, attempts;
    int complete = 0;
    for (int r = 0; r < flags.runs; ++r) {
      const Run run = OneOutage(flags, dir, port, outage_s, r, capture, &server);
      times.push_back(run.back_to_resumed_s);
      absl::StrAppend(&each, r == 0 ? "" : ", ",
                      run.back_to_resumed_s < 0 ? std::string("-")
                                                : absl::StrFormat("%.2f s", run.back_to_resumed_s));
      absl::StrAppend(&attempts, r == 0 ? "" : ", ", run.attempts);
      complete += run.complete;
    }
    failures += flags.runs - complete;
    std::printf("| %d s | %s | %.2f s | %s | %d/%d |\n", outage_s, each.c_str(),
                Percentile(times, 0.5), attempts.c_str(), complete, flags.runs);
    std::fflush(stdout);
  }
  kill(server, SIGTERM);
  waitpid(server, nullptr, 0);
  std::error_code ec;
  std::filesystem::remove_all(dir, ec);
  return failures == 0 ? 0 : 3;
}
