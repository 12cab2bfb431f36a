#include "core/calibrate/protocol_checks.h"

#include <cmath>

#include "absl/strings/str_format.h"
#include "core/calibrate/orientations.h"
#include "core/so3.h"
#include "core/validation.h"
#include "util/units.h"

namespace imucal::core::pipeline {
namespace {

// Two poses whose up directions agree within this are the same orientation (not a new pose).
constexpr double kDuplicateDeg = 2.0;
// ... and a move that turned less than this (along its path) did not re-place the robot.
constexpr double kNotTurnedDeg = 10.0;

// The six-face pairs, checked with the rough gyroscope's turns (its few percent of scale error
// are well inside the check's 20-degree tolerance).
void CheckPairs(const Capture& cap, const std::vector<StaticInterval>& ivs,
                const std::vector<int>& used, const TimeGaps& gaps, const GyroParams& rough,
                ProtocolChecks* out) {
  std::vector<FacePose> fps;
  for (size_t k = 0; k < used.size(); ++k) {
    FacePose fp;
    fp.index = used[k];
    fp.up = out->ups[static_cast<size_t>(used[k])];
    if (k > 0 && !cap.has_gyro) {
      fp.rotation_known = false;  // no gyroscope: the turn is not checked, not failed
    } else if (k > 0) {
      const size_t begin = ivs[static_cast<size_t>(used[k - 1])].end - 1;
      const size_t end = ivs[static_cast<size_t>(used[k])].begin;
      fp.rotation_from_previous = IntegrateRotation(cap, begin, end, rough);
      const long gap = gaps.In(begin, end);
      if (gap >= 0) {
        fp.rotation_known = false;
        out->warnings.push_back(
            absl::StrFormat("the turn from pose %d to pose %d was not checked: %s", used[k - 1],
                            used[k], TimeGaps::Describe(cap, static_cast<size_t>(gap))));
      }
    }
    fps.push_back(fp);
  }
  SixFaceCheck check = CheckSixFacePairs(fps);
  out->pairs = check.pairs;
  if (!cap.has_gyro && !out->pairs.empty()) {
    out->warnings.push_back(
        "six-face pairs: the half turns were not checked (the capture has no gyroscope); only "
        "each pair's face and mirrored horizontal components were");
  }
  for (const auto& p : out->pairs)
    if (!p.ok)
      out->warnings.push_back(absl::StrFormat("pair of poses %d and %d (%s) rejected: %s", p.pose_a,
                                              p.pose_b, p.face, p.reason));
  for (const auto& m : check.missing) out->warnings.push_back(m);
}

// Ferraris: a full turn about the vertical with each axis up gives that axis' gyro scale.
void CheckFerrarisTurns(const std::vector<TurnCandidate>& turns, ProtocolChecks* out) {
  std::string missing;
  for (int axis = 0; axis < 3; ++axis) {
    bool found = false;
    for (const TurnCandidate& t : turns)
      found |= t.turn.axis.squaredNorm() > 0 && ClassifyFace(t.turn.axis).axis == axis;
    if (!found) missing += absl::StrFormat("%s%c", missing.empty() ? "" : ", ", "xyz"[axis]);
  }
  if (!missing.empty()) {
    out->warnings.push_back(absl::StrFormat(
        "ferraris: no full turn about the vertical found with the %s axis up; turn the robot "
        "once around on the table with that axis up, still before and after",
        missing));
  }
}

// Marks a pose that repeats the previous one without a re-placement: same up direction and no
// rotation between them (a pose split in two by a bump, or a placement that was never made). Of
// the two, the longer stays: never a short fragment over the long rest beside it.
// A revisit after other poses is a new, independent placement and stays in.
// "Turned" is the path angle: after a full turn the orientation is the same but the robot was
// turned (a Ferraris turn), and across a time gap the turn is unknown, so never a duplicate.
void MarkDuplicates(const Capture& cap, const GyroParams& gyro, const TimeGaps& gaps,
                    const std::vector<Eigen::Vector3d>& ups, std::vector<StaticInterval>* ivs) {
  int previous = -1;
  for (size_t i = 0; i < ivs->size(); ++i) {
    if (!(*ivs)[i].used) continue;
    if (previous >= 0) {
      const size_t p = static_cast<size_t>(previous);
      const double angle = AngleBetweenDeg(ups[i], ups[p]);
      // Without a gyroscope a re-placement in the same orientation cannot be told from none:
      // the poses count as one, which loses a repeat but never double-counts a rest.
      const double turned =
          cap.has_gyro ? PathAngle(cap, (*ivs)[p].end - 1, (*ivs)[i].begin, gyro) * kRadToDeg : 0.0;
      if (angle < kDuplicateDeg && turned < kNotTurnedDeg &&
          gaps.In((*ivs)[p].end - 1, (*ivs)[i].begin) < 0) {
        const bool keep_this = (*ivs)[i].samples() > (*ivs)[p].samples();
        StaticInterval& dropped = (*ivs)[keep_this ? p : i];
        const StaticInterval& kept = (*ivs)[keep_this ? i : p];
        dropped.used = false;
        dropped.issue = IntervalIssue::kDuplicate;
        dropped.reason = absl::StrFormat(
            "duplicate of pose %d (%.1f-%.1f s, held longer): the same orientation within %.1f "
            "degrees, turned %.0f degrees between them; place the robot in a new orientation",
            keep_this ? static_cast<int>(i) : previous, kept.t_start_s, kept.t_end_s, angle,
            turned);
        if (!keep_this) continue;
      }
    }
    previous = static_cast<int>(i);
  }
}

bool OnlyFaces(const std::vector<Eigen::Vector3d>& ups) {
  for (const Eigen::Vector3d& up : ups)
    if (ClassifyFace(up).off_axis_deg > kFaceToleranceDeg) return false;
  return true;
}

}  // namespace

ProtocolChecks CheckProtocol(const Capture& cap, const CalibrateOptions& opt, const StaticPoses& sp,
                             const RoughGyro& rough) {
  ProtocolChecks out;
  out.intervals = sp.intervals;
  const std::vector<StaticInterval>& ivs = out.intervals;
  out.ups.assign(ivs.size(), Eigen::Vector3d::Zero());
  for (size_t i = 0; i < ivs.size(); ++i)
    out.ups[i] = sp.rough_accel.Apply(ivs[i].accel_mean).normalized();
  const std::vector<int> used = UsedIndices(ivs);
  std::vector<Eigen::Vector3d> used_ups;
  for (int i : used) used_ups.push_back(out.ups[static_cast<size_t>(i)]);
  out.protocol = opt.protocol;
  if (opt.protocol == ProtocolKind::kAuto) {
    out.protocol = DetectProtocol(used_ups);
    out.detected = true;
    // Ferraris: the six faces, not paired, and full turns. Faces: the six faces, not paired,
    // and no pose off them.
    if (out.protocol != ProtocolKind::kSixFace && CoversSixFaces(used_ups)) {
      if (!rough.turns.empty()) {
        out.protocol = ProtocolKind::kFerraris;
      } else if (OnlyFaces(used_ups)) {
        out.protocol = ProtocolKind::kFaces;
      }
    }
  }
  if (out.protocol == ProtocolKind::kSixFace)
    CheckPairs(cap, ivs, used, sp.gaps, rough.params, &out);
  if (out.protocol == ProtocolKind::kFerraris && cap.has_gyro)
    CheckFerrarisTurns(rough.turns, &out);
  for (std::string& w : RepeatedOrientations(cap, ivs, out.ups))
    out.warnings.push_back(std::move(w));
  MarkDuplicates(cap, rough.params, sp.gaps, out.ups, &out.intervals);
  return out;
}

FaceReferences VerifiedFaces(const std::vector<StaticInterval>& ivs,
                             const std::vector<PairCheck>& pairs,
                             const std::vector<Eigen::Vector3d>& ups, double g) {
  FaceReferences out;
  for (const PairCheck& p : pairs) {
    if (!p.ok) continue;
    out.means.push_back(0.5 * (ivs[static_cast<size_t>(p.pose_a)].accel_mean +
                               ivs[static_cast<size_t>(p.pose_b)].accel_mean));
    out.refs.push_back(ClassifyFace(ups[static_cast<size_t>(p.pose_a)]).Reference(g));
  }
  return out;
}

FaceReferences SingleFaces(const std::vector<StaticInterval>& ivs, const std::vector<int>& used,
                           const std::vector<Eigen::Vector3d>& ups, double g) {
  FaceReferences out;
  std::vector<Eigen::Vector3d> used_ups;
  for (int i : used) used_ups.push_back(ups[static_cast<size_t>(i)]);
  const auto placements = FacePlacements(used_ups);
  for (size_t f = 0; f < 6; ++f) {
    if (placements[f].empty()) continue;
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (int k : placements[f])
      mean += ivs[static_cast<size_t>(used[static_cast<size_t>(k)])].accel_mean;
    Eigen::Vector3d ref = Eigen::Vector3d::Zero();
    ref(static_cast<int>(f / 2)) = f % 2 == 0 ? g : -g;
    out.means.push_back(mean / static_cast<double>(placements[f].size()));
    out.refs.push_back(ref);
  }
  return out;
}

Eigen::Vector3d FrameAngles(const AccelParams& accel, const FaceReferences& faces) {
  AccelParams frame_free = accel;
  frame_free.frame_angles.setZero();
  std::vector<Eigen::Vector3d> out;
  for (const auto& m : faces.means) out.push_back(frame_free.Apply(m));
  const Eigen::AngleAxisd aa(BestFitRotation(out, faces.refs));
  return aa.angle() * aa.axis();
}

Eigen::Vector3d PairFaceAxis(const PairCheck& p, const Eigen::Vector3d& a,
                             const Eigen::Vector3d& b) {
  return p.rotation_rad.isZero() ? (a + b).normalized()
                                 : PairTurnAxis(a.normalized(), b.normalized(), p.rotation_rad);
}

Eigen::Matrix3d SetCaseFrameFromPairAxes(const std::vector<PairCheck>& pairs, double g,
                                         const std::function<Eigen::Vector3d(int)>& frame_free,
                                         AccelParams* accel) {
  std::vector<Eigen::Vector3d> out, refs;
  for (const PairCheck& p : pairs) {
    if (!p.ok) continue;
    const Eigen::Vector3d axis = PairFaceAxis(p, frame_free(p.pose_a), frame_free(p.pose_b));
    out.push_back(g * axis);
    refs.push_back(ClassifyFace(axis).Reference(g));
  }
  const Eigen::AngleAxisd aa(BestFitRotation(out, refs));
  const Eigen::Vector3d angles = aa.angle() * aa.axis();
  const Eigen::Matrix3d R_new_old =
      ExpSo3<double>(angles) * ExpSo3<double>(accel->frame_angles).transpose();
  accel->frame_angles = angles;
  return R_new_old;
}

}  // namespace imucal::core::pipeline
