// The moves' search (core/move_effects.h SELECTION): the rate-dependent gyroscope terms that only
// the rotations between static poses show, by the static search's rule (core/effects.h) on the
// moves' residuals. SearchMoveEffects runs the stages of the static search (search.h) on its own
// model (move_model.h): the fit without terms, then rounds of candidates (MoveDictionary),
// screening (F, BIC, held out by move, the trimmed gain), selection (the lowest BIC) and refit,
// then the report (the turns against the moves, the notes, the detection bounds).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Dense"
#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "boost/math/distributions/non_central_chi_squared.hpp"
#include "core/effects/common.h"
#include "core/effects/move_model.h"
#include "core/math_guard.h"
#include "core/so3.h"
#include "util/units.h"

namespace imucal::core::effects {
namespace {

constexpr char kAxes[] = "xyz";
constexpr int kMinMoves = 6;
constexpr int kTopCandidates = 5;

// The Jacobian columns of candidate terms at `model` (each at coefficient 0), all in one pass:
// a candidate changes phi_k by dphi_k/dc = -(x(v_k) + x(v_{k+1})) / 2 dt_k e_axis, and the
// rest of the chain rule (MoveResidual's) is the same for every candidate.
Eigen::MatrixXd CandidateColumns(const Model& model, const std::vector<MoveTerm>& cands,
                                 const std::vector<Prepared>& moves,
                                 const std::vector<Prepared>& turns) {
  const auto nc = static_cast<Eigen::Index>(cands.size());
  Eigen::MatrixXd out(static_cast<Eigen::Index>(3 * (moves.size() + turns.size())), nc);
  Eigen::VectorXd x0(nc), x1(nc);
  const auto regressors = [&](const Eigen::Vector3d& u, Eigen::VectorXd* x) {
    const SignalArray s = RateSignals(model.m * u);
    for (Eigen::Index c = 0; c < nc; ++c)
      (*x)(c) = cands[static_cast<size_t>(c)].regressor.Evaluate(s);
  };
  Eigen::Index row = 0;
  Eigen::Matrix3Xd b(3, nc);
  for (const Prepared& mv : moves) {
    b.setZero();
    Eigen::Matrix3d r = Eigen::Matrix3d::Identity(), jr, g;
    Eigen::Vector3d w0 = Rate(model, mv.u[0], nullptr);
    regressors(mv.u[0], &x0);
    for (size_t k = 0; k + 1 < mv.u.size(); ++k) {
      const Eigen::Vector3d w1 = Rate(model, mv.u[k + 1], nullptr);
      regressors(mv.u[k + 1], &x1);
      r = r * ExpAndRightJacobian(0.5 * (w0 + w1) * mv.dt[k], &jr);
      g.noalias() = r * jr;
      const double h = -0.5 * mv.dt[k];
      for (Eigen::Index c = 0; c < nc; ++c)
        b.col(c) += g.col(cands[static_cast<size_t>(c)].axis) * (h * (x0(c) + x1(c)));
      w0 = w1;
      x0.swap(x1);
    }
    const Eigen::Vector3d predicted = r.transpose() * mv.up_before;
    out.middleRows<3>(row) = Skew(predicted) * r.transpose() * b;
    row += 3;
  }
  for (const Prepared& t : turns) {
    b.setZero();
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    Eigen::Vector3d w0 = Rate(model, t.u[0], nullptr);
    regressors(t.u[0], &x0);
    for (size_t k = 0; k + 1 < t.u.size(); ++k) {
      const Eigen::Vector3d w1 = Rate(model, t.u[k + 1], nullptr);
      regressors(t.u[k + 1], &x1);
      sum += 0.5 * (w0 + w1) * t.dt[k];
      const double h = -0.5 * t.dt[k];
      for (Eigen::Index c = 0; c < nc; ++c)
        b(cands[static_cast<size_t>(c)].axis, c) += h * (x0(c) + x1(c));
      w0 = w1;
      x0.swap(x1);
    }
    if (t.axis.squaredNorm() > 0) {
      out.middleRows<3>(row) = b;
    } else {
      out.middleRows<3>(row).setZero();
      if (sum.norm() > 0) out.row(row) = (sum / sum.norm()).transpose() * b;
    }
    row += 3;
  }
  return out;
}

// Linearised leave-one-move-out for scoring: for each move, one Gauss-Newton step without it
// (H - J_i^T J_i)^-1 (g - J_i^T r_i) by the Woodbury identity from H^-1 (a pseudo-inverse where
// the move alone determines a direction), and its residual predicted linearly, r_i + J_i step.
// Returns the predicted held-out errors |r_i + J_i step| (rad).
std::vector<double> LinearHeldOut(const Eigen::MatrixXd& j, const Eigen::VectorXd& r,
                                  size_t moves) {
  const Eigen::MatrixXd h = j.transpose() * j;
  const Eigen::VectorXd g = j.transpose() * r;
  const Eigen::MatrixXd h_inv = PseudoInverse(h);
  std::vector<double> out;
  for (size_t i = 0; i < moves; ++i) {
    const auto row = static_cast<Eigen::Index>(3 * i);
    const Eigen::MatrixXd ji = j.middleRows<3>(row);
    const Eigen::Vector3d ri = r.segment<3>(row);
    const Eigen::VectorXd gi = g - ji.transpose() * ri;
    const Eigen::MatrixXd hj = h_inv * ji.transpose();  // P x 3
    const Eigen::Matrix3d s = Eigen::Matrix3d::Identity() - ji * hj;
    Eigen::VectorXd step;
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> se(0.5 * (s + s.transpose()));
    if (se.eigenvalues().minCoeff() > 1e-8) {
      step = -(h_inv * gi + hj * s.inverse() * (hj.transpose() * gi));
    } else {  // the move alone determines a direction: drop it there
      step = -PseudoInverse(h - ji.transpose() * ji) * gi;
    }
    out.push_back((ri + ji * step).norm());
  }
  return out;
}

std::string Describe(int axis, const Regressor& r) {
  return absl::StrFormat("gyro %c ~ %s", kAxes[axis], r.Name());
}

// What the term means, for the notes.
std::string Meaning(int axis, const Regressor& r) {
  const int own = static_cast<int>(Signal::kGx) + axis;
  const bool abs_pair =
      r.num_factors == 2 && r.factors[0] == r.factors[1] && !r.absolute[0] && r.absolute[1];
  if (abs_pair)
    return r.factors[0] == own ? "a scale that grows with the rate (scale nonlinearity)"
                               : "a misalignment that grows with the rate";
  if (r.num_factors == 1 && r.absolute[0])
    return r.factors[0] == own ? "a scale that differs between the two senses of rotation"
                               : "a misalignment that differs between the two senses of rotation";
  return "a bias proportional to the rate squared (rectification)";
}

// The human form of a move term's coefficient: % per 100 deg/s for gk*|gk|, % for |gk| (a
// scale), deg/s per (100 deg/s)^2 for the squares.
std::string HumanMoveCoefficient(const MoveTerm& t, double se) {
  const Regressor& r = t.regressor;
  const bool abs_pair =
      r.num_factors == 2 && r.factors[0] == r.factors[1] && !r.absolute[0] && r.absolute[1];
  if (abs_pair) {
    const double k = 100 * 100 / kRadToDeg;  // % per 100 deg/s
    return absl::StrFormat("%.3g +- %.2g %% per 100 deg/s", t.coefficient * k, se * k);
  }
  if (r.num_factors == 1)
    return absl::StrFormat("%.3g +- %.2g %% of |rate|", t.coefficient * 100, se * 100);
  const double k = kRadToDeg * std::pow(100 / kRadToDeg, 2);  // deg/s per (100 deg/s)^2
  return absl::StrFormat("%.3g +- %.2g deg/s per (100 deg/s)^2", t.coefficient * k, se * k);
}

// The moves whose held-out gain is left out of condition 4: a term must improve more moves than
// a knock or a slip in the hand spoils.
constexpr size_t kTrimmedMoves = 2;

// The held-out gain sum_i (before_i^2 - after_i^2) without the kTrimmedMoves moves that gain most.
double TrimmedGain(const std::vector<double>& before, const std::vector<double>& after) {
  std::vector<double> gain;
  for (size_t i = 0; i < before.size() && i < after.size(); ++i)
    gain.push_back(before[i] * before[i] - after[i] * after[i]);
  std::sort(gain.begin(), gain.end());
  double sum = 0;
  for (size_t i = 0; i + kTrimmedMoves < gain.size(); ++i) sum += gain[i];
  return sum;
}

struct Candidate {
  MoveCandidateScore score;
  MoveTerm term;
  Eigen::VectorXd perp;  // its column beyond the model
};

// DetectionBound for each gyro axis without a rate term: the scale that grows with the rate's
// size about that axis (`gk*|gk|` on k), from its candidate's column beyond the round's model.
// The last round's stand (the model as it ends).
void SetDetectionBounds(const Model& model, const std::vector<Prepared>& moves,
                        const Eigen::Vector3d& bias, const std::vector<Candidate>& cands, double s2,
                        double threshold, MoveSearchResult* out) {
  out->detection_bounds.clear();
  const double lambda = DetectableNoncentrality(1, threshold);
  Eigen::Vector3d fastest = Eigen::Vector3d::Zero();  // rad/s, through the model
  for (const Prepared& m : moves)
    for (const Eigen::Vector3d& u : m.u)
      fastest = fastest.cwiseMax((model.m * (u - bias)).cwiseAbs());
  for (int axis = 0; axis < 3; ++axis) {
    bool modelled = false;
    for (const MoveTerm& t : model.terms) modelled |= t.axis == axis;
    if (modelled) continue;
    const std::string g = absl::StrFormat("g%c", kAxes[axis]);
    const std::optional<Regressor> form = ParseRegressor(absl::StrFormat("%s*|%s|", g, g));
    if (!form) continue;
    DetectionBound b;
    b.sensor = Sensor::kGyro;
    b.axis = axis;
    b.regressor = form->Name();
    b.coefficient = std::numeric_limits<double>::infinity();
    for (const Candidate& c : cands)
      if (c.term.axis == axis && c.term.regressor == *form && c.perp.norm() > 0)
        b.coefficient = std::sqrt(lambda * s2) / c.perp.norm();
    b.from = absl::StrFormat("%d moves, up to %.0f deg/s about %c", static_cast<int>(moves.size()),
                             fastest(axis) * kRadToDeg, kAxes[axis]);
    out->detection_bounds.push_back(std::move(b));
  }
}

// Each round's best by BIC, to look at (IMUCAL_DEBUG_EFFECTS).
void DebugDump(int round, const std::vector<Candidate>& cands) {
  std::vector<const Candidate*> by_bic;
  for (const Candidate& c : cands) by_bic.push_back(&c);
  std::sort(by_bic.begin(), by_bic.end(), [](const Candidate* a, const Candidate* b) {
    return a->score.delta_bic < b->score.delta_bic;
  });
  for (size_t k = 0; k < by_bic.size() && k < 5; ++k) {
    const MoveCandidateScore& sc = by_bic[k]->score;
    std::fprintf(stderr,
                 "moves round %d: gyro %c ~ %-8s F %6.1f (%5.1f) BIC %+7.1f held-out %+7.1f "
                 "without the best %d moves %+7.1f%s\n",
                 round, kAxes[sc.axis], sc.regressor.c_str(), sc.f, sc.f_threshold, sc.delta_bic,
                 sc.press_gain, static_cast<int>(kTrimmedMoves), sc.trimmed_gain,
                 sc.passed ? " passed" : "");
  }
}

// The first round's best few by F.
void KeepTop(const std::vector<Candidate>& cands, std::vector<MoveCandidateScore>* top) {
  std::vector<const Candidate*> by_f;
  for (const Candidate& c : cands) by_f.push_back(&c);
  std::sort(by_f.begin(), by_f.end(),
            [](const Candidate* a, const Candidate* b) { return a->score.f > b->score.f; });
  for (size_t k = 0; k < by_f.size() && k < static_cast<size_t>(kTopCandidates); ++k)
    top->push_back(by_f[k]->score);
}

// The passing candidates the moves do not tell apart from the chosen one, named ("gyro x ~ |gx|,
// ..."; empty when none).
std::string Rivals(const Candidate& chosen, const std::vector<Candidate>& cands) {
  std::string text;
  for (const Candidate& c : cands) {
    if (&c == &chosen || !c.score.passed) continue;
    const double corr = std::abs(c.perp.dot(chosen.perp)) / (c.perp.norm() * chosen.perp.norm());
    if (corr > kAmbiguousCorrelation &&
        c.score.delta_bic - chosen.score.delta_bic < kWeakEvidenceBic)
      text += (text.empty() ? "" : ", ") + Describe(c.term.axis, c.term.regressor);
  }
  return text;
}

// The evidence of a term that entered (a JSON object, as the report reads it): its test and the
// moves' held-out error before (`before`) and after (`after`) it.
std::string Evidence(const Candidate& chosen, double threshold, int tests,
                     const std::string& rival_text, int moves, const MoveModelFit& before,
                     const MoveModelFit& after) {
  const MoveTerm& t = chosen.term;
  return absl::StrFormat(
      "{\"what\": \"rotations between poses: %s, F %.1f > %.1f (1%% over %d candidates), "
      "BIC %+.1f, held-out gain %.1f (%.1f without the %d moves that gain most; both over "
      "%.1f, in units of s^2); the gravity-direction error after the moves, held out by move, "
      "%.4f -> %.4f deg RMS%s\", \"moves\": %d, \"moves_heldout_before_rad\": %.6g, "
      "\"moves_heldout_after_rad\": %.6g, \"f\": %.4g, \"f_threshold\": %.4g, "
      "\"delta_bic\": %.4g}",
      Meaning(t.axis, t.regressor), chosen.score.f, threshold, tests, chosen.score.delta_bic,
      chosen.score.press_gain, chosen.score.trimmed_gain, static_cast<int>(kTrimmedMoves),
      threshold, before.RmsHeldOut() * kRadToDeg, after.RmsHeldOut() * kRadToDeg,
      rival_text.empty() ? "" : absl::StrCat("; not told apart from ", rival_text), moves,
      before.RmsHeldOut(), after.RmsHeldOut(), chosen.score.f, threshold, chosen.score.delta_bic);
}

// One search over a capture's moves: the stages of SearchMoveEffects, in the order it calls them.
class MoveSearch {
 public:
  MoveSearch(const MoveSearchInput& in, const MoveSearchOptions& opt, MoveSearchResult* out)
      : in_(in), opt_(opt), out_(*out), moves_(PrepareMoves(in)), turns_(PrepareTurns(in)) {}

  // The gyroscope fitted with the given terms alone. False (with the note why) when the moves
  // leave too few degrees of freedom to test a term; InvalidArgument for a given term that is
  // not one.
  absl::StatusOr<bool> FitGiven();
  // One round: candidates, screening, selection, refit. False when nothing entered.
  bool Round(int round);
  // The final coefficients, the turns against the moves, the notes.
  void Finish();

 private:
  // A round's candidates, scored at the current model.
  struct Screened {
    std::vector<Candidate> cands;
    int not_excited = 0;
    double rss0 = 0;
    int dof1 = 0;  // the degrees of freedom with one term more
  };
  // nullopt: too few degrees of freedom left for another term.
  std::optional<Screened> Screen() const;
  // The passing candidate with the lowest BIC, or -1.
  static int Test(double threshold, std::vector<Candidate>* cands);
  void Enter(const Candidate& chosen, const std::vector<Candidate>& cands, double threshold,
             int tests);
  void TurnsAgainstMoves();
  void Notes();

  const MoveSearchInput& in_;
  const MoveSearchOptions& opt_;
  MoveSearchResult& out_;
  const std::vector<Prepared> moves_, turns_;
  const std::vector<Regressor> dictionary_ = MoveDictionary();
  Model model_;
  int n_obs_ = 0;
  double floor_var_ = 0;
  MoveModelFit current_;
  std::vector<std::string> found_notes_;
};

absl::StatusOr<bool> MoveSearch::FitGiven() {
  model_.m = in_.matrix;
  for (const MoveGivenTerm& g : opt_.given) {
    const std::optional<Regressor> r = ParseRegressor(g.regressor);
    if (!r || g.axis < 0 || g.axis > 2)
      return absl::InvalidArgumentError(
          absl::StrFormat("given move term \"%s\" on axis %d", g.regressor, g.axis));
    model_.terms.push_back({g.axis, *r, 0.0});
  }
  const int iterations = Solve(moves_, turns_, &model_);
  out_.before = Analyse(model_, moves_, turns_, iterations);
  out_.ran = true;
  n_obs_ = out_.before.observations;
  for (const Prepared& m : moves_) floor_var_ += m.noise_var / static_cast<double>(moves_.size());
  out_.noise_floor_rad = std::sqrt(2 * floor_var_);
  if (n_obs_ - out_.before.rank < 4) {
    out_.notes.push_back(absl::StrFormat(
        "rotations between poses: %d constraints leave too few degrees of freedom beyond the "
        "gyroscope's %d parameters to test rate-dependent terms",
        n_obs_, out_.before.rank));
    out_.after = out_.before;
    return false;
  }
  for (size_t k = 0; k < model_.terms.size(); ++k) {
    Effect e;
    e.sensor = Sensor::kGyro;
    e.axis = model_.terms[k].axis;
    e.regressor = model_.terms[k].regressor.Name();
    e.coefficient = model_.terms[k].coefficient;
    e.std_error = out_.before.term_std_error[k];
    e.error_before = e.error_after = kNaN;
    e.evidence = "given: its form was stated, not searched for (fitted on the moves)";
    out_.effects.push_back(e);
  }
  current_ = out_.before;
  return true;
}

bool MoveSearch::Round(int round) {
  // -> candidates -> screening
  std::optional<Screened> s = Screen();
  if (!s) return false;
  const int tests = static_cast<int>(s->cands.size());
  if (round == 0) {
    out_.candidates = tests;
    out_.not_excited = s->not_excited;
  }
  ++out_.rounds;
  if (s->cands.empty()) return false;
  const double threshold = FThreshold(opt_.family_alpha, tests, s->dof1);
  // -> selection
  const int best = Test(threshold, &s->cands);
  if (std::getenv("IMUCAL_DEBUG_EFFECTS") != nullptr) DebugDump(round, s->cands);
  if (round == 0) KeepTop(s->cands, &out_.top);
  SetDetectionBounds(model_, moves_, in_.bias, s->cands, std::max(s->rss0 / s->dof1, floor_var_),
                     threshold, &out_);
  if (best < 0) return false;
  // -> refit with the winner in
  Enter(s->cands[static_cast<size_t>(best)], s->cands, threshold, tests);
  return true;
}

std::optional<MoveSearch::Screened> MoveSearch::Screen() const {
  const Linearisation lin = Linearise(model_, moves_, turns_);
  Screened out;
  out.rss0 = lin.r.squaredNorm();
  int rank = 0;
  PseudoInverse(lin.j.transpose() * lin.j, &rank);
  out.dof1 = n_obs_ - rank - 1;
  if (out.dof1 < 3) return std::nullopt;
  Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(lin.j);
  const Eigen::MatrixXd q =
      Eigen::MatrixXd(qr.householderQ()).leftCols(static_cast<Eigen::Index>(qr.rank()));
  const std::vector<double> press0_moves = LinearHeldOut(lin.j, lin.r, moves_.size());
  const double press0 = SumSquares(press0_moves);
  std::vector<MoveTerm> terms;
  for (int axis = 0; axis < 3; ++axis) {
    for (const Regressor& r : dictionary_) {
      bool present = false;
      for (const MoveTerm& t : model_.terms) present |= t.axis == axis && t.regressor == r;
      if (!present) terms.push_back({axis, r, 0.0});
    }
  }
  const Eigen::MatrixXd columns = CandidateColumns(model_, terms, moves_, turns_);
  Eigen::MatrixXd j_ext(lin.j.rows(), lin.j.cols() + 1);
  j_ext.leftCols(lin.j.cols()) = lin.j;
  for (size_t k = 0; k < terms.size(); ++k) {
    Candidate c;
    c.term = terms[k];
    const Eigen::VectorXd col = columns.col(static_cast<Eigen::Index>(k));
    c.perp = col - q * (q.transpose() * col);
    if (!col.allFinite() || col.norm() == 0 || c.perp.norm() <= kAbsorbedFraction * col.norm()) {
      ++out.not_excited;
      continue;
    }
    const double proj = c.perp.dot(lin.r);
    const double drss = proj * proj / c.perp.squaredNorm();
    const double rss1 = std::max(out.rss0 - drss, 1e-300);
    const double s2 = std::max(rss1 / out.dof1, floor_var_);
    MoveCandidateScore& s = c.score;
    s.axis = c.term.axis;
    s.regressor = c.term.regressor.Name();
    s.f = drss / s2;
    s.delta_bic = n_obs_ * std::log(rss1 / out.rss0) + std::log(static_cast<double>(n_obs_));
    s.coefficient = -proj / c.perp.squaredNorm();
    j_ext.rightCols<1>() = col;
    const std::vector<double> held = LinearHeldOut(j_ext, lin.r, moves_.size());
    s.press_gain = (press0 - SumSquares(held)) / s2;
    s.trimmed_gain = TrimmedGain(press0_moves, held) / s2;
    out.cands.push_back(std::move(c));
  }
  return out;
}

int MoveSearch::Test(double threshold, std::vector<Candidate>* cands) {
  int best = -1;
  for (size_t c = 0; c < cands->size(); ++c) {
    MoveCandidateScore& s = (*cands)[c].score;
    s.f_threshold = threshold;
    s.passed = s.f > threshold && s.delta_bic < 0 && s.press_gain > threshold &&
               s.trimmed_gain > threshold;
    if (s.passed && (best < 0 || s.delta_bic < (*cands)[static_cast<size_t>(best)].score.delta_bic))
      best = static_cast<int>(c);
  }
  return best;
}

void MoveSearch::Enter(const Candidate& chosen, const std::vector<Candidate>& cands,
                       double threshold, int tests) {
  const std::string rival_text = Rivals(chosen, cands);
  Model next = model_;
  MoveTerm t = chosen.term;
  t.coefficient = chosen.score.coefficient;
  next.terms.push_back(t);
  const int iterations = Solve(moves_, turns_, &next);
  const MoveModelFit fit = Analyse(next, moves_, turns_, iterations);
  model_ = next;
  Effect e;
  e.sensor = Sensor::kGyro;
  e.axis = t.axis;
  e.regressor = t.regressor.Name();
  e.coefficient = model_.terms.back().coefficient;
  e.std_error = fit.term_std_error.back();
  // A rate term does nothing at rest: the static residual is not its figure. The moves' are,
  // in the evidence.
  e.error_before = e.error_after = kNaN;
  e.evidence = Evidence(chosen, threshold, tests, rival_text, static_cast<int>(moves_.size()),
                        current_, fit);
  out_.effects.push_back(e);
  found_notes_.push_back(absl::StrFormat(
      "%s (%s; %s), held out by move %.3f -> %.3f deg RMS%s", Describe(t.axis, t.regressor),
      Meaning(t.axis, t.regressor), HumanMoveCoefficient(model_.terms.back(), e.std_error),
      current_.RmsHeldOut() * kRadToDeg, fit.RmsHeldOut() * kRadToDeg,
      rival_text.empty() ? "" : absl::StrCat("; the moves do not tell it from ", rival_text)));
  current_ = fit;
}

void MoveSearch::Finish() {
  out_.after = current_;
  // Every coefficient and standard error from the final fit (the given terms' included).
  for (size_t k = 0; k < out_.effects.size(); ++k) {
    out_.effects[k].coefficient = out_.after.terms[k].coefficient;
    out_.effects[k].std_error = out_.after.term_std_error[k];
  }
  if (!in_.turns.empty()) TurnsAgainstMoves();
  Notes();
}

// The turns against the moves: the moves alone fitted, each turn's angle.
void MoveSearch::TurnsAgainstMoves() {
  Model alone;
  alone.m = in_.matrix;
  Solve(moves_, {}, &alone);
  const Linearisation lin = Linearise(alone, moves_, {});
  int rank = 0;
  PseudoInverse(lin.j.transpose() * lin.j, &rank);
  if (rank == 9 && Observations(moves_.size(), {}) - rank >= 3) {
    for (const Prepared& t : turns_) {
      double angle = 0;
      TurnResidual(alone, t, nullptr, &angle);
      out_.turn_angle_moves_only_rad.push_back(angle);
    }
  }
}

void MoveSearch::Notes() {
  const double before_deg = out_.before.RmsHeldOut() * kRadToDeg;
  if (found_notes_.empty()) {
    std::string best;
    if (!out_.top.empty())
      best = absl::StrFormat("; the strongest, gyro %c ~ %s, F %.1f against %.1f",
                             kAxes[out_.top[0].axis], out_.top[0].regressor, out_.top[0].f,
                             out_.top[0].f_threshold);
    out_.notes.push_back(absl::StrFormat(
        "rotations between poses: no rate-dependent gyroscope term among %d tested on the %d "
        "moves%s. The gravity-direction error after the moves, held out by move, %.3f deg RMS "
        "(%.3f in-sample; the noise alone would leave %.3f)",
        out_.candidates, static_cast<int>(moves_.size()), best, before_deg,
        out_.before.RmsMoveError() * kRadToDeg, out_.noise_floor_rad * kRadToDeg));
  } else {
    std::string list;
    for (const std::string& n : found_notes_) list += (list.empty() ? "" : "; ") + n;
    out_.notes.push_back(absl::StrFormat(
        "rotations between poses: %s. The gravity-direction error after the %d moves, held out "
        "by move, %.3f -> %.3f deg RMS (the noise alone would leave %.3f)",
        list, static_cast<int>(moves_.size()), before_deg, out_.after.RmsHeldOut() * kRadToDeg,
        out_.noise_floor_rad * kRadToDeg));
  }
  if (!out_.turn_angle_moves_only_rad.empty()) {
    std::string angles;
    double worst = 0;
    for (size_t k = 0; k < out_.turn_angle_moves_only_rad.size(); ++k) {
      const double a = out_.turn_angle_moves_only_rad[k], nominal = turns_[k].angle;
      angles += absl::StrFormat("%s%.2f", angles.empty() ? "" : ", ", a * kRadToDeg);
      worst = std::max(worst, std::abs(a - nominal) / nominal);
    }
    out_.notes.push_back(absl::StrFormat(
        "full turns against the moves: fitted to the moves alone, the gyroscope reads the "
        "turns as %s deg (%.2f%% off whole turns at most)%s",
        angles, 100 * worst,
        worst > 0.005 ? ": the turns and the moves disagree on the scale, so a turn was not a "
                        "whole turn or the scale differs between them (rate, sense of rotation)"
                      : ""));
  }
}
}  // namespace
}  // namespace imucal::core::effects

namespace imucal::core {

MoveEffectDiagnostics MoveSearchResult::Diagnostics() const {
  MoveEffectDiagnostics d;
  d.ran = ran;
  d.moves = static_cast<int>(before.move_error_rad.size());
  d.candidates = candidates;
  d.not_excited = not_excited;
  d.rounds = rounds;
  d.heldout_before_rad = before.RmsHeldOut();
  d.heldout_after_rad = after.RmsHeldOut();
  d.in_sample_before_rad = before.RmsMoveError();
  d.in_sample_after_rad = after.RmsMoveError();
  d.noise_floor_rad = noise_floor_rad;
  d.heldout_before_per_move_rad = before.heldout_error_rad;
  d.heldout_after_per_move_rad = after.heldout_error_rad;
  d.top = top;
  d.turn_angle_moves_only_rad = turn_angle_moves_only_rad;
  d.detection_bounds = detection_bounds;
  return d;
}

double DetectableNoncentrality(int df, double threshold, double power) {
  if (!(threshold > 0) || !std::isfinite(threshold) || df < 1)
    return std::numeric_limits<double>::infinity();
  // The noncentrality at which P(chi2'(df, lambda) <= threshold) = 1 - power.
  return MathOr(std::numeric_limits<double>::infinity(), [&] {
    return boost::math::non_central_chi_squared_distribution<double>::find_non_centrality(
        static_cast<double>(df), threshold, 1 - power);
  });
}

absl::StatusOr<MoveSearchResult> SearchMoveEffects(const MoveSearchInput& in,
                                                   const MoveSearchOptions& opt) {
  MoveSearchResult out;
  if (in.t_s == nullptr || in.gyro_raw == nullptr) return absl::InvalidArgumentError("no samples");
  if (static_cast<int>(in.moves.size()) < effects::kMinMoves) {
    out.notes.push_back(absl::StrFormat(
        "rotations between poses: %d moves, too few to test rate-dependent gyroscope terms "
        "(at least %d)",
        static_cast<int>(in.moves.size()), effects::kMinMoves));
    return out;
  }
  if (absl::Status s = ValidateGyroMoves(*in.t_s, *in.gyro_raw, in.moves); !s.ok()) return s;
  effects::MoveSearch search(in, opt, &out);
  // -> the gyroscope with the given terms alone
  absl::StatusOr<bool> testable = search.FitGiven();
  if (!testable.ok()) return testable.status();
  if (!*testable) return out;
  // -> rounds: candidates, screening, selection, refit
  for (int round = 0; round < opt.max_terms; ++round)
    if (!search.Round(round)) break;
  // -> report
  search.Finish();
  return out;
}
}  // namespace imucal::core
