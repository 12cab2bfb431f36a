// `imucal export --device D`: a stored parameter version in another tool's format, converted by
// the server (ParameterService.Export). `export --params FILE` is offline (offline_commands.cc).
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "client/cli/args.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "client/cli/export_flags.h"
#include "client/cli/server_common.h"
#include "core/export.h"
#include "util/file.h"

namespace imucal::cli {

namespace pb = imucal::v1;

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
