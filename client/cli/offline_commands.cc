// Offline commands: calibrate, apply, simulate, demo, export. They need no server.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <sstream>
#include <utility>

#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "client/cli/args.h"
#include "client/cli/botch.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "client/cli/demo_common.h"
#include "client/cli/export_flags.h"
#include "client/cli/import_flags.h"
#include "client/cli/summary.h"
#include "client/sdk/corrector.h"
#include "core/calibrate/calibrate.h"
#include "core/calibrate/term_priors.h"
#include "core/export.h"
#include "core/simulator.h"
#include "core/static_detector.h"
#include "core/validation.h"
#include "formats/params_json.h"
#include "formats/plots.h"
#include "formats/report_json.h"
#include "importers/imucal_csv.h"
#include "importers/registry.h"
#include "util/file.h"
#include "util/parallel.h"
#include "util/units.h"

namespace imucal::cli {
namespace {

// Provenance of a parameter set made by this CLI: the software and when (RFC 3339, UTC).
void StampParams(core::ParamSet* params) {
  params->software = "imucal " IMUCAL_VERSION;
  params->created_at = absl::FormatTime("%Y-%m-%dT%H:%M:%SZ", absl::Now(), absl::UTCTimeZone());
}

absl::StatusOr<std::string> ReadFile(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return absl::NotFoundError(absl::StrFormat("%s: cannot open", path));
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

int Usage(const std::string& message, const char* help) {
  std::fprintf(stderr, "imucal: %s\n\n%s", message.c_str(), help);
  return kExitUsage;
}

constexpr char kCalibrateHelp[] =
    "usage: imucal calibrate FILE... [options]\n"
    "  Calibrates the accelerometer and gyroscope from a static multi-pose capture.\n"
    "  FILE: an imucal capture CSV, an imu_tk pair (accelerometer file, gyroscope file), a\n"
    "  EuRoC imu0/data.csv, a ROS 2 bag or .mcap file, or a vendor CSV with --columns (see "
    "below).\n"
    "options:\n"
    "  --format auto|imucal|euroc|imutk|columns|rosbag2|mcap   (default auto: from the content)\n"
    "  --protocol auto|six-face|positions|free|ferraris   (default auto: from the poses)\n"
    "  --gravity G                   local gravity, m/s^2 (default: the file's, else 9.80665)\n"
    "  --accel-unit m/s^2|g|counts   --gyro-unit rad/s|deg/s|counts   override the units\n"
    "  --device ID                   device id for the report\n"
    "  --seed N                      BSAS random seed (default 1; same seed, same result)\n"
    "  --json                        print the JSON report (report.md) instead of the summary\n"
    "  --out FILE                    also write the JSON report to FILE\n"
    "  --out DIR/, --plots DIR       write report.json, summary.txt and SVG plots into DIR:\n"
    "                                residual per pose after each stage and before/after the\n"
    "                                effects, pose coverage on the sphere, Allan deviation,\n"
    "                                each effect against its regressor\n"
    "  --no-effects                  skip the search for effects the model misses\n"
    "  --apply-time-effects          apply a found dependence on time since power-on (reported\n"
    "                                only, by default)\n"
    "  --params-out FILE             write the parameter set (imucal-params v1) to FILE\n"
    "  --no-bsas                     skip the BSAS stage (least squares, then LM)\n"
    "  --sensor-class C              the prior widths of the second-order terms and angles the\n"
    "                                poses may not determine: mems (default) or tactical\n"
    "  --no-heldout                  skip the leave-one-pose-out refits\n"
    "exit codes: 0 pass/warn, 1 usage, 2 bad input, 3 capture cannot determine the model,\n"
    "            4 calibrated but the verdict is fail, 5 internal error\n";

constexpr char kApplyHelp[] =
    "usage: imucal apply --params FILE IN OUT.csv [--format F] [input options]\n"
    "  Applies a parameter set (or a report containing one) to a capture and writes it in\n"
    "  m/s^2 and rad/s, keeping t, temp, extra columns and the header metadata.\n"
    "  IN may be an imu_tk pair (two files) before OUT.csv.\n"
    "  --accel-unit U --gyro-unit U   the input's units (a vendor CSV states none)\n";

constexpr char kSimulateHelp[] =
    "usage: imucal simulate --out FILE.csv [options]\n"
    "  Writes a simulated capture with known truth.\n"
    "options:\n"
    "  --protocol six-face|positions24|positions36|free   (default six-face)\n"
    "  --seed N            (default 1)          --rate HZ       (default 200)\n"
    "  --extra-poses N     random extra poses after the protocol (default 0)\n"
    "  --free-poses N      poses of the free protocol (default 36)\n"
    "  --accel-noise A     m/s^2 per sample (default 0.02)   --gyro-noise W  rad/s (0.002)\n"
    "  --accel-unit U --gyro-unit U   units of the written capture (counts: raw register values)\n"
    "  --floor-tilt DEG    (default 1)          --turn-error DEG  (default 3)\n"
    "  --accel-step S --gyro-step S   quantisation: readings rounded to multiples of S, in the\n"
    "                      written unit (e.g. 0.01 m/s^2, 0.0174533 rad/s); counts: 1\n"
    "  --no-temperature    no temp column\n"
    "  --effect SENSOR:AXIS:REGRESSOR:COEF   an extra effect, e.g. accel:y:temperature:0.005\n"
    "                      (repeat the flag for several)\n"
    "  --truth FILE.json   write the true parameter set\n"
    "  --botch-turn        six-face only: the first 180-degree turn stops a quarter turn short,\n"
    "                      is held, then finished (as `imucal demo --server --botch-turn`):\n"
    "                      streamed with `imucal upload`, the guide shows a failed pair and its\n"
    "                      re-do\n";

absl::StatusOr<core::SimOptions> SimOptionsFrom(const Args& a) {
  core::SimOptions o;
  if (auto p = a.Get("protocol")) {
    auto sp = core::ParseSimProtocol(*p);
    if (!sp.ok()) return sp.status();
    o.protocol = *sp;
  }
  auto seed = a.GetInt("seed", 1);
  auto extra = a.GetInt("extra-poses", 0);
  auto free_poses = a.GetInt("free-poses", o.free_poses);
  auto rate = a.GetDouble("rate", o.rate_hz);
  auto an = a.GetDouble("accel-noise", o.accel_noise_m_s2);
  auto gn = a.GetDouble("gyro-noise", o.gyro_noise_rad_s);
  auto tilt = a.GetDouble("floor-tilt", o.floor_tilt_deg);
  auto accel_step = a.GetDouble("accel-step", o.accel_step);
  auto gyro_step = a.GetDouble("gyro-step", o.gyro_step);
  auto turn = a.GetDouble("turn-error", o.turn_error_deg);
  for (const absl::Status& s :
       {seed.status(), extra.status(), free_poses.status(), rate.status(), an.status(), gn.status(),
        tilt.status(), turn.status(), accel_step.status(), gyro_step.status()})
    if (!s.ok()) return s;
  o.seed = static_cast<uint64_t>(*seed);
  o.extra_poses = static_cast<int>(*extra);
  o.free_poses = static_cast<int>(*free_poses);
  o.rate_hz = *rate;
  o.accel_noise_m_s2 = *an;
  o.gyro_noise_rad_s = *gn;
  o.floor_tilt_deg = *tilt;
  o.turn_error_deg = *turn;
  o.accel_step = *accel_step;
  o.gyro_step = *gyro_step;
  o.temperature = !a.Has("no-temperature");
  if (auto u = a.Get("accel-unit")) {
    auto p = core::ParseAccelUnit(*u);
    if (!p.ok()) return p.status();
    o.accel_unit = *p;
  }
  if (auto u = a.Get("gyro-unit")) {
    auto p = core::ParseGyroUnit(*u);
    if (!p.ok()) return p.status();
    o.gyro_unit = *p;
  }
  for (const std::string& e : a.GetAll("effect")) {
    std::vector<std::string> parts = absl::StrSplit(e, ':');
    double coef;
    if (parts.size() != 4 || (parts[0] != "accel" && parts[0] != "gyro") || parts[1].size() != 1 ||
        parts[1][0] < 'x' || parts[1][0] > 'z' || !absl::SimpleAtod(parts[3], &coef)) {
      return absl::InvalidArgumentError(
          "--effect: expected SENSOR:AXIS:REGRESSOR:COEF, e.g. accel:y:temperature:0.005");
    }
    o.effects.push_back({parts[0] == "accel" ? core::Sensor::kAccel : core::Sensor::kGyro,
                         parts[1][0] - 'x', parts[2], coef});
  }
  if (absl::Status s = core::ValidateSimOptions(o); !s.ok()) return s;
  return o;
}

// A parameter set holding a simulator's truth, so that it can be exported like any other.
core::ParamSet TruthParams(const core::SimResult& sim) {
  core::ParamSet p;
  p.device = sim.capture.device;
  p.accel_unit = sim.capture.accel_unit;
  p.gyro_unit = sim.capture.gyro_unit;
  p.gravity_m_s2 = sim.capture.gravity_m_s2;
  p.accel = sim.truth.accel;
  p.gyro = sim.truth.gyro;
  p.gyro_calibrated = true;
  p.software = "imucal simulate (truth)";
  return p;
}

}  // namespace

absl::StatusOr<importers::ImportOptions> ImportOptionsFrom(const Args& a) {
  importers::ImportOptions o;
  if (absl::Status s = ApplyFormatAndUnitFlags(a, &o); !s.ok()) return s;
  if (a.Get("gravity")) {
    auto g = a.GetDouble("gravity", 0);
    if (!g.ok()) return g.status();
    if (!(*g > 1 && *g < 20))
      return absl::InvalidArgumentError("--gravity: expected m/s^2 between 1 and 20");
    o.gravity_m_s2 = *g;
  }
  if (auto d = a.Get("device")) o.device = *d;
  if (absl::Status s = ApplyImportFlags(a, &o); !s.ok()) return s;
  return o;
}

// Units the parameters expect and the capture does not have. The gyro unit matters only when
// both have a gyroscope.
absl::Status CheckApplyUnits(const core::ParamSet& params, const core::Capture& in) {
  const bool gyro_differs = params.has_gyro && in.has_gyro && in.gyro_unit != params.gyro_unit;
  if (in.accel_unit == params.accel_unit && !gyro_differs) return absl::OkStatus();
  return absl::InvalidArgumentError(absl::StrFormat(
      "units differ: the capture is accel %s / gyro %s, the parameters expect %s / %s",
      core::AccelUnitName(in.accel_unit), core::GyroUnitName(in.gyro_unit),
      core::AccelUnitName(params.accel_unit), core::GyroUnitName(params.gyro_unit)));
}

// Applies `params` to every sample of `in` through the SDK's Corrector (as a robot does). A
// parameter set without a gyroscope leaves the capture's gyro as read, in its own unit.
absl::StatusOr<core::Capture> ApplyParams(const core::ParamSet& params, const core::Capture& in) {
  if (absl::Status s = CheckApplyUnits(params, in); !s.ok()) return s;
  auto corrector =
      sdk::Corrector::Create(params, in.size() ? std::optional<double>(in.t_s[0]) : std::nullopt);
  if (!corrector.ok()) return corrector.status();
  core::Capture out = in;
  out.accel_unit = core::AccelUnit::kMetersPerSecond2;
  if (params.has_gyro) out.gyro_unit = core::GyroUnit::kRadPerSecond;
  for (size_t i = 0; i < in.size(); ++i) {
    sdk::RawSample raw;
    raw.t_s = in.t_s[i];
    for (int k = 0; k < 3; ++k) {
      raw.accel[k] = in.accel[i](k);
      raw.gyro[k] = in.has_gyro ? in.gyro[i](k) : 0.0;  // no gyro: nothing is written back
    }
    if (in.has_temp()) raw.temp_c = in.temp[i];
    sdk::CalibratedSample c;
    corrector->Apply(raw, &c);
    out.accel[i] = Eigen::Vector3d(c.accel_m_s2[0], c.accel_m_s2[1], c.accel_m_s2[2]);
    if (in.has_gyro)
      out.gyro[i] = Eigen::Vector3d(c.gyro_rad_s[0], c.gyro_rad_s[1], c.gyro_rad_s[2]);
  }
  return out;
}

// What `apply` wrote, in one line: which sensors were corrected.
std::string AppliedText(const core::ParamSet& params, const core::Capture& in,
                        const core::Capture& out) {
  if (!in.has_gyro) {
    return absl::StrFormat(
        "calibrated accelerometer samples (m/s^2; the capture has no gyroscope)");
  }
  if (!params.has_gyro) {
    return absl::StrFormat(
        "samples: accelerometer calibrated (m/s^2); gyro left as read (%s): the parameter set "
        "has no gyroscope part",
        core::GyroUnitName(out.gyro_unit));
  }
  return "calibrated samples (m/s^2, rad/s)";
}

core::SimOptions DemoCaptureOptions(uint64_t seed, int extra_poses) {
  core::SimOptions so;
  so.protocol = core::SimProtocol::kSixFace;
  so.extra_poses = extra_poses;
  so.seed = seed;
  return so;
}

absl::Status PrintBeforeAfter(const core::SimOptions& capture_options, const core::SimTruth& truth,
                              const core::ParamSet& params) {
  // A fresh capture of the same unit (same truth, new poses), without noise.
  core::SimOptions vo = capture_options;
  vo.seed = capture_options.seed + 1000;
  vo.protocol = core::SimProtocol::kFree;
  vo.extra_poses = 0;
  vo.accel_noise_m_s2 = 0;
  vo.gyro_noise_rad_s = 0;
  auto val = core::Simulate(vo, truth);
  if (!val.ok()) return val.status();
  auto calibrated = ApplyParams(params, val->capture);
  if (!calibrated.ok()) return calibrated.status();
  // "Before": the nominal conversion a robot would use without calibration.
  std::vector<Eigen::Vector3d> nominal_a, nominal_g;
  const double ka = core::NominalAccelToSi(val->capture.accel_unit, val->capture.gravity_m_s2);
  const double kg = core::NominalGyroToSi(val->capture.gyro_unit);
  for (size_t i = 0; i < val->capture.size(); ++i) {
    nominal_a.push_back(ka * val->capture.accel[i]);
    nominal_g.push_back(kg * val->capture.gyro[i]);
  }
  const double g = vo.gravity_m_s2;
  const double before_a = core::VectorRmsError(nominal_a, val->true_accel_m_s2, false);
  const double after_a = core::VectorRmsError(calibrated->accel, val->true_accel_m_s2, false);
  const double after_a_aligned =
      core::VectorRmsError(calibrated->accel, val->true_accel_m_s2, true);
  const double before_g = core::VectorRmsError(nominal_g, val->true_gyro_rad_s, false);
  const double after_g = core::VectorRmsError(calibrated->gyro, val->true_gyro_rad_s, false);
  std::printf(
      "applied through the robot SDK's Corrector to a fresh noise-free capture of the same unit "
      "(%zu samples)\n"
      "                     before (nominal)      after (calibrated)\n"
      "  accel error RMS    %8.2f mg           %8.3f mg  (%.3f mg after best-fit rotation)\n"
      "  gyro error RMS     %8.3f deg/s        %8.4f deg/s\n",
      val->capture.size(), 1e3 * before_a / g, 1e3 * after_a / g, 1e3 * after_a_aligned / g,
      before_g * kRadToDeg, after_g * kRadToDeg);
  return absl::OkStatus();
}

int ReportError(const absl::Status& status) {
  std::fprintf(stderr, "imucal: %s\n", std::string(status.message()).c_str());
  switch (status.code()) {
    case absl::StatusCode::kInvalidArgument:
    case absl::StatusCode::kNotFound:
    case absl::StatusCode::kAlreadyExists:
    case absl::StatusCode::kDataLoss:
      return kExitBadInput;
    case absl::StatusCode::kFailedPrecondition:
      return kExitUndetermined;
    default:
      return kExitInternal;
  }
}

int RunCalibrate(const std::vector<std::string>& argv) {
  auto a =
      ParseCommandFlags("calibrate", argv);
  if (!a.ok()) return Usage(std::string(a.status().message()), kCalibrateHelp);
  if (a->Has("help")) return std::printf("%s%s", kCalibrateHelp, kImportFlagsHelp), kExitOk;
  if (a->positional().empty()) return Usage("calibrate needs a capture FILE", kCalibrateHelp);
  auto io = ImportOptionsFrom(*a);
  if (!io.ok()) return Usage(std::string(io.status().message()), kCalibrateHelp);
  core::CalibrateOptions co;
  if (auto p = a->Get("protocol")) {
    auto k = core::ParseProtocolKind(*p);
    if (!k.ok()) return Usage(std::string(k.status().message()), kCalibrateHelp);
    co.protocol = *k;
  }
  auto seed = a->GetInt("seed", 1);
  if (!seed.ok()) return Usage(std::string(seed.status().message()), kCalibrateHelp);
  co.seed = static_cast<uint64_t>(*seed);
  co.use_bsas = !a->Has("no-bsas");
  if (auto c = a->Get("sensor-class")) {
    auto priors = core::TermPriorsFor(*c);
    if (!priors.ok()) return Usage("--sensor-class: " + std::string(priors.status().message()), kCalibrateHelp);
    co.term_priors = *priors;
  }
  co.heldout = !a->Has("no-heldout");
  co.effects.enabled = !a->Has("no-effects");
  co.effects.apply_time_effects = a->Has("apply-time-effects");
  // The independent steps (a pair's two files, the threshold sweep) on the machine's cores.
  io->threads = co.threads = DefaultThreads();

  importers::ImportReport import;
  auto capture = importers::ImportCapture(a->positional(), *io, &import);
  if (!capture.ok()) return ReportError(capture.status());
  auto report = core::Calibrate(*capture, co);
  if (!report.ok()) return ReportError(report.status());
  const bool refused = report->verdict == core::Verdict::kRefused;
  if (refused) {
    // The refusal first (its first sentence names the problem), then what the import decided
    // (units, time base, gaps), which often explains why poses are missing.
    std::fprintf(stderr, "imucal: %s\n", report->refusal->message.c_str());
    for (const auto& n : import.notes) std::fprintf(stderr, "imucal: note: %s\n", n.c_str());
  } else {
    StampParams(&report->params);
  }
  const std::string json = formats::ReportToJson(*report);
  // --out DIR (an existing directory, or a path ending in '/') and --plots DIR: the report,
  // its summary and the plots. --out FILE: the JSON report alone.
  std::optional<std::string> bundle_dir = a->Get("plots");
  if (auto out = a->Get("out")) {
    if (std::filesystem::is_directory(*out) || out->ends_with('/')) {
      bundle_dir = *out;
    } else if (absl::Status s = WriteFileDurably(*out, json); !s.ok()) {
      return ReportError(s);
    }
  }
  std::vector<std::string> plot_paths;
  if (bundle_dir) {
    auto written = formats::WriteReportBundle(nlohmann::json::parse(json), json,
                                              FormatSummary(*report), *bundle_dir);
    if (!written.ok()) return ReportError(written.status());
    plot_paths = std::move(*written);
  }
  if (auto out = a->Get("params-out"); out && !refused) {
    if (absl::Status s = WriteFileDurably(*out, formats::ParamSetToJson(report->params)); !s.ok())
      return ReportError(s);
  }
  if (a->Has("json")) {
    std::fputs(json.c_str(), stdout);
  } else {
    std::printf(
        "input       %s (%s, %zu samples, accel %s, gyro %s)\n",
        absl::StrJoin(import.paths, " + ").c_str(), import.format.c_str(), capture->size(),
        std::string(core::AccelUnitName(capture->accel_unit)).c_str(),
        capture->has_gyro ? std::string(core::GyroUnitName(capture->gyro_unit)).c_str() : "none");
    for (const auto& n : import.notes) std::printf("note        %s\n", n.c_str());
    std::fputs(FormatSummary(*report).c_str(), stdout);
    for (const auto& p : plot_paths) std::printf("wrote       %s\n", p.c_str());
  }
  return ExitForVerdict(report->verdict);
}

int RunApply(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("apply", argv);
  if (!a.ok()) return Usage(std::string(a.status().message()), kApplyHelp);
  if (a->Has("help")) return std::printf("%s%s", kApplyHelp, kImportFlagsHelp), kExitOk;
  if (!a->Get("params")) return Usage("apply needs --params FILE", kApplyHelp);
  if (a->positional().size() < 2) return Usage("apply needs IN and OUT.csv", kApplyHelp);
  auto text = ReadFile(*a->Get("params"));
  if (!text.ok()) return ReportError(text.status());
  auto params = formats::ParamSetFromJson(*text);
  if (!params.ok()) {
    return ReportError(absl::InvalidArgumentError(
        absl::StrFormat("%s: %s", *a->Get("params"), params.status().message())));
  }
  std::vector<std::string> inputs(a->positional().begin(), a->positional().end() - 1);
  auto io = ImportOptionsFrom(*a);
  if (!io.ok()) return Usage(std::string(io.status().message()), kApplyHelp);
  auto capture = importers::ImportCapture(inputs, *io);
  if (!capture.ok()) return ReportError(capture.status());
  auto out = ApplyParams(*params, *capture);
  if (!out.ok()) return ReportError(out.status());
  if (absl::Status s = importers::WriteImucalCsvFile(*out, a->positional().back()); !s.ok())
    return ReportError(s);
  std::printf("wrote %zu %s to %s\n", out->size(), AppliedText(*params, *capture, *out).c_str(),
              a->positional().back().c_str());
  return kExitOk;
}

int RunSimulate(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("simulate", argv);
  if (!a.ok()) return Usage(std::string(a.status().message()), kSimulateHelp);
  if (a->Has("help")) return std::printf("%s", kSimulateHelp), kExitOk;
  if (!a->Get("out")) return Usage("simulate needs --out FILE.csv", kSimulateHelp);
  auto options = SimOptionsFrom(*a);
  if (!options.ok()) return Usage(std::string(options.status().message()), kSimulateHelp);
  const bool botch = a->Has("botch-turn");
  if (botch && options->protocol != core::SimProtocol::kSixFace)
    return Usage("--botch-turn needs --protocol six-face (its first pair is a half turn)",
                 kSimulateHelp);
  auto sim = core::Simulate(*options);
  if (!sim.ok()) return ReportError(sim.status());
  if (botch) {
    absl::StatusOr<core::Capture> botched = BotchFirstTurn(*sim, options->hold_s);
    if (!botched.ok()) return ReportError(botched.status());
    sim->capture = *std::move(botched);
  }
  if (absl::Status s = importers::WriteImucalCsvFile(sim->capture, *a->Get("out")); !s.ok())
    return ReportError(s);
  if (auto truth = a->Get("truth")) {
    if (absl::Status s = WriteFileDurably(*truth, formats::ParamSetToJson(TruthParams(*sim)));
        !s.ok())
      return ReportError(s);
  }
  std::printf("wrote %zu samples, %zu static poses (%s, seed %llu%s) to %s\n", sim->capture.size(),
              sim->poses.size(), core::ProtocolName(options->protocol).c_str(),
              static_cast<unsigned long long>(options->seed),
              botch ? ", first half turn botched: one more hold" : "", a->Get("out")->c_str());
  return kExitOk;
}

// The offline main job: simulate a six-face session with extra poses, calibrate it, apply the
// result to a fresh noise-free validation capture, print the error before and after.
int RunDemo(const std::vector<std::string>& argv) {
  constexpr char kDemoHelp[] =
      "usage: imucal demo [--out-dir DIR] [--seed N] [--extra-poses N] [--no-bsas]\n"
      "       imucal demo --server ADDR [--seed N]   (the same through the service)\n";
  auto a = ParseCommandFlags("demo", argv);
  if (!a.ok()) return Usage(std::string(a.status().message()), kDemoHelp);
  if (a->Has("help")) return std::printf("%s", kDemoHelp), kExitOk;
  const std::string dir = a->Get("out-dir").value_or("imucal-demo");
  auto seed = a->GetInt("seed", 7);
  if (!seed.ok()) return Usage(std::string(seed.status().message()), "");
  auto extra = a->GetInt("extra-poses", 24);
  if (!extra.ok()) return Usage(std::string(extra.status().message()), "");
  std::filesystem::create_directories(dir);

  const core::SimOptions so =
      DemoCaptureOptions(static_cast<uint64_t>(*seed), static_cast<int>(*extra));
  auto sim = core::Simulate(so);
  if (!sim.ok()) return ReportError(sim.status());
  sim->capture.device = "demo-robot";
  const std::string capture_path = dir + "/capture.csv";
  if (absl::Status s = importers::WriteImucalCsvFile(sim->capture, capture_path); !s.ok())
    return ReportError(s);
  std::printf("== 1. simulated a six-face session + %d extra poses at 200 Hz, 2 mg noise: %s\n",
              so.extra_poses, capture_path.c_str());

  core::CalibrateOptions co;
  co.use_bsas = !a->Has("no-bsas");
  auto report = core::Calibrate(sim->capture, co);
  if (!report.ok()) return ReportError(report.status());
  StampParams(&report->params);
  WriteFileDurably(dir + "/report.json", formats::ReportToJson(*report)).IgnoreError();
  WriteFileDurably(dir + "/params.json", formats::ParamSetToJson(report->params)).IgnoreError();
  std::printf("== 2. calibrated it (report.json, params.json in %s)\n%s", dir.c_str(),
              FormatSummary(*report).c_str());
  std::printf("== 3. ");
  if (absl::Status s = PrintBeforeAfter(so, sim->truth, report->params); !s.ok())
    return ReportError(s);
  return kExitOk;
}

namespace {

// ---------------------------------------------------------------------------------------------
// export (offline): a parameter set file in the formats robots' estimators load (core/export.h).

constexpr char kExportFileHelp[] =
    "usage: imucal export --params FILE --format json|kalibr|kalibr-intrinsics|openvins\n"
    "                     [--out FILE] [--rostopic /imu0] [--rate HZ] [noise values]\n"
    "  Writes a parameter set (or the one inside a report) for robots' estimators:\n"
    "  json               imucal-params v1, as stored (everything, biases included)\n"
    "  kalibr             Kalibr imu.yaml: noise densities, random walks, update_rate\n"
    "  kalibr-intrinsics  Kalibr scale-misalignment model (M, A, C_gyro_i, T_i_b) + noise keys\n"
    "  openvins           OpenVINS kalibr_imu_chain.yaml (Tw, R_IMUtoGYRO, Ta, R_IMUtoACC, Tg)\n"
    "  The YAML formats hold no biases, second-order terms or effects: the file's header and\n"
    "  this command say so. Matrix conventions: README, \"Exported formats\".\n"
    "options:\n"
    "  --out FILE              write FILE (default: standard output)\n";
constexpr char kExportFileHelpTail[] =
    "  (a stored version from the service: imucal --server ADDR export --device D --format F)\n"
    "exit codes: 0 written, 1 usage, 2 bad input (unreadable file, raw counts, singular\n"
    "            matrix, a noise figure or the rate neither measured nor given)\n";

}  // namespace

int RunExportFile(const std::vector<std::string>& argv) {
  auto a =
      ParseCommandFlags("export-file", argv);
  if (!a.ok()) return Usage(std::string(a.status().message()), kExportFileHelp);
  if (a->Has("help")) {
    return std::printf("%s%s%s", kExportFileHelp, kExportOptionsHelp, kExportFileHelpTail), kExitOk;
  }
  const auto params_path = a->Get("params");
  const auto format_name = a->Get("format");
  if (!params_path || !format_name)
    return Usage("export needs --params and --format", kExportFileHelp);
  if (!a->positional().empty())
    return Usage("unexpected argument '" + a->positional()[0] + "'", kExportFileHelp);
  std::optional<core::ExportFormat> format;
  if (*format_name != "json") {
    auto f = core::ParseExportFormat(*format_name);
    if (!f.ok())
      return Usage("--format: expected json, kalibr, kalibr-intrinsics or openvins",
                   kExportFileHelp);
    format = *f;
  }
  auto options = ExportOptionsFrom(*a);
  if (!options.ok()) return Usage(std::string(options.status().message()), kExportFileHelp);

  auto text = ReadFile(*params_path);
  if (!text.ok()) return ReportError(text.status());
  auto params = formats::ParamSetFromJson(*text);
  if (!params.ok()) {
    return ReportError(absl::InvalidArgumentError(
        absl::StrFormat("%s: %s", *params_path, params.status().message())));
  }
  std::string out;
  if (format) {
    auto exported = core::ExportParams(*params, *format, *options);
    if (!exported.ok()) {
      std::fprintf(stderr, "imucal: %s: %s\n", params_path->c_str(),
                   std::string(exported.status().message()).c_str());
      return kExitBadInput;  // the parameter set lacks what the format needs
    }
    out = *std::move(exported);
    for (const std::string& n : core::ExportNotes(*params, *format, *options))
      std::fprintf(stderr, "imucal: note: %s\n", n.c_str());
  } else {
    out = formats::ParamSetToJson(*params);
  }
  if (auto path = a->Get("out")) {
    if (absl::Status s = WriteFileDurably(*path, out); !s.ok()) return ReportError(s);
    std::fprintf(stderr, "imucal: wrote %s (%s)\n", path->c_str(), format_name->c_str());
  } else {
    std::fputs(out.c_str(), stdout);
  }
  return kExitOk;
}

}  // namespace imucal::cli
