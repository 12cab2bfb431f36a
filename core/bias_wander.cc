#include "core/bias_wander.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "absl/strings/str_format.h"
#include "util/units.h"

namespace imucal::core {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr int kModels = 4;

// One axis's sequence: times, pose means, their noise variances.
struct Seq {
  std::vector<double> t, y, r;
};

// The filter's prediction of each pose from the poses before it (in the order given): mean and
// variance of the persistent part c + x_k; variance infinite where nothing came before.
struct Predictions {
  std::vector<double> m, p;
};

// Kalman filter over the poses in `order` (forward or backward); returns the log-likelihood of
// all but the first pose (the constant is diffuse).
double Filter(const Seq& s, double q, double s2, bool backward, Predictions* pred) {
  const size_t n = s.y.size();
  if (pred) pred->m.assign(n, 0.0), pred->p.assign(n, kInf);
  double m = 0, p = kInf, ll = 0;
  for (size_t j = 0; j < n; ++j) {
    const size_t k = backward ? n - 1 - j : j;
    if (j > 0) {
      p += q;  // one move
    }
    if (pred) pred->m[k] = m, pred->p[k] = p;
    const double obs = s.r[k] + s2;
    if (std::isinf(p)) {
      m = s.y[k];
      p = obs;
      continue;
    }
    const double S = p + obs, v = s.y[k] - m;
    ll += -0.5 * (std::log(2 * M_PI * S) + v * v / S);
    const double gain = p / S;
    m += gain * v;
    p *= 1 - gain;
  }
  return ll;
}

// Combines independent Gaussian estimates (mean, variance); infinite variances carry nothing.
double Combine(std::initializer_list<std::pair<double, double>> parts) {
  double w = 0, wm = 0;
  for (const auto& [m, p] : parts) {
    if (std::isinf(p)) continue;
    w += 1 / p;
    wm += m / p;
  }
  return w > 0 ? wm / w : 0.0;
}

// The rest's random-walk step is compared with the steps between poses only when it is at least
// this fraction of the poses' noise floor: a real sensor's is orders of magnitude above it.
constexpr double kAllanResolvable = 1e-6;

struct AxisFit {
  double q = 0, s2 = 0;
};

// Golden-section search of f over [lo, hi] (maximum).
template <typename F>
double GoldenMax(F f, double lo, double hi) {
  const double g = 0.5 * (std::sqrt(5.0) - 1);
  double a = lo, b = hi, c = b - g * (b - a), d = a + g * (b - a);
  double fc = f(c), fd = f(d);
  for (int it = 0; it < 40; ++it) {
    if (fc > fd) {
      b = d, d = c, fd = fc;
      c = b - g * (b - a), fc = f(c);
    } else {
      a = c, c = d, fc = fd;
      d = a + g * (b - a), fd = f(d);
    }
  }
  return 0.5 * (a + b);
}

// Maximum likelihood of one model over log10 of its free standard deviations (s, w), grid then
// golden-section refinement per coordinate.
AxisFit FitModel(const Seq& s, WanderModel model, double scale, double* ll_out) {
  const bool has_shift = model == WanderModel::kShift || model == WanderModel::kShiftAndWalk;
  const bool has_walk = model == WanderModel::kWalk || model == WanderModel::kShiftAndWalk;
  // Free parameters as log10(sd / scale): the shift s and the walk's step w.
  const auto ll = [&](double ls, double lw) {
    const double sd_s = has_shift ? scale * std::pow(10.0, ls) : 0.0;
    const double sd_w = has_walk ? scale * std::pow(10.0, lw) : 0.0;
    return Filter(s, sd_w * sd_w, sd_s * sd_s, false, nullptr);
  };
  constexpr double kLo = -3.5, kHi = 0.7;
  constexpr int kGrid = 22;
  double bs = kLo, bw = kLo, best = -kInf;
  for (int i = 0; i < (has_shift ? kGrid : 1); ++i)
    for (int j = 0; j < (has_walk ? kGrid : 1); ++j) {
      const double ls = kLo + (kHi - kLo) * i / (kGrid - 1);
      const double lw = kLo + (kHi - kLo) * j / (kGrid - 1);
      const double v = ll(ls, lw);
      if (v > best) best = v, bs = ls, bw = lw;
    }
  const double step = (kHi - kLo) / (kGrid - 1);
  for (int round = 0; round < (has_shift && has_walk ? 3 : 1); ++round) {
    if (has_shift) bs = GoldenMax([&](double x) { return ll(x, bw); }, bs - step, bs + step);
    if (has_walk) bw = GoldenMax([&](double x) { return ll(bs, x); }, bw - step, bw + step);
  }
  *ll_out = ll(bs, bw);
  AxisFit f;
  if (has_shift) f.s2 = std::pow(scale * std::pow(10.0, bs), 2);
  if (has_walk) f.q = std::pow(scale * std::pow(10.0, bw), 2);
  return f;
}

// Each pose predicted from all the others (forward and backward filters combined), and the
// smoothed persistent part (the pose itself combined too).
void Predict(const Seq& s, const AxisFit& f, std::vector<double>* heldout,
             std::vector<double>* smoothed) {
  Predictions fw, bw;
  Filter(s, f.q, f.s2, false, &fw);
  Filter(s, f.q, f.s2, true, &bw);
  heldout->resize(s.y.size());
  smoothed->resize(s.y.size());
  for (size_t k = 0; k < s.y.size(); ++k) {
    (*heldout)[k] = s.y[k] - Combine({{fw.m[k], fw.p[k]}, {bw.m[k], bw.p[k]}});
    (*smoothed)[k] = Combine({{fw.m[k], fw.p[k]}, {bw.m[k], bw.p[k]}, {s.y[k], s.r[k] + f.s2}});
  }
}

double Rms(const std::vector<double>& v) {
  double ss = 0;
  for (double x : v) ss += x * x;
  return v.empty() ? 0.0 : std::sqrt(ss / static_cast<double>(v.size()));
}

std::string AxisPhrase(const AxisWander& a) {
  switch (a.model) {
    case WanderModel::kNone:
      return "nothing beyond the noise";
    case WanderModel::kShift:
      return absl::StrFormat("a new offset at each pose, %.4f deg/s", a.shift_rad_s * kRadToDeg);
    case WanderModel::kWalk:
      return absl::StrFormat(
          "a step at each move that stays (a random walk over the moves), "
          "%.4f deg/s",
          a.walk_rad_s * kRadToDeg);
    case WanderModel::kShiftAndWalk:
      return absl::StrFormat(
          "an offset at each pose, %.4f deg/s, on a random walk over the "
          "moves, %.4f deg/s per move",
          a.shift_rad_s * kRadToDeg, a.walk_rad_s * kRadToDeg);
  }
  return "";
}

}  // namespace

const char* WanderModelName(WanderModel model) {
  switch (model) {
    case WanderModel::kNone:
      return "none";
    case WanderModel::kShift:
      return "shift";
    case WanderModel::kWalk:
      return "walk";
    case WanderModel::kShiftAndWalk:
      return "shift+walk";
  }
  return "?";
}

namespace {

// Axis `a`: the model of its wander by BIC, and each pose's held-out prediction before (a constant
// bias) and after (the model's smoother). Returns the axis's variance about its weighted mean.
double FitAxis(const std::vector<WanderPose>& poses, int a, double penalty, BiasWander* out,
               std::vector<Eigen::Vector3d>* before, std::vector<Eigen::Vector3d>* after) {
  const size_t n = poses.size();
  Seq s;
  for (const WanderPose& p : poses) {
    s.t.push_back(p.t_s);
    s.y.push_back(p.rate_rad_s(a));
    s.r.push_back(std::max(1e-30, p.sigma_rad_s(a) * p.sigma_rad_s(a)));
  }
  // The scale of the search: the scatter about the weighted mean, never below the noise.
  double w = 0, wy = 0, mean_r = 0;
  for (size_t k = 0; k < n; ++k) w += 1 / s.r[k], wy += s.y[k] / s.r[k], mean_r += s.r[k] / n;
  const double mean = wy / w;
  double var = 0;
  for (double y : s.y) var += (y - mean) * (y - mean) / static_cast<double>(n);
  const double scale = std::sqrt(std::max(var, mean_r));

  AxisWander& aw = out->axes[static_cast<size_t>(a)];
  std::array<AxisFit, kModels> fits;
  double best = kInf;
  for (int m = 0; m < kModels; ++m) {
    const auto model = static_cast<WanderModel>(m);
    double ll = 0;
    if (model == WanderModel::kNone) {
      ll = Filter(s, 0, 0, false, nullptr);
    } else {
      fits[static_cast<size_t>(m)] = FitModel(s, model, scale, &ll);
    }
    const int params = m == 0 ? 0 : (m == 3 ? 2 : 1);
    aw.bic[static_cast<size_t>(m)] = -2 * ll + params * penalty;
    if (aw.bic[static_cast<size_t>(m)] < best)
      best = aw.bic[static_cast<size_t>(m)], aw.model = model;
  }
  const AxisFit& f = fits[static_cast<size_t>(aw.model)];
  aw.shift_rad_s = std::sqrt(f.s2);
  aw.walk_rad_s = std::sqrt(f.q);
  std::vector<double> ho_before, ho_after, sm, unused;
  Predict(s, AxisFit{}, &ho_before, &unused);
  Predict(s, f, &ho_after, &sm);
  aw.heldout_before_rad_s = Rms(ho_before);
  aw.heldout_after_rad_s = Rms(ho_after);
  for (size_t k = 0; k < n; ++k) {
    (*before)[k](a) = ho_before[k];
    (*after)[k](a) = ho_after[k];
    out->smoothed_rad_s[k](a) = sm[k];
  }
  return var;
}

// The figures over all axes: the noise floor, the held-out errors, the steps between poses and
// what each pose's two halves say.
void Totals(const std::vector<WanderPose>& poses, const std::vector<Eigen::Vector3d>& before,
            const std::vector<Eigen::Vector3d>& after, BiasWander* out) {
  const size_t n = poses.size();
  double floor_ss = 0, hb = 0, ha = 0, step_ss = 0, half_ss = 0, half_noise_ss = 0,
         duration_sum = 0;
  for (size_t k = 0; k < n; ++k) {
    floor_ss += poses[k].sigma_rad_s.squaredNorm();
    hb += before[k].squaredNorm();
    ha += after[k].squaredNorm();
    half_ss += poses[k].half_diff_rad_s.squaredNorm();
    half_noise_ss += poses[k].half_diff_sigma_rad_s.squaredNorm();
    duration_sum += poses[k].duration_s;
    if (k > 0) {
      step_ss += (poses[k].rate_rad_s - poses[k - 1].rate_rad_s).squaredNorm() -
                 poses[k].sigma_rad_s.squaredNorm() - poses[k - 1].sigma_rad_s.squaredNorm();
    }
  }
  const double dn = static_cast<double>(n);
  out->noise_floor_rad_s = std::sqrt(floor_ss / dn);
  out->heldout_before_rad_s = std::sqrt(hb / dn);
  out->heldout_after_rad_s = std::sqrt(ha / dn);
  out->step_rms_rad_s = std::sqrt(std::max(0.0, step_ss / (dn - 1)));
  if (half_noise_ss > 0) {
    out->within_pose_ratio = std::sqrt(half_ss / half_noise_ss);
    // A drift in time with K^2 = step^2 / dt: each pose's halves (T / 2 each) differ by
    // 2 avar(T / 2) = K^2 T / 3 more in variance.
    const double k2 = out->step_rms_rad_s * out->step_rms_rad_s / out->median_dt_s;
    out->drift_within_pose_ratio =
        std::sqrt((half_noise_ss + k2 * duration_sum / 3) / half_noise_ss);
  }
}

// The Allan deviation's side of the note: how the steps compare with the rate random walk `k`.
std::string AllanPhrase(const BiasWander& out, const Eigen::Vector3d& k_allan) {
  const double d = kRadToDeg;
  // A rest whose readings never change (a channel on one quantisation step, or noise-free) has
  // an Allan deviation of ~0 at every cluster time (1e-27 rad/s from rounding): it says nothing
  // of a random walk, and a ratio against it (1e25) would say something false.
  const bool allan_resolved = out.allan_step_rad_s > kAllanResolvable * out.noise_floor_rad_s;
  if (!(std::isfinite(out.allan_step_rad_s) && out.allan_step_rad_s > 0)) return "";
  if (!allan_resolved) {
    return "; the rest's readings do not change (quantised below a step, or noise-free), so "
           "its Allan deviation cannot tell a random walk";
  }
  const double ratio = out.step_rms_rad_s / out.allan_step_rad_s;
  const std::string k =
      absl::StrFormat("K %s%.5f deg/s/sqrt(s): %.4f deg/s", out.allan_is_bound ? "at most " : "",
                      k_allan.norm() * d, out.allan_step_rad_s * d);
  return ratio <= 1
             ? absl::StrFormat(
                   ", within what the rest's rate random walk allows over that time (%s)", k)
             : absl::StrFormat(
                   ", %.*f times what the rest's rate random walk allows over that time (%s)",
                   ratio < 10 ? 1 : 0, ratio, k);
}

// What the halves of each pose say: only when a drift in time of the steps' size would part
// them clearly (1.5 x the noise) can agreeing halves rule it out.
std::string WithinPhrase(const BiasWander& out) {
  if (!std::isfinite(out.within_pose_ratio)) return "";
  if (out.within_pose_ratio >= 1.5) {
    return absl::StrFormat(
        "; it moves within the poses too (their two halves differ by %.2f x the noise)",
        out.within_pose_ratio);
  }
  if (out.drift_within_pose_ratio >= 1.5) {
    return absl::StrFormat(
        "; within each pose its two halves agree to %.2f x the noise (a drift in time that "
        "made those steps would give %.1f x): the bias moves when the unit is moved, not while "
        "it rests",
        out.within_pose_ratio, out.drift_within_pose_ratio);
  }
  return absl::StrFormat(
      "; the poses are too short for their halves to tell a drift in time from steps at the "
      "moves (they agree to %.2f x the noise, a drift would give %.2f x): hold each pose "
      "longer to tell",
      out.within_pose_ratio, out.drift_within_pose_ratio);
}

std::string WanderNote(const BiasWander& out, const Eigen::Vector3d& k_allan) {
  bool wanders = false;
  for (const AxisWander& a : out.axes) wanders |= a.model != WanderModel::kNone;
  const double d = kRadToDeg;
  if (!wanders) {
    return absl::StrFormat(
        "gyroscope bias between poses: it holds; the static rate's scatter over the %d poses "
        "(%.4f deg/s RMS) is the noise (floor %.4f deg/s)",
        out.poses, out.static_rms_rad_s * d, out.noise_floor_rad_s * d);
  }
  const bool predicted = out.heldout_after_rad_s < 0.8 * out.heldout_before_rad_s;
  return absl::StrFormat(
      "gyroscope bias between poses: the static rate moves from one pose to the next by %.4f "
      "deg/s RMS (%.1f s apart)%s%s. Per axis: x %s; y %s; z %s. The static rate scatters by "
      "%.4f deg/s RMS about its mean against a noise floor of %.4f deg/s. Held out, a constant "
      "bias predicts a pose to %.4f deg/s, the wander's smoother to %.4f deg/s: %s",
      out.step_rms_rad_s * d, out.median_dt_s, AllanPhrase(out, k_allan), WithinPhrase(out),
      AxisPhrase(out.axes[0]), AxisPhrase(out.axes[1]), AxisPhrase(out.axes[2]),
      out.static_rms_rad_s * d, out.noise_floor_rad_s * d, out.heldout_before_rad_s * d,
      out.heldout_after_rad_s * d,
      predicted ? "the neighbouring poses predict part of it (steps that stay)"
                : "the neighbouring poses do not predict it");
}

}  // namespace

BiasWander AnalyseBiasWander(const std::vector<WanderPose>& poses, const Eigen::Vector3d& allan_k,
                             const Eigen::Vector3d& allan_k_bound) {
  BiasWander out;
  const size_t n = poses.size();
  if (n < 6) return out;
  out.ran = true;
  out.poses = static_cast<int>(n);
  std::vector<double> gaps;
  for (size_t k = 1; k < n; ++k) gaps.push_back(std::abs(poses[k].t_s - poses[k - 1].t_s));
  std::nth_element(gaps.begin(), gaps.begin() + static_cast<long>(gaps.size() / 2), gaps.end());
  out.median_dt_s = std::max(1e-3, gaps[gaps.size() / 2]);
  const double penalty = std::log(static_cast<double>(n - 1));
  std::vector<Eigen::Vector3d> before(n), after(n);
  out.smoothed_rad_s.assign(n, Eigen::Vector3d::Zero());
  double static_ss = 0;
  for (int a = 0; a < 3; ++a) static_ss += FitAxis(poses, a, penalty, &out, &before, &after);
  out.static_rms_rad_s = std::sqrt(static_ss);
  Totals(poses, before, after, &out);
  Eigen::Vector3d k_allan;
  bool any = false;
  for (int a = 0; a < 3; ++a) {
    k_allan(a) = std::isfinite(allan_k(a)) ? allan_k(a) : allan_k_bound(a);
    out.allan_is_bound |= !std::isfinite(allan_k(a)) && std::isfinite(allan_k_bound(a));
    any |= std::isfinite(k_allan(a));
  }
  if (any && k_allan.allFinite())
    out.allan_step_rad_s = k_allan.norm() * std::sqrt(out.median_dt_s);
  out.note = WanderNote(out, k_allan);
  return out;
}

}  // namespace imucal::core
