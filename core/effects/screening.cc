// Stage "screening" of the effect search (search.h): each candidate of the round scored by
// linearised least squares against the current weighted design (the Scorer: F against the
// residual variance, never below the noise level; the change in BIC; the held-out weighted sum of
// squares, leave-one-pose-out), then tested (SELECTION in core/effects.h, conditions 1-3 at the
// family alpha over the round's candidates).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

#include "Eigen/Dense"
#include "boost/math/distributions/fisher_f.hpp"
#include "core/effects/search.h"
#include "core/math_guard.h"

namespace imucal::core::effects {
namespace {

// An effect candidate scored on its columns (its lower powers' first). The accelerometer column
// is d r / d c = -n x: the coefficient has the opposite sign of the projection.
bool ScoreEffect(const Scorer& scorer, const Eigen::MatrixXd& cols, RoundCandidate* c) {
  Eigen::VectorXd coefficients;
  if (!scorer.Score(cols, &c->score, &c->perp, &coefficients)) return false;
  if (c->score.sensor == Sensor::kAccel) coefficients = -coefficients;
  c->score.coefficient = coefficients(coefficients.size() - 1);
  for (size_t g = 0; g < c->lower.size(); ++g)
    c->lower_coefficients.push_back(coefficients(static_cast<Eigen::Index>(g)));
  return true;
}

// A held parameter scored on its column of the |a| - g Jacobian `j` (weighted like the design).
bool ScoreHeld(const RoundDesigns& d, const Eigen::MatrixXd& j, RoundCandidate* c) {
  const Eigen::Index n = j.rows();
  Eigen::MatrixXd col(n, 1);
  for (Eigen::Index i = 0; i < n; ++i)
    col(i, 0) = j(i, c->model_param) * d.accel.weight[static_cast<size_t>(i)];
  Eigen::VectorXd coefficients;
  if (!d.accel_scorer->Score(col, &c->score, &c->perp, &coefficients)) return false;
  c->score.coefficient = -c->score.coefficient;  // the Gauss-Newton step of the parameter
  return true;
}

}  // namespace

Scorer::Scorer(const Design& d)
    : r_(d.r), rows_(d.x.rows()), n_(d.x.rows() - d.prior_rows), noise_s2_(d.noise_s2) {
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(d.x);
  q_ = qr.householderQ() * Eigen::MatrixXd::Identity(rows_, d.x.cols());
  h_ = q_.rowwise().squaredNorm();
  p_ = h_.head(n_).sum();
  rss_ = r_.squaredNorm();
}

double Scorer::LastBeyond(const Eigen::MatrixXd& pose_cols) const {
  const Eigen::MatrixXd cols = Padded(pose_cols);
  Eigen::MatrixXd p = cols - q_ * (q_.transpose() * cols);
  const Eigen::Index k = p.cols();
  Eigen::VectorXd last = p.col(k - 1);
  if (k > 1) {
    const Eigen::HouseholderQR<Eigen::MatrixXd> qr(p.leftCols(k - 1));
    const Eigen::MatrixXd qo = qr.householderQ() * Eigen::MatrixXd::Identity(rows_, k - 1);
    last -= qo * (qo.transpose() * last);
  }
  return last.norm();
}

bool Scorer::Score(const Eigen::MatrixXd& pose_cols, CandidateScore* s, Eigen::VectorXd* perp,
                   Eigen::VectorXd* coefficients) const {
  const Eigen::MatrixXd cols = Padded(pose_cols);
  const Eigen::MatrixXd p = cols - q_ * (q_.transpose() * cols);
  const Eigen::Index k = cols.cols();
  for (Eigen::Index c = 0; c < k; ++c) {
    const double norm2 = p.col(c).squaredNorm();
    if (!(norm2 > kAbsorbedFraction * kAbsorbedFraction * cols.col(c).squaredNorm()) || norm2 <= 0)
      return false;
  }
  // Frisch-Waugh: the columns' coefficients in the joint fit are those of the residual on
  // their part orthogonal to the model.
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(p);
  const Eigen::MatrixXd qp = qr.householderQ() * Eigen::MatrixXd::Identity(rows_, k);
  const Eigen::MatrixXd rp = qr.matrixQR().topRows(k).triangularView<Eigen::Upper>();
  if (std::abs(rp.diagonal().prod()) <= 0) return false;
  const Eigen::VectorXd qr_r = qp.transpose() * r_;
  const double drss = qr_r.squaredNorm();
  *coefficients = rp.triangularView<Eigen::Upper>().solve(qr_r);
  *perp = qp * qr_r;  // = p * coefficients
  const double rss_after = std::max(1e-300, rss_ - drss);
  const double s2 =
      std::max(noise_s2_, rss_after / std::max(1.0, static_cast<double>(n_ - k) - p_));
  s->f = drss / static_cast<double>(k) / s2;
  const double n = static_cast<double>(n_);
  s->delta_bic = n * std::log(rss_after / rss_) + static_cast<double>(k) * std::log(n);
  // Held-out: leave-one-out residuals e_i / (1 - h_ii) before and after adding the columns.
  double press_before = 0, press_after = 0;
  for (Eigen::Index i = 0; i < n_; ++i) {
    const double before = r_(i) / std::max(1e-9, 1 - h_(i));
    const double after = (r_(i) - (*perp)(i)) / std::max(1e-9, 1 - h_(i) - qp.row(i).squaredNorm());
    press_before += before * before;
    press_after += after * after;
  }
  s->press_gain = (press_before - press_after) / s2;
  s->coefficient = (*coefficients)(k - 1);  // the last column's; the caller converts
  return true;
}

Eigen::MatrixXd Scorer::Padded(const Eigen::MatrixXd& pose_cols) const {
  Eigen::MatrixXd cols = Eigen::MatrixXd::Zero(rows_, pose_cols.cols());
  cols.topRows(pose_cols.rows()) = pose_cols;
  return cols;
}

double FThreshold(double alpha, int tests, Eigen::Index dof, int df1) {
  if (dof < 1 || tests < 1) return std::numeric_limits<double>::infinity();
  return MathOr(std::numeric_limits<double>::infinity(), [&] {
    const boost::math::fisher_f_distribution<double> f(static_cast<double>(df1),
                                                       static_cast<double>(dof));
    return boost::math::quantile(boost::math::complement(f, alpha / tests));
  });
}

Eigen::Index Search::DofAfter(const State& st, Sensor sensor, int axis) const {
  const auto n = static_cast<Eigen::Index>(poses_.size());
  Eigen::Index p = 0;
  if (sensor == Sensor::kAccel) {
    // What the poses pay for at the round's state (Screen): the priors' share excluded.
    p = static_cast<Eigen::Index>(std::ceil(accel_pays_for_ - 1e-9));
  } else {
    p = 1;
    for (const Term& t : st.terms) p += t.sensor == Sensor::kGyro && t.axis == axis;
  }
  return n - p - 1;
}

// Also keeps what the accelerometer's poses pay for (DofAfter).
RoundDesigns Search::DesignsAt(const State& st) {
  RoundDesigns d;
  SetAccelModelSigma(st, st.free, signals_, in_.gravity_m_s2, &poses_);
  d.accel_poses = AccelPoses(poses_);
  d.accel = AccelDesign(st, d.accel_poses, st.free, signals_, in_.gravity_m_s2);
  d.accel_scorer = std::make_unique<Scorer>(d.accel);
  accel_pays_for_ = d.accel_scorer->pays_for();
  for (int j = 0; j < 3; ++j) {
    std::vector<const Term*> terms;
    for (const Term& t : st.terms)
      if (t.sensor == Sensor::kGyro && t.axis == j) terms.push_back(&t);
    const GyroAxisFit g = FitGyroAxis(j, rates_, gyro_sigma_, GyroTau(j, terms), terms, signals_);
    d.gyro_scorer[static_cast<size_t>(j)] = std::make_unique<Scorer>(g.design);
    d.gyro_weight[static_cast<size_t>(j)] = g.design.weight;
  }
  return d;
}

// A candidate's weighted columns, a row per pose and one column per regressor of `group`:
// an accelerometer term's trace on |a| - g, a gyroscope term's on the static rate.
Eigen::MatrixXd Search::CandidateColumns(const RoundDesigns& d, const State& st, Sensor sensor,
                                         int axis, const std::vector<Regressor>& group) const {
  const auto n = static_cast<Eigen::Index>(poses_.size());
  Eigen::MatrixXd cols(n, static_cast<Eigen::Index>(group.size()));
  for (Eigen::Index i = 0; i < n; ++i) {
    const auto ii = static_cast<size_t>(i);
    for (size_t g = 0; g < group.size(); ++g) {
      const double x = group[g].Evaluate(signals_[ii]);
      cols(i, static_cast<Eigen::Index>(g)) =
          sensor == Sensor::kAccel
              ? AccelEffectDerivative(st.accel, d.accel_poses[ii], axis, x) * d.accel.weight[ii]
              : x * d.gyro_weight[static_cast<size_t>(axis)][ii];
    }
  }
  return cols;
}

std::vector<RoundCandidate> Search::Screen(const State& st, std::vector<RoundCandidate> proposed,
                                           int* absorbed) {
  const RoundDesigns designs = DesignsAt(st);
  std::optional<Eigen::MatrixXd> jacobian;  // of |a| - g, for the held parameters
  std::vector<RoundCandidate> out;
  for (RoundCandidate& c : proposed) {
    if (c.model_param >= 0) {
      if (!jacobian) jacobian = MagnitudeJacobian(st.accel, designs.accel_poses);
      if (ScoreHeld(designs, *jacobian, &c)) out.push_back(std::move(c));
      continue;
    }
    std::vector<Regressor> group = c.lower;
    group.push_back(c.regressor);
    const Eigen::MatrixXd cols = CandidateColumns(designs, st, c.score.sensor, c.score.axis, group);
    if (ScoreEffect(designs.For(c.score.sensor, c.score.axis), cols, &c)) {
      out.push_back(std::move(c));
    } else {
      ++*absorbed;
    }
  }
  return out;
}

int Search::Test(const State& st, std::vector<RoundCandidate>* cands) const {
  const int tests = static_cast<int>(cands->size());
  int best = -1;
  for (size_t c = 0; c < cands->size(); ++c) {
    CandidateScore& s = (*cands)[c].score;
    const auto k = static_cast<int>(1 + (*cands)[c].lower.size());
    s.f_threshold =
        FThreshold(opt_.family_alpha, tests, DofAfter(st, s.sensor, s.axis) - (k - 1), k);
    // The held-out margin is the same F* s^2 per column entering.
    s.passed = s.f > s.f_threshold && s.delta_bic < 0 && s.press_gain > k * s.f_threshold;
    // Ranked by BIC, which compares candidates of different axes on one scale.
    if (s.passed && (best < 0 || s.delta_bic < (*cands)[static_cast<size_t>(best)].score.delta_bic))
      best = static_cast<int>(c);
  }
  return best;
}

void DebugDump(int round, const std::vector<RoundCandidate>& cands) {
  std::vector<RoundCandidate> sorted = cands;
  std::sort(sorted.begin(), sorted.end(),
            [](const auto& a, const auto& b) { return a.score.f > b.score.f; });
  for (size_t k = 0; k < 6 && k < sorted.size(); ++k) {
    const auto& sc = sorted[k].score;
    fprintf(stderr, "round %d: %s %s %s F %.1f thr %.1f bic %.1f press %.1f c %.3g %s\n", round,
            SensorName(sc.sensor), AxisName(sc.axis), sc.regressor.c_str(), sc.f, sc.f_threshold,
            sc.delta_bic, sc.press_gain, sc.coefficient, sc.passed ? "PASS" : "");
  }
}

}  // namespace imucal::core::effects
