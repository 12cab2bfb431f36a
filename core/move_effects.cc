#include "core/move_effects.h"

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
#include "boost/math/distributions/fisher_f.hpp"
#include "boost/math/distributions/non_central_chi_squared.hpp"
#include "core/so3.h"

namespace imucal::core {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kRadToDeg = 180.0 / M_PI;
constexpr char kAxes[] = "xyz";
// A candidate whose column keeps less than this fraction of its norm once the model's columns
// are projected out is not excited by the moves beyond the model (core/effects.cc's rule).
constexpr double kAbsorbedFraction = 1e-3;
// Named together with the chosen term: collinear beyond the model and close in BIC
// (core/effects.h, Kass and Raftery's "positive, not strong").
constexpr double kAmbiguousCorrelation = 0.9;
constexpr double kWeakEvidenceBic = 6.0;
// Eigenvalues of J^T J below this fraction of the largest are treated as zero.
constexpr double kNullEigenvalueRatio = 1e-14;
constexpr int kMinMoves = 6;
constexpr int kTopCandidates = 5;

// At most this many parameters (vec(M) and the terms): fixed-capacity matrices keep the
// per-sample Jacobian off the heap.
constexpr int kMaxParams = 32;
using Mat3X = Eigen::Matrix<double, 3, Eigen::Dynamic, 0, 3, kMaxParams>;

// One move or turn, ready to integrate: the debiased raw samples u_k and the steps dt_k.
struct Prepared {
  std::vector<Eigen::Vector3d> u;
  std::vector<double> dt;  // u.size() - 1
  Eigen::Vector3d up_before = Eigen::Vector3d::UnitZ();
  Eigen::Vector3d up_after = Eigen::Vector3d::UnitZ();
  // Turns: the known axis (zero when unknown) and angle.
  Eigen::Vector3d axis = Eigen::Vector3d::Zero();
  double angle = 0;
  double noise_var = 0;  // per residual component, from the noise alone (moves)
};

Prepared Prepare(const MoveSearchInput& in, size_t begin, size_t end,
                 const Eigen::Vector3d& bias_before, const Eigen::Vector3d& bias_after) {
  const std::vector<double>& t = *in.t_s;
  const std::vector<Eigen::Vector3d>& g = *in.gyro_raw;
  Prepared p;
  const double span = t[end] - t[begin];
  for (size_t k = begin; k <= end; ++k) {
    Eigen::Vector3d b = in.bias;
    if (in.interpolate_bias) {
      const double alpha = (t[k] - t[begin]) / span;
      b = bias_before + alpha * (bias_after - bias_before);
    }
    p.u.push_back(g[k] - b);
    if (k < end) p.dt.push_back(t[k + 1] - t[k]);
  }
  return p;
}

std::vector<Prepared> PrepareMoves(const MoveSearchInput& in) {
  std::vector<Prepared> out;
  for (const GyroMove& m : in.moves) {
    Prepared p = Prepare(in, m.begin, m.end, m.bias_before, m.bias_after);
    p.up_before = m.up_before.normalized();
    p.up_after = m.up_after.normalized();
    double dt2 = 0;
    for (double d : p.dt) dt2 += d * d;
    p.noise_var =
        in.gyro_noise_rad_s * in.gyro_noise_rad_s * dt2 + 2 * in.up_noise_rad * in.up_noise_rad;
    out.push_back(std::move(p));
  }
  return out;
}

std::vector<Prepared> PrepareTurns(const MoveSearchInput& in) {
  std::vector<Prepared> out;
  for (const GyroFullTurn& turn : in.turns) {
    Prepared p = Prepare(in, turn.begin, turn.end, turn.bias_before, turn.bias_after);
    if (turn.axis.squaredNorm() > 0) p.axis = turn.axis.normalized();
    p.angle = turn.angle_rad;
    out.push_back(std::move(p));
  }
  return out;
}

Eigen::Quaterniond ExpQ(const Eigen::Vector3d& phi) {
  const double t2 = phi.squaredNorm();
  double w, s;
  if (t2 < 1e-8) {
    w = 1.0 - t2 / 8.0;
    s = 0.5 - t2 / 48.0;
  } else {
    const double t = std::sqrt(t2);
    w = std::cos(0.5 * t);
    s = std::sin(0.5 * t) / t;
  }
  return Eigen::Quaterniond(w, s * phi.x(), s * phi.y(), s * phi.z());
}

// The model: M and the terms, with their parameter vector theta = (vec(M), c_1..c_T).
struct Model {
  Eigen::Matrix3d m = Eigen::Matrix3d::Identity();
  std::vector<MoveTerm> terms;

  int Params() const { return 9 + static_cast<int>(terms.size()); }
  Eigen::VectorXd Theta() const {
    Eigen::VectorXd th(Params());
    th.head<9>() = Eigen::Map<const Eigen::Matrix<double, 9, 1>>(m.data());
    for (size_t t = 0; t < terms.size(); ++t)
      th(9 + static_cast<Eigen::Index>(t)) = terms[t].coefficient;
    return th;
  }
  void SetTheta(const Eigen::VectorXd& th) {
    m = Eigen::Map<const Eigen::Matrix3d>(th.data());
    for (size_t t = 0; t < terms.size(); ++t)
      terms[t].coefficient = th(9 + static_cast<Eigen::Index>(t));
  }
};

SignalArray RateSignals(const Eigen::Vector3d& v) {
  SignalArray s{};
  s[static_cast<size_t>(Signal::kGx)] = v.x();
  s[static_cast<size_t>(Signal::kGy)] = v.y();
  s[static_cast<size_t>(Signal::kGz)] = v.z();
  return s;
}

// d regressor / d (gx, gy, gz) at `s` (the product rule; d|v|/dv = sign v).
Eigen::Vector3d RateGradient(const Regressor& r, const SignalArray& s) {
  Eigen::Vector3d grad = Eigen::Vector3d::Zero();
  for (int i = 0; i < r.num_factors; ++i) {
    const int sig = r.factors[static_cast<size_t>(i)];
    if (sig < static_cast<int>(Signal::kGx)) continue;  // not a rate: constant here
    const double v = s[static_cast<size_t>(sig)];
    double d = r.absolute[static_cast<size_t>(i)] ? (v > 0 ? 1.0 : v < 0 ? -1.0 : 0.0) : 1.0;
    for (int j = 0; j < r.num_factors; ++j) {
      if (j == i) continue;
      const auto sj = static_cast<size_t>(r.factors[static_cast<size_t>(j)]);
      const double x = s[sj] - r.centre[sj];
      d *= r.absolute[static_cast<size_t>(j)] ? std::abs(x) : x;
    }
    grad(sig - static_cast<int>(Signal::kGx)) += d;
  }
  return grad;
}

// The corrected rate of one sample and, when `dw` is not null, its derivative (3 x P).
Eigen::Vector3d Rate(const Model& model, const Eigen::Vector3d& u, Mat3X* dw) {
  const Eigen::Vector3d v = model.m * u;
  if (model.terms.empty() && dw == nullptr) return v;
  const SignalArray s = RateSignals(v);
  Eigen::Vector3d w = v;
  Eigen::Matrix3d a = Eigen::Matrix3d::Identity();
  if (dw != nullptr) dw->resize(3, model.Params());
  for (size_t t = 0; t < model.terms.size(); ++t) {
    const MoveTerm& term = model.terms[t];
    const double x = term.regressor.Evaluate(s);
    w(term.axis) -= term.coefficient * x;
    if (dw == nullptr) continue;
    a.row(term.axis) -= term.coefficient * RateGradient(term.regressor, s).transpose();
    dw->col(9 + static_cast<Eigen::Index>(t)).setZero();
    (*dw)(term.axis, 9 + static_cast<Eigen::Index>(t)) = -x;
  }
  if (dw != nullptr)
    for (int c = 0; c < 3; ++c) dw->middleCols<3>(3 * c) = u(c) * a;
  return w;
}

// The residual of a move (3-vector) and, when `jacobian` is not null, dr/dtheta (3 x P).
Eigen::Vector3d MoveResidual(const Model& model, const Prepared& mv, Mat3X* jacobian) {
  const size_t n = mv.u.size();
  if (jacobian == nullptr) {
    Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
    Eigen::Vector3d w0 = Rate(model, mv.u[0], nullptr);
    for (size_t k = 0; k + 1 < n; ++k) {
      const Eigen::Vector3d w1 = Rate(model, mv.u[k + 1], nullptr);
      q = q * ExpQ(0.5 * (w0 + w1) * mv.dt[k]);
      w0 = w1;
    }
    return q.normalized().toRotationMatrix().transpose() * mv.up_before - mv.up_after;
  }
  const int p = model.Params();
  Eigen::Matrix3d r = Eigen::Matrix3d::Identity(), jr, g;
  Mat3X b = Mat3X::Zero(3, p), dw0, dw1, dphi(3, p);
  Eigen::Vector3d w0 = Rate(model, mv.u[0], &dw0);
  for (size_t k = 0; k + 1 < n; ++k) {
    const Eigen::Vector3d w1 = Rate(model, mv.u[k + 1], &dw1);
    const Eigen::Vector3d phi = 0.5 * (w0 + w1) * mv.dt[k];
    r = r * ExpAndRightJacobian(phi, &jr);
    g.noalias() = r * jr;
    dphi = (0.5 * mv.dt[k]) * (dw0 + dw1);
    b.noalias() += g * dphi;
    w0 = w1;
    std::swap(dw0, dw1);
  }
  const Eigen::Vector3d predicted = r.transpose() * mv.up_before;
  *jacobian = Skew(predicted) * r.transpose() * b;
  return predicted - mv.up_after;
}

// A turn: sum_k phi_k - angle axis (axis known), or (|sum_k phi_k| - angle, 0, 0).
Eigen::Vector3d TurnResidual(const Model& model, const Prepared& turn, Mat3X* jacobian,
                             double* angle = nullptr) {
  const size_t n = turn.u.size();
  const int p = model.Params();
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  Mat3X dsum = Mat3X::Zero(3, p), dw0, dw1;
  Mat3X* d0 = jacobian != nullptr ? &dw0 : nullptr;
  Mat3X* d1 = jacobian != nullptr ? &dw1 : nullptr;
  Eigen::Vector3d w0 = Rate(model, turn.u[0], d0);
  for (size_t k = 0; k + 1 < n; ++k) {
    const Eigen::Vector3d w1 = Rate(model, turn.u[k + 1], d1);
    sum += 0.5 * (w0 + w1) * turn.dt[k];
    if (jacobian != nullptr) {
      dsum += (0.5 * turn.dt[k]) * (dw0 + dw1);
      std::swap(dw0, dw1);
    }
    w0 = w1;
  }
  if (angle != nullptr) *angle = sum.norm();
  if (turn.axis.squaredNorm() > 0) {
    if (jacobian != nullptr) *jacobian = dsum;
    return sum - turn.angle * turn.axis;
  }
  const double norm = sum.norm();
  if (jacobian != nullptr) {
    *jacobian = Mat3X::Zero(3, p);
    if (norm > 0) jacobian->row(0) = (sum / norm).transpose() * dsum;
  }
  return Eigen::Vector3d(norm - turn.angle, 0, 0);
}

double AngleError(const Eigen::Vector3d& r, const Prepared& mv) {
  const Eigen::Vector3d predicted = r + mv.up_after;
  return std::atan2(predicted.cross(mv.up_after).norm(), predicted.dot(mv.up_after));
}

// The stacked residuals (3 per move, then 3 per turn) and Jacobian at `model`.
struct Linearisation {
  Eigen::VectorXd r;
  Eigen::MatrixXd j;
};

Linearisation Linearise(const Model& model, const std::vector<Prepared>& moves,
                        const std::vector<Prepared>& turns, bool with_jacobian = true) {
  const auto rows = static_cast<Eigen::Index>(3 * (moves.size() + turns.size()));
  Linearisation lin;
  lin.r.resize(rows);
  if (with_jacobian) lin.j.resize(rows, model.Params());
  Mat3X jac;
  Eigen::Index row = 0;
  for (const Prepared& mv : moves) {
    lin.r.segment<3>(row) = MoveResidual(model, mv, with_jacobian ? &jac : nullptr);
    if (with_jacobian) lin.j.middleRows<3>(row) = jac;
    row += 3;
  }
  for (const Prepared& t : turns) {
    lin.r.segment<3>(row) = TurnResidual(model, t, with_jacobian ? &jac : nullptr);
    if (with_jacobian) lin.j.middleRows<3>(row) = jac;
    row += 3;
  }
  return lin;
}

// Pseudo-inverse of a symmetric PSD matrix, and its rank.
Eigen::MatrixXd PseudoInverse(const Eigen::MatrixXd& h, int* rank = nullptr) {
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(h);
  const Eigen::VectorXd& values = eig.eigenvalues();
  const double cutoff = kNullEigenvalueRatio * std::max(values.maxCoeff(), 0.0);
  Eigen::MatrixXd out = Eigen::MatrixXd::Zero(h.rows(), h.cols());
  int r = 0;
  for (Eigen::Index i = 0; i < values.size(); ++i) {
    if (!(values(i) > cutoff && values(i) > 0)) continue;
    const Eigen::VectorXd v = eig.eigenvectors().col(i);
    out += v * v.transpose() / values(i);
    ++r;
  }
  if (rank != nullptr) *rank = r;
  return out;
}

int Observations(size_t moves, const std::vector<Prepared>& turns) {
  int n = 2 * static_cast<int>(moves);
  for (const Prepared& t : turns) n += t.axis.squaredNorm() > 0 ? 3 : 1;
  return n;
}

// Levenberg-Marquardt (Marquardt's diagonal scaling) from `model`.
int Solve(const std::vector<Prepared>& moves, const std::vector<Prepared>& turns, Model* model,
          int max_iterations = 50) {
  Linearisation lin = Linearise(*model, moves, turns);
  double cost = lin.r.squaredNorm();
  double lambda = 1e-4;
  int it = 0;
  for (; it < max_iterations; ++it) {
    const Eigen::MatrixXd h = lin.j.transpose() * lin.j;
    const Eigen::VectorXd g = lin.j.transpose() * lin.r;
    bool improved = false;
    for (int tries = 0; tries < 12 && !improved; ++tries) {
      Eigen::MatrixXd a = h;
      for (Eigen::Index i = 0; i < a.rows(); ++i) a(i, i) += lambda * std::max(h(i, i), 1e-300);
      const Eigen::VectorXd step = -PseudoInverse(a) * g;
      Model trial = *model;
      trial.SetTheta(model->Theta() + step);
      const double trial_cost = Linearise(trial, moves, turns, false).r.squaredNorm();
      if (std::isfinite(trial_cost) && trial_cost <= cost) {
        const double change = cost - trial_cost;
        const bool small_step = step.norm() <= 1e-10 * (model->Theta().norm() + 1e-10);
        *model = trial;
        lin = Linearise(*model, moves, turns);
        improved = true;
        lambda = std::max(lambda / 10, 1e-12);
        if (change <= 1e-12 * cost || small_step) return it + 1;
        cost = trial_cost;
      } else {
        lambda *= 10;
      }
    }
    if (!improved) break;
  }
  return it;
}

// Leave-one-move-out at `model` (first order): for each move, one Gauss-Newton step without
// it, then the move integrated exactly with the result. `extra` (may be empty) is a candidate's
// column appended to the Jacobian, `extra_term` its term (coefficient 0 at `model`).
std::vector<double> HeldOut(const Model& model, const Linearisation& lin,
                            const std::vector<Prepared>& moves, const Eigen::VectorXd& extra,
                            const MoveTerm* extra_term) {
  Eigen::MatrixXd j = lin.j;
  if (extra.size() > 0) {
    j.conservativeResize(Eigen::NoChange, j.cols() + 1);
    j.col(j.cols() - 1) = extra;
  }
  const Eigen::MatrixXd h = j.transpose() * j;
  const Eigen::VectorXd g = j.transpose() * lin.r;
  std::vector<double> out;
  for (size_t i = 0; i < moves.size(); ++i) {
    const auto row = static_cast<Eigen::Index>(3 * i);
    const Eigen::MatrixXd ji = j.middleRows<3>(row);
    const Eigen::VectorXd step =
        -PseudoInverse(h - ji.transpose() * ji) * (g - ji.transpose() * lin.r.segment<3>(row));
    Model without = model;
    if (extra_term != nullptr) without.terms.push_back(*extra_term);
    without.SetTheta(without.Theta() + step);
    out.push_back(AngleError(MoveResidual(without, moves[i], nullptr), moves[i]));
  }
  return out;
}

double SumSquares(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x * x;
  return s;
}

double Rms(const std::vector<double>& v) {
  return v.empty() ? kNaN : std::sqrt(SumSquares(v) / static_cast<double>(v.size()));
}

MoveModelFit Analyse(const Model& model, const std::vector<Prepared>& moves,
                     const std::vector<Prepared>& turns, int iterations) {
  MoveModelFit fit;
  fit.matrix = model.m;
  fit.terms = model.terms;
  fit.iterations = iterations;
  const Linearisation lin = Linearise(model, moves, turns);
  fit.rss = lin.r.squaredNorm();
  fit.observations = Observations(moves.size(), turns);
  const Eigen::MatrixXd pinv = PseudoInverse(lin.j.transpose() * lin.j, &fit.rank);
  const int dof = fit.observations - fit.rank;
  fit.covariance = (dof > 0 ? fit.rss / dof : kNaN) * pinv;
  for (size_t t = 0; t < model.terms.size(); ++t) {
    const auto k = static_cast<Eigen::Index>(9 + t);
    fit.term_std_error.push_back(std::sqrt(std::max(0.0, fit.covariance(k, k))));
  }
  for (size_t i = 0; i < moves.size(); ++i) {
    fit.move_residual.push_back(lin.r.segment<3>(static_cast<Eigen::Index>(3 * i)));
    fit.move_error_rad.push_back(AngleError(fit.move_residual.back(), moves[i]));
  }
  fit.heldout_error_rad = HeldOut(model, lin, moves, Eigen::VectorXd(), nullptr);
  for (const Prepared& t : turns) {
    double angle = 0;
    TurnResidual(model, t, nullptr, &angle);
    fit.turn_angle_rad.push_back(angle);
  }
  return fit;
}

double FThreshold(double alpha, int tests, int dof) {
  if (dof < 1 || tests < 1) return std::numeric_limits<double>::infinity();
  const boost::math::fisher_f_distribution<double> f(1.0, static_cast<double>(dof));
  return boost::math::quantile(boost::math::complement(f, alpha / tests));
}

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
                             fastest(axis) * 180.0 / M_PI, kAxes[axis]);
    out->detection_bounds.push_back(std::move(b));
  }
}

}  // namespace

double MoveModelFit::RmsMoveError() const { return Rms(move_error_rad); }

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
  return boost::math::non_central_chi_squared_distribution<double>::find_non_centrality(
      static_cast<double>(df), threshold, 1 - power);
}
double MoveModelFit::RmsHeldOut() const { return Rms(heldout_error_rad); }

std::vector<Regressor> MoveDictionary() {
  std::vector<Regressor> out;
  const int gx = static_cast<int>(Signal::kGx);
  for (int k = 0; k < 3; ++k) {
    Regressor scale;  // gk*|gk|
    scale.factors[0] = scale.factors[1] = gx + k;
    scale.absolute[1] = true;
    scale.num_factors = 2;
    out.push_back(scale);
    Regressor asym;  // |gk|
    asym.factors[0] = gx + k;
    asym.absolute[0] = true;
    asym.num_factors = 1;
    out.push_back(asym);
    for (int l = k; l < 3; ++l) {  // gk^2, gk*gl
      Regressor sq;
      sq.factors[0] = gx + k;
      sq.factors[1] = gx + l;
      sq.num_factors = 2;
      out.push_back(sq);
    }
  }
  return out;
}

absl::StatusOr<MoveModelFit> FitMoveModel(const MoveSearchInput& in,
                                          const std::vector<MoveTerm>& terms) {
  if (in.t_s == nullptr || in.gyro_raw == nullptr) return absl::InvalidArgumentError("no samples");
  if (absl::Status s = ValidateGyroMoves(*in.t_s, *in.gyro_raw, in.moves); !s.ok()) return s;
  for (size_t i = 0; i < in.turns.size(); ++i) {
    const GyroFullTurn& t = in.turns[i];
    if (!(t.begin < t.end) || t.end >= in.t_s->size() || !(t.angle_rad > 0))
      return absl::InvalidArgumentError(absl::StrCat("turn ", i, ": cannot be integrated"));
  }
  for (const MoveTerm& t : terms)
    if (t.axis < 0 || t.axis > 2) return absl::InvalidArgumentError("term axis not x, y or z");
  if (in.moves.size() < 3 && in.turns.empty())
    return absl::FailedPreconditionError("fewer than 3 moves between static poses");
  const std::vector<Prepared> moves = PrepareMoves(in);
  const std::vector<Prepared> turns = PrepareTurns(in);
  Model model;
  model.m = in.matrix;
  model.terms = terms;
  const int it = Solve(moves, turns, &model);
  return Analyse(model, moves, turns, it);
}

absl::StatusOr<MoveSearchResult> SearchMoveEffects(const MoveSearchInput& in,
                                                   const MoveSearchOptions& opt) {
  MoveSearchResult out;
  if (in.t_s == nullptr || in.gyro_raw == nullptr) return absl::InvalidArgumentError("no samples");
  if (static_cast<int>(in.moves.size()) < kMinMoves) {
    out.notes.push_back(absl::StrFormat(
        "rotations between poses: %d moves, too few to test rate-dependent gyroscope terms "
        "(at least %d)",
        static_cast<int>(in.moves.size()), kMinMoves));
    return out;
  }
  if (absl::Status s = ValidateGyroMoves(*in.t_s, *in.gyro_raw, in.moves); !s.ok()) return s;
  const std::vector<Prepared> moves = PrepareMoves(in);
  const std::vector<Prepared> turns = PrepareTurns(in);
  Model model;
  model.m = in.matrix;
  for (const MoveGivenTerm& g : opt.given) {
    const std::optional<Regressor> r = ParseRegressor(g.regressor);
    if (!r || g.axis < 0 || g.axis > 2)
      return absl::InvalidArgumentError(
          absl::StrFormat("given move term \"%s\" on axis %d", g.regressor, g.axis));
    model.terms.push_back({g.axis, *r, 0.0});
  }
  int iterations = Solve(moves, turns, &model);
  out.before = Analyse(model, moves, turns, iterations);
  out.ran = true;
  const int n_obs = out.before.observations;
  double floor_var = 0;
  for (const Prepared& m : moves) floor_var += m.noise_var / static_cast<double>(moves.size());
  out.noise_floor_rad = std::sqrt(2 * floor_var);
  if (n_obs - out.before.rank < 4) {
    out.notes.push_back(absl::StrFormat(
        "rotations between poses: %d constraints leave too few degrees of freedom beyond the "
        "gyroscope's %d parameters to test rate-dependent terms",
        n_obs, out.before.rank));
    out.after = out.before;
    return out;
  }
  for (size_t k = 0; k < model.terms.size(); ++k) {
    Effect e;
    e.sensor = Sensor::kGyro;
    e.axis = model.terms[k].axis;
    e.regressor = model.terms[k].regressor.Name();
    e.coefficient = model.terms[k].coefficient;
    e.std_error = out.before.term_std_error[k];
    e.error_before = e.error_after = kNaN;
    e.evidence = "given: its form was stated, not searched for (fitted on the moves)";
    out.effects.push_back(e);
  }

  const std::vector<Regressor> dictionary = MoveDictionary();
  MoveModelFit current = out.before;
  std::vector<std::string> found_notes;
  for (int round = 0; round < opt.max_terms; ++round) {
    const Linearisation lin = Linearise(model, moves, turns);
    const double rss0 = lin.r.squaredNorm();
    int rank = 0;
    PseudoInverse(lin.j.transpose() * lin.j, &rank);
    const int dof1 = n_obs - rank - 1;
    if (dof1 < 3) break;
    Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(lin.j);
    const Eigen::MatrixXd q =
        Eigen::MatrixXd(qr.householderQ()).leftCols(static_cast<Eigen::Index>(qr.rank()));
    const std::vector<double> press0_moves = LinearHeldOut(lin.j, lin.r, moves.size());
    const double press0 = SumSquares(press0_moves);
    std::vector<MoveTerm> terms;
    for (int axis = 0; axis < 3; ++axis) {
      for (const Regressor& r : dictionary) {
        bool present = false;
        for (const MoveTerm& t : model.terms) present |= t.axis == axis && t.regressor == r;
        if (!present) terms.push_back({axis, r, 0.0});
      }
    }
    const Eigen::MatrixXd columns = CandidateColumns(model, terms, moves, turns);
    std::vector<Candidate> cands;
    int not_excited = 0;
    Eigen::MatrixXd j_ext(lin.j.rows(), lin.j.cols() + 1);
    j_ext.leftCols(lin.j.cols()) = lin.j;
    for (size_t k = 0; k < terms.size(); ++k) {
      Candidate c;
      c.term = terms[k];
      const Eigen::VectorXd col = columns.col(static_cast<Eigen::Index>(k));
      c.perp = col - q * (q.transpose() * col);
      if (!col.allFinite() || col.norm() == 0 || c.perp.norm() <= kAbsorbedFraction * col.norm()) {
        ++not_excited;
        continue;
      }
      const double proj = c.perp.dot(lin.r);
      const double drss = proj * proj / c.perp.squaredNorm();
      const double rss1 = std::max(rss0 - drss, 1e-300);
      const double s2 = std::max(rss1 / dof1, floor_var);
      MoveCandidateScore& s = c.score;
      s.axis = c.term.axis;
      s.regressor = c.term.regressor.Name();
      s.f = drss / s2;
      s.delta_bic = n_obs * std::log(rss1 / rss0) + std::log(static_cast<double>(n_obs));
      s.coefficient = -proj / c.perp.squaredNorm();
      j_ext.rightCols<1>() = col;
      const std::vector<double> held = LinearHeldOut(j_ext, lin.r, moves.size());
      s.press_gain = (press0 - SumSquares(held)) / s2;
      s.trimmed_gain = TrimmedGain(press0_moves, held) / s2;
      cands.push_back(std::move(c));
    }
    const int tests = static_cast<int>(cands.size());
    if (round == 0) {
      out.candidates = tests;
      out.not_excited = not_excited;
    }
    ++out.rounds;
    if (cands.empty()) break;
    const double threshold = FThreshold(opt.family_alpha, tests, dof1);
    int best = -1;
    for (size_t c = 0; c < cands.size(); ++c) {
      MoveCandidateScore& s = cands[c].score;
      s.f_threshold = threshold;
      s.passed = s.f > threshold && s.delta_bic < 0 && s.press_gain > threshold &&
                 s.trimmed_gain > threshold;
      if (s.passed && (best < 0 || s.delta_bic < cands[static_cast<size_t>(best)].score.delta_bic))
        best = static_cast<int>(c);
    }
    if (std::getenv("IMUCAL_DEBUG_EFFECTS") != nullptr) {  // each round's best, to look at
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
                     round, kAxes[sc.axis], sc.regressor.c_str(), sc.f, sc.f_threshold,
                     sc.delta_bic, sc.press_gain, static_cast<int>(kTrimmedMoves), sc.trimmed_gain,
                     sc.passed ? " passed" : "");
      }
    }
    if (round == 0) {
      std::vector<const Candidate*> by_f;
      for (const Candidate& c : cands) by_f.push_back(&c);
      std::sort(by_f.begin(), by_f.end(),
                [](const Candidate* a, const Candidate* b) { return a->score.f > b->score.f; });
      for (size_t k = 0; k < by_f.size() && k < static_cast<size_t>(kTopCandidates); ++k)
        out.top.push_back(by_f[k]->score);
    }
    SetDetectionBounds(model, moves, in.bias, cands, std::max(rss0 / dof1, floor_var), threshold,
                       &out);
    if (best < 0) break;
    const Candidate& chosen = cands[static_cast<size_t>(best)];
    // Rivals the moves do not tell apart from the chosen one.
    std::vector<std::string> rivals;
    for (const Candidate& c : cands) {
      if (&c == &chosen || !c.score.passed) continue;
      const double corr = std::abs(c.perp.dot(chosen.perp)) / (c.perp.norm() * chosen.perp.norm());
      if (corr > kAmbiguousCorrelation &&
          c.score.delta_bic - chosen.score.delta_bic < kWeakEvidenceBic)
        rivals.push_back(Describe(c.term.axis, c.term.regressor));
    }
    Model next = model;
    MoveTerm t = chosen.term;
    t.coefficient = chosen.score.coefficient;
    next.terms.push_back(t);
    iterations = Solve(moves, turns, &next);
    const MoveModelFit fit = Analyse(next, moves, turns, iterations);
    model = next;
    Effect e;
    e.sensor = Sensor::kGyro;
    e.axis = t.axis;
    e.regressor = t.regressor.Name();
    e.coefficient = model.terms.back().coefficient;
    e.std_error = fit.term_std_error.back();
    // A rate term does nothing at rest: the static residual is not its figure. The moves' are,
    // in the evidence.
    e.error_before = e.error_after = kNaN;
    std::string rival_text;
    for (const std::string& r : rivals) rival_text += (rival_text.empty() ? "" : ", ") + r;
    e.evidence = absl::StrFormat(
        "{\"what\": \"rotations between poses: %s, F %.1f > %.1f (1%% over %d candidates), "
        "BIC %+.1f, held-out gain %.1f (%.1f without the %d moves that gain most; both over "
        "%.1f, in units of s^2); the gravity-direction error after the moves, held out by move, "
        "%.4f -> %.4f deg RMS%s\", \"moves\": %d, \"moves_heldout_before_rad\": %.6g, "
        "\"moves_heldout_after_rad\": %.6g, \"f\": %.4g, \"f_threshold\": %.4g, "
        "\"delta_bic\": %.4g}",
        Meaning(t.axis, t.regressor), chosen.score.f, threshold, tests, chosen.score.delta_bic,
        chosen.score.press_gain, chosen.score.trimmed_gain, static_cast<int>(kTrimmedMoves),
        threshold, current.RmsHeldOut() * kRadToDeg, fit.RmsHeldOut() * kRadToDeg,
        rivals.empty() ? "" : absl::StrCat("; not told apart from ", rival_text),
        static_cast<int>(moves.size()), current.RmsHeldOut(), fit.RmsHeldOut(), chosen.score.f,
        threshold, chosen.score.delta_bic);
    out.effects.push_back(e);
    found_notes.push_back(absl::StrFormat(
        "%s (%s; %s), held out by move %.3f -> %.3f deg RMS%s", Describe(t.axis, t.regressor),
        Meaning(t.axis, t.regressor), HumanMoveCoefficient(model.terms.back(), e.std_error),
        current.RmsHeldOut() * kRadToDeg, fit.RmsHeldOut() * kRadToDeg,
        rivals.empty() ? "" : absl::StrCat("; the moves do not tell it from ", rival_text)));
    current = fit;
  }
  out.after = current;
  // Every coefficient and standard error from the final fit (the given terms' included).
  for (size_t k = 0; k < out.effects.size(); ++k) {
    out.effects[k].coefficient = out.after.terms[k].coefficient;
    out.effects[k].std_error = out.after.term_std_error[k];
  }

  // The turns against the moves: the moves alone fitted, each turn's angle.
  if (!in.turns.empty()) {
    Model alone;
    alone.m = in.matrix;
    Solve(moves, {}, &alone);
    const Linearisation lin = Linearise(alone, moves, {});
    int rank = 0;
    PseudoInverse(lin.j.transpose() * lin.j, &rank);
    if (rank == 9 && Observations(moves.size(), {}) - rank >= 3) {
      for (const Prepared& t : turns) {
        double angle = 0;
        TurnResidual(alone, t, nullptr, &angle);
        out.turn_angle_moves_only_rad.push_back(angle);
      }
    }
  }

  const double before_deg = out.before.RmsHeldOut() * kRadToDeg;
  if (found_notes.empty()) {
    std::string best;
    if (!out.top.empty())
      best = absl::StrFormat("; the strongest, gyro %c ~ %s, F %.1f against %.1f",
                             kAxes[out.top[0].axis], out.top[0].regressor, out.top[0].f,
                             out.top[0].f_threshold);
    out.notes.push_back(absl::StrFormat(
        "rotations between poses: no rate-dependent gyroscope term among %d tested on the %d "
        "moves%s. The gravity-direction error after the moves, held out by move, %.3f deg RMS "
        "(%.3f in-sample; the noise alone would leave %.3f)",
        out.candidates, static_cast<int>(moves.size()), best, before_deg,
        out.before.RmsMoveError() * kRadToDeg, out.noise_floor_rad * kRadToDeg));
  } else {
    std::string list;
    for (const std::string& n : found_notes) list += (list.empty() ? "" : "; ") + n;
    out.notes.push_back(absl::StrFormat(
        "rotations between poses: %s. The gravity-direction error after the %d moves, held out "
        "by move, %.3f -> %.3f deg RMS (the noise alone would leave %.3f)",
        list, static_cast<int>(moves.size()), before_deg, out.after.RmsHeldOut() * kRadToDeg,
        out.noise_floor_rad * kRadToDeg));
  }
  if (!out.turn_angle_moves_only_rad.empty()) {
    std::string angles;
    double worst = 0;
    for (size_t k = 0; k < out.turn_angle_moves_only_rad.size(); ++k) {
      const double a = out.turn_angle_moves_only_rad[k], nominal = turns[k].angle;
      angles += absl::StrFormat("%s%.2f", angles.empty() ? "" : ", ", a * kRadToDeg);
      worst = std::max(worst, std::abs(a - nominal) / nominal);
    }
    out.notes.push_back(absl::StrFormat(
        "full turns against the moves: fitted to the moves alone, the gyroscope reads the "
        "turns as %s deg (%.2f%% off whole turns at most)%s",
        angles, 100 * worst,
        worst > 0.005 ? ": the turns and the moves disagree on the scale, so a turn was not a "
                        "whole turn or the scale differs between them (rate, sense of rotation)"
                      : ""));
  }
  return out;
}

}  // namespace imucal::core
