// `imucal report`: the report of a session's latest solve, as a summary or the stored JSON,
// with --out DIR its bundle (report.json, summary.txt, plots).
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "client/cli/args.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "client/cli/json_text.h"
#include "client/cli/server_common.h"
#include "client/cli/summary.h"
#include "formats/params_json.h"
#include "formats/plots.h"
#include "nlohmann/json.hpp"

namespace imucal::cli {

namespace pb = imucal::v1;
using nlohmann::json;

namespace {

constexpr char kReportHelp[] =
    "usage: imucal report --session S [--json] [--out DIR]\n"
    "  The report of the session's latest solve: a summary, or with --json the\n"
    "  \"imucal-report v1\" document exactly as the server stores it.\n"
    "options:\n"
    "  --out DIR     also write report.json, summary.txt and SVG plots into DIR (residual per\n"
    "                pose after each stage, pose coverage on the sphere, Allan deviation, each\n"
    "                effect against its regressor)\n";

// The server report as text: what `report` prints and `report --out DIR` keeps as summary.txt.
std::string FormatReportSummary(const json& r) {
  std::string out;
  absl::StrAppendFormat(&out, "device      %s   session %s\n", JsonString(r, "device").c_str(),
                        JsonString(r, "session").c_str());
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
                              JsonString(p, "reason").c_str());
    }
  }
  if (r.contains("pairs")) {
    for (const auto& p : r["pairs"]) {
      absl::StrAppendFormat(&out, "  pair %-9s %-4s rotation %.1f deg, tilt %.1f deg  %s\n",
                            p.contains("poses") ? p["poses"].dump().c_str() : "?",
                            JsonString(p, "status").c_str(), JsonNumber(p, "rotation_deg"),
                            JsonNumber(p, "tilt_deg"), JsonString(p, "reason").c_str());
    }
  }
  if (r.contains("stages")) {
    for (const auto& s : r["stages"])
      absl::StrAppendFormat(&out, "stage       %-5s accel rms %.5f m/s^2 (%d iterations)\n",
                            JsonString(s, "name").c_str(), JsonNumber(s, "accel_rms"),
                            s.value("iterations", 0));
  }
  if (r.contains("residual")) {
    const json& res = r["residual"];
    absl::StrAppendFormat(
        &out, "residual    accel rms %.5f m/s^2, max %.5f m/s^2, gyro static rms %.6f rad/s\n",
        JsonNumber(res, "accel_rms"), JsonNumber(res, "accel_max"),
        JsonNumber(res, "gyro_static_rms"));
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
      absl::StrAppendFormat(&out, "accel bias  %s\n", JsonVector(p["accel"]["bias"]).c_str());
      absl::StrAppendFormat(&out, "accel scale %s\n", JsonVector(p["accel"]["scale"]).c_str());
    }
    if (p.contains("gyro"))
      absl::StrAppendFormat(&out, "gyro bias   %s\n",
                            JsonVector(p["gyro"]["bias"], "%+.6f").c_str());
  }
  if (r.contains("effects")) {
    for (const auto& e : r["effects"]) {
      // A rate term has no static figure (null): its held-out figures are the moves'.
      const double before = JsonNumber(e, "error_before"), after = JsonNumber(e, "error_after");
      const std::string held =
          std::isnan(before)
              ? std::string("held out on the moves: see effect_diagnostics.move_search")
              : absl::StrFormat("held-out rms %.3g -> %.3g", before, after);
      absl::StrAppendFormat(&out, "effect      %s %s ~ %s: %.3g (%s; %s)\n",
                            JsonString(e, "sensor").c_str(), JsonString(e, "axis").c_str(),
                            JsonString(e, "regressor").c_str(), JsonNumber(e, "coefficient"),
                            JsonString(e, "human").c_str(), held);
    }
  }
  if (r.contains("warnings")) {
    for (const auto& w : r["warnings"])
      absl::StrAppendFormat(&out, "warning     %s\n",
                            w.is_string() ? w.get<std::string>().c_str() : w.dump().c_str());
  }
  absl::StrAppendFormat(&out, "verdict     %s\n", JsonString(r, "verdict").c_str());
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
  return ExitForVerdict(core::ParseVerdict(JsonString(r, "verdict")));
}

}  // namespace imucal::cli
