#include "core/calibrate.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>

#include "Eigen/Dense"
#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "core/allan.h"
#include "core/gyro_solver.h"
#include "core/validation.h"

namespace imucal::core {
namespace {

constexpr double kRadToDeg = 180.0 / M_PI;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Quality gates (verdict). A few mg is what a field calibration of a MEMS unit should reach;
// a gravity-direction error above a degree after a move ruins a heading within minutes.
constexpr double kAccelPassRms = 0.02;  // m/s^2, about 2 mg
constexpr double kAccelFailRms = 0.05;  // m/s^2, about 5 mg
constexpr double kMovePassDeg = 1.0;
constexpr double kMoveFailDeg = 5.0;
// Two poses whose up directions agree within this are the same orientation (not a new pose).
constexpr double kDuplicateDeg = 2.0;
// ... and a move that turned less than this (along its path) did not re-place the robot.
constexpr double kNotTurnedDeg = 10.0;
// A time gap: an interval between samples over this many median intervals (as the importers
// note it). The gyroscope was not recorded across it.
constexpr double kGapFactor = 3.0;
// Full turns (Ferraris et al. 1995): the ends' up directions agree within kTurnSameUpDeg; the
// path is about one axis in one direction (|integral of rate| / integral of |rate| at least
// kTurnSingleAxis: a wobble of a few degrees keeps it above 0.95, a there-and-back move is near
// 0); its angle is within an eighth of a turn of whole turns with the rough gyroscope (whose
// nominal scale is good to a few percent); and its axis is vertical (then known in the body
// frame: the up direction) when within kTurnVerticalDeg of up.
constexpr double kTurnSameUpDeg = 5.0;
constexpr double kTurnSingleAxis = 0.9;
constexpr double kTurnAngleToleranceRad = M_PI / 4;
constexpr double kTurnVerticalDeg = 15.0;
// A move whose gravity direction changed by more than the gyroscope turned (1.25x its path
// angle plus 5 degrees, room for a rough scale off by 20 %) cannot be one recording: a cut.
constexpr double kCutPathFactor = 1.25;
constexpr double kCutSlackDeg = 5.0;
// The fewest well-spread poses for bias and scale alone (6 parameters, one spare).
constexpr size_t kBiasScalePoses = 7;

double AngleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return kRadToDeg * std::atan2(a.cross(b).norm(), a.dot(b));
}

std::vector<AccelPose> ToAccelPoses(const std::vector<StaticInterval>& ivs,
                                    const std::vector<int>& used, const NoiseLevel& noise) {
  std::vector<AccelPose> out;
  out.reserve(used.size());
  for (int i : used) {
    const StaticInterval& s = ivs[static_cast<size_t>(i)];
    AccelPose p;
    p.mean = s.accel_mean;
    p.mean_std =
        s.accel_std.cwiseMax(noise.accel_std) / std::sqrt(static_cast<double>(s.samples()));
    out.push_back(p);
  }
  return out;
}

std::vector<int> UsedIndices(const std::vector<StaticInterval>& ivs) {
  std::vector<int> out;
  for (size_t i = 0; i < ivs.size(); ++i)
    if (ivs[i].used) out.push_back(static_cast<int>(i));
  return out;
}

AccelMask LinearMask() {
  AccelMask m{};
  for (int i = 0; i < 9; ++i) m[static_cast<size_t>(i)] = true;
  return m;
}

AccelMask BiasScaleMask() {
  AccelMask m{};
  for (int i = 0; i < 6; ++i) m[static_cast<size_t>(i)] = true;
  return m;
}

// What the poses of one threshold can determine, best first.
enum class SweepTier {
  kNone = 0,
  kBiasScale = 1,  // 7+ poses, every axis up and down: bias and scale (6 parameters)
  kFaces = 2,      // the six faces: the affine model from the face references (ferraris)
  kFull = 3,       // 10+ poses on an ellipsoid: the full model
};

// One threshold multiplier of the sweep, scored by its leave-one-pose-out (PRESS) error within
// the best tier any multiplier reaches.
struct SweepResult {
  double multiplier = 0;
  std::vector<StaticInterval> intervals;
  AccelParams accel;
  double press = std::numeric_limits<double>::infinity();
  size_t poses = 0;
  SweepTier tier = SweepTier::kNone;
  bool escalated = false;  // found only above the usual multipliers
};

SweepResult ScoreMultiplier(const Capture& cap, const MotionSignal& motion, const NoiseLevel& noise,
                            const CalibrateOptions& opt, double m, size_t* most_poses) {
  SweepResult out;
  out.multiplier = m;
  const double g = cap.gravity_m_s2;
  std::vector<StaticInterval> ivs = DetectStatic(cap, motion, noise, m, opt.detector);
  const std::vector<AccelPose> poses = ToAccelPoses(ivs, UsedIndices(ivs), noise);
  *most_poses = std::max(*most_poses, poses.size());
  out.poses = poses.size();
  if (poses.size() >= 10) {
    const auto e = FitEllipsoid(poses, g);
    if (e.ok()) {
      out.accel = RefineAccelGaussNewton(*e, poses, g, LinearMask(), 10);
      out.press = PressRms(out.accel, poses, g, LinearMask());
      out.tier = SweepTier::kFull;
      out.intervals = std::move(ivs);
      return out;
    }
  }
  const auto a = FitAxisEllipsoid(poses, g);
  if (!a.ok()) return out;
  out.accel = RefineAccelGaussNewton(*a, poses, g, BiasScaleMask(), 10);
  std::vector<Eigen::Vector3d> ups;
  for (const AccelPose& p : poses) ups.push_back(out.accel.Apply(p.mean).normalized());
  if (CoversSixFaces(ups)) {
    out.tier = SweepTier::kFaces;
  } else if (poses.size() >= kBiasScalePoses) {
    out.tier = SweepTier::kBiasScale;
  } else {
    return out;
  }
  // With as many poses as parameters PRESS is undefined: the lowest such multiplier is kept.
  out.press = poses.size() > 6 ? PressRms(out.accel, poses, g, BiasScaleMask())
                               : std::numeric_limits<double>::max();
  if (!std::isfinite(out.press)) out.press = std::numeric_limits<double>::max();
  out.intervals = std::move(ivs);
  return out;
}

SweepResult SweepThreshold(const Capture& cap, const MotionSignal& motion, const NoiseLevel& noise,
                           const CalibrateOptions& opt, size_t* most_poses) {
  SweepResult best;
  auto consider = [&](const std::vector<double>& multipliers, bool escalated) {
    for (double m : multipliers) {
      SweepResult r = ScoreMultiplier(cap, motion, noise, opt, m, most_poses);
      r.escalated = escalated;
      if (r.tier > best.tier ||
          (r.tier == best.tier && r.tier != SweepTier::kNone && r.press < best.press)) {
        best = std::move(r);
      }
    }
  };
  consider(opt.multipliers, false);
  if (best.tier < SweepTier::kFaces) consider(opt.escalation_multipliers, true);
  return best;
}

// Time gaps of the capture: the sample index after each gap.
std::vector<size_t> FindTimeGaps(const Capture& cap) {
  std::vector<size_t> out;
  const double limit = kGapFactor * cap.MedianDt();
  if (!(limit > 0)) return out;
  for (size_t i = 1; i < cap.size(); ++i)
    if (cap.t_s[i] - cap.t_s[i - 1] > limit) out.push_back(i);
  return out;
}

// The first gap inside samples [begin, end] (a gap between samples i-1 and i with
// begin < i <= end), or -1.
long GapIn(const std::vector<size_t>& gaps, size_t begin, size_t end) {
  for (size_t i : gaps)
    if (i > begin && i <= end) return static_cast<long>(i);
  return -1;
}

std::string DescribeGap(const Capture& cap, size_t i) {
  return absl::StrFormat("a time gap of %.3f s at %.3f s", cap.t_s[i] - cap.t_s[i - 1],
                         cap.t_s[i - 1]);
}

// Body rotation (rotation vector, rad) over samples [begin, end] with the calibrated gyro.
Eigen::Vector3d IntegrateRotation(const Capture& cap, size_t begin, size_t end,
                                  const GyroParams& gyro) {
  Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
  for (size_t k = begin; k < end; ++k) {
    const Eigen::Vector3d w = 0.5 * gyro.matrix * (cap.gyro[k] + cap.gyro[k + 1] - 2 * gyro.bias);
    r = r * ExpSo3<double>(w * (cap.t_s[k + 1] - cap.t_s[k]));
  }
  const Eigen::AngleAxisd aa(r);
  return aa.angle() * aa.axis();
}

std::vector<GyroMove> MovesBetween(const std::vector<StaticInterval>& ivs,
                                   const std::vector<int>& used, const AccelParams& accel) {
  std::vector<GyroMove> moves;
  for (size_t k = 0; k + 1 < used.size(); ++k) {
    const StaticInterval& a = ivs[static_cast<size_t>(used[k])];
    const StaticInterval& b = ivs[static_cast<size_t>(used[k + 1])];
    GyroMove m;
    m.begin = a.end - 1;
    m.end = b.begin;
    m.up_before = accel.Apply(a.accel_mean).normalized();
    m.up_after = accel.Apply(b.accel_mean).normalized();
    m.bias_before = a.gyro_mean;
    m.bias_after = b.gyro_mean;
    moves.push_back(m);
  }
  return moves;
}

// Sample-weighted mean of the static gyro readings: the constant bias of the model.
Eigen::Vector3d StaticGyroBias(const std::vector<StaticInterval>& ivs,
                               const std::vector<int>& used) {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  double n = 0;
  for (int i : used) {
    const StaticInterval& s = ivs[static_cast<size_t>(i)];
    sum += s.gyro_mean * static_cast<double>(s.samples());
    n += static_cast<double>(s.samples());
  }
  return n > 0 ? Eigen::Vector3d(sum / n) : Eigen::Vector3d::Zero();
}

struct GyroStage {
  GyroParams params;
  bool calibrated = false;
  std::optional<GyroSolveResult> result;
  std::vector<std::string> warnings;
};

// A move between two used poses as the gyroscope fit sees it (from_pose/to_pose index ivs).
struct PlannedMove {
  int from_pose = 0, to_pose = 0;
  GyroMove move;
};

// Integral of |rate| (rad, with `gyro`) over samples [begin, end]: the path angle.
double PathAngle(const Capture& cap, size_t begin, size_t end, const GyroParams& gyro) {
  double sum = 0;
  for (size_t k = begin; k < end; ++k) {
    sum += (0.5 * gyro.matrix * (cap.gyro[k] + cap.gyro[k + 1] - 2 * gyro.bias)).norm() *
           (cap.t_s[k + 1] - cap.t_s[k]);
  }
  return sum;
}

// The moves between consecutive used poses that the gyroscope can be fitted on: a move across a
// time gap integrates over missing data, and a move whose gravity direction turned further than
// the gyroscope measured along its whole path was cut (its samples are not one recording). Those
// are left out, with a warning when `warnings` is not null. `rough` may be null (no cut check).
std::vector<PlannedMove> PlanMoves(const Capture& cap, const std::vector<StaticInterval>& ivs,
                                   const std::vector<int>& used, const AccelParams& accel,
                                   const std::vector<size_t>& gaps, const GyroParams* rough,
                                   std::vector<std::string>* warnings) {
  std::vector<PlannedMove> out;
  const std::vector<GyroMove> moves = MovesBetween(ivs, used, accel);
  for (size_t k = 0; k < moves.size(); ++k) {
    const GyroMove& m = moves[k];
    const long gap = GapIn(gaps, m.begin, m.end);
    if (gap >= 0) {
      if (warnings)
        warnings->push_back(absl::StrFormat(
            "move from pose %d to pose %d left out of the gyroscope fit: %s; the rotation "
            "across it was not recorded",
            used[k], used[k + 1], DescribeGap(cap, static_cast<size_t>(gap))));
      continue;
    }
    if (rough != nullptr) {
      const double tilt = AngleDeg(m.up_before, m.up_after);
      const double path = PathAngle(cap, m.begin, m.end, *rough) * kRadToDeg;
      if (tilt > kCutPathFactor * path + kCutSlackDeg) {
        if (warnings)
          warnings->push_back(absl::StrFormat(
              "move from pose %d to pose %d (%.2f-%.2f s) left out of the gyroscope fit: "
              "gravity turned %.0f degrees but the gyroscope only %.0f; the data is cut there "
              "(samples removed, or parts of a session joined)",
              used[k], used[k + 1], cap.t_s[m.begin], cap.t_s[m.end], tilt, path));
        continue;
      }
    }
    out.push_back(PlannedMove{used[k], used[k + 1], m});
  }
  return out;
}

std::vector<GyroMove> OnlyMoves(const std::vector<PlannedMove>& planned) {
  std::vector<GyroMove> out;
  for (const PlannedMove& p : planned) out.push_back(p.move);
  return out;
}

// A full-turn candidate: its samples, end up directions and raw integral.
struct TurnCandidate {
  GyroFullTurn turn;
  Eigen::Vector3d up = Eigen::Vector3d::UnitZ();           // mean of the two ends' up directions
  Eigen::Vector3d raw_integral = Eigen::Vector3d::Zero();  // sum of c_k, input unit * s
};

// Candidates for full turns, from the scale-free conditions: between two still stretches of
// the capture (anchors: a turn's ends need to be still, not long, so any detected interval that
// did not move or saturate), the same up direction at both ends, no time gap, and a path about
// one axis in one direction. The angle is checked once the scale is known (AcceptTurns).
std::vector<TurnCandidate> FindTurnCandidates(const Capture& cap,
                                              const std::vector<StaticInterval>& anchors,
                                              const AccelParams& accel, const Eigen::Vector3d& bias,
                                              const std::vector<size_t>& gaps) {
  std::vector<TurnCandidate> out;
  std::vector<const StaticInterval*> still;
  for (const StaticInterval& s : anchors)
    if (s.used || absl::StartsWith(s.reason, "too short")) still.push_back(&s);
  GyroSolveOptions go;
  go.bias = bias;
  for (size_t i = 0; i + 1 < still.size(); ++i) {
    const StaticInterval& a = *still[i];
    const StaticInterval& b = *still[i + 1];
    TurnCandidate c;
    c.turn.begin = a.end - 1;
    c.turn.end = b.begin;
    c.turn.bias_before = c.turn.bias_after = bias;
    if (c.turn.begin >= c.turn.end || GapIn(gaps, c.turn.begin, c.turn.end) >= 0) continue;
    const Eigen::Vector3d ua = accel.Apply(a.accel_mean).normalized();
    const Eigen::Vector3d ub = accel.Apply(b.accel_mean).normalized();
    if (AngleDeg(ua, ub) > kTurnSameUpDeg) continue;
    c.raw_integral = IntegrateRawTurn(cap.t_s, cap.gyro, c.turn, go);
    double path = 0;
    for (size_t k = c.turn.begin; k < c.turn.end; ++k)
      path += (0.5 * (cap.gyro[k] + cap.gyro[k + 1]) - bias).norm() * (cap.t_s[k + 1] - cap.t_s[k]);
    if (!c.raw_integral.allFinite() || !(path > 0) ||
        c.raw_integral.norm() < kTurnSingleAxis * path)
      continue;
    c.up = (ua + ub).normalized();
    out.push_back(c);
  }
  return out;
}

// Keeps the candidates whose angle with `scale` (rad/s per input unit, isotropic) is whole turns,
// sets their angle and axis, and describes them for the report. A turn about the vertical has
// its axis known in the body frame: +-up, the sign from the rate (a positive scale: the gyro's
// axes are assumed to point along the accelerometer's, which a turn about the vertical alone
// cannot check).
std::vector<TurnCandidate> AcceptTurns(const Capture& cap, std::vector<TurnCandidate> candidates,
                                       double scale, std::vector<TurnReport>* report) {
  std::vector<TurnCandidate> out;
  for (TurnCandidate& c : candidates) {
    const Eigen::Vector3d v = scale * c.raw_integral;
    const double angle = v.norm();
    const int k = static_cast<int>(std::lround(angle / (2 * M_PI)));
    if (k < 1 || std::abs(angle - 2 * M_PI * k) > kTurnAngleToleranceRad) continue;
    c.turn.angle_rad = 2 * M_PI * k;
    TurnReport tr;
    tr.t_start_s = cap.t_s[c.turn.begin];
    tr.t_end_s = cap.t_s[c.turn.end];
    tr.turns = k;
    if (AngleDeg(v, c.up) <= kTurnVerticalDeg || AngleDeg(v, -c.up) <= kTurnVerticalDeg) {
      c.turn.axis = v.dot(c.up) >= 0 ? c.up : Eigen::Vector3d(-c.up);
      const Face f = ClassifyFace(c.turn.axis);
      tr.axis = absl::StrFormat("%c%s (vertical)", "xyz"[f.axis], f.sign > 0 ? "" : " negative");
    } else {
      tr.axis = "unknown (not vertical)";
    }
    tr.axis_body = c.turn.axis;
    report->push_back(tr);
    out.push_back(std::move(c));
  }
  return out;
}

// The rough gyroscope for the pair, duplicate and turn checks, which tolerate a few percent of
// scale error: the nominal factor, or for raw counts an isotropic scale from the data: the
// moves' (EstimateIsotropicScale on the moves that are one recording), else the full turns'
// (each turn taken as one).
GyroParams RoughGyro(const Capture& cap, const std::vector<StaticInterval>& ivs,
                     const std::vector<int>& used, const AccelParams& accel,
                     const std::vector<size_t>& gaps,
                     const std::vector<TurnCandidate>& turn_candidates) {
  GyroParams g;
  g.bias = StaticGyroBias(ivs, used);
  const double nominal = NominalGyroToSi(cap.gyro_unit);
  double scale = nominal;
  if (std::isnan(nominal)) {
    GyroSolveOptions go;
    go.bias = g.bias;
    go.interpolate_bias = true;
    std::vector<GyroMove> moves =
        OnlyMoves(PlanMoves(cap, ivs, used, accel, gaps, nullptr, nullptr));
    if (!turn_candidates.empty()) {
      std::vector<double> s;
      for (const TurnCandidate& c : turn_candidates) s.push_back(2 * M_PI / c.raw_integral.norm());
      std::nth_element(s.begin(), s.begin() + static_cast<long>(s.size() / 2), s.end());
      GyroParams by_turns = g;
      by_turns.matrix = Eigen::Matrix3d::Identity() * s[s.size() / 2];
      scale = by_turns.matrix(0, 0);
      moves = OnlyMoves(PlanMoves(cap, ivs, used, accel, gaps, &by_turns, nullptr));
    }
    if (moves.size() >= 3 || turn_candidates.empty()) {
      const double from_moves = EstimateIsotropicScale(cap.t_s, cap.gyro, moves, go);
      if (std::isfinite(from_moves)) scale = from_moves;
    }
  }
  g.matrix = Eigen::Matrix3d::Identity() * (std::isfinite(scale) ? scale : 1.0);
  return g;
}

GyroStage SolveGyro(const Capture& cap, const std::vector<StaticInterval>& ivs,
                    const std::vector<PlannedMove>& planned,
                    const std::vector<TurnCandidate>& turns, const Eigen::Vector3d& bias,
                    const GyroParams& rough) {
  GyroStage out;
  out.params = rough;
  out.params.bias = bias;
  const double nominal = NominalGyroToSi(cap.gyro_unit);
  const std::vector<GyroMove> moves = OnlyMoves(planned);
  std::vector<GyroFullTurn> full_turns;
  for (const TurnCandidate& c : turns) full_turns.push_back(c.turn);
  GyroSolveOptions go;
  go.bias = out.params.bias;
  // Each move uses the bias measured at the poses on either side of it (a drifting bias is
  // followed); the stored model keeps the constant mean bias.
  go.interpolate_bias = true;
  go.initial_matrix = rough.matrix;
  (void)ivs;
  auto r = moves.size() >= 3 || !full_turns.empty()
               ? SolveGyroFromMovesAndTurns(cap.t_s, cap.gyro, moves, full_turns, go)
               : absl::StatusOr<GyroSolveResult>(
                     absl::FailedPreconditionError("fewer than 3 moves between static poses"));
  if (!r.ok()) {
    out.warnings.push_back(absl::StrFormat(
        "gyroscope: only the bias was calibrated (%s). Scale and misalignment need rotations "
        "between static poses, or a full turn about each axis%s",
        r.status().message(),
        std::isnan(nominal) ? "; the gyro is in raw counts, so its output stays in counts" : ""));
    if (std::isnan(nominal)) out.params.matrix.setIdentity();
    return out;
  }
  if (r->rank_deficient) {
    // A matrix the moves do not determine is not a calibration: keep the nominal (or, for
    // counts, isotropic) factor and say what would determine the rest.
    std::string which;
    for (const auto& u : r->undetermined) which += (which.empty() ? "" : "; ") + u;
    out.warnings.push_back(absl::StrFormat(
        "gyroscope: only the bias was calibrated, the moves do not determine the scale and "
        "misalignment (%s); turn the robot about each of its three axes between poses",
        which));
    return out;
  }
  out.params.matrix = r->matrix;
  out.calibrated = !r->rank_deficient;
  out.result = std::move(*r);
  return out;
}

double Max(const std::vector<double>& v) {
  double m = 0;
  for (double x : v)
    if (std::isfinite(x)) m = std::max(m, std::abs(x));
  return m;
}

double RmsFinite(const std::vector<double>& v) {
  std::vector<double> f;
  for (double x : v)
    if (std::isfinite(x)) f.push_back(x);
  return f.empty() ? kNaN : Rms(f);
}

std::vector<double> ToDeg(const std::vector<double>& rad) {
  std::vector<double> out;
  for (double x : rad) out.push_back(x * kRadToDeg);
  return out;
}

// Marks a pose that repeats the previous one without a re-placement: same up direction and no
// rotation between them (a pose split in two by a bump, or a placement that was never made).
// A revisit after other poses is a new, independent placement and stays in.
// "Turned" is the path angle: after a full turn the orientation is the same but the robot was
// turned (a Ferraris turn), and across a time gap the turn is unknown, so never a duplicate.
void MarkDuplicates(const Capture& cap, const GyroParams& gyro, std::vector<StaticInterval>* ivs,
                    const std::vector<Eigen::Vector3d>& ups, const std::vector<size_t>& gaps) {
  int previous = -1;
  for (size_t i = 0; i < ivs->size(); ++i) {
    if (!(*ivs)[i].used) continue;
    if (previous >= 0) {
      const StaticInterval& p = (*ivs)[static_cast<size_t>(previous)];
      const double angle = AngleDeg(ups[i], ups[static_cast<size_t>(previous)]);
      const double turned = PathAngle(cap, p.end - 1, (*ivs)[i].begin, gyro) * kRadToDeg;
      if (angle < kDuplicateDeg && turned < kNotTurnedDeg &&
          GapIn(gaps, p.end - 1, (*ivs)[i].begin) < 0) {
        (*ivs)[i].used = false;
        (*ivs)[i].reason = absl::StrFormat(
            "duplicate of pose %d (same orientation within %.1f degrees, turned %.0f degrees "
            "since); place the robot in a new orientation",
            previous, angle, turned);
        continue;
      }
    }
    previous = static_cast<int>(i);
  }
}

// The six-face references: pair-averaged face readings (raw) and +-g on the face axis.
struct FaceReferences {
  std::vector<Eigen::Vector3d> means, refs;
};
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

// Ferraris: each face held once (or more, averaged per face) against +-g on the face axis. No
// pair cancels the floor tilt: it stays in the misalignment angles.
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

// The covariance of the affine face fit's 12 magnitude parameters, when the poses are too few
// for the |a| = g refinement: the residual of the 3 n face equations (n faces, 12 unknowns) gives
// their variance, mapped through the fit by finite differences of the references.
AccelMatrix AffineFitCovariance(const FaceReferences& faces, const AccelParams& fit,
                                double* chi2_per_dof) {
  AccelMatrix cov = AccelMatrix::Constant(kNaN);
  const int n = static_cast<int>(faces.means.size());
  const int dof = 3 * n - 12;
  double ss = 0;
  for (int i = 0; i < n; ++i)
    ss += (fit.Apply(faces.means[static_cast<size_t>(i)]) - faces.refs[static_cast<size_t>(i)])
              .squaredNorm();
  *chi2_per_dof = dof > 0 ? ss / dof : kNaN;
  if (dof <= 0) return cov;
  const double h = 1e-4;
  Eigen::MatrixXd jac(kAccelParams, 3 * n);
  const AccelVector base = PackAccel(fit);
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < 3; ++j) {
      FaceReferences plus = faces;
      plus.refs[static_cast<size_t>(i)](j) += h;
      auto p = FitKnownReferences(plus.means, plus.refs);
      if (!p.ok()) return cov;
      jac.col(3 * i + j) = (PackAccel(*p) - base) / h;
    }
  }
  cov = *chi2_per_dof * jac * jac.transpose();
  return cov;
}

// Six-face stage 1 (seeds/000): the affine least-squares fit to the verified faces.
absl::StatusOr<AccelParams> FitVerifiedFaces(const FaceReferences& faces) {
  if (faces.means.size() < 6) {
    return absl::FailedPreconditionError(
        absl::StrFormat("only %d of 6 faces have a verified 180-degree pair",
                        static_cast<int>(faces.means.size())));
  }
  return FitKnownReferences(faces.means, faces.refs);
}

// The case frame for the final model: the rotation that best maps its frame-free output of the
// verified faces onto +-g (Kabsch), so frame_angles agree with the refined scale and angles.
Eigen::Vector3d FrameAngles(const AccelParams& accel, const FaceReferences& faces) {
  AccelParams frame_free = accel;
  frame_free.frame_angles.setZero();
  std::vector<Eigen::Vector3d> out;
  for (const auto& m : faces.means) out.push_back(frame_free.Apply(m));
  const Eigen::AngleAxisd aa(BestFitRotation(out, faces.refs));
  return aa.angle() * aa.axis();
}

// A verified pair's face direction (unit) from its two poses' specific forces `a` and `b`: the
// axis the unit was turned about (core/protocol.h PairTurnAxis, from the turn the calibrated
// gyroscope measured) instead of the pair's mean, which a turn of 180 + e degrees on a floor
// tilted by t leaves t * e / 2 off. A pair whose turn was not measured keeps its mean.
Eigen::Vector3d PairFaceAxis(const PairCheck& p, const Eigen::Vector3d& a,
                             const Eigen::Vector3d& b) {
  return p.rotation_rad.isZero() ? (a + b).normalized()
                                 : PairTurnAxis(a.normalized(), b.normalized(), p.rotation_rad);
}

// The case frame as FrameAngles, with each verified pair's face direction its PairFaceAxis.
// `frame_free(i)` is the specific force of pose i (an index of ivs) in the model's frame-free
// output.
Eigen::Vector3d TurnAxisFrameAngles(const std::vector<PairCheck>& pairs, double g,
                                    const std::function<Eigen::Vector3d(int)>& frame_free) {
  std::vector<Eigen::Vector3d> out, refs;
  for (const PairCheck& p : pairs) {
    if (!p.ok) continue;
    const Eigen::Vector3d axis = PairFaceAxis(p, frame_free(p.pose_a), frame_free(p.pose_b));
    out.push_back(g * axis);
    refs.push_back(ClassifyFace(axis).Reference(g));
  }
  const Eigen::AngleAxisd aa(BestFitRotation(out, refs));
  return aa.angle() * aa.axis();
}

// A pose's calibrated specific force (m/s^2) with the applied accelerometer effects taken out at
// its own signals (its mean temperature, its middle's time since `t0_s`), as the SDK's
// Corrector would give it.
Eigen::Vector3d CorrectedSpecificForce(const AccelParams& accel, const std::vector<Effect>& effects,
                                       const StaticInterval& s, double t0_s) {
  Eigen::Vector3d a = accel.Apply(s.accel_mean);
  SignalArray sig{};
  sig[static_cast<size_t>(Signal::kTemperature)] = s.temp_mean;
  sig[static_cast<size_t>(Signal::kTime)] = 0.5 * (s.t_start_s + s.t_end_s) - t0_s;
  for (int k = 0; k < 3; ++k) sig[static_cast<size_t>(Signal::kAx) + k] = a(k);
  for (const Effect& e : effects) {
    const std::optional<Regressor> r = ParseRegressor(e.regressor);
    if (e.sensor == Sensor::kAccel && e.applied && r) a(e.axis) -= e.coefficient * r->Evaluate(sig);
  }
  return a;
}

// Turns the gyroscope's output frame by `d` (new body = d * old body): its matrix and its
// coupling to specific force (which is in the body frame on both sides).
void TurnGyroParams(const Eigen::Matrix3d& d, GyroParams* gyro) {
  gyro->matrix = d * gyro->matrix;
  gyro->accel_coupling = d * gyro->accel_coupling * d.transpose();
}

// Turns the gyroscope's output frame by `d` (new body = d * old body) with the accelerometer's:
// TurnGyroParams, the fit's matrix and covariance (vec(d M) = (I kron d) vec(M)) and, unless
// null, the moves' up directions. Every move residual stays as it was. A covariance with
// undetermined (NaN) entries is left as it is: the frame moves by under a milliradian, far below
// what those entries' neighbours are known to.
void TurnGyroFrame(const Eigen::Matrix3d& d, GyroStage* gyro, std::vector<PlannedMove>* planned) {
  TurnGyroParams(d, &gyro->params);
  if (gyro->result) {
    gyro->result->matrix = d * gyro->result->matrix;
    Eigen::Matrix<double, 9, 9> k = Eigen::Matrix<double, 9, 9>::Zero();
    for (int c = 0; c < 3; ++c) k.block<3, 3>(3 * c, 3 * c) = d;
    if (gyro->result->covariance.allFinite())
      gyro->result->covariance = k * gyro->result->covariance * k.transpose();
  }
  if (planned == nullptr) return;
  for (PlannedMove& m : *planned) {
    m.move.up_before = d * m.move.up_before;
    m.move.up_after = d * m.move.up_after;
  }
}

AccelVector StageOneUnits(const AccelParams& p, const std::vector<AccelPose>& poses,
                          const AccelMask& free) {
  // One BSAS unit = the stage-1 standard error of the parameter (seeds/002 needs parameters of
  // similar magnitude; standard errors make every coordinate equally uncertain).
  const Eigen::MatrixXd j = MagnitudeJacobian(p, poses);
  const std::vector<double> sigma = MagnitudeSigmas(p, poses);
  Eigen::MatrixXd jw = j;
  for (Eigen::Index i = 0; i < jw.rows(); ++i) jw.row(i) /= sigma[static_cast<size_t>(i)];
  AccelVector unit = AccelVector::Ones();
  std::vector<int> idx;
  for (int c = 0; c < kAccelParams; ++c)
    if (free[static_cast<size_t>(c)]) idx.push_back(c);
  Eigen::MatrixXd info(idx.size(), idx.size());
  for (size_t a = 0; a < idx.size(); ++a)
    for (size_t b = 0; b < idx.size(); ++b)
      info(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b)) =
          jw.col(idx[a]).dot(jw.col(idx[b]));
  const Eigen::MatrixXd cov =
      info.ldlt().solve(Eigen::MatrixXd::Identity(info.rows(), info.cols()));
  for (size_t a = 0; a < idx.size(); ++a) {
    const double s =
        std::sqrt(std::abs(cov(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(a))));
    if (std::isfinite(s) && s > 0) unit(idx[a]) = s;
  }
  return unit;
}

// Backward elimination of the quadratic terms by leave-one-pose-out (PRESS) error: the full
// 15-parameter model is the default, and a term is dropped only where leaving it out predicts
// held-out poses better. With few poses at intermediate angles a second-order term fits noise
// (the Xsens capture's quadratic_x does); where it is real, dropping it biases that axis' bias.
AccelMask SelectQuadratics(const AccelParams& start, const std::vector<AccelPose>& poses, double g,
                           const AccelMask& determined, std::vector<std::string>* notes) {
  AccelMask mask = determined;
  auto press = [&](const AccelMask& m) {
    return PressRms(RefineAccelGaussNewton(start, poses, g, m, 10), poses, g, m);
  };
  // Only a term within two standard errors of zero may go: a significant one is kept even if
  // PRESS, itself noisy with a few dozen poses, would prefer the smaller model.
  const AccelParams full = RefineAccelGaussNewton(start, poses, g, mask, 10);
  const AccelVector se = AccelStdErrors(full, poses, mask);
  double best = press(mask);
  for (;;) {
    int drop = -1;
    double drop_press = best;
    for (int c = 9; c < 12; ++c) {
      if (!mask[static_cast<size_t>(c)]) continue;
      if (std::abs(PackAccel(full)(c)) > 2 * se(c)) continue;
      AccelMask trial = mask;
      trial[static_cast<size_t>(c)] = false;
      const double p = press(trial);
      if (p < drop_press) drop = c, drop_press = p;
    }
    if (drop < 0) break;
    mask[static_cast<size_t>(drop)] = false;
    best = drop_press;
  }
  for (int c = 9; c < 12; ++c) {
    if (determined[static_cast<size_t>(c)] && !mask[static_cast<size_t>(c)]) {
      notes->push_back(absl::StrFormat(
          "accel %s: held at 0; it is within two standard errors of zero and leaving it out "
          "predicts held-out poses better "
          "(add poses with that axis about 45 degrees from vertical to resolve it)",
          AccelParamName(c)));
    }
  }
  return mask;
}

// Sets every pose's common model error to the one the residual of `p` shows.
void SetModelSigma(const AccelParams& p, double g, const AccelMask& free,
                   std::vector<AccelPose>* poses) {
  int n_free = 0;
  for (bool f : free) n_free += f;
  const double tau = EstimateModelSigma(p, *poses, g, n_free);
  for (auto& pose : *poses) pose.model_sigma_m_s2 = tau;
}

// The gravity-direction error after each reported move with its signals, for the effects'
// examination of the rotation residuals (core/effects.h ExamineMoveResiduals).
std::vector<EffectMoveResidual> MoveResiduals(const Capture& cap,
                                              const std::vector<StaticInterval>& ivs,
                                              const std::vector<MoveReport>& moves) {
  const double t0 = cap.t_s.empty() ? 0.0 : cap.t_s.front();
  std::vector<EffectMoveResidual> out;
  for (const MoveReport& m : moves) {
    if (!std::isfinite(m.error_deg)) continue;
    const StaticInterval& a = ivs[static_cast<size_t>(m.from_pose)];
    const StaticInterval& b = ivs[static_cast<size_t>(m.to_pose)];
    EffectMoveResidual mr;
    mr.error_rad = m.error_deg / kRadToDeg;
    mr.rotation_rad = m.rotation_deg / kRadToDeg;
    mr.time_s = 0.5 * (a.t_end_s + b.t_start_s) - t0;
    mr.temp_c = 0.5 * (a.temp_mean + b.temp_mean);
    out.push_back(mr);
  }
  return out;
}

// Runs the effect search on the used poses and, when it adds effects, puts its refitted model,
// effects and residuals into the report.
absl::Status SearchEffects(const Capture& cap, const std::vector<StaticInterval>& ivs,
                           const std::vector<int>& used, const std::vector<AccelPose>& poses,
                           const AccelMask& free, bool gyro_si,
                           const std::vector<PlannedMove>& planned, const GyroStage& gyro,
                           const EffectSearchOptions& opt, CalibrationReport* rep) {
  EffectSearchInput in;
  in.gravity_m_s2 = cap.gravity_m_s2;
  in.accel = rep->params.accel;
  in.accel_free = free;
  in.gyro = rep->params.gyro;
  in.gyro_output_si = gyro_si;
  const double t0 = cap.t_s.empty() ? 0.0 : cap.t_s.front();
  for (size_t k = 0; k < used.size(); ++k) {
    const StaticInterval& s = ivs[static_cast<size_t>(used[k])];
    EffectPose p;
    p.pose_index = used[k];
    p.accel = poses[k];
    p.gyro_mean = s.gyro_mean;
    p.gyro_mean_std = s.gyro_std / std::sqrt(static_cast<double>(std::max<size_t>(1, s.samples())));
    p.temp_c = s.temp_mean;
    p.time_s = 0.5 * (s.t_start_s + s.t_end_s) - t0;
    in.poses.push_back(p);
  }
  in.moves = MoveResiduals(cap, ivs, rep->moves);
  // The rotations between poses, for the accelerometer candidates the search weighs (|a| - g
  // cannot tell every one apart): the gyroscope refitted (as in step 8) to the pose directions
  // each candidate gives; core/effects.h, THE MOVES.
  if (gyro.calibrated && planned.size() >= 3) {
    std::vector<std::pair<size_t, size_t>> ends;  // per planned move: its poses' index in `used`
    for (const PlannedMove& m : planned) {
      const auto from = std::find(used.begin(), used.end(), m.from_pose);
      const auto to = std::find(used.begin(), used.end(), m.to_pose);
      if (from == used.end() || to == used.end())
        return absl::InternalError("move off the used poses");
      ends.emplace_back(from - used.begin(), to - used.begin());
    }
    in.move_fit = [&cap, &planned, &gyro,
                   ends](const std::vector<Eigen::Vector3d>& up) -> std::optional<MoveFit> {
      std::vector<GyroMove> moves;
      for (size_t k = 0; k < planned.size(); ++k) {
        GyroMove m = planned[k].move;
        m.up_before = up[ends[k].first];
        m.up_after = up[ends[k].second];
        moves.push_back(m);
      }
      GyroSolveOptions go;
      go.bias = gyro.params.bias;
      go.interpolate_bias = true;
      go.initial_matrix = gyro.params.matrix;
      go.compute_heldout = false;
      const absl::StatusOr<GyroSolveResult> r = SolveGyroFromMoves(cap.t_s, cap.gyro, moves, go);
      if (!r.ok() || r->rank_deficient) return std::nullopt;
      return MoveFit{r->move_error_rad};
    };
  }
  absl::StatusOr<EffectSearchResult> res = FindEffects(in, opt);
  if (!res.ok()) return res.status();
  rep->effect_diagnostics = std::move(res->diagnostics);
  if (res->effects.empty()) return absl::OkStatus();
  ParamSet& ps = rep->params;
  ps.accel = res->accel;
  ps.gyro = res->gyro;
  ps.effects = std::move(res->effects);
  AccelVector se = res->accel_covariance.diagonal().cwiseSqrt();
  for (int c = 0; c < kAccelParams; ++c)
    if (!free[static_cast<size_t>(c)]) se(c) = kNaN;
  ps.stderrs.accel = UnpackAccel(se, ps.stderrs.accel.frame_angles);
  // Residuals of the model as stored (with its applied effects).
  std::vector<double> after;
  double gyro_ss = 0;
  for (const EffectPoseRow& row : rep->effect_diagnostics.rows) {
    after.push_back(row.accel_after_m_s2);
    gyro_ss += row.gyro_after_rad_s.squaredNorm();
    for (PoseReport& pr : rep->poses)
      if (pr.index == row.pose_index) pr.residual_m_s2 = row.accel_after_m_s2;
  }
  rep->residual.accel_rms_m_s2 = Rms(after);
  rep->residual.accel_max_m_s2 = Max(after);
  rep->residual.gyro_static_rms_rad_s = std::sqrt(gyro_ss / std::max<size_t>(1, after.size()));
  if (std::isfinite(rep->effect_diagnostics.accel_heldout_after_m_s2))
    rep->residual.accel_heldout_rms_m_s2 = rep->effect_diagnostics.accel_heldout_after_m_s2;
  ps.quality_accel_rms_m_s2 = rep->residual.accel_rms_m_s2;
  ps.quality_gyro_static_rms_rad_s = rep->residual.gyro_static_rms_rad_s;
  StageReport st;
  st.name = "effects";
  st.accel_rms_m_s2 = rep->residual.accel_rms_m_s2;
  st.iterations = rep->effect_diagnostics.rounds;
  for (const EffectPoseRow& row : rep->effect_diagnostics.rows) {
    st.pose_indices.push_back(row.pose_index);
    st.pose_residual_m_s2.push_back(row.accel_after_m_s2);
  }
  rep->stages.push_back(st);
  return absl::OkStatus();
}

// The gyroscope fit's figures in the report: each move's error (in-sample and held out) and
// rotation, their RMS and maximum, each full turn's error and integrated angle, and the matrix's
// standard errors. Replaces what an earlier fit put there.
void ReportGyroFit(const Capture& cap, const std::vector<PlannedMove>& planned,
                   const std::vector<TurnCandidate>& turns, const GyroStage& gyro,
                   CalibrationReport* rep) {
  rep->moves.clear();
  rep->residual.move_rms_deg = rep->residual.move_max_deg = kNaN;
  rep->residual.move_heldout_rms_deg = rep->residual.move_heldout_max_deg = kNaN;
  for (TurnReport& t : rep->turns) t.error_deg = kNaN;
  if (gyro.result) {
    const auto& gr = *gyro.result;
    rep->residual.move_rms_deg = Rms(gr.move_error_rad) * kRadToDeg;
    rep->residual.move_max_deg = Max(gr.move_error_rad) * kRadToDeg;
    if (!gr.heldout_error_rad.empty()) {
      rep->residual.move_heldout_rms_deg = RmsFinite(gr.heldout_error_rad) * kRadToDeg;
      rep->residual.move_heldout_max_deg = Max(gr.heldout_error_rad) * kRadToDeg;
    }
    const std::vector<double> in = ToDeg(gr.move_error_rad), out = ToDeg(gr.heldout_error_rad);
    for (size_t k = 0; k < planned.size() && k < in.size(); ++k) {
      MoveReport m;
      m.from_pose = planned[k].from_pose;
      m.to_pose = planned[k].to_pose;
      m.error_deg = in[k];
      if (k < out.size()) m.heldout_error_deg = out[k];
      m.rotation_deg =
          IntegrateRotation(cap, planned[k].move.begin, planned[k].move.end, gyro.params).norm() *
          kRadToDeg;
      rep->moves.push_back(m);
    }
    for (size_t k = 0; k < rep->turns.size() && k < gr.turn_error_rad.size(); ++k)
      rep->turns[k].error_deg = gr.turn_error_rad[k] * kRadToDeg;
    for (int c = 0; c < 9; ++c)
      rep->params.stderrs.gyro_matrix(c % 3, c / 3) = std::sqrt(gr.covariance(c, c));
  } else {
    rep->params.stderrs.gyro_matrix.setConstant(kNaN);
  }
  // Each turn's integrated angle with the final gyroscope (only when its output is in rad/s).
  if (gyro.calibrated || !std::isnan(NominalGyroToSi(cap.gyro_unit))) {
    for (size_t k = 0; k < rep->turns.size() && k < turns.size(); ++k)
      rep->turns[k].angle_deg = (gyro.params.matrix * turns[k].raw_integral).norm() * kRadToDeg;
  }
}

// Per-axis residuals of the verified faces with the stored model and its applied effects at
// each pose's signals (as the SDK's Corrector would apply them). A face's direction is the axis
// its pair was turned about (core/protocol.h PairTurnAxis), its size the mean of the two poses'.
void FaceResiduals(const Capture& cap, const std::vector<StaticInterval>& ivs,
                   CalibrationReport* rep) {
  const double t0 = cap.t_s.empty() ? 0.0 : cap.t_s.front();
  for (const PairCheck& p : rep->pairs) {
    if (!p.ok) continue;
    const Eigen::Vector3d a = CorrectedSpecificForce(rep->params.accel, rep->params.effects,
                                                     ivs[static_cast<size_t>(p.pose_a)], t0);
    const Eigen::Vector3d b = CorrectedSpecificForce(rep->params.accel, rep->params.effects,
                                                     ivs[static_cast<size_t>(p.pose_b)], t0);
    // The mean of the two sizes: the mean vector is shorter by cos(tilt), 0.15 mg at 1 degree.
    const Eigen::Vector3d axis = PairFaceAxis(p, a, b);
    const Eigen::Vector3d face = 0.5 * (a.norm() + b.norm()) * axis;
    const Face f = ClassifyFace(axis);
    rep->effect_diagnostics.faces.push_back({f.Label(), face - f.Reference(cap.gravity_m_s2)});
  }
}

std::string Verdict(const CalibrationReport& r, bool degraded) {
  const double move = r.residual.move_rms_deg;
  if (r.residual.accel_rms_m_s2 > kAccelFailRms || (std::isfinite(move) && move > kMoveFailDeg))
    return "fail";
  if (degraded || r.residual.accel_rms_m_s2 > kAccelPassRms ||
      (std::isfinite(move) && move > kMovePassDeg))
    return "warn";
  return "pass";
}

// Appends the time since the previous mark to report->phase_ms.
class PhaseTimer {
 public:
  explicit PhaseTimer(CalibrationReport* report) : report_(report) {}
  void Mark(const char* name) {
    const auto now = std::chrono::steady_clock::now();
    report_->phase_ms.emplace_back(name, 1e3 * std::chrono::duration<double>(now - last_).count());
    last_ = now;
  }

 private:
  CalibrationReport* report_;
  std::chrono::steady_clock::time_point last_ = std::chrono::steady_clock::now();
};

}  // namespace

absl::StatusOr<CalibrationReport> Calibrate(const Capture& cap, const CalibrateOptions& opt) {
  const auto t0 = std::chrono::steady_clock::now();
  if (absl::Status s = ValidateCapture(cap); !s.ok()) return s;
  CalibrationReport rep;
  PhaseTimer timer(&rep);
  rep.device = cap.device;
  rep.gravity_m_s2 = cap.gravity_m_s2;
  const double g = cap.gravity_m_s2;

  // 1. Noise and static intervals.
  const MotionSignal motion = ComputeMotionSignal(cap, opt.detector);
  rep.noise = EstimateNoise(cap, motion);
  size_t most_poses = 0;
  SweepResult sweep = SweepThreshold(cap, motion, rep.noise, opt, &most_poses);
  if (sweep.tier == SweepTier::kNone) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "too few static poses: found at most %d usable, the accelerometer needs at least 10 "
        "distinct orientations held still for %.1f s or more (bias and scale alone: at least %d, "
        "with every axis pointing up and down; or the six faces once each and full turns, the "
        "ferraris protocol)",
        static_cast<int>(most_poses), opt.detector.min_static_s,
        static_cast<int>(kBiasScalePoses)));
  }
  rep.threshold_multiplier = sweep.multiplier;
  timer.Mark("static");
  std::vector<StaticInterval>& ivs = sweep.intervals;
  if (sweep.escalated) {
    double ratio = 0;
    for (const StaticInterval& s : ivs)
      if (s.used) ratio = std::max(ratio, s.gyro_std.norm() / rep.noise.gyro_std.norm());
    rep.warnings.push_back(absl::StrFormat(
        "static poses: the usual thresholds (up to %g x the rest's noise variance) found too few "
        "still poses, so the threshold was raised to %g x: the poses shake more than the rest "
        "(gyro std up to %.0f x the rest's), as when the robot is held by hand. Their means are "
        "still used; place the robot on a support for a tighter calibration",
        opt.multipliers.empty() ? 0.0 : opt.multipliers.back(), sweep.multiplier, ratio));
  }
  const std::vector<size_t> gaps = FindTimeGaps(cap);
  for (size_t i = 0; i < ivs.size(); ++i) {
    const long gap = GapIn(gaps, ivs[i].begin, ivs[i].end - 1);
    if (gap >= 0 && ivs[i].used) {
      rep.warnings.push_back(absl::StrFormat(
          "pose %d (%.2f-%.2f s) spans %s: its means stay valid, nothing is integrated across it",
          static_cast<int>(i), ivs[i].t_start_s, ivs[i].t_end_s,
          DescribeGap(cap, static_cast<size_t>(gap))));
    }
  }

  // 2. Rough gyroscope (for pair, duplicate and turn checks), from the sweep's accelerometer,
  // and the full turns (Ferraris), whose ends need only be still, not long: they are looked for
  // between the intervals of the loosest threshold.
  std::vector<int> used = UsedIndices(ivs);
  std::vector<StaticInterval> anchors = DetectStatic(
      cap, motion, rep.noise,
      std::max(sweep.multiplier, opt.multipliers.empty() ? 0.0 : opt.multipliers.back()),
      opt.detector);
  const Eigen::Vector3d static_bias = StaticGyroBias(ivs, used);
  std::vector<TurnCandidate> turn_candidates =
      FindTurnCandidates(cap, anchors, sweep.accel, static_bias, gaps);
  const GyroParams rough_gyro = RoughGyro(cap, ivs, used, sweep.accel, gaps, turn_candidates);
  const std::vector<TurnCandidate> turns =
      AcceptTurns(cap, std::move(turn_candidates), rough_gyro.matrix(0, 0), &rep.turns);
  timer.Mark("gyro_rough");
  std::vector<Eigen::Vector3d> ups(ivs.size(), Eigen::Vector3d::Zero());
  for (size_t i = 0; i < ivs.size(); ++i)
    ups[i] = sweep.accel.Apply(ivs[i].accel_mean).normalized();

  // 3. Protocol and its checks.
  std::vector<Eigen::Vector3d> used_ups;
  for (int i : used) used_ups.push_back(ups[static_cast<size_t>(i)]);
  rep.protocol = opt.protocol;
  if (opt.protocol == ProtocolKind::kAuto) {
    rep.protocol = DetectProtocol(used_ups);
    rep.protocol_detected = true;
    // Ferraris: the six faces, not paired, and full turns.
    if (rep.protocol != ProtocolKind::kSixFace && !turns.empty() && CoversSixFaces(used_ups))
      rep.protocol = ProtocolKind::kFerraris;
  }
  if (rep.protocol == ProtocolKind::kSixFace) {
    std::vector<FacePose> fps;
    for (size_t k = 0; k < used.size(); ++k) {
      FacePose fp;
      fp.index = used[k];
      fp.up = ups[static_cast<size_t>(used[k])];
      if (k > 0) {
        const size_t begin = ivs[static_cast<size_t>(used[k - 1])].end - 1;
        const size_t end = ivs[static_cast<size_t>(used[k])].begin;
        fp.rotation_from_previous = IntegrateRotation(cap, begin, end, rough_gyro);
        const long gap = GapIn(gaps, begin, end);
        if (gap >= 0) {
          fp.rotation_known = false;
          rep.warnings.push_back(
              absl::StrFormat("the turn from pose %d to pose %d was not checked: %s", used[k - 1],
                              used[k], DescribeGap(cap, static_cast<size_t>(gap))));
        }
      }
      fps.push_back(fp);
    }
    SixFaceCheck check = CheckSixFacePairs(fps);
    rep.pairs = check.pairs;
    for (const auto& p : rep.pairs)
      if (!p.ok)
        rep.warnings.push_back(absl::StrFormat("pair of poses %d and %d (%s) rejected: %s",
                                               p.pose_a, p.pose_b, p.face, p.reason));
    for (const auto& m : check.missing) rep.warnings.push_back(m);
  }
  if (rep.protocol == ProtocolKind::kFerraris) {
    std::string missing;
    for (int axis = 0; axis < 3; ++axis) {
      bool found = false;
      for (const TurnCandidate& t : turns)
        found |= t.turn.axis.squaredNorm() > 0 && ClassifyFace(t.turn.axis).axis == axis;
      if (!found) missing += absl::StrFormat("%s%c", missing.empty() ? "" : ", ", "xyz"[axis]);
    }
    if (!missing.empty()) {
      rep.warnings.push_back(absl::StrFormat(
          "ferraris: no full turn about the vertical found with the %s axis up; turn the robot "
          "once around on the table with that axis up, still before and after",
          missing));
    }
  }
  MarkDuplicates(cap, rough_gyro, &ivs, ups, gaps);
  used = UsedIndices(ivs);
  std::vector<AccelPose> poses = ToAccelPoses(ivs, used, rep.noise);
  timer.Mark("protocol");

  // 4. Accelerometer stage 1: linear least squares.
  auto s1_time = std::chrono::steady_clock::now();
  absl::StatusOr<AccelParams> s1 = absl::UnknownError("unset");
  FaceReferences faces;
  if (rep.protocol == ProtocolKind::kSixFace) {
    faces = VerifiedFaces(ivs, rep.pairs, ups, g);
    s1 = FitVerifiedFaces(faces);
    if (!s1.ok()) {
      rep.warnings.push_back("six-face least squares not possible (" +
                             std::string(s1.status().message()) +
                             "); used the ellipsoid fit instead, frame alignment unknown");
    }
  } else if (rep.protocol == ProtocolKind::kFerraris) {
    faces = SingleFaces(ivs, used, ups, g);
    s1 = faces.means.size() == 6
             ? FitKnownReferences(faces.means, faces.refs)
             : absl::StatusOr<AccelParams>(absl::FailedPreconditionError(absl::StrFormat(
                   "only %d of the 6 faces placed", static_cast<int>(faces.means.size()))));
    if (s1.ok()) {
      rep.warnings.push_back(
          "ferraris: each face was held once, without the 180-degree pair, so the floor's tilt "
          "is not cancelled: it stays in the misalignment and frame angles (about 17 mrad per "
          "degree of tilt), while bias and scale err only by 1 - cos(tilt) (0.015 % at 1 "
          "degree). Hold each face again turned 180 degrees about the vertical (six-face) to "
          "cancel it");
    } else {
      rep.warnings.push_back("ferraris: face least squares not possible (" +
                             std::string(s1.status().message()) +
                             "); used the ellipsoid fit instead, frame alignment unknown");
    }
  }
  const bool s1_from_faces = s1.ok();
  bool bias_scale_only = false;
  if (!s1.ok()) s1 = FitEllipsoid(poses, g);
  if (!s1.ok() && poses.size() >= kBiasScalePoses) {
    // Too few poses for the full model: the largest one they determine.
    s1 = FitAxisEllipsoid(poses, g);
    if (s1.ok()) {
      bias_scale_only = true;
      *s1 = RefineAccelGaussNewton(*s1, poses, g, BiasScaleMask(), 20);
      rep.warnings.push_back(absl::StrFormat(
          "accelerometer: only bias and scale were calibrated (6 of 12 parameters): %d poses "
          "cannot determine the misalignment angles t_yx, t_zx, t_zy and the second-order terms, "
          "held at 0. Add poses to reach at least 10 distinct orientations, some with gravity "
          "between two axes (45 degrees)",
          static_cast<int>(poses.size())));
    }
  }
  if (!s1.ok()) return s1.status();
  StageReport ls;
  ls.name = "ls";
  ls.iterations = 1;
  ls.accel_rms_m_s2 = Rms(MagnitudeResiduals(*s1, poses, g));
  ls.ms = 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - s1_time).count();
  ls.pose_indices = used;
  ls.pose_residual_m_s2 = MagnitudeResiduals(*s1, poses, g);
  rep.stages.push_back(ls);

  // The model error beyond each pose's noise joins the weights (accel_solver.h). Stage 1 lacks
  // the second-order terms, so its misfit overstates it: it is measured again at each refit.
  SetModelSigma(*s1, g, LinearMask(), &poses);

  // 5. What the poses determine; undetermined parameters stay at neutral values.
  AccelMask all{};
  all.fill(true);
  if (bias_scale_only) all = BiasScaleMask();
  AccelObservability obs = AnalyseAccelObservability(*s1, poses, g, all);
  // Six-face: at axis-aligned poses the non-orthogonality angles reach |a| only at second order
  // (through the floor's tilt), but the face references of stage 1 (seeds/000) determine them
  // at first order. An angle stays at its stage-1 value, held fixed, when |a| = g on these
  // poses is nearly blind to it: less than a hundredth of the faces' information (its standard
  // error over ten times theirs). On a plain six-face capture |a| = g may "determine" an angle
  // to 0.015 rad (15 mg across the axis) where the faces give 1e-4 rad (a ratio near 100), and
  // refining on it only fits noise. A few extra poses between the axes bring the ratio to 2-5:
  // then holding the angle against what |a| = g says pushes the misfit into the weakly
  // determined second-order terms, which trade off against the biases (k g^2 on a face), so
  // the angle is refined as before.
  AccelMask held_by_faces{};
  if (s1_from_faces) {
    double faces_chi2 = kNaN;
    const AccelMatrix faces_cov = AffineFitCovariance(faces, *s1, &faces_chi2);
    AccelMask candidates = all;
    for (int c = 6; c < 9; ++c) {
      const size_t k = static_cast<size_t>(c);
      const double faces_sigma = std::sqrt(faces_cov(c, c));
      const bool faces_better = std::isfinite(faces_sigma) && 10 * faces_sigma < obs.sigma(c);
      held_by_faces[k] = !obs.determined[k] || faces_better;
      candidates[k] = !held_by_faces[k];
      if (!obs.determined[k]) {
        rep.warnings.push_back(absl::StrFormat(
            "accel %s: set by the six-face references (stage 1); |a| = g alone does not "
            "determine it, so later stages hold it",
            AccelParamName(c)));
      } else if (faces_better) {
        rep.warnings.push_back(absl::StrFormat(
            "accel %s: set by the six-face references (stage 1, +-%.2g rad), which determine "
            "it far better than |a| = g on these poses (+-%.2g rad); later stages hold it. "
            "Poses with gravity between two axes would let |a| = g refine it",
            AccelParamName(c), faces_sigma, obs.sigma(c)));
      }
    }
    obs = AnalyseAccelObservability(*s1, poses, g, candidates);
  }
  for (const auto& w : obs.warnings) rep.warnings.push_back(w);

  // The face references alone, when the poses are too few to refine |a| = g on (ferraris with
  // each face once: 6 poses for 6 parameters): the affine fit is the result.
  int n_determined = 0;
  for (bool d : obs.determined) n_determined += d;
  const bool affine_only = s1_from_faces && static_cast<int>(poses.size()) <= n_determined;

  // 6. Second-order terms stay unless leaving them out predicts held-out poses better.
  AccelMask free = obs.determined;
  if (!affine_only) {
    SetModelSigma(RefineAccelGaussNewton(*s1, poses, g, obs.determined, 10), g, obs.determined,
                  &poses);
    free = SelectQuadratics(*s1, poses, g, obs.determined, &rep.warnings);
  }

  // 7. BSAS, then LM.
  // Undetermined second-order terms and angles are held at their neutral value, 0: a stage-1
  // value the data does not support would be a confident number it cannot back.
  AccelVector s1_vector = PackAccel(*s1);
  for (int c = 6; c < kAccelParams; ++c)
    if (!obs.determined[static_cast<size_t>(c)] && !held_by_faces[static_cast<size_t>(c)])
      s1_vector(c) = 0;
  *s1 = UnpackAccel(s1_vector, s1->frame_angles);
  AccelParams start = *s1;
  absl::StatusOr<LmResult> lm = absl::UnknownError("unset");
  if (affine_only) {
    LmResult affine;
    affine.params = *s1;
    double chi2 = kNaN;
    affine.covariance = AffineFitCovariance(faces, *s1, &chi2);
    // Its standard errors cover the face-set angles too.
    for (int c = 6; c < 9; ++c)
      free[static_cast<size_t>(c)] |= held_by_faces[static_cast<size_t>(c)];
    affine.chi2_reduced = chi2;
    lm = affine;
    rep.warnings.push_back(absl::StrFormat(
        "accelerometer: %d poses leave nothing to refine |a| = g on; the result is the face "
        "references' least-squares fit (seeds/000), its standard errors from the faces' residual",
        static_cast<int>(poses.size())));
  } else {
    if (opt.use_bsas) {
      StageReport bs;
      start = RefineAccelBsas(*s1, poses, g, free, StageOneUnits(*s1, poses, free),
                              BsasStageOptions{.seed = opt.seed}, &bs);
      bs.pose_indices = used;
      bs.pose_residual_m_s2 = MagnitudeResiduals(start, poses, g);
      rep.stages.push_back(bs);
    }
    StageReport lm_report;
    lm = RefineAccelLm(start, poses, g, free, &lm_report);
    if (!lm.ok()) return lm.status();
    // The weights and the covariance with the model error of the final fit.
    SetModelSigma(lm->params, g, free, &poses);
    lm = RefineAccelLm(lm->params, poses, g, free, nullptr);
    if (!lm.ok()) return lm.status();
    lm_report.pose_indices = used;
    lm_report.pose_residual_m_s2 = MagnitudeResiduals(lm->params, poses, g);
    lm_report.accel_rms_m_s2 = Rms(lm_report.pose_residual_m_s2);
    rep.stages.push_back(lm_report);
  }
  rep.accel_chi2_reduced = lm->chi2_reduced;
  if ((rep.protocol == ProtocolKind::kSixFace || rep.protocol == ProtocolKind::kFerraris) &&
      s1_from_faces) {
    lm->params.frame_angles = FrameAngles(lm->params, faces);
  }
  AccelParams& accel = lm->params;
  timer.Mark("accel");

  // 8. Final gyroscope with the final accelerometer.
  std::vector<PlannedMove> planned =
      PlanMoves(cap, ivs, used, accel, gaps, &rough_gyro, &rep.warnings);
  GyroStage gyro = SolveGyro(cap, ivs, planned, turns, StaticGyroBias(ivs, used), rough_gyro);
  for (const auto& w : gyro.warnings) rep.warnings.push_back(w);
  timer.Mark("gyro");

  // The pairs' turns as the calibrated gyroscope measures them (the check itself ran on the
  // rough one, which its 20-degree tolerance allows), with the bias the pair's own two poses
  // read: both have the same face up, so a bias that follows the pose or the warm-up cancels.
  for (PairCheck& p : rep.pairs) {
    if (std::isnan(p.rotation_deg)) continue;  // across a time gap: not measured
    const StaticInterval& a = ivs[static_cast<size_t>(p.pose_a)];
    const StaticInterval& b = ivs[static_cast<size_t>(p.pose_b)];
    GyroParams at_pair = gyro.params;
    at_pair.bias = 0.5 * (a.gyro_mean + b.gyro_mean);
    const Eigen::Vector3d turn = IntegrateRotation(cap, a.end - 1, b.begin, at_pair);
    p.rotation_deg = turn.norm() * kRadToDeg;
    // Only a calibrated gyroscope's angle is good to the milliradians the turn axis needs.
    if (gyro.calibrated) p.rotation_rad = turn;
  }
  // 8b. The case frame from the axes the pairs were turned about, now that the gyroscope has
  // measured the turns; the gyroscope, fitted in the frame of step 7, turns with it.
  if (rep.protocol == ProtocolKind::kSixFace && s1_from_faces && gyro.calibrated) {
    AccelParams frame_free = accel;
    frame_free.frame_angles.setZero();
    const Eigen::Vector3d angles = TurnAxisFrameAngles(rep.pairs, g, [&](int i) {
      return frame_free.Apply(ivs[static_cast<size_t>(i)].accel_mean);
    });
    TurnGyroFrame(ExpSo3<double>(angles) * ExpSo3<double>(accel.frame_angles).transpose(), &gyro,
                  &planned);
    accel.frame_angles = angles;
  }

  // 8. Residuals, in-sample and held out.
  const std::vector<double> r = MagnitudeResiduals(accel, poses, g);
  rep.residual.accel_rms_m_s2 = Rms(r);
  rep.residual.accel_max_m_s2 = Max(r);
  std::vector<double> held(poses.size(), kNaN);
  if (opt.heldout && !affine_only) {
    held = HeldOutMagnitudeResiduals(accel, poses, g, free);
    if (rep.protocol == ProtocolKind::kFerraris) {
      // A face placed once cannot be predicted without it (its axis' bias and scale go with it).
      std::vector<Eigen::Vector3d> heldout_ups;
      for (int i : used) heldout_ups.push_back(ups[static_cast<size_t>(i)]);
      for (const auto& p : FacePlacements(heldout_ups))
        if (p.size() == 1) held[static_cast<size_t>(p.front())] = kNaN;
    }
    rep.residual.accel_heldout_rms_m_s2 = RmsFinite(held);
    // None predictable (too few poses beyond the model): both n/a, not a max of 0.
    rep.residual.accel_heldout_max_m_s2 =
        std::isfinite(rep.residual.accel_heldout_rms_m_s2) ? Max(held) : kNaN;
  }
  timer.Mark("heldout");
  double gyro_ss = 0;
  for (int i : used) {
    const StaticInterval& s = ivs[static_cast<size_t>(i)];
    gyro_ss += (gyro.params.matrix * (s.gyro_mean - gyro.params.bias)).squaredNorm();
  }
  rep.residual.gyro_static_rms_rad_s = used.empty() ? 0 : std::sqrt(gyro_ss / used.size());
  ReportGyroFit(cap, planned, turns, gyro, &rep);

  // 9. Poses for the report.
  for (size_t i = 0, k = 0; i < ivs.size(); ++i) {
    PoseReport pr;
    pr.index = static_cast<int>(i);
    pr.interval = ivs[i];
    pr.up = accel.Apply(ivs[i].accel_mean).normalized();
    const Face f = ClassifyFace(pr.up);
    if (f.off_axis_deg <= kFaceToleranceDeg) pr.face = f.Label();
    if (ivs[i].used) {
      pr.residual_m_s2 = r[k];
      pr.heldout_m_s2 = held[k];
      ++k;
    }
    rep.poses.push_back(pr);
  }

  // 10. The parameter set.
  ParamSet& ps = rep.params;
  ps.device = cap.device;
  ps.accel_unit = cap.accel_unit;
  ps.gyro_unit = cap.gyro_unit;
  ps.gravity_m_s2 = g;
  ps.accel = accel;
  ps.gyro = gyro.params;
  ps.gyro_calibrated = gyro.calibrated;
  const AccelVector se = lm->covariance.diagonal().cwiseSqrt();
  AccelVector se_or_nan = se;
  for (int c = 0; c < kAccelParams; ++c)
    if (!free[static_cast<size_t>(c)]) se_or_nan(c) = kNaN;
  ps.stderrs.accel = UnpackAccel(se_or_nan, Eigen::Vector3d::Constant(s1_from_faces ? kNaN : 0.0));
  // Gyro bias standard error from the scatter of the pose means (includes slow drift).
  if (used.size() >= 2) {
    Eigen::Vector3d ss = Eigen::Vector3d::Zero();
    for (int i : used) ss += (ivs[static_cast<size_t>(i)].gyro_mean - gyro.params.bias).cwiseAbs2();
    ps.stderrs.gyro_bias =
        (ss / static_cast<double>(used.size() - 1) / static_cast<double>(used.size())).cwiseSqrt();
  }
  ps.quality_accel_rms_m_s2 = rep.residual.accel_rms_m_s2;
  ps.quality_gyro_static_rms_rad_s = rep.residual.gyro_static_rms_rad_s;

  timer.Mark("report");

  // Noise figures (Allan deviation) of the longest used static interval, core/allan.h.
  if (auto na = NoiseFromLongestInterval(cap, ivs, ps); na.ok()) {
    ps.noise = std::move(na->figures);
    rep.allan = std::move(na->curves);
  }

  // 11. Close the loop: effects the residual shows, added and refitted jointly.
  // (Not with the face references alone: no pose is spare to test an effect on.)
  if (opt.effects.enabled && !affine_only) {
    const bool gyro_si = gyro.calibrated || !std::isnan(NominalGyroToSi(cap.gyro_unit));
    absl::Status s =
        SearchEffects(cap, ivs, used, poses, free, gyro_si, planned, gyro, opt.effects, &rep);
    if (!s.ok()) return s;
    // 11b. Applied accelerometer effects move the pose directions that steps 8 and 8b fitted the
    // case frame and the gyroscope to: both are fitted again to the corrected directions.
    bool accel_effect = false;
    for (const Effect& e : rep.params.effects)
      accel_effect |= e.sensor == Sensor::kAccel && e.applied;
    if (accel_effect && gyro.calibrated) {
      const double t0_s = cap.t_s.front();
      const auto corrected = [&](int i) {
        return CorrectedSpecificForce(rep.params.accel, rep.params.effects,
                                      ivs[static_cast<size_t>(i)], t0_s);
      };
      Eigen::Matrix3d turn = Eigen::Matrix3d::Identity();
      if (rep.protocol == ProtocolKind::kSixFace && s1_from_faces) {
        const Eigen::Matrix3d frame = ExpSo3<double>(rep.params.accel.frame_angles);
        const Eigen::Vector3d angles = TurnAxisFrameAngles(
            rep.pairs, g,
            [&](int i) -> Eigen::Vector3d { return frame.transpose() * corrected(i); });
        turn = ExpSo3<double>(angles) * frame.transpose();
        rep.params.accel.frame_angles = angles;
      }
      std::vector<PlannedMove> replanned = planned;
      for (PlannedMove& m : replanned) {
        m.move.up_before = corrected(m.from_pose).normalized();
        m.move.up_after = corrected(m.to_pose).normalized();
      }
      GyroParams initial = rep.params.gyro;
      TurnGyroParams(turn, &initial);
      GyroStage refit = SolveGyro(cap, ivs, replanned, turns, initial.bias, initial);
      if (refit.calibrated) {
        rep.params.gyro.matrix = refit.params.matrix;
        rep.params.gyro.accel_coupling = refit.params.accel_coupling;
        ReportGyroFit(cap, replanned, turns, refit, &rep);
      } else {  // keep step 8's fit, in the new frame (the moves' ups are not reported)
        GyroStage turned = gyro;
        TurnGyroFrame(turn, &turned, nullptr);
        rep.params.gyro.matrix = turned.params.matrix;
        rep.params.gyro.accel_coupling = turned.params.accel_coupling;
        ReportGyroFit(cap, planned, turns, turned, &rep);
      }
      // The rotation residuals' trends as the refitted model leaves them: what the effect
      // explained no longer shows as a trend.
      ExamineMoveResiduals(MoveResiduals(cap, ivs, rep.moves), &rep.effect_diagnostics);
    }
    if (accel_effect) {
      for (PoseReport& pr : rep.poses) {
        pr.up = CorrectedSpecificForce(rep.params.accel, rep.params.effects, pr.interval,
                                       cap.t_s.front())
                    .normalized();
        const Face f = ClassifyFace(pr.up);
        pr.face = f.off_axis_deg <= kFaceToleranceDeg ? f.Label() : "";
      }
    }
    FaceResiduals(cap, ivs, &rep);
    timer.Mark("effects");
  } else if (opt.effects.enabled) {
    rep.effect_diagnostics.notes.push_back(absl::StrFormat(
        "effects not searched: the %d poses all go into the face references' fit, none is spare "
        "to test an effect on. Place each face twice (six-face) or add poses between the faces",
        static_cast<int>(poses.size())));
  }
  // Undetermined first-order parameters degrade the verdict; undetermined second-order terms
  // do not (six-face determines seeds/000's 12-parameter model completely), but are warned of.
  bool degraded = !gyro.calibrated;
  for (int c = 0; c < 9; ++c)
    degraded |= !obs.determined[static_cast<size_t>(c)] && !held_by_faces[static_cast<size_t>(c)];
  for (const auto& p : rep.pairs) degraded |= !p.ok;
  rep.verdict = Verdict(rep, degraded);
  rep.total_ms = 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

}  // namespace imucal::core
