// The effect search's driver (search.h): the stages in order, each one's result handed to the
// next, the result filled in as they finish. The math lives in the stages' files.
#include "core/effects/search.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_format.h"
#include "util/str_util.h"

namespace imucal::core::effects {

Search::Search(const EffectSearchInput& in, const EffectSearchOptions& opt) : in_(in), opt_(opt) {
  poses_ = in.poses;
  signals_ = PoseSignals(poses_, in.accel, in.gyro);
  // The references of the centred factors (params.h EffectReference): the mean over the
  // poses, rounded so the names stay readable (any reference is exact: the SDK evaluates the
  // name as written).
  double temp_sum = 0, time_sum = 0;
  int temp_n = 0;
  for (const EffectPose& p : poses_) {
    if (std::isfinite(p.temp_c)) temp_sum += p.temp_c, ++temp_n;
    time_sum += p.time_s;
  }
  if (temp_n > 0) reference_.temperature_c = std::round(temp_sum / temp_n * 10) / 10;
  if (!poses_.empty())
    reference_.time_s = std::round(time_sum / static_cast<double>(poses_.size()));
  for (const GivenEffect& g : opt.given) {
    const std::optional<Regressor> r = ParseRegressor(g.regressor);
    if (!r) continue;  // Run() refuses it
    for (int i = 0; i < r->num_factors; ++i) {
      const double c = r->centre[static_cast<size_t>(r->factors[i])];
      if (c == 0) continue;
      (r->factors[i] == static_cast<int>(Signal::kTime) ? reference_.time_s
                                                        : reference_.temperature_c) = c;
    }
  }
  centre_[static_cast<size_t>(Signal::kTemperature)] = reference_.temperature_c;
  centre_[static_cast<size_t>(Signal::kTime)] = reference_.time_s;
  rates_ = StaticRates(poses_, signals_);
  gyro_sigma_ = GyroSigmas(poses_, in.gyro);
}

State Search::StartState() const {
  State st;
  st.accel = in_.accel;
  st.free = in_.accel_free;
  st.priors = in_.accel_priors;
  return st;
}

absl::StatusOr<EffectSearchResult> Search::Run() {
  EffectSearchResult out;
  out.reference = reference_;
  EffectDiagnostics& diag = out.diagnostics;
  diag.ran = true;
  // -> refit: the model as the pipeline left it, with the search's weights
  State st = StartState();
  absl::StatusOr<Fit> base = Refit(&st);
  if (!base.ok()) return base.status();
  Fit fit = *base;
  const Excitation excited = ExcitedSignals(poses_, signals_, in_.accel, in_.gyro);
  NoiseFloors(&diag);
  diag.accel_heldout_before_m_s2 = RmsOf(base->accel_heldout);
  diag.gyro_heldout_before_rad_s = GyroRms(base->gyro_heldout);
  // -> the given effects
  if (absl::Status s = EnterGiven(&st, &fit, &out); !s.ok()) return s;
  // -> rounds: candidates, screening, selection, refit
  for (int round = 0; round < opt_.max_effects; ++round) {
    absl::StatusOr<bool> entered = Round(round, excited, &st, &fit, &out);
    if (!entered.ok()) return entered.status();
    if (!*entered) break;
  }
  // -> report
  if (absl::Status s = Finish(st, fit, *base, excited, &out); !s.ok()) return s;
  return out;
}

absl::Status Search::EnterGiven(State* st, Fit* fit, EffectSearchResult* out) {
  if (opt_.given.empty()) return absl::OkStatus();
  State next = *st;
  for (size_t k = 0; k < opt_.given.size(); ++k) {
    const GivenEffect& g = opt_.given[k];
    const std::optional<Regressor> r = ParseRegressor(g.regressor);
    if (!r || g.axis < 0 || g.axis > 2 || !CentreMismatch(*r, reference_).empty())
      return absl::InvalidArgumentError(absl::StrFormat(
          "given effect %d: \"%s\" on axis %d is not a regressor (core/regressor.h) on x, y "
          "or z, centred on one reference per signal",
          static_cast<int>(k), g.regressor, g.axis));
    Term t;
    t.sensor = g.sensor;
    t.axis = g.axis;
    t.regressor = *r;
    t.applied = !UsesSignal(*r, Signal::kTime) || opt_.apply_time_effects;
    next.terms.push_back(t);
  }
  absl::StatusOr<Fit> after = Refit(&next);
  if (!after.ok()) return after.status();
  for (size_t k = 0; k < next.terms.size(); ++k) {
    Effect e = ToEffect(next.terms[k]);
    e.std_error = after->term_stderr[k];
    const bool accel = e.sensor == Sensor::kAccel;
    e.error_before = accel ? RmsOf(fit->accel_heldout) : GyroRms(fit->gyro_heldout);
    e.error_after = accel ? RmsOf(after->accel_heldout) : GyroRms(after->gyro_heldout);
    e.evidence = "given: its form was stated, not searched for";
    out->effects.push_back(e);
  }
  *st = next;
  *fit = *after;
  return absl::OkStatus();
}

absl::StatusOr<bool> Search::Round(int round, const Excitation& excited, State* st, Fit* fit,
                                   EffectSearchResult* out) {
  EffectDiagnostics& diag = out->diagnostics;
  // -> candidates -> screening
  int absorbed = 0, not_excited = 0;
  std::vector<RoundCandidate> proposed = Candidates(*st, excited, &absorbed, &not_excited);
  std::vector<RoundCandidate> cands = Screen(*st, std::move(proposed), &absorbed);
  if (round == 0) {
    diag.candidates = static_cast<int>(cands.size());
    diag.absorbed = absorbed;
    diag.not_excited = not_excited;
  }
  ++diag.rounds;
  if (cands.empty()) return false;
  const int tests = static_cast<int>(cands.size());
  last_tests_ = tests;
  const int best = Test(*st, &cands);
  if (round == 0) KeepTop(cands, &diag);
  if (std::getenv("IMUCAL_DEBUG_EFFECTS") != nullptr) DebugDump(round, cands);
  if (best < 0) return false;
  if (round + 1 == opt_.max_effects) {
    diag.notes.push_back(absl::StrFormat(
        "stopped at the limit of %d effects with significant candidates left; the model may "
        "lack a term the dictionary does not hold",
        opt_.max_effects));
  }
  // -> selection
  const Choice choice = Select(*st, best, &cands);
  // -> refit with the winner in
  const RoundCandidate& win = cands[static_cast<size_t>(choice.best)];
  const absl::Status s = win.model_param >= 0 ? FreeHeld(win, st, fit, &diag)
                                              : EnterEffect(cands, choice, tests, st, fit, out);
  if (!s.ok()) return s;
  return true;
}

// A held parameter freed (RE-EXAMINATION).
absl::Status Search::FreeHeld(const RoundCandidate& win, State* st, Fit* fit,
                              EffectDiagnostics* diag) {
  State next = *st;
  next.free[static_cast<size_t>(win.model_param)] = true;
  absl::StatusOr<Fit> after = Refit(&next);
  if (!after.ok()) return after.status();
  diag->notes.push_back(absl::StrFormat(
      "re-examined with the effects in: %s, held before the search, is estimated now "
      "(F %.1f > %.1f, BIC %+.1f, held-out sum of squares -%.1f noise units; accelerometer "
      "held-out RMS %.3f -> %.3f mg)",
      AccelParamName(win.model_param), win.score.f, win.score.f_threshold, win.score.delta_bic,
      win.score.press_gain, RmsOf(fit->accel_heldout) / kMgPerMs2,
      RmsOf(after->accel_heldout) / kMgPerMs2));
  freed_.push_back(win.model_param);
  *st = next;
  *fit = *after;
  return absl::OkStatus();
}

absl::Status Search::EnterEffect(const std::vector<RoundCandidate>& cands, const Choice& choice,
                                 int tests, State* st, Fit* fit, EffectSearchResult* out) {
  const RoundCandidate& win = cands[static_cast<size_t>(choice.best)];
  EffectDiagnostics* diag = &out->diagnostics;
  const std::vector<Term> entering = TermsOf(win, opt_.apply_time_effects);
  const bool gyro_only = win.score.sensor == Sensor::kGyro;
  State next = *st;
  for (const Term& t : entering) next.terms.push_back(t);
  absl::StatusOr<Fit> after = Refit(&next, gyro_only ? fit : nullptr);
  if (!after.ok()) return after.status();
  const bool accel = !gyro_only;
  const double before_rms = accel ? RmsOf(fit->accel_heldout) : GyroRms(fit->gyro_heldout);
  const double after_rms = accel ? RmsOf(after->accel_heldout) : GyroRms(after->gyro_heldout);
  const std::string evidence =
      Evidence(win, cands[static_cast<size_t>(choice.static_best)], cands, tests, diag);
  if (choice.gave_way >= 0 && !Collinear(win, cands[static_cast<size_t>(choice.gave_way)])) {
    // Evidence() names collinear rivals; one that gave way on the BIC band alone is named
    // here, with what would tell them apart.
    const RoundCandidate& timed = cands[static_cast<size_t>(choice.gave_way)];
    diag->notes.push_back(absl::StrFormat(
        "ambiguous: %s entered rather than %s, which the data favour but not strongly (BIC "
        "%+.1f vs %+.1f, a difference under 6 is not strong evidence): a time term is not "
        "applied on the robot; %s",
        Describe(win), Describe(timed), win.score.delta_bic, timed.score.delta_bic,
        Separator(win.regressor, timed.regressor)));
  }
  for (size_t k = 0; k < entering.size(); ++k) {
    const size_t at = next.terms.size() - entering.size() + k;
    Effect e = ToEffect(next.terms[at]);
    e.std_error = after->term_stderr[at];
    e.error_before = before_rms;
    e.error_after = after_rms;
    e.evidence = k + 1 == entering.size() ? evidence
                                          : Cat("entered with ", Describe(win),
                                                " (a power enters with the lower "
                                                "ones): ",
                                                evidence);
    out->effects.push_back(e);
  }
  *st = next;
  *fit = *after;
  return absl::OkStatus();
}

absl::Status Search::Finish(const State& st, const Fit& fit, const Fit& base,
                            const Excitation& excited, EffectSearchResult* out) {
  EffectDiagnostics& diag = out->diagnostics;
  // Coefficients as finally refitted (each effect's error_before/after stays as measured when
  // it entered).
  for (size_t k = 0; k < st.terms.size(); ++k) {
    out->effects[k].coefficient = st.terms[k].coefficient;
    out->effects[k].std_error = fit.term_stderr[k];
  }
  diag.accel_heldout_after_m_s2 = RmsOf(fit.accel_heldout);
  diag.gyro_heldout_after_rad_s = GyroRms(fit.gyro_heldout);

  // The stored model carries only the applied effects: refit without the others (a drift the
  // robot will not correct is best left in the bias as its mean over the capture).
  State stored = st;
  std::erase_if(stored.terms, [](const Term& t) { return !t.applied; });
  absl::StatusOr<Fit> final_fit = stored.terms.size() == st.terms.size() ? fit : Refit(&stored);
  if (!final_fit.ok()) return final_fit.status();
  Rows(base, *final_fit, fit, &diag);
  out->accel = stored.accel;
  out->gyro = in_.gyro;
  out->gyro.bias = in_.gyro.bias + in_.gyro.matrix.inverse() * stored.gyro_offset;
  FillAccelCovariance(stored.free, *final_fit, out);
  out->accel_free = stored.free;
  for (size_t k = 0, s = 0; k < st.terms.size(); ++k) {
    if (!st.terms[k].applied) continue;
    out->effects[k].coefficient = stored.terms[s].coefficient;
    out->effects[k].std_error = final_fit->term_stderr[s];
    ++s;
  }
  FinalNotes(st, *final_fit, &diag);
  TemperatureBounds(st, excited, &diag);
  ExamineMoveResiduals(in_.moves, &diag);
  return absl::OkStatus();
}

}  // namespace imucal::core::effects

namespace imucal::core {

absl::StatusOr<EffectSearchResult> FindEffects(const EffectSearchInput& input,
                                               const EffectSearchOptions& options) {
  if (!options.enabled) return absl::InvalidArgumentError("effect search is disabled");
  // The parameters the poses pay for: a term its prior decides counts for nothing.
  std::vector<AccelPose> poses;
  for (const EffectPose& p : input.poses) poses.push_back(p.accel);
  const int n_free = static_cast<int>(std::ceil(
      EffectiveParameters(input.accel, poses, input.accel_free, input.accel_priors) - 1e-9));
  if (static_cast<int>(input.poses.size()) < n_free + 3) {
    EffectSearchResult out;
    out.accel = input.accel;
    out.gyro = input.gyro;
    out.diagnostics.notes.push_back(absl::StrFormat(
        "effects not searched: %d poses leave too few degrees of freedom beyond the %d model "
        "parameters they determine",
        static_cast<int>(input.poses.size()), n_free));
    return out;
  }
  effects::Search search(input, options);
  return search.Run();
}

}  // namespace imucal::core
