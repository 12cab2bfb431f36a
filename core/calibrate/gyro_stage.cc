#include "core/calibrate/gyro_stage.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "core/so3.h"
#include "util/units.h"

namespace imucal::core::pipeline {
namespace {

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

// The moves between consecutive used poses that the gyroscope can be fitted on: a move across a
// time gap integrates over missing data, and a move whose gravity direction turned further than
// the gyroscope measured along its whole path was cut (its samples are not one recording). Those
// are left out, with a warning when `warnings` is not null. `rough` may be null (no cut check).
std::vector<PlannedMove> PlanMoves(const Capture& cap, const std::vector<StaticInterval>& ivs,
                                   const std::vector<int>& used, const AccelParams& accel,
                                   const TimeGaps& gaps, const GyroParams* rough,
                                   std::vector<std::string>* warnings) {
  std::vector<PlannedMove> out;
  const std::vector<GyroMove> moves = MovesBetween(ivs, used, accel);
  for (size_t k = 0; k < moves.size(); ++k) {
    const GyroMove& m = moves[k];
    const long gap = gaps.In(m.begin, m.end);
    if (gap >= 0) {
      if (warnings)
        warnings->push_back(absl::StrFormat(
            "move from pose %d to pose %d left out of the gyroscope fit: %s; the rotation "
            "across it was not recorded",
            used[k], used[k + 1], TimeGaps::Describe(cap, static_cast<size_t>(gap))));
      continue;
    }
    if (rough != nullptr) {
      const double tilt = AngleBetweenDeg(m.up_before, m.up_after);
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

// Candidates for full turns, from the scale-free conditions: between two still stretches of
// the capture (anchors: a turn's ends need to be still, not long, so any detected interval that
// did not move or saturate), the same up direction at both ends, no time gap, and a path about
// one axis in one direction. The angle is checked once the scale is known (AcceptTurns).
std::vector<TurnCandidate> FindTurnCandidates(const Capture& cap,
                                              const std::vector<StaticInterval>& anchors,
                                              const AccelParams& accel, const Eigen::Vector3d& bias,
                                              const TimeGaps& gaps) {
  std::vector<TurnCandidate> out;
  std::vector<const StaticInterval*> still;
  for (const StaticInterval& s : anchors)
    if (s.used || s.issue == IntervalIssue::kTooShort) still.push_back(&s);
  GyroSolveOptions go;
  go.bias = bias;
  for (size_t i = 0; i + 1 < still.size(); ++i) {
    const StaticInterval& a = *still[i];
    const StaticInterval& b = *still[i + 1];
    TurnCandidate c;
    c.turn.begin = a.end - 1;
    c.turn.end = b.begin;
    c.turn.bias_before = c.turn.bias_after = bias;
    if (c.turn.begin >= c.turn.end || gaps.In(c.turn.begin, c.turn.end) >= 0) continue;
    const Eigen::Vector3d ua = accel.Apply(a.accel_mean).normalized();
    const Eigen::Vector3d ub = accel.Apply(b.accel_mean).normalized();
    if (AngleBetweenDeg(ua, ub) > kTurnSameUpDeg) continue;
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
    if (AngleBetweenDeg(v, c.up) <= kTurnVerticalDeg ||
        AngleBetweenDeg(v, -c.up) <= kTurnVerticalDeg) {
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

// The rough scale (rad/s per input unit, isotropic): the nominal factor, or for raw counts the
// moves' (EstimateIsotropicScale on the moves that are one recording), else the full turns'
// (each turn taken as one).
double RoughScale(const Capture& cap, const std::vector<StaticInterval>& ivs,
                  const std::vector<int>& used, const AccelParams& accel, const TimeGaps& gaps,
                  const std::vector<TurnCandidate>& turn_candidates, const Eigen::Vector3d& bias) {
  const double nominal = NominalGyroToSi(cap.gyro_unit);
  if (!std::isnan(nominal)) return nominal;
  double scale = nominal;
  GyroSolveOptions go;
  go.bias = bias;
  go.interpolate_bias = true;
  std::vector<GyroMove> moves = OnlyMoves(PlanMoves(cap, ivs, used, accel, gaps, nullptr, nullptr));
  if (!turn_candidates.empty()) {
    std::vector<double> s;
    for (const TurnCandidate& c : turn_candidates) s.push_back(2 * M_PI / c.raw_integral.norm());
    std::nth_element(s.begin(), s.begin() + static_cast<long>(s.size() / 2), s.end());
    GyroParams by_turns;
    by_turns.bias = bias;
    by_turns.matrix = Eigen::Matrix3d::Identity() * s[s.size() / 2];
    scale = by_turns.matrix(0, 0);
    moves = OnlyMoves(PlanMoves(cap, ivs, used, accel, gaps, &by_turns, nullptr));
  }
  if (moves.size() >= 3 || turn_candidates.empty()) {
    const double from_moves = EstimateIsotropicScale(cap.t_s, cap.gyro, moves, go);
    if (std::isfinite(from_moves)) scale = from_moves;
  }
  return scale;
}

}  // namespace

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

double PathAngle(const Capture& cap, size_t begin, size_t end, const GyroParams& gyro) {
  double sum = 0;
  for (size_t k = begin; k < end; ++k) {
    sum += (0.5 * gyro.matrix * (cap.gyro[k] + cap.gyro[k + 1] - 2 * gyro.bias)).norm() *
           (cap.t_s[k + 1] - cap.t_s[k]);
  }
  return sum;
}

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

RoughGyro EstimateRoughGyro(const Capture& cap, const CalibrateOptions& opt,
                            const StaticPoses& sp) {
  // A turn's ends need only be still, not long: they are looked for between the intervals of
  // the loosest threshold.
  const std::vector<StaticInterval> anchors =
      DetectStatic(cap, sp.motion, sp.noise,
                   std::max(sp.multiplier, opt.multipliers.empty() ? 0.0 : opt.multipliers.back()),
                   opt.detector);
  const std::vector<int> used = UsedIndices(sp.intervals);
  RoughGyro out;
  out.params.bias = StaticGyroBias(sp.intervals, used);
  std::vector<TurnCandidate> candidates =
      FindTurnCandidates(cap, anchors, sp.rough_accel, out.params.bias, sp.gaps);
  const double scale =
      RoughScale(cap, sp.intervals, used, sp.rough_accel, sp.gaps, candidates, out.params.bias);
  out.params.matrix = Eigen::Matrix3d::Identity() * (std::isfinite(scale) ? scale : 1.0);
  out.turns = AcceptTurns(cap, std::move(candidates), out.params.matrix(0, 0), &out.turn_reports);
  return out;
}

std::vector<GyroMove> OnlyMoves(const std::vector<PlannedMove>& planned) {
  std::vector<GyroMove> out;
  for (const PlannedMove& p : planned) out.push_back(p.move);
  return out;
}

GyroFit FitGyro(const Capture& cap, const std::vector<PlannedMove>& planned,
                const std::vector<TurnCandidate>& turns, const GyroParams& initial) {
  GyroFit out;
  out.params = initial;
  const double nominal = NominalGyroToSi(cap.gyro_unit);
  const std::vector<GyroMove> moves = OnlyMoves(planned);
  std::vector<GyroFullTurn> full_turns;
  for (const TurnCandidate& c : turns) full_turns.push_back(c.turn);
  GyroSolveOptions go;
  go.bias = initial.bias;
  // Each move uses the bias measured at the poses on either side of it (a drifting bias is
  // followed); the stored model keeps the constant mean bias.
  go.interpolate_bias = true;
  go.initial_matrix = initial.matrix;
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
  out.calibrated = true;
  out.result = std::move(*r);
  return out;
}

FinalGyro SolveFinalGyro(const Capture& cap, const std::vector<StaticInterval>& ivs,
                         const std::vector<int>& used, const AccelParams& accel,
                         const TimeGaps& gaps, const RoughGyro& rough) {
  FinalGyro out;
  out.planned = PlanMoves(cap, ivs, used, accel, gaps, &rough.params, &out.warnings);
  GyroParams initial = rough.params;
  initial.bias = StaticGyroBias(ivs, used);
  out.fit = FitGyro(cap, out.planned, rough.turns, initial);
  out.warnings.insert(out.warnings.end(), out.fit.warnings.begin(), out.fit.warnings.end());
  return out;
}

void MeasurePairTurns(const Capture& cap, const std::vector<StaticInterval>& ivs,
                      const GyroFit& gyro, std::vector<PairCheck>* pairs) {
  for (PairCheck& p : *pairs) {
    if (std::isnan(p.rotation_deg)) continue;  // across a time gap: not measured
    const StaticInterval& a = ivs[static_cast<size_t>(p.pose_a)];
    const StaticInterval& b = ivs[static_cast<size_t>(p.pose_b)];
    GyroParams at_pair = gyro.params;
    at_pair.bias = 0.5 * (a.gyro_mean + b.gyro_mean);
    const Eigen::Vector3d turn = IntegrateRotation(cap, a.end - 1, b.begin, at_pair);
    p.rotation_deg = turn.norm() * kRadToDeg;
    if (gyro.calibrated) p.rotation_rad = turn;
  }
}

void TurnGyroParams(const Eigen::Matrix3d& R_new_old, GyroParams* gyro) {
  gyro->matrix = R_new_old * gyro->matrix;
  gyro->accel_coupling = R_new_old * gyro->accel_coupling * R_new_old.transpose();
}

void TurnGyroFrame(const Eigen::Matrix3d& R_new_old, GyroFit* gyro,
                   std::vector<PlannedMove>* planned) {
  TurnGyroParams(R_new_old, &gyro->params);
  if (gyro->result) {
    gyro->result->matrix = R_new_old * gyro->result->matrix;
    Eigen::Matrix<double, 9, 9> k = Eigen::Matrix<double, 9, 9>::Zero();
    for (int c = 0; c < 3; ++c) k.block<3, 3>(3 * c, 3 * c) = R_new_old;
    if (gyro->result->covariance.allFinite())
      gyro->result->covariance = k * gyro->result->covariance * k.transpose();
  }
  if (planned == nullptr) return;
  for (PlannedMove& m : *planned) {
    m.move.up_before = R_new_old * m.move.up_before;
    m.move.up_after = R_new_old * m.move.up_after;
  }
}

}  // namespace imucal::core::pipeline
