// The moves' model (move_model.h, core/move_effects.h MODEL): integration of the corrected rate
// over each move and turn, the analytic Jacobian, the Levenberg-Marquardt fit and its figures;
// FitMoveModel and the moves' dictionary.
#include "core/effects/move_model.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Dense"
#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "core/effects/common.h"
#include "core/so3.h"

namespace imucal::core::effects {
namespace {

// Eigenvalues of J^T J below this fraction of the largest are treated as zero.
constexpr double kNullEigenvalueRatio = 1e-14;

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

}  // namespace

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

SignalArray RateSignals(const Eigen::Vector3d& v) {
  SignalArray s{};
  s[static_cast<size_t>(Signal::kGx)] = v.x();
  s[static_cast<size_t>(Signal::kGy)] = v.y();
  s[static_cast<size_t>(Signal::kGz)] = v.z();
  return s;
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
      q = q * ExpQuaternion(0.5 * (w0 + w1) * mv.dt[k]);
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
                             double* angle) {
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

Linearisation Linearise(const Model& model, const std::vector<Prepared>& moves,
                        const std::vector<Prepared>& turns, bool with_jacobian) {
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
Eigen::MatrixXd PseudoInverse(const Eigen::MatrixXd& h, int* rank) {
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
          int max_iterations) {
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

}  // namespace imucal::core::effects

namespace imucal::core {

using effects::Analyse;
using effects::Model;
using effects::Prepared;
using effects::PrepareMoves;
using effects::PrepareTurns;
using effects::Rms;
using effects::Solve;

double MoveModelFit::RmsMoveError() const { return Rms(move_error_rad); }

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

}  // namespace imucal::core
