#include "core/health/fleet.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"

namespace imucal::core::health {
namespace {

constexpr double kMadToSigma = 1.4826;

double Median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const size_t m = v.size() / 2;
  return v.size() % 2 ? v[m] : (v[m - 1] + v[m]) / 2;
}

double Mad(const std::vector<double>& v, double median) {
  std::vector<double> d;
  for (double x : v) d.push_back(std::abs(x - median));
  return kMadToSigma * Median(d);
}

// The value of quantity q (0: |f| - g, 1-3: gyro bias x-z) of a check.
double CheckValue(const HealthCheck& c, int q) {
  return q == 0 ? c.norm_minus_g_m_s2 : c.gyro_bias_rad_s(q - 1);
}

}  // namespace

std::vector<std::string> FleetParameterNames(bool with_gyro) {
  std::vector<std::string> n = {"accel bias x",   "accel bias y",   "accel bias z",
                                "accel scale x",  "accel scale y",  "accel scale z",
                                "accel angle yx", "accel angle zx", "accel angle zy"};
  if (!with_gyro) return n;
  for (const char* s : {"gyro bias x", "gyro bias y", "gyro bias z", "gyro scale x", "gyro scale y",
                        "gyro scale z", "gyro matrix xy", "gyro matrix xz", "gyro matrix yx",
                        "gyro matrix yz", "gyro matrix zx", "gyro matrix zy"})
    n.push_back(s);
  return n;
}

Eigen::VectorXd FleetParameterVector(const ParamSet& p, bool with_gyro) {
  Eigen::VectorXd v(with_gyro ? 21 : 9);
  v << p.accel.bias, p.accel.scale, p.accel.tri_angles, Eigen::VectorXd::Zero(with_gyro ? 12 : 0);
  if (with_gyro) {
    const Eigen::Matrix3d& m = p.gyro.matrix;
    v.tail<12>() << p.gyro.bias, m.diagonal(), m(0, 1), m(0, 2), m(1, 0), m(1, 2), m(2, 0), m(2, 1);
  }
  return v;
}

Eigen::VectorXd FleetStdErrorVector(const ParamSet& p, bool with_gyro) {
  Eigen::VectorXd v(with_gyro ? 21 : 9);
  v << p.stderrs.accel.bias, p.stderrs.accel.scale, p.stderrs.accel.tri_angles,
      Eigen::VectorXd::Zero(with_gyro ? 12 : 0);
  if (with_gyro) {
    const Eigen::Matrix3d& m = p.stderrs.gyro_matrix;
    v.tail<12>() << p.stderrs.gyro_bias, m.diagonal(), m(0, 1), m(0, 2), m(1, 0), m(1, 2), m(2, 0),
        m(2, 1);
  }
  return v;
}

absl::StatusOr<FleetReference> BuildFleetReference(const std::string& sensor_model,
                                                   const std::vector<ParamSet>& actives,
                                                   int min_siblings) {
  if (static_cast<int>(actives.size()) < min_siblings) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "sensor model %s has %d active parameter sets; the fleet reference needs %d", sensor_model,
        actives.size(), min_siblings));
  }
  FleetReference f;
  f.sensor_model = sensor_model;
  f.siblings = static_cast<int>(actives.size());
  f.with_gyro = true;
  for (const ParamSet& p : actives) {
    f.with_gyro &= p.has_gyro;
    if (p.accel_unit != actives.front().accel_unit || p.gyro_unit != actives.front().gyro_unit) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "sensor model %s: device %s's parameters are in other units than device %s's",
          sensor_model, p.device, actives.front().device));
    }
  }
  f.names = FleetParameterNames(f.with_gyro);
  const int np = static_cast<int>(f.names.size());
  f.median.resize(np);
  f.mad.resize(np);
  for (int i = 0; i < np; ++i) {
    std::vector<double> x, se;
    for (const ParamSet& p : actives) {
      x.push_back(FleetParameterVector(p, f.with_gyro)(i));
      const double s = FleetStdErrorVector(p, f.with_gyro)(i);
      if (std::isfinite(s)) se.push_back(s);
    }
    f.median(i) = Median(x);
    const double floor = se.empty() ? 0.0 : Median(se);
    f.mad(i) = std::max(Mad(x, f.median(i)), floor);
  }
  return f;
}

FleetDistance DistanceToFleet(const FleetReference& fleet, const ParamSet& params,
                              double max_mads) {
  FleetDistance d;
  const Eigen::VectorXd x = FleetParameterVector(params, fleet.with_gyro);
  d.z = (x - fleet.median).cwiseQuotient(fleet.mad.cwiseMax(1e-300));
  d.max_mads = d.z.cwiseAbs().maxCoeff(&d.worst);
  d.far = d.max_mads > max_mads;
  if (d.far) {
    d.reason = absl::StrFormat(
        "%s is %.1f MADs from %d siblings (median %.6g, MAD %.3g, this %.6g)", fleet.names[d.worst],
        d.max_mads, fleet.siblings, fleet.median(d.worst), fleet.mad(d.worst), x(d.worst));
  }
  return d;
}

std::vector<WalkingAway> UnitsWalkingAway(const std::vector<UnitChecks>& units, int window,
                                          double max_mads, double min_move_mads) {
  static constexpr const char* kNames[4] = {"|a| - g", "gyro bias x", "gyro bias y", "gyro bias z"};
  std::vector<WalkingAway> out;
  for (int q = 0; q < 4; ++q) {
    std::vector<double> first, last;
    std::vector<int> which;
    for (int u = 0; u < static_cast<int>(units.size()); ++u) {
      const std::vector<HealthCheck>& c = units[u].checks;
      if (static_cast<int>(c.size()) < 2 * window || (q > 0 && !c.front().has_gyro)) continue;
      std::vector<double> f, l;
      for (int i = 0; i < window; ++i) {
        f.push_back(CheckValue(c[i], q));
        l.push_back(CheckValue(c[c.size() - 1 - i], q));
      }
      first.push_back(Median(f));
      last.push_back(Median(l));
      which.push_back(u);
    }
    if (which.size() < 8) continue;  // too few units to be a reference
    const double m = Median(last), s = std::max(Mad(last, m), 1e-300);
    for (size_t i = 0; i < which.size(); ++i) {
      const double f = std::abs(first[i] - m) / s, l = std::abs(last[i] - m) / s;
      if (l <= max_mads || l < f + min_move_mads) continue;
      WalkingAway w{units[which[i]].device, kNames[q], f, l, ""};
      w.reason = absl::StrFormat(
          "%s: %s walked from %.1f to %.1f MADs of the fleet's %d units (median %.4g, MAD %.3g)",
          w.device, w.quantity, f, l, static_cast<int>(which.size()), m, s);
      out.push_back(w);
    }
  }
  return out;
}

double FleetGyroSpread(const std::vector<UnitChecks>& units) {
  std::vector<double> spreads;
  for (const UnitChecks& u : units) {
    if (u.checks.size() < 4 || !u.checks.front().has_gyro) continue;
    for (int k = 0; k < 3; ++k) {
      std::vector<double> d;
      for (size_t i = 1; i < u.checks.size(); ++i)
        d.push_back(u.checks[i].gyro_bias_rad_s(k) - u.checks[i - 1].gyro_bias_rad_s(k));
      spreads.push_back(Mad(d, Median(d)) / std::sqrt(2.0));
    }
  }
  return Median(spreads);
}

}  // namespace imucal::core::health
