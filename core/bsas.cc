#include "core/bsas.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <vector>

namespace imucal::core {
namespace {

// Programmer-error check: bad sizes, bounds or options are bugs in the caller, not data.
void BsasCheck(bool ok, const char* what) {
  if (!ok) {
    std::fprintf(stderr, "imucal BSAS precondition failed: %s\n", what);
    std::abort();
  }
}

// Uniform in [0, 1) from the top 53 bits of one engine output. Portable, unlike
// std::uniform_real_distribution, whose algorithm each standard library chooses.
double Uniform01(std::mt19937_64& rng) { return static_cast<double>(rng() >> 11) * 0x1.0p-53; }

// NaN counts as zero, so a NaN comparison proposes no move instead of a NaN point.
double Sign(double v) {
  if (v > 0.0) return 1.0;
  if (v < 0.0) return -1.0;
  return 0.0;
}

// A NaN cost never improves; anything that is not NaN improves on a NaN best.
bool Improves(double cost, double best) {
  return !std::isnan(cost) && (std::isnan(best) || cost < best);
}

void OptionsAreValid(const BsasOptions& o) {
  BsasCheck(o.k >= 1, "options.k >= 1");
  BsasCheck(o.d_init >= 0.0 && o.d0 >= 0.0, "antenna lengths >= 0");
  BsasCheck(o.eta_d >= 0.0 && o.eta_d <= 1.0, "options.eta_d in [0, 1]");
  BsasCheck(o.eta_step > 0.0 && o.eta_step < 1.0, "options.eta_step in (0, 1)");
  BsasCheck(o.step_init > 0.0, "options.step_init > 0");
  BsasCheck(o.p_min >= 0.0 && o.p_min <= 1.0, "options.p_min in [0, 1]");
  BsasCheck(o.p_step >= 0.0 && o.p_step <= 1.0, "options.p_step in [0, 1]");
  BsasCheck(o.n_flag >= 0, "options.n_flag >= 0");
  BsasCheck(o.max_iterations >= 0, "options.max_iterations >= 0");
}

void BoxIsValid(const Eigen::VectorXd& x0, const Eigen::VectorXd& lower,
                const Eigen::VectorXd& upper) {
  BsasCheck(x0.size() == lower.size() && x0.size() == upper.size(),
            "x0, lower and upper have the same size");
  for (Eigen::Index i = 0; i < x0.size(); ++i) {
    BsasCheck(lower(i) <= upper(i), "lower <= upper");
    BsasCheck(lower(i) <= x0(i) && x0(i) <= upper(i), "x0 inside [lower, upper]");
  }
}

// out = clamp(x + scale * dir) onto the box, element by element (no temporaries).
void StepClamped(const Eigen::VectorXd& x, double scale, const Eigen::VectorXd& dir,
                 const Eigen::VectorXd& lower, const Eigen::VectorXd& upper, Eigen::VectorXd* out) {
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    const double v = x(i) + scale * dir(i);
    (*out)(i) = v > upper(i) ? upper(i) : (v < lower(i) ? lower(i) : v);
  }
}

// A random unit direction: uniform in [-1, 1]^n, normalised as rBAS does (x / (1e-16 + |x|)).
// A scalar loop rather than Eigen's norm() keeps the rounding independent of vectorisation.
void RandomDirection(std::mt19937_64& rng, Eigen::VectorXd* dir) {
  double sum_sq = 0.0;
  for (Eigen::Index i = 0; i < dir->size(); ++i) {
    const double v = 2.0 * Uniform01(rng) - 1.0;
    (*dir)(i) = v;
    sum_sq += v * v;
  }
  const double inv = 1.0 / (1e-16 + std::sqrt(sum_sq));
  for (Eigen::Index i = 0; i < dir->size(); ++i) (*dir)(i) *= inv;
}

}  // namespace

BsasResult MinimizeBsas(const std::function<double(const Eigen::VectorXd&)>& f,
                        const Eigen::VectorXd& x0, const Eigen::VectorXd& lower,
                        const Eigen::VectorXd& upper, const BsasOptions& options) {
  OptionsAreValid(options);
  BoxIsValid(x0, lower, upper);
  const Eigen::Index n = x0.size();
  const int k = options.k;
  std::mt19937_64 rng(options.seed);

  BsasResult result;
  result.x = x0;
  result.cost = f(x0);
  result.evaluations = 1;

  double d = options.d_init;
  double step = options.step_init;
  int kept_steps = 0;  // consecutive failed iterations that kept the step
  std::vector<Eigen::VectorXd> dirs(k, Eigen::VectorXd(n));
  std::vector<Eigen::VectorXd> candidates(k, Eigen::VectorXd(n));
  std::vector<double> f_left(k), f_right(k), f_cand(k);
  std::vector<int> improving;
  improving.reserve(k);
  Eigen::VectorXd probe(n);

  for (int iter = 0; iter < options.max_iterations; ++iter) {
    for (int j = 0; j < k; ++j) RandomDirection(rng, &dirs[j]);
    // rBAS order: all left antennae, all right antennae, then the candidates.
    for (int j = 0; j < k; ++j) {
      StepClamped(result.x, d, dirs[j], lower, upper, &probe);
      f_left[j] = f(probe);
    }
    for (int j = 0; j < k; ++j) {
      StepClamped(result.x, -d, dirs[j], lower, upper, &probe);
      f_right[j] = f(probe);
    }
    for (int j = 0; j < k; ++j) {
      StepClamped(result.x, -step * Sign(f_left[j] - f_right[j]), dirs[j], lower, upper,
                  &candidates[j]);
      f_cand[j] = f(candidates[j]);
    }
    result.evaluations += 3 * k;
    ++result.iterations;

    improving.clear();
    int best = -1;
    for (int j = 0; j < k; ++j) {
      if (!Improves(f_cand[j], result.cost)) continue;
      improving.push_back(j);
      if (best < 0 || f_cand[j] < f_cand[best]) best = j;
    }
    if (best >= 0) {
      int chosen = best;
      if (Uniform01(rng) <= options.p_min) {
        const auto pick = static_cast<size_t>(Uniform01(rng) * improving.size());
        chosen = improving[pick < improving.size() ? pick : improving.size() - 1];
      }
      // rBAS records min(f_temp) even when it moves to a random improving beetle; we keep the
      // cost of the point actually chosen so that cost == f(x) always holds.
      result.x = candidates[chosen];
      result.cost = f_cand[chosen];
      continue;
    }

    d = options.eta_d * d + options.d0;
    const bool keep = Uniform01(rng) < options.p_step;
    if (keep && kept_steps < options.n_flag) {
      ++kept_steps;
    } else {
      step *= options.eta_step;
      kept_steps = 0;
    }
    if (step < options.step_tol) break;
  }
  return result;
}

uint64_t DeriveBsasSeed(uint64_t seed, uint64_t stage) {
  // SplitMix64 (Steele, Lea, Flood 2014): the golden-ratio increment is odd, so distinct stages
  // give distinct inputs, and the finaliser is a bijection, so distinct outputs.
  uint64_t z = seed + (stage + 1) * 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

namespace {

void GroupsAreValid(const std::vector<std::vector<int>>& groups, Eigen::Index n) {
  BsasCheck(!groups.empty(), "at least one group");
  for (const std::vector<int>& group : groups) {
    BsasCheck(!group.empty(), "groups are non-empty");
    std::vector<bool> seen(n, false);
    for (int index : group) {
      BsasCheck(index >= 0 && index < n, "group indices inside x0");
      BsasCheck(!seen[index], "group indices distinct");
      seen[index] = true;
    }
  }
}

Eigen::VectorXd Gather(const Eigen::VectorXd& full, const std::vector<int>& group) {
  Eigen::VectorXd sub(static_cast<Eigen::Index>(group.size()));
  for (size_t i = 0; i < group.size(); ++i) sub(i) = full(group[i]);
  return sub;
}

void Scatter(const Eigen::VectorXd& sub, const std::vector<int>& group, Eigen::VectorXd* full) {
  for (size_t i = 0; i < group.size(); ++i) (*full)(group[i]) = sub(i);
}

// Whether a round that took the cost from `start` to `end` is worth another round.
bool RoundImproved(double start, double end, double rel_tol) {
  if (end == 0.0) return false;
  if (std::isnan(start)) return !std::isnan(end);
  return start - end >= rel_tol * std::abs(start);
}

}  // namespace

BsasResult MinimizeBsasStaged(const std::function<double(const Eigen::VectorXd&)>& f,
                              const Eigen::VectorXd& x0, const Eigen::VectorXd& lower,
                              const Eigen::VectorXd& upper,
                              const std::vector<std::vector<int>>& groups, int max_rounds,
                              double rel_tol, const BsasOptions& options) {
  OptionsAreValid(options);
  BoxIsValid(x0, lower, upper);
  GroupsAreValid(groups, x0.size());

  BsasResult result;
  result.x = x0;
  result.cost = f(x0);
  result.evaluations = 1;
  uint64_t stage = 0;
  for (int round = 0; round < max_rounds; ++round) {
    const double round_start = result.cost;
    for (const std::vector<int>& group : groups) {
      // The other coordinates stay at result.x for the whole stage; `work` holds them and each
      // evaluation overwrites only the group's entries.
      Eigen::VectorXd work = result.x;
      const auto sub_f = [&f, &group, &work](const Eigen::VectorXd& sub) {
        Scatter(sub, group, &work);
        return f(work);
      };
      BsasOptions stage_options = options;
      stage_options.seed = DeriveBsasSeed(options.seed, stage++);
      const BsasResult r = MinimizeBsas(sub_f, Gather(result.x, group), Gather(lower, group),
                                        Gather(upper, group), stage_options);
      result.iterations += r.iterations;
      result.evaluations += r.evaluations;
      if (Improves(r.cost, result.cost)) {
        Scatter(r.x, group, &result.x);
        result.cost = r.cost;
      }
    }
    if (!RoundImproved(round_start, result.cost, rel_tol)) break;
  }
  return result;
}

}  // namespace imucal::core
