#include "core/motion/align.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>
#include <vector>

#include "Eigen/Dense"
#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/so3.h"
#include "util/units.h"

namespace imucal::core::motion {
namespace {

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// The reference's rate is taken over intervals of about this (s): over a single interval of a
// 120 Hz motion capture its orientation noise divided by 8 ms swamps the rate.
constexpr double kRateIntervalS = 0.05;

// One reference interval's mean rate, in the reference body frame, and its ends.
struct RefRate {
  double t_s;  // mid-time, reference clock
  double t0_s, t1_s;
  Eigen::Vector3d w_rad_s;
};

std::vector<RefRate> ReferenceRates(const MotionRecording& r, double gap_s, double step_s) {
  const size_t m = std::max<size_t>(1, static_cast<size_t>(std::lround(kRateIntervalS / step_s)));
  std::vector<RefRate> rates;
  for (size_t j = 0; j + m < r.ref_t_s.size(); j += m) {
    bool gap = false;
    for (size_t i = j; i < j + m; ++i) gap |= r.ref_t_s[i + 1] - r.ref_t_s[i] > gap_s;
    if (gap) continue;
    const double dt = r.ref_t_s[j + m] - r.ref_t_s[j];
    const Eigen::Vector3d phi = LogQuaternion(r.q_world_ref[j].conjugate() * r.q_world_ref[j + m]);
    rates.push_back(
        {0.5 * (r.ref_t_s[j] + r.ref_t_s[j + m]), r.ref_t_s[j], r.ref_t_s[j + m], phi / dt});
  }
  return rates;
}

// The gyro's integral from the first stamp to t (trapezoid, linear between samples).
struct GyroIntegral {
  std::vector<Eigen::Vector3d> at_sample;
  explicit GyroIntegral(const MotionRecording& r)
      : at_sample(r.t_s.size(), Eigen::Vector3d::Zero()) {
    for (size_t k = 1; k < r.t_s.size(); ++k) {
      at_sample[k] = at_sample[k - 1] +
                     0.5 * (r.t_s[k] - r.t_s[k - 1]) * (r.gyro_rad_s[k] + r.gyro_rad_s[k - 1]);
    }
  }
};

// Gyro linearly interpolated at IMU time t (false outside the stream), and its time derivative.
bool GyroAt(const MotionRecording& r, double t, Eigen::Vector3d* w, Eigen::Vector3d* dw) {
  const auto it = std::upper_bound(r.t_s.begin(), r.t_s.end(), t);
  if (it == r.t_s.begin() || it == r.t_s.end()) return false;
  const size_t k = static_cast<size_t>(it - r.t_s.begin()) - 1;
  const double dt = r.t_s[k + 1] - r.t_s[k];
  const double f = (t - r.t_s[k]) / dt;
  *w = (1.0 - f) * r.gyro_rad_s[k] + f * r.gyro_rad_s[k + 1];
  if (dw != nullptr) *dw = (r.gyro_rad_s[k + 1] - r.gyro_rad_s[k]) / dt;
  return true;
}

// |w_ref| on the grid t0 + i*dt (reference clock), NaN where no two close rates bracket it.
std::vector<double> RefMagnitudeGrid(const std::vector<RefRate>& rates, double gap_s, double t0,
                                     double dt, size_t n) {
  std::vector<double> grid(n, std::nan(""));
  size_t j = 0;
  for (size_t i = 0; i < n; ++i) {
    const double t = t0 + dt * static_cast<double>(i);
    while (j + 1 < rates.size() && rates[j + 1].t_s < t) ++j;
    if (j + 1 >= rates.size() || rates[j].t_s > t) continue;
    const double span = rates[j + 1].t_s - rates[j].t_s;
    if (span > 2.0 * kRateIntervalS + gap_s) continue;
    const double f = (t - rates[j].t_s) / span;
    grid[i] = (1.0 - f) * rates[j].w_rad_s.norm() + f * rates[j + 1].w_rad_s.norm();
  }
  return grid;
}

// Pearson correlation of a[i] with b[i + lag] over the pairs where both are numbers.
double Correlation(const std::vector<double>& a, const std::vector<double>& b, long lag) {
  double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
  long n = 0;
  for (long i = 0; i < static_cast<long>(a.size()); ++i) {
    const long j = i + lag;
    if (j < 0 || j >= static_cast<long>(b.size()) || std::isnan(b[j])) continue;
    sa += a[i], sb += b[j], saa += a[i] * a[i], sbb += b[j] * b[j], sab += a[i] * b[j];
    ++n;
  }
  if (n < 100) return -1.0;
  const double cov = sab - sa * sb / n, va = saa - sa * sa / n, vb = sbb - sb * sb / n;
  return (va > 0 && vb > 0) ? cov / std::sqrt(va * vb) : -1.0;
}

// The coarse offset (s) and its correlation: whole IMU samples, then a parabola on the peak.
void CoarseOffset(const MotionRecording& r, const std::vector<RefRate>& rates, double gap_s,
                  const AlignOptions& options, double* offset_s, double* correlation) {
  std::vector<double> dts;
  for (size_t k = 0; k + 1 < r.t_s.size(); ++k) dts.push_back(r.t_s[k + 1] - r.t_s[k]);
  const double dt = Median(dts);
  const long max_lag = static_cast<long>(std::ceil(options.max_offset_s / dt));
  const double t0 = r.t_s.front();
  const size_t n = static_cast<size_t>((r.t_s.back() - t0) / dt);
  std::vector<double> a(n);
  Eigen::Vector3d w;
  for (size_t i = 0; i < n; ++i) {
    a[i] = GyroAt(r, t0 + dt * static_cast<double>(i), &w, nullptr) ? w.norm() : 0.0;
  }
  // b[i] is at reference time t0 + (i - max_lag) dt, so a[i] pairs with b[i + max_lag + lag].
  const std::vector<double> b =
      RefMagnitudeGrid(rates, gap_s, t0 - dt * static_cast<double>(max_lag), dt,
                       n + 2 * static_cast<size_t>(max_lag));
  std::vector<double> c(2 * max_lag + 1);
  long best = 0;
  for (long lag = -max_lag; lag <= max_lag; ++lag) {
    c[lag + max_lag] = Correlation(a, b, lag + max_lag);
    if (c[lag + max_lag] > c[best + max_lag]) best = lag;
  }
  double shift = 0.0;
  if (best > -max_lag && best < max_lag) {
    const double l = c[best + max_lag - 1], m = c[best + max_lag], h = c[best + max_lag + 1];
    const double den = l - 2 * m + h;
    if (den < 0) shift = std::clamp(0.5 * (l - h) / den, -0.5, 0.5);
  }
  *offset_s = (static_cast<double>(best) + shift) * dt;
  *correlation = c[best + max_lag];
}

struct RatePair {
  Eigen::Vector3d ref, gyro, gyro_dot;
};

// Integral of the gyro to IMU time t (false outside the stream) and the rate there.
bool IntegralAt(const MotionRecording& r, const GyroIntegral& in, double t, Eigen::Vector3d* i,
                Eigen::Vector3d* w) {
  const auto it = std::upper_bound(r.t_s.begin(), r.t_s.end(), t);
  if (it == r.t_s.begin() || it == r.t_s.end()) return false;
  const size_t k = static_cast<size_t>(it - r.t_s.begin()) - 1;
  GyroAt(r, t, w, nullptr);
  *i = in.at_sample[k] + 0.5 * (t - r.t_s[k]) * (r.gyro_rad_s[k] + *w);
  return true;
}

// The gyro's mean over each reference interval (shifted to the IMU clock) and its derivative
// with respect to the offset.
std::vector<RatePair> Pairs(const MotionRecording& r, const std::vector<RefRate>& rates,
                            double offset_s) {
  const GyroIntegral integral(r);
  std::vector<RatePair> pairs;
  for (const RefRate& rr : rates) {
    Eigen::Vector3d i0, i1, w0, w1;
    if (!IntegralAt(r, integral, rr.t0_s - offset_s, &i0, &w0) ||
        !IntegralAt(r, integral, rr.t1_s - offset_s, &i1, &w1)) {
      continue;
    }
    const double dt = rr.t1_s - rr.t0_s;
    // d/d offset of mean_{[t0 - o, t1 - o]} w = -(w(t1 - o) - w(t0 - o)) / dt; the fit's
    // Jacobian column is -gyro_dot.
    pairs.push_back({rr.w_rad_s, (i1 - i0) / dt, (w1 - w0) / dt});
  }
  return pairs;
}

// Kabsch: the rotation R minimising sum |(g - mean g) - R (r - mean r)|^2.
Eigen::Matrix3d Kabsch(const std::vector<RatePair>& pairs) {
  Eigen::Vector3d mr = Eigen::Vector3d::Zero(), mg = Eigen::Vector3d::Zero();
  for (const RatePair& p : pairs) mr += p.ref, mg += p.gyro;
  mr /= static_cast<double>(pairs.size());
  mg /= static_cast<double>(pairs.size());
  Eigen::Matrix3d h = Eigen::Matrix3d::Zero();
  for (const RatePair& p : pairs) h += (p.ref - mr) * (p.gyro - mg).transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1.0 : 1.0;
  return svd.matrixV() * d * svd.matrixU().transpose();
}

// Gauss-Newton on (rotation, bias, offset); returns the covariance of (dtheta, b, offset).
Eigen::Matrix<double, 7, 7> RefineJointly(const MotionRecording& r,
                                          const std::vector<RefRate>& rates, Eigen::Matrix3d* rot,
                                          double* offset_s, double* residual_rms) {
  Eigen::Vector3d bias = Eigen::Vector3d::Zero();
  Eigen::Matrix<double, 7, 7> n_mat;
  double sse = 0.0;
  size_t count = 0;
  for (int iteration = 0; iteration < 4; ++iteration) {
    const std::vector<RatePair> pairs = Pairs(r, rates, *offset_s);
    n_mat.setZero();
    Eigen::Matrix<double, 7, 1> g = Eigen::Matrix<double, 7, 1>::Zero();
    sse = 0.0;
    count = pairs.size();
    for (const RatePair& p : pairs) {
      const Eigen::Vector3d rw = *rot * p.ref;
      const Eigen::Vector3d e = p.gyro - rw - bias;
      Eigen::Matrix<double, 3, 7> j;  // d e / d(dtheta, b, offset)
      j.leftCols<3>() = Skew(rw);
      j.middleCols<3>(3) = -Eigen::Matrix3d::Identity();
      j.col(6) = -p.gyro_dot;
      n_mat += j.transpose() * j;
      g += j.transpose() * e;
      sse += e.squaredNorm();
    }
    const Eigen::Matrix<double, 7, 1> step = -n_mat.ldlt().solve(g);
    *rot = ExpSo3<double>(Eigen::Vector3d(step.head<3>())) * *rot;
    bias += step.segment<3>(3);
    *offset_s += step(6);
  }
  const double dof = std::max(1.0, 3.0 * static_cast<double>(count) - 7.0);
  *residual_rms = std::sqrt(sse / std::max<size_t>(1, count));
  return (sse / dof) * n_mat.inverse();
}

}  // namespace

Eigen::Vector3d LogQuaternion(const Eigen::Quaterniond& q) {
  const Eigen::AngleAxisd aa(q);
  return aa.angle() * aa.axis();
}

absl::StatusOr<Alignment> EstimateAlignment(const MotionRecording& r, const AlignOptions& options) {
  const std::string& name = r.name;
  if (r.t_s.size() < 100) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: only %d IMU samples", name, static_cast<int>(r.t_s.size())));
  }
  if (r.ref_t_s.size() < 2 || r.ref_t_s.back() < r.t_s.front() - options.max_offset_s ||
      r.ref_t_s.front() > r.t_s.back() + options.max_offset_s) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: the reference does not overlap the IMU in time (IMU %.3f..%.3f s, reference "
        "%.3f..%.3f s from the IMU's first stamp)",
        name, r.t_s.front(), r.t_s.back(), r.ref_t_s.empty() ? 0.0 : r.ref_t_s.front(),
        r.ref_t_s.empty() ? 0.0 : r.ref_t_s.back()));
  }
  std::vector<double> ref_dts;
  for (size_t j = 0; j + 1 < r.ref_t_s.size(); ++j)
    ref_dts.push_back(r.ref_t_s[j + 1] - r.ref_t_s[j]);
  Alignment out;
  out.gap_s = options.gap_factor * Median(ref_dts);
  const std::vector<RefRate> rates = ReferenceRates(r, out.gap_s, Median(ref_dts));
  double rms = 0.0;
  for (const RefRate& rr : rates) rms += rr.w_rad_s.squaredNorm();
  rms = rates.empty() ? 0.0 : std::sqrt(rms / static_cast<double>(rates.size()));
  if (static_cast<int>(rates.size()) < options.min_reference_intervals) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: the reference has %d usable intervals (at most %.4f s apart), %d needed", name,
        static_cast<int>(rates.size()), out.gap_s, options.min_reference_intervals));
  }
  if (rms < options.min_rate_rms_rad_s) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: the reference hardly moves (rate RMS %.4f rad/s): nothing to align or learn on", name,
        rms));
  }
  CoarseOffset(r, rates, out.gap_s, options, &out.offset_s, &out.correlation);
  if (out.correlation < options.min_correlation) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: the reference does not follow the IMU: |rate| correlates at most %.2f (at an "
        "offset of %.3f s; %.2f needed) - another body, or no overlap in time",
        name, out.correlation, out.offset_s, options.min_correlation));
  }
  std::vector<RatePair> pairs = Pairs(r, rates, out.offset_s);
  Eigen::Matrix3d rot = Kabsch(pairs);
  double residual_rms = 0.0;
  const Eigen::Matrix<double, 7, 7> cov =
      RefineJointly(r, rates, &rot, &out.offset_s, &residual_rms);
  out.intervals_used = static_cast<int>(Pairs(r, rates, out.offset_s).size());
  out.frame_residual = residual_rms / rms;
  out.q_imu_ref = Eigen::Quaterniond(rot).normalized();
  out.rotation_deg = Eigen::AngleAxisd(out.q_imu_ref).angle() * kRadToDeg;
  out.rotation_std_error_deg = std::sqrt(cov.topLeftCorner<3, 3>().trace() / 3.0) * kRadToDeg;
  out.offset_std_error_s = std::sqrt(cov(6, 6));
  if (out.frame_residual > options.max_frame_residual) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: the reference's frame does not match the IMU: the best rotation leaves %.0f%% of "
        "the rate (%.0f%% allowed) - the orientation of another body, or its inverse?",
        name, 100 * out.frame_residual, 100 * options.max_frame_residual));
  }
  out.offset_applied = std::abs(out.offset_s) > options.shared_clock_s;
  out.rotation_applied = out.rotation_deg > options.frame_identity_deg;
  out.summary = absl::StrFormat(
      "clock offset %.2f +- %.2f ms (%s), reference-to-IMU rotation %.2f +- %.2f deg (%s), "
      "|rate| correlation %.3f, rotation fit residual %.1f%% of the rate, %d reference "
      "intervals",
      1e3 * out.offset_s, 1e3 * out.offset_std_error_s,
      out.offset_applied ? "removed" : "one clock: kept, the gyro's delay is learnt",
      out.rotation_deg, out.rotation_std_error_deg,
      out.rotation_applied ? "removed" : "taken as the IMU frame", out.correlation,
      100 * out.frame_residual, out.intervals_used);
  return out;
}

AlignedReference AlignReference(const MotionRecording& r, const Alignment& alignment) {
  AlignedReference out;
  const size_t n = r.t_s.size();
  out.q_world_imu.assign(n, Eigen::Quaterniond::Identity());
  out.valid.assign(n, 0);
  const double shift = alignment.offset_applied ? alignment.offset_s : 0.0;
  const Eigen::Quaterniond q_ref_imu =
      alignment.rotation_applied ? alignment.q_imu_ref.conjugate() : Eigen::Quaterniond::Identity();
  Eigen::Vector3d up = Eigen::Vector3d::Zero();
  size_t j = 0;
  for (size_t k = 0; k < n; ++k) {
    const double t = r.t_s[k] + shift;
    while (j + 1 < r.ref_t_s.size() && r.ref_t_s[j + 1] < t) ++j;
    if (j + 1 >= r.ref_t_s.size() || r.ref_t_s[j] > t) continue;
    const double span = r.ref_t_s[j + 1] - r.ref_t_s[j];
    if (span > alignment.gap_s) continue;
    const double f = (t - r.ref_t_s[j]) / span;
    out.q_world_imu[k] = r.q_world_ref[j].slerp(f, r.q_world_ref[j + 1]) * q_ref_imu;
    out.valid[k] = 1;
    ++out.valid_count;
    up += out.q_world_imu[k] * r.accel_m_s2[k];
  }
  if (up.norm() > 0) out.up_world = up.normalized();
  return out;
}

}  // namespace imucal::core::motion
