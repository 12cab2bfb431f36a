// The figures for closing the loop, over many seeds (default 20 per row):
//   - detection rate per effect type: the simulated effect found with the right sensor, axis and
//     regressor (and how often its coefficient lies within 3 standard errors of the truth);
//   - the false-alarm rate on clean captures, with and without a temperature channel;
//   - the error before and after on a fresh validation capture of the same unit, through the
//     SDK's Corrector (median over seeds), next to the validation capture's noise floor (the
//     truth with its effects applied to it);
//   - on other temperature histories of the same unit (a linear ramp, a cool-down, a plateau 2
//     degC above the calibration's range; tests/core/effect_scenarios.h HistoryScenario), the
//     validation error of the model found next to a reference fit given the true effect's form
//     (its coefficient fitted with the model, nothing searched), both in units of the truth's
//     floor on the sensor(s) the truth acts on, median over seeds and histories; `ratio` is
//     found / reference (aim: at most 1.3);
//   - for a rate-dependent gyroscope term (kRateCases, simulated with hand-paced moves), the
//     validation is the gravity-direction error after the fresh capture's moves through the
//     SDK (MoveErrorOn; the holds cannot show a rate term), and the other histories are scored
//     on their moves too;
//   - the time the effect search adds to Calibrate.
//   - detection against what the capture says it could detect: a truth the search did not find is
//     "detectable" when its coefficient exceeds the detection bound the report states for its
//     form (core/move_effects.h DetectionBound), or the report states none; `missed` counts the
//     detectable ones not found (aim: 0; the bound is a 90% one, so about 1 in 10 just above it).
// Scenarios and magnitudes: tests/core/effect_scenarios.h (six-face + 24 extra poses, 200 Hz,
// 2 mg noise, units with second-order terms from the wide prior). The calibration capture's
// temperature path cycles with the seed through a warm-up (8 degC), a ramp, a cool-down and a
// plateau (HistoryScenario): on a plateau no temperature effect is detectable, and the report
// must say so. The other three paths validate. Time effects are applied (opt-in) for the
// validation.
//
// Usage: effects_bench [--seeds=N] [--clean-seeds=N] [--case=NAME] [--seed=N] [--no-temperature]
//   --clean-seeds sets how many clean captures measure the false alarms (default: --seeds).
//   --no-temperature runs the cases that do not need a temperature channel on captures without
//   one (the clean rows measure both anyway).
//   --case and --seed run one scenario (a name of tests/core/effect_scenarios.h, or Wander for
//   the wandering gyro bias's rows: --seeds of them) or one seed,
//   to look at a capture the table lists; with IMUCAL_DEBUG_EFFECTS=1 the search prints each
//   round's best candidates.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "bench/bench_flags.h"
#include "core/calibrate/calibrate.h"
#include "tests/core/effect_scenarios.h"

namespace imucal::core {
namespace {

double Median(std::vector<double> v) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

struct Run {
  CalibrationReport report;
  double ms = 0;
};

Run CalibrateTimed(const Capture& cap, bool effects, bool apply_time,
                   const std::vector<SimEffect>* given = nullptr) {
  CalibrateOptions opt;
  opt.use_bsas = false;
  opt.effects.enabled = effects;
  opt.effects.apply_time_effects = apply_time;
  if (given != nullptr) {  // the reference fit: the true forms, nothing searched
    for (const SimEffect& e : *given) opt.effects.given.push_back({e.sensor, e.axis, e.regressor});
    opt.effects.max_effects = 0;
  }
  const auto t0 = std::chrono::steady_clock::now();
  absl::StatusOr<CalibrationReport> r = Calibrate(cap, opt);
  const double ms =
      1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!r.ok()) {
    std::fprintf(stderr, "calibrate failed: %s\n", std::string(r.status().message()).c_str());
    std::exit(1);
  }
  return {*std::move(r), ms};
}

// RMS over the 9 entries of the calibrated gyroscope matrix minus the truth's, ppm (both map
// raw rad/s to the accelerometer's case frame).
double MatrixErrorPpm(const ParamSet& p, const SimTruth& truth) {
  return 1e6 * (p.gyro.matrix - truth.gyro.matrix).norm() / 3.0;
}

bool Same(const Effect& e, const SimEffect& s) {
  return e.sensor == s.sensor && e.axis == s.axis && SameForm(e.regressor, s.regressor);
}

// True when a note of the report names the truth's form on its sensor and axis as one the
// capture cannot tell from another ("ambiguous: gyro x ~ (temperature-29.1) explains the
// residual about as well as gyro x ~ (time-122)": a ramp's temperature rises with time).
bool NamedAmbiguous(const CalibrationReport& r, const SimEffect& e) {
  const std::string who =
      absl::StrFormat("%s %c ~ ", e.sensor == Sensor::kAccel ? "accel" : "gyro", "xyz"[e.axis]);
  for (const std::string& note : r.effect_diagnostics.notes) {
    if (note.rfind("ambiguous", 0) != 0) continue;
    for (size_t at = note.find(who); at != std::string::npos; at = note.find(who, at + 1)) {
      const size_t begin = at + who.size();
      const size_t end = note.find_first_of(" ,;", begin);
      if (SameForm(note.substr(begin, end - begin), e.regressor)) return true;
    }
  }
  return false;
}

// The detection bound the report states for the form of a truth effect (core/move_effects.h
// DetectionBound; +inf: the capture does not excite it), NaN where it states none (the form has
// no bound: a capture that does not find it claims nothing, so it counts as detectable).
double BoundFor(const CalibrationReport& r, const SimEffect& e) {
  const EffectDiagnostics& d = r.effect_diagnostics;
  for (const std::vector<DetectionBound>* list :
       {&d.detection_bounds, &d.move_search.detection_bounds})
    for (const DetectionBound& b : *list)
      if (b.sensor == e.sensor && b.axis == e.axis && SameForm(b.regressor, e.regressor))
        return b.coefficient;
  return NAN;
}

// What to run when not everything: one case by name, one seed.
struct Only {
  int clean_seeds = 0;  // the clean captures' seeds (0: as many as --seeds)
  std::string name;
  int seed = 0;
  bool no_temperature = false;  // the captures without a temperature channel
};

// A gyro bias that wanders (core/simulator.h gyro_bias_shift_rad_s, gyro_bias_walk), without an
// effect and with the g-sensitivity case's: does the search add effects the wander makes up,
// does it still find the real one, and does the wander's analysis (core/bias_wander.h) tell a
// new offset per pose from a drift in time?
void Wander(int seeds) {
  struct Kind {
    const char* name;
    double shift, walk;
  };
  const Kind kinds[] = {{"new offset at each move, 0.04 deg/s", 0.04 * kDegS, 0},
                        {"drift in time, K 0.02 deg/s/sqrt(s)", 0, 0.02 * kDegS}};
  const SimEffect gsens = kEffectCases[4].effects.front();  // GyroGSensitivity
  std::printf(
      "\nwandering gyro bias, no temperature channel (%d seeds): effects found without a "
      "simulated effect; the g-sensitivity (gyro y~ax 0.05 deg/s/g) found; the wander's models "
      "per axis (shift, walk, both, none over all axes); within-pose ratio and held-out static "
      "rate before -> after (medians)\n",
      seeds);
  for (const Kind& k : kinds) {
    for (bool with_effect : {false, true}) {
      int alarms = 0, found = 0, applied = 0, counts[4] = {0, 0, 0, 0};
      std::vector<double> within, before, after;
      std::string which;  // the other effects of the first few captures that had any
      for (int seed = 1; seed <= seeds; ++seed) {
        std::vector<SimEffect> effects;
        if (with_effect) effects.push_back(gsens);
        SimOptions o = EffectScenario(static_cast<uint64_t>(seed) + 2000, effects, false);
        o.gyro_bias_shift_rad_s = k.shift;
        o.gyro_bias_walk = k.walk;
        absl::StatusOr<SimResult> sim = Simulate(o);
        if (!sim.ok()) std::exit(1);
        const Run run = CalibrateTimed(sim->capture, true, false);
        const ParamSet& p = run.report.params;
        bool got = false;
        for (const Effect& e : p.effects) got |= with_effect && Same(e, gsens);
        found += got;
        const bool alarm = static_cast<int>(p.effects.size()) > (got ? 1 : 0);
        alarms += alarm;
        bool any_applied = false;
        for (const Effect& e : p.effects)
          any_applied |= e.applied && !(with_effect && Same(e, gsens));
        applied += any_applied;
        if (alarm && alarms <= 3) {
          which += absl::StrFormat(" [seed %d:", seed + 2000);
          for (const Effect& e : p.effects)
            if (!(with_effect && Same(e, gsens)))
              which +=
                  absl::StrFormat(" %s %c~%s%s", e.sensor == Sensor::kAccel ? "accel" : "gyro",
                                  "xyz"[e.axis], e.regressor, e.applied ? "" : " (not applied)");
          which += "]";
        }
        const BiasWander& w = run.report.gyro_wander;
        for (const AxisWander& a : w.axes) {
          ++counts[a.model == WanderModel::kShift          ? 0
                   : a.model == WanderModel::kWalk         ? 1
                   : a.model == WanderModel::kShiftAndWalk ? 2
                                                           : 3];
        }
        within.push_back(w.within_pose_ratio);
        before.push_back(w.heldout_before_rad_s / kDegS);
        after.push_back(w.heldout_after_rad_s / kDegS);
      }
      std::printf(
          "  %-38s %-10s other effects %2d/%d (applied %2d)  %s  models %d/%d/%d/%d  within %.2f  "
          "held out %.4f -> %.4f deg/s\n   %s\n",
          k.name, with_effect ? "+ g-sens." : "no effect", alarms, seeds, applied,
          with_effect ? absl::StrFormat("found %2d/%d", found, seeds).c_str() : "            ",
          counts[0], counts[1], counts[2], counts[3], Median(within), Median(before), Median(after),
          which.c_str());
    }
  }
}

// The table's header lines.
void PrintTableHeader(int seeds) {
  std::printf(
      "effects_bench: %d seeds per row; six-face + 24 extra poses, 200 Hz, 2 mg noise, units "
      "with second-order terms from the wide prior; calibrated on a warm-up, a ramp, a cool-down "
      "or a plateau (by seed), validated on the others\n\n",
      seeds);
  std::printf("%-30s %9s %9s %6s %9s %9s | %-25s | %-27s | %-23s | %s\n", "effect (truth)", "found",
              "detectable", "missed", "within3se", "other", "validation accel mg",
              "validation gyro deg/s", "validation moves deg",
              "other histories: found / reference");
  std::printf(
      "%-30s %9s %9s %6s %9s %9s | %7s %7s %7s   | %8s %8s %8s   | %7s %7s %7s | %7s %7s %6s\n", "",
      "", "", "", "", "", "before", "after", "floor", "before", "after", "floor", "before", "after",
      "floor", "found", "ref", "ratio");
}

// What the rows share: the effect search's times, and the lines printed after the table.
struct Totals {
  std::vector<double> search_ms, base_ms;
  std::string misses, matrix_rows;
};

// One case's columns, over its seeds.
struct CaseTally {
  int found = 0, within = 0, other = 0, detectable = 0, missed = 0;
  // Validation errors before / after / floor: accel (mg), gyro (deg/s), moves (deg); the gyro
  // matrix's error (ppm) without / with the effect search.
  std::vector<double> ab, aa, af, gb, ga, gf, mb, ma, vb, va, vf;
  // Per seed and other history: the found model's and the reference fit's validation error on
  // the sensor(s) the truth acts on, each in units of that sensor's floor (so sensors add).
  std::vector<double> hist_found, hist_ref;
};

// The sensor(s) a case's truth acts on; a rate term shows on the moves, not the holds.
struct ActsOn {
  bool accel = false, gyro = false, moves = false;
};

// Were the truth's effects found (and within 3 standard errors), could they have been, and did
// the search add others? Tallies one seed's calibration; what it missed goes to `misses`.
void ScoreDetection(const EffectCase& c, int seed, const std::string& capture_name,
                    const std::vector<SimEffect>& effects, const Run& run, CaseTally* t,
                    std::string* misses) {
  bool all = true, all3 = true, can = true;
  std::string bounds;  // the truths not found, with the bound stated for them
  for (const SimEffect& want : effects) {
    const Effect* got = nullptr;
    for (const Effect& e : run.report.params.effects)
      if (Same(e, want)) got = &e;
    all &= got != nullptr;
    if (got == nullptr) {
      const double bound = BoundFor(run.report, want);
      const bool ambiguous = NamedAmbiguous(run.report, want);
      // NaN (no bound): detectable, unless the report names it as one it cannot tell apart.
      can &= !(std::abs(want.coefficient) <= bound) && !ambiguous;
      bounds += absl::StrFormat(" [%s: truth %.3g, bound %.3g%s]", want.regressor, want.coefficient,
                                bound, ambiguous ? ", named as ambiguous" : "");
    }
    all3 &= got != nullptr && std::abs(got->coefficient - want.coefficient) < 3 * got->std_error;
    if (got != nullptr && std::abs(got->coefficient - want.coefficient) >= 3 * got->std_error)
      *misses +=
          absl::StrFormat("  %s seed %d: %s %.4g +- %.2g, truth %.4g (%.1f se off)\n", c.name, seed,
                          want.regressor, got->coefficient, got->std_error, want.coefficient,
                          std::abs(got->coefficient - want.coefficient) / got->std_error);
  }
  t->found += all;
  t->within += all3;
  t->detectable += can;
  t->missed += can && !all;
  // Other effects: main effects found (not a lower power entered with a higher one) that are
  // none of the truth's.
  bool extra = false;
  for (const Effect& e : run.report.params.effects) {
    bool truth = false;
    for (const SimEffect& want : effects) truth |= Same(e, want);
    extra |= !truth && !IsLowerPower(e, run.report.params.effects);
  }
  t->other += extra;
  if (!all || extra) {  // what was found instead, to read beside the table
    std::string got;
    for (const Effect& e : run.report.params.effects)
      got += absl::StrFormat(" %s %c~%s", e.sensor == Sensor::kAccel ? "accel" : "gyro",
                             "xyz"[e.axis], e.regressor);
    *misses += absl::StrFormat("  %s seed %d (%s):%s%s\n", c.name, seed, capture_name,
                               got.empty() ? " nothing" : got, bounds);
  }
}

// The other temperature histories of the unit: the found model's and a reference fit's error
// (the true forms given) relative to the floor. False when a simulation failed.
bool ScoreHistories(const EffectCase& c, int seed, bool one_seed, History calibrated_on,
                    const std::vector<SimEffect>& effects, const SimResult& sim, const Run& run,
                    bool time, double move_s, ActsOn on, CaseTally* t) {
  const Run reference = CalibrateTimed(sim.capture, true, time, &effects);
  for (History h : kHistories) {
    if (h == calibrated_on) continue;
    absl::StatusOr<SimResult> history =
        Simulate(HistoryScenario(static_cast<uint64_t>(seed) + 700, effects, h, move_s), sim.truth);
    if (!history.ok()) return false;
    const HoldError fo = ErrorOn(*history, run.report.params),
                    re = ErrorOn(*history, reference.report.params),
                    fl = ErrorOn(*history, TruthParams(*history));
    const double mo = on.moves ? MoveErrorOn(*history, run.report.params) : 0,
                 mr = on.moves ? MoveErrorOn(*history, reference.report.params) : 0,
                 mf = on.moves ? MoveErrorOn(*history, TruthParams(*history)) : 1;
    // Relative to the floor, so a two-sensor case sums like with like.
    const auto rel = [&](const HoldError& e, double moves) {
      return (on.accel ? e.accel_m_s2 / fl.accel_m_s2 : 0.0) +
             (on.gyro ? e.gyro_rad_s / fl.gyro_rad_s : 0.0) + (on.moves ? moves / mf : 0.0);
    };
    t->hist_found.push_back(rel(fo, mo));
    t->hist_ref.push_back(rel(re, mr));
    if (one_seed)
      std::printf(
          "  %s seed %d %s: accel %.3f / %.3f mg, gyro %.4f / %.4f deg/s (found / "
          "reference), floor %.3f mg %.4f deg/s\n",
          c.name.c_str(), seed, HistoryName(h), fo.accel_m_s2 / kMg, re.accel_m_s2 / kMg,
          fo.gyro_rad_s / kDegS, re.gyro_rad_s / kDegS, fl.accel_m_s2 / kMg, fl.gyro_rad_s / kDegS);
  }
  return true;
}

// The gyro matrix against the truth without and with the search, and the validation capture's
// errors before (the effects left out) and after, next to its floor.
void ScoreValidation(const SimResult& sim, const SimResult& val, const Run& run, CaseTally* t) {
  const Run plain = CalibrateTimed(sim.capture, false, false);
  t->mb.push_back(MatrixErrorPpm(plain.report.params, sim.truth));
  t->ma.push_back(MatrixErrorPpm(run.report.params, sim.truth));
  ParamSet without = run.report.params;
  without.effects.clear();
  const HoldError b = ErrorOn(val, without), a = ErrorOn(val, run.report.params),
                  f = ErrorOn(val, TruthParams(val));
  t->ab.push_back(b.accel_m_s2 / kMg), t->aa.push_back(a.accel_m_s2 / kMg),
      t->af.push_back(f.accel_m_s2 / kMg);
  t->gb.push_back(b.gyro_rad_s / kDegS), t->ga.push_back(a.gyro_rad_s / kDegS),
      t->gf.push_back(f.gyro_rad_s / kDegS);
  t->vb.push_back(MoveErrorOn(val, without) / kDegS);
  t->va.push_back(MoveErrorOn(val, run.report.params) / kDegS);
  t->vf.push_back(MoveErrorOn(val, TruthParams(val)) / kDegS);
}

// One seed of a case: the calibration capture, its calibration, and every score. False when a
// simulation failed.
bool RunCaseSeed(const EffectCase& c, int seed, const Only& only, double move_s, ActsOn on,
                 CaseTally* t, Totals* totals) {
  const bool temperature = !only.no_temperature;
  const std::vector<SimEffect> effects = EffectsFor(c, static_cast<uint64_t>(seed));
  const History calibrated_on = kHistories[static_cast<size_t>(seed) % 4];
  absl::StatusOr<SimResult> sim = Simulate(
      temperature ? HistoryScenario(static_cast<uint64_t>(seed), effects, calibrated_on, move_s)
                  : EffectScenario(static_cast<uint64_t>(seed), effects, temperature, move_s));
  if (!sim.ok()) return false;
  bool time = false;
  for (const SimEffect& e : c.effects) time |= e.regressor.find("time") != std::string::npos;
  const Run run = CalibrateTimed(sim->capture, true, time);
  totals->search_ms.push_back(run.ms);
  if (only.seed > 0)  // one capture looked at: what the search said
    for (const std::string& n : run.report.effect_diagnostics.notes)
      std::printf("  note: %s\n", n.c_str());
  ScoreDetection(c, seed, temperature ? HistoryName(calibrated_on) : "no temperature", effects, run,
                 t, &totals->misses);
  absl::StatusOr<SimResult> val = Simulate(
      EffectScenario(static_cast<uint64_t>(seed) + 500, effects, temperature, move_s), sim->truth);
  if (!val.ok()) return false;
  if (temperature && !ScoreHistories(c, seed, only.seed > 0, calibrated_on, effects, *sim, run,
                                     time, move_s, on, t))
    return false;
  ScoreValidation(*sim, *val, run, t);
  return true;
}

// A case's row of the table (and its line of the gyro matrix's table, kept for after it).
void PrintCaseRow(const EffectCase& c, const CaseTally& t, int runs, double move_s,
                  std::string* matrix_rows) {
  std::string truth;
  for (const SimEffect& e : EffectsFor(c, 1))
    truth +=
        absl::StrFormat("%s%s %c~%s", truth.empty() ? "" : " + ",
                        e.sensor == Sensor::kAccel ? "accel" : "gyro", "xyz"[e.axis], e.regressor);
  if (c.name.find("Turnover") != std::string::npos) truth += " (T0 per seed)";
  if (move_s != 2.5) truth += absl::StrFormat(" (%.0f s moves)", move_s);
  std::printf(
      "%-30s %4d/%-4d %4d/%-4d %6d %4d/%-4d %4d/%-4d | %7.3f %7.3f %7.3f   | %8.4f %8.4f %8.4f   "
      "| %7.4f %7.4f %7.4f | %7.2f %7.2f %6.2f\n",
      truth.c_str(), t.found, runs, t.detectable, runs, t.missed, t.within, runs, t.other, runs,
      Median(t.ab), Median(t.aa), Median(t.af), Median(t.gb), Median(t.ga), Median(t.gf),
      Median(t.vb), Median(t.va), Median(t.vf), Median(t.hist_found), Median(t.hist_ref),
      Median(t.hist_found) / Median(t.hist_ref));
  *matrix_rows += absl::StrFormat("%-30s %8.0f %8.0f\n", truth, Median(t.mb), Median(t.ma));
}

// A case over its seeds, and its row. False when a simulation failed.
bool RunCase(const EffectCase& c, int seeds, const Only& only, Totals* totals) {
  CaseTally t;
  ActsOn on;
  for (const SimEffect& e : c.effects)
    (e.sensor == Sensor::kAccel ? on.accel : ReadsRate(e.regressor) ? on.moves : on.gyro) = true;
  const double move_s = CaseMoveSeconds(c);
  for (int seed = 1; seed <= seeds; ++seed) {
    if (only.seed > 0 && seed != only.seed) continue;
    if (!RunCaseSeed(c, seed, only, move_s, on, &t, totals)) return false;
  }
  PrintCaseRow(c, t, only.seed > 0 ? 1 : seeds, move_s, &totals->matrix_rows);
  return true;
}

// The false alarms on clean captures (no effect simulated): with and without a temperature
// channel, and (with one) moves at a hand's pace, where a rate-dependent gyroscope term would
// show. False when a simulation failed.
bool CleanRows(int clean, Totals* totals) {
  std::printf("\nclean captures (no effect simulated): captures with any effect added\n");
  struct Clean {
    bool temperature;
    double move_s;
    const char* label;
  };
  for (const Clean& row :
       {Clean{true, 2.5, "with temperature:"}, Clean{false, 2.5, "without temperature:"},
        Clean{true, 1.0, "1 s moves:"}}) {
    const bool temperature = row.temperature;
    int alarms = 0;
    std::string which;
    for (int seed = 1; seed <= clean; ++seed) {
      const auto clean_seed = static_cast<uint64_t>(seed) + 1000;
      absl::StatusOr<SimResult> sim = Simulate(
          temperature ? HistoryScenario(clean_seed, {}, kHistories[static_cast<size_t>(seed) % 4],
                                        row.move_s)
                      : EffectScenario(clean_seed, {}, temperature, row.move_s));
      if (!sim.ok()) return false;
      const Run with = CalibrateTimed(sim->capture, true, false);
      const Run without = CalibrateTimed(sim->capture, false, false);
      totals->search_ms.push_back(with.ms);
      totals->base_ms.push_back(without.ms);
      if (!with.report.params.effects.empty()) {
        ++alarms;
        for (const Effect& e : with.report.params.effects)
          which += absl::StrFormat(" [seed %d: %s %c~%s]", seed + 1000,
                                   e.sensor == Sensor::kAccel ? "accel" : "gyro", "xyz"[e.axis],
                                   e.regressor);
      }
    }
    std::printf("  %-22s %d/%d false alarms (%.0f%% clean)%s\n", row.label, alarms, clean,
                100.0 * (clean - alarms) / clean, which.c_str());
  }
  return true;
}

int Main(int seeds, const Only& only) {
  if (only.name == "Wander") {  // the wandering bias's rows alone
    Wander(seeds);
    return 0;
  }
  PrintTableHeader(seeds);
  Totals totals;
  std::vector<EffectCase> cases(std::begin(kEffectCases), std::end(kEffectCases));
  cases.insert(cases.end(), std::begin(kHarderCases), std::end(kHarderCases));
  cases.insert(cases.end(), std::begin(kRateCases), std::end(kRateCases));
  for (const EffectCase& c : cases) {
    if (!only.name.empty() && c.name != only.name) continue;
    if (only.no_temperature && UsesTemperature(c)) continue;  // needs the channel
    if (!RunCase(c, seeds, only, &totals)) return 1;
  }
  std::printf(
      "\ngyro matrix against the truth (RMS of its 9 entries, ppm, median over seeds): calibrated "
      "without the\neffect search, and with it (its frame and matrix refitted to the directions "
      "the accelerometer effects correct)\n%-30s %8s %8s\n%s",
      "effect (truth)", "without", "with", totals.matrix_rows.c_str());
  if (!totals.misses.empty())
    std::printf("\nnot found as simulated, found with more, or beyond 3 standard errors:\n%s",
                totals.misses.c_str());
  // One scenario looked at: no summary.
  if (!only.name.empty() || only.seed > 0 || only.no_temperature) return 0;
  const int clean = only.clean_seeds > 0 ? only.clean_seeds : seeds;
  if (!CleanRows(clean, &totals)) return 1;
  std::printf(
      "\ncalibrate median %.1f ms with the effect search, %.1f ms without (clean captures)\n",
      Median(totals.search_ms), Median(totals.base_ms));
  Wander(clean);
  return 0;
}

}  // namespace
}  // namespace imucal::core

int main(int argc, char** argv) {
  int seeds = 20;
  imucal::core::Only only;
  CLI::App app{
      "Closing the loop: detection and false-alarm rates of the effect search, and the error "
      "before and after on validation captures, over many seeds.",
      "effects_bench"};
  app.add_option("--seeds", seeds, "seeds per row (at least 1)");
  app.add_option("--clean-seeds", only.clean_seeds,
                 "clean captures that measure the false alarms (0: as many as --seeds)");
  app.add_option("--case", only.name,
                 "run this scenario only (a name of tests/core/effect_scenarios.h)");
  app.add_option("--seed", only.seed, "run this seed only (0: every seed)");
  app.add_flag("--no-temperature", only.no_temperature,
               "the cases that do not need a temperature channel, on captures without one");
  imucal::bench::ParseBenchFlags(app, argc, argv);
  return imucal::core::Main(std::max(1, seeds), only);
}
