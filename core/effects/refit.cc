// Stage "refit" of the effect search (search.h): the model refitted with the working state's
// terms. The accelerometer: Ceres over the free model parameters and every accelerometer effect's
// coefficient, with the accelerometer stage's priors (the problem core/accel_solver.h
// SolveAccelProblem sets up for the accelerometer solver too), then the sandwich covariance and
// the exact leave-one-pose-out refits. The gyroscope: its static rate is linear in the offset and
// the coefficients, an exact weighted least squares per axis.
#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include "Eigen/Dense"
#include "ceres/ceres.h"
#include "core/accel_problem.h"
#include "core/effects/search.h"
#include "core/robust_covariance.h"

namespace imucal::core::effects {
namespace {

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

}  // namespace

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

namespace {

// The covariance over [free | coefficients] of the joint fit's design at its solution.
Eigen::MatrixXd JointCovariance(const Design& d) {
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
  return JointCovariance(AccelDesign(*st, AccelPoses(poses), free, signals, g));
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

}  // namespace

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

absl::StatusOr<Fit> Search::Refit(State* st, const Fit* previous) {
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

absl::Status Search::RefitAccel(State* st, Fit* out) {
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

void Search::RefitGyro(State* st, Fit* out) const {
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

double Search::GyroTau(int j, const std::vector<const Term*>& terms) const {
  const GyroAxisFit g0 = FitGyroAxis(j, rates_, gyro_sigma_, 0.0, terms, signals_);
  std::vector<double> r, s;
  for (size_t i = 0; i < poses_.size(); ++i) {
    r.push_back(g0.residual(static_cast<Eigen::Index>(i)));
    s.push_back(gyro_sigma_[i](j));
  }
  return CommonModelSigma(r, s, static_cast<double>(poses_.size() - 1 - terms.size()));
}

}  // namespace imucal::core::effects
