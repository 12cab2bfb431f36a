#include "core/gyro_solver.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Eigenvalues"
#include "Eigen/Geometry"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "ceres/problem.h"
#include "ceres/sized_cost_function.h"
#include "ceres/solver.h"
#include "ceres/types.h"
#include "core/robust_covariance.h"
#include "core/so3.h"
#include "util/units.h"

namespace imucal::core {
namespace {

using Mat39 = Eigen::Matrix<double, 3, 9>;
using Mat99 = Eigen::Matrix<double, 9, 9>;
using Vec9 = Eigen::Matrix<double, 9, 1>;

constexpr char kAxisNames[3] = {'x', 'y', 'z'};

// Eigenvalues of J^T J below this fraction of the largest are numerically zero: the singular
// values of J are then below ~1e-7 of the largest, far below any real excitation but far above
// the round-off (~1e-16) of an exactly unobservable direction.
constexpr double kNullEigenvalueRatio = 1e-14;
// An entry is in the null space when a unit step along the null space moves it by more than this
// (0.1 of the step): e.g. with rotations about a sensor axis only, the entries of the other
// columns are fully free (1) while the axis' own column moves only by its misalignment (~1e-3).
constexpr double kNullProjectionThreshold = 0.01;  // squared, compared with diag(P_null)

// Everything the residual of one move needs: the fixed increments c_k (input unit * s), so that
// phi_k = M c_k, and the normalised up vectors.
struct PreparedMove {
  std::vector<Eigen::Vector3d> increments;
  Eigen::Vector3d up_before = Eigen::Vector3d::UnitZ();
  Eigen::Vector3d up_after = Eigen::Vector3d::UnitZ();
};

// A full turn reduces to its integral C = sum_k c_k: the residual is linear in M.
struct PreparedTurn {
  Eigen::Vector3d integral = Eigen::Vector3d::Zero();
  Eigen::Vector3d axis = Eigen::Vector3d::Zero();  // zero: unknown
  double angle = 0;
};

// r = M C - angle axis, dr/dvec(M) = C^T kron I3 (axis known); r = |M C| - angle,
// dr/dvec(M) = (M C / |M C|)^T (C^T kron I3) (axis unknown, in component 0; the others 0).
Eigen::Vector3d TurnResidual(const PreparedTurn& turn, const Eigen::Matrix3d& m,
                             Eigen::Matrix<double, 3, 9>* jacobian) {
  const Eigen::Vector3d v = m * turn.integral;
  Eigen::Matrix<double, 3, 9> j = Eigen::Matrix<double, 3, 9>::Zero();
  for (int c = 0; c < 3; ++c)
    j.block<3, 3>(0, 3 * c) = turn.integral(c) * Eigen::Matrix3d::Identity();
  if (turn.axis.squaredNorm() > 0) {
    if (jacobian != nullptr) *jacobian = j;
    return v - turn.angle * turn.axis;
  }
  const double norm = v.norm();
  if (jacobian != nullptr) {
    jacobian->setZero();
    if (norm > 0) jacobian->row(0) = (v / norm).transpose() * j;
  }
  return Eigen::Vector3d(norm - turn.angle, 0, 0);
}

// prod_k Exp(M c_k) as a unit quaternion: about half the work of the matrix product, for the
// evaluations that need no Jacobian (the isotropic grid, error reports).
Eigen::Quaterniond IntegrateDeltaQ(const std::vector<Eigen::Vector3d>& increments,
                                   const Eigen::Matrix3d& matrix) {
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
  for (const Eigen::Vector3d& c : increments) q = q * ExpQuaternion(matrix * c);
  return q.normalized();
}

// DeltaR = prod_k Exp(M c_k) and, if `dtheta_dm` is not null, the derivative of the right
// perturbation theta of DeltaR (DeltaR(M + dM) ~= DeltaR Exp(theta)) with respect to vec(M):
//   dtheta/dvec(M) = DeltaR^T [B_0 B_1 B_2],   B_j = sum_k c_kj R_{begin..k} Jr(phi_k),
// because dphi_k = dM c_k = (c_k^T kron I3) dvec(M) and R_{k+1..end}^T = DeltaR^T R_{begin..k}.
Eigen::Matrix3d IntegrateDeltaR(const std::vector<Eigen::Vector3d>& increments,
                                const Eigen::Matrix3d& matrix, Mat39* dtheta_dm) {
  if (dtheta_dm == nullptr) return IntegrateDeltaQ(increments, matrix).toRotationMatrix();
  Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
  Mat39 b = Mat39::Zero();
  Eigen::Matrix3d jr;
  for (const Eigen::Vector3d& c : increments) {
    r = r * ExpAndRightJacobian(matrix * c, &jr);
    const Eigen::Matrix3d g = r * jr;
    b.leftCols<3>() += c.x() * g;
    b.middleCols<3>(3) += c.y() * g;
    b.rightCols<3>() += c.z() * g;
  }
  *dtheta_dm = r.transpose() * b;
  return r;
}

// r = DeltaR^T up_before - up_after; dr/dvec(M) = [DeltaR^T up_before]x dtheta/dvec(M), since
// (DeltaR Exp(theta))^T v = Exp(-theta) DeltaR^T v ~= p - theta x p = p + [p]x theta.
Eigen::Vector3d MoveResidual(const PreparedMove& move, const Eigen::Matrix3d& matrix,
                             Mat39* jacobian) {
  Mat39 dtheta_dm;
  const Eigen::Matrix3d delta_r =
      IntegrateDeltaR(move.increments, matrix, jacobian != nullptr ? &dtheta_dm : nullptr);
  const Eigen::Vector3d predicted = delta_r.transpose() * move.up_before;
  if (jacobian != nullptr) *jacobian = Skew(predicted) * dtheta_dm;
  return predicted - move.up_after;
}

double AngleBetween(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

// Angle between predicted and measured up after the move (both unit vectors).
double MoveAngleError(const PreparedMove& move, const Eigen::Matrix3d& matrix) {
  const Eigen::Matrix3d delta_r = IntegrateDeltaR(move.increments, matrix, nullptr);
  return AngleBetween(delta_r.transpose() * move.up_before, move.up_after);
}

// ---------------------------------------------------------------------------------------------
// Validation.

absl::Status TimeIsValid(const std::vector<double>& t_s,
                         const std::vector<Eigen::Vector3d>& gyro_raw) {
  if (t_s.size() != gyro_raw.size()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%d timestamps but %d gyro samples", t_s.size(), gyro_raw.size()));
  }
  for (size_t i = 0; i < t_s.size(); ++i) {
    if (!std::isfinite(t_s[i])) {
      return absl::InvalidArgumentError(absl::StrCat("non-finite time at sample ", i));
    }
    if (i > 0 && !(t_s[i] > t_s[i - 1])) {
      return absl::InvalidArgumentError(absl::StrCat("time not increasing at sample ", i));
    }
  }
  return absl::OkStatus();
}

bool IsUsableDirection(const Eigen::Vector3d& v) { return v.allFinite() && v.norm() > 1e-9; }

// The move's own range: bounds, strictly increasing time, finite samples and directions. Enough
// for the single-move helpers; ValidateGyroMoves adds the whole-series checks.
absl::Status MoveIsValid(const std::vector<double>& t_s,
                         const std::vector<Eigen::Vector3d>& gyro_raw, const GyroMove& move,
                         size_t index) {
  if (t_s.size() != gyro_raw.size()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%d timestamps but %d gyro samples", t_s.size(), gyro_raw.size()));
  }
  if (!(move.begin < move.end) || move.end >= gyro_raw.size()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("move %d: sample range [%d, %d] is empty or outside [0, %d)", index,
                        move.begin, move.end, gyro_raw.size()));
  }
  if (!IsUsableDirection(move.up_before) || !IsUsableDirection(move.up_after)) {
    return absl::InvalidArgumentError(
        absl::StrCat("move ", index, ": up vector is zero or not finite"));
  }
  if (!move.bias_before.allFinite() || !move.bias_after.allFinite()) {
    return absl::InvalidArgumentError(absl::StrCat("move ", index, ": bias is not finite"));
  }
  for (size_t k = move.begin; k <= move.end; ++k) {
    if (!gyro_raw[k].allFinite() || !std::isfinite(t_s[k])) {
      return absl::InvalidArgumentError(absl::StrCat("move ", index, ": non-finite sample ", k));
    }
    if (k > move.begin && !(t_s[k] > t_s[k - 1])) {
      return absl::InvalidArgumentError(
          absl::StrCat("move ", index, ": time not increasing at sample ", k));
    }
  }
  return absl::OkStatus();
}

absl::Status OptionsAreValid(const GyroSolveOptions& options) {
  if (options.max_iterations < 1) {
    return absl::InvalidArgumentError("max_iterations must be at least 1");
  }
  if (!options.bias.allFinite()) return absl::InvalidArgumentError("bias is not finite");
  if (!(options.undetermined_rel_sigma > 0.0)) {
    return absl::InvalidArgumentError("undetermined_rel_sigma must be positive");
  }
  if (!options.scale_unknown) {
    const Eigen::Matrix3d& m = options.initial_matrix;
    if (!m.allFinite() || !(std::abs(m.determinant()) > 0.0)) {
      return absl::InvalidArgumentError("initial_matrix is not finite or is singular");
    }
  }
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------------------------
// Preparation: c_k = ((u_k - b_k) + (u_{k+1} - b_{k+1})) / 2 * dt_k, so that the midpoint rate
// times dt_k is exactly M c_k (and the Jacobian is consistent with the midpoint rule).

PreparedMove PrepareMove(const std::vector<double>& t_s,
                         const std::vector<Eigen::Vector3d>& gyro_raw, const GyroMove& move,
                         const Eigen::Vector3d& bias, bool interpolate_bias) {
  const double t0 = t_s[move.begin];
  const double span = t_s[move.end] - t0;
  auto debiased = [&](size_t k) -> Eigen::Vector3d {
    if (!interpolate_bias) return gyro_raw[k] - bias;
    const double alpha = (t_s[k] - t0) / span;
    return gyro_raw[k] - (move.bias_before + alpha * (move.bias_after - move.bias_before));
  };
  PreparedMove prepared;
  prepared.up_before = move.up_before.normalized();
  prepared.up_after = move.up_after.normalized();
  prepared.increments.reserve(move.end - move.begin);
  Eigen::Vector3d previous = debiased(move.begin);
  for (size_t k = move.begin; k < move.end; ++k) {
    const Eigen::Vector3d next = debiased(k + 1);
    prepared.increments.push_back(0.5 * (previous + next) * (t_s[k + 1] - t_s[k]));
    previous = next;
  }
  return prepared;
}

std::vector<PreparedMove> PrepareMoves(const std::vector<double>& t_s,
                                       const std::vector<Eigen::Vector3d>& gyro_raw,
                                       const std::vector<GyroMove>& moves,
                                       const GyroSolveOptions& options) {
  std::vector<PreparedMove> prepared;
  prepared.reserve(moves.size());
  for (const GyroMove& move : moves) {
    prepared.push_back(PrepareMove(t_s, gyro_raw, move, options.bias, options.interpolate_bias));
  }
  return prepared;
}

// Sum over moves of |r|^2, abandoned (returning a value above `bound`) once it exceeds `bound`.
double SumSquaredResidual(const std::vector<PreparedMove>& moves, const Eigen::Matrix3d& m,
                          double bound = std::numeric_limits<double>::infinity()) {
  double sum = 0.0;
  for (const PreparedMove& move : moves) {
    sum += MoveResidual(move, m, nullptr).squaredNorm();
    if (sum > bound) break;
  }
  return sum;
}

// Golden-section minimisation of f over [lo, hi] (f unimodal there).
template <typename F>
double GoldenSectionMinimum(F f, double lo, double hi, int iterations) {
  const double inv_phi = (std::sqrt(5.0) - 1.0) / 2.0;
  double x1 = hi - inv_phi * (hi - lo);
  double x2 = lo + inv_phi * (hi - lo);
  double f1 = f(x1);
  double f2 = f(x2);
  for (int i = 0; i < iterations; ++i) {
    if (f1 < f2) {
      hi = x2;
      x2 = x1;
      f2 = f1;
      x1 = hi - inv_phi * (hi - lo);
      f1 = f(x1);
    } else {
      lo = x1;
      x1 = x2;
      f1 = f2;
      x2 = lo + inv_phi * (hi - lo);
      f2 = f(x2);
    }
  }
  return f1 < f2 ? x1 : x2;
}

double IsotropicScale(const std::vector<PreparedMove>& moves) {
  // Centre: the scale at which the median move turns by 1 rad along its path.
  std::vector<double> path;
  for (const PreparedMove& move : moves) {
    double length = 0.0;
    for (const Eigen::Vector3d& c : move.increments) length += c.norm();
    if (length > 0.0 && std::isfinite(length)) path.push_back(length);
  }
  if (path.empty()) return kNaN;
  std::nth_element(path.begin(), path.begin() + path.size() / 2, path.end());
  const double log_centre = -std::log(path[path.size() / 2]);

  // Grid: 6 decades, 20 points per decade (steps of 12%, narrower than the basin of the true
  // scale for paths up to several turns), then golden section between the best point's
  // neighbours.
  constexpr int kPointsPerDecade = 20;
  constexpr int kHalfDecades = 3;
  const double step = std::log(10.0) / kPointsPerDecade;
  auto cost = [&](double log_s, double bound) {
    return SumSquaredResidual(moves, std::exp(log_s) * Eigen::Matrix3d::Identity(), bound);
  };
  // The exact grid minimum, found faster: every 5th point first, then the others, abandoning a
  // point as soon as its partial sum exceeds the best so far (most points fail within a move).
  const int n = kPointsPerDecade * kHalfDecades;
  int best = -n;
  double best_cost = std::numeric_limits<double>::infinity();
  for (const bool coarse : {true, false}) {
    for (int i = -n; i <= n; ++i) {
      if ((i % 5 == 0) != coarse) continue;
      const double c = cost(log_centre + i * step, best_cost);
      if (c < best_cost) {
        best_cost = c;
        best = i;
      }
    }
  }
  const double lo = log_centre + std::max(best - 1, -n) * step;
  const double hi = log_centre + std::min(best + 1, n) * step;
  // 12 golden steps shrink the bracket (a factor 1.26) to ~0.4 % relative: a start for LM,
  // which converges from there in a few iterations (40 steps cost 30 ms on a real capture).
  const auto unbounded = [&](double log_s) {
    return cost(log_s, std::numeric_limits<double>::infinity());
  };
  return std::exp(GoldenSectionMinimum(unbounded, lo, hi, 12));
}

// ---------------------------------------------------------------------------------------------
// Ceres.

// One move: r = DeltaR(M)^T up_before - up_after, parameter vec(M) (column-major, so an
// Eigen::Matrix3d's data() is the parameter block). Analytic Jacobian from MoveResidual.
class MoveCost final : public ceres::SizedCostFunction<3, 9> {
 public:
  static ceres::CostFunction* Create(const PreparedMove* move) { return new MoveCost(move); }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const Eigen::Map<const Eigen::Matrix3d> matrix(parameters[0]);
    Eigen::Map<Eigen::Vector3d> r(residuals);
    if (jacobians == nullptr || jacobians[0] == nullptr) {
      r = MoveResidual(*move_, matrix, nullptr);
      return r.allFinite();
    }
    Mat39 j;
    r = MoveResidual(*move_, matrix, &j);
    Eigen::Map<Eigen::Matrix<double, 3, 9, Eigen::RowMajor>> jacobian(jacobians[0]);
    jacobian = j;
    return r.allFinite() && j.allFinite();
  }

 private:
  explicit MoveCost(const PreparedMove* move) : move_(move) {}
  const PreparedMove* move_;  // not owned; outlives the problem
};

class TurnCost final : public ceres::SizedCostFunction<3, 9> {
 public:
  static ceres::CostFunction* Create(const PreparedTurn* turn) { return new TurnCost(turn); }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const Eigen::Map<const Eigen::Matrix3d> matrix(parameters[0]);
    Eigen::Map<Eigen::Vector3d> r(residuals);
    Mat39 j;
    r = TurnResidual(*turn_, matrix, &j);
    if (jacobians != nullptr && jacobians[0] != nullptr) {
      Eigen::Map<Eigen::Matrix<double, 3, 9, Eigen::RowMajor>> jacobian(jacobians[0]);
      jacobian = j;
    }
    return r.allFinite() && j.allFinite();
  }

 private:
  explicit TurnCost(const PreparedTurn* turn) : turn_(turn) {}
  const PreparedTurn* turn_;  // not owned; outlives the problem
};

struct LmOutcome {
  Eigen::Matrix3d matrix;
  int iterations = 0;
  double cost = 0.0;
  bool converged = false;
};

absl::StatusOr<LmOutcome> RunLevenbergMarquardt(const std::vector<PreparedMove>& moves,
                                                const std::vector<PreparedTurn>& turns,
                                                const Eigen::Matrix3d& initial,
                                                int max_iterations) {
  LmOutcome outcome;
  outcome.matrix = initial;
  ceres::Problem problem;
  for (const PreparedMove& move : moves) {
    problem.AddResidualBlock(MoveCost::Create(&move), nullptr, outcome.matrix.data());
  }
  for (const PreparedTurn& turn : turns) {
    problem.AddResidualBlock(TurnCost::Create(&turn), nullptr, outcome.matrix.data());
  }
  ceres::Solver::Options options;
  options.minimizer_type = ceres::TRUST_REGION;
  options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  options.linear_solver_type = ceres::DENSE_QR;
  options.max_num_iterations = max_iterations;
  // Tighter than Ceres' defaults so that noise-free data reach ~1e-12 relative (LM converges
  // quadratically near a zero-residual optimum); looser would stop at ~1e-8, tighter only chases
  // round-off in the cost of noisy data.
  options.function_tolerance = 1e-12;
  options.parameter_tolerance = 1e-10;
  options.gradient_tolerance = 1e-14;
  options.logging_type = ceres::SILENT;
  options.minimizer_progress_to_stdout = false;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  if (!summary.IsSolutionUsable() || !outcome.matrix.allFinite()) {
    return absl::InternalError(absl::StrCat("gyro solve failed: ", summary.message));
  }
  outcome.iterations = summary.num_successful_steps + summary.num_unsuccessful_steps;
  outcome.cost = summary.final_cost;
  outcome.converged = summary.termination_type == ceres::CONVERGENCE;
  return outcome;
}

// ---------------------------------------------------------------------------------------------
// Analysis at the solution: covariance, observability, leave-one-out.

struct Linearisation {
  std::vector<Mat39> jacobians;
  std::vector<Eigen::Vector3d> residuals;
  Mat99 hessian = Mat99::Zero();       // J^T J
  Vec9 gradient = Vec9::Zero();        // J^T r
  Mat99 turn_hessian = Mat99::Zero();  // the turns' share of J^T J
};

// Moves first (their Jacobians and residuals are indexed like the moves), then the turns, which
// enter only the Hessian and gradient.
Linearisation Linearise(const std::vector<PreparedMove>& moves,
                        const std::vector<PreparedTurn>& turns, const Eigen::Matrix3d& m) {
  Linearisation lin;
  for (const PreparedMove& move : moves) {
    Mat39 j;
    const Eigen::Vector3d r = MoveResidual(move, m, &j);
    lin.hessian += j.transpose() * j;
    lin.gradient += j.transpose() * r;
    lin.jacobians.push_back(j);
    lin.residuals.push_back(r);
  }
  for (const PreparedTurn& turn : turns) {
    Mat39 j;
    const Eigen::Vector3d r = TurnResidual(turn, m, &j);
    lin.hessian += j.transpose() * j;
    lin.turn_hessian += j.transpose() * j;
    lin.gradient += j.transpose() * r;
  }
  return lin;
}

int TurnConstraints(const std::vector<PreparedTurn>& turns) {
  int n = 0;
  for (const PreparedTurn& t : turns) n += t.axis.squaredNorm() > 0 ? 3 : 1;
  return n;
}

// Pseudo-inverse and null-space projector of a symmetric PSD 9x9 matrix.
struct SpectralSplit {
  Mat99 pseudo_inverse = Mat99::Zero();
  Mat99 null_projector = Mat99::Zero();
  int rank = 0;
};

SpectralSplit SplitSpectrum(const Mat99& h) {
  const Eigen::SelfAdjointEigenSolver<Mat99> eigen(h);
  const Vec9& values = eigen.eigenvalues();
  const double cutoff = kNullEigenvalueRatio * std::max(values.maxCoeff(), 0.0);
  SpectralSplit split;
  for (int i = 0; i < 9; ++i) {
    const Vec9 v = eigen.eigenvectors().col(i);
    if (values(i) > cutoff && values(i) > 0.0) {
      split.pseudo_inverse += v * v.transpose() / values(i);
      ++split.rank;
    } else {
      split.null_projector += v * v.transpose();
    }
  }
  return split;
}

// Marks entries of vec(M) that the data cannot determine and names them.
void FindUndetermined(const SpectralSplit& split, const Mat99& covariance, double matrix_scale,
                      double rel_sigma, GyroSolveResult* result) {
  std::array<bool, 9> undetermined{};
  for (int i = 0; i < 9; ++i) {
    const double variance = covariance(i, i);
    undetermined[i] =
        split.null_projector(i, i) > kNullProjectionThreshold ||
        (std::isfinite(variance) && std::sqrt(std::max(variance, 0.0)) > rel_sigma * matrix_scale);
  }
  for (int col = 0; col < 3; ++col) {
    const bool whole =
        undetermined[3 * col] && undetermined[3 * col + 1] && undetermined[3 * col + 2];
    if (whole) {
      result->undetermined.push_back(absl::StrFormat("gyro matrix column %c (rotations about %c)",
                                                     kAxisNames[col], kAxisNames[col]));
      continue;
    }
    for (int row = 0; row < 3; ++row) {
      if (!undetermined[3 * col + row]) continue;
      result->undetermined.push_back(
          absl::StrFormat("gyro matrix entry (%c,%c)", kAxisNames[row], kAxisNames[col]));
    }
  }
  for (int i = 0; i < 9; ++i) {
    if (!undetermined[i]) continue;
    result->covariance.row(i).setConstant(kNaN);
    result->covariance.col(i).setConstant(kNaN);
  }
  result->rank_deficient = split.rank < 9 || !result->undetermined.empty();
}

void AnalyseSolution(const std::vector<PreparedMove>& moves, const std::vector<PreparedTurn>& turns,
                     const Linearisation& lin, const GyroSolveOptions& options,
                     GyroSolveResult* result) {
  const SpectralSplit split = SplitSpectrum(lin.hessian);
  const int dof = 2 * static_cast<int>(moves.size()) + TurnConstraints(turns) - split.rank;
  const double reduced_chi2 = dof > 0 ? 2.0 * result->cost / dof : kNaN;
  result->covariance = reduced_chi2 * split.pseudo_inverse;
  if (std::isfinite(reduced_chi2)) {
    // Moves in time order share their rests (and a hand-held move's error grows with its
    // angle): the sandwich over the moves (core/robust_covariance.h); the turns, whose angle is
    // known, as information at the fit's misfit.
    std::vector<ObservationBlock> blocks;
    blocks.reserve(moves.size());
    for (size_t i = 0; i < moves.size(); ++i)
      blocks.push_back({lin.jacobians[i], lin.residuals[i]});
    result->covariance = RobustCovariance(split.pseudo_inverse, blocks,
                                          reduced_chi2 * lin.turn_hessian, result->covariance);
  }
  const double matrix_scale = result->matrix.norm() / std::sqrt(3.0);
  FindUndetermined(split, result->covariance, matrix_scale, options.undetermined_rel_sigma, result);
  result->move_error_rad.reserve(moves.size());
  for (const PreparedMove& move : moves) {
    result->move_error_rad.push_back(MoveAngleError(move, result->matrix));
  }
  for (const PreparedTurn& turn : turns) {
    result->turn_error_rad.push_back(TurnResidual(turn, result->matrix, nullptr).norm());
  }
}

// First-order leave-one-out (see the header): one Gauss-Newton step without move i from the full
// solution, then move i re-integrated exactly.
std::vector<double> HeldOutErrors(const std::vector<PreparedMove>& moves, const Linearisation& lin,
                                  const Eigen::Matrix3d& m) {
  std::vector<double> errors;
  errors.reserve(moves.size());
  for (size_t i = 0; i < moves.size(); ++i) {
    const Mat39& j = lin.jacobians[i];
    const Mat99 h = lin.hessian - j.transpose() * j;
    const Vec9 g = lin.gradient - j.transpose() * lin.residuals[i];
    const Vec9 step = -SplitSpectrum(h).pseudo_inverse * g;
    const Eigen::Matrix3d m_without = m + Eigen::Map<const Eigen::Matrix3d>(step.data());
    errors.push_back(MoveAngleError(moves[i], m_without));
  }
  return errors;
}

}  // namespace

absl::Status ValidateGyroMoves(const std::vector<double>& t_s,
                               const std::vector<Eigen::Vector3d>& gyro_raw,
                               const std::vector<GyroMove>& moves) {
  if (absl::Status status = TimeIsValid(t_s, gyro_raw); !status.ok()) return status;
  for (size_t i = 0; i < moves.size(); ++i) {
    if (absl::Status status = MoveIsValid(t_s, gyro_raw, moves[i], i); !status.ok()) {
      return status;
    }
  }
  return absl::OkStatus();
}

Eigen::Vector3d PredictUpAfterMove(const std::vector<double>& t_s,
                                   const std::vector<Eigen::Vector3d>& gyro_raw,
                                   const GyroMove& move, const Eigen::Matrix3d& matrix,
                                   const Eigen::Vector3d& bias, bool interpolate_bias) {
  if (!MoveIsValid(t_s, gyro_raw, move, 0).ok()) return Eigen::Vector3d::Constant(kNaN);
  const PreparedMove prepared = PrepareMove(t_s, gyro_raw, move, bias, interpolate_bias);
  return IntegrateDeltaR(prepared.increments, matrix, nullptr).transpose() * move.up_before;
}

Eigen::Vector3d GyroMoveResidual(const std::vector<double>& t_s,
                                 const std::vector<Eigen::Vector3d>& gyro_raw, const GyroMove& move,
                                 const Eigen::Matrix3d& matrix, const Eigen::Vector3d& bias,
                                 bool interpolate_bias, Eigen::Matrix<double, 3, 9>* jacobian) {
  if (!MoveIsValid(t_s, gyro_raw, move, 0).ok()) {
    if (jacobian != nullptr) jacobian->setConstant(kNaN);
    return Eigen::Vector3d::Constant(kNaN);
  }
  const PreparedMove prepared = PrepareMove(t_s, gyro_raw, move, bias, interpolate_bias);
  return MoveResidual(prepared, matrix, jacobian);
}

double EstimateIsotropicScale(const std::vector<double>& t_s,
                              const std::vector<Eigen::Vector3d>& gyro_raw,
                              const std::vector<GyroMove>& moves, const GyroSolveOptions& options) {
  if (moves.empty() || !ValidateGyroMoves(t_s, gyro_raw, moves).ok()) return kNaN;
  return IsotropicScale(PrepareMoves(t_s, gyro_raw, moves, options));
}

absl::StatusOr<GyroSolveResult> SolveGyroFromMoves(const std::vector<double>& t_s,
                                                   const std::vector<Eigen::Vector3d>& gyro_raw,
                                                   const std::vector<GyroMove>& moves,
                                                   const GyroSolveOptions& options) {
  return SolveGyroFromMovesAndTurns(t_s, gyro_raw, moves, {}, options);
}

Eigen::Vector3d IntegrateRawTurn(const std::vector<double>& t_s,
                                 const std::vector<Eigen::Vector3d>& gyro_raw,
                                 const GyroFullTurn& turn, const GyroSolveOptions& options) {
  GyroMove m;
  m.begin = turn.begin;
  m.end = turn.end;
  m.bias_before = turn.bias_before;
  m.bias_after = turn.bias_after;
  if (!MoveIsValid(t_s, gyro_raw, m, 0).ok()) return Eigen::Vector3d::Constant(kNaN);
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& c :
       PrepareMove(t_s, gyro_raw, m, options.bias, options.interpolate_bias).increments)
    sum += c;
  return sum;
}

absl::StatusOr<GyroSolveResult> SolveGyroFromMovesAndTurns(
    const std::vector<double>& t_s, const std::vector<Eigen::Vector3d>& gyro_raw,
    const std::vector<GyroMove>& moves, const std::vector<GyroFullTurn>& turns,
    const GyroSolveOptions& options) {
  if (absl::Status status = OptionsAreValid(options); !status.ok()) return status;
  if (absl::Status status = ValidateGyroMoves(t_s, gyro_raw, moves); !status.ok()) {
    return status;
  }
  std::vector<PreparedTurn> prepared_turns;
  for (size_t i = 0; i < turns.size(); ++i) {
    PreparedTurn p;
    p.integral = IntegrateRawTurn(t_s, gyro_raw, turns[i], options);
    if (!p.integral.allFinite() || !(turns[i].angle_rad > 0) || !turns[i].axis.allFinite()) {
      return absl::InvalidArgumentError(absl::StrCat("turn ", i, ": cannot be integrated"));
    }
    if (turns[i].axis.squaredNorm() > 0) p.axis = turns[i].axis.normalized();
    p.angle = turns[i].angle_rad;
    prepared_turns.push_back(p);
  }
  if (moves.size() < 3 && turns.empty()) {
    return absl::FailedPreconditionError(absl::StrCat(
        "gyro calibration needs at least 3 moves between static poses, got ", moves.size()));
  }
  const std::vector<PreparedMove> prepared = PrepareMoves(t_s, gyro_raw, moves, options);

  GyroSolveResult result;
  Eigen::Matrix3d initial = options.initial_matrix;
  if (options.scale_unknown && !prepared_turns.empty()) {
    double angle = 0, integral = 0;
    for (const PreparedTurn& t : prepared_turns) angle += t.angle, integral += t.integral.norm();
    result.initial_scale = integral > 0 ? angle / integral : kNaN;
    if (!std::isfinite(result.initial_scale)) {
      return absl::FailedPreconditionError("no gyro rate in any turn: cannot find its scale");
    }
    initial = result.initial_scale * Eigen::Matrix3d::Identity();
  } else if (options.scale_unknown) {
    result.initial_scale = IsotropicScale(prepared);
    if (!std::isfinite(result.initial_scale)) {
      return absl::FailedPreconditionError("no gyro rate in any move: cannot find its scale");
    }
    initial = result.initial_scale * Eigen::Matrix3d::Identity();
  }
  absl::StatusOr<LmOutcome> lm =
      RunLevenbergMarquardt(prepared, prepared_turns, initial, options.max_iterations);
  if (!lm.ok()) return lm.status();
  result.matrix = lm->matrix;
  result.iterations = lm->iterations;
  result.cost = lm->cost;
  result.converged = lm->converged;

  const Linearisation lin = Linearise(prepared, prepared_turns, result.matrix);
  AnalyseSolution(prepared, prepared_turns, lin, options, &result);
  if (options.compute_heldout)
    result.heldout_error_rad = HeldOutErrors(prepared, lin, result.matrix);
  return result;
}

}  // namespace imucal::core
