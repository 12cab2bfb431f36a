#include "core/motion/learn.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"

namespace imucal::core::motion {
namespace {

// A block is applied only within 2 % of the rate it was learnt at (core/dynamic_gyro.h).
constexpr double kRateTolerance = 0.02;

std::vector<const FitRecording*> FitsOf(const std::vector<const PreparedRecording*>& set) {
  std::vector<const FitRecording*> fits;
  for (const PreparedRecording* p : set) fits.push_back(&p->fit);
  return fits;
}

double Aoe(const PreparedRecording& p, const ParamSet& params) {
  return CompareOrientation(*p.recording, p.fit.reference, CorrectedRates(*p.recording, params))
      .aoe_deg;
}

absl::Status CheckStart(const ParamSet& start) {
  if (!start.has_gyro || start.gyro_unit != GyroUnit::kRadPerSecond ||
      start.accel_unit != AccelUnit::kMetersPerSecond2) {
    return absl::InvalidArgumentError(
        "the static parameter set must take rad/s and m/s^2 (the recordings' units) and have "
        "a gyroscope");
  }
  return absl::OkStatus();
}

absl::Status CheckRates(const std::vector<const PreparedRecording*>& training) {
  std::vector<double> rates;
  for (const PreparedRecording* p : training) rates.push_back(p->fit.rate_hz);
  std::sort(rates.begin(), rates.end());
  const double median = rates[rates.size() / 2];
  for (const PreparedRecording* p : training) {
    if (std::abs(p->fit.rate_hz / median - 1.0) > kRateTolerance) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: IMU rate %.2f Hz, the other training recordings' %.2f Hz: one block is learnt "
          "at one rate",
          p->recording->name, p->fit.rate_hz, median));
    }
  }
  return absl::OkStatus();
}

// Leave one recording out: the held-out AOE of the static model and of the learnt one.
void LeaveOneOut(const std::vector<const PreparedRecording*>& training,
                 const std::optional<ParamSet>& start, const LearnOptions& options,
                 LearnResult* result) {
  const ParamSet begin = start ? *start : NominalParams();
  for (size_t out = 0; out < training.size(); ++out) {
    std::vector<const PreparedRecording*> rest;
    for (size_t i = 0; i < training.size(); ++i) {
      if (i != out) rest.push_back(training[i]);
    }
    const ModelFit stage1 = FitStatic(FitsOf(rest), begin, options.fit);
    const ModelFit learnt = FitDynamic(FitsOf(rest), stage1, options.fit);
    DynamicGyroRecording figure;
    figure.name = training[out]->recording->name;
    figure.sha256 = training[out]->recording->sha256;
    figure.duration_s = training[out]->recording->DurationS();
    figure.aoe_static_deg = Aoe(*training[out], start ? *start : stage1.params);
    figure.aoe_learnt_deg = Aoe(*training[out], learnt.params);
    result->held_out.push_back(figure);
  }
}

void Gate(const LearnOptions& options, LearnResult* result) {
  const HeldOutVerdict v = JudgeHeldOut(result->held_out, options.gate_margin);
  result->gate_passed = v.passed;
  result->gate_reason = v.reason;
}

DynamicGyroEnvelope EnvelopeOf(const std::vector<const PreparedRecording*>& training,
                               const ParamSet& params) {
  DynamicGyroEnvelope e;
  for (const PreparedRecording* p : training) {
    std::vector<Eigen::Vector3d> w_s, accel;
    StaticOutputs(*p->recording, params, &w_s, &accel);
    for (size_t k = 0; k < w_s.size(); ++k) {
      e.max_abs_rate_rad_s = e.max_abs_rate_rad_s.cwiseMax(w_s[k].cwiseAbs());
      e.max_abs_accel_m_s2 = e.max_abs_accel_m_s2.cwiseMax(accel[k].cwiseAbs());
    }
  }
  return e;
}

}  // namespace

ParamSet NominalParams() {
  ParamSet p;
  p.accel_unit = AccelUnit::kMetersPerSecond2;
  p.gyro_unit = GyroUnit::kRadPerSecond;
  return p;
}

absl::StatusOr<PreparedRecording> Prepare(const MotionRecording& recording,
                                          const LearnOptions& options) {
  absl::StatusOr<Alignment> alignment = EstimateAlignment(recording, options.align);
  if (!alignment.ok()) return alignment.status();
  PreparedRecording p;
  p.recording = &recording;
  p.alignment = *alignment;
  const AlignedReference reference = AlignReference(recording, p.alignment);
  const double duration = recording.DurationS();
  const double rate = duration > 0 ? static_cast<double>(recording.t_s.size() - 1) / duration : 0;
  std::vector<int> horizons = options.horizons_samples;
  for (double s : options.horizons_s) horizons.push_back(static_cast<int>(std::lround(s * rate)));
  std::sort(horizons.begin(), horizons.end());
  horizons.erase(std::unique(horizons.begin(), horizons.end()), horizons.end());
  std::erase_if(horizons,
                [&](int h) { return h < 1 || h >= static_cast<int>(recording.t_s.size()); });
  p.fit = PrepareFit(recording, reference, horizons, options.block_s);
  if (p.fit.windows.size() < 50) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the reference covers too little of the IMU stream (%d usable windows)",
                        recording.name, static_cast<int>(p.fit.windows.size())));
  }
  return p;
}

absl::StatusOr<LearnResult> Learn(const std::vector<const PreparedRecording*>& training,
                                  const std::optional<ParamSet>& start,
                                  const LearnOptions& options) {
  if (training.empty()) return absl::InvalidArgumentError("no training recording");
  const ParamSet begin = start ? *start : NominalParams();
  if (absl::Status s = CheckStart(begin); !s.ok()) return s;
  if (absl::Status s = CheckRates(training); !s.ok()) return s;
  LearnResult result;
  if (training.size() >= 2) LeaveOneOut(training, start, options, &result);
  Gate(options, &result);
  const ModelFit stage1 = FitStatic(FitsOf(training), begin, options.fit);
  result.candidate = FitDynamic(FitsOf(training), stage1, options.fit);
  result.static_params = start ? *start : stage1.params;
  result.notes = result.candidate.notes;
  DynamicGyro& block = *result.candidate.params.dynamic_gyro;
  block.envelope = EnvelopeOf(training, result.candidate.params);
  block.training = result.held_out;
  if (block.training.empty()) {
    for (const PreparedRecording* p : training) {
      block.training.push_back({p->recording->name, p->recording->sha256, p->recording->DurationS(),
                                std::nan(""), std::nan("")});
    }
  }
  block.gate_reason = result.gate_reason;
  result.learnt_params = result.gate_passed ? result.candidate.params : result.static_params;
  return result;
}

Evaluation Evaluate(const PreparedRecording& p, const LearnResult& result,
                    const LearnOptions& options) {
  Evaluation e;
  const MotionRecording& r = *p.recording;
  const AlignedReference& ref = p.fit.reference;
  ParamSet nominal = NominalParams();
  e.raw = CompareOrientation(r, ref, CorrectedRates(r, nominal));
  if (const auto bias = FirstRestBias(r, options.rest_s, &e.rest_note)) {
    nominal.gyro.bias = *bias;
    e.rest_bias = CompareOrientation(r, ref, CorrectedRates(r, nominal));
    e.has_rest = true;
  } else {
    e.rest_bias.aoe_deg = e.rest_bias.final_heading_deg = std::nan("");
  }
  e.static_model = CompareOrientation(r, ref, CorrectedRates(r, result.static_params));
  e.learnt =
      CompareOrientation(r, ref, CorrectedRates(r, result.learnt_params, &e.outside_envelope));
  return e;
}

HeldOutVerdict JudgeHeldOut(const std::vector<DynamicGyroRecording>& held_out, double gate_margin) {
  HeldOutVerdict out;
  if (held_out.size() < 2) {
    out.reason = "refused: leave-one-recording-out needs at least 2 training recordings";
    return out;
  }
  double mean_static = 0.0, mean_learnt = 0.0;
  std::string worse, figures;
  for (const DynamicGyroRecording& r : held_out) {
    mean_static += r.aoe_static_deg / static_cast<double>(held_out.size());
    mean_learnt += r.aoe_learnt_deg / static_cast<double>(held_out.size());
    figures += absl::StrFormat("%s%s %.3f -> %.3f", figures.empty() ? "" : ", ", r.name,
                               r.aoe_static_deg, r.aoe_learnt_deg);
    if (!(r.aoe_learnt_deg <= r.aoe_static_deg)) worse += (worse.empty() ? "" : ", ") + r.name;
  }
  const bool better = mean_learnt <= (1.0 - gate_margin) * mean_static;
  out.passed = better && worse.empty();
  const std::string verdict =
      out.passed ? "passed"
      : !better  ? absl::StrFormat("refused: the mean held-out AOE does not fall by %.0f%%",
                                   100 * gate_margin)
                 : "refused: worse than the static model on " + worse;
  out.reason = absl::StrFormat(
      "%s (leave-one-recording-out AOE, static -> learnt, deg: %s; mean %.3f -> %.3f)", verdict,
      figures, mean_static, mean_learnt);
  return out;
}

}  // namespace imucal::core::motion
