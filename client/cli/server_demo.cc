// `imucal demo --server ADDR`: the README's main job through the service. A simulated robot
// streams a six-face calibration capture through the SDK's uploader while `guide` shows the
// technician's view; the guide starts the solve when the protocol is complete; the robot then
// fetches its active parameters through the SDK and applies them; the error before and after is
// printed.
#include <cstdio>
#include <thread>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "client/cli/args.h"
#include "client/cli/botch.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "client/cli/demo_common.h"
#include "client/cli/server_common.h"
#include "client/sdk/client.h"
#include "client/sdk/uploader.h"

namespace imucal::cli {
namespace pb = ::imucal::v1;

namespace {

constexpr char kServerDemoHelp[] =
    "usage: imucal demo --server ADDR [--seed N] [--device ID] [--botch-turn]\n"
    "                   [--robot-token-file F]\n"
    "  --robot-token-file  the robot's own token (bound to --device): the robot registers,\n"
    "                streams and fetches with it, the technician (--token-file) does the\n"
    "                rest; without it both use the one connection\n"
    "  --botch-turn  the robot's first 180-degree turn stops a quarter turn short and is\n"
    "                finished after a hold: the guide shows the failed pair and its re-do\n";

// The robot's connection settings: its own token when it has one (README "Security"), over the
// same TLS settings as the technician's. InvalidArgument with the usage message.
absl::StatusOr<sdk::ClientOptions> RobotClientOptions(const Args& a) {
  sdk::ClientOptions robot_options = ConnectionOptions();
  if (auto file = a.Get("robot-token-file")) {
    absl::StatusOr<std::string> token = sdk::ReadTokenFile(*file);
    if (!token.ok()) return absl::InvalidArgumentError(token.status().message());
    robot_options.bearer_token = *std::move(token);
    if (absl::Status s = sdk::ValidateClientOptions(robot_options); !s.ok())
      return absl::InvalidArgumentError(absl::StrCat("--robot-token-file: ", s.message()));
  }
  return robot_options;
}

// The robot registers its device, as the simulated capture describes it.
grpc::Status RegisterRobot(const Server& robot_server, const std::string& device,
                           const core::SimOptions& so, const core::Capture& capture) {
  pb::RegisterDeviceRequest reg;
  pb::Device* d = reg.mutable_device();
  d->set_id(device);
  d->set_sensor_model("simulated MEMS IMU");
  d->set_nominal_rate_hz(so.rate_hz);
  d->set_accel_unit(std::string(core::AccelUnitName(capture.accel_unit)));
  d->set_gyro_unit(std::string(core::GyroUnitName(capture.gyro_unit)));
  pb::Device registered;
  return robot_server.devices->RegisterDevice(CallContext().get(), reg, &registered);
}

// Step 2: the robot streams `capture` into the session on a thread of its own while the guide
// follows it and starts the solve. The guide's exit code, or the robot's error.
int StreamWhileGuiding(const Server& server, const Server& robot_server, const std::string& device,
                       const pb::Session& session, const core::Capture& capture) {
  absl::Status upload_status;
  std::thread robot([&] {
    sdk::UploadOptions options;
    options.batch_samples = 400;
    sdk::Uploader uploader(robot_server.channel, options);
    upload_status = uploader.Upload(session.id(), capture).status();
  });
  const int guide_rc = RunGuide(
      {"--server", server.address, "--device", device, "--session", session.id(), "--seed", "1"});
  robot.join();
  if (!upload_status.ok()) {
    // The guide starts the solve as soon as the protocol is complete; a robot still streaming
    // then finds its session closed and stops, as a real one does. Anything else is an error.
    pb::Session now;
    const bool closed =
        GetSession(server, session.id(), &now).ok() && now.state() != pb::SESSION_STATE_OPEN;
    if (!closed) return ReportError(upload_status);
    std::printf("   (the robot stopped streaming: its session closed for the solve)\n");
  }
  return guide_rc;
}

// A version that missed a quality gate with a warn verdict (e.g. six faces leave the
// second-order terms undetermined) stays a candidate: the technician reviews it and promotes
// it, as `imucal params promote` does. kExitOk, or the exit code.
int PromoteIfWarn(const Server& server, const std::string& device, const std::string& session_id) {
  pb::Session solved;
  if (grpc::Status s = GetSession(server, session_id, &solved); !s.ok()) return RpcError(server, s);
  pb::GetParametersRequest get;
  get.set_device_id(device);
  get.set_version(solved.version());
  pb::ParameterSet version;
  if (grpc::Status s = server.params->GetParameters(CallContext().get(), get, &version); !s.ok())
    return RpcError(server, s);
  if (version.state() != pb::VERSION_STATE_CANDIDATE ||
      VerdictOf(version.verdict_kind(), version.verdict()) != core::Verdict::kWarn)
    return kExitOk;
  std::printf("== 2b. verdict warn: the technician reviews the report and promotes version %d\n",
              version.version());
  pb::PromoteRequest promote;
  promote.set_device_id(device);
  promote.set_version(version.version());
  promote.set_reason("demo: warn verdict reviewed");
  if (grpc::Status s = server.params->Promote(CallContext().get(), promote, &version); !s.ok())
    return RpcError(server, s);
  return kExitOk;
}

}  // namespace

int RunServerDemo(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("demo-server", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), "");
  if (a->Has("help")) return std::printf("%s", kServerDemoHelp), kExitOk;
  auto seed = a->GetInt("seed", 7);
  if (!seed.ok()) return UsageError(std::string(seed.status().message()), "");
  const std::string device = a->Get("device").value_or(absl::StrCat("demo-robot-", *seed));
  Server server = Connect(*a);
  absl::StatusOr<sdk::ClientOptions> robot_options = RobotClientOptions(*a);
  if (!robot_options.ok()) return UsageError(std::string(robot_options.status().message()), "");
  Server robot_server = ConnectWith(server.address, *robot_options);

  // One extra pose after the six faces: the robot moves on, so the last face's pose closes.
  const core::SimOptions so = DemoCaptureOptions(static_cast<uint64_t>(*seed), 1);
  auto sim = core::Simulate(so);
  if (!sim.ok()) return ReportError(sim.status());
  if (a->Has("botch-turn")) {
    absl::StatusOr<core::Capture> botched = BotchFirstTurn(*sim, so.hold_s);
    if (!botched.ok()) return ReportError(botched.status());
    sim->capture = *std::move(botched);
  }

  std::printf("== 1. robot %s registers and a six-face session opens on %s\n", device.c_str(),
              server.address.c_str());
  if (grpc::Status s = RegisterRobot(robot_server, device, so, sim->capture); !s.ok())
    return RpcError(robot_server, s);
  pb::Session session;
  if (grpc::Status s = CreateSession(server, device, pb::PROTOCOL_SIX_FACE, 0.0, &session); !s.ok())
    return RpcError(server, s);

  std::printf("== 2. the robot streams its capture (%zu samples) while the guide follows\n",
              sim->capture.size());
  if (a->Has("botch-turn"))
    std::printf("   (the first half turn stops a quarter turn short, is held, then finished)\n");
  std::fflush(stdout);
  if (int code = StreamWhileGuiding(server, robot_server, device, session, sim->capture);
      code != kExitOk)
    return code;
  if (int code = PromoteIfWarn(server, device, session.id()); code != kExitOk) return code;

  std::printf("== 3. the robot fetches its active parameters through the SDK\n");
  sdk::ParamClient params(robot_server.channel);
  auto fetched = params.FetchActive(device, absl::Seconds(5));
  if (!fetched.ok()) return ReportError(fetched.status());
  std::printf("   version %d (crc32c checked)\n", fetched->params.version);
  std::printf("== 4. ");
  if (absl::Status s = PrintBeforeAfter(so, sim->truth, fetched->params); !s.ok())
    return ReportError(s);
  return kExitOk;
}
}  // namespace imucal::cli
