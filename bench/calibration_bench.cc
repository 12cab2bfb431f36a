// The accuracy and speed figures for the accelerometer stages and the whole pipeline.
//
//   1. BSAS vs LM: over many seeds of simulated six-face + 24 extra poses captures,
//      a. Calibrate() with and without the BSAS stage (same poses, same quadratic selection):
//         parameter error against the simulated truth, final LM residual, time;
//      b. the stages alone from the same stage-1 start, on poses built from the simulator's known
//         holds: LM alone, BSAS alone (no LM after it), BSAS then LM.
//   2. The real Xsens capture of IMU-TK (both sensors): Calibrate() time and the four figures
//      IMU-TK's authors report, for comparison with its 0.85 s.
// Errors are compared on the 12 magnitude parameters only: frame_angles are a gauge of the
// magnitude model (core/model.h). Tables print first, then Google Benchmark times the runs.
//
// Usage: calibration_bench [--seeds=N] [--skip_tables] [--benchmark_* flags]
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Dense"
#include "absl/strings/str_format.h"
#include "bench/bench_flags.h"
#include "benchmark/benchmark.h"
#include "core/accel_solver.h"
#include "core/calibrate/accel_stage.h"
#include "core/calibrate/calibrate.h"
#include "core/crb.h"
#include "core/model.h"
#include "core/simulator.h"
#include "importers/registry.h"

namespace imucal::core {
namespace {

constexpr int kDefaultSeeds = 50;
constexpr double kTrimS = 0.3;  // trimmed from each side of a known hold (the moves' ramps)
constexpr double kXsensGravity = 9.81744;  // IMU-TK authors' local gravity (SOURCE.txt)
// Display units per group: bias mm/s^2, scale ppm, tri urad, quadratic 1e-6 /(m/s^2).
constexpr std::array<double, 4> kDisplay = {1e3, 1e6, 1e6, 1e6};
constexpr const char* kDisplayUnits = "bias mm/s^2, scale ppm, tri urad, quad 1e-6/(m/s^2)";

double Ms(std::chrono::steady_clock::time_point t0) {
  return 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

SimOptions BenchSimOptions(uint64_t seed) {
  SimOptions o;
  o.protocol = SimProtocol::kSixFace;
  o.extra_poses = 24;
  o.seed = seed;
  return o;
}

// Sum of squared errors per parameter group (3 axes each).
std::array<double, 4> GroupSquaredErrors(const AccelParams& estimate, const AccelParams& truth) {
  const AccelVector e = PackAccel(estimate) - PackAccel(truth);
  std::array<double, 4> out{};
  for (int c = 0; c < kAccelParams; ++c) out[static_cast<size_t>(c / 3)] += e(c) * e(c);
  return out;
}

// Running sums of one method over the seeds.
struct Tally {
  std::array<double, 4> sq{};  // squared parameter errors, summed
  double cost = 0, rms = 0, evaluations = 0, ms = 0;
  int runs = 0;
  std::vector<double> ms_all;

  void Add(const AccelParams& estimate, const AccelParams& truth, double cost_value,
           double rms_value, double evals, double ms_value) {
    const std::array<double, 4> e = GroupSquaredErrors(estimate, truth);
    for (size_t g = 0; g < 4; ++g) sq[g] += e[g];
    cost += cost_value;
    rms += rms_value;
    evaluations += evals;
    ms += ms_value;
    ms_all.push_back(ms_value);
    ++runs;
  }
  // RMS over seeds and axes, in display units.
  double GroupRms(size_t g) const { return kDisplay[g] * std::sqrt(sq[g] / (3.0 * runs)); }
  double Mean(double sum) const { return sum / runs; }
  double MedianMs() const {
    std::vector<double> v = ms_all;
    std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
    return v[v.size() / 2];
  }
};

// ---------------------------------------------------------------------------------------------
// 1a. The pipeline with and without BSAS.

double StageMs(const CalibrationReport& r, std::string_view name) {
  for (const StageReport& st : r.stages)
    if (st.name == name) return st.ms;
  return 0;
}

struct PipelineSummary {
  double max_diff_se = 0;  // max over seeds and parameters of |with - without| / stderr
  double with_ms = 0, without_ms = 0;
};

PipelineSummary PrintPipelineComparison(int seeds) {
  Tally with, without;
  double with_bsas_ms = 0, with_lm_ms = 0, without_lm_ms = 0;
  int failures = 0, quadratics_held = 0;
  PipelineSummary out;
  for (int s = 1; s <= seeds; ++s) {
    const auto sim = Simulate(BenchSimOptions(static_cast<uint64_t>(s)));
    if (!sim.ok()) {
      ++failures;
      continue;
    }
    CalibrateOptions opt;
    opt.seed = static_cast<uint64_t>(s);
    opt.use_bsas = true;
    const auto a = Calibrate(sim->capture, opt);
    opt.use_bsas = false;
    const auto b = Calibrate(sim->capture, opt);
    if (!a.ok() || !b.ok()) {
      ++failures;
      continue;
    }
    const AccelParams& truth = sim->truth.accel;
    with.Add(a->params.accel, truth, 0, a->stages.back().accel_rms_m_s2, 0, a->total_ms);
    without.Add(b->params.accel, truth, 0, b->stages.back().accel_rms_m_s2, 0, b->total_ms);
    with_bsas_ms += StageMs(*a, "bsas");
    with_lm_ms += StageMs(*a, "lm");
    without_lm_ms += StageMs(*b, "lm");
    const AccelVector se = PackAccel(a->params.stderrs.accel);
    const AccelVector d = PackAccel(a->params.accel) - PackAccel(b->params.accel);
    for (int c = 0; c < kAccelParams; ++c) {
      if (std::isfinite(se(c)) && se(c) > 0) {
        out.max_diff_se = std::max(out.max_diff_se, std::abs(d(c)) / se(c));
      }
      if (c >= 9 && !std::isfinite(se(c))) ++quadratics_held;
    }
  }
  std::printf(
      "\n1a. Calibrate() with and without BSAS: six-face + 24 extra poses, %d seeds (%d failed)\n"
      "    parameter error = RMS over seeds and axes of (estimate - truth); %s\n",
      seeds, failures, kDisplayUnits);
  std::printf("    %-12s %8s %8s %8s %8s %11s %9s %9s %9s %9s\n", "pipeline", "bias", "scale",
              "tri", "quad", "LM rms mg", "total ms", "median", "bsas ms", "lm ms");
  std::printf("    %-12s %8.3f %8.1f %8.1f %8.2f %11.5f %9.1f %9.1f %9.2f %9.2f\n", "ls+bsas+lm",
              with.GroupRms(0), with.GroupRms(1), with.GroupRms(2), with.GroupRms(3),
              1e3 / kStandardGravity * with.Mean(with.rms), with.Mean(with.ms), with.MedianMs(),
              with.Mean(with_bsas_ms), with.Mean(with_lm_ms));
  std::printf("    %-12s %8.3f %8.1f %8.1f %8.2f %11.5f %9.1f %9.1f %9s %9.2f\n", "ls+lm",
              without.GroupRms(0), without.GroupRms(1), without.GroupRms(2), without.GroupRms(3),
              1e3 / kStandardGravity * without.Mean(without.rms), without.Mean(without.ms),
              without.MedianMs(), "-", without.Mean(without_lm_ms));
  std::printf(
      "    max over seeds and parameters of |with - without| / reported stderr: %.2e\n"
      "    quadratic terms held at 0 by the PRESS selection: %d of %d (same mask in both runs; a "
      "held term's error is |truth|)\n",
      out.max_diff_se, quadratics_held, 3 * with.runs);
  out.with_ms = with.Mean(with.ms);
  out.without_ms = without.Mean(without.ms);
  return out;
}

// ---------------------------------------------------------------------------------------------
// 1b. The stages alone from the same start, on poses from the simulator's known holds.

// The mean raw reading of each known hold, trimmed by kTrimS on each side.
std::vector<AccelPose> KnownHoldPoses(const SimResult& sim) {
  std::vector<AccelPose> out;
  const Capture& cap = sim.capture;
  for (const SimPose& hold : sim.poses) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero(), sum_sq = Eigen::Vector3d::Zero();
    double n = 0;
    for (size_t k = 0; k < cap.size(); ++k) {
      if (cap.t_s[k] < hold.t_start_s + kTrimS || cap.t_s[k] > hold.t_end_s - kTrimS) continue;
      sum += cap.accel[k];
      sum_sq += cap.accel[k].cwiseAbs2();
      ++n;
    }
    AccelPose p;
    p.mean = sum / n;
    const Eigen::Vector3d var = ((sum_sq - n * p.mean.cwiseAbs2()) / (n - 1)).cwiseMax(0.0);
    p.mean_std = var.cwiseSqrt() / std::sqrt(n);
    out.push_back(p);
  }
  return out;
}

// Stage 1 as Calibrate does it for six-face: each face's pair of poses (face, face turned 180
// degrees) averaged against +-g on the face axis (seeds/000).
absl::StatusOr<AccelParams> SixFaceStageOne(const SimResult& sim,
                                            const std::vector<AccelPose>& poses, double g) {
  std::vector<Eigen::Vector3d> means, refs;
  for (size_t i = 0; i < sim.poses.size(); ++i) {
    const std::string& label = sim.poses[i].label;
    if (label.size() != 2 || i + 1 >= sim.poses.size() ||
        sim.poses[i + 1].label != label + " turned") {
      continue;
    }
    Eigen::Vector3d ref = Eigen::Vector3d::Zero();
    ref(label[0] - 'X') = (label[1] == '+' ? 1.0 : -1.0) * g;
    means.push_back(0.5 * (poses[i].mean + poses[i + 1].mean));
    refs.push_back(ref);
  }
  return FitKnownReferences(means, refs);
}

// sum_i (r_i / sigma_i)^2 with sigma_i at the start: the cost both BSAS and LM minimise.
double WeightedCost(const AccelParams& p, const std::vector<AccelPose>& poses,
                    const std::vector<double>& sigma, double g) {
  const std::vector<double> r = MagnitudeResiduals(p, poses, g);
  double s = 0;
  for (size_t i = 0; i < r.size(); ++i) s += (r[i] / sigma[i]) * (r[i] / sigma[i]);
  return s;
}

// One seed's stage problem: the poses, the stage-1 start and what the pipeline would free.
struct StageProblem {
  SimResult sim;
  std::vector<AccelPose> poses;
  AccelParams start;
  AccelMask free{};
  AccelVector unit;
  double g = kStandardGravity;
  double tau = 0;  // the model sigma fitted at stage 1, as Calibrate fits it
};

std::optional<StageProblem> MakeStageProblem(uint64_t seed) {
  auto sim = Simulate(BenchSimOptions(seed));
  if (!sim.ok()) return std::nullopt;
  StageProblem p;
  p.sim = *std::move(sim);
  p.g = p.sim.capture.gravity_m_s2;
  p.poses = KnownHoldPoses(p.sim);
  const auto s1 = SixFaceStageOne(p.sim, p.poses, p.g);
  if (!s1.ok()) return std::nullopt;
  p.start = *s1;
  pipeline::SetModelSigma(p.start, p.g, MaskOf(kAccelFirstOrder), {}, &p.poses);  // as Calibrate does
  p.tau = p.poses.empty() ? 0.0 : p.poses.front().model_sigma_m_s2;
  AccelMask all{};
  all.fill(true);
  p.free = AnalyseAccelObservability(p.start, p.poses, p.g, all).determined;
  p.unit = pipeline::StageOneUnits(p.start, p.poses, p.free);  // as Calibrate chooses them
  return p;
}

struct StageSummary {
  Tally stage1, lm, bsas, bsas_lm;
  std::array<double, 4> crb_sq{};  // squared Cramer-Rao bounds, summed like Tally::sq
  int bsas_worse = 0;              // seeds where BSAS alone ended above the LM cost
  double worst_excess = 0;
};

StageSummary PrintStageComparison(int seeds) {
  StageSummary out;
  int failures = 0, not_all_free = 0;
  double tau_sum = 0;
  for (int s = 1; s <= seeds; ++s) {
    const auto p = MakeStageProblem(static_cast<uint64_t>(s));
    if (p) tau_sum += p->tau;
    if (!p) {
      ++failures;
      continue;
    }
    const AccelParams& truth = p->sim.truth.accel;
    const std::vector<double> sigma = MagnitudeSigmas(p->start, p->poses);
    auto cost = [&](const AccelParams& a) { return WeightedCost(a, p->poses, sigma, p->g); };

    StageReport lm_rep, bsas_rep, lm2_rep;
    const auto lm_fit = RefineAccelLm(p->start, p->poses, p->g, p->free, &lm_rep);
    const AccelParams bsas_fit =
        RefineAccelBsas(p->start, p->poses, p->g, p->free, p->unit,
                        BsasStageOptions{.seed = static_cast<uint64_t>(s)}, &bsas_rep);
    const auto bsas_lm_fit = RefineAccelLm(bsas_fit, p->poses, p->g, p->free, &lm2_rep);
    if (!lm_fit.ok() || !bsas_lm_fit.ok()) {
      ++failures;
      continue;
    }
    not_all_free += std::count(p->free.begin(), p->free.end(), false) > 0;
    const double lm_cost = cost(lm_fit->params), bsas_cost = cost(bsas_fit);
    out.stage1.Add(p->start, truth, cost(p->start), 0, 0, 0);
    out.lm.Add(lm_fit->params, truth, lm_cost, 0, lm_rep.evaluations, lm_rep.ms);
    out.bsas.Add(bsas_fit, truth, bsas_cost, 0, bsas_rep.evaluations, bsas_rep.ms);
    out.bsas_lm.Add(bsas_lm_fit->params, truth, cost(bsas_lm_fit->params), 0,
                    bsas_rep.evaluations + lm2_rep.evaluations, bsas_rep.ms + lm2_rep.ms);
    out.bsas_worse += bsas_cost > lm_cost * (1 + 1e-9);
    out.worst_excess = std::max(out.worst_excess, bsas_cost - lm_cost);
    // The bound at the truth (pose noise only), for scale.
    const AccelVector bound = AccelCramerRaoStd(truth, p->poses, p->g, p->free);
    for (int c = 0; c < kAccelParams; ++c) {
      if (std::isfinite(bound(c))) out.crb_sq[static_cast<size_t>(c / 3)] += bound(c) * bound(c);
    }
  }
  const int runs = out.lm.runs;
  std::printf(
      "\n1b. The stages alone from the six-face stage-1 start, poses from the simulator's known "
      "holds\n    (trimmed %.1f s each side, mean_std = sample std / sqrt(n)); %d seeds (%d "
      "failed, %d with a parameter not determined)\n"
      "    cost = sum (r_i/sigma_i)^2 over 36 poses, sigma_i = MagnitudeSigmas at the start: pose "
      "noise (+) the stage-1\n    model sigma tau (mean %.2f mg), as Calibrate weights; "
      "parameter error RMS over seeds and axes; %s\n",
      kTrimS, seeds, failures, not_all_free, 1e3 / kStandardGravity * tau_sum / seeds,
      kDisplayUnits);
  std::printf("    %-16s %10s %8s %8s %8s %8s %9s %9s %9s\n", "method", "mean cost", "bias",
              "scale", "tri", "quad", "evals", "mean ms", "med ms");
  const std::array<std::pair<const char*, const Tally*>, 4> rows = {
      {{"stage-1 (start)", &out.stage1},
       {"LM alone", &out.lm},
       {"BSAS alone", &out.bsas},
       {"BSAS then LM", &out.bsas_lm}}};
  for (const auto& [name, t] : rows) {
    std::printf("    %-16s %10.2f %8.3f %8.1f %8.1f %8.2f %9.0f %9.3f %9.3f\n", name,
                t->Mean(t->cost), t->GroupRms(0), t->GroupRms(1), t->GroupRms(2), t->GroupRms(3),
                t->Mean(t->evaluations), t->Mean(t->ms), t->MedianMs());
  }
  std::printf("    %-16s %10s", "CRB (RMS)", "");
  for (size_t g = 0; g < 4; ++g) {
    std::printf(" %8.*f",
                g == 0   ? 3
                : g == 3 ? 2
                         : 1,
                kDisplay[g] * std::sqrt(out.crb_sq[g] / (3.0 * runs)));
  }
  std::printf(
      "\n    BSAS alone ended above the LM cost in %d of %d seeds (worst excess %.3g cost "
      "units)\n",
      out.bsas_worse, runs, out.worst_excess);
  return out;
}

void PrintConclusion(const PipelineSummary& pipe, const StageSummary& st) {
  const Tally& lm = st.lm;
  const Tally& bs = st.bsas;
  // BSAS alone's parameter error relative to LM's, worst and best group.
  double worst_group = 0, best_group = 1e300;
  for (size_t g = 0; g < 4; ++g) {
    worst_group = std::max(worst_group, bs.GroupRms(g) / lm.GroupRms(g));
    best_group = std::min(best_group, bs.GroupRms(g) / lm.GroupRms(g));
  }
  std::printf(
      "\nConclusion: LM alone reaches the weighted-cost minimum (mean %.2f) in %.0f evaluations "
      "and %.2f ms; BSAS alone ends at mean cost %.2f (above LM in %d of %d seeds) after %.0f "
      "evaluations and %.1f ms, with parameter errors %.2f-%.2fx LM's; BSAS before LM changes "
      "the pipeline's final parameters by at most %.1e stderr and adds %.1f ms to Calibrate(). "
      "%s\n",
      lm.Mean(lm.cost), lm.Mean(lm.evaluations), lm.Mean(lm.ms), bs.Mean(bs.cost), st.bsas_worse,
      lm.runs, bs.Mean(bs.evaluations), bs.Mean(bs.ms), best_group, worst_group, pipe.max_diff_se,
      pipe.with_ms - pipe.without_ms,
      st.bsas_worse == lm.runs && best_group >= 1 && pipe.max_diff_se < 0.1
          ? "LM wins on cost, accuracy and time; BSAS buys nothing on these well-started captures."
          : "BSAS changed the result or beat LM on some seeds: read the table before choosing.");
}

// ---------------------------------------------------------------------------------------------
// 2. The Xsens capture of IMU-TK.

std::string XsensDir() { return std::string(IMUCAL_SHARED_DIR) + "/data/real/xsens-imutk"; }

bool HaveXsens() {
  return std::filesystem::exists(XsensDir() + "/xsens_acc.mat") &&
         std::filesystem::exists(XsensDir() + "/xsens_gyro.mat");
}

absl::StatusOr<Capture> ImportXsens() {
  importers::ImportOptions io;
  io.gravity_m_s2 = kXsensGravity;
  return importers::ImportCapture({XsensDir() + "/xsens_acc.mat", XsensDir() + "/xsens_gyro.mat"},
                                  io);
}

void PrintXsens() {
  std::printf("\n2. Real Xsens capture (IMU-TK test data), g = %.5f m/s^2\n", kXsensGravity);
  if (!HaveXsens()) {
    std::printf("    skipped: %s not found\n", XsensDir().c_str());
    return;
  }
  const auto t0 = std::chrono::steady_clock::now();
  const auto cap = ImportXsens();
  const double import_ms = Ms(t0);
  if (!cap.ok()) {
    std::printf("    import failed: %s\n", std::string(cap.status().message()).c_str());
    return;
  }
  for (const bool use_bsas : {true, false}) {
    CalibrateOptions opt;
    opt.use_bsas = use_bsas;
    const auto rep = Calibrate(*cap, opt);
    if (!rep.ok()) {
      std::printf("    calibrate failed: %s\n", std::string(rep.status().message()).c_str());
      return;
    }
    int used = 0;
    for (const PoseReport& p : rep->poses) used += p.interval.used;
    const double ug = 1e6 / kXsensGravity;
    const Residuals& r = rep->residual;
    std::printf(
        "    use_bsas=%d: %zu samples, import %.1f ms, Calibrate %.1f ms (one run; see "
        "BM_Xsens* below), verdict %s, protocol %s\n"
        "      static intervals used       %d of %zu (threshold x%.0f)\n"
        "      |a|-g in-sample             RMS %.1f ug, max %.1f ug\n"
        "      |a|-g held-out (LOO)        RMS %.1f ug, max %.1f ug\n"
        "      gravity direction in-sample RMS %.3f deg, max %.3f deg (after each move)\n"
        "      gravity direction held-out  RMS %.3f deg, max %.3f deg\n",
        use_bsas, cap->size(), import_ms, rep->total_ms,
        std::string(VerdictName(rep->verdict)).c_str(),
        std::string(ProtocolKindName(rep->protocol)).c_str(), used, rep->poses.size(),
        rep->threshold_multiplier, ug * r.accel_rms_m_s2, ug * r.accel_max_m_s2,
        ug * r.accel_heldout_rms_m_s2, ug * r.accel_heldout_max_m_s2, r.move_rms_deg,
        r.move_max_deg, r.move_heldout_rms_deg, r.move_heldout_max_deg);
  }
}

// ---------------------------------------------------------------------------------------------
// Google Benchmark timings.

const SimResult& BenchCapture() {
  static const SimResult* const kSim = new SimResult(*Simulate(BenchSimOptions(1)));
  return *kSim;
}

void BM_CalibrateSimulated(benchmark::State& state) {
  const SimResult& sim = BenchCapture();
  CalibrateOptions opt;
  opt.use_bsas = state.range(0) != 0;
  for (auto _ : state) {
    auto rep = Calibrate(sim.capture, opt);
    benchmark::DoNotOptimize(rep);
  }
}
BENCHMARK(BM_CalibrateSimulated)
    ->ArgName("use_bsas")
    ->Arg(1)
    ->Arg(0)
    ->Unit(benchmark::kMillisecond);

const StageProblem& BenchStageProblem() {
  static const StageProblem* const kProblem = new StageProblem(*MakeStageProblem(1));
  return *kProblem;
}

void BM_StageLm(benchmark::State& state) {
  const StageProblem& p = BenchStageProblem();
  for (auto _ : state) {
    auto fit = RefineAccelLm(p.start, p.poses, p.g, p.free, nullptr);
    benchmark::DoNotOptimize(fit);
  }
}
BENCHMARK(BM_StageLm)->Unit(benchmark::kMillisecond);

void BM_StageBsas(benchmark::State& state) {
  const StageProblem& p = BenchStageProblem();
  for (auto _ : state) {
    auto fit = RefineAccelBsas(p.start, p.poses, p.g, p.free, p.unit, BsasStageOptions{}, nullptr);
    benchmark::DoNotOptimize(fit);
  }
}
BENCHMARK(BM_StageBsas)->Unit(benchmark::kMillisecond);

const Capture* XsensCapture() {
  static const Capture* const kCapture = [] {
    if (!HaveXsens()) return static_cast<Capture*>(nullptr);
    auto cap = ImportXsens();
    return cap.ok() ? new Capture(*std::move(cap)) : nullptr;
  }();
  return kCapture;
}

// Calibrate() on the imported capture (both sensors, held-out refits included).
void BM_XsensCalibrate(benchmark::State& state) {
  const Capture* cap = XsensCapture();
  if (!cap) {
    state.SkipWithError("Xsens capture not available");
    return;
  }
  CalibrateOptions opt;
  opt.use_bsas = state.range(0) != 0;
  for (auto _ : state) {
    auto rep = Calibrate(*cap, opt);
    benchmark::DoNotOptimize(rep);
  }
}
BENCHMARK(BM_XsensCalibrate)
    ->ArgName("use_bsas")
    ->Arg(1)
    ->Arg(0)
    ->Unit(benchmark::kMillisecond)
    ->MinTime(3.0);

// The same with the import (reading and parsing both text files) inside the timed loop.
void BM_XsensImportAndCalibrate(benchmark::State& state) {
  if (!XsensCapture()) {
    state.SkipWithError("Xsens capture not available");
    return;
  }
  for (auto _ : state) {
    auto cap = ImportXsens();
    auto rep = Calibrate(*cap, CalibrateOptions{});
    benchmark::DoNotOptimize(rep);
  }
}
BENCHMARK(BM_XsensImportAndCalibrate)->Unit(benchmark::kMillisecond)->MinTime(3.0);

}  // namespace
}  // namespace imucal::core

namespace {

// benchmark::Initialize takes --help itself (it prints its usage and exits 0): this bench's
// flags are printed first. -h reaches CLI11, whose help ends with a pointer to --help.
const CLI::App* help_app = nullptr;
void PrintHelp() {
  std::fputs(help_app->help().c_str(), stdout);
  std::printf("\nGoogle Benchmark's flags:\n");
  benchmark::PrintDefaultHelp();
}

}  // namespace

int main(int argc, char** argv) {
  int seeds = imucal::core::kDefaultSeeds;
  bool skip_tables = false;
  CLI::App app{
      "BSAS against LM and the Xsens capture of IMU-TK: tables first, then Google Benchmark "
      "times the runs.",
      "calibration_bench"};
  app.add_option("--seeds", seeds, "simulated captures per table (seeds 1..N; at least 1)");
  app.add_flag("--skip_tables", skip_tables, "only the Google Benchmark timings");
  app.footer("--benchmark_* flags go to Google Benchmark; --help lists them too.");
  imucal::bench::ShowDefaultsTakeLast(app);
  help_app = &app;
  benchmark::Initialize(&argc, argv, PrintHelp);  // removes the --benchmark_* flags
  imucal::bench::ParseBenchFlags(app, argc, argv);
  seeds = std::max(1, seeds);
  const bool tables = !skip_tables;
  if (tables) {
    const auto pipeline = imucal::core::PrintPipelineComparison(seeds);
    const auto stages = imucal::core::PrintStageComparison(seeds);
    imucal::core::PrintConclusion(pipeline, stages);
    imucal::core::PrintXsens();
    std::printf("\n");
    std::fflush(stdout);
  }
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
