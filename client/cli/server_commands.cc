// Server commands: devices, session, upload, solve, report, params, export. Each is a thin
// layer over one or two RPCs of proto/imucal/v1/imucal.proto: parse flags -> call -> print
// (human by default, --json for scripts).
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "client/cli/args.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "client/cli/export_flags.h"
#include "client/cli/import_flags.h"
#include "client/cli/server_common.h"
#include "client/cli/summary.h"
#include "client/sdk/uploader.h"
#include "formats/params_json.h"
#include "formats/plots.h"
#include "importers/registry.h"
#include "nlohmann/json.hpp"
#include "util/file.h"

namespace imucal::cli {
namespace {

namespace pb = imucal::v1;
using nlohmann::json;

constexpr char kServerFlagHelp[] =
    "  --server ADDR     the calibration service (default $IMUCAL_SERVER, else 127.0.0.1:50051);\n"
    "                    replicas: ipv4:IP:PORT,IP:PORT or dns:///NAME:PORT (calls spread\n"
    "                    round-robin over those that answer)\n"
    "  --ca-cert PEM     CA of the server's TLS certificate (default $IMUCAL_CA_CERT)\n"
    "  --tls-server-name N   the name the certificate holds (default: the host dialled)\n"
    "  --token-file F | --token T   bearer token (default $IMUCAL_TOKEN_FILE, $IMUCAL_TOKEN)\n"
    "exit codes: 0 ok, 1 usage, 2 bad input or unknown id, 3 the state forbids it (e.g. not\n"
    "            enough poses yet), 4 verdict fail, 5 internal, 6 server unreachable,\n"
    "            7 the server refused the token or its role\n";

// ------------------------------------------------------------------------------------------
// devices

constexpr char kDevicesHelp[] =
    "usage: imucal devices [--json]\n"
    "       imucal devices register ID --sensor-model M --rate HZ --accel-unit U --gyro-unit U\n"
    "       imucal devices get ID [--json]\n"
    "  Lists the registered devices, registers one (the same metadata again is a no-op), or\n"
    "  shows one. Units: accel m/s^2|g|counts, gyro rad/s|deg/s|counts.\n"
    "options:\n";

void PrintDevice(const pb::Device& d) {
  std::printf("%-20s %-14s %8.1f Hz  accel %-6s gyro %-6s active %s\n", d.id().c_str(),
              d.sensor_model().empty() ? "-" : d.sensor_model().c_str(), d.nominal_rate_hz(),
              d.accel_unit().c_str(), d.gyro_unit().c_str(),
              d.active_version() > 0 ? absl::StrCat("v", d.active_version()).c_str() : "none");
}

int DevicesHelp() { return std::printf("%s%s", kDevicesHelp, kServerFlagHelp), kExitOk; }

}  // namespace

int RunDevices(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("devices", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kDevicesHelp);
  if (a->Has("help")) return DevicesHelp();
  Server server = Connect(*a);
  const auto& pos = a->positional();
  if (pos.empty()) {
    pb::ListDevicesResponse all;
    std::string token;
    do {
      pb::ListDevicesRequest req;
      req.set_page_size(1000);
      req.set_page_token(token);
      pb::ListDevicesResponse page;
      auto ctx = CallContext();
      if (grpc::Status s = server.devices->ListDevices(ctx.get(), req, &page); !s.ok())
        return RpcError(server, s);
      for (auto& d : *page.mutable_devices()) *all.add_devices() = std::move(d);
      token = page.next_page_token();
    } while (!token.empty());
    if (a->Has("json")) return std::printf("%s\n", ProtoJson(all).c_str()), kExitOk;
    if (all.devices().empty()) std::printf("no devices registered\n");
    for (const auto& d : all.devices()) PrintDevice(d);
    return kExitOk;
  }
  if (pos[0] == "get" && pos.size() == 2) {
    pb::GetDeviceRequest req;
    req.set_device_id(pos[1]);
    pb::Device d;
    auto ctx = CallContext();
    if (grpc::Status s = server.devices->GetDevice(ctx.get(), req, &d); !s.ok())
      return RpcError(server, s);
    if (a->Has("json")) return std::printf("%s\n", ProtoJson(d).c_str()), kExitOk;
    PrintDevice(d);
    return kExitOk;
  }
  if (pos[0] == "register" && pos.size() == 2) {
    for (const char* flag : {"rate", "accel-unit", "gyro-unit"}) {
      if (!a->Get(flag))
        return UsageError(absl::StrCat("devices register needs --", flag), kDevicesHelp);
    }
    auto rate = a->GetDouble("rate", 0);
    if (!rate.ok() || !(*rate > 0))
      return UsageError("--rate: expected a sample rate in Hz > 0", kDevicesHelp);
    pb::RegisterDeviceRequest req;
    pb::Device* d = req.mutable_device();
    d->set_id(pos[1]);
    d->set_sensor_model(a->Get("sensor-model").value_or(""));
    d->set_nominal_rate_hz(*rate);
    d->set_accel_unit(*a->Get("accel-unit"));
    d->set_gyro_unit(*a->Get("gyro-unit"));
    pb::Device out;
    auto ctx = CallContext();
    if (grpc::Status s = server.devices->RegisterDevice(ctx.get(), req, &out); !s.ok())
      return RpcError(server, s);
    if (a->Has("json")) return std::printf("%s\n", ProtoJson(out).c_str()), kExitOk;
    std::printf("registered %s\n", out.id().c_str());
    PrintDevice(out);
    return kExitOk;
  }
  return UsageError(absl::StrCat("devices: unexpected '", absl::StrJoin(pos, " "), "'"),
                    kDevicesHelp);
}

// ------------------------------------------------------------------------------------------
// session

namespace {

constexpr char kSessionHelp[] =
    "usage: imucal session start --device D [--protocol six-face|positions|free|ferraris|auto] "
    "[--json]\n"
    "       imucal session list [--device D] [--state open|solving|solved|failed|cancelled]\n"
    "       imucal session show ID [--json]\n"
    "       imucal session poses ID [--json]\n"
    "       imucal session cancel ID\n"
    "  Opens a calibration session (a device has at most one open), lists, shows (with its poses\n"
    "  and six-face pair verdicts as the server judged them while samples arrived), or cancels.\n"
    "options:\n"
    "  --gravity G       local gravity for `start`, m/s^2 (default 9.80665)\n";

void PrintSession(const pb::Session& s) {
  std::printf("%-14s %-18s %-9s %-9s %9lld samples %3d poses  %s%s\n", s.id().c_str(),
              s.device_id().c_str(), SessionStateName(s.state()).c_str(),
              ProtocolName(s.protocol()).c_str(), static_cast<long long>(s.samples()),
              s.poses_accepted(), TimeText(s.created_at()).c_str(),
              s.version() > 0 ? absl::StrCat("  -> v", s.version()).c_str() : "");
}

grpc::Status ListPoses(const Server& server, const std::string& session_id,
                       pb::ListPosesResponse* out) {
  pb::ListPosesRequest req;
  req.set_session_id(session_id);
  return server.sessions->ListPoses(CallContext().get(), req, out);
}

void PrintPoses(const pb::ListPosesResponse& poses) {
  for (const pb::PoseEvent& p : poses.poses()) {
    std::printf("  pose %2d %-3s %7.1f-%7.1f s  %s\n", p.index(), p.face().c_str(), p.t_start_s(),
                p.t_end_s(), p.accepted() ? "accepted" : ("rejected: " + p.reason()).c_str());
  }
  for (const pb::PairVerdict& p : poses.pairs()) {
    std::printf("  pair %-3s poses %d, %d: %s (turn %.1f deg, tilt %.1f deg)\n", p.face().c_str(),
                p.pose_a(), p.pose_b(), p.ok() ? "ok" : ("FAILED: " + p.reason()).c_str(),
                p.rotation_deg(), p.tilt_deg());
  }
}

absl::StatusOr<pb::SessionState> ParseState(const std::string& name) {
  for (int i = pb::SESSION_STATE_OPEN; i <= pb::SESSION_STATE_CANCELLED; ++i) {
    if (SessionStateName(static_cast<pb::SessionState>(i)) == name)
      return static_cast<pb::SessionState>(i);
  }
  return absl::InvalidArgumentError(absl::StrCat("--state: unknown state '", name, "'"));
}

}  // namespace

int RunSession(const std::vector<std::string>& argv) {
  auto a =
      ParseCommandFlags("session", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kSessionHelp);
  if (a->Has("help")) return std::printf("%s%s", kSessionHelp, kServerFlagHelp), kExitOk;
  const auto& pos = a->positional();
  if (pos.empty())
    return UsageError("session needs start, list, show, poses or cancel", kSessionHelp);
  Server server = Connect(*a);
  const bool as_json = a->Has("json");
  if (pos[0] == "start" && pos.size() == 1) {
    auto device = a->Get("device");
    if (!device) return UsageError("session start needs --device", kSessionHelp);
    auto protocol = ParseProtocol(a->Get("protocol").value_or("auto"));
    if (!protocol.ok()) return UsageError(std::string(protocol.status().message()), kSessionHelp);
    auto gravity = a->GetDouble("gravity", 0.0);
    if (!gravity.ok()) return UsageError(std::string(gravity.status().message()), kSessionHelp);
    pb::Session s;
    if (grpc::Status st = CreateSession(server, *device, *protocol, *gravity, &s); !st.ok())
      return RpcError(server, st);
    if (as_json) return std::printf("%s\n", ProtoJson(s).c_str()), kExitOk;
    std::printf("session %s opened for %s (protocol %s)\n", s.id().c_str(), s.device_id().c_str(),
                ProtocolName(s.protocol()).c_str());
    return kExitOk;
  }
  if (pos[0] == "list" && pos.size() == 1) {
    pb::ListSessionsResponse all;
    pb::ListSessionsRequest req;
    req.set_device_id(a->Get("device").value_or(""));
    if (auto st = a->Get("state")) {
      auto state = ParseState(*st);
      if (!state.ok()) return UsageError(std::string(state.status().message()), kSessionHelp);
      req.set_state(*state);
    }
    req.set_page_size(1000);
    do {
      pb::ListSessionsResponse page;
      auto ctx = CallContext();
      if (grpc::Status st = server.sessions->ListSessions(ctx.get(), req, &page); !st.ok())
        return RpcError(server, st);
      for (auto& s : *page.mutable_sessions()) *all.add_sessions() = std::move(s);
      req.set_page_token(page.next_page_token());
    } while (!req.page_token().empty());
    if (as_json) return std::printf("%s\n", ProtoJson(all).c_str()), kExitOk;
    if (all.sessions().empty()) std::printf("no sessions\n");
    for (const auto& s : all.sessions()) PrintSession(s);
    return kExitOk;
  }
  if (pos[0] == "poses" && pos.size() == 2) {
    pb::ListPosesResponse poses;
    if (grpc::Status st = ListPoses(server, pos[1], &poses); !st.ok()) return RpcError(server, st);
    if (as_json) return std::printf("%s\n", ProtoJson(poses).c_str()), kExitOk;
    if (poses.poses().empty()) std::printf("no poses yet\n");
    PrintPoses(poses);
    return kExitOk;
  }
  if ((pos[0] == "show" || pos[0] == "cancel") && pos.size() == 2) {
    pb::Session s;
    grpc::Status st;
    if (pos[0] == "show") {
      st = GetSession(server, pos[1], &s);
    } else {
      pb::CancelSessionRequest req;
      req.set_session_id(pos[1]);
      st = server.sessions->CancelSession(CallContext().get(), req, &s);
    }
    if (!st.ok()) return RpcError(server, st);
    if (as_json) return std::printf("%s\n", ProtoJson(s).c_str()), kExitOk;
    if (pos[0] == "cancel") std::printf("cancelled session %s\n", s.id().c_str());
    PrintSession(s);
    if (pos[0] == "show") {
      pb::ListPosesResponse poses;
      if (grpc::Status ps = ListPoses(server, pos[1], &poses); !ps.ok())
        return RpcError(server, ps);
      PrintPoses(poses);
    }
    return kExitOk;
  }
  return UsageError(absl::StrCat("session: unexpected '", absl::StrJoin(pos, " "), "'"),
                    kSessionHelp);
}

// ------------------------------------------------------------------------------------------
// solve (shared with upload --solve)

namespace {

constexpr char kSolveHelp[] =
    "usage: imucal solve --session S [--wait] [--force] [--seed N] [--timeout SECONDS] [--json]\n"
    "  Starts a solve job for the session's samples. With --wait, waits for the result and\n"
    "  prints the version created, its verdict and whether it became active. A session whose\n"
    "  robot is still uploading (a sample stream open) is not solved: the server says so.\n"
    "options:\n"
    "  --force            solve even while a stream is open: the upload is ended and the rest\n"
    "                     of its capture is not stored\n";

// Starts a solve and, if `wait`, polls the job until it finishes (at most timeout_s).
int SolveAndMaybeWait(const Server& server, const std::string& session, uint64_t seed, bool wait,
                      double timeout_s, bool as_json, bool force = false) {
  pb::SolveSessionRequest req;
  req.set_session_id(session);
  req.set_seed(seed);
  req.set_force(force);
  pb::SolveJob job;
  {
    auto ctx = CallContext();
    grpc::Status s = server.sessions->SolveSession(ctx.get(), req, &job);
    // Already solving (this command ran before, and lost its server or was stopped): with
    // --wait, follow the running job rather than fail.
    pb::Session now;
    if (!s.ok() && s.error_code() == grpc::StatusCode::FAILED_PRECONDITION && wait) {
      pb::GetSessionRequest get;
      get.set_session_id(session);
      auto again = CallContext();
      if (server.sessions->GetSession(again.get(), get, &now).ok() &&
          now.state() == pb::SESSION_STATE_SOLVING && !now.solve_job_id().empty()) {
        std::fprintf(stderr, "imucal: session %s is already being solved: waiting for job %s\n",
                     session.c_str(), now.solve_job_id().c_str());
        job.set_id(now.solve_job_id());
        job.set_session_id(session);
        job.set_state(pb::JOB_STATE_RUNNING);
        s = grpc::Status::OK;
      }
    }
    if (!s.ok()) return RpcError(server, s);
  }
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::milliseconds(int64_t(timeout_s * 1000));
  // A poll with a growing interval: solves take from a fraction of a second to minutes.
  auto interval = std::chrono::milliseconds(50);
  bool lost_server = false;
  while (wait && (job.state() == pb::JOB_STATE_QUEUED || job.state() == pb::JOB_STATE_RUNNING ||
                  job.state() == pb::JOB_STATE_UNSPECIFIED)) {
    if (std::chrono::steady_clock::now() > deadline) {
      std::fprintf(stderr, "imucal: solve job %s still %s after %.0f s\n", job.id().c_str(),
                   JobStateName(job.state()).c_str(), timeout_s);
      return kExitUnavailable;
    }
    std::this_thread::sleep_for(interval);
    interval = std::min(interval * 2, std::chrono::milliseconds(1000));
    pb::GetSolveJobRequest get;
    get.set_job_id(job.id());
    auto ctx = CallContext();
    ctx->set_wait_for_ready(true);  // through a restart, or on to another replica
    pb::SolveJob now;
    if (grpc::Status s = server.sessions->GetSolveJob(ctx.get(), get, &now); !s.ok()) {
      // The server that runs the job stopped: the job lives on in storage, and another replica
      // (or the same one, restarted) runs it again (README "Scaling out"). Ask until the
      // timeout.
      if (s.error_code() != grpc::StatusCode::UNAVAILABLE &&
          s.error_code() != grpc::StatusCode::DEADLINE_EXCEEDED)
        return RpcError(server, s);
      if (!lost_server) {
        std::fprintf(stderr, "imucal: lost %s (%s); still waiting for job %s\n",
                     server.address.c_str(), s.error_message().c_str(), job.id().c_str());
        lost_server = true;
      }
      continue;
    }
    job = std::move(now);
  }
  if (as_json) {
    std::printf("%s\n", ProtoJson(job).c_str());
  } else if (!wait) {
    std::printf("solve job %s %s for session %s\n", job.id().c_str(),
                JobStateName(job.state()).c_str(), session.c_str());
  } else if (job.state() == pb::JOB_STATE_DONE) {
    std::printf("solved session %s: version %d, verdict %s, %s\n", session.c_str(), job.version(),
                job.verdict().c_str(),
                job.activated() ? "now active" : "candidate (not activated: see the report)");
  } else {
    std::printf("solve of session %s failed: %s\n", session.c_str(), job.error().c_str());
  }
  if (!wait) return kExitOk;
  if (job.state() == pb::JOB_STATE_FAILED) return kExitUndetermined;
  return ExitForVerdict(job.verdict());
}

}  // namespace

int RunSolve(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("solve", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kSolveHelp);
  if (a->Has("help")) return std::printf("%s%s", kSolveHelp, kServerFlagHelp), kExitOk;
  auto session = a->Get("session");
  if (!session || !a->positional().empty())
    return UsageError("solve needs --session S", kSolveHelp);
  auto seed = a->GetInt("seed", 0);
  auto timeout = a->GetDouble("timeout", 600);
  if (!seed.ok() || !timeout.ok())
    return UsageError("--seed and --timeout take numbers", kSolveHelp);
  Server server = Connect(*a);
  return SolveAndMaybeWait(server, *session, static_cast<uint64_t>(*seed), a->Has("wait"), *timeout,
                           a->Has("json"), a->Has("force"));
}

// ------------------------------------------------------------------------------------------
// upload

namespace {

constexpr char kUploadHelp[] =
    "usage: imucal upload FILE... --device D [--session S] [--solve] [options]\n"
    "  Streams a capture's raw samples to a session: the given one; else the device's open\n"
    "  session while it holds no samples (the one `guide --device D` opened); else a new one.\n"
    "  Resumes after the last acknowledged batch when the connection drops or the server\n"
    "  restarts (it retries until nothing was acknowledged for 5 minutes), and when run again\n"
    "  for the same session and file; a session holding another capture's start is refused,\n"
    "  naming both. FILE: imucal CSV or an imu_tk pair. With a robot's token: into its own\n"
    "  device's session the guide opened (a robot may not open one, nor --solve).\n"
    "options:\n"
    "  --protocol six-face|positions|free|ferraris|auto   for a new session (default auto)\n"
    "  --format F   --accel-unit U   --gyro-unit U   input as for calibrate (and below)\n"
    "  --batch N          samples per batch (default 2000)\n"
    "  --pace X           send at X times the capture's real-time rate (its t_s), as a robot\n"
    "                     streams while it captures (default: as fast as the server takes it)\n"
    "  --solve            solve when the upload is complete and wait for the verdict\n"
    "  --seed N           with --solve: the solve's BSAS seed (default 0)\n"
    "  --timeout SECONDS  with --solve: how long to wait for the verdict (default 600)\n"
    "  --json             print the session (and solve job) as JSON\n";

// Draws "[#####.....]  42%  12000/28000 samples" on stderr, over itself.
class ProgressBar {
 public:
  explicit ProgressBar(bool enabled) : enabled_(enabled) {}
  void Update(int64_t done, int64_t total) {
    if (!enabled_ || total <= 0) return;
    const int width = 30;
    const int filled = static_cast<int>(width * done / total);
    const int percent = static_cast<int>(100 * done / total);
    if (percent == last_percent_) return;
    last_percent_ = percent;
    std::fprintf(stderr, "\r[%s%s] %3d%%  %lld/%lld samples", std::string(filled, '#').c_str(),
                 std::string(width - filled, '.').c_str(), percent, static_cast<long long>(done),
                 static_cast<long long>(total));
    std::fflush(stderr);
  }
  void Finish() {
    if (enabled_ && last_percent_ >= 0) std::fputs("\n", stderr);
  }

 private:
  bool enabled_;
  int last_percent_ = -1;
};

// The capture's name for the session (SampleBatch.source): its file names without their
// directories, which are the technician's business, not the server's.
std::string CaptureName(const std::vector<std::string>& files) {
  std::vector<std::string> names;
  for (const std::string& f : files) names.push_back(std::filesystem::path(f).filename().string());
  return absl::StrJoin(names, "+");
}

absl::StatusOr<importers::ImportOptions> UploadImportOptions(const Args& a) {
  importers::ImportOptions o;
  if (auto f = a.Get("format")) o.format = *f;
  if (auto u = a.Get("accel-unit")) {
    auto p = core::ParseAccelUnit(*u);
    if (!p.ok())
      return absl::InvalidArgumentError(absl::StrCat("--accel-unit: ", p.status().message()));
    o.accel_unit = *p;
  }
  if (auto u = a.Get("gyro-unit")) {
    auto p = core::ParseGyroUnit(*u);
    if (!p.ok())
      return absl::InvalidArgumentError(absl::StrCat("--gyro-unit: ", p.status().message()));
    o.gyro_unit = *p;
  }
  if (absl::Status s = ApplyImportFlags(a, &o); !s.ok()) return s;
  return o;
}

}  // namespace

int RunUpload(const std::vector<std::string>& argv) {
  auto a =
      ParseCommandFlags("upload", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kUploadHelp);
  if (a->Has("help"))
    return std::printf("%s%s%s", kUploadHelp, kImportFlagsHelp, kServerFlagHelp), kExitOk;
  if (a->positional().empty()) return UsageError("upload needs a capture FILE", kUploadHelp);
  auto device = a->Get("device");
  auto session_id = a->Get("session");
  if (!device && !session_id) return UsageError("upload needs --device or --session", kUploadHelp);
  auto batch = a->GetInt("batch", 2000);
  if (!batch.ok() || *batch < 1 || *batch > 20000)
    return UsageError("--batch: expected 1..20000 samples (the server's limit per batch)",
                      kUploadHelp);
  auto pace = a->GetDouble("pace", 0);
  if (!pace.ok() || !(*pace >= 0) || !std::isfinite(*pace))
    return UsageError("--pace: expected a positive number (times real time)", kUploadHelp);
  auto io = UploadImportOptions(*a);
  if (!io.ok()) return UsageError(std::string(io.status().message()), kUploadHelp);
  auto capture = importers::ImportCapture(a->positional(), *io);
  if (!capture.ok()) return ReportError(capture.status());
  if (!capture->has_gyro) {
    std::fprintf(stderr, "imucal: %s: %s\n", a->positional().front().c_str(),
                 sdk::kNoGyroUploadMessage);
    return kExitBadInput;
  }

  Server server = Connect(*a);
  pb::Session session;
  if (session_id) {
    if (grpc::Status s = GetSession(server, *session_id, &session); !s.ok())
      return RpcError(server, s);
    if (device && session.device_id() != *device) {
      std::fprintf(stderr, "imucal: session %s belongs to %s, not %s\n", session_id->c_str(),
                   session.device_id().c_str(), device->c_str());
      return kExitBadInput;
    }
  }
  const std::string device_id = device ? *device : session.device_id();
  // The server keeps samples in the device's registered units: refuse a capture in others.
  {
    pb::GetDeviceRequest req;
    req.set_device_id(device_id);
    pb::Device d;
    auto ctx = CallContext();
    if (grpc::Status s = server.devices->GetDevice(ctx.get(), req, &d); !s.ok())
      return RpcError(server, s);
    const std::string accel(core::AccelUnitName(capture->accel_unit));
    const std::string gyro(core::GyroUnitName(capture->gyro_unit));
    if (d.accel_unit() != accel || d.gyro_unit() != gyro) {
      std::fprintf(stderr,
                   "imucal: the capture is in accel %s, gyro %s but %s is registered with accel "
                   "%s, gyro %s (use --accel-unit/--gyro-unit if the file's units are wrong)\n",
                   accel.c_str(), gyro.c_str(), device_id.c_str(), d.accel_unit().c_str(),
                   d.gyro_unit().c_str());
      return kExitBadInput;
    }
  }
  if (!session_id) {
    // The device's open session, when there is one: the guide opened it for this capture. Only
    // an empty one is joined: the uploader resumes by batch number, so a session that already
    // holds another capture's batches would silently skip this capture's first ones.
    pb::ListSessionsRequest req;
    req.set_device_id(device_id);
    req.set_state(pb::SESSION_STATE_OPEN);
    pb::ListSessionsResponse open;
    auto ctx = CallContext();
    if (grpc::Status s = server.sessions->ListSessions(ctx.get(), req, &open); !s.ok())
      return RpcError(server, s);
    if (!open.sessions().empty()) {
      const pb::Session& found = open.sessions(0);
      if (found.samples() > 0) {
        std::fprintf(stderr,
                     "imucal: %s already has an open session %s holding %lld samples: to resume "
                     "that capture run again with --session %s; to start over, cancel it "
                     "(imucal session cancel %s)\n",
                     device_id.c_str(), found.id().c_str(), static_cast<long long>(found.samples()),
                     found.id().c_str(), found.id().c_str());
        return kExitUndetermined;  // as the server's FAILED_PRECONDITION for it
      }
      session = found;
      session_id = found.id();
      if (!a->Has("json"))
        std::printf("streaming into %s's open session %s\n", device_id.c_str(), found.id().c_str());
    }
  }
  if (!session_id) {
    auto protocol = ParseProtocol(a->Get("protocol").value_or("auto"));
    if (!protocol.ok()) return UsageError(std::string(protocol.status().message()), kUploadHelp);
    if (grpc::Status s =
            CreateSession(server, device_id, *protocol, capture->gravity_m_s2, &session);
        !s.ok()) {
      const int code = RpcError(server, s);
      // A robot's token may join the session the guide opened, not open one.
      if (s.error_code() == grpc::StatusCode::PERMISSION_DENIED) {
        std::fprintf(stderr,
                     "imucal: %s has no open session to stream into, and this token may not "
                     "open one: a technician opens it (imucal guide --device %s, or imucal "
                     "session start --device %s), then run this again\n",
                     device_id.c_str(), device_id.c_str(), device_id.c_str());
      }
      return code;
    }
    if (!a->Has("json"))
      std::printf("session %s opened for %s\n", session.id().c_str(), device_id.c_str());
  }

  ProgressBar bar(::isatty(STDERR_FILENO) == 1);
  // The SDK's Uploader with its retry policy (client/sdk/uploader.h): a server restart is
  // ridden out, the same way a robot's upload rides it out.
  sdk::UploadOptions options;
  options.batch_samples = static_cast<int>(*batch);
  options.source = CaptureName(a->positional());
  options.pace = *pace;
  options.progress = [&bar](int64_t done, int64_t total) { bar.Update(done, total); };
  sdk::Uploader uploader(server.channel, options);
  absl::StatusOr<sdk::UploadResult> result = uploader.Upload(session.id(), *capture);
  bar.Finish();
  if (!result.ok()) {
    const int code = RpcError(server, result.status());
    // A refusal (another capture's session, a closed one) is not cured by running it again.
    if (!absl::IsFailedPrecondition(result.status()) && !absl::IsInvalidArgument(result.status()))
      std::fprintf(stderr, "imucal: run the same command with --session %s to resume\n",
                   session.id().c_str());
    return code;
  }
  if (!a->Has("json")) {
    std::printf("uploaded %lld samples to session %s", static_cast<long long>(result->sent_samples),
                session.id().c_str());
    if (result->skipped_samples > 0)
      std::printf(" (resumed: %lld were already stored)",
                  static_cast<long long>(result->skipped_samples));
    if (result->reconnects > 0) std::printf(" after %d reconnects", result->reconnects);
    std::printf("\n");
  }
  if (!a->Has("solve")) {
    if (a->Has("json")) {
      if (grpc::Status s = GetSession(server, session.id(), &session); !s.ok())
        return RpcError(server, s);
      std::printf("%s\n", ProtoJson(session).c_str());
    }
    return kExitOk;
  }
  auto seed = a->GetInt("seed", 0);
  auto timeout = a->GetDouble("timeout", 600);
  if (!seed.ok() || !timeout.ok())
    return UsageError("--seed and --timeout take numbers", kUploadHelp);
  return SolveAndMaybeWait(server, session.id(), static_cast<uint64_t>(*seed), true, *timeout,
                           a->Has("json"));
}

// ------------------------------------------------------------------------------------------
// report

namespace {

constexpr char kReportHelp[] =
    "usage: imucal report --session S [--json] [--out DIR]\n"
    "  The report of the session's latest solve: a summary, or with --json the\n"
    "  \"imucal-report v1\" document exactly as the server stores it.\n"
    "options:\n"
    "  --out DIR     also write report.json, summary.txt and SVG plots into DIR (residual per\n"
    "                pose after each stage, pose coverage on the sphere, Allan deviation, each\n"
    "                effect against its regressor)\n";

std::string Vec(const json& v, const char* fmt = "%+.5f") {
  if (!v.is_array()) return "-";
  std::vector<std::string> parts;
  for (const auto& x : v)
    parts.push_back(x.is_number() ? absl::StrFormat(fmt, x.get<double>()) : std::string("null"));
  return absl::StrCat("[", absl::StrJoin(parts, ", "), "]");
}

double Num(const json& j, const char* key) {
  return j.contains(key) && j[key].is_number() ? j[key].get<double>() : std::nan("");
}

std::string Str(const json& j, const char* key) {
  return j.contains(key) && j[key].is_string() ? j[key].get<std::string>() : "";
}

// The server report as text: what `report` prints and `report --out DIR` keeps as summary.txt.
std::string FormatReportSummary(const json& r) {
  std::string out;
  absl::StrAppendFormat(&out, "device      %s   session %s\n", Str(r, "device").c_str(),
                        Str(r, "session").c_str());
  int used = 0, total = 0;
  if (r.contains("poses")) {
    for (const auto& p : r["poses"]) {
      ++total;
      used += p.value("used", false);
    }
  }
  absl::StrAppendFormat(&out, "poses       %d found, %d used\n", total, used);
  if (r.contains("poses")) {
    for (const auto& p : r["poses"]) {
      if (!p.value("used", true))
        absl::StrAppendFormat(&out, "  pose %-3d  not used: %s\n", p.value("index", -1),
                              Str(p, "reason").c_str());
    }
  }
  if (r.contains("pairs")) {
    for (const auto& p : r["pairs"]) {
      absl::StrAppendFormat(&out, "  pair %-9s %-4s rotation %.1f deg, tilt %.1f deg  %s\n",
                            p.contains("poses") ? p["poses"].dump().c_str() : "?",
                            Str(p, "status").c_str(), Num(p, "rotation_deg"), Num(p, "tilt_deg"),
                            Str(p, "reason").c_str());
    }
  }
  if (r.contains("stages")) {
    for (const auto& s : r["stages"])
      absl::StrAppendFormat(&out, "stage       %-5s accel rms %.5f m/s^2 (%d iterations)\n",
                            Str(s, "name").c_str(), Num(s, "accel_rms"), s.value("iterations", 0));
  }
  if (r.contains("residual")) {
    const json& res = r["residual"];
    absl::StrAppendFormat(
        &out, "residual    accel rms %.5f m/s^2, max %.5f m/s^2, gyro static rms %.6f rad/s\n",
        Num(res, "accel_rms"), Num(res, "accel_max"), Num(res, "gyro_static_rms"));
  }
  if (r.contains("parameters") && r["parameters"].is_object()) {
    // The Allan figures of the parameter set's noise block, read back with the SDK's reader and
    // printed as `calibrate`'s summary prints them.
    absl::StatusOr<core::ParamSet> params = formats::ParamSetFromJson(r["parameters"].dump());
    if (params.ok()) {
      out += FormatAllanFigures(params->noise, params->has_gyro);
    } else {
      absl::StrAppendFormat(&out, "allan       not shown: %s\n", params.status().message());
    }
    const json& p = r["parameters"];
    if (p.contains("accel")) {
      absl::StrAppendFormat(&out, "accel bias  %s\n", Vec(p["accel"]["bias"]).c_str());
      absl::StrAppendFormat(&out, "accel scale %s\n", Vec(p["accel"]["scale"]).c_str());
    }
    if (p.contains("gyro"))
      absl::StrAppendFormat(&out, "gyro bias   %s\n", Vec(p["gyro"]["bias"], "%+.6f").c_str());
  }
  if (r.contains("effects")) {
    for (const auto& e : r["effects"]) {
      // A rate term has no static figure (null): its held-out figures are the moves'.
      const double before = Num(e, "error_before"), after = Num(e, "error_after");
      const std::string held =
          std::isnan(before)
              ? std::string("held out on the moves: see effect_diagnostics.move_search")
              : absl::StrFormat("held-out rms %.3g -> %.3g", before, after);
      absl::StrAppendFormat(&out, "effect      %s %s ~ %s: %.3g (%s; %s)\n",
                            Str(e, "sensor").c_str(), Str(e, "axis").c_str(),
                            Str(e, "regressor").c_str(), Num(e, "coefficient"),
                            Str(e, "human").c_str(), held);
    }
  }
  if (r.contains("warnings")) {
    for (const auto& w : r["warnings"])
      absl::StrAppendFormat(&out, "warning     %s\n",
                            w.is_string() ? w.get<std::string>().c_str() : w.dump().c_str());
  }
  absl::StrAppendFormat(&out, "verdict     %s\n", Str(r, "verdict").c_str());
  return out;
}

}  // namespace

int RunReport(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("report", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kReportHelp);
  if (a->Has("help")) return std::printf("%s%s", kReportHelp, kServerFlagHelp), kExitOk;
  auto session = a->Get("session");
  if (!session) return UsageError("report needs --session S", kReportHelp);
  Server server = Connect(*a);
  pb::GetReportRequest req;
  req.set_session_id(*session);
  pb::Report report;
  auto ctx = CallContext();
  if (grpc::Status s = server.sessions->GetReport(ctx.get(), req, &report); !s.ok())
    return RpcError(server, s);
  json r = json::parse(report.json(), nullptr, /*allow_exceptions=*/false);
  if (r.is_discarded() || !r.is_object()) {
    std::fprintf(stderr, "imucal: the server's report is not valid JSON\n");
    return kExitInternal;
  }
  const std::string summary = FormatReportSummary(r);
  if (a->Has("json")) {
    std::fputs(report.json().c_str(), stdout);
    if (!report.json().empty() && report.json().back() != '\n') std::fputs("\n", stdout);
  } else {
    std::fputs(summary.c_str(), stdout);
  }
  if (auto dir = a->Get("out")) {
    // The report, its summary and its plots, as the offline `calibrate --out DIR` writes them.
    auto written = formats::WriteReportBundle(r, report.json(), summary, *dir);
    if (!written.ok()) return ReportError(written.status());
    for (const auto& p : *written) std::fprintf(stderr, "imucal: wrote %s\n", p.c_str());
  }
  return ExitForVerdict(Str(r, "verdict"));
}

// ------------------------------------------------------------------------------------------
// params

namespace {

constexpr char kParamsHelp[] =
    "usage: imucal params get --device D [--version N] [--json]\n"
    "       imucal params list --device D [--json]\n"
    "       imucal params promote --device D --version N [--reason TEXT]\n"
    "       imucal params rollback --device D --to N [--reason TEXT]\n"
    "  Shows a parameter version (default the active one; --json prints the \"imucal-params v1\"\n"
    "  document exactly as stored), lists the versions, makes a version active, or makes an\n"
    "  earlier version active again.\n"
    "options:\n";

void PrintParamHeader(const pb::ParameterSet& p) {
  std::printf("v%-4d %-10s %-5s accel rms %.5f m/s^2  %s  session %s\n", p.version(),
              VersionStateName(p.state()).c_str(), p.verdict().c_str(), p.accel_rms_m_s2(),
              TimeText(p.created_at()).c_str(), p.session_id().c_str());
}

}  // namespace

int RunParams(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("params", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kParamsHelp);
  if (a->Has("help")) return std::printf("%s%s", kParamsHelp, kServerFlagHelp), kExitOk;
  const auto& pos = a->positional();
  auto device = a->Get("device");
  if (pos.size() != 1)
    return UsageError("params needs get, list, promote or rollback", kParamsHelp);
  if (!device) return UsageError("params needs --device D", kParamsHelp);
  auto version = a->GetInt("version", 0);
  auto to = a->GetInt("to", 0);
  if (!version.ok() || !to.ok()) return UsageError("--version and --to take numbers", kParamsHelp);
  Server server = Connect(*a);
  const bool as_json = a->Has("json");
  const std::string& verb = pos[0];
  pb::ParameterSet p;
  auto ctx = CallContext();
  grpc::Status s;
  if (verb == "get") {
    if (*version > 0) {
      pb::GetParametersRequest req;
      req.set_device_id(*device);
      req.set_version(static_cast<int32_t>(*version));
      s = server.params->GetParameters(ctx.get(), req, &p);
    } else {
      pb::GetActiveParametersRequest req;
      req.set_device_id(*device);
      s = server.params->GetActiveParameters(ctx.get(), req, &p);
    }
    if (!s.ok()) return RpcError(server, s);
    if (as_json) {
      std::fputs(p.json().c_str(), stdout);
      if (!p.json().empty() && p.json().back() != '\n') std::fputs("\n", stdout);
      return kExitOk;
    }
    std::printf("device      %s\n", p.device_id().c_str());
    std::printf("version     ");
    PrintParamHeader(p);
    json j = json::parse(p.json(), nullptr, false);
    if (j.is_object()) {
      if (j.contains("accel")) {
        std::printf("accel unit  %s\n", Str(j["accel"], "input_unit").c_str());
        std::printf("accel bias  %s\n", Vec(j["accel"]["bias"]).c_str());
        std::printf("accel scale %s\n", Vec(j["accel"]["scale"]).c_str());
      }
      if (j.contains("gyro")) {
        std::printf("gyro unit   %s\n", Str(j["gyro"], "input_unit").c_str());
        std::printf("gyro bias   %s\n", Vec(j["gyro"]["bias"], "%+.6f").c_str());
      }
      if (j.contains("effects")) std::printf("effects     %zu\n", j["effects"].size());
    }
    std::printf("crc32c      %08x\n", p.crc32c());
    return kExitOk;
  }
  if (verb == "list") {
    pb::ListVersionsResponse all;
    pb::ListVersionsRequest req;
    req.set_device_id(*device);
    req.set_page_size(1000);
    do {
      pb::ListVersionsResponse page;
      auto page_ctx = CallContext();
      if (s = server.params->ListVersions(page_ctx.get(), req, &page); !s.ok())
        return RpcError(server, s);
      for (auto& v : *page.mutable_versions()) *all.add_versions() = std::move(v);
      req.set_page_token(page.next_page_token());
    } while (!req.page_token().empty());
    if (as_json) return std::printf("%s\n", ProtoJson(all).c_str()), kExitOk;
    if (all.versions().empty()) std::printf("%s has no parameter versions\n", device->c_str());
    for (const auto& v : all.versions()) PrintParamHeader(v);
    return kExitOk;
  }
  if (verb == "promote") {
    if (*version <= 0) return UsageError("params promote needs --version N", kParamsHelp);
    pb::PromoteRequest req;
    req.set_device_id(*device);
    req.set_version(static_cast<int32_t>(*version));
    req.set_reason(a->Get("reason").value_or(""));
    s = server.params->Promote(ctx.get(), req, &p);
  } else if (verb == "rollback") {
    if (*to <= 0) return UsageError("params rollback needs --to N", kParamsHelp);
    pb::RollbackRequest req;
    req.set_device_id(*device);
    req.set_to_version(static_cast<int32_t>(*to));
    req.set_reason(a->Get("reason").value_or(""));
    s = server.params->Rollback(ctx.get(), req, &p);
  } else {
    return UsageError(absl::StrCat("params: unknown action '", verb, "'"), kParamsHelp);
  }
  if (!s.ok()) return RpcError(server, s);
  p.clear_json();
  if (as_json) return std::printf("%s\n", ProtoJson(p).c_str()), kExitOk;
  std::printf("%s v%d is now active\n", p.device_id().c_str(), p.version());
  return kExitOk;
}

// ------------------------------------------------------------------------------------------
// export

namespace {

constexpr char kExportHelp[] =
    "usage: imucal export --device D [--version N]\n"
    "                     --format json|kalibr|kalibr-intrinsics|openvins [--out FILE]\n"
    "  A stored parameter version (default the active one) in another tool's format (see\n"
    "  `imucal export --params FILE --help` for the formats). What the format cannot hold\n"
    "  (biases, second-order terms, effects) is listed on stderr.\n"
    "options:\n"
    "  --out FILE              write FILE (default: standard output)\n";

}  // namespace

int RunExport(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("export-server", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kExportHelp);
  if (a->Has("help"))
    return std::printf("%s%s%s", kExportHelp, kExportOptionsHelp, kServerFlagHelp), kExitOk;
  auto device = a->Get("device");
  auto format = a->Get("format");
  auto version = a->GetInt("version", 0);
  if (!device || !format) return UsageError("export needs --device and --format", kExportHelp);
  if (*format != "json" && !core::ParseExportFormat(*format).ok())
    return UsageError("--format: expected json, kalibr, kalibr-intrinsics or openvins",
                      kExportHelp);
  if (!version.ok()) return UsageError(std::string(version.status().message()), kExportHelp);
  auto options = ExportOptionsFrom(*a);
  if (!options.ok()) return UsageError(std::string(options.status().message()), kExportHelp);
  Server server = Connect(*a);
  pb::ExportRequest req;
  req.set_device_id(*device);
  req.set_version(static_cast<int32_t>(*version));
  req.set_format(*format);
  auto given = [](double v) { return std::isfinite(v) ? v : 0.0; };  // 0: not given
  if (a->Get("rostopic")) req.set_rostopic(options->rostopic);
  req.set_update_rate_hz(given(options->update_rate_hz));
  if (auto m = a->Get("openvins-model")) req.set_openvins_model(*m);
  req.set_accel_noise_density(given(options->accel_noise_density));
  req.set_accel_random_walk(given(options->accel_random_walk));
  req.set_gyro_noise_density(given(options->gyro_noise_density));
  req.set_gyro_random_walk(given(options->gyro_random_walk));
  pb::ExportResponse out;
  auto ctx = CallContext();
  if (grpc::Status s = server.params->Export(ctx.get(), req, &out); !s.ok())
    return RpcError(server, s);
  for (const auto& note : out.notes()) std::fprintf(stderr, "imucal: note: %s\n", note.c_str());
  if (auto path = a->Get("out")) {
    if (absl::Status s = WriteFileDurably(*path, out.content()); !s.ok()) return ReportError(s);
    std::fprintf(stderr, "wrote %s\n", path->c_str());
    return kExitOk;
  }
  std::fputs(out.content().c_str(), stdout);
  return kExitOk;
}

}  // namespace imucal::cli
