// `imucal params`: a device's parameter versions (ParameterService): show, list, promote,
// roll back, and upload a parameter set made offline (e.g. by `imucal learn`) as a new version.
#include <cstdio>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "client/cli/args.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "client/cli/json_text.h"
#include "client/cli/server_common.h"
#include "core/calibrate/verdict.h"
#include "formats/params_json.h"
#include "nlohmann/json.hpp"
#include "util/file.h"

namespace imucal::cli {

namespace pb = imucal::v1;
using nlohmann::json;

namespace {

constexpr char kParamsHelp[] =
    "usage: imucal params get --device D [--version N] [--json]\n"
    "       imucal params list --device D [--json]\n"
    "       imucal params promote --device D --version N [--reason TEXT]\n"
    "       imucal params rollback --device D --to N [--reason TEXT]\n"
    "       imucal params upload --device D --file P.json [--reason TEXT]\n"
    "  Shows a parameter version (default the active one; --json prints the \"imucal-params v1\"\n"
    "  document exactly as stored), lists the versions, makes a version active, or makes an\n"
    "  earlier version active again. upload stores an \"imucal-params v1\" file made offline\n"
    "  (imucal learn's, with its dynamic_gyro block) as the device's next version, judged as a\n"
    "  solve is: active at once on verdict pass, else a candidate to promote (exit 4 on fail).\n"
    "options:\n";

void PrintParamHeader(const pb::ParameterSet& p) {
  std::printf("v%-4d %-10s %-5s accel rms %.5f m/s^2  %s  session %s\n", p.version(),
              VersionStateName(p.state()).c_str(), p.verdict().c_str(), p.accel_rms_m_s2(),
              TimeText(p.created_at()).c_str(), p.session_id().c_str());
}

// The stored document's figures in a technician's words (`params get` without --json).
void PrintParamSet(const pb::ParameterSet& p) {
  std::printf("device      %s\n", p.device_id().c_str());
  std::printf("version     ");
  PrintParamHeader(p);
  json j = json::parse(p.json(), nullptr, false);
  if (j.is_object()) {
    if (j.contains("accel")) {
      std::printf("accel unit  %s\n", JsonString(j["accel"], "input_unit").c_str());
      std::printf("accel bias  %s\n", JsonVector(j["accel"]["bias"]).c_str());
      std::printf("accel scale %s\n", JsonVector(j["accel"]["scale"]).c_str());
    }
    if (j.contains("gyro")) {
      std::printf("gyro unit   %s\n", JsonString(j["gyro"], "input_unit").c_str());
      std::printf("gyro bias   %s\n", JsonVector(j["gyro"]["bias"], "%+.6f").c_str());
    }
    if (j.contains("effects")) std::printf("effects     %zu\n", j["effects"].size());
  }
  std::printf("crc32c      %08x\n", p.crc32c());
}

// `params get`: version `version` of the device, or (0) its active one.
int GetParams(const Server& server, const std::string& device, int64_t version, bool as_json) {
  pb::ParameterSet p;
  auto ctx = CallContext();
  grpc::Status s;
  if (version > 0) {
    pb::GetParametersRequest req;
    req.set_device_id(device);
    req.set_version(static_cast<int32_t>(version));
    s = server.params->GetParameters(ctx.get(), req, &p);
  } else {
    pb::GetActiveParametersRequest req;
    req.set_device_id(device);
    s = server.params->GetActiveParameters(ctx.get(), req, &p);
  }
  if (!s.ok()) return RpcError(server, s);
  if (as_json) {
    std::fputs(p.json().c_str(), stdout);
    if (!p.json().empty() && p.json().back() != '\n') std::fputs("\n", stdout);
    return kExitOk;
  }
  PrintParamSet(p);
  return kExitOk;
}

// `params list`: every page of the device's versions.
int ListParams(const Server& server, const std::string& device, bool as_json) {
  pb::ListVersionsResponse all;
  pb::ListVersionsRequest req;
  req.set_device_id(device);
  grpc::Status s = ForEachPage(server.params.get(), &pb::ParameterService::Stub::ListVersions, req,
                               [&](pb::ListVersionsResponse& page) {
                                 for (auto& v : *page.mutable_versions())
                                   *all.add_versions() = std::move(v);
                               });
  if (!s.ok()) return RpcError(server, s);
  if (as_json) return std::printf("%s\n", ProtoJson(all).c_str()), kExitOk;
  if (all.versions().empty()) std::printf("%s has no parameter versions\n", device.c_str());
  for (const auto& v : all.versions()) PrintParamHeader(v);
  return kExitOk;
}

// `params promote` (--version N) or `params rollback` (--to N): makes that version active.
int ActivateParams(const Args& a, const Server& server, const std::string& verb,
                   const std::string& device, int64_t version, int64_t to) {
  pb::ParameterSet p;
  auto ctx = CallContext();
  grpc::Status s;
  if (verb == "promote") {
    if (version <= 0) return UsageError("params promote needs --version N", kParamsHelp);
    pb::PromoteRequest req;
    req.set_device_id(device);
    req.set_version(static_cast<int32_t>(version));
    req.set_reason(a.Get("reason").value_or(""));
    s = server.params->Promote(ctx.get(), req, &p);
  } else {
    if (to <= 0) return UsageError("params rollback needs --to N", kParamsHelp);
    pb::RollbackRequest req;
    req.set_device_id(device);
    req.set_to_version(static_cast<int32_t>(to));
    req.set_reason(a.Get("reason").value_or(""));
    s = server.params->Rollback(ctx.get(), req, &p);
  }
  if (!s.ok()) return RpcError(server, s);
  p.clear_json();
  if (a.Has("json")) return std::printf("%s\n", ProtoJson(p).c_str()), kExitOk;
  std::printf("%s v%d is now active\n", p.device_id().c_str(), p.version());
  return kExitOk;
}

// `params upload`: the file checked here first (a malformed one is bad input, named by its
// JSON path), then stored by the server, which judges it and says why it is not active.
int UploadParams(const Args& a, const Server& server, const std::string& device) {
  const std::optional<std::string> file = a.Get("file");
  if (!file) return UsageError("params upload needs --file P.json", kParamsHelp);
  absl::StatusOr<std::string> text = ReadFileBytes(*file);
  absl::Status valid = text.status();
  if (valid.ok()) valid = formats::ParamSetFromJson(*text).status();
  if (!valid.ok()) {
    std::fprintf(stderr, "imucal: %s: %s\n", file->c_str(), std::string(valid.message()).c_str());
    return kExitBadInput;
  }
  pb::UploadParametersRequest req;
  req.set_device_id(device);
  req.set_json(*std::move(text));
  req.set_reason(a.Get("reason").value_or(""));
  pb::UploadParametersResponse out;
  auto ctx = CallContext();
  if (grpc::Status s = server.params->UploadParameters(ctx.get(), req, &out); !s.ok())
    return RpcError(server, s);
  const pb::ParameterSet& v = out.version();
  if (a.Has("json")) {
    pb::UploadParametersResponse header = out;
    header.mutable_version()->clear_json();
    std::printf("%s\n", ProtoJson(header).c_str());
  } else {
    std::printf("%s v%d stored: verdict %s, %s\n", v.device_id().c_str(), v.version(),
                v.verdict().c_str(),
                v.state() == pb::VERSION_STATE_ACTIVE ? "now active"
                                                      : "a candidate (params promote to use it)");
    for (const std::string& r : out.reasons()) std::printf("  - %s\n", r.c_str());
  }
  return ExitForVerdict(core::ParseVerdict(v.verdict()));
}

}  // namespace

int RunParams(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("params", argv);
  if (!a.ok()) return UsageError(std::string(a.status().message()), kParamsHelp);
  if (a->Has("help")) return std::printf("%s%s", kParamsHelp, kServerFlagHelp), kExitOk;
  const auto& pos = a->positional();
  auto device = a->Get("device");
  if (pos.size() != 1)
    return UsageError("params needs get, list, promote, rollback or upload", kParamsHelp);
  if (!device) return UsageError("params needs --device D", kParamsHelp);
  auto version = a->GetInt("version", 0);
  auto to = a->GetInt("to", 0);
  if (!version.ok() || !to.ok()) return UsageError("--version and --to take numbers", kParamsHelp);
  Server server = Connect(*a);
  const bool as_json = a->Has("json");
  const std::string& verb = pos[0];
  if (verb == "get") return GetParams(server, *device, *version, as_json);
  if (verb == "list") return ListParams(server, *device, as_json);
  if (verb == "promote" || verb == "rollback")
    return ActivateParams(*a, server, verb, *device, *version, *to);
  if (verb == "upload") return UploadParams(*a, server, *device);
  return UsageError(absl::StrCat("params: unknown action '", verb, "'"), kParamsHelp);
}

}  // namespace imucal::cli
