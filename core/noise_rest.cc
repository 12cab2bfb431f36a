#include "core/noise_rest.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "core/static_detector.h"

namespace imucal::core {
namespace {

// At most this many cut stretches are listed in the note (the total is always given).
constexpr size_t kListedCuts = 4;

// The samples [begin, end) of the file sample `i` came from (the whole capture for one file).
SampleRange FileBounds(const Capture& capture, size_t i) {
  SampleRange out{0, capture.size()};
  for (size_t start : capture.FileStarts()) {
    if (start <= i) {
      out.begin = start;
    } else {
      out.end = start;
      break;
    }
  }
  return out;
}

// The still stretches the detector finds, each given back what the detector leaves off at a
// record's or a file's ends (its trim and half a variance window, which it cannot see past):
// a record that is one rest stays whole. A stretch "moved" (its halves' accelerometer means
// differ) is kept: a move would have broken the stretch (its window variance, its means), so
// what is left is a slow drift of the rest itself, which the Allan deviation is there to show.
std::vector<SampleRange> StillStretches(const Capture& capture) {
  const StaticDetectorOptions options;
  const MotionSignal motion = ComputeMotionSignal(capture, options);
  const NoiseLevel noise = EstimateNoise(capture, motion);
  const double dt = capture.MedianDt();
  const size_t trim = dt > 0 ? static_cast<size_t>(std::lround(options.trim_s / dt)) : 0;
  const size_t slack = motion.window + trim;
  std::vector<SampleRange> out;
  for (const StaticInterval& iv :
       DetectStatic(capture, motion, noise, kNoiseRestMultiplier, options)) {
    if (iv.issue != IntervalIssue::kNone && iv.issue != IntervalIssue::kMoved) continue;
    SampleRange r{iv.begin, iv.end};
    const SampleRange file = FileBounds(capture, iv.begin);
    if (r.begin - file.begin <= slack) r.begin = file.begin;
    if (file.end - r.end <= slack) r.end = file.end;
    out.push_back(r);
  }
  return out;
}

// What lies in [0, n) outside `segments` (in time order).
std::vector<SampleRange> Complement(const std::vector<SampleRange>& segments, size_t n) {
  std::vector<SampleRange> out;
  size_t at = 0;
  for (const SampleRange& r : segments) {
    if (r.begin > at) out.push_back({at, r.begin});
    at = r.end;
  }
  if (at < n) out.push_back({at, n});
  return out;
}

// "a-b s" of a stretch, from the record's first sample.
std::string Span(const Capture& capture, const SampleRange& r, double dt) {
  const double t0 = capture.t_s.front();
  return absl::StrFormat("%.1f-%.1f s", capture.t_s[r.begin] - t0,
                         capture.t_s[r.end - 1] - t0 + dt);
}

std::string CutList(const Capture& capture, const std::vector<SampleRange>& cut, double dt) {
  std::vector<std::string> parts;
  for (size_t i = 0; i < cut.size() && i < kListedCuts; ++i)
    parts.push_back(Span(capture, cut[i], dt));
  if (cut.size() > kListedCuts)
    parts.push_back(absl::StrFormat("%d more", cut.size() - kListedCuts));
  return absl::StrFormat("%d stretch%s: %s", cut.size(), cut.size() == 1 ? "" : "es",
                         absl::StrJoin(parts, ", "));
}

std::string NotAtRest(const Capture& capture, const std::vector<SampleRange>& stretches, double dt,
                      double record_s) {
  const std::string needs = absl::StrFormat(
      "the noise figures need at least %.0f s untouched (the white-noise density; minutes for "
      "the bias instability, an hour or more for the random walk). Record the sensor at rest on "
      "a firm support; a calibration capture's moves are not noise",
      kMinNoiseRestS);
  if (stretches.empty()) {
    return absl::StrFormat(
        "the record is not at rest: the still detector finds no still stretch in its %.0f s (it "
        "moves throughout), and %s",
        record_s, needs);
  }
  const SampleRange longest = *std::max_element(
      stretches.begin(), stretches.end(),
      [](const SampleRange& a, const SampleRange& b) { return a.size() < b.size(); });
  return absl::StrFormat(
      "the record is not at rest: its longest still stretch is %.1f s (%s) of the %.0f s "
      "recorded, and %s",
      static_cast<double>(longest.size()) * dt, Span(capture, longest, dt), record_s, needs);
}

}  // namespace

absl::StatusOr<NoiseRest> FindNoiseRest(const Capture& capture) {
  NoiseRest out;
  const double dt = capture.MedianDt();
  if (capture.size() < 2 || !(dt > 0)) {
    return absl::FailedPreconditionError(
        "the record is not at rest: it holds fewer than two "
        "samples in time order");
  }
  out.record_s = static_cast<double>(capture.size()) * dt;
  const std::vector<SampleRange> stretches = StillStretches(capture);
  for (const SampleRange& r : stretches)
    if (static_cast<double>(r.size()) * dt >= kMinNoiseRestS) out.segments.push_back(r);
  if (out.segments.empty())
    return absl::FailedPreconditionError(NotAtRest(capture, stretches, dt, out.record_s));
  out.cut = Complement(out.segments, capture.size());
  for (const SampleRange& r : out.segments) out.rest_s += static_cast<double>(r.size()) * dt;
  for (const SampleRange& r : out.cut) out.cut_s += static_cast<double>(r.size()) * dt;
  out.whole = out.cut.empty();
  if (out.whole) return out;
  if (out.segments.size() == 1) {
    out.note = absl::StrFormat(
        "the record is not at rest throughout: the figures are those of its longest rest, %s "
        "(%.1f s of the %.1f s recorded); %.1f s cut in %s",
        Span(capture, out.segments.front(), dt), out.rest_s, out.record_s, out.cut_s,
        CutList(capture, out.cut, dt));
  } else {
    out.note = absl::StrFormat(
        "motion cut out of the rest: %.1f s in %s. The figures pool the Allan variances of the "
        "%d still stretches (%.1f s of the %.1f s recorded), each difference taken inside one "
        "stretch, so a change of orientation between them does not enter",
        out.cut_s, CutList(capture, out.cut, dt), static_cast<int>(out.segments.size()), out.rest_s,
        out.record_s);
  }
  return out;
}

}  // namespace imucal::core
