#include "core/calibrate.h"

#include <chrono>
#include <cmath>
#include <limits>

#include "Eigen/Dense"
#include "absl/strings/str_format.h"
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
// ... and a move that turned less than this did not re-place the robot.
constexpr double kNotTurnedDeg = 10.0;

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
    p.mean_std = s.accel_std.cwiseMax(noise.accel_std) / std::sqrt(static_cast<double>(s.samples()));
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

// One threshold multiplier of the sweep, scored by its leave-one-pose-out (PRESS) error.
struct SweepResult {
  double multiplier = 0;
  std::vector<StaticInterval> intervals;
  AccelParams accel;
  double press = std::numeric_limits<double>::infinity();
  size_t poses = 0;
};

SweepResult SweepThreshold(const Capture& cap, const MotionSignal& motion, const NoiseLevel& noise,
                           const CalibrateOptions& opt, size_t* most_poses) {
  SweepResult best;
  const double g = cap.gravity_m_s2;
  for (double m : opt.multipliers) {
    std::vector<StaticInterval> ivs = DetectStatic(cap, motion, noise, m, opt.detector);
    const std::vector<AccelPose> poses = ToAccelPoses(ivs, UsedIndices(ivs), noise);
    *most_poses = std::max(*most_poses, poses.size());
    if (poses.size() < 10) continue;
    const auto e = FitEllipsoid(poses, g);
    if (!e.ok()) continue;
    const AccelParams fit = RefineAccelGaussNewton(*e, poses, g, LinearMask(), 10);
    const double press = PressRms(fit, poses, g, LinearMask());
    if (press < best.press) {
      best.multiplier = m;
      best.intervals = std::move(ivs);
      best.accel = fit;
      best.press = press;
      best.poses = poses.size();
    }
  }
  return best;
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

// The rough gyroscope for the pair and duplicate checks, which tolerate a few percent of scale
// error: the nominal factor, or for raw counts the isotropic scale the moves imply.
GyroParams RoughGyro(const Capture& cap, const std::vector<StaticInterval>& ivs,
                     const std::vector<int>& used, const AccelParams& accel) {
  GyroParams g;
  g.bias = StaticGyroBias(ivs, used);
  const double nominal = NominalGyroToSi(cap.gyro_unit);
  double scale = nominal;
  if (std::isnan(nominal)) {
    GyroSolveOptions go;
    go.bias = g.bias;
    go.interpolate_bias = true;
    scale = EstimateIsotropicScale(cap.t_s, cap.gyro, MovesBetween(ivs, used, accel), go);
  }
  g.matrix = Eigen::Matrix3d::Identity() * (std::isfinite(scale) ? scale : 1.0);
  return g;
}

GyroStage SolveGyro(const Capture& cap, const std::vector<StaticInterval>& ivs,
                    const std::vector<int>& used, const AccelParams& accel,
                    const GyroParams& rough) {
  GyroStage out;
  out.params = rough;
  out.params.bias = StaticGyroBias(ivs, used);
  const double nominal = NominalGyroToSi(cap.gyro_unit);
  const std::vector<GyroMove> moves = MovesBetween(ivs, used, accel);
  GyroSolveOptions go;
  go.bias = out.params.bias;
  // Each move uses the bias measured at the poses on either side of it (a drifting bias is
  // followed); the stored model keeps the constant mean bias.
  go.interpolate_bias = true;
  go.initial_matrix = rough.matrix;
  auto r = moves.size() >= 3 ? SolveGyroFromMoves(cap.t_s, cap.gyro, moves, go)
                             : absl::StatusOr<GyroSolveResult>(absl::FailedPreconditionError(
                                   "fewer than 3 moves between static poses"));
  if (!r.ok()) {
    out.warnings.push_back(absl::StrFormat(
        "gyroscope: only the bias was calibrated (%s). Scale and misalignment need rotations "
        "between static poses%s",
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
void MarkDuplicates(const Capture& cap, const GyroParams& gyro, std::vector<StaticInterval>* ivs,
                    const std::vector<Eigen::Vector3d>& ups) {
  int previous = -1;
  for (size_t i = 0; i < ivs->size(); ++i) {
    if (!(*ivs)[i].used) continue;
    if (previous >= 0) {
      const StaticInterval& p = (*ivs)[static_cast<size_t>(previous)];
      const double angle = AngleDeg(ups[i], ups[static_cast<size_t>(previous)]);
      const double turned =
          IntegrateRotation(cap, p.end - 1, (*ivs)[i].begin, gyro).norm() * kRadToDeg;
      if (angle < kDuplicateDeg && turned < kNotTurnedDeg) {
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
    const Face f = ClassifyFace(ups[static_cast<size_t>(p.pose_a)]);
    Eigen::Vector3d ref = Eigen::Vector3d::Zero();
    ref(f.axis) = f.sign * g;
    out.means.push_back(0.5 * (ivs[static_cast<size_t>(p.pose_a)].accel_mean +
                               ivs[static_cast<size_t>(p.pose_b)].accel_mean));
    out.refs.push_back(ref);
  }
  return out;
}

// Six-face stage 1 (seeds/000): the affine least-squares fit to the verified faces.
absl::StatusOr<AccelParams> FitVerifiedFaces(const FaceReferences& faces) {
  if (faces.means.size() < 6) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "only %d of 6 faces have a verified 180-degree pair", static_cast<int>(faces.means.size())));
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
    const double s = std::sqrt(std::abs(cov(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(a))));
    if (std::isfinite(s) && s > 0) unit(idx[a]) = s;
  }
  return unit;
}

// Backward elimination of the quadratic terms by leave-one-pose-out (PRESS) error: the full
// 15-parameter model is the default, and a term is dropped only where leaving it out predicts
// held-out poses better. With few poses at intermediate angles a second-order term fits noise
// (the Xsens capture's quadratic_x does); where it is real, dropping it biases that axis' bias.
AccelMask SelectQuadratics(const AccelParams& start, const std::vector<AccelPose>& poses,
                           double g, const AccelMask& determined,
                           std::vector<std::string>* notes) {
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

// Runs the effect search on the used poses and, when it adds effects, puts its refitted model,
// effects and residuals into the report.
absl::Status SearchEffects(const Capture& cap, const std::vector<StaticInterval>& ivs,
                           const std::vector<int>& used, const std::vector<AccelPose>& poses,
                           const AccelMask& free, bool gyro_si, const EffectSearchOptions& opt,
                           CalibrationReport* rep) {
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
  rep->stages.push_back(st);
  return absl::OkStatus();
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
  if (sweep.poses == 0) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "too few static poses: found at most %d usable, the accelerometer needs at least 10 "
        "distinct orientations held still for %.1f s or more",
        static_cast<int>(most_poses), opt.detector.min_static_s));
  }
  rep.threshold_multiplier = sweep.multiplier;
  timer.Mark("static");
  std::vector<StaticInterval>& ivs = sweep.intervals;

  // 2. Rough gyroscope (for pair checks), from the sweep's accelerometer.
  std::vector<int> used = UsedIndices(ivs);
  const GyroParams rough_gyro = RoughGyro(cap, ivs, used, sweep.accel);
  timer.Mark("gyro_rough");
  std::vector<Eigen::Vector3d> ups(ivs.size(), Eigen::Vector3d::Zero());
  for (size_t i = 0; i < ivs.size(); ++i) ups[i] = sweep.accel.Apply(ivs[i].accel_mean).normalized();

  // 3. Protocol and its checks.
  std::vector<Eigen::Vector3d> used_ups;
  for (int i : used) used_ups.push_back(ups[static_cast<size_t>(i)]);
  rep.protocol = opt.protocol;
  if (opt.protocol == ProtocolKind::kAuto) {
    rep.protocol = DetectProtocol(used_ups);
    rep.protocol_detected = true;
  }
  if (rep.protocol == ProtocolKind::kSixFace) {
    std::vector<FacePose> fps;
    for (size_t k = 0; k < used.size(); ++k) {
      FacePose fp;
      fp.index = used[k];
      fp.up = ups[static_cast<size_t>(used[k])];
      if (k > 0) {
        fp.rotation_from_previous = IntegrateRotation(
            cap, ivs[static_cast<size_t>(used[k - 1])].end - 1,
            ivs[static_cast<size_t>(used[k])].begin, rough_gyro);
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
  MarkDuplicates(cap, rough_gyro, &ivs, ups);
  used = UsedIndices(ivs);
  std::vector<AccelPose> poses = ToAccelPoses(ivs, used, rep.noise);
  timer.Mark("protocol");

  // 4. Accelerometer stage 1: linear least squares.
  auto s1_time = std::chrono::steady_clock::now();
  absl::StatusOr<AccelParams> s1 = absl::UnknownError("unset");
  if (rep.protocol == ProtocolKind::kSixFace) {
    s1 = FitVerifiedFaces(VerifiedFaces(ivs, rep.pairs, ups, g));
    if (!s1.ok()) {
      rep.warnings.push_back("six-face least squares not possible (" +
                             std::string(s1.status().message()) +
                             "); used the ellipsoid fit instead, frame alignment unknown");
    }
  }
  const bool s1_from_faces = s1.ok();
  if (!s1.ok()) s1 = FitEllipsoid(poses, g);
  if (!s1.ok()) return s1.status();
  StageReport ls;
  ls.name = "ls";
  ls.iterations = 1;
  ls.accel_rms_m_s2 = Rms(MagnitudeResiduals(*s1, poses, g));
  ls.ms = 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - s1_time).count();
  rep.stages.push_back(ls);

  // The model error beyond each pose's noise joins the weights (accel_solver.h). Stage 1 lacks
  // the second-order terms, so its misfit overstates it: it is measured again at each refit.
  SetModelSigma(*s1, g, LinearMask(), &poses);

  // 5. What the poses determine; undetermined parameters stay at neutral values.
  AccelMask all{};
  all.fill(true);
  AccelObservability obs = AnalyseAccelObservability(*s1, poses, g, all);
  // Six-face: at axis-aligned poses the non-orthogonality angles reach |a| only at second order,
  // but the face references of stage 1 (seeds/000) determine them. Those stay at their stage-1
  // value, held fixed, instead of being reported undetermined.
  AccelMask held_by_faces{};
  if (s1_from_faces) {
    AccelMask candidates = all;
    for (int c = 6; c < 9; ++c) {
      held_by_faces[static_cast<size_t>(c)] = !obs.determined[static_cast<size_t>(c)];
      candidates[static_cast<size_t>(c)] = obs.determined[static_cast<size_t>(c)];
      if (held_by_faces[static_cast<size_t>(c)]) {
        rep.warnings.push_back(absl::StrFormat(
            "accel %s: set by the six-face references (stage 1); |a| = g alone does not "
            "determine it, so later stages hold it",
            AccelParamName(c)));
      }
    }
    obs = AnalyseAccelObservability(*s1, poses, g, candidates);
  }
  for (const auto& w : obs.warnings) rep.warnings.push_back(w);

  // 6. Second-order terms stay unless leaving them out predicts held-out poses better.
  SetModelSigma(RefineAccelGaussNewton(*s1, poses, g, obs.determined, 10), g, obs.determined,
                &poses);
  const AccelMask free = SelectQuadratics(*s1, poses, g, obs.determined, &rep.warnings);

  // 7. BSAS, then LM.
  // Undetermined second-order terms and angles are held at their neutral value, 0: a stage-1
  // value the data does not support would be a confident number it cannot back.
  AccelVector s1_vector = PackAccel(*s1);
  for (int c = 6; c < kAccelParams; ++c)
    if (!obs.determined[static_cast<size_t>(c)] && !held_by_faces[static_cast<size_t>(c)])
      s1_vector(c) = 0;
  *s1 = UnpackAccel(s1_vector, s1->frame_angles);
  AccelParams start = *s1;
  if (opt.use_bsas) {
    StageReport bs;
    start = RefineAccelBsas(*s1, poses, g, free, StageOneUnits(*s1, poses, free),
                            BsasStageOptions{.seed = opt.seed}, &bs);
    rep.stages.push_back(bs);
  }
  StageReport lm_report;
  auto lm = RefineAccelLm(start, poses, g, free, &lm_report);
  if (!lm.ok()) return lm.status();
  // The weights and the covariance with the model error of the final fit.
  SetModelSigma(lm->params, g, free, &poses);
  lm = RefineAccelLm(lm->params, poses, g, free, nullptr);
  if (!lm.ok()) return lm.status();
  lm_report.accel_rms_m_s2 = Rms(MagnitudeResiduals(lm->params, poses, g));
  rep.stages.push_back(lm_report);
  rep.accel_chi2_reduced = lm->chi2_reduced;
  if (rep.protocol == ProtocolKind::kSixFace && s1_from_faces) {
    lm->params.frame_angles = FrameAngles(lm->params, VerifiedFaces(ivs, rep.pairs, ups, g));
  }
  const AccelParams& accel = lm->params;
  timer.Mark("accel");

  // 8. Final gyroscope with the final accelerometer.
  const GyroStage gyro = SolveGyro(cap, ivs, used, accel, rough_gyro);
  for (const auto& w : gyro.warnings) rep.warnings.push_back(w);
  timer.Mark("gyro");

  // The pairs' turn angles as the calibrated gyroscope measures them (the check itself ran on
  // the rough one, which its 20-degree tolerance allows).
  for (PairCheck& p : rep.pairs) {
    p.rotation_deg = IntegrateRotation(cap, ivs[static_cast<size_t>(p.pose_a)].end - 1,
                                       ivs[static_cast<size_t>(p.pose_b)].begin, gyro.params)
                         .norm() * kRadToDeg;
  }

  // 8. Residuals, in-sample and held out.
  const std::vector<double> r = MagnitudeResiduals(accel, poses, g);
  rep.residual.accel_rms_m_s2 = Rms(r);
  rep.residual.accel_max_m_s2 = Max(r);
  std::vector<double> held(poses.size(), kNaN);
  if (opt.heldout) {
    held = HeldOutMagnitudeResiduals(accel, poses, g, free);
    rep.residual.accel_heldout_rms_m_s2 = RmsFinite(held);
    rep.residual.accel_heldout_max_m_s2 = Max(held);
  }
  timer.Mark("heldout");
  double gyro_ss = 0;
  for (int i : used) {
    const StaticInterval& s = ivs[static_cast<size_t>(i)];
    gyro_ss += (gyro.params.matrix * (s.gyro_mean - gyro.params.bias)).squaredNorm();
  }
  rep.residual.gyro_static_rms_rad_s = used.empty() ? 0 : std::sqrt(gyro_ss / used.size());
  if (gyro.result) {
    const auto& gr = *gyro.result;
    rep.residual.move_rms_deg = Rms(gr.move_error_rad) * kRadToDeg;
    rep.residual.move_max_deg = Max(gr.move_error_rad) * kRadToDeg;
    if (!gr.heldout_error_rad.empty()) {
      rep.residual.move_heldout_rms_deg = RmsFinite(gr.heldout_error_rad) * kRadToDeg;
      rep.residual.move_heldout_max_deg = Max(gr.heldout_error_rad) * kRadToDeg;
    }
    const std::vector<double> in = ToDeg(gr.move_error_rad), out = ToDeg(gr.heldout_error_rad);
    for (size_t k = 0; k + 1 < used.size() && k < in.size(); ++k) {
      MoveReport m;
      m.from_pose = used[k];
      m.to_pose = used[k + 1];
      m.error_deg = in[k];
      if (k < out.size()) m.heldout_error_deg = out[k];
      m.rotation_deg =
          IntegrateRotation(cap, ivs[static_cast<size_t>(used[k])].end - 1,
                            ivs[static_cast<size_t>(used[k + 1])].begin, gyro.params)
              .norm() * kRadToDeg;
      rep.moves.push_back(m);
    }
  }

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
  ps.stderrs.accel = UnpackAccel(se_or_nan, Eigen::Vector3d::Constant(
                                                rep.protocol == ProtocolKind::kSixFace ? kNaN : 0.0));
  if (gyro.result) {
    for (int c = 0; c < 9; ++c) ps.stderrs.gyro_matrix(c % 3, c / 3) = std::sqrt(gyro.result->covariance(c, c));
  } else {
    ps.stderrs.gyro_matrix.setConstant(kNaN);
  }
  // Gyro bias standard error from the scatter of the pose means (includes slow drift).
  if (used.size() >= 2) {
    Eigen::Vector3d ss = Eigen::Vector3d::Zero();
    for (int i : used) ss += (ivs[static_cast<size_t>(i)].gyro_mean - gyro.params.bias).cwiseAbs2();
    ps.stderrs.gyro_bias = (ss / static_cast<double>(used.size() - 1) / static_cast<double>(used.size())).cwiseSqrt();
  }
  ps.quality_accel_rms_m_s2 = rep.residual.accel_rms_m_s2;
  ps.quality_gyro_static_rms_rad_s = rep.residual.gyro_static_rms_rad_s;

  timer.Mark("report");

  // 11. Close the loop: effects the residual shows, added and refitted jointly.
  if (opt.effects.enabled) {
    const bool gyro_si = gyro.calibrated || !std::isnan(NominalGyroToSi(cap.gyro_unit));
    absl::Status s = SearchEffects(cap, ivs, used, poses, free, gyro_si, opt.effects, &rep);
    if (!s.ok()) return s;
    timer.Mark("effects");
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
