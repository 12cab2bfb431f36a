#include "core/calibrate/orientations.h"

#include <array>
#include <cmath>
#include <limits>

#include "absl/strings/str_format.h"
#include "core/protocol.h"
#include "core/so3.h"

namespace imucal::core::pipeline {
namespace {

std::string Where(const Capture& cap, const StaticInterval& s) {
  const int file = cap.FileOf(s.begin);
  const std::string name = file >= 0 ? cap.files[static_cast<size_t>(file)].path : "the capture";
  return absl::StrFormat("%s (%.1f-%.1f s)", name, s.t_start_s, s.t_end_s);
}

}  // namespace

std::vector<Eigen::Vector3d> RawUps(const Capture& cap, const std::vector<StaticInterval>& ivs) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  for (const StaticInterval& s : ivs) {
    lo = lo.cwiseMin(s.accel_mean);
    hi = hi.cwiseMax(s.accel_mean);
  }
  const Eigen::Vector3d centre = cap.accel_unit == AccelUnit::kCounts && !ivs.empty()
                                     ? Eigen::Vector3d(0.5 * (lo + hi))
                                     : Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector3d> out;
  for (const StaticInterval& s : ivs) {
    const Eigen::Vector3d v = s.accel_mean - centre;
    out.push_back(v.norm() > 0 ? Eigen::Vector3d(v.normalized()) : Eigen::Vector3d::Zero());
  }
  return out;
}

int DistinctOrientations(const std::vector<Eigen::Vector3d>& ups) {
  std::vector<Eigen::Vector3d> dirs;
  for (const Eigen::Vector3d& u : ups) {
    bool seen = false;
    for (const Eigen::Vector3d& d : dirs)
      seen |= d == u || AngleBetweenDeg(d, u) <= kSameOrientationDeg;
    if (!seen) dirs.push_back(u);
  }
  return static_cast<int>(dirs.size());
}

std::vector<std::string> RepeatedOrientations(const Capture& cap,
                                              const std::vector<StaticInterval>& ivs,
                                              const std::vector<Eigen::Vector3d>& ups) {
  std::vector<std::string> out;
  std::vector<size_t> stops;
  for (size_t i = 0; i < ivs.size() && i < ups.size(); ++i)
    if (ivs[i].issue != IntervalIssue::kTurning && ups[i].squaredNorm() > 0) stops.push_back(i);
  if (cap.files.size() > 1) {
    for (size_t a = 0; a < stops.size(); ++a) {
      for (size_t b = a + 1; b < stops.size(); ++b) {
        const StaticInterval& x = ivs[stops[a]];
        const StaticInterval& y = ivs[stops[b]];
        if (cap.FileOf(x.begin) == cap.FileOf(y.begin)) continue;
        const double angle = AngleBetweenDeg(ups[stops[a]], ups[stops[b]]);
        if (angle > kRepeatedOrientationDeg) continue;
        const Face f = ClassifyFace(ups[stops[a]]);
        out.push_back(absl::StrFormat(
            "%s and %s hold the same orientation%s, %.3g degrees apart: one of them was meant "
            "for another",
            Where(cap, x), Where(cap, y),
            f.off_axis_deg <= kFaceToleranceDeg ? absl::StrFormat(" (%s up)", f.Label()) : "",
            angle));
      }
    }
  }
  // The faces: when every stop is on one and five of the six are up somewhere, the sixth is
  // named.
  std::array<bool, 6> up{};
  bool all_on_faces = !stops.empty();
  for (size_t i : stops) {
    const Face f = ClassifyFace(ups[i]);
    all_on_faces &= f.off_axis_deg <= kFaceToleranceDeg;
    up[static_cast<size_t>(2 * f.axis + (f.sign > 0 ? 0 : 1))] = true;
  }
  int covered = 0;
  for (bool u : up) covered += u;
  if (all_on_faces && covered == 5) {
    for (size_t k = 0; k < 6; ++k) {
      if (up[k]) continue;
      Face f;
      f.axis = static_cast<int>(k / 2);
      f.sign = k % 2 == 0 ? 1 : -1;
      out.push_back(absl::StrFormat("no pose has %s up", f.Label()));
    }
  }
  return out;
}

}  // namespace imucal::core::pipeline
