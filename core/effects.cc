#include "core/effects.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <memory>
#include <string>
#include <string_view>
#include <utility>

#include "Eigen/Dense"
#include "absl/strings/str_format.h"
#include "boost/math/distributions/fisher_f.hpp"
#include "boost/math/distributions/students_t.hpp"
#include "ceres/ceres.h"
#include "core/accel_problem.h"
#include "core/robust_covariance.h"
#include "util/str_util.h"

namespace imucal::core {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kRadToDeg = 180.0 / M_PI;
constexpr double kMgPerMs2 = kStandardGravity / 1e3;  // m/s^2 per mg
// A candidate whose column keeps less than this fraction of its norm once the current model's
// columns are projected out is numerically in the model (a bias, a scale). Nearly collinear
// ones stay: the F test judges whether the part the model lacks is significant.
constexpr double kAbsorbedFraction = 1e-3;
// A signal is excited when its spread over the poses exceeds this many times its own noise.
constexpr double kExcitedRatio = 5.0;
// Two candidates of one sensor explain the data equally well when their columns (beyond the
// current model) are this collinear and their BIC differ by less than kAmbiguousBic (Kass and
// Raftery: "not worth more than a bare mention"); among such ties the simpler one enters.
// Up to kWeakEvidenceBic (Kass and Raftery: "positive", not yet "strong") the data favour one
// but do not settle the question: the better one enters on its merit and the rival is still
// named in the notes. In simulation a slow warm-up (temperature nearly linear in time) puts a
// temperature effect 2-6 ahead of time in BIC (only the warm-up's curvature tells them apart),
// which a note gated at 2 left unsaid.
constexpr double kAmbiguousCorrelation = 0.9;
constexpr double kAmbiguousBic = 2.0;
constexpr double kWeakEvidenceBic = 6.0;
// The rotations between poses judge at most this many passing accelerometer candidates per
// round (each costs a gyroscope refit over every move).
constexpr size_t kMaxMoveJudged = 8;

// The accelerometer model's own terms: linear in the specific force (scale, misalignment) and
// the square of the output axis's own signal (its quadratic). The model's observability and
// selection decide those; the search does not re-add them as effects.
bool IsModelTerm(Sensor sensor, int axis, const Regressor& r) {
  if (sensor != Sensor::kAccel) return false;
  const auto is_accel = [](int s) {
    return s >= static_cast<int>(Signal::kAx) && s <= static_cast<int>(Signal::kAz);
  };
  if (r.num_factors == 1) return is_accel(r.factors[0]);
  return r.num_factors == 2 && r.factors[0] == r.factors[1] &&
         r.factors[0] == static_cast<int>(Signal::kAx) + axis;
}

const char* AxisName(int axis) { return axis == 0 ? "x" : axis == 1 ? "y" : "z"; }
const char* SensorName(Sensor s) { return s == Sensor::kAccel ? "accel" : "gyro"; }

bool UsesSignal(const Regressor& r, Signal s) {
  for (int i = 0; i < r.num_factors; ++i)
    if (r.factors[i] == static_cast<int>(s)) return true;
  return false;
}

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

// The marginality rule for interactions with temperature or time. `temperature*ax` on gyro y
// says that the gyroscope's sensitivity to ax changes with temperature; a coefficient can
// change only where the model has one. Without its main term the product is that main term
// scaled by an arbitrary origin (degC has no physical zero: over a 25-33 degC capture
// `temperature*ax` is nearly 29 times `ax`), and the two would trade places on noise alone.
// So a regressor that multiplies temperature or time with sensor signals is a candidate only
// when its sensor part is modelled on that output: by the model's own terms (the accelerometer's
// linear map and quadratic, the gyroscope's matrix over the rates) or by an effect already in.
// Pure temperature or time regressors are bias terms, whose main term (the bias) every model has.
bool MainTermModelled(const State& st, Sensor sensor, int axis, const Regressor& r) {
  Regressor main;  // r without its temperature and time factors (still sorted)
  for (int i = 0; i < r.num_factors; ++i) {
    const int f = r.factors[i];
    if (f != static_cast<int>(Signal::kTemperature) && f != static_cast<int>(Signal::kTime))
      main.factors[main.num_factors++] = f;
  }
  if (main.num_factors == r.num_factors || main.num_factors == 0) return true;
  if (IsModelTerm(sensor, axis, main)) return true;
  const bool rate = main.num_factors == 1 && main.factors[0] >= static_cast<int>(Signal::kGx);
  if (sensor == Sensor::kGyro && rate) return true;
  for (const Term& t : st.terms)
    if (t.sensor == sensor && t.axis == axis && t.regressor == main) return true;
  return false;
}

// Signals of every pose from the model before any effect (what the SDK computes at run time).
std::vector<SignalArray> PoseSignals(const std::vector<EffectPose>& poses, const AccelParams& accel,
                                     const GyroParams& gyro) {
  std::vector<SignalArray> out;
  for (const EffectPose& p : poses) {
    const Eigen::Vector3d a = accel.Apply(p.accel.mean);
    const Eigen::Vector3d w = gyro.Apply(p.gyro_mean, a);
    SignalArray s{};
    s[static_cast<size_t>(Signal::kTemperature)] = p.temp_c;
    s[static_cast<size_t>(Signal::kTime)] = p.time_s;
    for (int k = 0; k < 3; ++k) {
      s[static_cast<size_t>(Signal::kAx) + k] = a(k);
      s[static_cast<size_t>(Signal::kGx) + k] = w(k);
    }
    out.push_back(s);
  }
  return out;
}

// Baseline static rates (rad/s) of the gyro model, before effects and the fitted offset.
std::vector<Eigen::Vector3d> StaticRates(const std::vector<EffectPose>& poses,
                                         const std::vector<SignalArray>& signals) {
  std::vector<Eigen::Vector3d> out;
  for (size_t i = 0; i < poses.size(); ++i) {
    const SignalArray& s = signals[i];
    out.emplace_back(s[static_cast<size_t>(Signal::kGx)], s[static_cast<size_t>(Signal::kGy)],
                     s[static_cast<size_t>(Signal::kGz)]);
  }
  return out;
}

// Per pose and gyro axis: the std of the static mean in rad/s (noise through the gyro matrix).
std::vector<Eigen::Vector3d> GyroSigmas(const std::vector<EffectPose>& poses,
                                        const GyroParams& gyro) {
  std::vector<Eigen::Vector3d> out;
  for (const EffectPose& p : poses) {
    Eigen::Vector3d s;
    for (int j = 0; j < 3; ++j)
      s(j) = std::max(1e-15, gyro.matrix.row(j).transpose().cwiseProduct(p.gyro_mean_std).norm());
    out.push_back(s);
  }
  return out;
}

// tau with sum r_i^2 / (sigma_i^2 + tau^2) = dof (0 when the noise explains the residual).
double CommonModelSigma(const std::vector<double>& r, const std::vector<double>& sigma,
                        double dof) {
  auto chi2 = [&](double tau) {
    double s = 0;
    for (size_t i = 0; i < r.size(); ++i) s += r[i] * r[i] / (sigma[i] * sigma[i] + tau * tau);
    return s;
  };
  if (dof <= 0 || chi2(0) <= dof) return 0.0;
  double hi = 1e-300;
  for (double x : r) hi = std::max(hi, 10 * std::abs(x));
  double lo = 0;
  for (int it = 0; it < 80; ++it) {
    const double mid = 0.5 * (lo + hi);
    (chi2(mid) > dof ? lo : hi) = mid;
  }
  return hi;
}

// ---------------------------------------------------------------- accelerometer with effects

// Sets every pose's frame-free offset from the accelerometer terms.
void SetAccelOffsets(const State& st, const std::vector<SignalArray>& signals,
                     std::vector<EffectPose>* poses) {
  const Eigen::Matrix3d rt = ExpSo3<double>(st.accel.frame_angles).transpose();
  for (size_t i = 0; i < poses->size(); ++i) {
    Eigen::Vector3d body = Eigen::Vector3d::Zero();
    for (const Term& t : st.terms)
      if (t.sensor == Sensor::kAccel)
        body(t.axis) += t.coefficient * t.regressor.Evaluate(signals[i]);
    (*poses)[i].accel.offset_m_s2 = rt * body;
  }
}

std::vector<AccelPose> AccelPoses(const std::vector<EffectPose>& poses) {
  std::vector<AccelPose> out;
  for (const EffectPose& p : poses) out.push_back(p.accel);
  return out;
}

// d(|a_i| - g)/d(coefficient) of an accelerometer term on `axis`: -n_body,axis * x_i.
double AccelEffectDerivative(const AccelParams& p, const AccelPose& pose, int axis, double x) {
  const Eigen::Vector3d a_ff =
      LowerMisalignment<double>(p.tri_angles) * p.PerAxis(pose.mean) - pose.offset_m_s2;
  const Eigen::Vector3d n_body = ExpSo3<double>(p.frame_angles) * a_ff.normalized();
  return -n_body(axis) * x;
}

// The accelerometer's weighted design [free model columns | accelerometer term columns] and
// weighted residual at the current state: one row per pose, then one per active prior
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

Design AccelDesign(const State& st, const std::vector<AccelPose>& poses, const AccelMask& free,
                   const std::vector<SignalArray>& signals, double g) {
  Design d;
  const std::vector<double> sigma = MagnitudeSigmas(st.accel, poses);
  std::vector<AccelPose> bare = poses;
  for (AccelPose& p : bare) p.model_sigma_m_s2 = 0;
  const std::vector<double> noise = MagnitudeSigmas(st.accel, bare);
  d.noise_s2 = 0;
  for (size_t i = 0; i < poses.size(); ++i)
    d.noise_s2 += std::pow(noise[i] / sigma[i], 2) / static_cast<double>(poses.size());
  const std::vector<double> r = MagnitudeResiduals(st.accel, poses, g);
  const Eigen::MatrixXd j = MagnitudeJacobian(st.accel, poses);
  std::vector<int> cols;
  for (int c = 0; c < kAccelParams; ++c)
    if (free[static_cast<size_t>(c)]) cols.push_back(c);
  std::vector<const Term*> terms;
  for (const Term& t : st.terms)
    if (t.sensor == Sensor::kAccel) terms.push_back(&t);
  const auto n = static_cast<Eigen::Index>(poses.size());
  const std::vector<AccelPrior> active = ActivePriors(free, st.priors);
  d.prior_rows = static_cast<Eigen::Index>(active.size());
  d.x = Eigen::MatrixXd::Zero(n + d.prior_rows,
                              static_cast<Eigen::Index>(cols.size() + terms.size()));
  d.r.resize(n + d.prior_rows);
  const AccelVector theta = PackAccel(st.accel);
  for (Eigen::Index m = 0; m < d.prior_rows; ++m) {
    const AccelPrior& q = active[static_cast<size_t>(m)];
    const auto col = std::find(cols.begin(), cols.end(), q.index) - cols.begin();
    d.x(n + m, col) = 1.0 / q.sigma;
    d.r(n + m) = (theta(q.index) - q.value) / q.sigma;
  }
  for (Eigen::Index i = 0; i < n; ++i) {
    const double w = 1.0 / sigma[static_cast<size_t>(i)];
    d.weight.push_back(w);
    d.r(i) = r[static_cast<size_t>(i)] * w;
    Eigen::Index k = 0;
    for (int c : cols) d.x(i, k++) = j(i, c) * w;
    for (const Term* t : terms)
      d.x(i, k++) = AccelEffectDerivative(st.accel, poses[static_cast<size_t>(i)], t->axis,
                                          t->regressor.Evaluate(signals[static_cast<size_t>(i)])) *
                    w;
  }
  return d;
}

// The parameters the poses pay for in a design with prior rows: the trace of the hat matrix over
// the poses' rows (a term its prior decides counts for nothing, one the poses decide for 1;
// core/accel_solver.h EffectiveParameters). The column count when there are no prior rows.
double EffectiveColumns(const Design& d) {
  if (d.prior_rows == 0 || d.x.rows() <= d.x.cols()) return static_cast<double>(d.x.cols());
  const Eigen::MatrixXd info = d.x.transpose() * d.x;
  const Eigen::MatrixXd obs = d.x.topRows(d.x.rows() - d.prior_rows);
  const Eigen::MatrixXd share = info.ldlt().solve(obs.transpose() * obs);
  return share.allFinite() ? share.trace() : static_cast<double>(d.x.cols());
}

// Applies a step over [free model parameters | accelerometer term coefficients].
void StepAccel(const Eigen::VectorXd& step, const AccelMask& free, State* st) {
  AccelVector theta = PackAccel(st->accel);
  Eigen::Index k = 0;
  for (int c = 0; c < kAccelParams; ++c)
    if (free[static_cast<size_t>(c)]) theta(c) += step(k++);
  st->accel = UnpackAccel(theta, st->accel.frame_angles);
  for (Term& t : st->terms)
    if (t.sensor == Sensor::kAccel) t.coefficient += step(k++);
}

// Gauss-Newton over the model and the accelerometer coefficients from a nearby start (the many
// leave-one-out refits; the reported joint fit runs on Ceres).
void AccelGaussNewton(const AccelMask& free, const std::vector<SignalArray>& signals, double g,
                      std::vector<EffectPose> poses, State* st, int iterations) {
  for (int it = 0; it < iterations; ++it) {
    SetAccelOffsets(*st, signals, &poses);
    const Design d = AccelDesign(*st, AccelPoses(poses), free, signals, g);
    if (d.x.rows() <= d.x.cols()) return;
    const Eigen::VectorXd step = d.x.colPivHouseholderQr().solve(-d.r);
    if (!step.allFinite()) return;
    StepAccel(step, free, st);
    if (step.norm() < 1e-12 * (1 + PackAccel(st->accel).norm())) return;
  }
}

// One pose's weighted magnitude residual with the accelerometer terms as Ceres parameters:
// blocks bias, scale, tri, quadratic (3 each) and, when there are terms, their coefficients.
class AccelEffectCost : public ceres::CostFunction {
 public:
  AccelEffectCost(const AccelPose& pose, const Eigen::Vector3d& frame_angles,
                  std::vector<std::pair<int, double>> terms, double g, double inv_sigma)
      : pose_(pose), frame_(frame_angles), terms_(std::move(terms)), g_(g), w_(inv_sigma) {
    set_num_residuals(1);
    for (int b = 0; b < 4; ++b) mutable_parameter_block_sizes()->push_back(3);
    if (!terms_.empty())
      mutable_parameter_block_sizes()->push_back(static_cast<int>(terms_.size()));
  }

  bool Evaluate(double const* const* params, double* residual, double** jacobians) const override {
    AccelParams p;
    p.bias = Eigen::Map<const Eigen::Vector3d>(params[0]);
    p.scale = Eigen::Map<const Eigen::Vector3d>(params[1]);
    p.tri_angles = Eigen::Map<const Eigen::Vector3d>(params[2]);
    p.quadratic = Eigen::Map<const Eigen::Vector3d>(params[3]);
    p.frame_angles = frame_;
    AccelPose pose = pose_;
    const Eigen::Matrix3d rt = ExpSo3<double>(frame_).transpose();
    Eigen::Vector3d body = Eigen::Vector3d::Zero();
    for (size_t k = 0; k < terms_.size(); ++k)
      body(terms_[k].first) += params[4][k] * terms_[k].second;
    pose.offset_m_s2 = rt * body;
    const std::vector<AccelPose> one = {pose};
    residual[0] = MagnitudeResiduals(p, one, g_)[0] * w_;
    if (jacobians == nullptr) return std::isfinite(residual[0]);
    const Eigen::MatrixXd j = MagnitudeJacobian(p, one);
    for (int b = 0; b < 4; ++b)
      if (jacobians[b] != nullptr)
        for (int k = 0; k < 3; ++k) jacobians[b][k] = j(0, 3 * b + k) * w_;
    if (!terms_.empty() && jacobians[4] != nullptr) {
      for (size_t k = 0; k < terms_.size(); ++k)
        jacobians[4][k] = AccelEffectDerivative(p, pose, terms_[k].first, terms_[k].second) * w_;
    }
    return std::isfinite(residual[0]);
  }

 private:
  AccelPose pose_;
  Eigen::Vector3d frame_;
  std::vector<std::pair<int, double>> terms_;  // (axis, regressor value at this pose)
  double g_, w_;
};

// The joint refit: Ceres over the free model parameters and every accelerometer coefficient,
// weights fixed at the start. Returns the covariance over [free | coefficients] (scaled by the
// reduced chi^2 when above 1) and writes the result into `st`.
absl::StatusOr<Eigen::MatrixXd> AccelJointFit(const AccelMask& free,
                                              const std::vector<SignalArray>& signals, double g,
                                              std::vector<EffectPose> poses, State* st) {
  SetAccelOffsets(*st, signals, &poses);
  const std::vector<double> sigma = MagnitudeSigmas(st->accel, AccelPoses(poses));
  std::vector<double> coeffs;
  std::vector<Term*> terms;
  for (Term& t : st->terms)
    if (t.sensor == Sensor::kAccel) terms.push_back(&t), coeffs.push_back(t.coefficient);
  AccelParams& p = st->accel;
  const AccelBlocks blocks = AccelParamBlocks(&p);
  ceres::Problem problem;
  for (size_t i = 0; i < poses.size(); ++i) {
    std::vector<std::pair<int, double>> values;
    for (const Term* t : terms) values.emplace_back(t->axis, t->regressor.Evaluate(signals[i]));
    AccelPose bare = poses[i].accel;
    bare.offset_m_s2.setZero();
    auto* cost = new AccelEffectCost(bare, p.frame_angles, std::move(values), g, 1.0 / sigma[i]);
    std::vector<double*> b(blocks.begin(), blocks.end());
    if (!coeffs.empty()) b.push_back(coeffs.data());
    problem.AddResidualBlock(cost, nullptr, b);
  }
  const absl::StatusOr<AccelProblemSummary> solved = SolveAccelProblem(
      free, st->priors, blocks, "joint accelerometer refit with effects", &problem);
  if (!solved.ok()) return solved.status();
  for (size_t k = 0; k < terms.size(); ++k) terms[k]->coefficient = coeffs[k];
  SetAccelOffsets(*st, signals, &poses);
  const Design d = AccelDesign(*st, AccelPoses(poses), free, signals, g);
  // As the accelerometer stage's (core/accel_solver.h RefineAccelLm): the poses pay for what
  // the priors leave to them (EffectiveColumns); scaled by the reduced chi^2 when above 1, then the
  // sandwich over the poses in time order with the priors as information
  // (core/robust_covariance.h).
  const Eigen::Index n_poses = d.x.rows() - d.prior_rows;
  const double dof = static_cast<double>(n_poses) - EffectiveColumns(d);
  const Eigen::MatrixXd info = d.x.transpose() * d.x;
  const Eigen::MatrixXd bread =
      info.ldlt().solve(Eigen::MatrixXd::Identity(info.rows(), info.cols()));
  const double chi2 = dof > 0 ? d.r.head(n_poses).squaredNorm() / dof : 1.0;
  Eigen::MatrixXd cov = chi2 > 1 ? Eigen::MatrixXd(bread * chi2) : bread;
  std::vector<ObservationBlock> blocks_in_time;
  blocks_in_time.reserve(static_cast<size_t>(n_poses));
  for (Eigen::Index i = 0; i < n_poses; ++i)
    blocks_in_time.push_back({d.x.row(i), d.r.segment(i, 1)});
  const Eigen::MatrixXd prior_rows = d.x.bottomRows(d.prior_rows);
  return RobustCovariance(bread, blocks_in_time, prior_rows.transpose() * prior_rows, cov);
}

// Sets every pose's common model error from the residual of the current state.
void SetAccelModelSigma(const State& st, const AccelMask& free,
                        const std::vector<SignalArray>& signals, double g,
                        std::vector<EffectPose>* poses) {
  SetAccelOffsets(st, signals, poses);
  std::vector<AccelPose> bare = AccelPoses(*poses);
  for (AccelPose& p : bare) p.model_sigma_m_s2 = 0;
  const double n_free = EffectiveColumns(AccelDesign(st, AccelPoses(*poses), free, signals, g));
  const double tau =
      CommonModelSigma(MagnitudeResiduals(st.accel, bare, g), MagnitudeSigmas(st.accel, bare),
                       static_cast<double>(poses->size()) - n_free);
  for (EffectPose& p : *poses) p.accel.model_sigma_m_s2 = tau;
}

// Leave-one-pose-out |a| - g (m/s^2), exact refits from the full fit.
constexpr double kMaxHeldOutLeverage = 0.99;

std::vector<double> AccelHeldOut(const State& st, const AccelMask& free,
                                 const std::vector<SignalArray>& signals, double g,
                                 const std::vector<EffectPose>& poses) {
  std::vector<double> out(poses.size(), kNaN);
  // A pose with leverage near 1 is the only one that fixes some combination of the parameters
  // (a face placed once, in a protocol without pairs): without it that combination is not
  // determined, and "predicting" it measures nothing. Such poses stay NaN (left out of every
  // held-out RMS; the notes say how many).
  std::vector<EffectPose> all = poses;
  SetAccelOffsets(st, signals, &all);
  const Design d = AccelDesign(st, AccelPoses(all), free, signals, g);
  Eigen::VectorXd leverage = Eigen::VectorXd::Ones(d.x.rows());
  if (d.x.rows() > d.x.cols()) {
    const Eigen::HouseholderQR<Eigen::MatrixXd> qr(d.x);
    const Eigen::MatrixXd q = qr.householderQ() * Eigen::MatrixXd::Identity(d.x.rows(), d.x.cols());
    leverage = q.rowwise().squaredNorm();
  }
  for (size_t i = 0; i < poses.size(); ++i) {
    if (leverage(static_cast<Eigen::Index>(i)) > kMaxHeldOutLeverage) continue;
    std::vector<EffectPose> rest = poses;
    std::vector<SignalArray> rest_signals = signals;
    rest.erase(rest.begin() + static_cast<long>(i));
    rest_signals.erase(rest_signals.begin() + static_cast<long>(i));
    State refit = st;
    AccelGaussNewton(free, rest_signals, g, rest, &refit, 8);
    std::vector<EffectPose> one = {poses[i]};
    SetAccelOffsets(refit, {signals[i]}, &one);
    out[i] = MagnitudeResiduals(refit.accel, AccelPoses(one), g)[0];
  }
  return out;
}

// --------------------------------------------------------------------- gyroscope with effects

// Per gyro axis, the static-rate model offset_j + sum_k c_k x_ik is linear: exact weighted least
// squares. Returns the residuals (rad/s) and, through `heldout`, the exact leave-one-out ones.
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
                        const std::vector<SignalArray>& signals) {
  const auto n = static_cast<Eigen::Index>(rates.size());
  const auto p = static_cast<Eigen::Index>(1 + terms.size());
  Eigen::MatrixXd x(n, p);
  Eigen::VectorXd y(n);
  std::vector<double> w(static_cast<size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i) {
    const auto ii = static_cast<size_t>(i);
    w[ii] = 1.0 / std::hypot(sigma[ii](axis), tau);
    x(i, 0) = w[ii];
    for (size_t k = 0; k < terms.size(); ++k)
      x(i, static_cast<Eigen::Index>(k + 1)) = terms[k]->regressor.Evaluate(signals[ii]) * w[ii];
    y(i) = rates[ii](axis) * w[ii];
  }
  GyroAxisFit out;
  const Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(x);
  out.solution = qr.solve(y);
  const Eigen::VectorXd e = y - x * out.solution;
  const Eigen::MatrixXd info = x.transpose() * x;
  out.covariance = info.ldlt().solve(Eigen::MatrixXd::Identity(p, p));
  const double dof = static_cast<double>(n - p);
  const double chi2 = dof > 0 ? e.squaredNorm() / dof : 1.0;
  if (chi2 > 1) out.covariance *= chi2;
  out.residual.resize(n);
  out.heldout.resize(n);
  const Eigen::MatrixXd inv = info.ldlt().solve(Eigen::MatrixXd::Identity(p, p));
  for (Eigen::Index i = 0; i < n; ++i) {
    const double h = x.row(i).dot(inv * x.row(i).transpose());
    out.residual(i) = e(i) / w[static_cast<size_t>(i)];
    out.heldout(i) = out.residual(i) / std::max(1e-9, 1.0 - h);
  }
  out.design.x = x;
  out.design.r = e;
  out.design.weight = w;
  out.design.noise_s2 = 0;
  for (Eigen::Index i = 0; i < n; ++i) {
    const auto ii = static_cast<size_t>(i);
    out.design.noise_s2 += std::pow(sigma[ii](axis) * w[ii], 2) / static_cast<double>(n);
  }
  return out;
}

// ------------------------------------------------------------------------------ scoring

// The candidate scorer: the current weighted design's orthonormal basis, leverages and residual.
class Scorer {
 public:
  // The statistics count the poses' rows (n_) and the parameters they pay for (p_,
  // EffectiveColumns); the fit and the projections use every row.
  explicit Scorer(const Design& d)
      : r_(d.r), rows_(d.x.rows()), n_(d.x.rows() - d.prior_rows), noise_s2_(d.noise_s2) {
    const Eigen::HouseholderQR<Eigen::MatrixXd> qr(d.x);
    q_ = qr.householderQ() * Eigen::MatrixXd::Identity(rows_, d.x.cols());
    h_ = q_.rowwise().squaredNorm();
    p_ = h_.head(n_).sum();
    rss_ = r_.squaredNorm();
  }
  // The parameters the poses pay for (EffectiveColumns).
  double pays_for() const { return p_; }
  // The residual variance a candidate is tested against before it enters (weighted units).
  double variance() const {
    return std::max(noise_s2_, rss_ / std::max(1.0, static_cast<double>(n_) - p_));
  }
  // The size of the last of `pose_cols` beyond the model and the columns before it (0 when they
  // span it): what a coefficient on it moves the residual by, per unit.
  double LastBeyond(const Eigen::MatrixXd& pose_cols) const {
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
  double rss() const { return rss_; }

  // Fills score (except threshold/passed) for a candidate of one or more columns entering
  // together (a power with its lower powers); false when the current model absorbs any of them.
  // `perp` is the fitted direction beyond the model (the columns' part the model lacks, times
  // their coefficients); `coefficients` are per column, in column units.
  // `pose_cols` has a row per pose; a candidate has no prior (its rows there are zero).
  bool Score(const Eigen::MatrixXd& pose_cols, CandidateScore* s, Eigen::VectorXd* perp,
             Eigen::VectorXd* coefficients) const {
    const Eigen::MatrixXd cols = Padded(pose_cols);
    const Eigen::MatrixXd p = cols - q_ * (q_.transpose() * cols);
    const Eigen::Index k = cols.cols();
    for (Eigen::Index c = 0; c < k; ++c) {
      const double norm2 = p.col(c).squaredNorm();
      if (!(norm2 > kAbsorbedFraction * kAbsorbedFraction * cols.col(c).squaredNorm()) ||
          norm2 <= 0)
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
      const double after =
          (r_(i) - (*perp)(i)) / std::max(1e-9, 1 - h_(i) - qp.row(i).squaredNorm());
      press_before += before * before;
      press_after += after * after;
    }
    s->press_gain = (press_before - press_after) / s2;
    s->coefficient = (*coefficients)(k - 1);  // the last column's; the caller converts
    return true;
  }

 private:
  // A candidate's columns (a row per pose) with zero rows for the priors, which it has none of.
  Eigen::MatrixXd Padded(const Eigen::MatrixXd& pose_cols) const {
    Eigen::MatrixXd cols = Eigen::MatrixXd::Zero(rows_, pose_cols.cols());
    cols.topRows(pose_cols.rows()) = pose_cols;
    return cols;
  }

  Eigen::VectorXd r_;
  Eigen::Index rows_, n_;
  double p_ = 0;
  double noise_s2_;
  Eigen::MatrixXd q_;
  Eigen::VectorXd h_;
  double rss_ = 0;
};

double FThreshold(double alpha, int tests, Eigen::Index dof, int df1 = 1) {
  if (dof < 1 || tests < 1) return std::numeric_limits<double>::infinity();
  const boost::math::fisher_f_distribution<double> f(static_cast<double>(df1),
                                                     static_cast<double>(dof));
  return boost::math::quantile(boost::math::complement(f, alpha / tests));
}

// Every regressor of 1..max_factors factors over the signals.
std::vector<Regressor> Dictionary(int max_factors) {
  std::vector<Regressor> out;
  for (int a = 0; a < kNumSignals; ++a) {
    Regressor r;
    r.factors[0] = a;
    r.num_factors = 1;
    out.push_back(r);
    if (max_factors < 2) continue;
    for (int b = a; b < kNumSignals; ++b) {
      Regressor r2 = r;
      r2.factors[1] = b;
      r2.num_factors = 2;
      out.push_back(r2);
    }
  }
  return out;
}

// Which signals vary over the poses by more than their own noise.
std::array<bool, kNumSignals> ExcitedSignals(const std::vector<EffectPose>& poses,
                                             const std::vector<SignalArray>& signals,
                                             const AccelParams& accel, const GyroParams& gyro) {
  std::array<bool, kNumSignals> out{};
  const auto n = static_cast<double>(signals.size());
  for (int s = 0; s < kNumSignals; ++s) {
    double mean = 0, noise2 = 0;
    bool finite = true;
    for (size_t i = 0; i < signals.size(); ++i) {
      const double v = signals[i][static_cast<size_t>(s)];
      finite &= std::isfinite(v);
      mean += v / n;
      // Measurement noise of the signal at this pose (accel and rate through the model).
      if (s >= static_cast<int>(Signal::kAx) && s <= static_cast<int>(Signal::kAz)) {
        const int k = s - static_cast<int>(Signal::kAx);
        const Eigen::Matrix3d m = accel.Misalignment() * accel.scale.asDiagonal();
        noise2 += m.row(k).transpose().cwiseProduct(poses[i].accel.mean_std).squaredNorm() / n;
      } else if (s >= static_cast<int>(Signal::kGx)) {
        const int k = s - static_cast<int>(Signal::kGx);
        noise2 +=
            gyro.matrix.row(k).transpose().cwiseProduct(poses[i].gyro_mean_std).squaredNorm() / n;
      }
    }
    // At rest the true rate is zero: a measured static rate is the gyroscope's residual itself,
    // so rates are never excited on static poses (they are tested on the moves).
    if (!finite || s >= static_cast<int>(Signal::kGx)) continue;
    double var = 0;
    for (const SignalArray& a : signals) var += std::pow(a[static_cast<size_t>(s)] - mean, 2) / n;
    out[static_cast<size_t>(s)] = var > 0 && var > kExcitedRatio * kExcitedRatio * noise2;
  }
  return out;
}

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
  double MoveRms() const {
    double s = 0;
    for (double e : move_error_rad) s += e * e;
    return std::sqrt(s / static_cast<double>(std::max<size_t>(1, move_error_rad.size())));
  }
};

std::string Describe(Sensor sensor, int axis, const Regressor& r) {
  return Cat(SensorName(sensor), " ", AxisName(axis), " ~ ", r.Name());
}

// The candidate's name, its lower powers first: "gyro x ~ (temperature-31.2) +
// (temperature-31.2)^2".
std::string Describe(const RoundCandidate& c) {
  if (c.model_param >= 0) return Cat("accel model term ", AccelParamName(c.model_param));
  std::string terms;
  for (const Regressor& l : c.lower) terms += l.Name() + " + ";
  return Cat(SensorName(c.score.sensor), " ", AxisName(c.score.axis), " ~ ", terms,
             c.regressor.Name());
}

bool UsesTime(const RoundCandidate& c) {
  bool time = UsesSignal(c.regressor, Signal::kTime);
  for (const Regressor& l : c.lower) time |= UsesSignal(l, Signal::kTime);
  return time;
}

// The terms a candidate adds to the model, lower powers first.
std::vector<Term> TermsOf(const RoundCandidate& c, bool apply_time) {
  std::vector<Term> out;
  const auto add = [&](const Regressor& r, double coefficient) {
    Term t;
    t.sensor = c.score.sensor;
    t.axis = c.score.axis;
    t.regressor = r;
    t.coefficient = coefficient;
    t.applied = !UsesSignal(r, Signal::kTime) || apply_time;
    out.push_back(t);
  };
  for (size_t k = 0; k < c.lower.size(); ++k) add(c.lower[k], c.lower_coefficients[k]);
  add(c.regressor, c.score.coefficient);
  return out;
}

// What would tell two regressors apart.
std::string Separator(const Regressor& a, const Regressor& b) {
  const bool temp = UsesSignal(a, Signal::kTemperature) || UsesSignal(b, Signal::kTemperature);
  const bool time = UsesSignal(a, Signal::kTime) || UsesSignal(b, Signal::kTime);
  if (temp && time) {
    return "temperature and time rose together in this capture; a capture at a steady "
           "temperature (or one that warms and cools) would tell them apart";
  }
  return "poses that vary one of them without the other, or per-axis references (known "
         "orientations), would tell them apart";
}

std::string TermName(const Term& t) { return Describe(t.sensor, t.axis, t.regressor); }

Effect ToEffect(const Term& t) {
  Effect e;
  e.sensor = t.sensor;
  e.axis = t.axis;
  e.regressor = t.regressor.Name();
  e.coefficient = t.coefficient;
  e.applied = t.applied;
  return e;
}

double RmsOf(const std::vector<double>& v) {
  double s = 0;
  int n = 0;
  for (double x : v)
    if (std::isfinite(x)) s += x * x, ++n;
  return n > 0 ? std::sqrt(s / n) : kNaN;
}

// The whole model's fit: accelerometer (Ceres joint) and gyroscope (linear) with `st`'s terms.
// Fills the standard errors of the terms and the residuals.
struct Fit {
  std::vector<double> accel_residual, accel_heldout;         // m/s^2
  std::vector<Eigen::Vector3d> gyro_residual, gyro_heldout;  // rad/s
  std::vector<double> term_stderr;                           // per st.terms
  Eigen::MatrixXd accel_cov;                                 // over [free | accel coefficients]
};

class Search {
 public:
  Search(const EffectSearchInput& in, const EffectSearchOptions& opt) : in_(in), opt_(opt) {
    poses_ = in.poses;
    signals_ = PoseSignals(poses_, in.accel, in.gyro);
    // The references of the centred factors (params.h EffectReference): the mean over the
    // poses, rounded so the names stay readable (any reference is exact: the SDK evaluates the
    // name as written).
    double temp_sum = 0, time_sum = 0;
    int temp_n = 0;
    for (const EffectPose& p : poses_) {
      if (std::isfinite(p.temp_c)) temp_sum += p.temp_c, ++temp_n;
      time_sum += p.time_s;
    }
    if (temp_n > 0) reference_.temperature_c = std::round(temp_sum / temp_n * 10) / 10;
    if (!poses_.empty())
      reference_.time_s = std::round(time_sum / static_cast<double>(poses_.size()));
    for (const GivenEffect& g : opt.given) {
      const std::optional<Regressor> r = ParseRegressor(g.regressor);
      if (!r) continue;  // Run() refuses it
      for (int i = 0; i < r->num_factors; ++i) {
        const double c = r->centre[static_cast<size_t>(r->factors[i])];
        if (c == 0) continue;
        (r->factors[i] == static_cast<int>(Signal::kTime) ? reference_.time_s
                                                          : reference_.temperature_c) = c;
      }
    }
    centre_[static_cast<size_t>(Signal::kTemperature)] = reference_.temperature_c;
    centre_[static_cast<size_t>(Signal::kTime)] = reference_.time_s;
    rates_ = StaticRates(poses_, signals_);
    gyro_sigma_ = GyroSigmas(poses_, in.gyro);
  }

  // Refits everything with the terms in `st` (only those with applied, if `applied_only`).
  // `previous`: a fit of the same accelerometer terms (a gyroscope term was added): its
  // accelerometer part is reused, the expensive part being the leave-one-out refits.
  absl::StatusOr<Fit> Refit(State* st, const Fit* previous = nullptr) {
    Fit fit;
    fit.term_stderr.assign(st->terms.size(), kNaN);
    if (previous != nullptr) {
      fit.accel_cov = previous->accel_cov;
      fit.accel_residual = previous->accel_residual;
      fit.accel_heldout = previous->accel_heldout;
      for (size_t k = 0; k < previous->term_stderr.size(); ++k)
        if (st->terms[k].sensor == Sensor::kAccel) fit.term_stderr[k] = previous->term_stderr[k];
    } else if (absl::Status s = RefitAccel(st, &fit); !s.ok()) {
      return s;
    }
    RefitGyro(st, &fit);
    return fit;
  }

  absl::Status RefitAccel(State* st, Fit* out) {
    Fit& fit = *out;
    SetAccelModelSigma(*st, st->free, signals_, in_.gravity_m_s2, &poses_);
    absl::StatusOr<Eigen::MatrixXd> cov =
        AccelJointFit(st->free, signals_, in_.gravity_m_s2, poses_, st);
    if (!cov.ok()) return cov.status();
    SetAccelModelSigma(*st, st->free, signals_, in_.gravity_m_s2, &poses_);
    cov = AccelJointFit(st->free, signals_, in_.gravity_m_s2, poses_, st);
    if (!cov.ok()) return cov.status();
    fit.accel_cov = *cov;
    int n_free = 0;
    for (bool f : st->free) n_free += f;
    for (size_t k = 0, a = 0; k < st->terms.size(); ++k) {
      if (st->terms[k].sensor != Sensor::kAccel) continue;
      const auto idx = static_cast<Eigen::Index>(n_free + a++);
      fit.term_stderr[k] = std::sqrt(std::max(0.0, (*cov)(idx, idx)));
    }
    SetAccelOffsets(*st, signals_, &poses_);
    fit.accel_residual = MagnitudeResiduals(st->accel, AccelPoses(poses_), in_.gravity_m_s2);
    fit.accel_heldout = AccelHeldOut(*st, st->free, signals_, in_.gravity_m_s2, poses_);
    return absl::OkStatus();
  }

  void RefitGyro(State* st, Fit* out) const {
    Fit& fit = *out;
    fit.gyro_residual.assign(poses_.size(), Eigen::Vector3d::Zero());
    fit.gyro_heldout.assign(poses_.size(), Eigen::Vector3d::Zero());
    for (int j = 0; j < 3; ++j) {
      std::vector<const Term*> terms;
      std::vector<size_t> index;
      for (size_t k = 0; k < st->terms.size(); ++k)
        if (st->terms[k].sensor == Sensor::kGyro && st->terms[k].axis == j)
          terms.push_back(&st->terms[k]), index.push_back(k);
      const double tau = GyroTau(j, terms);
      const GyroAxisFit g = FitGyroAxis(j, rates_, gyro_sigma_, tau, terms, signals_);
      st->gyro_offset(j) = g.solution(0);
      for (size_t k = 0; k < terms.size(); ++k) {
        const auto c = static_cast<Eigen::Index>(k + 1);
        st->terms[index[k]].coefficient = g.solution(c);
        fit.term_stderr[index[k]] = std::sqrt(std::max(0.0, g.covariance(c, c)));
      }
      for (size_t i = 0; i < poses_.size(); ++i) {
        fit.gyro_residual[i](j) = g.residual(static_cast<Eigen::Index>(i));
        fit.gyro_heldout[i](j) = g.heldout(static_cast<Eigen::Index>(i));
      }
    }
  }

  // tau of gyro axis j for its current terms.
  double GyroTau(int j, const std::vector<const Term*>& terms) const {
    const GyroAxisFit g0 = FitGyroAxis(j, rates_, gyro_sigma_, 0.0, terms, signals_);
    std::vector<double> r, s;
    for (size_t i = 0; i < poses_.size(); ++i) {
      r.push_back(g0.residual(static_cast<Eigen::Index>(i)));
      s.push_back(gyro_sigma_[i](j));
    }
    return CommonModelSigma(r, s, static_cast<double>(poses_.size() - 1 - terms.size()));
  }

  absl::StatusOr<EffectSearchResult> Run() {
    EffectSearchResult out;
    out.reference = reference_;
    EffectDiagnostics& diag = out.diagnostics;
    diag.ran = true;
    State st;
    st.accel = in_.accel;
    st.free = in_.accel_free;
    st.priors = in_.accel_priors;
    absl::StatusOr<Fit> base = Refit(&st);
    if (!base.ok()) return base.status();
    Fit fit = *base;
    const std::array<bool, kNumSignals> excited =
        ExcitedSignals(poses_, signals_, in_.accel, in_.gyro);
    NoiseFloors(&diag);
    diag.accel_heldout_before_m_s2 = RmsOf(base->accel_heldout);
    diag.gyro_heldout_before_rad_s = GyroRms(base->gyro_heldout);
    if (!opt_.given.empty()) {
      State next = st;
      for (size_t k = 0; k < opt_.given.size(); ++k) {
        const GivenEffect& g = opt_.given[k];
        const std::optional<Regressor> r = ParseRegressor(g.regressor);
        if (!r || g.axis < 0 || g.axis > 2 || !CentreMismatch(*r, reference_).empty())
          return absl::InvalidArgumentError(absl::StrFormat(
              "given effect %d: \"%s\" on axis %d is not a regressor (core/regressor.h) on x, y "
              "or z, centred on one reference per signal",
              static_cast<int>(k), g.regressor, g.axis));
        Term t;
        t.sensor = g.sensor;
        t.axis = g.axis;
        t.regressor = *r;
        t.applied = !UsesSignal(*r, Signal::kTime) || opt_.apply_time_effects;
        next.terms.push_back(t);
      }
      absl::StatusOr<Fit> after = Refit(&next);
      if (!after.ok()) return after.status();
      for (size_t k = 0; k < next.terms.size(); ++k) {
        Effect e = ToEffect(next.terms[k]);
        e.std_error = after->term_stderr[k];
        const bool accel = e.sensor == Sensor::kAccel;
        e.error_before = accel ? RmsOf(fit.accel_heldout) : GyroRms(fit.gyro_heldout);
        e.error_after = accel ? RmsOf(after->accel_heldout) : GyroRms(after->gyro_heldout);
        e.evidence = "given: its form was stated, not searched for";
        out.effects.push_back(e);
      }
      st = next;
      fit = *after;
    }

    for (int round = 0; round < opt_.max_effects; ++round) {
      std::vector<RoundCandidate> cands;
      int absorbed = 0, not_excited = 0;
      ScoreRound(st, excited, &cands, &absorbed, &not_excited);
      if (round == 0) {
        diag.candidates = static_cast<int>(cands.size());
        diag.absorbed = absorbed;
        diag.not_excited = not_excited;
      }
      ++diag.rounds;
      if (cands.empty()) break;
      const int tests = static_cast<int>(cands.size());
      last_tests_ = tests;
      int best = -1;
      for (size_t c = 0; c < cands.size(); ++c) {
        CandidateScore& s = cands[c].score;
        const auto k = static_cast<int>(1 + cands[c].lower.size());
        s.f_threshold =
            FThreshold(opt_.family_alpha, tests, DofAfter(st, s.sensor, s.axis) - (k - 1), k);
        // The held-out margin is the same F* s^2 per column entering.
        s.passed = s.f > s.f_threshold && s.delta_bic < 0 && s.press_gain > k * s.f_threshold;
        // Ranked by BIC, which compares candidates of different axes on one scale.
        if (s.passed &&
            (best < 0 || s.delta_bic < cands[static_cast<size_t>(best)].score.delta_bic))
          best = static_cast<int>(c);
      }
      if (round == 0) KeepTop(cands, &diag);
      if (std::getenv("IMUCAL_DEBUG_EFFECTS") != nullptr) {
        std::vector<RoundCandidate> sorted = cands;
        std::sort(sorted.begin(), sorted.end(),
                  [](const auto& a, const auto& b) { return a.score.f > b.score.f; });
        for (size_t k = 0; k < 6 && k < sorted.size(); ++k) {
          const auto& sc = sorted[k].score;
          fprintf(stderr, "round %d: %s %s %s F %.1f thr %.1f bic %.1f press %.1f c %.3g %s\n",
                  round, SensorName(sc.sensor), AxisName(sc.axis), sc.regressor.c_str(), sc.f,
                  sc.f_threshold, sc.delta_bic, sc.press_gain, sc.coefficient,
                  sc.passed ? "PASS" : "");
        }
      }
      if (best < 0) break;
      if (round + 1 == opt_.max_effects) {
        diag.notes.push_back(absl::StrFormat(
            "stopped at the limit of %d effects with significant candidates left; the model may "
            "lack a term the dictionary does not hold",
            opt_.max_effects));
      }
      // Among passing candidates that explain the residual as well: the simplest regressor
      // (`temperature` before `temperature^2`), then one without `time`: a warm-up that time and
      // temperature explain equally is attributed to temperature, which the SDK applies on every
      // sample and which holds across power cycles (the ambiguity is reported either way).
      const size_t first = static_cast<size_t>(best);
      // (A candidate's size counts the lower powers entering with it.)
      auto rank = [](const RoundCandidate& c) {
        int factors = c.regressor.num_factors;
        for (const Regressor& l : c.lower) factors += l.num_factors;
        return 2 * factors + (UsesTime(c) ? 1 : 0);
      };
      for (size_t c = 0; c < cands.size(); ++c) {
        if (cands[c].score.passed && Ambiguous(cands[first], cands[c]) &&
            rank(cands[c]) < rank(cands[static_cast<size_t>(best)]))
          best = static_cast<int>(c);
      }
      // Prefer what the robot can apply. A time effect is not applied (time since power-on grows
      // without bound once the warm-up is over), so choosing it where a candidate made only of
      // run-time signals (temperature, specific force) explains the data about as well leaves a
      // real effect uncorrected. Such a candidate wins when it is within the weak-evidence band
      // of BIC (kWeakEvidenceBic: the data do not strongly prefer time), collinear with the
      // time one or not; among several, the lowest BIC. The notes still name both
      // and say what capture would tell them apart.
      int gave_way = -1;  // the time candidate that gave way, if any
      if (!opt_.apply_time_effects && UsesTime(cands[static_cast<size_t>(best)])) {
        const RoundCandidate& timed = cands[static_cast<size_t>(best)];
        int swap = -1;
        for (size_t c = 0; c < cands.size(); ++c) {
          const RoundCandidate& x = cands[c];
          if (!x.score.passed || UsesTime(x) || x.score.sensor != timed.score.sensor) continue;
          if (!(x.score.delta_bic - timed.score.delta_bic < kWeakEvidenceBic)) continue;
          if (swap < 0 || x.score.delta_bic < cands[static_cast<size_t>(swap)].score.delta_bic)
            swap = static_cast<int>(c);
        }
        if (swap >= 0) gave_way = best, best = swap;
      }
      const int static_best = best;
      ResolveByMoves(st, &cands, &best);
      const RoundCandidate& win = cands[static_cast<size_t>(best)];
      if (win.model_param >= 0) {  // a held parameter freed (RE-EXAMINATION)
        State next = st;
        next.free[static_cast<size_t>(win.model_param)] = true;
        absl::StatusOr<Fit> after = Refit(&next);
        if (!after.ok()) return after.status();
        diag.notes.push_back(absl::StrFormat(
            "re-examined with the effects in: %s, held before the search, is estimated now "
            "(F %.1f > %.1f, BIC %+.1f, held-out sum of squares -%.1f noise units; accelerometer "
            "held-out RMS %.3f -> %.3f mg)",
            AccelParamName(win.model_param), win.score.f, win.score.f_threshold,
            win.score.delta_bic, win.score.press_gain, RmsOf(fit.accel_heldout) / kMgPerMs2,
            RmsOf(after->accel_heldout) / kMgPerMs2));
        freed_.push_back(win.model_param);
        st = next;
        fit = *after;
        continue;
      }
      const std::vector<Term> entering = TermsOf(win, opt_.apply_time_effects);
      const bool gyro_only = win.score.sensor == Sensor::kGyro;
      State next = st;
      for (const Term& t : entering) next.terms.push_back(t);
      absl::StatusOr<Fit> after = Refit(&next, gyro_only ? &fit : nullptr);
      if (!after.ok()) return after.status();
      const bool accel = !gyro_only;
      const double before_rms = accel ? RmsOf(fit.accel_heldout) : GyroRms(fit.gyro_heldout);
      const double after_rms = accel ? RmsOf(after->accel_heldout) : GyroRms(after->gyro_heldout);
      const std::string evidence =
          Evidence(win, cands[static_cast<size_t>(static_best)], cands, tests, &diag);
      if (gave_way >= 0 && !Collinear(win, cands[static_cast<size_t>(gave_way)])) {
        // Evidence() names collinear rivals; one that gave way on the BIC band alone is named
        // here, with what would tell them apart.
        const RoundCandidate& timed = cands[static_cast<size_t>(gave_way)];
        diag.notes.push_back(absl::StrFormat(
            "ambiguous: %s entered rather than %s, which the data favour but not strongly (BIC "
            "%+.1f vs %+.1f, a difference under 6 is not strong evidence): a time term is not "
            "applied on the robot; %s",
            Describe(win), Describe(timed), win.score.delta_bic, timed.score.delta_bic,
            Separator(win.regressor, timed.regressor)));
      }
      for (size_t k = 0; k < entering.size(); ++k) {
        const size_t at = next.terms.size() - entering.size() + k;
        Effect e = ToEffect(next.terms[at]);
        e.std_error = after->term_stderr[at];
        e.error_before = before_rms;
        e.error_after = after_rms;
        e.evidence = k + 1 == entering.size() ? evidence
                                              : Cat("entered with ", Describe(win),
                                                    " (a power enters with the lower "
                                                    "ones): ",
                                                    evidence);
        out.effects.push_back(e);
      }
      st = next;
      fit = *after;
    }
    // Coefficients as finally refitted (each effect's error_before/after stays as measured when
    // it entered).
    for (size_t k = 0; k < st.terms.size(); ++k) {
      out.effects[k].coefficient = st.terms[k].coefficient;
      out.effects[k].std_error = fit.term_stderr[k];
    }
    diag.accel_heldout_after_m_s2 = RmsOf(fit.accel_heldout);
    diag.gyro_heldout_after_rad_s = GyroRms(fit.gyro_heldout);

    // The stored model carries only the applied effects: refit without the others (a drift the
    // robot will not correct is best left in the bias as its mean over the capture).
    State stored = st;
    std::erase_if(stored.terms, [](const Term& t) { return !t.applied; });
    absl::StatusOr<Fit> final_fit = stored.terms.size() == st.terms.size() ? fit : Refit(&stored);
    if (!final_fit.ok()) return final_fit.status();
    Rows(*base, *final_fit, fit, &diag);
    out.accel = stored.accel;
    out.gyro = in_.gyro;
    out.gyro.bias = in_.gyro.bias + in_.gyro.matrix.inverse() * stored.gyro_offset;
    FillAccelCovariance(stored.free, *final_fit, &out);
    out.accel_free = stored.free;
    for (size_t k = 0, s = 0; k < st.terms.size(); ++k) {
      if (!st.terms[k].applied) continue;
      out.effects[k].coefficient = stored.terms[s].coefficient;
      out.effects[k].std_error = final_fit->term_stderr[s];
      ++s;
    }
    FinalNotes(st, *final_fit, &diag);
    TemperatureBounds(st, excited, &diag);
    ExamineMoveResiduals(in_.moves, &diag);
    return out;
  }

  // DETECTION BOUNDS (core/move_effects.h DetectionBound): on each output where the search did
  // not put it, the smallest bias slope `(temperature-T)`, curvature `(temperature-T)^2` and (on
  // the accelerometer) scale slope `(temperature-T)*a` this capture would have found, at the final
  // model and the last round's threshold. Each form is tested as the search tests it: with the
  // lower powers it lacks on that output (a curvature with its slope: the bound is the one for a
  // turnover at the capture's reference temperature, the hardest place for it).
  void TemperatureBounds(const State& st, const std::array<bool, kNumSignals>& excited,
                         EffectDiagnostics* diag) {
    const auto temp = static_cast<size_t>(Signal::kTemperature);
    double lo = std::numeric_limits<double>::infinity(), hi = -lo;
    for (const SignalArray& a : signals_)
      if (std::isfinite(a[temp])) lo = std::min(lo, a[temp]), hi = std::max(hi, a[temp]);
    if (!(hi >= lo)) return;  // no temperature channel: the notes say so
    const std::string from =
        absl::StrFormat("%d poses at %.1f-%.1f degC", static_cast<int>(poses_.size()), lo, hi);
    const int tests = std::max(1, last_tests_);
    const RoundDesigns designs = DesignsAt(st);
    for (int sensor = 0; sensor < (in_.gyro_output_si ? 2 : 1); ++sensor) {
      const auto sn = static_cast<Sensor>(sensor);
      for (int axis = 0; axis < 3; ++axis) {
        std::vector<std::string> forms = {"temperature", "temperature^2"};
        if (sn == Sensor::kAccel) forms.push_back(absl::StrFormat("temperature*a%c", "xyz"[axis]));
        const Scorer& scorer = designs.For(sn, axis);
        for (const std::string& name : forms) {
          const Regressor form = ParseRegressor(name)->CentredOn(centre_);
          if (InModel(st, sn, axis, form)) continue;  // found: its coefficient says the rest
          const std::optional<std::vector<Regressor>> lower = LowerPowers(st, sn, axis, form);
          if (!lower) continue;
          std::vector<Regressor> group = *lower;
          group.push_back(form);
          const auto k = static_cast<Eigen::Index>(group.size());
          const Eigen::MatrixXd cols = CandidateColumns(designs, st, sn, axis, group);
          DetectionBound b;
          b.sensor = sn;
          b.axis = axis;
          b.regressor = form.Name();
          b.from = from;
          b.coefficient = std::numeric_limits<double>::infinity();
          const double beyond = excited[temp] ? scorer.LastBeyond(cols) : 0.0;
          const double f_star = FThreshold(opt_.family_alpha, tests,
                                           DofAfter(st, sn, axis) - (k - 1), static_cast<int>(k));
          if (beyond > 0) {
            const double lambda =
                DetectableNoncentrality(static_cast<int>(k), static_cast<double>(k) * f_star);
            b.coefficient = std::sqrt(lambda * scorer.variance()) / beyond;
          }
          diag->detection_bounds.push_back(std::move(b));
        }
      }
    }
    // One note: per sensor and kind of form, the range of the bounds over the axes.
    std::string text;
    // 0: a bias slope, 1: a curvature (temperature alone, one or two factors), 2: a scale slope.
    const auto kind_of = [](const std::string& name) {
      const std::optional<Regressor> r = ParseRegressor(name);
      if (!r) return -1;
      for (int i = 0; i < r->num_factors; ++i)
        if (r->factors[i] != static_cast<int>(Signal::kTemperature)) return 2;
      return r->num_factors - 1;
    };
    const char* const kKinds[] = {"bias slope", "curvature", "scale slope"};
    for (int sensor = 0; sensor < 2; ++sensor) {
      for (int kind = 0; kind < 3; ++kind) {
        std::vector<const DetectionBound*> same;
        for (const DetectionBound& b : diag->detection_bounds)
          if (static_cast<int>(b.sensor) == sensor && kind_of(b.regressor) == kind)
            same.push_back(&b);
        if (same.empty()) continue;
        const DetectionBound* low = same.front();
        const DetectionBound* high = same.front();
        std::string axes;
        for (const DetectionBound* b : same) {
          if (b->coefficient < low->coefficient) low = b;
          if (b->coefficient > high->coefficient) high = b;
          axes += AxisName(b->axis);
        }
        const auto sn = static_cast<Sensor>(sensor);
        const std::string lo_text = HumanValue(sn, low->regressor, low->coefficient);
        const std::string hi_text = HumanValue(sn, high->regressor, high->coefficient);
        const std::string range =
            !std::isfinite(high->coefficient)
                ? absl::StrFormat("none (%s: the temperature does not vary)", axes)
            : lo_text == hi_text ? absl::StrFormat("%s (%s)", hi_text, axes)
                                 : absl::StrFormat("%s to %s (%s)", lo_text, hi_text, axes);
        absl::StrAppendFormat(&text, "%s %s %s %s", text.empty() ? "" : ";", SensorName(sn),
                              kKinds[kind], range);
      }
    }
    if (!text.empty())
      diag->notes.push_back(
          Cat("temperature: where none was found, this capture (", from,
              ") would have found one 9 times in 10 at:", text,
              ". A smaller one may be there; a capture over a wider temperature span sees smaller "
              "ones"));
  }

 private:
  static double GyroRms(const std::vector<Eigen::Vector3d>& v) {
    double s = 0;
    for (const auto& x : v) s += x.squaredNorm();
    return v.empty() ? kNaN : std::sqrt(s / static_cast<double>(v.size()));
  }

  Eigen::Index DofAfter(const State& st, Sensor sensor, int axis) const {
    const auto n = static_cast<Eigen::Index>(poses_.size());
    Eigen::Index p = 0;
    if (sensor == Sensor::kAccel) {
      // What the poses pay for at the round's state (ScoreRound): the priors' share excluded.
      p = static_cast<Eigen::Index>(std::ceil(accel_pays_for_ - 1e-9));
    } else {
      p = 1;
      for (const Term& t : st.terms) p += t.sensor == Sensor::kGyro && t.axis == axis;
    }
    return n - p - 1;
  }

  bool InModel(const State& st, Sensor sensor, int axis, const Regressor& r) const {
    for (const Term& t : st.terms)
      if (t.sensor == sensor && t.axis == axis && t.regressor == r) return true;
    return false;
  }

  // The physical forms of temperature and time (effects.h, POLYNOMIALS): the lower powers that
  // must enter with `r` on this output (empty: none missing), or nullopt when `r` is not a
  // candidate yet (a product of temperature and time before both its main terms are in).
  std::optional<std::vector<Regressor>> LowerPowers(const State& st, Sensor sensor, int axis,
                                                    const Regressor& r) const {
    int count[kNumSignals] = {};
    for (int i = 0; i < r.num_factors; ++i) ++count[r.factors[i]];
    const int temp = static_cast<int>(Signal::kTemperature);
    const int time = static_cast<int>(Signal::kTime);
    if (count[temp] > 0 && count[time] > 0) {
      if (!InModel(st, sensor, axis, Without(r, temp)) ||
          !InModel(st, sensor, axis, Without(r, time)))
        return std::nullopt;
      return std::vector<Regressor>{};
    }
    for (int s : {temp, time}) {
      if (count[s] < 2) continue;
      const Regressor below = Without(r, s);
      if (InModel(st, sensor, axis, below)) return std::vector<Regressor>{};
      return std::vector<Regressor>{below};
    }
    return std::vector<Regressor>{};
  }

  // `r` with one factor of `signal` removed (its centre kept while a factor of it remains).
  static Regressor Without(const Regressor& r, int signal) {
    Regressor out;
    bool removed = false;
    for (int i = 0; i < r.num_factors; ++i) {
      if (!removed && r.factors[i] == signal) {
        removed = true;
        continue;
      }
      out.factors[out.num_factors++] = r.factors[i];
    }
    for (int i = 0; i < out.num_factors; ++i)
      out.centre[static_cast<size_t>(out.factors[i])] =
          r.centre[static_cast<size_t>(out.factors[i])];
    return out;
  }

  // The weighted designs candidates are scored against at a state: the accelerometer's (its
  // poses with the state's model error) and each gyroscope axis's.
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

  // Also keeps what the accelerometer's poses pay for (DofAfter).
  RoundDesigns DesignsAt(const State& st) {
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
  Eigen::MatrixXd CandidateColumns(const RoundDesigns& d, const State& st, Sensor sensor, int axis,
                                   const std::vector<Regressor>& group) const {
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

  void ScoreRound(const State& st, const std::array<bool, kNumSignals>& excited,
                  std::vector<RoundCandidate>* cands, int* absorbed, int* not_excited) {
    const RoundDesigns designs = DesignsAt(st);
    const std::vector<AccelPose>& ap = designs.accel_poses;
    const Design& ad = designs.accel;
    const auto n = static_cast<Eigen::Index>(poses_.size());
    for (const Regressor& plain : Dictionary(opt_.max_factors)) {
      const Regressor r = plain.CentredOn(centre_);
      bool ok = true;
      for (int f = 0; f < r.num_factors; ++f) ok &= excited[static_cast<size_t>(r.factors[f])];
      bool has_values = true;
      for (const SignalArray& s : signals_) has_values &= std::isfinite(r.Evaluate(s));
      if (!has_values) continue;  // a signal the capture does not have (no temperature)
      for (int sensor = 0; sensor < (in_.gyro_output_si ? 2 : 1); ++sensor) {
        for (int axis = 0; axis < 3; ++axis) {
          if (!ok) {
            ++*not_excited;
            continue;
          }
          bool exists = false;
          for (const Term& t : st.terms)
            exists |= static_cast<int>(t.sensor) == sensor && t.axis == axis && t.regressor == r;
          if (exists) continue;
          if (IsModelTerm(static_cast<Sensor>(sensor), axis, r)) {
            ++*absorbed;
            continue;
          }
          if (!MainTermModelled(st, static_cast<Sensor>(sensor), axis, r)) continue;
          const std::optional<std::vector<Regressor>> lower =
              LowerPowers(st, static_cast<Sensor>(sensor), axis, r);
          if (!lower.has_value()) continue;
          std::vector<Regressor> group = *lower;
          group.push_back(r);
          const Eigen::MatrixXd cols =
              CandidateColumns(designs, st, static_cast<Sensor>(sensor), axis, group);
          RoundCandidate c;
          c.regressor = r;
          c.lower = *lower;
          c.score.sensor = sensor == 0 ? Sensor::kAccel : Sensor::kGyro;
          c.score.axis = axis;
          c.score.regressor = r.Name();
          const Scorer& scorer = designs.For(static_cast<Sensor>(sensor), axis);
          Eigen::VectorXd coefficients;
          if (!scorer.Score(cols, &c.score, &c.perp, &coefficients)) {
            ++*absorbed;
            continue;
          }
          // The accelerometer column is d r / d c = -n x: the coefficient has the opposite sign
          // of the projection.
          if (sensor == 0) coefficients = -coefficients;
          c.score.coefficient = coefficients(coefficients.size() - 1);
          for (size_t g = 0; g < c.lower.size(); ++g)
            c.lower_coefficients.push_back(coefficients(static_cast<Eigen::Index>(g)));
          cands->push_back(std::move(c));
        }
      }
    }
    // RE-EXAMINATION (effects.h): once an effect is in, the parameters the model held.
    if (st.terms.empty()) return;
    const Eigen::MatrixXd j = MagnitudeJacobian(st.accel, ap);
    for (int p = 0; p < kAccelParams; ++p) {
      if (!in_.accel_held[static_cast<size_t>(p)] || st.free[static_cast<size_t>(p)]) continue;
      Eigen::MatrixXd col(n, 1);
      for (Eigen::Index i = 0; i < n; ++i) col(i, 0) = j(i, p) * ad.weight[static_cast<size_t>(i)];
      RoundCandidate c;
      c.model_param = p;
      c.score.sensor = Sensor::kAccel;
      c.score.axis = p % 3;
      c.score.regressor = Cat("model ", AccelParamName(p));
      Eigen::VectorXd coefficients;
      if (!designs.accel_scorer->Score(col, &c.score, &c.perp, &coefficients)) continue;
      c.score.coefficient = -c.score.coefficient;  // the Gauss-Newton step of the parameter
      cands->push_back(std::move(c));
    }
  }

  // True when `a` and `b` are one explanation to the static residual: nearly collinear beyond
  // the current model.
  static bool Collinear(const RoundCandidate& a, const RoundCandidate& b) {
    if (&a == &b || a.score.sensor != b.score.sensor) return false;
    if (a.score.sensor == Sensor::kGyro && a.score.axis != b.score.axis) return false;
    const double corr = std::abs(a.perp.dot(b.perp)) / (a.perp.norm() * b.perp.norm());
    return corr > kAmbiguousCorrelation;
  }

  // True when `b` holds `a`'s terms and more (`a` = (temperature-31.2), `b` = (temperature-31.2)
  // + (temperature-31.2)^2) on the same output.
  static bool Nested(const RoundCandidate& a, const RoundCandidate& b) {
    if (a.score.sensor != b.score.sensor || a.score.axis != b.score.axis || !a.lower.empty())
      return false;
    return std::find(b.lower.begin(), b.lower.end(), a.regressor) != b.lower.end();
  }

  // True when `a` and `b` are collinear and their BIC differ by less than `max_delta_bic`.
  static bool Ambiguous(const RoundCandidate& a, const RoundCandidate& b,
                        double max_delta_bic = kAmbiguousBic) {
    return Collinear(a, b) && std::abs(a.score.delta_bic - b.score.delta_bic) < max_delta_bic;
  }

  // True when `a` and `b` act on the same output axis through the same specific-force factors,
  // differing only in temperature or time (`temperature*ay` and `time*ay` on y, `temperature`
  // and `temperature^2`). The moves see a candidate only through the pose directions it gives;
  // such two give the same pattern over the poses up to how temperature follows time, which the
  // moves, made during the same warm-up, know no better than the static poses.
  static bool SameGeometry(const RoundCandidate& a, const RoundCandidate& b) {
    if (a.score.sensor != b.score.sensor || a.score.axis != b.score.axis) return false;
    const auto force = [](const Regressor& r) {
      std::vector<int> f;
      for (int i = 0; i < r.num_factors; ++i)
        if (r.factors[i] >= static_cast<int>(Signal::kAx) &&
            r.factors[i] <= static_cast<int>(Signal::kAz))
          f.push_back(r.factors[i]);
      return f;
    };
    return force(a.regressor) == force(b.regressor);
  }

  // One-sided paired t of the moves' squared errors: positive when `b`'s directions fit the
  // rotations between poses better than `a`'s. NaN unless both were judged.
  static double MovePairedT(const RoundCandidate& a, const RoundCandidate& b) {
    const size_t n = a.move_error_rad.size();
    if (n < 3 || b.move_error_rad.size() != n) return kNaN;
    double mean = 0, ss = 0;
    for (size_t k = 0; k < n; ++k)
      mean += (std::pow(a.move_error_rad[k], 2) - std::pow(b.move_error_rad[k], 2)) / n;
    for (size_t k = 0; k < n; ++k)
      ss += std::pow(std::pow(a.move_error_rad[k], 2) - std::pow(b.move_error_rad[k], 2) - mean, 2);
    const double sd = std::sqrt(ss / static_cast<double>(n - 1));
    return sd > 0 ? mean / (sd / std::sqrt(static_cast<double>(n))) : kNaN;
  }

  // The one-sided t quantile for `tests` comparisons over `moves` moves at the family alpha.
  double MoveTThreshold(int tests, size_t moves) const {
    if (tests < 1 || moves < 3) return std::numeric_limits<double>::infinity();
    const boost::math::students_t t(static_cast<double>(moves - 1));
    return boost::math::quantile(boost::math::complement(t, opt_.family_alpha / tests));
  }

  // The specific-force direction of every pose (unit, body frame) with the state's
  // accelerometer model and terms, as the SDK's Corrector computes it.
  std::vector<Eigen::Vector3d> Directions(const State& st) const {
    std::vector<Eigen::Vector3d> out;
    for (size_t i = 0; i < poses_.size(); ++i) {
      Eigen::Vector3d a = st.accel.Apply(poses_[i].accel.mean);
      for (const Term& t : st.terms)
        if (t.sensor == Sensor::kAccel)
          a(t.axis) -= t.coefficient * t.regressor.Evaluate(signals_[i]);
      out.push_back(a.normalized());
    }
    return out;
  }

  // The moves' judgement (effects.h, SELECTION: THE MOVES). `best` is the static choice; it
  // becomes the candidate whose directions the rotations between poses fit significantly
  // better, if any.
  // Why the moves separate what |a| - g cannot: `ax*az` on x and `ax^2` on z move |a| alike,
  // but the first tilts a pose's direction about y and the second about x, by amounts that
  // differ from pose to pose; the gyroscope, integrating the rotation from pose to pose, sees
  // which one the poses went through. Its matrix, refitted per candidate, absorbs what a
  // misalignment of the gyroscope would explain, not a quadratic pattern over the poses.
  void ResolveByMoves(const State& st, std::vector<RoundCandidate>* cands, int* best) const {
    const size_t b = static_cast<size_t>(*best);
    if (!in_.move_fit || (*cands)[b].score.sensor != Sensor::kAccel || (*cands)[b].model_param >= 0)
      return;
    std::vector<size_t> group = {b};
    std::vector<size_t> others;
    for (size_t c = 0; c < cands->size(); ++c)
      if (c != b && (*cands)[c].score.passed && (*cands)[c].score.sensor == Sensor::kAccel &&
          (*cands)[c].model_param < 0 && !SameGeometry((*cands)[b], (*cands)[c]))
        others.push_back(c);
    std::sort(others.begin(), others.end(), [&](size_t x, size_t y) {
      return (*cands)[x].score.delta_bic < (*cands)[y].score.delta_bic;
    });
    for (size_t c : others)
      if (group.size() < kMaxMoveJudged) group.push_back(c);
    if (group.size() < 2) return;
    std::vector<std::vector<double>> errors;  // per group member; kept only if all were judged
    for (size_t c : group) {
      State trial = st;
      for (const Term& t : TermsOf((*cands)[c], true)) trial.terms.push_back(t);
      AccelGaussNewton(trial.free, signals_, in_.gravity_m_s2, poses_, &trial, 8);
      const std::optional<MoveFit> f = in_.move_fit(Directions(trial));
      if (!f || f->error_rad.size() < 3) return;  // the moves say nothing: the static choice
      for (double e : f->error_rad)
        if (!std::isfinite(e)) return;
      errors.push_back(f->error_rad);
    }
    for (size_t k = 0; k < group.size(); ++k)
      (*cands)[group[k]].move_error_rad = std::move(errors[k]);
    const RoundCandidate& chosen = (*cands)[b];
    const double t_crit =
        MoveTThreshold(static_cast<int>(group.size() - 1), chosen.move_error_rad.size());
    for (size_t c : group) {
      const RoundCandidate& x = (*cands)[c];
      if (c == b || !(MovePairedT(chosen, x) > t_crit)) continue;
      if (static_cast<size_t>(*best) == b ||
          x.MoveRms() < (*cands)[static_cast<size_t>(*best)].MoveRms())
        *best = static_cast<int>(c);
    }
  }

  static void KeepTop(std::vector<RoundCandidate> cands, EffectDiagnostics* diag) {
    std::sort(cands.begin(), cands.end(), [](const RoundCandidate& a, const RoundCandidate& b) {
      return a.score.f > b.score.f;
    });
    for (size_t k = 0; k < cands.size() && k < 8; ++k) diag->top.push_back(cands[k].score);
  }

  // The entering effect's evidence, and notes on the candidates it was weighed against:
  // `static_best` is the static choice (it differs from `win` when the moves overruled it).
  std::string Evidence(const RoundCandidate& win, const RoundCandidate& static_best,
                       const std::vector<RoundCandidate>& cands, int tests,
                       EffectDiagnostics* diag) {
    const std::string win_name = Describe(win);
    const auto judged = static_cast<int>(
        std::count_if(cands.begin(), cands.end(), [](const auto& c) { return c.Judged(); }));
    const double t_crit = MoveTThreshold(judged - 1, win.move_error_rad.size());
    const auto by_moves = [&](const RoundCandidate& lost, const char* why) {
      diag->notes.push_back(absl::StrFormat(
          "resolved by the rotations between poses: %s rather than %s, %s (BIC %+.1f vs %+.1f); "
          "the gyroscope, refitted to each one's pose directions, leaves %.4f vs %.4f deg RMS "
          "after the %d moves (paired t %.1f > %.1f)",
          win_name, Describe(lost), why, win.score.delta_bic, lost.score.delta_bic,
          win.MoveRms() * kRadToDeg, lost.MoveRms() * kRadToDeg,
          static_cast<int>(win.move_error_rad.size()), MovePairedT(lost, win), t_crit));
    };
    if (&win != &static_best) by_moves(static_best, "which |a| - g preferred");
    std::string rivals;
    for (const RoundCandidate& c : cands) {
      if (&c == &win || &c == &static_best || !Ambiguous(win, c, kWeakEvidenceBic)) continue;
      // A polynomial and its own lower power are not rival explanations: the higher one is
      // tested again next round, with the lower one in.
      if (Nested(win, c) || Nested(c, win)) continue;
      // |a| - g does not tell them apart; the moves may, unless they differ in temperature or
      // time only.
      const double t = SameGeometry(win, c) ? kNaN : MovePairedT(c, win);
      if (t > t_crit) {
        by_moves(c, "which explains |a| - g as well");
        continue;
      }
      const std::string name = Describe(c);
      rivals += Cat(rivals.empty() ? "" : ", ", name);
      const double gap = std::abs(win.score.delta_bic - c.score.delta_bic);
      const std::string favoured = win.score.delta_bic <= c.score.delta_bic ? win_name : name;
      diag->notes.push_back(Cat(
          "ambiguous: ", win_name,
          gap < kAmbiguousBic ? Cat(" explains the residual about as well as ", name)
                              : Cat(" and ", name, " both explain the residual; the data favour ",
                                    favoured, " but not strongly"),
          absl::StrFormat(" (BIC %+.1f vs %+.1f", win.score.delta_bic, c.score.delta_bic),
          gap < kAmbiguousBic ? "); " : ", a difference under 6 is not strong evidence); ",
          std::isfinite(t)
              ? absl::StrFormat("the rotations between poses do not decide between them either "
                                "(%.4f vs %.4f deg RMS after the moves, paired t %.1f against "
                                "%.1f); ",
                                win.MoveRms() * kRadToDeg, c.MoveRms() * kRadToDeg, t, t_crit)
              : "",
          Separator(win.regressor, c.regressor)));
    }
    return absl::StrFormat(
        "F %.1f > %.1f (F(1,dof) at %.2g/%d candidates, Bonferroni); BIC %+.1f; held-out sum of "
        "squares -%.1f (noise units)%s%s",
        win.score.f, win.score.f_threshold, opt_.family_alpha, tests, win.score.delta_bic,
        win.score.press_gain,
        &win != &static_best ? "; chosen over the static choice by the rotations between poses"
                             : "",
        rivals.empty() ? "" : Cat("; ambiguous with ", rivals));
  }

  void NoiseFloors(EffectDiagnostics* diag) const {
    std::vector<AccelPose> bare = AccelPoses(poses_);
    for (AccelPose& p : bare) p.model_sigma_m_s2 = 0, p.offset_m_s2.setZero();
    diag->accel_noise_floor_m_s2 = RmsOf(MagnitudeSigmas(in_.accel, bare));
    double s = 0;
    for (const auto& g : gyro_sigma_) s += g.squaredNorm();
    diag->gyro_noise_floor_rad_s = std::sqrt(s / static_cast<double>(gyro_sigma_.size()));
  }

  void Rows(const Fit& before, const Fit& after, const Fit& all, EffectDiagnostics* diag) const {
    for (size_t i = 0; i < poses_.size(); ++i) {
      EffectPoseRow row;
      row.pose_index = poses_[i].pose_index;
      row.signals = signals_[i];
      row.accel_before_m_s2 = before.accel_residual[i];
      row.accel_after_m_s2 = after.accel_residual[i];
      row.gyro_before_rad_s = before.gyro_residual[i];
      row.gyro_after_rad_s = after.gyro_residual[i];
      row.accel_all_m_s2 = all.accel_residual[i];
      row.gyro_all_rad_s = all.gyro_residual[i];
      diag->rows.push_back(row);
    }
  }

  static void FillAccelCovariance(const AccelMask& free, const Fit& fit, EffectSearchResult* out) {
    std::vector<int> idx;
    for (int c = 0; c < kAccelParams; ++c)
      if (free[static_cast<size_t>(c)]) idx.push_back(c);
    for (size_t a = 0; a < idx.size(); ++a)
      for (size_t b = 0; b < idx.size(); ++b)
        out->accel_covariance(idx[a], idx[b]) =
            fit.accel_cov(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b));
  }

  void FinalNotes(const State& st, const Fit& fit, EffectDiagnostics* diag) const {
    bool has_temp = true;
    for (const EffectPose& p : poses_) has_temp &= std::isfinite(p.temp_c);
    for (const Term& t : st.terms) {
      if (UsesSignal(t.regressor, Signal::kTime)) {
        diag->notes.push_back(
            Cat(TermName(t), ": a dependence on time since the capture started",
                t.applied ? " (applied: the user opted in)"
                          : " is reported, not applied (opt in to apply it at run time)",
                has_temp ? ""
                         : "; the capture has no temperature channel, so a warm-up would look the "
                           "same: record temperature to tell them apart"));
      }
    }
    const double accel_rms = RmsOf(fit.accel_residual);
    const auto unpredictable = std::count_if(fit.accel_heldout.begin(), fit.accel_heldout.end(),
                                             [](double v) { return !std::isfinite(v); });
    if (unpredictable > 0) {
      diag->notes.push_back(absl::StrFormat(
          "%d of %d poses are each the only one to fix part of the accelerometer model (a face "
          "placed once): the others cannot predict them, so the held-out figures leave them out%s",
          static_cast<int>(unpredictable), static_cast<int>(fit.accel_heldout.size()),
          unpredictable == static_cast<long>(fit.accel_heldout.size())
              ? "; none is left, so accelerometer effects could not be judged held out. Place "
                "each face twice (the six-face protocol) or add poses between the faces"
              : ""));
    }
    diag->notes.push_back(absl::StrFormat(
        "remaining accelerometer residual %.3f mg RMS (held out %.3f mg) against a noise floor "
        "of %.3f mg",
        accel_rms / kStandardGravity * 1e3, RmsOf(fit.accel_heldout) / kStandardGravity * 1e3,
        diag->accel_noise_floor_m_s2 / kStandardGravity * 1e3));
    diag->notes.push_back(absl::StrFormat(
        "remaining gyroscope static residual %.4f deg/s RMS (held out %.4f deg/s) against a "
        "noise floor of %.4f deg/s",
        GyroRms(fit.gyro_residual) * kRadToDeg, GyroRms(fit.gyro_heldout) * kRadToDeg,
        diag->gyro_noise_floor_rad_s * kRadToDeg));
    if (!has_temp) {
      diag->notes.push_back("no temperature channel: temperature effects could not be tested");
    }
    if (!in_.gyro_output_si) {
      diag->notes.push_back(
          "gyroscope effects not searched: its output stays in raw counts (scale not calibrated)");
    }
    if (diag->not_excited > 0) {
      diag->notes.push_back(absl::StrFormat(
          "%d candidates not testable on static poses: their signals (rates) do not vary at "
          "rest",
          diag->not_excited));
    }
  }

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

}  // namespace

absl::StatusOr<EffectSearchResult> FindEffects(const EffectSearchInput& input,
                                               const EffectSearchOptions& options) {
  if (!options.enabled) return absl::InvalidArgumentError("effect search is disabled");
  // The parameters the poses pay for: a term its prior decides counts for nothing.
  std::vector<AccelPose> poses;
  for (const EffectPose& p : input.poses) poses.push_back(p.accel);
  const int n_free = static_cast<int>(std::ceil(
      EffectiveParameters(input.accel, poses, input.accel_free, input.accel_priors) - 1e-9));
  if (static_cast<int>(input.poses.size()) < n_free + 3) {
    EffectSearchResult out;
    out.accel = input.accel;
    out.gyro = input.gyro;
    out.diagnostics.notes.push_back(absl::StrFormat(
        "effects not searched: %d poses leave too few degrees of freedom beyond the %d model "
        "parameters they determine",
        static_cast<int>(input.poses.size()), n_free));
    return out;
  }
  Search search(input, options);
  return search.Run();
}

namespace {

// A coefficient's unit as an engineer reads it, and the factor from SI to it.
struct HumanUnit {
  double factor = 1;
  std::string unit;
};

HumanUnit HumanUnitOf(Sensor sensor, const std::string& regressor) {
  // Numerator: mg or deg/s. Each factor of the regressor: degC, s, g or deg/s. A factor of the
  // sensor's own kind turns the ratio into ppm (mg/g = 1000 ppm, (deg/s)/(deg/s) = 1e6 ppm).
  const std::optional<Regressor> r = ParseRegressor(regressor);
  const bool accel = sensor == Sensor::kAccel;
  double factor = accel ? 1e3 / kStandardGravity : kRadToDeg;
  std::string numerator = accel ? "mg" : "deg/s";
  std::vector<std::string> units;
  bool ppm = false;
  if (r) {
    for (int i = 0; i < r->num_factors; ++i) {
      const auto s = static_cast<Signal>(r->factors[i]);
      const bool is_accel = s >= Signal::kAx && s <= Signal::kAz;
      const bool is_rate = s >= Signal::kGx;
      if (!ppm && ((accel && is_accel) || (!accel && is_rate))) {
        // mg per g or (deg/s) per (deg/s): relative, in ppm.
        factor = 1e6;
        numerator = "ppm";
        ppm = true;
        continue;
      }
      if (s == Signal::kTemperature) units.push_back("degC");
      if (s == Signal::kTime) factor *= 3600, units.push_back("h");
      if (is_accel) factor *= kStandardGravity, units.push_back("g");
      if (is_rate) factor /= kRadToDeg, units.push_back("(deg/s)");
    }
  }
  std::string unit = numerator;
  for (size_t i = 0; i < units.size(); ++i) {
    size_t run = 1;
    while (i + run < units.size() && units[i + run] == units[i]) ++run;
    unit += "/" + units[i] + (run > 1 ? "^2" : "");
    i += run - 1;
  }
  if (units.empty() && !ppm) unit += " per regressor unit";
  return {factor, unit};
}

}  // namespace

std::string HumanCoefficient(const Effect& e) {
  const HumanUnit u = HumanUnitOf(e.sensor, e.regressor);
  return absl::StrFormat("%.4g +- %.2g %s", e.coefficient * u.factor, e.std_error * u.factor,
                         u.unit);
}

std::string HumanValue(Sensor sensor, const std::string& regressor, double value) {
  const HumanUnit u = HumanUnitOf(sensor, regressor);
  return absl::StrFormat("%.2g %s", value * u.factor, u.unit);
}

// The rotation residuals: regress the gravity-direction error after each move on each of its
// signals (with an intercept); a slope significant at 1% over the signals (Bonferroni) is
// reported with its size.
void ExamineMoveResiduals(const std::vector<EffectMoveResidual>& all, EffectDiagnostics* diag) {
  constexpr std::string_view kNote = "rotation residuals: ";
  // A move whose gravity direction turned less than this is blind to the gyroscope's error.
  constexpr double kBlindTiltRad = 5.0 / kRadToDeg;
  std::vector<MoveTrend>& trends = diag->move_trends;
  trends.clear();
  std::erase_if(diag->notes, [&](const std::string& note) { return note.starts_with(kNote); });
  std::vector<EffectMoveResidual> m;
  for (const EffectMoveResidual& r : all)
    if (!(r.tilt_rad < kBlindTiltRad)) m.push_back(r);
  const int blind = static_cast<int>(all.size() - m.size());
  const std::string left_out =
      blind == 0 ? ""
                 : absl::StrFormat(
                       "; %d that turned about the vertical left out: gravity stays "
                       "where it was whatever the gyroscope reads",
                       blind);
  if (m.size() < 6) return;
  struct MoveSignal {
    const char* name;
    const char* unit;
    double scale;  // signal unit per reported unit
    double (*get)(const EffectMoveResidual&);
  };
  const MoveSignal signals[] = {
      {"the rotation angle", "per 100 deg", 100 / kRadToDeg,
       [](const EffectMoveResidual& r) { return r.rotation_rad; }},
      {"time", "per minute", 60, [](const EffectMoveResidual& r) { return r.time_s; }},
      {"temperature", "per degC", 1, [](const EffectMoveResidual& r) { return r.temp_c; }},
  };
  int tested = 0;
  std::vector<std::string> found;
  const auto n = static_cast<Eigen::Index>(m.size());
  for (const MoveSignal& sig : signals) {
    Eigen::MatrixXd x(n, 2);
    Eigen::VectorXd y(n);
    bool finite = true;
    for (Eigen::Index i = 0; i < n; ++i) {
      x(i, 0) = 1;
      x(i, 1) = sig.get(m[static_cast<size_t>(i)]);
      y(i) = m[static_cast<size_t>(i)].error_rad;
      finite &= std::isfinite(x(i, 1));
    }
    if (!finite || (x.col(1).array() - x.col(1).mean()).matrix().norm() <= 0) continue;
    ++tested;
    const Eigen::VectorXd b = x.colPivHouseholderQr().solve(y);
    const double rss1 = (y - x * b).squaredNorm();
    const double rss0 = (y.array() - y.mean()).matrix().squaredNorm();
    const double dof = static_cast<double>(n - 2);
    const double f = (rss0 - rss1) / std::max(1e-300, rss1 / dof);
    // The slope's standard error: sqrt(s^2 / Sxx), s^2 the residual variance about the line.
    const double sxx = (x.col(1).array() - x.col(1).mean()).matrix().squaredNorm();
    MoveTrend t;
    t.signal = sig.name;
    t.unit = Cat("deg ", sig.unit);
    t.slope_deg = b(1) * sig.scale * kRadToDeg;
    t.slope_std_error_deg = std::sqrt(rss1 / dof / sxx) * sig.scale * kRadToDeg;
    t.f = f;
    trends.push_back(std::move(t));
  }
  const auto dof = static_cast<Eigen::Index>(n - 2);
  for (MoveTrend& r : trends) {
    r.f_threshold = FThreshold(0.01, tested, dof);
    r.significant = r.f > r.f_threshold;
    if (r.significant) {
      found.push_back(absl::StrFormat("%s (%+.3f +- %.3f %s, F %.1f)", r.signal, r.slope_deg,
                                      r.slope_std_error_deg, r.unit, r.f));
    }
  }
  double ss = 0;
  for (const auto& r : m) ss += r.error_rad * r.error_rad;
  const double rms_deg = std::sqrt(ss / static_cast<double>(m.size())) * kRadToDeg;
  if (found.empty()) {
    diag->notes.push_back(
        Cat(kNote, absl::StrFormat("the gravity-direction error after the %d moves (%.3f deg "
                                   "RMS%s) shows no trend with the rotation angle, time or "
                                   "temperature",
                                   static_cast<int>(m.size()), rms_deg, left_out)));
  } else {
    std::string list;
    for (const auto& f : found) list += (list.empty() ? "" : "; ") + f;
    diag->notes.push_back(Cat(
        kNote, absl::StrFormat("the gravity-direction error after the %d moves (%.3f deg RMS%s) "
                               "grows with %s: a rate-dependent gyroscope effect (scale "
                               "nonlinearity, or a drift during moves) that static poses cannot "
                               "test; moves of different sizes and speeds would locate it",
                               static_cast<int>(m.size()), rms_deg, left_out, list)));
  }
}

}  // namespace imucal::core
