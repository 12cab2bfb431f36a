// The effect search's internals (core/effects.h is its public face): the working model, the fits,
// the candidates of a round and the Search that runs the stages. FindEffects() (search.cc) runs
// them as Ceres's Solver::Solve runs its phases:
//
//   input (the converged model without effects)
//     -> refit          the model refitted with the search's weights (refit.cc): the
//                       accelerometer jointly on Ceres with its priors, the gyroscope's static
//                       rate by exact weighted least squares; the given effects entered
//     -> rounds, until nothing passes or max_effects:
//          candidates   the dictionary's regressors each output may take now: excitation,
//                       absorption, marginality, lower powers; the held parameters to re-examine
//                       (candidates.cc)
//          screening    each scored against the current weighted design (F, BIC, held out) and
//                       tested (screening.cc)
//          selection    the lowest BIC, then the simpler of an ambiguous pair, what the robot can
//                       apply, and the moves' judgement (selection.cc)
//          refit        the winner entered (or the held parameter freed), everything refitted
//     -> report         the stored model (applied effects only), rows, notes, detection bounds,
//                       the rotation residuals, human units (report.cc)
//
// The moves' own search (core/move_effects.h) is beside it: move_model.cc, move_search.cc.
#ifndef IMUCAL_CORE_EFFECTS_SEARCH_H_
#define IMUCAL_CORE_EFFECTS_SEARCH_H_

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/effects.h"
#include "core/effects/common.h"

namespace imucal::core::effects {

constexpr double kMgPerMs2 = kStandardGravity / 1e3;  // m/s^2 per mg
// A signal is excited when its spread over the poses exceeds this many times its own noise.
constexpr double kExcitedRatio = 5.0;
// The rotations between poses judge at most this many passing accelerometer candidates per
// round (each costs a gyroscope refit over every move).
constexpr size_t kMaxMoveJudged = 8;

inline const char* AxisName(int axis) { return axis == 0 ? "x" : axis == 1 ? "y" : "z"; }
inline const char* SensorName(Sensor s) { return s == Sensor::kAccel ? "accel" : "gyro"; }

inline bool UsesSignal(const Regressor& r, Signal s) {
  for (int i = 0; i < r.num_factors; ++i)
    if (r.factors[i] == static_cast<int>(s)) return true;
  return false;
}

// RMS of the finite values (NaN when none is).
double RmsOf(const std::vector<double>& v);
// RMS of the vectors' norms (NaN when empty).
double GyroRms(const std::vector<Eigen::Vector3d>& v);

// An effect in the working model: what it acts on, its regressor and its coefficient.
struct Term {
  Sensor sensor = Sensor::kAccel;
  int axis = 0;
  Regressor regressor;
  double coefficient = 0;
  bool applied = true;
};

// The working model: the accelerometer and gyroscope fits and the effects added so far.
struct State {
  AccelParams accel;
  AccelMask free{};  // the accelerometer model's estimated parameters (the search may free more)
  // The priors the accelerometer stage estimated its terms with (EffectSearchInput::
  // accel_priors): every refit of the search is the same maximum a posteriori fit, with the
  // effects' coefficients beside the model's terms.
  AccelPriors priors;
  Eigen::Vector3d gyro_offset = Eigen::Vector3d::Zero();  // rad/s, added to the static rate fit
  std::vector<Term> terms;
};

// Which signals vary over the poses by more than their own noise (candidates.cc).
using Excitation = std::array<bool, kNumSignals>;

// The weighted design of a fit: [free model columns | term columns] and the weighted residual at
// the current state, one row per pose, then (accelerometer) one per active prior
// ((theta_c - value) / sigma, core/accel_solver.h ActivePriors).
struct Design {
  Eigen::MatrixXd x;
  Eigen::VectorXd r;
  std::vector<double> weight;  // per pose: 1 / sigma_i, sigma_i^2 = noise_i^2 + tau^2
  // The rows after the poses' that are priors: not observations of the capture. They shape the
  // fit, not the count of data (BIC's N, the held-out sum, the degrees of freedom).
  Eigen::Index prior_rows = 0;
  // Mean of noise_i^2 / sigma_i^2: the weighted residual variance that the within-pose noise
  // alone would give (1 when tau = 0). The F statistic's variance never goes below it.
  double noise_s2 = 1.0;
};

// The whole model's fit: accelerometer (Ceres joint) and gyroscope (linear) with a state's
// terms: the standard errors of the terms and the residuals.
struct Fit {
  std::vector<double> accel_residual, accel_heldout;         // m/s^2
  std::vector<Eigen::Vector3d> gyro_residual, gyro_heldout;  // rad/s
  std::vector<double> term_stderr;                           // per State::terms
  Eigen::MatrixXd accel_cov;                                 // over [free | accel coefficients]
};

// One candidate of a round: what it is (candidates.cc), then its score (screening.cc) and, when
// the moves judged it, their verdict (selection.cc).
struct RoundCandidate {
  CandidateScore score;
  Regressor regressor;
  // Lower powers that enter with it (`(temperature-31.2)` with `(temperature-31.2)^2` when the
  // first is not in yet) and their coefficients (SI per regressor unit).
  std::vector<Regressor> lower;
  std::vector<double> lower_coefficients;
  // >= 0: not an effect but a held parameter of the accelerometer model, re-examined
  // (PackAccel index).
  int model_param = -1;
  Eigen::VectorXd perp;
  // Set when the rotations between poses were consulted (Search::ResolveByMoves): the
  // gravity-direction error after each move (rad) with the gyroscope refitted to this
  // candidate's pose directions.
  std::vector<double> move_error_rad;

  bool Judged() const { return !move_error_rad.empty(); }
  double MoveRms() const;
};

// The candidate's name, its lower powers first: "gyro x ~ (temperature-31.2) +
// (temperature-31.2)^2".
std::string Describe(const RoundCandidate& c);
std::string Describe(Sensor sensor, int axis, const Regressor& r);
bool UsesTime(const RoundCandidate& c);
// The terms a candidate adds to the model, lower powers first.
std::vector<Term> TermsOf(const RoundCandidate& c, bool apply_time);
Effect ToEffect(const Term& t);

// The candidate scorer: the current weighted design's orthonormal basis, leverages and residual
// (screening.cc).
class Scorer {
 public:
  // The statistics count the poses' rows (n_) and the parameters they pay for (p_,
  // EffectiveColumns); the fit and the projections use every row.
  explicit Scorer(const Design& d);
  // The parameters the poses pay for (EffectiveColumns).
  double pays_for() const { return p_; }
  // The residual variance a candidate is tested against before it enters (weighted units).
  double variance() const {
    return std::max(noise_s2_, rss_ / std::max(1.0, static_cast<double>(n_) - p_));
  }
  // The size of the last of `pose_cols` beyond the model and the columns before it (0 when they
  // span it): what a coefficient on it moves the residual by, per unit.
  double LastBeyond(const Eigen::MatrixXd& pose_cols) const;
  double rss() const { return rss_; }

  // Fills score (except threshold/passed) for a candidate of one or more columns entering
  // together (a power with its lower powers); false when the current model absorbs any of them.
  // `perp` is the fitted direction beyond the model (the columns' part the model lacks, times
  // their coefficients); `coefficients` are per column, in column units.
  // `pose_cols` has a row per pose; a candidate has no prior (its rows there are zero).
  bool Score(const Eigen::MatrixXd& pose_cols, CandidateScore* s, Eigen::VectorXd* perp,
             Eigen::VectorXd* coefficients) const;

 private:
  // A candidate's columns (a row per pose) with zero rows for the priors, which it has none of.
  Eigen::MatrixXd Padded(const Eigen::MatrixXd& pose_cols) const;

  Eigen::VectorXd r_;
  Eigen::Index rows_, n_;
  double p_ = 0;
  double noise_s2_;
  Eigen::MatrixXd q_;
  Eigen::VectorXd h_;
  double rss_ = 0;
};

// The weighted designs candidates are scored against at a state: the accelerometer's (its poses
// with the state's model error) and each gyroscope axis's.
struct RoundDesigns {
  std::vector<AccelPose> accel_poses;
  Design accel;
  std::unique_ptr<Scorer> accel_scorer;
  std::array<std::vector<double>, 3> gyro_weight;
  std::array<std::unique_ptr<Scorer>, 3> gyro_scorer;
  const Scorer& For(Sensor sensor, int axis) const {
    return sensor == Sensor::kAccel ? *accel_scorer : *gyro_scorer[static_cast<size_t>(axis)];
  }
};

// What the selection chose among a round's passing candidates (indices into them).
struct Choice {
  int best = -1;         // what enters: after the moves' judgement
  int static_best = -1;  // the static choice (|a| - g), before the moves' judgement
  int gave_way = -1;     // a time candidate that gave way to one the robot can apply, or -1
};

// One search over a capture's poses. Each stage is a member, defined in the file of its stage.
class Search {
 public:
  Search(const EffectSearchInput& in, const EffectSearchOptions& opt);  // search.cc
  absl::StatusOr<EffectSearchResult> Run();                             // search.cc

 private:
  // search.cc: the driver.
  State StartState() const;
  absl::Status EnterGiven(State* st, Fit* fit, EffectSearchResult* out);
  // One round; false when nothing entered (the search is over).
  absl::StatusOr<bool> Round(int round, const Excitation& excited, State* st, Fit* fit,
                             EffectSearchResult* out);
  absl::Status Finish(const State& st, const Fit& fit, const Fit& base, const Excitation& excited,
                      EffectSearchResult* out);

  // refit.cc: the model refitted with `st`'s terms. `previous`: a fit of the same accelerometer
  // terms (a gyroscope term was added): its accelerometer part is reused, the expensive part
  // being the leave-one-out refits.
  absl::StatusOr<Fit> Refit(State* st, const Fit* previous = nullptr);
  absl::Status RefitAccel(State* st, Fit* out);
  void RefitGyro(State* st, Fit* out) const;
  double GyroTau(int j, const std::vector<const Term*>& terms) const;  // of gyro axis j

  // candidates.cc: the round's candidates, unscored, in the dictionary's order, then the held
  // parameters to re-examine.
  std::vector<RoundCandidate> Candidates(const State& st, const Excitation& excited, int* absorbed,
                                         int* not_excited) const;
  std::optional<std::vector<Regressor>> LowerPowers(const State& st, Sensor sensor, int axis,
                                                    const Regressor& r) const;

  // screening.cc: scores the candidates (drops the absorbed), then tests them; the passing one
  // with the lowest BIC, or -1.
  std::vector<RoundCandidate> Screen(const State& st, std::vector<RoundCandidate> proposed,
                                     int* absorbed);
  int Test(const State& st, std::vector<RoundCandidate>* cands) const;
  RoundDesigns DesignsAt(const State& st);
  Eigen::MatrixXd CandidateColumns(const RoundDesigns& d, const State& st, Sensor sensor, int axis,
                                   const std::vector<Regressor>& group) const;
  Eigen::Index DofAfter(const State& st, Sensor sensor, int axis) const;

  // selection.cc
  Choice Select(const State& st, int best, std::vector<RoundCandidate>* cands) const;
  void ResolveByMoves(const State& st, std::vector<RoundCandidate>* cands, int* best) const;
  std::vector<Eigen::Vector3d> Directions(const State& st) const;
  double MoveTThreshold(int tests, size_t moves) const;

  // search.cc: the winner in, everything refitted, what entered reported.
  absl::Status FreeHeld(const RoundCandidate& win, State* st, Fit* fit, EffectDiagnostics* diag);
  absl::Status EnterEffect(const std::vector<RoundCandidate>& cands, const Choice& choice,
                           int tests, State* st, Fit* fit, EffectSearchResult* out);

  // report.cc
  std::string Evidence(const RoundCandidate& win, const RoundCandidate& static_best,
                       const std::vector<RoundCandidate>& cands, int tests,
                       EffectDiagnostics* diag) const;
  void NoiseFloors(EffectDiagnostics* diag) const;
  void Rows(const Fit& before, const Fit& after, const Fit& all, EffectDiagnostics* diag) const;
  void FinalNotes(const State& st, const Fit& fit, EffectDiagnostics* diag) const;
  void TemperatureBounds(const State& st, const Excitation& excited, EffectDiagnostics* diag);

  const EffectSearchInput& in_;
  const EffectSearchOptions& opt_;
  std::vector<EffectPose> poses_;
  std::vector<SignalArray> signals_;
  std::vector<Eigen::Vector3d> rates_;
  std::vector<Eigen::Vector3d> gyro_sigma_;
  EffectReference reference_;
  SignalArray centre_{};       // reference_ indexed by Signal
  std::vector<int> freed_;     // held parameters freed by the re-examination, in order
  double accel_pays_for_ = 0;  // the accelerometer design's EffectiveColumns at the last round
  int last_tests_ = 0;         // the candidates of the last round (its Bonferroni count)
};

// Candidates (candidates.cc).
Excitation ExcitedSignals(const std::vector<EffectPose>& poses,
                          const std::vector<SignalArray>& signals, const AccelParams& accel,
                          const GyroParams& gyro);
// True when the state holds `r` on that output.
bool InModel(const State& st, Sensor sensor, int axis, const Regressor& r);

// Signals and noise of the poses (refit.cc).
// Signals of every pose from the model before any effect (what the SDK computes at run time).
std::vector<SignalArray> PoseSignals(const std::vector<EffectPose>& poses, const AccelParams& accel,
                                     const GyroParams& gyro);
// Baseline static rates (rad/s) of the gyro model, before effects and the fitted offset.
std::vector<Eigen::Vector3d> StaticRates(const std::vector<EffectPose>& poses,
                                         const std::vector<SignalArray>& signals);
// Per pose and gyro axis: the std of the static mean in rad/s (noise through the gyro matrix).
std::vector<Eigen::Vector3d> GyroSigmas(const std::vector<EffectPose>& poses,
                                        const GyroParams& gyro);

// The accelerometer with effects (refit.cc).
std::vector<AccelPose> AccelPoses(const std::vector<EffectPose>& poses);
// d(|a_i| - g)/d(coefficient) of an accelerometer term on `axis`: -n_body,axis * x_i.
double AccelEffectDerivative(const AccelParams& p, const AccelPose& pose, int axis, double x);
Design AccelDesign(const State& st, const std::vector<AccelPose>& poses, const AccelMask& free,
                   const std::vector<SignalArray>& signals, double g);
// Sets every pose's common model error from the residual of the current state.
void SetAccelModelSigma(const State& st, const AccelMask& free,
                        const std::vector<SignalArray>& signals, double g,
                        std::vector<EffectPose>* poses);
// Gauss-Newton over the model and the accelerometer coefficients from a nearby start (the many
// leave-one-out refits; the reported joint fit runs on Ceres).
void AccelGaussNewton(const AccelMask& free, const std::vector<SignalArray>& signals, double g,
                      std::vector<EffectPose> poses, State* st, int iterations);

// The gyroscope with effects (refit.cc). Per gyro axis, the static-rate model offset_j + sum_k
// c_k x_ik is linear: exact weighted least squares, with the exact leave-one-out residuals.
struct GyroAxisFit {
  Eigen::VectorXd residual;    // rad/s
  Eigen::VectorXd heldout;     // rad/s
  Eigen::MatrixXd covariance;  // over [offset | coefficients], scaled by chi^2 when above 1
  Eigen::VectorXd solution;
  Design design;  // weighted, at the solution
};
GyroAxisFit FitGyroAxis(int axis, const std::vector<Eigen::Vector3d>& rates,
                        const std::vector<Eigen::Vector3d>& sigma, double tau,
                        const std::vector<const Term*>& terms,
                        const std::vector<SignalArray>& signals);

// Selection (selection.cc).
// True when `a` and `b` are one explanation to the static residual: nearly collinear beyond the
// current model.
bool Collinear(const RoundCandidate& a, const RoundCandidate& b);
// True when `b` holds `a`'s terms and more on the same output.
bool Nested(const RoundCandidate& a, const RoundCandidate& b);
// True when `a` and `b` are collinear and their BIC differ by less than `max_delta_bic`.
bool Ambiguous(const RoundCandidate& a, const RoundCandidate& b,
               double max_delta_bic = kAmbiguousBic);
// True when `a` and `b` act on the same output axis through the same specific-force factors,
// differing only in temperature or time.
bool SameGeometry(const RoundCandidate& a, const RoundCandidate& b);
// One-sided paired t of the moves' squared errors: positive when `b`'s directions fit the
// rotations between poses better than `a`'s. NaN unless both were judged.
double MovePairedT(const RoundCandidate& a, const RoundCandidate& b);

// Screening (screening.cc): a round's best six by F on stderr (IMUCAL_DEBUG_EFFECTS).
void DebugDump(int round, const std::vector<RoundCandidate>& cands);

// Report (report.cc).
// What would tell two regressors apart.
std::string Separator(const Regressor& a, const Regressor& b);
// The first round's best few by F.
void KeepTop(std::vector<RoundCandidate> cands, EffectDiagnostics* diag);
void FillAccelCovariance(const AccelMask& free, const Fit& fit, EffectSearchResult* out);

}  // namespace imucal::core::effects

#endif  // IMUCAL_CORE_EFFECTS_SEARCH_H_
