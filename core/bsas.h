// Beetle Swarm Antennae Search (BSAS): a derivative-free, bounded, randomised local search.
//
// The algorithm follows the BSAS authors' reference code (R package rBAS, `BSASoptim`), as
// restated in shared/notes/field-notes.md section 2; seeds/002 uses it to refine the
// 15-parameter accelerometer model in four stages (scale, bias, angles, K2).
//
// One iteration, at the current point x with best cost f_best = f(x):
//   for j = 1..k:  dir_j  = r_j / |r_j|,  r_j ~ uniform [-1, 1]^n
//                  left_j  = clamp(x + d * dir_j),  right_j = clamp(x - d * dir_j)
//                  cand_j  = clamp(x - step * dir_j * sign(f(left_j) - f(right_j)))
//   (3k evaluations). If some f(cand_j) < f_best: move to the best candidate or, with
//   probability p_min, to a uniformly chosen improving one. Otherwise
//   d = eta_d * d + d0 and step = eta_step * step, except that with probability p_step the step
//   is kept; after n_flag consecutive kept steps the next failure shrinks it unconditionally.
//   Stop after max_iterations iterations or as soon as step < step_tol.
// clamp() projects onto the box [lower, upper]. A NaN difference f(left) - f(right) counts as
// zero (the candidate is x itself); a NaN candidate cost never counts as an improvement.
//
// Only signs of cost differences drive the search, so the parameters must be in comparable
// (normalised) units: one unit of each coordinate should change the cost by a similar amount.
// BSAS is a refinement: seed it from a least-squares solution and keep Levenberg-Marquardt as
// the reference (field notes section 2).
//
// REPRODUCIBILITY: every random draw comes from one std::mt19937_64 seeded with
// `BsasOptions::seed` (whose output sequence the C++ standard fixes), turned into doubles by
// the portable 53-bit mapping below instead of std::uniform_real_distribution (whose output is
// implementation-defined). The same f, x0, bounds, options and seed therefore give a
// bit-identical BsasResult on every standard library, provided f itself is deterministic and the
// build keeps IEEE double arithmetic (no -ffast-math). The draws per iteration do not depend on
// the cost values, except for the improving-candidate and keep-step draws, which are made only
// when the algorithm takes that branch.
#ifndef IMUCAL_CORE_BSAS_H_
#define IMUCAL_CORE_BSAS_H_

#include <cstdint>
#include <functional>
#include <vector>

#include "Eigen/Core"

namespace imucal::core {

// Defaults are rBAS `BSASoptim`'s.
struct BsasOptions {
  int k = 5;                 // beetles (random directions) per iteration
  double d_init = 3.0;       // initial antenna length (rBAS d1)
  double d0 = 0.001;         // antenna length floor added at every decay
  double eta_d = 0.95;       // antenna length decay on a failed iteration
  double step_init = 0.8;    // initial step size
  double eta_step = 0.95;    // step decay on a failed iteration
  double p_min = 0.2;        // probability of moving to a random improving candidate
  double p_step = 0.2;       // probability of keeping the step on a failed iteration
  int n_flag = 2;            // at most this many kept steps in a row
  int max_iterations = 200;  // rBAS n
  double step_tol = 0.01;    // stop once step < step_tol
  uint64_t seed = 1;
};

struct BsasResult {
  Eigen::VectorXd x;    // best point found; x0 if nothing improved on it
  double cost = 0.0;    // f(x), never greater than f(x0)
  int iterations = 0;   // iterations run (each costs 3k evaluations)
  int evaluations = 0;  // calls to f, including the one at x0
};

// Minimises f over the box [lower, upper] starting from x0 (which must lie inside it; all three
// the same size, lower <= upper). Every evaluated point lies inside the box.
// evaluations == 1 + 3 * k * iterations. Violated preconditions or invalid options are programmer
// errors and abort with a message.
BsasResult MinimizeBsas(const std::function<double(const Eigen::VectorXd&)>& f,
                        const Eigen::VectorXd& x0, const Eigen::VectorXd& lower,
                        const Eigen::VectorXd& upper, const BsasOptions& options);

// Block-coordinate BSAS (seeds/002's staged scheme): runs MinimizeBsas on one group of
// coordinates at a time with the others held fixed, group after group in the given order; one
// pass over all groups is a round. Rounds repeat until a round lowers the cost by less than
// rel_tol * |cost at the start of the round| (or to exactly zero), or max_rounds rounds ran.
// Stage s (counting from 0 across rounds) runs with seed DeriveBsasSeed(options.seed, s), so
// each stage draws a distinct stream and the whole run is reproducible from options.seed.
// Groups must be non-empty and hold valid, distinct indices; a coordinate in no group stays at
// x0. iterations and evaluations are summed over the stages; evaluations also counts the one
// initial call f(x0) (each stage evaluates its own start again).
BsasResult MinimizeBsasStaged(const std::function<double(const Eigen::VectorXd&)>& f,
                              const Eigen::VectorXd& x0, const Eigen::VectorXd& lower,
                              const Eigen::VectorXd& upper,
                              const std::vector<std::vector<int>>& groups, int max_rounds,
                              double rel_tol, const BsasOptions& options);

// The seed of stage `stage` of MinimizeBsasStaged: a SplitMix64 mix of (seed, stage).
uint64_t DeriveBsasSeed(uint64_t seed, uint64_t stage);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_BSAS_H_
