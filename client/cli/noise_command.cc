// `imucal noise REST...` / `imucal noise --session S`: the noise figures of a rest recording
// alone (core/allan.h), with their cluster times and 95% intervals, and the noise keys of
// Kalibr's imu.yaml and of OpenVINS's kalibr_imu_chain.yaml written with yaml-cpp. The rest comes
// from files (the importers) or from a robot's stored session on the server (noise_source.h);
// everything after reading it is the same code.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "client/cli/args.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "client/cli/demo_common.h"
#include "client/cli/import_flags.h"
#include "client/cli/noise_source.h"
#include "core/allan.h"
#include "core/export.h"
#include "core/noise_rest.h"
#include "formats/params_json.h"
#include "formats/plots.h"
#include "importers/registry.h"
#include "nlohmann/json.hpp"
#include "util/file.h"
#include "yaml-cpp/yaml.h"

namespace imucal::cli {
namespace {

constexpr char kNoiseHelp[] =
    "usage: imucal noise REST... [options]\n"
    "       imucal noise --session S [--server ADDR] [options]\n"
    "  The noise figures of a recording at rest (minutes to hours, the sensor untouched): the\n"
    "  overlapping Allan deviation of each calibrated axis and, read off it, the white-noise\n"
    "  density N, the bias instability B and the rate random walk K, each with the cluster time\n"
    "  it was read at and its 95% confidence interval. A figure the record is too short to\n"
    "  reach is an upper bound (a 95% upper limit), marked '<='. The still detector checks the\n"
    "  rest: a record with no still stretch of 10 s is refused; motion in it (a capture's moves,\n"
    "  handling) is cut out, and the output says what was cut. REST: any capture format\n"
    "  calibrate reads. --session S: a robot's rest as the server stored it (its samples in the\n"
    "  device's registered units), with the same figures as the same samples in a file.\n"
    "options:\n"
    "  --session S         read session S's stored samples from the server instead of files\n"
    "  --server ADDR       with --session: the calibration service (default $IMUCAL_SERVER,\n"
    "                      else 127.0.0.1:50051); --ca-cert, --token-file / --token as for the\n"
    "                      server commands\n"
    "  --params P.json     apply this parameter set first (the figures of the calibrated\n"
    "                      signal; needed for a capture in raw counts)\n"
    "  --out DIR           write DIR/imu.yaml (Kalibr), DIR/kalibr_imu_chain.yaml (OpenVINS noise\n"
    "                      keys), DIR/noise.json and the Allan plots DIR/allan_{accel,gyro}.svg\n"
    "  --rostopic T        rostopic of the YAML files (default /imu0)\n"
    "  --json              print the figures as JSON\n"
    "  --gravity G         local gravity, m/s^2, for a capture in g (default: the file's,\n"
    "                      else 9.80665)\n"
    "  --format F, --accel-unit U, --gyro-unit U, --device ID: files only, as for calibrate\n"
    "exit codes: 0 ok, 1 usage, 2 bad input or unknown session, 3 the record is not at rest\n"
    "            or the session holds no samples yet, 5 internal, 6 server unreachable, 7 the\n"
    "            server refused the token or its role\n";

constexpr const char* kAxes[6] = {"accel x", "accel y", "accel z", "gyro x", "gyro y", "gyro z"};

int Usage(const std::string& message) {
  std::fprintf(stderr, "imucal: %s\n\n%s", message.c_str(), kNoiseHelp);
  return kExitUsage;
}

std::string Fig(const core::AllanReading& r) {
  if (std::isnan(r.value)) return "not reached";
  if (r.upper_bound) return absl::StrFormat("<= %.3g (95%%) at %.3g s", r.value, r.tau_s);
  return absl::StrFormat("%.3g [%.3g, %.3g] at %.3g s", r.value, r.low, r.high, r.tau_s);
}

nlohmann::json Num(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); }

nlohmann::json ReadingJson(const core::AllanReading& r) {
  return {{"value", Num(r.value)},
          {"tau_s", Num(r.tau_s)},
          {"interval_95", {Num(r.low), Num(r.high)}},
          {"upper_bound", r.upper_bound}};
}

// The value a filter is given for one sensor's figure: the largest axis (conservative, as
// core/export.h), and whether any axis' figure is only an upper bound.
struct Key {
  double value = 0;
  bool bound = false;
};
Key Largest(const core::NoiseAnalysis& na, bool gyro, core::AllanReading core::AxisReadings::*f) {
  Key key;
  for (size_t k = gyro ? 3 : 0; k < (gyro ? 6u : 3u); ++k) {
    const core::AllanReading& r = na.readings[k].*f;
    if (!(r.value > key.value)) continue;
    key.value = r.value;
    key.bound = r.upper_bound;
  }
  return key;
}

// The four noise keys with a comment on each that is a bound; `emit` is inside a map.
void EmitNoiseKeys(const core::NoiseAnalysis& na, YAML::Emitter* out) {
  struct Row {
    const char* key;
    bool gyro;
    core::AllanReading core::AxisReadings::*figure;
    const char* unit;
  };
  for (const Row& row :
       {Row{"accelerometer_noise_density", false, &core::AxisReadings::noise_density,
            "m/s^2/sqrt(Hz)"},
        Row{"accelerometer_random_walk", false, &core::AxisReadings::random_walk, "m/s^3/sqrt(Hz)"},
        Row{"gyroscope_noise_density", true, &core::AxisReadings::noise_density, "rad/s/sqrt(Hz)"},
        Row{"gyroscope_random_walk", true, &core::AxisReadings::random_walk, "rad/s^2/sqrt(Hz)"}}) {
    const Key key = Largest(na, row.gyro, row.figure);
    *out << YAML::Key << row.key << YAML::Value << core::YamlFloat(key.value);
    *out << YAML::Comment(key.bound ? absl::StrFormat("%s; an UPPER BOUND: the rest is too short "
                                                      "to reach it (largest axis)",
                                                      row.unit)
                                    : absl::StrFormat("%s (largest axis)", row.unit));
  }
}

std::string KalibrImuYaml(const core::NoiseAnalysis& na, const std::string& rostopic) {
  YAML::Emitter out;
  out << YAML::Comment(absl::StrFormat(
      "Kalibr imu.yaml: noise of a %.0f s rest at %.6g Hz (imucal noise; continuous-time "
      "densities)",
      static_cast<double>(na.figures.samples) / na.figures.rate_hz, na.figures.rate_hz));
  out << YAML::BeginMap;
  EmitNoiseKeys(na, &out);
  out << YAML::Key << "rostopic" << YAML::Value << rostopic;
  out << YAML::Key << "update_rate" << YAML::Value << core::YamlFloat(na.figures.rate_hz);
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

std::string OpenVinsNoiseYaml(const core::NoiseAnalysis& na, const std::string& rostopic) {
  YAML::Emitter out;
  out << YAML::Comment(
      "OpenVINS kalibr_imu_chain.yaml noise keys (imucal noise); the intrinsics come from "
      "imucal export --format openvins");
  out << YAML::BeginMap << YAML::Key << "imu0" << YAML::Value << YAML::BeginMap;
  EmitNoiseKeys(na, &out);
  out << YAML::Key << "rostopic" << YAML::Value << rostopic;
  out << YAML::Key << "update_rate" << YAML::Value << core::YamlFloat(na.figures.rate_hz);
  out << YAML::EndMap << YAML::EndMap;
  // OpenVINS reads the file with OpenCV's FileStorage, which wants this first line.
  return "%YAML:1.0\n---\n" + std::string(out.c_str()) + "\n";
}

// How a unit was decided, as the calibration report says it (formats/report_json.cc).
std::string UnitSource(const std::string& source) { return source.empty() ? "unstated" : source; }

// What part of the record the figures are of: its still stretches and what was cut.
nlohmann::json RestJson(const core::NoiseRest& rest, const core::Capture& capture) {
  auto ranges = [&](const std::vector<core::SampleRange>& v) {
    nlohmann::json out = nlohmann::json::array();
    for (const core::SampleRange& r : v) {
      out.push_back({{"t_start_s", capture.t_s[r.begin]},
                     {"t_end_s", capture.t_s[r.end - 1]},
                     {"samples", r.size()}});
    }
    return out;
  };
  return {{"whole", rest.whole},
          {"record_s", rest.record_s},
          {"rest_s", rest.rest_s},
          {"cut_s", rest.cut_s},
          {"segments", ranges(rest.segments)},
          {"cut", ranges(rest.cut)},
          {"method",
           rest.segments.size() > 1 ? "pooled: each difference inside one segment" : "one segment"},
          {"note", rest.note}};
}

nlohmann::json NoiseJson(const core::NoiseAnalysis& na, const NoiseInput& input,
                         const nlohmann::json& rest) {
  const importers::ImportReport& import = input.report;
  nlohmann::json axes = nlohmann::json::object();
  for (size_t k = 0; k < 6; ++k) {
    axes[std::string(kAxes[k]).replace(std::string(kAxes[k]).find(' '), 1, "_")] = {
        {"noise_density", ReadingJson(na.readings[k].noise_density)},
        {"bias_instability", ReadingJson(na.readings[k].bias_instability)},
        {"random_walk", ReadingJson(na.readings[k].random_walk)}};
  }
  nlohmann::json out = {{"format", "imucal-noise v1"},
                        {"inputs", import.paths},
                        {"samples", na.figures.samples},
                        {"rate_hz", na.figures.rate_hz},
                        {"units",
                         {{"accel",
                           {{"noise_density", "m/s^2/sqrt(Hz)"},
                            {"bias_instability", "m/s^2"},
                            {"random_walk", "m/s^3/sqrt(Hz)"}}},
                          {"gyro",
                           {{"noise_density", "rad/s/sqrt(Hz)"},
                            {"bias_instability", "rad/s"},
                            {"random_walk", "rad/s^2/sqrt(Hz)"}}}}},
                        {"axes", axes},
                        {"rest", rest},
                        {"input_units",
                         {{"accel", core::AccelUnitName(input.capture.accel_unit)},
                          {"gyro", core::GyroUnitName(input.capture.gyro_unit)},
                          {"accel_source", UnitSource(input.capture.accel_unit_source)},
                          {"gyro_source", UnitSource(input.capture.gyro_unit_source)}}},
                        {"notes", na.figures.notes}};
  if (input.session) {
    out["session"] = {{"id", input.session->id},
                      {"device", input.session->device},
                      {"server", input.session->server}};
  }
  return out;
}

// The rest to analyse: the files' capture (the importers), or the session's (`read_session`).
int ReadNoiseInput(const Args& a, const NoiseSessionReader& read_session, NoiseInput* in) {
  auto io = ImportOptionsFrom(a);
  if (!io.ok()) return Usage(std::string(io.status().message()));
  auto session = a.Get("session");
  if (!session) {
    if (a.positional().empty()) return Usage("noise needs a REST recording or --session S");
    auto capture = importers::ImportCapture(a.positional(), *io, &in->report);
    if (!capture.ok()) return ReportError(capture.status());
    in->capture = *std::move(capture);
    return kExitOk;
  }
  if (session->empty()) return Usage("--session: empty (a session id, from imucal session list)");
  if (!a.positional().empty()) {
    return Usage("give REST files or --session S, not both (" + a.positional().front() + ")");
  }
  // A session's samples are in its device's registered units: what names a file's units or
  // layout has nothing to say about them.
  for (const char* flag : {"format", "accel-unit", "gyro-unit", "device", "columns", "topic"}) {
    if (a.Has(flag)) {
      return Usage(absl::StrFormat(
          "--%s applies to files; a session's samples are in its device's registered units", flag));
    }
  }
  if (!read_session) return Usage("--session needs the server commands (this build has none)");
  if (int code = read_session(*session, a.Get("server"), in); code != kExitOk) return code;
  if (io->gravity_m_s2) in->capture.gravity_m_s2 = *io->gravity_m_s2;
  return kExitOk;
}

// The signal analysed: the parameter set's calibration applied to `input`'s capture (through the
// SDK, as a robot applies it), else `accel` and `gyro` set to the nominal factors of its units.
// Returns kExitOk or the exit code of the error printed.
int SignalToAnalyse(const Args& a, NoiseInput* input, core::AccelParams* accel,
                    core::GyroParams* gyro) {
  if (auto params_path = a.Get("params")) {
    std::ifstream f(*params_path, std::ios::binary);
    if (!f) return ReportError(absl::NotFoundError(*params_path + ": cannot open"));
    std::stringstream text;
    text << f.rdbuf();
    auto params = formats::ParamSetFromJson(text.str());
    if (!params.ok()) {
      return ReportError(absl::InvalidArgumentError(
          absl::StrFormat("%s: %s", *params_path, params.status().message())));
    }
    auto calibrated = ApplyParams(*params, input->capture);
    if (!calibrated.ok()) return ReportError(calibrated.status());
    input->capture = *std::move(calibrated);
  } else {
    const double ka =
        core::NominalAccelToSi(input->capture.accel_unit, input->capture.gravity_m_s2);
    const double kg = core::NominalGyroToSi(input->capture.gyro_unit);
    if (std::isnan(ka) || std::isnan(kg)) {
      return ReportError(absl::InvalidArgumentError(
          input->session ? "the device's samples are in raw counts, which have no unit: give "
                           "--params P.json (a calibration of this sensor)"
                         : "the capture is in raw counts, which have no unit: give --params "
                           "P.json (a calibration of this sensor) or --accel-unit/--gyro-unit"));
    }
    accel->scale = Eigen::Vector3d::Constant(ka);
    gyro->matrix = kg * Eigen::Matrix3d::Identity();
  }
  return kExitOk;
}

// The rest of `capture` (the still detector's stretches, motion cut out: core/noise_rest.h)
// and its figures, calibrated by `accel` and `gyro`. A record with no rest long enough is
// refused (FailedPrecondition: exit 3). Returns kExitOk or the exit code of the error printed.
int AnalyseRest(const core::Capture& capture, const core::AccelParams& accel,
                const core::GyroParams& gyro, core::NoiseRest* rest, core::NoiseAnalysis* na) {
  auto found = core::FindNoiseRest(capture);
  if (!found.ok()) return ReportError(found.status());
  *rest = *std::move(found);
  auto analysis = core::ComputeNoiseOfSegments(capture, rest->segments,
                                               core::SampleCorrection(accel, gyro, {}, 0.0));
  if (!analysis.ok()) return ReportError(analysis.status());
  *na = *std::move(analysis);
  if (!rest->whole) na->figures.notes.insert(na->figures.notes.begin(), rest->note);
  if (rest->segments.size() > 1 && rest->whole) {
    na->figures.notes.push_back(
        "several files were joined: the Allan variances of their rests are pooled, no "
        "difference spans two files");
  }
  return kExitOk;
}

// The figures as text: what was read, the rest used, each axis' figures, the notes.
void PrintNoiseText(const core::NoiseAnalysis& analysis, const core::NoiseRest& rest,
                    const NoiseInput& input) {
  const core::NoiseAnalysis* const na = &analysis;
  const core::Capture* const capture = &input.capture;
  const importers::ImportReport& import = input.report;
  std::printf("input       %s (%s, %zu samples at %.6g Hz, %.0f s)\n",
              absl::StrJoin(import.paths, " + ").c_str(), import.format.c_str(), capture->size(),
              na->figures.rate_hz, rest.record_s);
  for (const auto& n : import.notes) std::printf("note        %s\n", n.c_str());
  std::printf("rest        %s\n",
              rest.whole ? absl::StrFormat("the whole record (%.1f s still)", rest.rest_s).c_str()
                         : absl::StrFormat("%.1f s used, %.1f s cut (see the first note)",
                                           rest.rest_s, rest.cut_s)
                               .c_str());
  std::printf(
      "figures     value [95%% interval] at the cluster time read; '<=' a 95%% upper bound\n"
      "            units: accel N m/s^2/sqrt(Hz), B m/s^2, K m/s^3/sqrt(Hz); gyro N "
      "rad/s/sqrt(Hz), B rad/s, K rad/s^2/sqrt(Hz)\n");
  std::printf("%-8s  %-40s  %-40s  %s\n", "axis", "N (white noise density)", "B (bias instability)",
              "K (rate random walk)");
  for (size_t k = 0; k < 6; ++k) {
    const core::AxisReadings& r = na->readings[k];
    std::printf("%-8s  %-40s  %-40s  %s\n", kAxes[k], Fig(r.noise_density).c_str(),
                Fig(r.bias_instability).c_str(), Fig(r.random_walk).c_str());
  }
  bool bounds = false;
  for (const auto& r : na->readings)
    bounds |=
        r.noise_density.upper_bound || r.bias_instability.upper_bound || r.random_walk.upper_bound;
  if (bounds) {
    std::printf(
        "note        '<=' figures are upper bounds, not measurements: the record is too short "
        "to reach them (B and K need minutes to hours at rest)\n");
  }
  for (const auto& n : na->figures.notes) std::printf("note        %s\n", n.c_str());
}

}  // namespace

int RunNoiseWith(const std::vector<std::string>& argv, const NoiseSessionReader& read_session) {
  auto a = ParseCommandFlags("noise", argv);
  if (!a.ok()) return Usage(std::string(a.status().message()));
  if (a->Has("help")) return std::printf("%s%s", kNoiseHelp, kImportFlagsHelp), kExitOk;
  const std::string rostopic = a->Get("rostopic").value_or("/imu0");
  if (absl::Status s = core::ValidateRosTopic(rostopic); !s.ok()) {
    return Usage("--rostopic: " + std::string(s.message()));
  }
  NoiseInput input;
  if (int code = ReadNoiseInput(*a, read_session, &input); code != kExitOk) return code;
  core::Capture* const capture = &input.capture;

  core::AccelParams accel;
  core::GyroParams gyro;
  if (int code = SignalToAnalyse(*a, &input, &accel, &gyro); code != kExitOk) return code;
  core::NoiseRest rest;
  core::NoiseAnalysis analysis;
  if (int code = AnalyseRest(*capture, accel, gyro, &rest, &analysis); code != kExitOk) return code;
  const core::NoiseAnalysis* const na = &analysis;

  const nlohmann::json json = NoiseJson(*na, input, RestJson(rest, *capture));
  if (auto dir = a->Get("out")) {
    std::error_code error;
    std::filesystem::create_directories(*dir, error);
    const std::filesystem::path d(*dir);
    nlohmann::json report = {{"allan", nlohmann::json::object()}};
    std::vector<nlohmann::json> ac, gc;
    for (size_t i = 0; i < na->curves.tau_s.size(); ++i) {
      const Eigen::Vector3d& va = na->curves.accel_m_s2[i];
      const Eigen::Vector3d& vg = na->curves.gyro_rad_s[i];
      ac.push_back({Num(va.x()), Num(va.y()), Num(va.z())});
      gc.push_back({Num(vg.x()), Num(vg.y()), Num(vg.z())});
    }
    report["allan"] = {{"tau", na->curves.tau_s}, {"accel", ac}, {"gyro", gc}};
    core::ParamSet fitted;
    fitted.noise = na->figures;
    report["parameters"] = nlohmann::json::parse(formats::ParamSetToJson(fitted));
    for (const auto& [name, text] :
         {std::pair<std::string, std::string>{"imu.yaml", KalibrImuYaml(*na, rostopic)},
          {"kalibr_imu_chain.yaml", OpenVinsNoiseYaml(*na, rostopic)},
          {"noise.json", json.dump(1) + "\n"}}) {
      if (absl::Status s = WriteFileDurably((d / name).string(), text); !s.ok())
        return ReportError(s);
      if (!a->Has("json")) std::printf("wrote       %s\n", (d / name).c_str());
    }
    auto plots = formats::WriteReportPlots(report, *dir);
    if (!plots.ok()) return ReportError(plots.status());
    if (!a->Has("json"))
      for (const auto& p : *plots) std::printf("wrote       %s\n", p.c_str());
  }
  if (a->Has("json")) {
    std::puts(json.dump(1).c_str());
    return kExitOk;
  }
  PrintNoiseText(*na, rest, input);
  return kExitOk;
}

}  // namespace imucal::cli
