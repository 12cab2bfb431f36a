// The gyroscope's static rate read as a sequence over the poses (issue 16, item 6): does the bias
// stay put between poses, and if not, how does it move, and how much of the static residual does
// that explain?
//
// A capture's static poses follow one another, a move between each two. Per gyro axis, pose k
// reads
//   y_k = c + x_k + u_k + e_k
//   c    the stored bias's error (a constant; diffuse prior)
//   x_k  a random walk over the moves, Var(x_k - x_{k-1}) = w^2: a bias that steps at each move
//        and keeps the step (the poses' order predicts it: the neighbours share it)
//   u_k  an offset of the pose's own, iid N(0, s^2): a bias that moves when the unit is moved
//        (handled, set down) and is drawn anew at the next (the order does not predict it)
//   e_k  the pose mean's white noise, sigma_k (the scatter within the pose)
// The steps are counted per move, not per second: the two halves of each pose say whether the
// bias also moves while the unit rests (a drift in time), see within_pose_ratio. Four models:
// none (w = s = 0: only the noise, what the report's noise floor assumes), shift (s), walk (w),
// both. Each is fitted by maximum likelihood (Kalman filter over the poses, the constant
// diffuse, so the first pose's term is dropped) and the one with the least BIC (a parameter
// costs ln(N - 1)) is kept, per axis.
//
// What it gives:
//   - the pose-to-pose bias step (RMS of the successive differences less the noise's share), and
//     what the rest's Allan rate random walk allows over the median time between poses
//     (K_allan sqrt(dt), with K_allan the rest's K or its upper bound): a step many times that
//     is not the rest's random walk;
//   - whether the bias holds within a pose: each pose's second half minus its first, against the
//     white noise's share (a ratio near 1: it holds; a bias that drifts within the poses, or a
//     pose window that takes in the tail of a move, shows above 1), and the ratio a drift in
//     time would give if it made the steps between poses (K^2 = step^2 / dt; the halves of a
//     pose of length T then differ by K^2 T / 3 more in variance: the Allan variance at T / 2);
//   - the held-out static residual before (a constant bias: each pose predicted by the weighted
//     mean of the others) and after (each pose predicted from the others by the chosen model's
//     smoother: a random walk is predicted by the neighbouring poses, an iid offset by nothing);
//   - the smoothed persistent bias c + x_k per pose (what a random walk smoothed across the poses
//     would put into the integration of the moves around pose k).
// Nothing here is applied on the robot: a bias that wanders cannot be corrected at run time. It
// tells what the static residual is made of and how far the report's noise floor (white noise,
// one bias) is from describing the unit.
#ifndef IMUCAL_CORE_BIAS_WANDER_H_
#define IMUCAL_CORE_BIAS_WANDER_H_

#include <array>
#include <limits>
#include <string>
#include <vector>

#include "Eigen/Core"

namespace imucal::core {

// One static pose: its middle's time, its mean calibrated rate (the stored model and its effects
// applied; rad/s) and that mean's white-noise standard deviation per axis, and the difference of
// its two halves' means (second minus first) with that difference's white-noise standard
// deviation.
struct WanderPose {
  double t_s = 0;
  double duration_s = 0;
  Eigen::Vector3d rate_rad_s = Eigen::Vector3d::Zero();
  Eigen::Vector3d sigma_rad_s = Eigen::Vector3d::Zero();
  Eigen::Vector3d half_diff_rad_s = Eigen::Vector3d::Zero();
  Eigen::Vector3d half_diff_sigma_rad_s = Eigen::Vector3d::Zero();
};

enum class WanderModel { kNone, kShift, kWalk, kShiftAndWalk };
// "none", "shift", "walk", "shift+walk".
const char* WanderModelName(WanderModel model);

struct AxisWander {
  WanderModel model = WanderModel::kNone;
  double shift_rad_s = 0;       // s of the chosen model (0 when it has none)
  double walk_rad_s = 0;        // w of the chosen model, per move (0 when it has none)
  std::array<double, 4> bic{};  // per model, in WanderModel's order (lower is better)
  double heldout_before_rad_s = 0, heldout_after_rad_s = 0;  // RMS over the poses
};

struct BiasWander {
  bool ran = false;
  int poses = 0;
  std::array<AxisWander, 3> axes;
  // 3-axis RMS over the poses, rad/s.
  double static_rms_rad_s = 0;   // |rate - its weighted mean|
  double noise_floor_rad_s = 0;  // |sigma|
  double heldout_before_rad_s = 0, heldout_after_rad_s = 0;
  double step_rms_rad_s = 0;  // successive differences, the noise's share taken out
  double median_dt_s = 0;     // between successive poses' middles
  // |K_allan| sqrt(median_dt_s); NaN when no K is known.
  double allan_step_rad_s = std::numeric_limits<double>::quiet_NaN();
  bool allan_is_bound = false;  // K_allan was an upper bound (the rest too short to see K)
  // RMS |half difference| / its white-noise RMS; and what it would be if a drift in time made
  // the steps between poses.
  double within_pose_ratio = std::numeric_limits<double>::quiet_NaN();
  double drift_within_pose_ratio = std::numeric_limits<double>::quiet_NaN();
  std::vector<Eigen::Vector3d> smoothed_rad_s;  // per pose, c + x_k of the chosen models
  std::string note;                             // what the report says, one paragraph
};

// Needs at least 6 poses (else ran = false). allan_k: the rest's K per axis (rad/s/sqrt(s)), NaN
// where not measured; allan_k_bound: its upper bound, used where K is NaN.
BiasWander AnalyseBiasWander(const std::vector<WanderPose>& poses, const Eigen::Vector3d& allan_k,
                             const Eigen::Vector3d& allan_k_bound);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_BIAS_WANDER_H_
