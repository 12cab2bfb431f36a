// Stage "selection" of the effect search (search.h): which of a round's passing candidates
// enters. The lowest BIC; among candidates that explain the residual as well (collinear, BIC
// within 2), the simplest; a time candidate gives way to one the robot can apply within the weak
// evidence band; then the rotations between poses judge the accelerometer candidates that |a| - g
// cannot tell apart (core/effects.h, SELECTION: THE MOVES).
#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <utility>
#include <vector>

#include "boost/math/distributions/students_t.hpp"
#include "core/effects/search.h"
#include "core/math_guard.h"

namespace imucal::core::effects {

// True when `a` and `b` are one explanation to the static residual: nearly collinear beyond
// the current model.
bool Collinear(const RoundCandidate& a, const RoundCandidate& b) {
  if (&a == &b || a.score.sensor != b.score.sensor) return false;
  if (a.score.sensor == Sensor::kGyro && a.score.axis != b.score.axis) return false;
  const double corr = std::abs(a.perp.dot(b.perp)) / (a.perp.norm() * b.perp.norm());
  return corr > kAmbiguousCorrelation;
}

// True when `b` holds `a`'s terms and more (`a` = (temperature-31.2), `b` = (temperature-31.2)
// + (temperature-31.2)^2) on the same output.
bool Nested(const RoundCandidate& a, const RoundCandidate& b) {
  if (a.score.sensor != b.score.sensor || a.score.axis != b.score.axis || !a.lower.empty())
    return false;
  return std::find(b.lower.begin(), b.lower.end(), a.regressor) != b.lower.end();
}

// True when `a` and `b` are collinear and their BIC differ by less than `max_delta_bic`.
bool Ambiguous(const RoundCandidate& a, const RoundCandidate& b, double max_delta_bic) {
  return Collinear(a, b) && std::abs(a.score.delta_bic - b.score.delta_bic) < max_delta_bic;
}

// True when `a` and `b` act on the same output axis through the same specific-force factors,
// differing only in temperature or time (`temperature*ay` and `time*ay` on y, `temperature`
// and `temperature^2`). The moves see a candidate only through the pose directions it gives;
// such two give the same pattern over the poses up to how temperature follows time, which the
// moves, made during the same warm-up, know no better than the static poses.
bool SameGeometry(const RoundCandidate& a, const RoundCandidate& b) {
  if (a.score.sensor != b.score.sensor || a.score.axis != b.score.axis) return false;
  const auto force = [](const Regressor& r) {
    std::vector<int> f;
    for (int i = 0; i < r.num_factors; ++i)
      if (r.factors[i] >= static_cast<int>(Signal::kAx) &&
          r.factors[i] <= static_cast<int>(Signal::kAz))
        f.push_back(r.factors[i]);
    return f;
  };
  return force(a.regressor) == force(b.regressor);
}

// One-sided paired t of the moves' squared errors: positive when `b`'s directions fit the
// rotations between poses better than `a`'s. NaN unless both were judged.
double MovePairedT(const RoundCandidate& a, const RoundCandidate& b) {
  const size_t n = a.move_error_rad.size();
  if (n < 3 || b.move_error_rad.size() != n) return kNaN;
  double mean = 0, ss = 0;
  for (size_t k = 0; k < n; ++k)
    mean += (std::pow(a.move_error_rad[k], 2) - std::pow(b.move_error_rad[k], 2)) / n;
  for (size_t k = 0; k < n; ++k)
    ss += std::pow(std::pow(a.move_error_rad[k], 2) - std::pow(b.move_error_rad[k], 2) - mean, 2);
  const double sd = std::sqrt(ss / static_cast<double>(n - 1));
  return sd > 0 ? mean / (sd / std::sqrt(static_cast<double>(n))) : kNaN;
}

// The one-sided t quantile for `tests` comparisons over `moves` moves at the family alpha.
double Search::MoveTThreshold(int tests, size_t moves) const {
  if (tests < 1 || moves < 3) return std::numeric_limits<double>::infinity();
  return MathOr(std::numeric_limits<double>::infinity(), [&] {
    const boost::math::students_t t(static_cast<double>(moves - 1));
    return boost::math::quantile(boost::math::complement(t, opt_.family_alpha / tests));
  });
}

// The specific-force direction of every pose (unit, body frame) with the state's
// accelerometer model and terms, as the SDK's Corrector computes it.
std::vector<Eigen::Vector3d> Search::Directions(const State& st) const {
  std::vector<Eigen::Vector3d> out;
  for (size_t i = 0; i < poses_.size(); ++i) {
    Eigen::Vector3d a = st.accel.Apply(poses_[i].accel.mean);
    for (const Term& t : st.terms)
      if (t.sensor == Sensor::kAccel)
        a(t.axis) -= t.coefficient * t.regressor.Evaluate(signals_[i]);
    out.push_back(a.normalized());
  }
  return out;
}

// The moves' judgement (effects.h, SELECTION: THE MOVES). `best` is the static choice; it
// becomes the candidate whose directions the rotations between poses fit significantly
// better, if any.
// Why the moves separate what |a| - g cannot: `ax*az` on x and `ax^2` on z move |a| alike,
// but the first tilts a pose's direction about y and the second about x, by amounts that
// differ from pose to pose; the gyroscope, integrating the rotation from pose to pose, sees
// which one the poses went through. Its matrix, refitted per candidate, absorbs what a
// misalignment of the gyroscope would explain, not a quadratic pattern over the poses.
void Search::ResolveByMoves(const State& st, std::vector<RoundCandidate>* cands, int* best) const {
  const size_t b = static_cast<size_t>(*best);
  if (!in_.move_fit || (*cands)[b].score.sensor != Sensor::kAccel || (*cands)[b].model_param >= 0)
    return;
  std::vector<size_t> group = {b};
  std::vector<size_t> others;
  for (size_t c = 0; c < cands->size(); ++c)
    if (c != b && (*cands)[c].score.passed && (*cands)[c].score.sensor == Sensor::kAccel &&
        (*cands)[c].model_param < 0 && !SameGeometry((*cands)[b], (*cands)[c]))
      others.push_back(c);
  std::sort(others.begin(), others.end(), [&](size_t x, size_t y) {
    return (*cands)[x].score.delta_bic < (*cands)[y].score.delta_bic;
  });
  for (size_t c : others)
    if (group.size() < kMaxMoveJudged) group.push_back(c);
  if (group.size() < 2) return;
  std::vector<std::vector<double>> errors;  // per group member; kept only if all were judged
  for (size_t c : group) {
    State trial = st;
    for (const Term& t : TermsOf((*cands)[c], true)) trial.terms.push_back(t);
    AccelGaussNewton(trial.free, signals_, in_.gravity_m_s2, poses_, &trial, 8);
    const std::optional<MoveFit> f = in_.move_fit(Directions(trial));
    if (!f || f->error_rad.size() < 3) return;  // the moves say nothing: the static choice
    for (double e : f->error_rad)
      if (!std::isfinite(e)) return;
    errors.push_back(f->error_rad);
  }
  for (size_t k = 0; k < group.size(); ++k)
    (*cands)[group[k]].move_error_rad = std::move(errors[k]);
  const RoundCandidate& chosen = (*cands)[b];
  const double t_crit =
      MoveTThreshold(static_cast<int>(group.size() - 1), chosen.move_error_rad.size());
  for (size_t c : group) {
    const RoundCandidate& x = (*cands)[c];
    if (c == b || !(MovePairedT(chosen, x) > t_crit)) continue;
    if (static_cast<size_t>(*best) == b ||
        x.MoveRms() < (*cands)[static_cast<size_t>(*best)].MoveRms())
      *best = static_cast<int>(c);
  }
}

Choice Search::Select(const State& st, int best, std::vector<RoundCandidate>* all) const {
  std::vector<RoundCandidate>& cands = *all;
  // Among passing candidates that explain the residual as well: the simplest regressor
  // (`temperature` before `temperature^2`), then one without `time`: a warm-up that time and
  // temperature explain equally is attributed to temperature, which the SDK applies on every
  // sample and which holds across power cycles (the ambiguity is reported either way).
  const size_t first = static_cast<size_t>(best);
  // (A candidate's size counts the lower powers entering with it.)
  auto rank = [](const RoundCandidate& c) {
    int factors = c.regressor.num_factors;
    for (const Regressor& l : c.lower) factors += l.num_factors;
    return 2 * factors + (UsesTime(c) ? 1 : 0);
  };
  for (size_t c = 0; c < cands.size(); ++c) {
    if (cands[c].score.passed && Ambiguous(cands[first], cands[c]) &&
        rank(cands[c]) < rank(cands[static_cast<size_t>(best)]))
      best = static_cast<int>(c);
  }
  // Prefer what the robot can apply. A time effect is not applied (time since power-on grows
  // without bound once the warm-up is over), so choosing it where a candidate made only of
  // run-time signals (temperature, specific force) explains the data about as well leaves a
  // real effect uncorrected. Such a candidate wins when it is within the weak-evidence band
  // of BIC (kWeakEvidenceBic: the data do not strongly prefer time), collinear with the
  // time one or not; among several, the lowest BIC. The notes still name both
  // and say what capture would tell them apart.
  int gave_way = -1;  // the time candidate that gave way, if any
  if (!opt_.apply_time_effects && UsesTime(cands[static_cast<size_t>(best)])) {
    const RoundCandidate& timed = cands[static_cast<size_t>(best)];
    int swap = -1;
    for (size_t c = 0; c < cands.size(); ++c) {
      const RoundCandidate& x = cands[c];
      if (!x.score.passed || UsesTime(x) || x.score.sensor != timed.score.sensor) continue;
      if (!(x.score.delta_bic - timed.score.delta_bic < kWeakEvidenceBic)) continue;
      if (swap < 0 || x.score.delta_bic < cands[static_cast<size_t>(swap)].score.delta_bic)
        swap = static_cast<int>(c);
    }
    if (swap >= 0) gave_way = best, best = swap;
  }
  Choice choice;
  choice.static_best = best;
  choice.gave_way = gave_way;
  ResolveByMoves(st, &cands, &best);
  choice.best = best;
  return choice;
}

}  // namespace imucal::core::effects
