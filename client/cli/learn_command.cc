// `imucal learn --train REC... --test REC... [--params static.json] --out P.json [--json]
// [--plots DIR]`: a dynamic gyro block learnt from recordings with a reference orientation
// (issue 27; core/motion/learn.h), gated on held-out recordings, and the orientation error of
// raw, rest-bias, static and learnt gyro on every test recording.
#include <openssl/evp.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "client/cli/command_table.h"
#include "client/cli/commands.h"
#include "core/motion/learn.h"
#include "formats/params_json.h"
#include "formats/plots.h"
#include "importers/reference.h"
#include "nlohmann/json.hpp"
#include "util/file.h"
#include "util/parallel.h"

namespace imucal::cli {
namespace {

constexpr char kLearnHelp[] =
    "usage: imucal learn --train REC... --test REC... [--params static.json] --out P.json\n"
    "                    [--json] [--plots DIR]\n"
    "  Learns the gyroscope's dynamic block (delay, odd rate non-linearity, a linear dilated\n"
    "  filter; docs/motion.md) with the static matrix, bias and g-terms in motion, from\n"
    "  recordings with a reference orientation. The block is kept only if it beats the static\n"
    "  model on training recordings it was not fitted on (leave one out); else --out holds the\n"
    "  static result and the output says why. For every test recording it prints the absolute\n"
    "  orientation error (AOE, RMS, deg) and the final heading error (deg) of: the raw gyro, the\n"
    "  bias of the first rest, the static model and the learnt one.\n"
    "  REC: IMU_FILE:REFERENCE_FILE (IMU: TUM-VI/ROS CSV or EuRoC imu0/data.csv; reference:\n"
    "  TUM-VI/ROS CSV, EuRoC mocap0 or state_groundtruth_estimate0, or the TUM trajectory\n"
    "  format 't tx ty tz qx qy qz qw') or an EuRoC/ASL directory.\n"
    "options:\n"
    "  --train REC...   the recordings to learn from (2 or more for the gate)\n"
    "  --test REC...    the recordings to report on (none may be a training one)\n"
    "  --params P       the static parameter set to start from (rad/s, m/s^2); default nominal\n"
    "  --out P.json     the parameter set learnt (the static one where the gate refused)\n"
    "  --json           print one JSON object instead of the table\n"
    "  --plots DIR      orientation error over time per test recording (SVG)\n";

int LearnUsage(const std::string& message) {
  std::fprintf(stderr, "imucal learn: %s\n\n%s", message.c_str(), kLearnHelp);
  return kExitUsage;
}

// `--train A B --test C` -> `--train A --train B --test C` (the parser takes one value a flag).
std::vector<std::string> SpreadLists(const std::vector<std::string>& argv) {
  std::vector<std::string> out;
  std::string list;
  for (const std::string& a : argv) {
    if (a == "--train" || a == "--test") {
      list = a;
      continue;
    }
    if (a.starts_with("-")) list.clear();
    if (!list.empty()) out.push_back(list);
    out.push_back(a);
  }
  return out;
}

std::string Sha256Hex(const std::string& a, const std::string& b) {
  EVP_MD_CTX* ctx = EVP_MD_CTX_new();
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int length = 0;
  EVP_DigestInit_ex(ctx, EVP_sha256(), nullptr);
  EVP_DigestUpdate(ctx, a.data(), a.size());
  EVP_DigestUpdate(ctx, b.data(), b.size());
  EVP_DigestFinal_ex(ctx, digest, &length);
  EVP_MD_CTX_free(ctx);
  std::string hex;
  for (unsigned int i = 0; i < length; ++i) hex += absl::StrFormat("%02x", digest[i]);
  return hex;
}

absl::StatusOr<core::motion::MotionRecording> Read(const std::string& spec) {
  absl::StatusOr<core::motion::MotionRecording> r = importers::ReadMotionRecording(spec);
  if (!r.ok()) return r;
  absl::StatusOr<std::string> imu = ReadFileBytes(r->imu_path);
  absl::StatusOr<std::string> ref = ReadFileBytes(r->reference_path);
  if (!imu.ok()) return imu.status();
  if (!ref.ok()) return ref.status();
  r->sha256 = Sha256Hex(*imu, *ref);
  return r;
}

nlohmann::json Figures(const core::motion::Evaluation& e, bool aoe) {
  const auto pick = [&](const core::motion::OrientationError& o) -> nlohmann::json {
    const double v = aoe ? o.aoe_deg : o.final_heading_deg;
    return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
  };
  return {{"raw", pick(e.raw)},
          {"rest_bias", pick(e.rest_bias)},
          {"static", pick(e.static_model)},
          {"learnt", pick(e.learnt)}};
}

absl::Status WritePlot(const std::string& dir, size_t index, const std::string& name,
                       const core::motion::Evaluation& e) {
  formats::Plot plot;
  plot.title = "orientation error, " + name;
  plot.x_label = "time (s)";
  plot.y_label = "orientation error (deg)";
  plot.caption = "angle between the integrated gyro and the reference; lower is better";
  const struct {
    const char* label;
    const core::motion::OrientationError* o;
    const char* colour;
  } series[] = {{"raw", &e.raw, "#7f7f7f"},
                {"rest bias", &e.rest_bias, "#ff7f0e"},
                {"static", &e.static_model, "#1f77b4"},
                {"learnt", &e.learnt, "#2ca02c"}};
  for (const auto& s : series) {
    if (s.o->t_s.empty()) continue;
    formats::PlotSeries ps{.label = s.label, .colour = s.colour, .line = true};
    const size_t stride = std::max<size_t>(1, s.o->t_s.size() / 1500);
    for (size_t k = 0; k < s.o->t_s.size(); k += stride) {
      ps.x.push_back(s.o->t_s[k]);
      ps.y.push_back(s.o->error_deg[k]);
    }
    plot.series.push_back(ps);
  }
  std::error_code error;
  std::filesystem::create_directories(dir, error);
  const std::string file =
      absl::StrFormat("%s/orientation_error_%d_%s.svg", dir, static_cast<int>(index + 1),
                      std::filesystem::path(name.substr(0, name.find(':'))).stem().string());
  return WriteFileDurably(file, formats::RenderSvg(plot));
}

void PrintTable(const std::vector<std::string>& names,
                const std::vector<core::motion::Evaluation>& evals) {
  std::printf("%-40s %28s   %28s\n", "", "AOE (deg)", "final heading (deg)");
  std::printf("%-40s %6s %6s %6s %6s   %6s %6s %6s %6s\n", "test recording", "raw", "rest",
              "static", "learnt", "raw", "rest", "static", "learnt");
  for (size_t i = 0; i < evals.size(); ++i) {
    const core::motion::Evaluation& e = evals[i];
    std::string n = names[i];
    if (n.size() > 40) n = "..." + n.substr(n.size() - 37);
    std::printf("%-40s %6.2f %6.2f %6.2f %6.2f   %6.2f %6.2f %6.2f %6.2f\n", n.c_str(),
                e.raw.aoe_deg, e.rest_bias.aoe_deg, e.static_model.aoe_deg, e.learnt.aoe_deg,
                e.raw.final_heading_deg, e.rest_bias.final_heading_deg,
                e.static_model.final_heading_deg, e.learnt.final_heading_deg);
    if (!e.has_rest) std::printf("  %s: rest bias: %s\n", names[i].c_str(), e.rest_note.c_str());
    if (e.outside_envelope > 0) {
      std::printf("  %s: %d samples outside the block's training envelope\n", names[i].c_str(),
                  e.outside_envelope);
    }
  }
}

void PrintLearnt(const std::vector<core::motion::PreparedRecording>& prepared,
                 const core::motion::LearnResult& result) {
  for (const core::motion::PreparedRecording& p : prepared) {
    std::printf("aligned %s: %s\n", p.recording->name.c_str(), p.alignment.summary.c_str());
  }
  const core::DynamicGyro& b = *result.candidate.params.dynamic_gyro;
  std::printf(
      "learnt: delay %.3f +- %.3f ms, odd rate (%.3g, %.3g, %.3g) +- (%.2g, %.2g, %.2g) "
      "1/(rad/s), filter %d taps x %d (ridge %g)\n",
      1e3 * b.delay_s, 1e3 * b.delay_std_error_s, b.odd_rate(0), b.odd_rate(1), b.odd_rate(2),
      b.odd_rate_std_error(0), b.odd_rate_std_error(1), b.odd_rate_std_error(2), b.taps, b.dilation,
      b.ridge_lambda);
  for (const std::string& note : result.notes) std::printf("  %s\n", note.c_str());
  std::printf("gate: %s\n", result.gate_reason.c_str());
}

int RunLearnOn(const std::vector<core::motion::MotionRecording>& recordings, size_t train_count,
               const std::optional<core::ParamSet>& start, const Args& a) {
  core::motion::LearnOptions options;
  options.fit.threads = DefaultThreads();
  std::vector<core::motion::PreparedRecording> prepared;
  for (const core::motion::MotionRecording& r : recordings) {
    auto p = core::motion::Prepare(r, options);
    if (!p.ok()) return ReportError(p.status());
    prepared.push_back(std::move(*p));
  }
  std::vector<const core::motion::PreparedRecording*> train;
  for (size_t i = 0; i < train_count; ++i) train.push_back(&prepared[i]);
  auto result = core::motion::Learn(train, start, options);
  if (!result.ok()) return ReportError(result.status());
  std::vector<core::motion::Evaluation> evals;
  std::vector<std::string> names;
  for (size_t i = train_count; i < prepared.size(); ++i) {
    evals.push_back(core::motion::Evaluate(prepared[i], *result, options));
    names.push_back(recordings[i].name);
  }
  core::ParamSet out = result->learnt_params;
  out.software = "imucal " IMUCAL_VERSION " learn";
  if (absl::Status s = WriteFileDurably(*a.Get("out"), formats::ParamSetToJson(out)); !s.ok()) {
    return ReportError(s);
  }
  if (auto dir = a.Get("plots")) {
    for (size_t i = 0; i < evals.size(); ++i) {
      if (absl::Status s = WritePlot(*dir, i, names[i], evals[i]); !s.ok()) return ReportError(s);
    }
  }
  if (a.Has("json")) {
    nlohmann::json j = {
        {"gate", {{"passed", result->gate_passed}, {"reason", result->gate_reason}}},
        {"test", nlohmann::json::array()}};
    for (size_t i = 0; i < evals.size(); ++i) {
      j["test"].push_back({{"recording", names[i]},
                           {"aoe_deg", Figures(evals[i], true)},
                           {"final_heading_deg", Figures(evals[i], false)}});
    }
    std::printf("%s\n", j.dump(1).c_str());
    return kExitOk;
  }
  PrintLearnt(prepared, *result);
  PrintTable(names, evals);
  std::printf("wrote %s (%s)\n", a.Get("out")->c_str(),
              result->gate_passed ? "static model and the learnt block" : "the static model");
  return kExitOk;
}

}  // namespace

int RunLearn(const std::vector<std::string>& argv) {
  auto a = ParseCommandFlags("learn", SpreadLists(argv));
  if (!a.ok()) return LearnUsage(std::string(a.status().message()));
  if (a->Has("help")) return std::printf("%s", kLearnHelp), kExitOk;
  const std::vector<std::string> train_specs = a->GetAll("train");
  const std::vector<std::string> test_specs = a->GetAll("test");
  if (train_specs.empty()) return LearnUsage("learn needs --train REC...");
  if (!a->Get("out")) return LearnUsage("learn needs --out P.json");
  if (!a->positional().empty()) return LearnUsage("unexpected '" + a->positional()[0] + "'");
  std::optional<core::ParamSet> start;
  if (auto path = a->Get("params")) {
    absl::StatusOr<std::string> text = ReadFileBytes(*path);
    if (!text.ok()) return ReportError(text.status());
    absl::StatusOr<core::ParamSet> p = formats::ParamSetFromJson(*text);
    if (!p.ok()) {
      return ReportError(
          absl::InvalidArgumentError(*path + ": " + std::string(p.status().message())));
    }
    start = *p;
  }
  std::vector<core::motion::MotionRecording> recordings;
  for (const std::string& spec : train_specs) {
    auto r = Read(spec);
    if (!r.ok()) return ReportError(r.status());
    recordings.push_back(std::move(*r));
  }
  for (const std::string& spec : test_specs) {
    auto r = Read(spec);
    if (!r.ok()) return ReportError(r.status());
    for (size_t i = 0; i < train_specs.size(); ++i) {
      if (recordings[i].sha256 == r->sha256) {
        return ReportError(absl::InvalidArgumentError(absl::StrFormat(
            "test recording '%s' is also in the training set (as '%s'): a held-out figure "
            "needs a recording the block never saw",
            spec, train_specs[i])));
      }
    }
    recordings.push_back(std::move(*r));
  }
  return RunLearnOn(recordings, train_specs.size(), start, *a);
}

}  // namespace imucal::cli
