// `imucal devices`: list, register or show the server's devices (DeviceService).
#include <cstdio>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "client/cli/args.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "client/cli/server_common.h"

namespace imucal::cli {

namespace pb = imucal::v1;

namespace {

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
    grpc::Status s = ForEachPage(server.devices.get(), &pb::DeviceService::Stub::ListDevices,
                                 pb::ListDevicesRequest(), [&](pb::ListDevicesResponse& page) {
                                   for (auto& d : *page.mutable_devices())
                                     *all.add_devices() = std::move(d);
                                 });
    if (!s.ok()) return RpcError(server, s);
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

}  // namespace imucal::cli
