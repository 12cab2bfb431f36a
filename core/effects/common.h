// What the static effect search (search.h) and the moves' search (move_search.cc) share: the
// rules by which a candidate is absorbed, ambiguous or significant.
#ifndef IMUCAL_CORE_EFFECTS_COMMON_H_
#define IMUCAL_CORE_EFFECTS_COMMON_H_

#include <cmath>
#include <limits>

#include "Eigen/Core"
#include "util/units.h"

namespace imucal::core::effects {

// A candidate whose column keeps less than this fraction of its norm once the current model's
// columns are projected out is numerically in the model (a bias, a scale). Nearly collinear
// ones stay: the F test judges whether the part the model lacks is significant. The moves'
// search uses the same rule (a column the moves do not excite beyond the model).
constexpr double kAbsorbedFraction = 1e-3;
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
// The F(df1, dof) quantile at alpha / tests (Bonferroni); +inf without a test or a dof.
double FThreshold(double alpha, int tests, Eigen::Index dof, int df1 = 1);

}  // namespace imucal::core::effects

#endif  // IMUCAL_CORE_EFFECTS_COMMON_H_
