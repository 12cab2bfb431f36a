// Online static-pose segmentation: the incremental counterpart of core/static_detector.h, fed
// sample by sample while a robot streams, for the technician's live guide.
//
// Model (as the offline detector): a sample is still when the window variance (sum over the
// three axes) of the accelerometer AND of the gyroscope is at most `multiplier` times the
// learnt white-noise variance of that sensor. The window is centred on the sample it classifies,
// so classification runs window/2 samples behind the newest sample.
// The noise floor is learnt from the data: the 10th percentile of the window variances over the
// first `learn_s` seconds (a calibration capture starts at rest, as Calibrate assumes), then
// refined with every accepted pose (an exponential average of its window variances, never above
// the initial estimate). Quantised (integer) readings keep at least one step's rounding noise.
//
// A still run is a pose trimmed by `trim_s` at both ends, rejected when shorter than
// `min_static_s` ("too short") or when its first and second half means differ by more than
// `moved_sigma` standard errors and 3 noise std ("moved"), as DetectStatic does. A run is
// accepted as soon as it has been held for the hold time (min_static_s after trimming) and its
// halves agree: the pose event, the accepted count and the next-pose guidance fire then, so the
// last pose of a capture counts even if the robot stops streaming while still. The run may keep
// growing; its statistics (the accepted-means sum, the noise floor refinement) are updated when
// motion (or Flush()) ends it, with no second pose event. A run that ends before the hold time,
// or that had moved when it reached it, is judged when it ends, as a whole.
//
// Six-face guidance: the wanted sequence is Z+, Z+ turned, Z-, Z- turned, Y+, Y+ turned, Y-, Y-
// turned, X+, X+ turned, X-, X- turned (seeds/000, core/simulator.h). An accepted pose whose face
// (ClassifyFace of its accelerometer mean) is the wanted one advances the sequence. The 180-degree
// turn needs the gyroscope integrated between the poses, which the segmenter does not do: the
// caller (imucald) checks each pair with CheckSixFacePairs and, when the pair that completed a
// face fails, calls RedoTurn so that the turned placement is wanted again. Raw counts carry an
// unknown offset, so for counts the mean is centred by the running mean of the accepted pose
// means once four poses are in (an approximation: exact only when opposite faces balance).
//
// Direction guidance (the positions and free protocols): the sphere of up directions is split
// into the 26 directions of a cube seen from its centre (6 faces "Z+", 12 edges "X+Z+", 8
// corners "X+Y-Z+"); each accepted pose covers the direction nearest to its up vector. The
// 24-position protocol (seeds/002: three groups of 8 turns in 45-degree steps about a
// horizontal x, y, z) puts each face up twice and each edge once, so it wants the 18 faces and
// edges and 24 poses. The hand-held protocol (Tedaldi) wants the 6 faces (bias, scale and the
// second-order terms are best seen with an axis along gravity) and the 8 corners (every pair
// of axes tilted together, for the misalignment angles) and 18 poses: the 15-parameter model
// plus the 3 degrees of freedom the effect search needs beyond it (core/effects.h). The next
// pose asked for is the missing direction nearest to the last pose (the least turning).
//
// Memory is bounded: a ring of one window, the learning window (at most kMaxLearnSamples
// variances) and at most kMaxChunks partial sums per still run, whatever the session length.
#ifndef IMUCAL_CORE_ONLINE_SEGMENTER_H_
#define IMUCAL_CORE_ONLINE_SEGMENTER_H_

#include <array>
#include <cstddef>
#include <deque>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "core/capture.h"

namespace imucal::core {

// The protocol the guidance follows (see the header comment).
enum class GuidedProtocol {
  kAny,        // any new orientation; no target, so no "complete"
  kSixFace,    // the twelve six-face steps in order
  kPositions,  // 24 positions: the 6 faces and 12 edges of the cube of directions
  kFree,       // hand-held: the 6 faces and 8 corners, 18 poses
};

struct OnlineSegmenterOptions {
  double rate_hz = 0.0;              // nominal; 0: learnt from the first sample intervals
  double window_s = 0.5;             // variance window
  double min_static_s = 1.0;         // after trimming
  double trim_s = 0.1;               // removed from each end of a still run
  double moved_sigma = 8.0;          // as StaticDetectorOptions::moved_sigma
  double multiplier = 6.0;           // threshold = multiplier * noise variance
  double learn_s = 2.0;              // initial rest used to learn the noise floor
  double stillness_period_s = 0.25;  // sample time between two stillness updates
  GuidedProtocol protocol = GuidedProtocol::kAny;  // the guidance and progress to emit
  AccelUnit accel_unit = AccelUnit::kMetersPerSecond2;
  // The physical bound on a pose, as StaticDetectorOptions: over a still run the gyroscope, the
  // rest rate removed (the mean of the learning rest, then of the accepted poses), turns less
  // than `rotation_sigmas` times its noise's random walk plus `rest_rate_bound_deg_s` times the
  // run's duration, else the run is "turning" (a steady turn about the vertical has neither
  // variance nor a change of the accelerometer). Not applied for a gyroscope in counts (no
  // nominal scale).
  GyroUnit gyro_unit = GyroUnit::kRadPerSecond;
  double rotation_sigmas = 5.0;
  double rest_rate_bound_deg_s = 0.5;
};

struct StillnessUpdate {
  double t_s = 0;
  bool still = false;
  double still_for_s = 0;   // since the still run started (before trimming)
  double needed_s = 0;      // min_static_s + 2 * trim_s
  double motion_ratio = 0;  // max over the sensors of window variance / threshold
};

struct PoseUpdate {
  int index = 0;  // 0, 1, 2, ... over all poses, accepted or not
  bool accepted = false;
  std::string reason;  // why rejected, in a technician's words
  std::string face;    // "Z+" when on a face (within kFaceToleranceDeg), else ""
  double t_start_s = 0, t_end_s = 0;
  Eigen::Vector3d accel_mean = Eigen::Vector3d::Zero();  // input units
  Eigen::Vector3d gyro_mean = Eigen::Vector3d::Zero();
  size_t samples = 0;
};

struct NextPoseUpdate {
  std::string instruction;
  std::string face;  // wanted face (six-face) or cube direction ("X+Z+"), "" when any or done
  bool turn_half = false;
  bool done = false;  // the protocol is complete (six-face, positions, free)
};

// What the protocol has and still needs, for the guide's progress line.
struct GuideProgress {
  int poses_accepted = 0;
  // Poses the protocol needs in all (accepted so far plus the least still to do); 0 when the
  // protocol sets no target (kAny). Complete when poses_accepted >= poses_wanted.
  int poses_wanted = 0;
  // Six-face: faces whose two steps are done / still wanted, in protocol order. Positions and
  // free: the wanted cube directions ("Z+", "X+Z+", "X+Y-Z+") covered / not yet covered.
  std::vector<std::string> done, pending;
  double coverage = 0;  // done / (done + pending), 0..1; 0 for kAny
};

struct SegmenterEvent {
  enum class Kind { kStillness, kPose, kNextPose };
  Kind kind = Kind::kStillness;
  StillnessUpdate stillness;
  PoseUpdate pose;
  NextPoseUpdate next_pose;
};

class OnlineSegmenter {
 public:
  static constexpr size_t kMaxLearnSamples = 8192;
  static constexpr size_t kMaxChunks = 256;
  static constexpr int kSixFaceSteps = 12;

  explicit OnlineSegmenter(OnlineSegmenterOptions options);

  // The first guidance (the pose wanted before any sample arrives).
  NextPoseUpdate CurrentNextPose() const;

  // Feeds one sample (input units; t strictly increasing, as the caller validates). Appends the
  // events it causes to `events`.
  void Add(double t_s, const Eigen::Vector3d& accel, const Eigen::Vector3d& gyro,
           std::vector<SegmenterEvent>* events);
  // Ends the current still run, if any, as if the robot moved (e.g. the session is closing).
  void Flush(std::vector<SegmenterEvent>* events);
  // Six-face: the pair that completed `face` (its turned placement, the last step done) failed
  // the caller's pair check; that turned placement is wanted again. Returns false (and changes
  // nothing) when the last step done is not `face`'s turned placement.
  bool RedoTurn(const std::string& face);
  // The protocol's progress now.
  GuideProgress Progress() const;

  int poses_accepted() const { return poses_accepted_; }
  int poses_total() const { return next_pose_index_; }
  int six_face_step() const { return step_; }  // 0..12: wanted steps done
  // The last pose judged (index -1 before any): an accepted one's statistics (means, end time,
  // samples) are those of its whole run once motion or Flush() has ended it.
  const PoseUpdate& last_pose() const { return last_pose_; }
  bool noise_learnt() const { return noise_learnt_; }
  // Per-axis noise variances (input units squared); zero until learnt.
  const Eigen::Vector3d& accel_noise_var() const { return accel_floor_; }
  const Eigen::Vector3d& gyro_noise_var() const { return gyro_floor_; }
  // Six-face faces whose two steps are done, and those still wanted, in protocol order.
  std::vector<std::string> FacesDone() const;
  std::vector<std::string> FacesPending() const;
  // Positions and free: for each of the 26 cube directions (core/online_segmenter.cc
  // CubeDirections()), whether an accepted pose covers it. All false for counts until the
  // offset is estimated (four poses).
  std::array<bool, 26> DirectionsCovered() const;

  static constexpr size_t kMaxGuidePoses = 1024;  // accepted up vectors kept for coverage

 private:
  struct Sample {
    double t_s;
    Eigen::Vector3d accel, gyro;
  };
  // Sums of a stretch of samples (accel relative to the run's first sample).
  struct Chunk {
    size_t n = 0;
    Eigen::Vector3d accel_sum = Eigen::Vector3d::Zero();
    Eigen::Vector3d gyro_sum = Eigen::Vector3d::Zero();
  };

  void LearnRate(double t_s);
  void Classify(const Sample& s, const Eigen::Vector3d& accel_var, const Eigen::Vector3d& gyro_var,
                std::vector<SegmenterEvent>* events);
  void AddToRun(const Sample& s);
  void EndRun(std::vector<SegmenterEvent>* events);
  // Judges the run's trimmed samples so far (index and face left unset); false when fewer than
  // two samples are left after trimming.
  bool EvaluateRun(PoseUpdate* pose) const;
  // Counts `pose` (judged accepted) and emits its pose event and the guidance.
  void AcceptPose(PoseUpdate pose, std::vector<SegmenterEvent>* events);
  void RefineFloor();
  void FinishLearning();
  std::string FaceOf(const Eigen::Vector3d& accel_mean) const;
  // The up direction of an accelerometer mean (counts: centred as FaceOf does); zero when not
  // known yet.
  Eigen::Vector3d UpOf(const Eigen::Vector3d& accel_mean) const;
  NextPoseUpdate NextDirection(const Eigen::Vector3d& last_up) const;
  void Guide(const PoseUpdate& pose, std::vector<SegmenterEvent>* events);

  OnlineSegmenterOptions options_;
  // Sampling.
  double first_t_s_ = 0;
  size_t seen_ = 0;
  size_t window_ = 0;  // samples, odd; 0 until the rate is known
  std::deque<Sample> ring_;
  Eigen::Vector3d offset_a_ = Eigen::Vector3d::Zero(), offset_g_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d s1a_ = Eigen::Vector3d::Zero(), s2a_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d s1g_ = Eigen::Vector3d::Zero(), s2g_ = Eigen::Vector3d::Zero();
  bool integer_valued_ = true;
  // Noise floor (per-axis variances).
  bool noise_learnt_ = false;
  std::vector<Eigen::Vector3d> learn_a_, learn_g_;
  Eigen::Vector3d accel_floor_ = Eigen::Vector3d::Zero(), gyro_floor_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d accel_floor0_ = Eigen::Vector3d::Zero(), gyro_floor0_ = Eigen::Vector3d::Zero();
  // The current still run.
  bool in_run_ = false;
  double run_start_t_s_ = 0;
  size_t run_seen_ = 0;          // samples of the run so far (before trimming)
  std::deque<Sample> run_tail_;  // the last trim samples, not yet summed
  size_t trim_n_ = 0;
  std::vector<Chunk> chunks_;
  size_t chunk_n_ = 1;  // samples per chunk (doubles when kMaxChunks is reached)
  Eigen::Vector3d run_offset_a_ = Eigen::Vector3d::Zero();
  double run_first_t_s_ = 0, run_last_t_s_ = 0;
  Eigen::Vector3d run_var_a_ = Eigen::Vector3d::Zero(), run_var_g_ = Eigen::Vector3d::Zero();
  size_t run_var_n_ = 0;
  bool run_judged_at_hold_ = false;  // the run reached the hold time and was judged then
  bool run_accepted_ = false;        // ... and accepted: its pose event has fired
  Eigen::Vector3d run_accepted_mean_ = Eigen::Vector3d::Zero();  // in pose_mean_sum_
  // The rotation test: the rest rate (input units), the run's rotation so far and its largest
  // excursion (input units x s).
  Eigen::Vector3d rest_rate_sum_ = Eigen::Vector3d::Zero();
  double rest_rate_n_ = 0;
  Eigen::Vector3d run_rotation_ = Eigen::Vector3d::Zero();
  double run_excursion_ = 0;
  double run_prev_t_s_ = 0;
  PoseUpdate last_pose_;  // index -1 until the first pose (the constructor)
  double last_stillness_t_s_ = -1e300;
  // Poses and guidance.
  int next_pose_index_ = 0;
  int poses_accepted_ = 0;
  Eigen::Vector3d pose_mean_sum_ = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector3d> accepted_means_;  // at most kMaxGuidePoses, input units
  int step_ = 0;
};

}  // namespace imucal::core

#endif  // IMUCAL_CORE_ONLINE_SEGMENTER_H_
