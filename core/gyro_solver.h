// Gyroscope scale and misalignment from the rotations between static poses (Tedaldi, Pretto,
// Menegatti, ICRA 2014; IMU-TK), with exact SO(3) integration and an analytic Jacobian.
//
// MODEL (core/model.h, inverse form, accel_coupling = 0 here):
//   w_k = M (u_k - b_k)                         body rate, rad/s; body frame = accelerometer frame
// with M = GyroModel::matrix [rad/s per input unit] and b_k the gyro bias [input unit].
//
// PREDICTION for one move (sample indices begin..end, dt_k = t_{k+1} - t_k):
//   phi_k  = (w_k + w_{k+1}) / 2 * dt_k         midpoint (trapezoidal) rotation vector
//   DeltaR = Exp(phi_begin) Exp(phi_begin+1) ... Exp(phi_end-1)     body-frame right product, so
//            R_world_body(end) = R_world_body(begin) * DeltaR
//   up_pred = DeltaR^T * up_before               (gravity direction is fixed in the world)
//   r       = up_pred - up_after                 3-vector; |r| ~ gravity-direction error in rad
// Since phi_k = M c_k with c_k = ((u_k - b_k) + (u_{k+1} - b_{k+1})) / 2 * dt_k, the prediction
// depends on M only through these c_k, which are fixed for a given bias.
//
// JACOBIAN (right perturbation, vec(M) column-major):
//   DeltaR(M + dM) ~= DeltaR * Exp(sum_k R_{k+1..end}^T Jr(phi_k) dM c_k)
//   d up_pred / d theta = [up_pred]x
//   dr / d vec(M) = [up_pred]x DeltaR^T sum_k R_{begin..k} Jr(phi_k) (c_k^T kron I3)
// where R_{begin..k} = Exp(phi_begin)...Exp(phi_k) (so R_{k+1..end}^T = DeltaR^T R_{begin..k}):
// one forward pass per move, no autodiff.
//
// OBSERVABILITY (rule of thumb): a move determines M only through the raw rate directions it
// excites, and only the part of the rotation that tilts gravity (rotation about the up vector
// leaves `up` unchanged). Rotations about a single sensor axis determine only that axis' column of
// M; every axis needs rotations with components about it, and at least 5 well-spread moves are
// needed for all 9 entries (each move gives 2 constraints). Unobservable entries are reported in
// GyroSolveResult::undetermined rather than as an error.
#ifndef IMUCAL_CORE_GYRO_SOLVER_H_
#define IMUCAL_CORE_GYRO_SOLVER_H_

#include <cstddef>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace imucal::core {

// The motion between static pose i and static pose i+1.
struct GyroMove {
  // Sample index range [begin, end] to integrate, begin < end: from the last sample of static
  // pose i to the first sample of pose i+1.
  size_t begin = 0;
  size_t end = 0;
  // Unit gravity ("up", specific-force) directions in the body frame at the two poses, from the
  // calibrated accelerometer. The solver normalises them.
  Eigen::Vector3d up_before = Eigen::Vector3d::UnitZ();
  Eigen::Vector3d up_after = Eigen::Vector3d::UnitZ();
  // Raw gyro static means at the two poses, input units (used when interpolate_bias is set).
  Eigen::Vector3d bias_before = Eigen::Vector3d::Zero();
  Eigen::Vector3d bias_after = Eigen::Vector3d::Zero();
};

// A full turn (Ferraris et al. 1995): the robot turned about one axis from a static orientation
// back to it, `turns` whole times. The integral of the body rate over it is then the rotation
// vector of the whole path:
//   sum_k M c_k = angle_rad * axis          (axis known: a turn about the vertical, axis = +-up)
//   |sum_k M c_k| = |angle_rad|             (axis unknown: only the angle constrains M)
// with c_k the bias-corrected increments of GyroMove's PREDICTION and angle_rad = 2 pi turns.
// A turn about the vertical leaves gravity's direction unchanged, so a GyroMove over it says
// nothing about the scale along that axis: the known angle does.
struct GyroFullTurn {
  size_t begin = 0;  // sample range [begin, end] to integrate, as GyroMove
  size_t end = 0;
  Eigen::Vector3d bias_before = Eigen::Vector3d::Zero();
  Eigen::Vector3d bias_after = Eigen::Vector3d::Zero();
  // Unit rotation axis in the body frame, or zero when unknown.
  Eigen::Vector3d axis = Eigen::Vector3d::Zero();
  double angle_rad = 2 * 3.14159265358979323846;  // 2 pi * whole turns (> 0)
};

struct GyroSolveOptions {
  // Starting M [rad/s per input unit]: the nominal factor times identity for rad/s or deg/s.
  Eigen::Matrix3d initial_matrix = Eigen::Matrix3d::Identity();
  // Raw counts: ignore initial_matrix and start from EstimateIsotropicScale(...) * I.
  bool scale_unknown = false;
  // Constant gyro bias [input unit], used unless interpolate_bias is set.
  Eigen::Vector3d bias = Eigen::Vector3d::Zero();
  // Bias linear in time over each move, from its bias_before (at t[begin]) to bias_after
  // (at t[end]): follows a slowly drifting bias that the static poses measure. Static means
  // belong to the poses' middles, not the move's ends; for a linear drift the resulting rate
  // error is antisymmetric over the move and nearly cancels (1e-4 relative in the tests).
  bool interpolate_bias = false;
  int max_iterations = 100;  // Levenberg-Marquardt iterations
  // Leave-one-move-out errors (first-order, see GyroSolveResult::heldout_error_rad).
  bool compute_heldout = true;
  // An entry of M is reported undetermined when its one-sigma standard error exceeds this
  // fraction of the matrix scale |M|_F / sqrt(3) (or it lies in the exact null space).
  double undetermined_rel_sigma = 0.1;
};

struct GyroSolveResult {
  Eigen::Matrix3d matrix = Eigen::Matrix3d::Identity();  // M, rad/s per input unit
  // Covariance of vec(M) (column-major: M(0,0), M(1,0), M(2,0), M(0,1), ...), equal to
  // s^2 (J^T J)^+ with the reduced chi^2 s^2 = sum |r|^2 / (2 N - rank): each move's residual
  // carries 2 degrees of freedom, the component along `up` being second order. Rows and columns
  // of undetermined entries are NaN; all entries are NaN when 2 N <= rank.
  Eigen::Matrix<double, 9, 9> covariance = Eigen::Matrix<double, 9, 9>::Zero();
  // In-sample error per move: angle between predicted and measured up after the move, rad.
  std::vector<double> move_error_rad;
  // Per full turn: |integrated rotation vector - angle_rad * axis| (axis known) or
  // ||integrated| - angle_rad| (axis unknown), rad, at the solution.
  std::vector<double> turn_error_rad;
  // Leave-one-move-out error per move, rad: M_-i is ONE Gauss-Newton step from the full solution
  // without move i, (J^T J - J_i^T J_i)^+ (J^T r - J_i^T r_i), using the Jacobians and residuals
  // at the solution (the first-order LOO: exact for a linear model, close when the fit is good);
  // move i is then re-integrated exactly with M_-i. Empty unless compute_heldout.
  std::vector<double> heldout_error_rad;
  int iterations = 0;          // Levenberg-Marquardt steps taken (successful + unsuccessful)
  double cost = 0.0;           // 0.5 * sum over moves of |r|^2 at the solution (Ceres' convention)
  bool converged = false;      // Ceres reported CONVERGENCE (else it stopped on max_iterations)
  double initial_scale = 0.0;  // the isotropic starting scale when scale_unknown, else 0
  bool rank_deficient = false;
  // Entries the moves cannot determine, e.g. "gyro matrix column z (rotations about z)" when a
  // whole column is undetermined, else "gyro matrix entry (x,z)" (row, column).
  std::vector<std::string> undetermined;
};

// Checks that `moves` can be integrated: equal lengths, strictly increasing time, finite samples,
// begin < end <= last index, finite non-zero up vectors and finite biases. InvalidArgument naming
// the first fault. Does not check the number of moves.
absl::Status ValidateGyroMoves(const std::vector<double>& t_s,
                               const std::vector<Eigen::Vector3d>& gyro_raw,
                               const std::vector<GyroMove>& moves);

// The predicted up after `move` for a fixed model: DeltaR^T * move.up_before (up_before as given,
// not normalised). The bias is `bias`, or interpolated from the move when interpolate_bias.
// Checks only the move's own sample range; returns NaNs when it cannot be integrated (see
// ValidateGyroMoves).
Eigen::Vector3d PredictUpAfterMove(const std::vector<double>& t_s,
                                   const std::vector<Eigen::Vector3d>& gyro_raw,
                                   const GyroMove& move, const Eigen::Matrix3d& matrix,
                                   const Eigen::Vector3d& bias, bool interpolate_bias);

// Residual r = PredictUpAfterMove(...) - up_after (both up vectors normalised) and, if
// `jacobian` is not null, dr / d vec(M) (column-major vec). The function the solver minimises;
// exposed so that callers and tests can check it. NaNs for a move that cannot be integrated.
Eigen::Vector3d GyroMoveResidual(const std::vector<double>& t_s,
                                 const std::vector<Eigen::Vector3d>& gyro_raw, const GyroMove& move,
                                 const Eigen::Matrix3d& matrix, const Eigen::Vector3d& bias,
                                 bool interpolate_bias, Eigen::Matrix<double, 3, 9>* jacobian);

// The s > 0 of M = s * I that minimises the summed squared residual, from the data alone (raw
// counts, unknown unit): a log-spaced grid over 6 decades centred on the s that makes the median
// move turn by 1 rad along its path, then golden-section refinement around the best grid point.
// Uses options.bias / options.interpolate_bias. Assumes the gyro axes are nominally those of the
// accelerometer (no axis swapped or negated: M near s * I); a remapped sensor needs a signed,
// permuted initial_matrix instead. Returns NaN when the moves fail ValidateGyroMoves or no move
// has any rate.
double EstimateIsotropicScale(const std::vector<double>& t_s,
                              const std::vector<Eigen::Vector3d>& gyro_raw,
                              const std::vector<GyroMove>& moves, const GyroSolveOptions& options);

// Solves for the 9 entries of M by Levenberg-Marquardt (Ceres), one residual block per move.
// InvalidArgument for malformed input (see ValidateGyroMoves, non-finite or singular initial
// matrix, max_iterations < 1), FailedPrecondition for fewer than 3 moves, Internal when Ceres
// returns an unusable solution. Rank deficiency is a result: rank_deficient and undetermined.
absl::StatusOr<GyroSolveResult> SolveGyroFromMoves(const std::vector<double>& t_s,
                                                   const std::vector<Eigen::Vector3d>& gyro_raw,
                                                   const std::vector<GyroMove>& moves,
                                                   const GyroSolveOptions& options);

// The same with full turns (GyroFullTurn) as further residual blocks, each in rad like the moves'
// (3 components when the axis is known, 1 otherwise). FailedPrecondition for fewer than 3 moves
// and no turn; too few constraints (2 per move, 3 or 1 per turn, 9 unknowns) is a result:
// rank_deficient and undetermined. With turns, scale_unknown starts from the scale that makes the
// turns' mean angle exact. Moves and turns share the options' bias handling.
absl::StatusOr<GyroSolveResult> SolveGyroFromMovesAndTurns(
    const std::vector<double>& t_s, const std::vector<Eigen::Vector3d>& gyro_raw,
    const std::vector<GyroMove>& moves, const std::vector<GyroFullTurn>& turns,
    const GyroSolveOptions& options);

// The bias-corrected integral sum_k c_k of a full turn (input unit * s), with the options' bias
// handling: times M, the turn's integrated rotation vector.
Eigen::Vector3d IntegrateRawTurn(const std::vector<double>& t_s,
                                 const std::vector<Eigen::Vector3d>& gyro_raw,
                                 const GyroFullTurn& turn, const GyroSolveOptions& options);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_GYRO_SOLVER_H_
