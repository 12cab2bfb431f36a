#include "core/online_segmenter.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/protocol.h"

namespace imucal::core {
namespace {

struct SixFaceStep {
  const char* face;
  bool turn_half;
  const char* instruction;
};

// The order of seeds/000 and core/simulator.h. Body axes: x forward, y left, z up; the axis
// is named too so that a robot with another convention is still unambiguous.
constexpr std::array<SixFaceStep, OnlineSegmenter::kSixFaceSteps> kSixFace = {{
    {"Z+", false, "Lay the robot flat, top up (+Z up), and keep it still"},
    {"Z+", true, "Now turn it half a turn about the vertical, top still up, and keep it still"},
    {"Z-", false, "Turn it upside down (-Z up) and keep it still"},
    {"Z-", true, "Now turn it half a turn about the vertical, still upside down"},
    {"Y+", false, "Lay it on its right side (+Y up) and keep it still"},
    {"Y+", true, "Now turn it half a turn about the vertical, still on its right side"},
    {"Y-", false, "Lay it on its left side (-Y up) and keep it still"},
    {"Y-", true, "Now turn it half a turn about the vertical, still on its left side"},
    {"X+", false, "Stand it on its back, nose up (+X up), and keep it still"},
    {"X+", true, "Now turn it half a turn about the vertical, nose still up"},
    {"X-", false, "Stand it on its nose (-X up) and keep it still"},
    {"X-", true, "Now turn it half a turn about the vertical, still on its nose"},
}};

// The 26 directions of a cube seen from its centre: components in {-1, 0, 1}, not all zero.
struct CubeDirection {
  Eigen::Vector3d unit;
  int axes = 0;       // nonzero components: 1 face, 2 edge, 3 corner
  std::string label;  // "Z+", "X+Z+", "X+Y-Z+"
};

const std::array<CubeDirection, 26>& CubeDirections() {
  static const std::array<CubeDirection, 26> kDirections = [] {
    std::array<CubeDirection, 26> out;
    size_t n = 0;
    // Faces first, then edges, then corners, each as the six-face protocol orders its faces
    // (Z+ Z- Y+ Y- X+ X-): the order of the progress lists, and the guide's choice among
    // equally near directions.
    constexpr int kOrder[3] = {1, -1, 0};
    for (int axes = 1; axes <= 3; ++axes) {
      for (int z : kOrder) {
        for (int y : kOrder) {
          for (int x : kOrder) {
            const Eigen::Vector3d v(x, y, z);
            if ((v.array() != 0).count() != axes) continue;
            CubeDirection& d = out[n++];
            d.unit = v.normalized();
            d.axes = axes;
            for (int a = 0; a < 3; ++a)
              if (v(a) != 0)
                absl::StrAppend(&d.label, std::string(1, "XYZ"[a]), v(a) > 0 ? "+" : "-");
          }
        }
      }
    }
    return out;
  }();
  return kDirections;
}

size_t NearestDirection(const Eigen::Vector3d& up) {
  const auto& dirs = CubeDirections();
  size_t best = 0;
  for (size_t i = 1; i < dirs.size(); ++i)
    if (dirs[i].unit.dot(up) > dirs[best].unit.dot(up)) best = i;
  return best;
}

bool Wanted(GuidedProtocol protocol, const CubeDirection& d) {
  switch (protocol) {
    case GuidedProtocol::kPositions:
      return d.axes <= 2;
    case GuidedProtocol::kFree:
      return d.axes != 2;
    default:
      return false;
  }
}

int PosesWanted(GuidedProtocol protocol) {
  switch (protocol) {
    case GuidedProtocol::kSixFace:
      return OnlineSegmenter::kSixFaceSteps;
    case GuidedProtocol::kPositions:
      return 24;
    case GuidedProtocol::kFree:
      return 18;
    default:
      return 0;
  }
}

// "its nose (+X) and its top (+Z)": the body parts that point up in direction `d` (body axes:
// x forward, y left, z up).
std::string PartsUp(const CubeDirection& d) {
  static constexpr const char* kPart[3][2] = {{"tail (-X)", "nose (+X)"},
                                              {"right side (-Y)", "left side (+Y)"},
                                              {"bottom (-Z)", "top (+Z)"}};
  std::vector<std::string> parts;
  for (int a = 0; a < 3; ++a)
    if (d.unit(a) != 0) parts.push_back(absl::StrCat("its ", kPart[a][d.unit(a) > 0 ? 1 : 0]));
  if (parts.size() == 1) return parts[0];
  std::string out = parts[0];
  for (size_t i = 1; i + 1 < parts.size(); ++i) absl::StrAppend(&out, ", ", parts[i]);
  return absl::StrCat(out, " and ", parts.back());
}

// Per-axis q-quantile of a list of vectors.
Eigen::Vector3d Quantile(const std::vector<Eigen::Vector3d>& v, double q) {
  Eigen::Vector3d out = Eigen::Vector3d::Zero();
  if (v.empty()) return out;
  std::vector<double> axis(v.size());
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())));
  for (int j = 0; j < 3; ++j) {
    for (size_t i = 0; i < v.size(); ++i) axis[i] = v[i](j);
    std::nth_element(axis.begin(), axis.begin() + static_cast<long>(k), axis.end());
    out(j) = axis[k];
  }
  return out;
}

bool IsInteger(const Eigen::Vector3d& x) {
  return x(0) == std::round(x(0)) && x(1) == std::round(x(1)) && x(2) == std::round(x(2));
}

}  // namespace

OnlineSegmenter::OnlineSegmenter(OnlineSegmenterOptions options) : options_(std::move(options)) {
  last_pose_.index = -1;
  if (options_.rate_hz > 0) LearnRate(0);
}

void OnlineSegmenter::LearnRate(double dt_s) {
  const double rate = options_.rate_hz > 0 ? options_.rate_hz : (dt_s > 0 ? 1.0 / dt_s : 100.0);
  window_ = std::max<size_t>(5, static_cast<size_t>(std::lround(options_.window_s * rate))) | 1;
  trim_n_ = static_cast<size_t>(std::lround(options_.trim_s * rate));
}

NextPoseUpdate OnlineSegmenter::CurrentNextPose() const {
  NextPoseUpdate next;
  if (options_.protocol == GuidedProtocol::kPositions ||
      options_.protocol == GuidedProtocol::kFree) {
    return NextDirection(last_pose_.index >= 0 && last_pose_.accepted ? UpOf(last_pose_.accel_mean)
                                                                      : Eigen::Vector3d::UnitZ());
  }
  if (options_.protocol != GuidedProtocol::kSixFace) {
    next.instruction =
        absl::StrFormat("Put the robot in a new orientation and hold it still for %.1f s",
                        options_.min_static_s + 2 * options_.trim_s);
    return next;
  }
  if (step_ >= kSixFaceSteps) {
    next.done = true;
    next.instruction = "All twelve poses are in: the session can be solved";
    return next;
  }
  next.face = kSixFace[step_].face;
  next.turn_half = kSixFace[step_].turn_half;
  next.instruction = kSixFace[step_].instruction;
  return next;
}

NextPoseUpdate OnlineSegmenter::NextDirection(const Eigen::Vector3d& last_up) const {
  NextPoseUpdate next;
  const double hold_s = options_.min_static_s + 2 * options_.trim_s;
  const std::array<bool, 26> covered = DirectionsCovered();
  const auto& dirs = CubeDirections();
  std::optional<size_t> best;
  int missing = 0;
  for (size_t i = 0; i < dirs.size(); ++i) {
    if (!Wanted(options_.protocol, dirs[i]) || covered[i]) continue;
    ++missing;
    if (!best || dirs[i].unit.dot(last_up) > dirs[*best].unit.dot(last_up) + 1e-12) best = i;
  }
  if (!best) {
    const int more = PosesWanted(options_.protocol) - poses_accepted_;
    if (more <= 0) {
      next.done = true;
      next.instruction = "Every direction the protocol wants is in: the session can be solved";
    } else {
      next.instruction = absl::StrFormat(
          "Every direction is covered; %d more pose%s in any new orientation, each held still "
          "for %.1f s",
          more, more == 1 ? "" : "s", hold_s);
    }
    return next;
  }
  const CubeDirection& d = dirs[*best];
  next.face = d.label;
  next.instruction =
      d.axes == 1
          ? absl::StrFormat("Turn it so that %s points straight up, and hold it still for %.1f s",
                            PartsUp(d), hold_s)
          : absl::StrFormat(
                "Tilt it so that %s point up equally (%s), and hold it still for "
                "%.1f s",
                PartsUp(d), d.axes == 2 ? "45 degrees between them" : "a corner up", hold_s);
  absl::StrAppend(&next.instruction,
                  absl::StrFormat("  (%d direction%s to go)", missing, missing == 1 ? "" : "s"));
  return next;
}

Eigen::Vector3d OnlineSegmenter::UpOf(const Eigen::Vector3d& accel_mean) const {
  Eigen::Vector3d up = accel_mean;
  if (options_.accel_unit == AccelUnit::kCounts) {
    if (poses_accepted_ < 4) return Eigen::Vector3d::Zero();  // the offset is not known yet
    up -= pose_mean_sum_ / poses_accepted_;
  }
  return up;
}

std::array<bool, 26> OnlineSegmenter::DirectionsCovered() const {
  std::array<bool, 26> covered{};
  for (const Eigen::Vector3d& mean : accepted_means_) {
    const Eigen::Vector3d up = UpOf(mean);
    if (up.norm() > 0) covered[NearestDirection(up)] = true;
  }
  return covered;
}

GuideProgress OnlineSegmenter::Progress() const {
  GuideProgress p;
  p.poses_accepted = poses_accepted_;
  switch (options_.protocol) {
    case GuidedProtocol::kAny:
      return p;
    case GuidedProtocol::kSixFace:
      // The poses in so far (a wrong face or a failed pair's placement among them) and the
      // steps of the protocol still to do.
      p.poses_wanted = poses_accepted_ + kSixFaceSteps - step_;
      p.done = FacesDone();
      p.pending = FacesPending();
      break;
    case GuidedProtocol::kPositions:
    case GuidedProtocol::kFree: {
      const std::array<bool, 26> covered = DirectionsCovered();
      const auto& dirs = CubeDirections();
      for (size_t i = 0; i < dirs.size(); ++i) {
        if (!Wanted(options_.protocol, dirs[i])) continue;
        (covered[i] ? p.done : p.pending).push_back(dirs[i].label);
      }
      p.poses_wanted = std::max(PosesWanted(options_.protocol),
                                poses_accepted_ + static_cast<int>(p.pending.size()));
      break;
    }
  }
  const size_t all = p.done.size() + p.pending.size();
  p.coverage = all == 0 ? 0.0 : static_cast<double>(p.done.size()) / static_cast<double>(all);
  return p;
}

std::vector<std::string> OnlineSegmenter::FacesDone() const {
  std::vector<std::string> out;
  for (int i = 1; i < step_; i += 2) out.emplace_back(kSixFace[i].face);
  return out;
}

std::vector<std::string> OnlineSegmenter::FacesPending() const {
  std::vector<std::string> out;
  for (int i = 1; i < kSixFaceSteps; i += 2)
    if (i >= step_) out.emplace_back(kSixFace[i].face);
  return out;
}

void OnlineSegmenter::Add(double t_s, const Eigen::Vector3d& accel, const Eigen::Vector3d& gyro,
                          std::vector<SegmenterEvent>* events) {
  if (seen_ == 0) {
    first_t_s_ = t_s;
    offset_a_ = accel;
    offset_g_ = gyro;
  } else if (window_ == 0) {
    LearnRate(t_s - ring_.back().t_s);
  }
  ++seen_;
  integer_valued_ = integer_valued_ && IsInteger(accel) && IsInteger(gyro);
  ring_.push_back({t_s, accel, gyro});
  const Eigen::Vector3d da = accel - offset_a_, dg = gyro - offset_g_;
  s1a_ += da;
  s2a_ += da.cwiseAbs2();
  s1g_ += dg;
  s2g_ += dg.cwiseAbs2();
  if (window_ == 0 || ring_.size() < window_) return;
  if (ring_.size() > window_) {
    const Sample& old = ring_.front();
    const Eigen::Vector3d oa = old.accel - offset_a_, og = old.gyro - offset_g_;
    s1a_ -= oa;
    s2a_ -= oa.cwiseAbs2();
    s1g_ -= og;
    s2g_ -= og.cwiseAbs2();
    ring_.pop_front();
  }
  // Running sums drift by rounding: recompute them from the ring now and then.
  if (seen_ % (64 * window_) == 0) {
    s1a_.setZero(), s2a_.setZero(), s1g_.setZero(), s2g_.setZero();
    for (const Sample& s : ring_) {
      s1a_ += s.accel - offset_a_;
      s2a_ += (s.accel - offset_a_).cwiseAbs2();
      s1g_ += s.gyro - offset_g_;
      s2g_ += (s.gyro - offset_g_).cwiseAbs2();
    }
  }
  const double n = static_cast<double>(window_);
  const Eigen::Vector3d var_a = ((s2a_ - s1a_.cwiseAbs2() / n) / (n - 1)).cwiseMax(0.0);
  const Eigen::Vector3d var_g = ((s2g_ - s1g_.cwiseAbs2() / n) / (n - 1)).cwiseMax(0.0);
  const Sample& centre = ring_[window_ / 2];

  if (!noise_learnt_) {
    rest_rate_sum_ += centre.gyro;  // the learning rest's rate: the first rest rate
    rest_rate_n_ += 1;
    learn_a_.push_back(var_a);
    learn_g_.push_back(var_g);
    if (centre.t_s - first_t_s_ >= options_.learn_s || learn_a_.size() >= kMaxLearnSamples)
      FinishLearning();
    if (!noise_learnt_) return;
    // Only the variances of the learning period were kept (bounded memory), so the first pose
    // starts with the samples still in the ring, classified by the newest window.
    for (size_t i = 0; i <= window_ / 2; ++i) Classify(ring_[i], var_a, var_g, events);
    return;
  }
  Classify(centre, var_a, var_g, events);
}

void OnlineSegmenter::FinishLearning() {
  // A calibration capture starts at rest: the low quantile of the first window variances is
  // the white-noise floor (the offline EstimateNoise's 10th percentile, over the initial rest).
  accel_floor_ = Quantile(learn_a_, 0.10);
  gyro_floor_ = Quantile(learn_g_, 0.10);
  // Quantised readings quieter than one step still carry a step's rounding noise (1/12).
  const double min_var = integer_valued_ ? 1.0 / 12 : 1e-24;
  accel_floor_ = accel_floor_.cwiseMax(min_var);
  gyro_floor_ = gyro_floor_.cwiseMax(min_var);
  accel_floor0_ = accel_floor_;
  gyro_floor0_ = gyro_floor_;
  learn_a_.clear();
  learn_a_.shrink_to_fit();
  learn_g_.clear();
  learn_g_.shrink_to_fit();
  noise_learnt_ = true;
}

void OnlineSegmenter::Classify(const Sample& s, const Eigen::Vector3d& accel_var,
                               const Eigen::Vector3d& gyro_var,
                               std::vector<SegmenterEvent>* events) {
  const double thr_a = options_.multiplier * accel_floor_.sum();
  const double thr_g = options_.multiplier * gyro_floor_.sum();
  const double ratio = std::max(accel_var.sum() / thr_a, gyro_var.sum() / thr_g);
  const bool still = ratio <= 1.0;
  if (still) {
    if (!in_run_) {
      in_run_ = true;
      run_start_t_s_ = s.t_s;
      run_seen_ = 0;
      run_tail_.clear();
      chunks_.clear();
      chunk_n_ = 1;
      run_var_a_.setZero();
      run_var_g_.setZero();
      run_var_n_ = 0;
      run_judged_at_hold_ = false;
      run_accepted_ = false;
      run_rotation_.setZero();
      run_excursion_ = 0;
    }
    run_var_a_ += accel_var;
    run_var_g_ += gyro_var;
    ++run_var_n_;
    AddToRun(s);
    // Held for the hold time: judge the run now, so that a pose counts even when no motion
    // (nor Flush) ever ends it.
    if (!run_judged_at_hold_ && !chunks_.empty() &&
        run_last_t_s_ - run_first_t_s_ >= options_.min_static_s) {
      run_judged_at_hold_ = true;
      PoseUpdate pose;
      if (EvaluateRun(&pose) && pose.accepted) AcceptPose(std::move(pose), events);
    }
  } else if (in_run_) {
    EndRun(events);
  }
  if (s.t_s - last_stillness_t_s_ >= options_.stillness_period_s) {
    last_stillness_t_s_ = s.t_s;
    SegmenterEvent e;
    e.kind = SegmenterEvent::Kind::kStillness;
    e.stillness.t_s = s.t_s;
    e.stillness.still = still;
    e.stillness.still_for_s = still ? s.t_s - run_start_t_s_ : 0.0;
    e.stillness.needed_s = options_.min_static_s + 2 * options_.trim_s;
    e.stillness.motion_ratio = ratio;
    events->push_back(std::move(e));
  }
}

void OnlineSegmenter::AddToRun(const Sample& s) {
  if (++run_seen_ <= trim_n_) return;  // settling at the start of the run
  run_tail_.push_back(s);
  if (run_tail_.size() <= trim_n_) return;  // may be the end of the run: trimmed then
  const Sample x = run_tail_.front();
  run_tail_.pop_front();
  if (chunks_.empty()) {
    run_offset_a_ = x.accel;
    run_first_t_s_ = x.t_s;
    run_prev_t_s_ = x.t_s;
  }
  if (rest_rate_n_ > 0) {
    run_rotation_ += (x.gyro - rest_rate_sum_ / rest_rate_n_) * (x.t_s - run_prev_t_s_);
    run_excursion_ = std::max(run_excursion_, run_rotation_.norm());
  }
  run_prev_t_s_ = x.t_s;
  if (chunks_.empty() || chunks_.back().n >= chunk_n_) chunks_.emplace_back();
  Chunk& c = chunks_.back();
  ++c.n;
  c.accel_sum += x.accel - run_offset_a_;
  c.gyro_sum += x.gyro;
  run_last_t_s_ = x.t_s;
  if (chunks_.size() > kMaxChunks) {  // halve the resolution: memory stays bounded
    std::vector<Chunk> merged;
    for (size_t i = 0; i < chunks_.size(); i += 2) {
      Chunk m = chunks_[i];
      if (i + 1 < chunks_.size()) {
        m.n += chunks_[i + 1].n;
        m.accel_sum += chunks_[i + 1].accel_sum;
        m.gyro_sum += chunks_[i + 1].gyro_sum;
      }
      merged.push_back(m);
    }
    chunks_ = std::move(merged);
    chunk_n_ *= 2;
  }
}

void OnlineSegmenter::Flush(std::vector<SegmenterEvent>* events) {
  if (in_run_) EndRun(events);
}

bool OnlineSegmenter::RedoTurn(const std::string& face) {
  if (options_.protocol != GuidedProtocol::kSixFace || step_ == 0) return false;
  const SixFaceStep& done = kSixFace[static_cast<size_t>(step_ - 1)];
  if (!done.turn_half || face != done.face) return false;
  --step_;
  return true;
}

void OnlineSegmenter::EndRun(std::vector<SegmenterEvent>* events) {
  in_run_ = false;
  PoseUpdate pose;
  const bool has_samples = EvaluateRun(&pose);
  if (run_accepted_) {
    // Accepted at the hold time (its event has fired): update its statistics with the whole run.
    run_accepted_ = false;
    if (has_samples) {
      pose_mean_sum_ += pose.accel_mean - run_accepted_mean_;
      pose.index = last_pose_.index;
      pose.face = last_pose_.face;  // as announced
      pose.accepted = true;         // as announced
      pose.reason.clear();
      last_pose_ = std::move(pose);
    }
    RefineFloor();
    return;
  }
  if (!has_samples) return;  // nothing left after trimming: a pause, not a pose
  if (pose.accepted) {
    AcceptPose(std::move(pose), events);
    RefineFloor();
    return;
  }
  pose.index = next_pose_index_++;
  pose.face = FaceOf(pose.accel_mean);
  last_pose_ = pose;
  SegmenterEvent e;
  e.kind = SegmenterEvent::Kind::kPose;
  e.pose = std::move(pose);
  events->push_back(std::move(e));
}

bool OnlineSegmenter::EvaluateRun(PoseUpdate* pose) const {
  Chunk total, first_half;
  for (const Chunk& c : chunks_) total.n += c.n;
  if (total.n < 2) return false;
  size_t k = 0;
  for (; k < chunks_.size() && 2 * (first_half.n + chunks_[k].n) <= total.n + 1; ++k) {
    first_half.n += chunks_[k].n;
    first_half.accel_sum += chunks_[k].accel_sum;
  }
  for (const Chunk& c : chunks_) {
    total.accel_sum += c.accel_sum;
    total.gyro_sum += c.gyro_sum;
  }
  const double n = static_cast<double>(total.n);
  pose->t_start_s = run_first_t_s_;
  pose->t_end_s = run_last_t_s_;
  pose->samples = total.n;
  pose->accel_mean = run_offset_a_ + total.accel_sum / n;
  pose->gyro_mean = total.gyro_sum / n;
  pose->accepted = true;
  pose->reason.clear();
  const double duration = pose->t_end_s - pose->t_start_s;
  const double rad = options_.gyro_unit == GyroUnit::kCounts ? 0.0
                                                             : NominalGyroToSi(options_.gyro_unit);
  const double turned = run_excursion_ * rad;
  const double bound =
      options_.rotation_sigmas * gyro_floor_.cwiseSqrt().norm() * rad * std::sqrt(n) *
          (n > 1 ? duration / (n - 1) : 0.0) +
      options_.rest_rate_bound_deg_s * std::numbers::pi / 180.0 * duration;
  if (rad > 0 && rest_rate_n_ > 0 && turned > bound) {
    pose->accepted = false;
    pose->reason = absl::StrFormat(
        "turning: the gyroscope turned %.1f deg over these %.1f s, more than a rest can (%.2f "
        "deg); a rest is still, not a steady turn",
        turned * 180.0 / std::numbers::pi, duration, bound * 180.0 / std::numbers::pi);
  } else if (duration < options_.min_static_s) {
    pose->accepted = false;
    pose->reason = absl::StrFormat("too short: held %.1f s, needs %.1f s; hold the pose longer",
                                   duration, options_.min_static_s);
  } else if (first_half.n > 0 && first_half.n < total.n) {
    // Moved during the pose: as DetectStatic, the two halves' means differ by more than the
    // noise of the means AND by more than the per-sample noise.
    const double n1 = static_cast<double>(first_half.n), n2 = n - n1;
    const Eigen::Vector3d m1 = first_half.accel_sum / n1;
    const Eigen::Vector3d m2 = (total.accel_sum - first_half.accel_sum) / n2;
    const Eigen::Vector3d shift = (m2 - m1).cwiseAbs();
    const Eigen::Vector3d noise_std = accel_floor_.cwiseSqrt();
    const Eigen::Vector3d sigma_means = noise_std * std::sqrt(1.0 / n1 + 1.0 / n2);
    for (int j = 0; j < 3; ++j) {
      if (shift(j) > options_.moved_sigma * sigma_means(j) && shift(j) > 3 * noise_std(j)) {
        pose->accepted = false;
        pose->reason = absl::StrFormat(
            "moved during capture: axis %c shifted by %.1f noise std between the first and "
            "second half; keep the robot still",
            "xyz"[j], shift(j) / noise_std(j));
        break;
      }
    }
  }
  return true;
}

void OnlineSegmenter::AcceptPose(PoseUpdate pose, std::vector<SegmenterEvent>* events) {
  pose.index = next_pose_index_++;
  pose.face = FaceOf(pose.accel_mean);  // before this pose counts, as the offset estimate
  ++poses_accepted_;
  pose_mean_sum_ += pose.accel_mean;
  // The rest rate follows the accepted poses (each as much as the learning rest).
  rest_rate_sum_ += pose.gyro_mean * std::max(1.0, rest_rate_n_ / poses_accepted_);
  rest_rate_n_ += std::max(1.0, rest_rate_n_ / poses_accepted_);
  if (accepted_means_.size() < kMaxGuidePoses) accepted_means_.push_back(pose.accel_mean);
  run_accepted_ = in_run_;
  run_accepted_mean_ = pose.accel_mean;
  last_pose_ = pose;
  SegmenterEvent e;
  e.kind = SegmenterEvent::Kind::kPose;
  e.pose = pose;
  events->push_back(std::move(e));
  Guide(pose, events);
}

void OnlineSegmenter::RefineFloor() {
  // Refine the floor with the pose's own window variances; never above the initial rest's.
  if (run_var_n_ == 0) return;
  const double m = static_cast<double>(run_var_n_);
  accel_floor_ = (0.8 * accel_floor_ + 0.2 * run_var_a_ / m).cwiseMin(accel_floor0_);
  gyro_floor_ = (0.8 * gyro_floor_ + 0.2 * run_var_g_ / m).cwiseMin(gyro_floor0_);
}

std::string OnlineSegmenter::FaceOf(const Eigen::Vector3d& accel_mean) const {
  const Eigen::Vector3d up = UpOf(accel_mean);
  if (up.norm() == 0) return "";
  const Face face = ClassifyFace(up);
  return face.off_axis_deg <= kFaceToleranceDeg ? face.Label() : "";
}

void OnlineSegmenter::Guide(const PoseUpdate& pose, std::vector<SegmenterEvent>* events) {
  SegmenterEvent e;
  e.kind = SegmenterEvent::Kind::kNextPose;
  if (options_.protocol == GuidedProtocol::kSixFace && step_ < kSixFaceSteps) {
    if (pose.face == kSixFace[step_].face) {
      ++step_;
      e.next_pose = CurrentNextPose();
    } else {
      e.next_pose = CurrentNextPose();
      e.next_pose.instruction =
          absl::StrCat(pose.face.empty() ? std::string("That pose was not on a face")
                                         : absl::StrCat("That was ", pose.face, " up"),
                       "; wanted ", kSixFace[step_].face, ". ", e.next_pose.instruction);
    }
  } else {
    e.next_pose = CurrentNextPose();
    // Positions and free: a pose on a direction that an earlier pose had covered adds a pose
    // but no coverage; say so, as the six-face guidance does for a wrong face.
    const Eigen::Vector3d up = UpOf(pose.accel_mean);
    const bool direction_guidance = options_.protocol == GuidedProtocol::kPositions ||
                                    options_.protocol == GuidedProtocol::kFree;
    if (direction_guidance && !e.next_pose.done && up.norm() > 0 && !accepted_means_.empty() &&
        accepted_means_.back() == pose.accel_mean) {
      const size_t dir = NearestDirection(up);
      const bool seen_before = std::any_of(accepted_means_.begin(), accepted_means_.end() - 1,
                                           [&](const Eigen::Vector3d& m) {
                                             const Eigen::Vector3d u = UpOf(m);
                                             return u.norm() > 0 && NearestDirection(u) == dir;
                                           });
      if (seen_before) {
        e.next_pose.instruction = absl::StrCat("That was ", CubeDirections()[dir].label,
                                               " up again. ", e.next_pose.instruction);
      }
    }
  }
  events->push_back(std::move(e));
}

}  // namespace imucal::core
