// `imucal upload`: stream a capture's raw samples into a session through the SDK's Uploader
// (resuming), and with --solve follow the solve to its verdict.
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "client/cli/args.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "client/cli/import_flags.h"
#include "client/cli/server_common.h"
#include "client/sdk/uploader.h"
#include "importers/registry.h"

namespace imucal::cli {

namespace pb = imucal::v1;

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

// The capture's import options: --format, the units, the importer flags (not calibrate's
// --gravity and --device: upload's --device is the server's).
absl::StatusOr<importers::ImportOptions> UploadImportOptions(const Args& a) {
  importers::ImportOptions o;
  if (absl::Status s = ApplyFormatAndUnitFlags(a, &o); !s.ok()) return s;
  if (absl::Status s = ApplyImportFlags(a, &o); !s.ok()) return s;
  return o;
}

// Upload's own flags, checked.
struct UploadFlags {
  int batch_samples = 2000;
  double pace = 0;  // times real time; 0: as fast as the server takes it
  importers::ImportOptions import;
};

// InvalidArgument with the usage message for a bad --batch, --pace or import flag.
absl::StatusOr<UploadFlags> ParseUploadFlags(const Args& a) {
  UploadFlags flags;
  auto batch = a.GetInt("batch", 2000);
  if (!batch.ok() || *batch < 1 || *batch > 20000)
    return absl::InvalidArgumentError(
        "--batch: expected 1..20000 samples (the server's limit per batch)");
  flags.batch_samples = static_cast<int>(*batch);
  auto pace = a.GetDouble("pace", 0);
  if (!pace.ok() || !(*pace >= 0) || !std::isfinite(*pace))
    return absl::InvalidArgumentError("--pace: expected a positive number (times real time)");
  flags.pace = *pace;
  auto io = UploadImportOptions(a);
  if (!io.ok()) return io.status();
  flags.import = *std::move(io);
  return flags;
}

// The server keeps samples in the device's registered units: a capture in others is refused
// (kExitBadInput, said on stderr). kExitOk when they match, else the exit code.
int CheckDeviceUnits(const Server& server, const std::string& device_id,
                     const core::Capture& capture) {
  pb::GetDeviceRequest req;
  req.set_device_id(device_id);
  pb::Device d;
  auto ctx = CallContext();
  if (grpc::Status s = server.devices->GetDevice(ctx.get(), req, &d); !s.ok())
    return RpcError(server, s);
  const std::string accel(core::AccelUnitName(capture.accel_unit));
  const std::string gyro(core::GyroUnitName(capture.gyro_unit));
  if (d.accel_unit() != accel || d.gyro_unit() != gyro) {
    std::fprintf(stderr,
                 "imucal: the capture is in accel %s, gyro %s but %s is registered with accel "
                 "%s, gyro %s (use --accel-unit/--gyro-unit if the file's units are wrong)\n",
                 accel.c_str(), gyro.c_str(), device_id.c_str(), d.accel_unit().c_str(),
                 d.gyro_unit().c_str());
    return kExitBadInput;
  }
  return kExitOk;
}

// The device's open session, when there is one: the guide opened it for this capture. Only an
// empty one is joined: the uploader resumes by batch number, so a session that already holds
// another capture's batches would silently skip this capture's first ones. Leaves `session`
// alone when the device has none open; kExitOk, or the exit code of a refusal.
int JoinOpenSession(const Server& server, const std::string& device_id, bool as_json,
                    pb::Session* session) {
  pb::ListSessionsRequest req;
  req.set_device_id(device_id);
  req.set_state(pb::SESSION_STATE_OPEN);
  pb::ListSessionsResponse open;
  auto ctx = CallContext();
  if (grpc::Status s = server.sessions->ListSessions(ctx.get(), req, &open); !s.ok())
    return RpcError(server, s);
  if (open.sessions().empty()) return kExitOk;
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
  *session = found;
  if (!as_json)
    std::printf("streaming into %s's open session %s\n", device_id.c_str(), found.id().c_str());
  return kExitOk;
}

// A new session for the device, in --protocol, at the capture's gravity. kExitOk, or the exit
// code (a robot's token, which may not open one, is told who can).
int OpenSession(const Args& a, const Server& server, const std::string& device_id,
                double gravity_m_s2, pb::Session* session) {
  auto protocol = ParseProtocol(a.Get("protocol").value_or("auto"));
  if (!protocol.ok()) return UsageError(std::string(protocol.status().message()), kUploadHelp);
  if (grpc::Status s = CreateSession(server, device_id, *protocol, gravity_m_s2, session);
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
  if (!a.Has("json"))
    std::printf("session %s opened for %s\n", session->id().c_str(), device_id.c_str());
  return kExitOk;
}

// The session to stream into: --session's (which must be --device's, when both are given);
// else the device's open session while it holds no samples; else a new one. The capture must
// be in the device's units. kExitOk, or the exit code.
int FindSession(const Args& a, const Server& server, const core::Capture& capture,
                pb::Session* session) {
  auto device = a.Get("device");
  auto session_id = a.Get("session");
  if (session_id) {
    if (grpc::Status s = GetSession(server, *session_id, session); !s.ok())
      return RpcError(server, s);
    if (device && session->device_id() != *device) {
      std::fprintf(stderr, "imucal: session %s belongs to %s, not %s\n", session_id->c_str(),
                   session->device_id().c_str(), device->c_str());
      return kExitBadInput;
    }
  }
  const std::string device_id = device ? *device : session->device_id();
  if (int code = CheckDeviceUnits(server, device_id, capture); code != kExitOk) return code;
  if (!session_id) {
    if (int code = JoinOpenSession(server, device_id, a.Has("json"), session); code != kExitOk)
      return code;
  }
  if (session->id().empty())
    return OpenSession(a, server, device_id, capture.gravity_m_s2, session);
  return kExitOk;
}

// Streams the capture through the SDK's Uploader with its retry policy (client/sdk/uploader.h):
// a server restart is ridden out, the same way a robot's upload rides it out. Prints what was
// uploaded (unless as_json); kExitOk, or the exit code.
int StreamCapture(const Server& server, const pb::Session& session, const core::Capture& capture,
                  const UploadFlags& flags, const std::vector<std::string>& files, bool as_json) {
  ProgressBar bar(::isatty(STDERR_FILENO) == 1);
  sdk::UploadOptions options;
  options.batch_samples = flags.batch_samples;
  options.source = CaptureName(files);
  options.pace = flags.pace;
  options.progress = [&bar](int64_t done, int64_t total) { bar.Update(done, total); };
  sdk::Uploader uploader(server.channel, options);
  absl::StatusOr<sdk::UploadResult> result = uploader.Upload(session.id(), capture);
  bar.Finish();
  if (!result.ok()) {
    const int code = RpcError(server, result.status());
    // A refusal (another capture's session, a closed one) is not cured by running it again.
    if (!absl::IsFailedPrecondition(result.status()) && !absl::IsInvalidArgument(result.status()))
      std::fprintf(stderr, "imucal: run the same command with --session %s to resume\n",
                   session.id().c_str());
    return code;
  }
  if (!as_json) {
    std::printf("uploaded %lld samples to session %s", static_cast<long long>(result->sent_samples),
                session.id().c_str());
    if (result->skipped_samples > 0)
      std::printf(" (resumed: %lld were already stored)",
                  static_cast<long long>(result->skipped_samples));
    if (result->reconnects > 0) std::printf(" after %d reconnects", result->reconnects);
    std::printf("\n");
  }
  return kExitOk;
}

// After the upload: with --solve, the solve and its verdict; else with --json the session.
int FinishUpload(const Args& a, const Server& server, pb::Session* session) {
  if (!a.Has("solve")) {
    if (a.Has("json")) {
      if (grpc::Status s = GetSession(server, session->id(), session); !s.ok())
        return RpcError(server, s);
      std::printf("%s\n", ProtoJson(*session).c_str());
    }
    return kExitOk;
  }
  auto seed = a.GetInt("seed", 0);
  auto timeout = a.GetDouble("timeout", 600);
  if (!seed.ok() || !timeout.ok())
    return UsageError("--seed and --timeout take numbers", kUploadHelp);
  return SolveAndMaybeWait(server, session->id(), static_cast<uint64_t>(*seed), true, *timeout,
                           a.Has("json"));
}

}  // namespace

int RunUpload(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("upload", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kUploadHelp);
  if (a->Has("help"))
    return std::printf("%s%s%s", kUploadHelp, kImportFlagsHelp, kServerFlagHelp), kExitOk;
  if (a->positional().empty()) return UsageError("upload needs a capture FILE", kUploadHelp);
  if (!a->Get("device") && !a->Get("session"))
    return UsageError("upload needs --device or --session", kUploadHelp);
  absl::StatusOr<UploadFlags> flags = ParseUploadFlags(*a);
  if (!flags.ok()) return UsageError(std::string(flags.status().message()), kUploadHelp);
  auto capture = importers::ImportCapture(a->positional(), flags->import);
  if (!capture.ok()) return ReportError(capture.status());
  if (!capture->has_gyro) {
    std::fprintf(stderr, "imucal: %s: %s\n", a->positional().front().c_str(),
                 sdk::kNoGyroUploadMessage);
    return kExitBadInput;
  }
  Server server = Connect(*a);
  pb::Session session;
  if (int code = FindSession(*a, server, *capture, &session); code != kExitOk) return code;
  if (int code = StreamCapture(server, session, *capture, *flags, a->positional(), a->Has("json"));
      code != kExitOk)
    return code;
  return FinishUpload(*a, server, &session);
}

}  // namespace imucal::cli
