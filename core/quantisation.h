// What a grid of readings costs a mean: the standard error of the mean of n readings rounded to
// a grid of step q (a sensor's quantisation: whole counts, 0.01 m/s^2, 1/131 deg/s).
//
// Rounding adds to each reading an error that depends on where the true value sits in its grid
// cell. With noise sigma >> q the noise dithers it and the errors average away like noise; with
// sigma << q every reading of a rest rounds the same way, and the mean keeps a systematic error
// up to q/2 that no number of samples removes. Over an unknown position in the cell (uniform),
// that error has standard deviation q/sqrt(12) without noise; Gaussian noise of std sigma damps
// the periodic error's harmonics by exp(-2 pi^2 k^2 sigma^2 / q^2) (its characteristic function
// at the grid's frequencies), the first harmonic dominating:
//   rounding_std = (q / sqrt(12)) exp(-2 pi^2 sigma^2 / q^2)
// and the mean's standard error is sqrt(sigma^2 / n + rounding_std^2). A gyro channel stuck on
// one step through a rest (noise far below the step) so gets q/sqrt(12), not the 3.5e-6 rad/s its
// few flips gave; with sigma = q the term is exp(-2 pi^2) = 3e-9 of the step, nothing.
#ifndef IMUCAL_CORE_QUANTISATION_H_
#define IMUCAL_CORE_QUANTISATION_H_

#include <cmath>

namespace imucal::core {

// The systematic rounding error's standard deviation of a mean of readings on a grid of step
// `step` (0: no grid, no error) with per-sample noise `sigma` (the readings' scatter: when the
// noise is below the step it is mostly 0, which is the case that matters).
inline double RoundingBiasStd(double step, double sigma) {
  if (!(step > 0)) return 0.0;
  const double r = sigma / step;
  return step / std::sqrt(12.0) * std::exp(-2.0 * M_PI * M_PI * r * r);
}

// sqrt(statistical^2 + RoundingBiasStd(step, sigma)^2): a mean's standard error `statistical`
// (sigma / sqrt(n), or a scatter of means) with the grid's systematic part added.
inline double WithRoundingError(double statistical, double step, double sigma) {
  return std::hypot(statistical, RoundingBiasStd(step, sigma));
}

}  // namespace imucal::core

#endif  // IMUCAL_CORE_QUANTISATION_H_
