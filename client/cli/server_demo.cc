// `imucal demo --server ADDR`: the README's main job through the service. A simulated robot
// streams a six-face calibration capture through the SDK's uploader while `guide` shows the
// technician's view; the guide starts the solve when the protocol is complete; the robot then
// fetches its active parameters through the SDK and applies them; the error before and after is
// printed.
#include <cstdio>
#include <thread>

#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "client/cli/args.h"
#include "client/cli/commands.h"
#include "client/cli/demo_common.h"
#include "client/cli/server_common.h"
#include "client/sdk/client.h"
#include "client/sdk/uploader.h"

namespace imucal::cli {
namespace pb = ::imucal::v1;

int RunServerDemo(const std::vector<std::string>& argv) {
  auto a = Args::Parse(argv, {"server", "seed", "device"}, {"help"});
  if (!a.ok()) return UsageError(std::string(a.status().message()), "");
  if (a->Has("help")) {
    std::printf("usage: imucal demo --server ADDR [--seed N] [--device ID]\n");
    return kExitOk;
  }
  auto seed = a->GetInt("seed", 7);
  if (!seed.ok()) return UsageError(std::string(seed.status().message()), "");
  const std::string device = a->Get("device").value_or(absl::StrCat("demo-robot-", *seed));
  Server server = Connect(*a);

  // One extra pose after the six faces: the robot moves on, so the last face's pose closes.
  const core::SimOptions so = DemoCaptureOptions(static_cast<uint64_t>(*seed), 1);
  auto sim = core::Simulate(so);
  if (!sim.ok()) return ReportError(sim.status());

  std::printf("== 1. robot %s registers and a six-face session opens on %s\n", device.c_str(),
              server.address.c_str());
  pb::RegisterDeviceRequest reg;
  pb::Device* d = reg.mutable_device();
  d->set_id(device);
  d->set_sensor_model("simulated MEMS IMU");
  d->set_nominal_rate_hz(so.rate_hz);
  d->set_accel_unit(std::string(core::AccelUnitName(sim->capture.accel_unit)));
  d->set_gyro_unit(std::string(core::GyroUnitName(sim->capture.gyro_unit)));
  pb::Device registered;
  if (grpc::Status s = server.devices->RegisterDevice(CallContext().get(), reg, &registered);
      !s.ok())
    return RpcError(server, s);
  pb::Session session;
  if (grpc::Status s = CreateSession(server, device, pb::PROTOCOL_SIX_FACE, 0.0, &session);
      !s.ok())
    return RpcError(server, s);

  std::printf("== 2. the robot streams its capture (%zu samples) while the guide follows\n",
              sim->capture.size());
  std::fflush(stdout);
  absl::Status upload_status;
  std::thread robot([&] {
    sdk::UploadOptions options;
    options.batch_samples = 400;
    sdk::Uploader uploader(server.channel, options);
    upload_status = uploader.Upload(session.id(), sim->capture).status();
  });
  const int guide_rc = RunGuide({"--server", server.address, "--device", device, "--session",
                                 session.id(), "--seed", "1"});
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
  if (guide_rc != kExitOk) return guide_rc;

  std::printf("== 3. the robot fetches its active parameters through the SDK\n");
  sdk::ParamClient params(server.channel);
  auto fetched = params.FetchActive(device, absl::Seconds(5));
  if (!fetched.ok()) return ReportError(fetched.status());
  std::printf("   version %d (crc32c checked)\n", fetched->params.version);
  std::printf("== 4. ");
  if (absl::Status s = PrintBeforeAfter(so, sim->truth, fetched->params); !s.ok())
    return ReportError(s);
  return kExitOk;
}

}  // namespace imucal::cli
