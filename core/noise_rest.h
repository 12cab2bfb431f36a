// The rest in a recording given for the noise figures (`imucal noise`): the still stretches the
// project's still detector (core/static_detector.h) finds, with what was cut around them.
//
// A recording meant as a rest is not always one: a capture with moves given by mistake, a rest
// with a few seconds of handling in it (picked up, put down a little turned). The Allan
// deviation of the whole record would count the motion as noise (a moving capture gave a white
// noise density 10^4 times too high; ten seconds of handling in an hour's rest, bias
// instability and random walk 2-3 times too high). So:
//   - a record with no still stretch of at least kMinNoiseRestS is refused (not a rest);
//   - otherwise the still stretches of at least kMinNoiseRestS each are the rest, and the
//     figures pool their Allan variances (core/allan.h ComputeNoiseOfSegments: every difference
//     inside one stretch, so a change of orientation between them does not enter);
//   - a record in one orientation where nothing moves stays whole (the detector's trimming and
//     its half-window at a record's or a file's ends are given back).
#ifndef IMUCAL_CORE_NOISE_REST_H_
#define IMUCAL_CORE_NOISE_REST_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/allan.h"
#include "core/capture.h"

namespace imucal::core {

// The shortest still stretch that counts as rest for the noise figures: the white-noise density
// is read near tau = 1 s with at least kMinClustersForFit (6) clusters and a slope over several
// cluster times, so 10 s is about the least that gives it (README: "a 10-30 s rest gives N").
inline constexpr double kMinNoiseRestS = 10.0;

// The detector's threshold multiplier for a rest: a still window's variance exceeds twice the
// noise variance with negligible probability (chi-squared with tens of degrees of freedom), and
// 8 leaves room for a rest whose noise is not stationary (temperature, a building's vibration),
// while a hand's motion reads hundreds of times the noise variance.
inline constexpr double kNoiseRestMultiplier = 8.0;

struct NoiseRest {
  std::vector<SampleRange> segments;  // the rest's stretches, in time order
  std::vector<SampleRange> cut;       // what lies around and between them, in time order
  double record_s = 0;                // the record's span (its files' spans, summed)
  double rest_s = 0;                  // the segments' spans, summed
  double cut_s = 0;                   // the cut stretches' spans, summed
  bool whole = true;                  // nothing was cut
  // One sentence for the output when something was cut (empty when whole): the span used, how
  // much was cut and where, and how the segments are combined.
  std::string note;
};

// The rest of `capture` (input units; the detector learns the noise from the data). Returns
// FailedPrecondition whose message starts "the record is not at rest: " when no still stretch
// reaches kMinNoiseRestS.
absl::StatusOr<NoiseRest> FindNoiseRest(const Capture& capture);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_NOISE_REST_H_
