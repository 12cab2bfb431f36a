// Gyroscope terms that only the rotations between static poses can show (issue 16, item 5).
//
// Static poses hold the rate at zero, so a term in the rate cannot be tested on them (the static
// search, core/effects.h, says so). The moves between poses can: the gyroscope integrated over
// a move must carry the gravity direction measured before it onto the one measured after it.
//
// MODEL (the SDK's, core/correction.h): the rate of the model, then each term subtracted,
//   v_k = M (u_k - b_k)                              the gyroscope model's rate, rad/s
//   w_k[axis] = v_k[axis] - sum_t c_t x_t(v_k)       each term t on its output axis
// with x_t a regressor over the model's rates (core/regressor.h: gx, gy, gz, |gx|, ...). As in
// core/gyro_solver.h the bias b_k is interpolated between the static means of the move's two
// poses (the stored model keeps the constant bias), and the rate is integrated exactly on SO(3)
// with the midpoint rule:
//   phi_k = (w_k + w_{k+1}) / 2 dt_k,   DeltaR = prod_k Exp(phi_k),
//   r = DeltaR^T up_before - up_after   (3-vector, |r| ~ gravity-direction error in rad)
// Full turns (GyroFullTurn) add sum_k phi_k - angle axis (axis known) or |sum_k phi_k| - angle.
// The parameters are vec(M) (column-major) and the coefficients c_t, fitted jointly by
// Levenberg-Marquardt with the analytic Jacobian
//   dr/dtheta = [up_pred]x DeltaR^T sum_k R_{begin..k} Jr(phi_k) dphi_k/dtheta,
//   dw_k/dvec(M) = A_k (u_k^T kron I3),  A_k = I - sum_t c_t e_axis(t) grad x_t(v_k)^T,
//   dw_k/dc_t = -x_t(v_k) e_axis(t)
// (core/gyro_solver.h's Jacobian with dphi_k/dvec(M) = c_k^T kron I3 generalised; the
// derivative of |v| is sign(v)).
//
// DICTIONARY, per gyro output axis j and rate signals k, l of x, y, z (36 candidates):
//   gk*|gk|   a scale that grows with the rate's size (k = j: the axis's own scale
//             nonlinearity; k != j: a misalignment that grows with the rate, which only fast,
//             large turns reveal)
//   |gk|      a scale that differs between the two senses of rotation (scale-factor asymmetry
//             when k = j; a misalignment that differs between them when k != j)
//   gk^2, gk*gl   a rate-squared bias (rectification; cross-coupling of two axes' rates)
// The linear terms (scale and misalignment) are the model's own matrix M.
//
// SELECTION, forward stepwise by the static search's rule (core/effects.h), on the moves'
// residuals. Each move's residual carries 2 degrees of freedom (the component along `up` is
// second order), a turn 3 (axis known) or 1: N observations, dof = N - rank. Each round scores
// every candidate by linearised least squares at the current fit (its Jacobian column with
// the current model's columns projected out); it enters only if
//   1. F = dRSS / s^2 beats the F(1, dof - 1) quantile at 1% / the number of candidates of the
//      round (Bonferroni), s^2 = RSS_after / (dof - 1), never below what the gyroscope's white
//      noise and the pose directions' noise alone give (the noise floor);
//   2. BIC falls: N ln(RSS_after / RSS_before) + ln N < 0;
//   3. the held-out sum of squares, each move predicted by a fit without it, falls by more than
//      F* s^2 (leave-one-move-out, first order: one Gauss-Newton step from the full fit without
//      the move, by the Woodbury identity, and the move's residual predicted linearly; the
//      figures reported, MoveModelFit::heldout_error_rad, integrate each held-out move exactly
//      as GyroSolveResult::heldout_error_rad does);
//   4. the gain is the moves', not one or two moves': the held-out gain without the 2 moves
//      that gain most still exceeds F* s^2. Conditions 1-3 sum over the moves, where a move that
//      went wrong (a knock, a slip in the hand) weighs as much as ten good ones; a rate term
//      shows on every fast move about its axis. (On the imutk-ros2-repeat capture 4, gz^2 on z
//      had F 43 against 17, but 135 of its held-out gain of 141 (in s^2) came from two long
//      turns about z; the same form fitted to capture 2 of the same unit came out 2.6 standard
//      errors smaller.)
// The passing candidate with the lowest BIC enters, M and every coefficient are refitted, and
// the search repeats until nothing passes. Candidates whose columns are collinear with the
// chosen one (|r| > 0.9) within 6 of its BIC are named with it: the moves do not tell them apart.
//
// Every term here is applicable: the robot has its rate at run time.
#ifndef IMUCAL_CORE_MOVE_EFFECTS_H_
#define IMUCAL_CORE_MOVE_EFFECTS_H_

#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "core/gyro_solver.h"
#include "core/model.h"
#include "core/params.h"
#include "core/regressor.h"

namespace imucal::core {

// What a capture could not have missed (issue 25, item 4): where a search found no term of a form
// on an output, the smallest coefficient of that form it would have found 9 times in 10. From
// the search's own test at its final model: the form's column beyond the model (and beyond its
// lower powers), the residual's noise, and the F threshold of the search's last round; the
// noncentrality that the test passes with probability 0.9 (chi-square with the candidate's
// degrees of freedom at its threshold) over the column's size, in units of the noise:
//   |coefficient| >= sqrt(lambda_0.9) * s / |column beyond the model|.
// It says whether "none found" means "none there": a term above the bound would have been found.
// (The held-out and BIC conditions are met wherever F is, at these sizes.)
struct DetectionBound {
  Sensor sensor = Sensor::kGyro;
  int axis = 0;
  std::string regressor;   // the form, as the effect would be named ("(temperature-29.6)")
  double coefficient = 0;  // SI per regressor unit; +inf: the capture does not excite the form
  std::string from;        // what it comes from: "40 poses at 25.1-33.0 degC"
};

// The noncentrality at which a chi-square test of `df` degrees of freedom at `threshold` (the
// statistic's value, df * F*) passes with probability `power`.
double DetectableNoncentrality(int df, double threshold, double power = 0.9);

// One term on a gyro output axis: w[axis] -= coefficient * regressor(model rates).
struct MoveTerm {
  int axis = 0;
  Regressor regressor;
  double coefficient = 0;  // rad/s per regressor unit
};

struct MoveSearchInput {
  // The capture's samples (not owned; must outlive the call).
  const std::vector<double>* t_s = nullptr;
  const std::vector<Eigen::Vector3d>* gyro_raw = nullptr;
  std::vector<GyroMove> moves;
  std::vector<GyroFullTurn> turns;
  Eigen::Matrix3d matrix = Eigen::Matrix3d::Identity();  // the model's M, the fit's start
  Eigen::Vector3d bias = Eigen::Vector3d::Zero();        // constant bias, input units
  bool interpolate_bias = true;  // each move's bias from its poses (GyroSolveOptions)
  // The noise floor: per-sample white noise of the calibrated rate (rad/s, per axis, RMS over
  // the axes), and of one pose's gravity direction (rad, per component).
  double gyro_noise_rad_s = 0;
  double up_noise_rad = 0;
};

// Given terms (a reference fit that knows the form): fitted, never searched.
struct MoveGivenTerm {
  int axis = 0;
  std::string regressor;
};

struct MoveSearchOptions {
  double family_alpha = 0.01;  // false-alarm probability per round over all candidates
  int max_terms = 3;
  std::vector<MoveGivenTerm> given;
};

// The gyroscope fitted to the moves (and turns) with a set of terms.
struct MoveModelFit {
  Eigen::Matrix3d matrix = Eigen::Matrix3d::Identity();
  std::vector<MoveTerm> terms;  // coefficients fitted
  std::vector<double> term_std_error;
  // Covariance of (vec(M), coefficients), s^2 (J^T J)^+ with s^2 = RSS / dof.
  Eigen::MatrixXd covariance;
  std::vector<Eigen::Vector3d> move_residual;  // per move, r (see MODEL), in-sample
  std::vector<double> move_error_rad;          // per move, in-sample
  std::vector<double> heldout_error_rad;       // per move, leave-one-move-out (first order)
  std::vector<double> turn_angle_rad;          // per turn: |sum_k phi_k|
  double rss = 0;                              // sum over moves and turns of |r|^2
  int observations = 0;                        // 2 per move, 3 or 1 per turn
  int rank = 0;
  int iterations = 0;
  double RmsMoveError() const;
  double RmsHeldOut() const;
};

// One candidate as its round scored it.
struct MoveCandidateScore {
  int axis = 0;
  std::string regressor;
  double f = 0, f_threshold = 0;
  double delta_bic = 0;
  double press_gain = 0;    // held-out sum of squares before - after, in units of s^2
  double trimmed_gain = 0;  // the same without the 2 moves that gain most (condition 4)
  double coefficient = 0;   // linearised, rad/s per regressor unit
  bool passed = false;
};

// What the report keeps of a search (core/effects.h EffectDiagnostics::move_search).
struct MoveEffectDiagnostics {
  bool ran = false;
  int moves = 0, candidates = 0, not_excited = 0, rounds = 0;
  // The gravity-direction error after the moves, RMS over them (rad): held out by move and
  // in-sample, without and with the terms found; what the noise alone would leave.
  double heldout_before_rad = 0, heldout_after_rad = 0;
  double in_sample_before_rad = 0, in_sample_after_rad = 0;
  double noise_floor_rad = 0;
  // Per move (in the order of CalibrationReport::moves), held out by move: without and with the
  // terms found (rad).
  std::vector<double> heldout_before_per_move_rad, heldout_after_per_move_rad;
  std::vector<MoveCandidateScore> top;
  std::vector<double> turn_angle_moves_only_rad;  // see MoveSearchResult
  std::vector<DetectionBound> detection_bounds;   // see MoveSearchResult
};

struct MoveSearchResult {
  bool ran = false;
  int candidates = 0;   // tested in the first round
  int not_excited = 0;  // skipped: the moves do not excite the candidate beyond the model
  int rounds = 0;
  MoveModelFit before;                  // the model without terms (with the given ones)
  MoveModelFit after;                   // with every term found
  std::vector<Effect> effects;          // gyroscope effects, in the order found
  std::vector<MoveCandidateScore> top;  // the first round's best few by F
  double noise_floor_rad = 0;           // RMS gravity-direction error the noise alone would leave
  // Fitted to the moves alone, each full turn's angle (rad): when the turns and the moves
  // disagree on the scale, this says by how much. Empty without turns or when the moves alone
  // do not determine M.
  std::vector<double> turn_angle_moves_only_rad;
  // Per gyro axis without a rate term found: the smallest scale that grows with the rate
  // (`gk*|gk|` on axis k) these moves would have found (DetectionBound).
  std::vector<DetectionBound> detection_bounds;
  std::vector<std::string> notes;

  MoveEffectDiagnostics Diagnostics() const;
};

// The candidates (see DICTIONARY), each on every output axis.
std::vector<Regressor> MoveDictionary();

// Fits M and the terms' coefficients (starting at the terms' coefficients) to the moves and
// turns. InvalidArgument for malformed moves (ValidateGyroMoves) or a term that is not on x, y
// or z; FailedPrecondition for fewer than 3 moves and no turn.
absl::StatusOr<MoveModelFit> FitMoveModel(const MoveSearchInput& input,
                                          const std::vector<MoveTerm>& terms);

// Runs the search (see the top of this file). With fewer than 6 moves, or too few degrees of
// freedom, it says so in the notes and finds nothing.
absl::StatusOr<MoveSearchResult> SearchMoveEffects(const MoveSearchInput& input,
                                                   const MoveSearchOptions& options);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_MOVE_EFFECTS_H_
