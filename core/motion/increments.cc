#include "core/motion/increments.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "Eigen/Geometry"
#include "core/motion/evaluate.h"
#include "core/so3.h"

namespace imucal::core::motion {
namespace {

Eigen::Vector3d Phi(const MotionRecording& r, const std::vector<Eigen::Vector3d>& w, int j) {
  return 0.5 * (r.t_s[j + 1] - r.t_s[j]) * (w[j] + w[j + 1]);
}

}  // namespace

void LinearSystem::Add(const LinearSystem& o) {
  if (n.size() == 0) {
    *this = o;
    return;
  }
  n += o.n;
  g += o.g;
  c += o.c;
  windows += o.windows;
  block_g.insert(block_g.end(), o.block_g.begin(), o.block_g.end());
}

FitRecording PrepareFit(const MotionRecording& r, const AlignedReference& reference,
                        const std::vector<int>& horizons, double block_s) {
  FitRecording fit;
  fit.recording = &r;
  fit.reference = reference;
  const double step = MedianStepS(r.t_s);
  fit.rate_hz = step > 0 ? 1.0 / step : 0.0;
  const int n = static_cast<int>(r.t_s.size());
  fit.segment_start.assign(n, 0);
  std::vector<int> gaps_before(n, 0);  // IMU gaps among the steps before k
  for (int k = 1; k < n; ++k) {
    const bool gap = r.t_s[k] - r.t_s[k - 1] > kImuGapFactor * step;
    fit.segment_start[k] = gap ? k : fit.segment_start[k - 1];
    gaps_before[k] = gaps_before[k - 1] + (gap ? 1 : 0);
  }
  const double t0 = n > 0 ? r.t_s.front() : 0.0;
  for (size_t h = 0; h < horizons.size(); ++h) {
    const int steps = horizons[h];
    const int stride = std::max(1, steps / 2);
    for (int s = 0; s + steps < n; s += stride) {
      if (!reference.valid[s] || !reference.valid[s + steps]) continue;
      if (gaps_before[s + steps] != gaps_before[s]) continue;
      const int block = static_cast<int>((r.t_s[s] - t0) / block_s);
      fit.windows.push_back({s, steps, static_cast<int>(h), block});
      fit.blocks = std::max(fit.blocks, block + 1);
    }
  }
  return fit;
}

std::vector<Eigen::Vector3d> WindowResiduals(const FitRecording& fit,
                                             const std::vector<Eigen::Vector3d>& w) {
  const MotionRecording& r = *fit.recording;
  const std::vector<Eigen::Quaterniond>& q = fit.reference.q_world_imu;
  std::vector<Eigen::Quaterniond> exp(r.t_s.size() - 1);
  for (size_t j = 0; j + 1 < r.t_s.size(); ++j)
    exp[j] = ExpQuaternion(Phi(r, w, static_cast<int>(j)));
  std::vector<Eigen::Vector3d> out;
  out.reserve(fit.windows.size());
  for (const Window& win : fit.windows) {
    Eigen::Quaterniond pred = Eigen::Quaterniond::Identity();
    for (int j = win.start; j < win.start + win.steps; ++j) pred = pred * exp[j];
    const Eigen::Quaterniond ref = q[win.start].conjugate() * q[win.start + win.steps];
    out.push_back(LogQuaternion((pred.normalized().conjugate() * ref).normalized()));
  }
  return out;
}

LinearSystem Accumulate(const FitRecording& fit, const std::vector<Eigen::Vector3d>& w,
                        const std::vector<Eigen::Vector3d>& residuals,
                        const std::vector<double>& weights, int parameters,
                        const JacobianTimes& jacobian) {
  const MotionRecording& r = *fit.recording;
  const size_t steps = r.t_s.size() - 1;
  std::vector<Eigen::Matrix3d> rot(steps), jr(steps);
  for (size_t j = 0; j < steps; ++j) {
    rot[j] = ExpAndRightJacobian(Phi(r, w, static_cast<int>(j)), &jr[j]);
  }
  LinearSystem sys;
  sys.n = Eigen::MatrixXd::Zero(parameters, parameters);
  sys.g = Eigen::VectorXd::Zero(parameters);
  sys.block_g.assign(fit.blocks, Eigen::VectorXd::Zero(parameters));
  Eigen::MatrixXd a(3, parameters);
  std::vector<Eigen::Matrix3d> coef;
  for (size_t i = 0; i < fit.windows.size(); ++i) {
    if (weights[i] <= 0.0) continue;
    const Window& win = fit.windows[i];
    coef.assign(win.steps + 1, Eigen::Matrix3d::Zero());
    Eigen::Matrix3d m = Eigen::Matrix3d::Identity();  // the steps after j
    for (int j = win.steps - 1; j >= 0; --j) {
      const int step = win.start + j;
      const Eigen::Matrix3d d = (0.5 * (r.t_s[step + 1] - r.t_s[step])) * m.transpose() * jr[step];
      coef[j] += d;
      coef[j + 1] += d;
      m = rot[step] * m;
    }
    a.setZero();
    for (int j = 0; j <= win.steps; ++j) jacobian(win.start + j, coef[j], &a);
    const double wt = weights[i];
    sys.n.noalias() += wt * a.transpose() * a;
    const Eigen::VectorXd ga = wt * a.transpose() * residuals[i];
    sys.g += ga;
    sys.block_g[win.block] += ga;
    sys.c += wt * residuals[i].squaredNorm();
    ++sys.windows;
  }
  return sys;
}

}  // namespace imucal::core::motion
