// The moves' model (core/move_effects.h MODEL), internal to core/effects: a move or turn ready
// to integrate, the gyroscope with its rate terms, the residuals with their analytic Jacobian, and
// the Levenberg-Marquardt fit FitMoveModel and the moves' search (move_search.cc) share.
#ifndef IMUCAL_CORE_EFFECTS_MOVE_MODEL_H_
#define IMUCAL_CORE_EFFECTS_MOVE_MODEL_H_

#include <cstddef>
#include <vector>

#include "Eigen/Core"
#include "core/move_effects.h"

namespace imucal::core::effects {

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

std::vector<Prepared> PrepareMoves(const MoveSearchInput& in);
std::vector<Prepared> PrepareTurns(const MoveSearchInput& in);

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

SignalArray RateSignals(const Eigen::Vector3d& v);
// The corrected rate of one sample and, when `dw` is not null, its derivative (3 x P).
Eigen::Vector3d Rate(const Model& model, const Eigen::Vector3d& u, Mat3X* dw);
// The residual of a move (3-vector) and, when `jacobian` is not null, dr/dtheta (3 x P).
Eigen::Vector3d MoveResidual(const Model& model, const Prepared& mv, Mat3X* jacobian);
// A turn: sum_k phi_k - angle axis (axis known), or (|sum_k phi_k| - angle, 0, 0).
Eigen::Vector3d TurnResidual(const Model& model, const Prepared& turn, Mat3X* jacobian,
                             double* angle = nullptr);
double AngleError(const Eigen::Vector3d& r, const Prepared& mv);

// The stacked residuals (3 per move, then 3 per turn) and Jacobian at `model`.
struct Linearisation {
  Eigen::VectorXd r;
  Eigen::MatrixXd j;
};
Linearisation Linearise(const Model& model, const std::vector<Prepared>& moves,
                        const std::vector<Prepared>& turns, bool with_jacobian = true);

// Pseudo-inverse of a symmetric PSD matrix, and its rank.
Eigen::MatrixXd PseudoInverse(const Eigen::MatrixXd& h, int* rank = nullptr);
// 2 per move, 3 per turn about a known axis, 1 per other turn.
int Observations(size_t moves, const std::vector<Prepared>& turns);
// Levenberg-Marquardt (Marquardt's diagonal scaling) from `model`; the iterations it took.
int Solve(const std::vector<Prepared>& moves, const std::vector<Prepared>& turns, Model* model,
          int max_iterations = 50);
double SumSquares(const std::vector<double>& v);
double Rms(const std::vector<double>& v);  // NaN when empty
// The fit's figures at `model` (covariance, residuals, leave-one-move-out errors, turn angles).
MoveModelFit Analyse(const Model& model, const std::vector<Prepared>& moves,
                     const std::vector<Prepared>& turns, int iterations);

}  // namespace imucal::core::effects

#endif  // IMUCAL_CORE_EFFECTS_MOVE_MODEL_H_
