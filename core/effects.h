// Closing the loop: find in a finished solve's residuals what the model misses, trace it to an
// effect, add the effect, and show the error before and after (issue "close the loop").
//
// RESIDUALS examined, one row per used static pose i:
//   accelerometer  r_i = |a_i| - g                      a_i = calibrated specific force, m/s^2
//   gyroscope      w_i = M (v_i - b) - C a_i            calibrated static rate, rad/s, per axis
// (the rotation residuals between poses are examined too, see EffectDiagnostics::notes).
//
// SIGNALS of a pose: temperature (mean, degC), time (pose middle, s from capture start), the
// calibrated specific force ax, ay, az (m/s^2) and rate gx, gy, gz (rad/s) of the model before
// any effect, as the SDK's Corrector computes them at run time. Pose order is not a signal of
// its own: poses come one after another, so an effect that grows with the order grows with
// `time`, which the robot can evaluate and the spec names (an order index would only reshape
// time by the hold lengths). Rates are zero at rest; they are tested on the moves.
//
// DICTIONARY (generic, nothing listed by hand): every regressor of one or two factors over the
// signals the capture has (core/regressor.h: `temperature`, `ax*az`, `time^2`, ...), acting
// additively on one output axis of either sensor:
//   out[axis] -= coefficient * regressor          (core/params.h Effect)
// Its trace on the residual follows from the model: an accelerometer term on axis j moves |a_i|
// by -n_ij * x_i (n_i = a_i / |a_i|, the pose's gravity direction), a gyroscope term moves the
// static rate of axis j by -x_i. A candidate that is one of the model's own terms (any `ax` on
// the accelerometer is scale or misalignment, `ax^2` on accel x is quadratic_x) or that the
// current model spans numerically is skipped as "absorbed"; one whose signal does not vary over
// the poses (rates at rest: the static rate is the residual itself) is "not excited".
// The magnitude |a| - g cannot tell every pair apart: `ax*az` on x moves |a| exactly as `ax^2`
// on z (both by ax^2 az / |a|), so a cross-axis quadratic and a per-axis quadratic of another
// axis are one explanation to the static residual. The rotations between poses tell them apart
// (THE MOVES, below): each candidate's pose directions, with the gyroscope refitted to them (a
// gyroscope fitted once to the uncorrected directions would absorb most of the difference).
// Without moves, or when they do not decide, the search reports the tie rather than pretending
// to know the axis.
//
// POLYNOMIALS in temperature and time are written about a reference inside the capture
// (EffectReference: the mean pose temperature and time), `(temperature-31.2)` rather than
// `temperature`: degC and time since power-on have no physical zero, so a polynomial about 0
// has nearly collinear coefficients and a square alone cannot put its turnover anywhere but at
// 0. A power enters only with its lower powers: `(temperature-31.2)^2` on an output where
// `(temperature-31.2)` is not in is scored as the pair (an F test on 2 degrees of freedom, BIC
// penalty 2 ln N, the held-out margin per column), so a quadratic with its turnover anywhere is
// one candidate. A product of temperature and time is a candidate only once both its main
// terms are in on that output.
//
// MARGINALITY: a regressor that multiplies temperature or time with sensor signals
// (`temperature*ax`) is a candidate on an output only once its sensor part (`ax`) is modelled
// there, by the model's own terms or an effect already in: it says how a coefficient changes,
// and degC has an arbitrary zero, so alone it is the main term in disguise.
//
// SELECTION, forward stepwise. Each round scores every candidate by linearised least squares
// against the current model (weights 1 / (sigma_i^2 + tau^2): sigma_i the pose mean's noise from
// the scatter within the pose, tau the model error common to all poses, 0 when the noise
// explains the residual). A candidate enters only if all three hold:
//   1. F = dRSS / s^2 exceeds the F(1, dof) quantile at alpha / m: m the number of candidates
//      tested in the round (Bonferroni), s^2 = RSS_after / dof the residual variance, but never
//      below what the within-pose noise alone would give (the noise level);
//   2. the Bayesian information criterion falls: N ln(RSS_after / RSS_before) + ln N < 0;
//   3. the held-out (leave-one-pose-out) weighted sum of squares falls by more than the same
//      margin, F* s^2: the effect must predict poses it was not fitted to.
// The passing candidate with the lowest BIC enters, the model is refitted jointly (accelerometer:
// Ceres over the free model parameters and every accelerometer effect coefficient, with the
// priors the accelerometer stage estimated its terms with, EffectSearchInput::accel_priors;
// gyroscope: the static model is linear in its bias and coefficients, an exact weighted least
// squares), and the search repeats until nothing passes.
// THE MODEL STAYS WHOLE (issue 25): a second-order term or angle the poses hardly determine is
// neither held at a value nor dropped while the effects are searched; it stays shrunk toward its
// prior, moves with the effects in every refit (the leave-one-pose-out ones included), and its
// uncertainty enters the effects' standard errors (the sandwich covariance of
// core/robust_covariance.h, the priors as information). The statistics count the poses, and the
// parameters the poses pay for: the trace of the hat matrix over the poses' rows, where a term
// its prior decides counts for nothing and one the poses decide for 1. Candidates as collinear with
// the chosen one (beyond the current model, correlation over 0.9) whose BIC is within 6 of it are
// named in the notes with what would tell them apart: the data do not strongly prefer one (Kass and
// Raftery: a BIC difference under 2 is "barely worth a mention", 2-6 "positive", over 6 "strong").
// Within 2 the simpler regressor (and one without `time`) enters. PREFER WHAT THE ROBOT CAN APPLY:
// unless time effects are opted in, a candidate containing `time` gives way to the best passing one
// made only of run-time signals (temperature, specific force) on the same sensor within 6 of its
// BIC (collinear with it or not): a time term is not applied on the robot, so a weak
// preference for time would leave a real effect uncorrected (the notes still name both, and
// what capture would tell them apart).
// RE-EXAMINATION: an unmodelled effect masks what the base model's selection saw (a warm-up's
// drift hides a quadratic's evidence, so the selection held it at 0). Once an effect is in, every
// parameter in EffectSearchInput::accel_held is a candidate of each round beside the effects,
// scored by the same F, BIC and held-out rule on its column of the |a| - g Jacobian; one that
// passes and wins the round is freed (estimated from then on) and the rounds go on, so the
// model is examined again after every change until nothing passes. The notes name each one
// freed. (The gyroscope's static model is its bias alone: it holds nothing to re-examine.)
// THE MOVES then judge accelerometer candidates when the pipeline gives EffectSearchInput::
// move_fit: the best passing ones by BIC (up to 8) that differ from the chosen one in their
// output axis or specific-force factors (not only in temperature or time, which the moves,
// made during the same warm-up, cannot tell apart any better) are each added to the model,
// refitted, and their pose directions handed to the gyroscope, refitted to them. A candidate whose
// directions the rotations between poses fit better than the chosen one's (one-sided paired t over
// the moves' squared errors, at alpha over the number compared) replaces it; among several, the one
// the moves fit best. A paired test over moves, not a likelihood over their components: a
// pose's direction enters the move before it and the one after it, so the components are not
// independent, and the test must not count them as if they were. This is what tells `ax*az` on
// x from `ax^2` on z, and it overrules the static ranking only on significant evidence.
// DETECTION BOUNDS: "none found" must say whether none is there. On every output where no
// temperature term entered, the search states the smallest bias slope `(temperature-T)` and
// curvature `(temperature-T)^2` (with its slope: a turnover anywhere) that it would have found 9
// times in 10 on this capture (core/move_effects.h DetectionBound), and says it in a note: a
// capture whose temperature hardly moves gets a large bound, or none at all when it does not
// vary. The moves' search does the same for the gyroscope's rate-dependent scale.
#ifndef IMUCAL_CORE_EFFECTS_H_
#define IMUCAL_CORE_EFFECTS_H_

#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "core/accel_solver.h"
#include "core/move_effects.h"
#include "core/params.h"
#include "core/regressor.h"

namespace imucal::core {

// One used static pose, as the diagnostics see it.
struct EffectPose {
  int pose_index = 0;  // index in CalibrationReport::poses
  AccelPose accel;     // raw mean and its std (input units); offset and model sigma are set here
  Eigen::Vector3d gyro_mean = Eigen::Vector3d::Zero();       // raw, input units
  Eigen::Vector3d gyro_mean_std = Eigen::Vector3d::Ones();   // std of that mean, input units
  double temp_c = std::numeric_limits<double>::quiet_NaN();  // NaN: no temperature channel
  double time_s = 0.0;  // the pose's middle, s from capture start
};

// The gravity-direction error after one move between static poses (the gyroscope's rotation
// residual), with the signals of the move.
struct EffectMoveResidual {
  double error_rad = 0;     // angle between predicted and measured gravity direction after it
  double rotation_rad = 0;  // total rotation of the move
  double time_s = 0;        // the move's middle, s from capture start
  double temp_c = std::numeric_limits<double>::quiet_NaN();
  // The angle between the gravity directions before and after it (NaN: not known). A move that
  // turned about the vertical (a full turn on a table, a face placed again) leaves gravity where
  // it was: its gravity-direction error is near zero whatever the gyroscope does.
  double tilt_rad = std::numeric_limits<double>::quiet_NaN();
};

// The gyroscope refitted to a set of pose directions: the gravity-direction error after each
// move (rad), in a fixed order of the moves.
struct MoveFit {
  std::vector<double> error_rad;
};

// An effect whose form the caller knows (sensor, axis, regressor): it enters the model before the
// search, its coefficient fitted with the model's. A centred factor sets the reference the other
// effects are centred on (all given effects must agree on it).
struct GivenEffect {
  Sensor sensor = Sensor::kAccel;
  int axis = 0;
  std::string regressor;
};

struct EffectSearchOptions {
  bool enabled = true;
  std::vector<GivenEffect> given;  // entered before the search (e.g. a reference fit)
  double family_alpha = 0.01;      // false-alarm probability per round over all candidates
  int max_effects = 10;
  int max_factors = 2;  // regressors of at most this many factors
  // Effects on `time` (drift since power-on) are found and reported; applied only when true.
  bool apply_time_effects = false;
};

// Score of one candidate in the round it was tested (units: weighted, i.e. noise units).
struct CandidateScore {
  Sensor sensor = Sensor::kAccel;
  int axis = 0;
  std::string regressor;
  double f = 0;  // dRSS / s^2
  double f_threshold = 0;
  double delta_bic = 0;    // < 0: the criterion prefers the effect
  double press_gain = 0;   // held-out weighted sum of squares before - after
  double coefficient = 0;  // linearised, SI per regressor unit
  bool passed = false;
};

// Per used pose, for plots and the report: the signals and the residuals without and with the
// effects found (in-sample, SI).
struct EffectPoseRow {
  int pose_index = 0;
  SignalArray signals{};  // indexed by Signal; temperature NaN when absent
  // before: no effects; after: the stored model (applied effects); all: every effect found,
  // applied or not (the fit the coefficients come from).
  double accel_before_m_s2 = 0, accel_after_m_s2 = 0, accel_all_m_s2 = 0;  // |a| - g
  Eigen::Vector3d gyro_before_rad_s = Eigen::Vector3d::Zero();             // static rate
  Eigen::Vector3d gyro_after_rad_s = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_all_rad_s = Eigen::Vector3d::Zero();
};

// Six-face protocols fix each face's orientation: the per-axis residual of a verified face,
// calibrated minus +-g on the face axis. The face's reading is its 180-degree pair's mean size
// (the mean of the two sizes) along the axis the pair was turned about (core/protocol.h
// PairTurnAxis): the floor tilt then cancels whatever the turn's error, where the pair's mean
// leaves tilt * error / 2.
struct FaceResidual {
  std::string face;                                         // "X+", ...
  Eigen::Vector3d residual_m_s2 = Eigen::Vector3d::Zero();  // body frame, with the stored model
};

// One signal's linear trend in the gravity-direction error after the moves (see
// EffectSearchInput::moves): slope and its standard error in the reported unit.
struct MoveTrend {
  std::string signal;  // "the rotation angle", "time", "temperature"
  std::string unit;    // the slope's: "deg per 100 deg", "deg per minute", "deg per degC"
  double slope_deg = 0, slope_std_error_deg = 0;
  double f = 0, f_threshold = 0;  // F(1, moves - 2) of the slope, 1% over the signals tested
  bool significant = false;       // f > f_threshold: named in the notes
};

struct EffectDiagnostics {
  bool ran = false;
  int rounds = 0;
  int candidates = 0;   // distinct candidates tested in the first round
  int absorbed = 0;     // skipped: the model already spans them
  int not_excited = 0;  // skipped: the regressor does not vary over the poses
  // Noise floors: the RMS the static residual would have if the model were perfect, from the
  // scatter within each pose.
  double accel_noise_floor_m_s2 = 0;
  double gyro_noise_floor_rad_s = 0;
  // Held-out (leave-one-pose-out) RMS of the static residual, without and with all effects.
  double accel_heldout_before_m_s2 = 0, accel_heldout_after_m_s2 = 0;
  double gyro_heldout_before_rad_s = 0, gyro_heldout_after_rad_s = 0;
  std::vector<CandidateScore> top;  // the best few candidates of the first round
  std::vector<EffectPoseRow> rows;
  std::vector<FaceResidual> faces;     // six-face only, filled by the pipeline
  std::vector<MoveTrend> move_trends;  // every signal tested on the moves (6 moves or more)
  // The rate-dependent gyroscope terms tested on the moves (core/move_effects.h).
  MoveEffectDiagnostics move_search;
  // What the capture could not have missed (DETECTION BOUNDS): per output without a temperature
  // term, the smallest bias slope and curvature in temperature it would have found; the moves'
  // bounds on the gyro's rate-dependent scale are in move_search.
  std::vector<DetectionBound> detection_bounds;
  std::vector<std::string> notes;  // ambiguities, what was not testable, residual vs floor
};

struct EffectSearchInput {
  std::vector<EffectPose> poses;
  double gravity_m_s2 = kStandardGravity;
  AccelParams accel;       // the converged model without effects
  AccelMask accel_free{};  // its free parameters
  // The priors it was estimated with (core/calibrate/term_priors.h: the second-order terms and
  // angles of the sensor class, the faces' angles): every refit of the search keeps them, so a
  // weakly determined term stays shrunk toward its prior and its uncertainty enters the effects'
  // standard errors, as in the model without effects (issue 25).
  AccelPriors accel_priors;
  // Parameters the data determine but the model held (a quadratic the selection kept at 0, an
  // angle kept at the face references): once an effect is in, each is tested again with it
  // present, by the same rule as a candidate effect (RE-EXAMINATION).
  AccelMask accel_held{};
  GyroParams gyro;
  // False when the gyro model's output is not in rad/s (raw counts without a calibrated scale):
  // gyroscope effects are then not searched.
  bool gyro_output_si = true;
  // Examined for structure (does the error grow with the rotation angle, time, temperature?):
  // what static poses cannot test, a rate-dependent gyro effect, shows up here. Reported as a
  // note; nothing is added to the model from it.
  std::vector<EffectMoveResidual> moves;
  // The rotations between poses as a second, independent view of the accelerometer (optional).
  // Given every pose's calibrated specific-force direction (unit, body frame, in the order of
  // `poses`), refits the gyroscope matrix to them and returns the gravity-direction residuals
  // after the moves. Static |a| - g cannot tell `ax*az` on x from `ax^2` on z; the directions
  // they give differ, and so do the rotations that connect them (SELECTION, above).
  std::function<std::optional<MoveFit>(const std::vector<Eigen::Vector3d>& up)> move_fit;
};

struct EffectSearchResult {
  AccelParams accel;  // refitted jointly with the applied accelerometer effects
  GyroParams gyro;    // bias refitted with the applied gyroscope effects
  AccelMatrix accel_covariance = AccelMatrix::Zero();
  AccelMask accel_free{};       // the parameters estimated in the end (input's, and any freed)
  std::vector<Effect> effects;  // in the order found
  EffectReference reference;    // what the effects' centred factors are taken about
  EffectDiagnostics diagnostics;
};

// Runs the search (see the top of this file). Never adds an effect the data does not support;
// with too few poses it says how few and returns the model unchanged.
absl::StatusOr<EffectSearchResult> FindEffects(const EffectSearchInput& input,
                                               const EffectSearchOptions& options);

// The rotation residuals examined for structure (EffectSearchInput::moves): fills
// diag->move_trends and adds the "rotation residuals: ..." note, replacing what an earlier
// examination put there (the pipeline examines the moves again after it refits the gyroscope to
// the directions an applied accelerometer effect corrects). Moves whose gravity direction turned
// less than 5 degrees (tilt_rad) are left out and counted in the note: their error is blind to
// the gyroscope, and their near-zero errors at near-zero net rotation would read as a trend with
// the angle. Fewer than 6 moves left: nothing.
void ExamineMoveResiduals(const std::vector<EffectMoveResidual>& moves, EffectDiagnostics* diag);

// The effect's coefficient in the units an engineer uses: mg/degC, deg/s per g, ppm/degC, ...,
// with its standard error: "0.52 +- 0.03 mg/degC".
std::string HumanCoefficient(const Effect& effect);
// A value of a coefficient of that form in the same units, 2 digits: "0.021 mg/degC".
std::string HumanValue(Sensor sensor, const std::string& regressor, double value);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_EFFECTS_H_
