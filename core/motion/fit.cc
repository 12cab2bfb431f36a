#include "core/motion/fit.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "Eigen/Dense"
#include "absl/strings/str_format.h"
#include "core/motion/evaluate.h"
#include "util/parallel.h"

namespace imucal::core::motion {
namespace {

constexpr int kCoreParameters = 25;  // C 9, b 3, G 9, delay 1, odd 3
constexpr int kStaticParameters = 21;
// The median of |r| for a 3-D Gaussian residual of per-axis sigma is 1.538 sigma.
constexpr double kMedianToSigma3d = 1.0 / 1.538;

using Vectors = std::vector<Eigen::Vector3d>;

// The per-sample quantities a stage linearises about.
struct SampleState {
  Vectors rate, w_s, accel;
};

SampleState StateOf(const FitRecording& f, const ParamSet& params) {
  SampleState s;
  StaticOutputs(*f.recording, params, &s.w_s, &s.accel);
  s.rate = CorrectedRates(*f.recording, params);
  return s;
}

// d w_s(k) / d (C, b, G): 3 x 21.
Eigen::Matrix<double, 3, 21> StaticJacobian(const FitRecording& f, const ParamSet& p,
                                            const SampleState& s, int k) {
  Eigen::Matrix<double, 3, 21> j = Eigen::Matrix<double, 3, 21>::Zero();
  const Eigen::Vector3d u = f.recording->gyro_rad_s[k] - p.gyro.bias;
  for (int i = 0; i < 3; ++i) {
    j.block<1, 3>(i, 3 * i) = u.transpose();
    j.block<1, 3>(i, 12 + 3 * i) = -s.accel[k].transpose();
  }
  j.block<3, 3>(0, 9) = -p.gyro.matrix;
  return j;
}

// d w(k) / d (C, b, G, delay, odd): 3 x 25, through the delay and the odd term.
Eigen::Matrix<double, 3, 25> CoreJacobian(const FitRecording& f, const ParamSet& p,
                                          const SampleState& s, int k) {
  Eigen::Matrix<double, 3, 25> j = Eigen::Matrix<double, 3, 25>::Zero();
  const DynamicGyro& b = *p.dynamic_gyro;
  const int prev = std::max(k - 1, f.segment_start[k]);
  const double rho = b.delay_s * b.rate_hz;
  j.leftCols<21>() = (1.0 + rho) * StaticJacobian(f, p, s, k);
  if (prev != k) j.leftCols<21>() -= rho * StaticJacobian(f, p, s, prev);
  const Eigen::Vector3d diff = s.w_s[k] - s.w_s[prev];
  j.col(21) = b.rate_hz * diff;
  const Eigen::Vector3d v0 = s.w_s[k] + rho * diff;
  for (int i = 0; i < 3; ++i) {
    j.row(i) *= 1.0 + 2.0 * b.odd_rate(i) * std::abs(v0(i));
    j(i, 22 + i) = v0(i) * std::abs(v0(i));
  }
  return j;
}

// Huber weights, every horizon alike (fit.h).
std::vector<std::vector<double>> RobustWeights(const std::vector<const FitRecording*>& fits,
                                               const std::vector<Vectors>& residuals,
                                               double huber_k) {
  int horizons = 0;
  for (const FitRecording* f : fits) {
    for (const Window& w : f->windows) horizons = std::max(horizons, w.horizon + 1);
  }
  std::vector<std::vector<double>> norms(horizons);
  for (size_t i = 0; i < fits.size(); ++i) {
    for (size_t w = 0; w < residuals[i].size(); ++w) {
      norms[fits[i]->windows[w].horizon].push_back(residuals[i][w].norm());
    }
  }
  std::vector<double> sigma(horizons, 1.0), count(horizons, 1.0);
  for (int h = 0; h < horizons; ++h) {
    if (norms[h].empty()) continue;
    std::vector<double> v = norms[h];
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    sigma[h] = std::max(1e-12, v[v.size() / 2] * kMedianToSigma3d);
    count[h] = static_cast<double>(v.size());
  }
  std::vector<std::vector<double>> weights(fits.size());
  for (size_t i = 0; i < fits.size(); ++i) {
    for (size_t w = 0; w < residuals[i].size(); ++w) {
      const int h = fits[i]->windows[w].horizon;
      const double e = residuals[i][w].norm() / sigma[h];
      const double huber = e <= huber_k ? 1.0 : huber_k / e;
      weights[i].push_back(huber / (sigma[h] * sigma[h] * count[h]));
    }
  }
  return weights;
}

// One linearisation of every recording: their systems, in order (ParallelFor, deterministic).
std::vector<LinearSystem> Linearise(
    const std::vector<const FitRecording*>& fits, const ParamSet& params, int parameters,
    double huber_k, int threads,
    const std::function<JacobianTimes(size_t, const SampleState&)>& jacobian_of) {
  std::vector<SampleState> states(fits.size());
  std::vector<Vectors> residuals(fits.size());
  ParallelFor(fits.size(), threads, [&](size_t i) {
    states[i] = StateOf(*fits[i], params);
    residuals[i] = WindowResiduals(*fits[i], states[i].rate);
  });
  const auto weights = RobustWeights(fits, residuals, huber_k);
  std::vector<LinearSystem> systems(fits.size());
  ParallelFor(fits.size(), threads, [&](size_t i) {
    systems[i] = Accumulate(*fits[i], states[i].rate, residuals[i], weights[i], parameters,
                            jacobian_of(i, states[i]));
  });
  return systems;
}

LinearSystem Total(const std::vector<LinearSystem>& systems) {
  LinearSystem total;
  for (const LinearSystem& s : systems) total.Add(s);
  return total;
}

// The clustered (sandwich) covariance of the solution of `total`'s first `active` parameters.
Eigen::MatrixXd ClusteredCovariance(const LinearSystem& total, int active) {
  const Eigen::MatrixXd n = total.n.topLeftCorner(active, active);
  const Eigen::MatrixXd n_inv = n.ldlt().solve(Eigen::MatrixXd::Identity(active, active));
  Eigen::MatrixXd meat = Eigen::MatrixXd::Zero(active, active);
  Eigen::VectorXd mean = Eigen::VectorXd::Zero(active);
  const double blocks = static_cast<double>(total.block_g.size());
  for (const Eigen::VectorXd& g : total.block_g) mean += g.head(active) / blocks;
  for (const Eigen::VectorXd& g : total.block_g) {
    const Eigen::VectorXd d = g.head(active) - mean;
    meat += d * d.transpose();
  }
  if (blocks > 1) meat *= blocks / (blocks - 1.0);
  return n_inv * meat * n_inv;
}

void ApplyCoreStep(const Eigen::VectorXd& d, ParamSet* p) {
  for (int i = 0; i < 3; ++i) {
    for (int c = 0; c < 3; ++c) {
      p->gyro.matrix(i, c) += d(3 * i + c);
      p->gyro.accel_coupling(i, c) += d(12 + 3 * i + c);
    }
  }
  p->gyro.bias += d.segment<3>(9);
  if (d.size() > kStaticParameters && p->dynamic_gyro) {
    p->dynamic_gyro->delay_s += d(21);
    p->dynamic_gyro->odd_rate += d.segment<3>(22);
  }
}

// Stages 1 and 2: Gauss-Newton on the first `active` core parameters.
ModelFit FitCore(const std::vector<const FitRecording*>& fits, ModelFit fit, int active,
                 const FitOptions& options) {
  LinearSystem total;
  for (int it = 0; it < options.iterations; ++it) {
    const ParamSet p = fit.params;
    const auto systems = Linearise(
        fits, p, active, options.huber_k, options.threads, [&](size_t i, const SampleState& s) {
          return JacobianTimes(
              [&, i, s_ptr = &s](int k, const Eigen::Matrix3d& c, Eigen::MatrixXd* a) {
                if (active == kStaticParameters) {
                  a->noalias() += c * StaticJacobian(*fits[i], p, *s_ptr, k);
                } else {
                  a->noalias() += c * CoreJacobian(*fits[i], p, *s_ptr, k);
                }
              });
        });
    total = Total(systems);
    Eigen::MatrixXd n = total.n;
    n.diagonal() *= 1.0 + 1e-10;
    ApplyCoreStep(n.ldlt().solve(total.g), &fit.params);
  }
  const Eigen::MatrixXd cov = ClusteredCovariance(total, active);
  fit.std_errors = Eigen::VectorXd::Constant(kCoreParameters, std::nan(""));
  fit.std_errors.head(active) = cov.diagonal().cwiseMax(0.0).cwiseSqrt();
  return fit;
}

JacobianTimes FilterJacobian(const FitRecording& f, const SampleState& s, int taps, int dilation) {
  return [&f, &s, taps, dilation](int k, const Eigen::Matrix3d& c, Eigen::MatrixXd* a) {
    for (int l = 0; l < taps; ++l) {
      const int idx = std::max(k - l * dilation, f.segment_start[k]);
      for (int i = 0; i < 3; ++i) {
        for (int ch = 0; ch < 6; ++ch) {
          const double x = ch < 3 ? s.w_s[idx](ch) : s.accel[idx](ch - 3);
          a->col(i * 6 * taps + 6 * l + ch) += x * c.col(i);
        }
      }
    }
  };
}

// The ridge by cross-validation grouped by recording: the held-out weighted increment cost of
// each lambda (0 = no filter: the cost with the weights at zero). Returns lambda, or 0 when no
// filter does better than none on held-out recordings.
double RidgeByCrossValidation(const std::vector<LinearSystem>& systems,
                              const std::vector<double>& grid, std::vector<std::string>* notes) {
  const LinearSystem total = Total(systems);
  double none = 0.0;
  for (const LinearSystem& s : systems) none += s.c;
  double best_cost = none, best_lambda = 0.0;
  std::string costs;
  for (double lambda : grid) {
    double cost = 0.0;
    for (const LinearSystem& held : systems) {
      Eigen::MatrixXd n = total.n - held.n;
      const Eigen::VectorXd g = total.g - held.g;
      n.diagonal() *= 1.0 + lambda;
      const Eigen::VectorXd theta = n.ldlt().solve(g);
      cost += theta.dot(held.n * theta) - 2.0 * theta.dot(held.g) + held.c;
    }
    costs += absl::StrFormat(" %g:%.4f", lambda, cost / none);
    if (cost < best_cost) best_cost = cost, best_lambda = lambda;
  }
  notes->push_back(absl::StrFormat(
      "filter ridge by leave-one-recording-out (held-out cost relative to no filter):%s -> %s",
      costs, best_lambda > 0 ? absl::StrFormat("%g", best_lambda) : "no filter"));
  return best_lambda;
}

// Stage 3: the filter over the fixed core model.
void FitFilter(const std::vector<const FitRecording*>& fits, const FitOptions& options,
               ModelFit* fit) {
  DynamicGyro& block = *fit->params.dynamic_gyro;
  const int parameters = 18 * options.taps;
  block.taps = options.taps;
  block.dilation = options.dilation;
  block.weights.assign(parameters, 0.0);
  double lambda = 0.0;
  for (int it = 0; it < 2; ++it) {
    const auto systems =
        Linearise(fits, fit->params, parameters, options.huber_k, options.threads,
                  [&](size_t i, const SampleState& s) {
                    return FilterJacobian(*fits[i], s, options.taps, options.dilation);
                  });
    if (it == 0) {
      lambda =
          fits.size() >= 2 ? RidgeByCrossValidation(systems, options.ridge_grid, &fit->notes) : 0.0;
      if (fits.size() < 2) fit->notes.push_back("no filter: cross-validation needs 2 recordings");
      if (lambda == 0.0) break;
    }
    const LinearSystem total = Total(systems);
    Eigen::MatrixXd n = total.n;
    const Eigen::VectorXd d = lambda * total.n.diagonal();
    n.diagonal() += d;
    const Eigen::Map<Eigen::VectorXd> theta(block.weights.data(), parameters);
    const Eigen::VectorXd step = n.ldlt().solve(total.g - d.cwiseProduct(theta));
    for (int p = 0; p < parameters; ++p) block.weights[p] += step(p);
  }
  if (lambda == 0.0) {
    block.taps = 0;
    block.dilation = 1;
    block.weights.clear();
  }
  block.ridge_lambda = lambda;
}

}  // namespace

ModelFit FitDynamic(const std::vector<const FitRecording*>& fits, const ModelFit& stage1,
                    const FitOptions& options) {
  ModelFit fit = stage1;
  DynamicGyro block;
  std::vector<double> rates;
  for (const FitRecording* f : fits) rates.push_back(f->rate_hz);
  std::nth_element(rates.begin(), rates.begin() + rates.size() / 2, rates.end());
  block.rate_hz = rates[rates.size() / 2];
  block.envelope.max_abs_rate_rad_s.setConstant(std::numeric_limits<double>::infinity());
  block.envelope.max_abs_accel_m_s2.setConstant(std::numeric_limits<double>::infinity());
  fit.params.dynamic_gyro = block;
  fit = FitCore(fits, fit, kCoreParameters, options);
  fit.params.dynamic_gyro->delay_std_error_s = fit.std_errors(21);
  fit.params.dynamic_gyro->odd_rate_std_error = fit.std_errors.segment<3>(22);
  if (options.filter) FitFilter(fits, options, &fit);
  return fit;
}

ModelFit FitStatic(const std::vector<const FitRecording*>& fits, const ParamSet& start,
                   const FitOptions& options) {
  ModelFit fit;
  fit.params = start;
  fit.params.dynamic_gyro.reset();
  fit = FitCore(fits, fit, kStaticParameters, options);
  fit.params.gyro_calibrated = true;
  return fit;
}

}  // namespace imucal::core::motion
