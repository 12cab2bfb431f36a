// Drift detection per device (issue 28): from the health checks since the device's active version
// (core/health/check.h), a state (ok, watch, recalibrate) with its evidence.
//
// QUANTITIES, one scalar series each, in physical units:
//   along gravity   f . u0 - g [m/s^2]   (u0: the dock direction, else the learning checks' mean
//                                         direction): an accel bias or scale change along g;
//                                         |f| - g when the checks are not in one orientation
//   tilt a, tilt b  (u - u0) . e_a, e_b [rad] (e_a, e_b across u0): the gravity direction at the
//                   dock; a mounting rotation or an accel bias across g. Only when the checks are
//                   taken in one orientation (DriftOptions::fixed_orientation).
//   gyro x, y, z    the calibrated gyro at rest [rad/s]
//
// EACH UNIT JUDGED BY ITS OWN SCATTER, SELF-STARTING. Check n is scored against the checks before
// it since the version (Hawkins's self-starting CUSUM): their mean m and their spread, with a
// prior spread s0 worth nu0 = `prior_checks` checks:
//   sigma^2 = (nu0 s0^2 + sum_{i<n} (x_i - m)^2) / (nu0 + n - 1)
//   r = (x_n - m) / (sigma sqrt(1 + 1/n))
// which is Student-t with nu0 + n - 1 degrees of freedom when nothing changed, and independent
// from check to check. (Residuals from one baseline fixed by the first checks are not: the
// baseline's error is in every later residual, and a CUSUM adds it up; with 8 learning checks
// that made the false-alarm rate 6 times the stated one.) r is mapped to the normal score with
// the same tail probability, so the threshold below holds from the first checks on. sigma is
// never under the check's own SE (noise + Allan wander). For the gyro, s0 is the fleet's median
// spread (core/health/fleet.h) or a default: a MEMS gyro's bias moves from one power-up to the
// next by far more than its noise (the shared repeat set: 0.05-0.07 deg/s between poses), so the
// noise would call every power-up a change. For the accelerometer and the tilt, s0 is a stated
// repeatability (a dock's placement, unmodelled temperature). Scoring starts at check
// `learning_checks`; the first ones also give the evidence's baseline (their median) and the
// unit's spread for the evidence (1.4826 MAD of successive differences / sqrt 2: a step spoils
// one difference, a ramp or a season hardly moves them).
//
// THE TEST: a two-sided CUSUM per quantity on the normal scores,
//   S+ = max(0, S+ + z - k),  S- = max(0, S- - z - k),   k = design shift / 2 (sigmas),
// alarm when either reaches h. h is set from the false-alarm rate: a device with C one-sided
// statistics and c checks a month alarms falsely at most alpha per month (the union bound) when
// each statistic's in-control average run length is ARL0 = C c / alpha checks, and Siegmund's
// approximation for normal increments gives h from ARL0:
//   ARL0 = (exp(2 k b) - 2 k b - 1) / (2 k^2),  b = h + 1.166,
// refined to the exact run length of the statistic's Markov chain (Brook and Evans 1972), since at
// the k used here Siegmund's overstates ARL0 up to 1.8 times (h too low, alarms too often).
// k = 1.5 (a 3-sigma design shift): the aim is a step of 5 spreads within 3 checks, which after
// the learnt spread's uncertainty (the median baseline, the t tails) scores about 3.5-4, and at
// that shift k = 1.5 detects within 3 checks more often than k = 2 or 2.5 at the same ARL0.
// Recalibrate: a statistic reached h at the alpha of `false_alarms_per_device_month` (latched:
// a shock does not heal); watch: a statistic is now at the h of `watch_alarms_per_device_month`,
// or the learning checks disagree with the version's own figures (a bad calibration).
//
// STEP OR DRIFT OR TEMPERATURE. After an alarm the quantity's residuals since the learning are
// fitted by a step (d = m after check j) and by a ramp (d = beta (t - t_j) after check j), each
// with its best change point; the ramp is called when it fits better by more than 2 ln(n) noise
// variances with at least 3 checks after its onset (the shock's step is the default). When the
// checks span at least min_temp_span_c, the quantity is also regressed on temperature over all
// checks (x = a + c (T - Tmean)); if its residuals raise no alarm and c is significant (3 SE),
// the change is what the temperature explains (the stored temperature effect misses it): not
// a recalibration by itself.
//
// Deterministic: a pure function of the rows (no clock, no random numbers), so a server can
// recompute the state from what it stored.
#ifndef IMUCAL_CORE_HEALTH_DRIFT_H_
#define IMUCAL_CORE_HEALTH_DRIFT_H_

#include <optional>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "core/health/check.h"
#include "core/params.h"
#include "util/units.h"

namespace imucal::core::health {

inline constexpr double kDay_s =
    86400.0;  // s per day, the unit of drift rates and of the fleet simulator

enum class HealthState { kOk, kWatch, kRecalibrate };
const char* HealthStateName(HealthState state);  // "ok", "watch", "recalibrate"

enum class Quantity { kAlongGravity, kTiltA, kTiltB, kGyroX, kGyroY, kGyroZ };
inline constexpr int kNumQuantities = 6;
const char* QuantityName(Quantity q);  // "along gravity", "tilt a", ..., "gyro bias z"

enum class ChangeKind { kNone, kStep, kDrift, kTemperature };
const char* ChangeKindName(ChangeKind kind);  // "", "step", "drift", "temperature"

// The active version's own figures.
struct DriftReference {
  int version = 0;
  double activated_s = 0;  // checks before this time belong to an earlier version: ignored
  // What the version's own uncertainty lets a check read when nothing changed (0: unknown).
  double along_gravity_se_m_s2 = 0;
  Eigen::Vector3d gyro_bias_se_rad_s = Eigen::Vector3d::Zero();
  // The dock's gravity direction in the body frame, when known; else the learning checks' own.
  std::optional<Eigen::Vector3d> dock_gravity_dir_body;
};

// The reference a parameter set gives: its version, and its standard errors projected on what a
// check reads (the accel bias's SE along the dock direction when given, else its RMS).
DriftReference ReferenceFromParams(const ParamSet& params, double activated_s);

struct DriftOptions {
  double false_alarms_per_device_month = 0.01;  // recalibrate
  double watch_alarms_per_device_month = 0.2;   // watch
  double checks_per_day = 0;  // 0: from the checks' own spacing (1.5 with fewer than 4)
  int learning_checks = 5;
  bool fixed_orientation = true;  // the checks are taken at a dock: the tilt is tested
  double prior_checks = 6;        // nu0: the prior spread's weight, in checks
  // The prior check-to-check spreads (module header). Gyro: 0.04 deg/s per axis, the repeat
  // set's 0.05-0.07 deg/s between poses over sqrt(2); the fleet's median when known.
  double gyro_spread_prior_rad_s = 0.04 * kDegToRad;
  double accel_spread_prior_m_s2 = 3e-3;  // 0.3 mg
  double tilt_spread_prior_rad = 0.02 * kDegToRad;
  double design_shift_sigmas = 3.0;  // the change the CUSUM is tuned to; k = half of it (<= 3)
  double min_temp_span_c = 5.0;
  double version_disagreement_sigmas = 5.0;
};

struct QuantityEvidence {
  Quantity quantity = Quantity::kAlongGravity;
  bool tested = false;
  double baseline = 0;       // physical unit of the quantity (m/s^2, rad, rad/s)
  double spread = 0;         // sigma
  double dof = 0;            // nu
  double latest_change = 0;  // the last check minus the baseline
  double statistic = 0;      // max(S+, S-) at the last check
  int alarm_check = -1;      // the first check whose statistic reached the alarm threshold
  ChangeKind kind = ChangeKind::kNone;
  int onset_check = -1;  // where the step or the ramp starts (index into the checks)
  double onset_t_s = 0;
  double step_size = 0;               // a step's size (physical)
  double drift_per_day = 0;           // a ramp's slope (physical per day)
  double temp_coefficient_per_c = 0;  // when temperature was regressed (physical per degC)
  double temp_coefficient_se_per_c = 0;
  bool version_disagrees = false;  // the learning baseline is far from the version's figure
  std::vector<double> residual;    // per check: x - baseline (physical), for the plot
  std::vector<double> cusum;       // per check: max(S+, S-) (0 in the learning checks)
};

struct DriftAssessment {
  HealthState state = HealthState::kOk;
  std::string summary;  // one line: what changed, since when, the next action
  int checks = 0;       // those of the version
  int learning = 0;     // of which in the learning window
  double checks_per_day = 0;
  double threshold_alarm = 0;  // h (normal-score units)
  double threshold_watch = 0;
  double design_k = 0;
  int worst = -1;  // index into quantities of the evidence the summary names
  std::vector<QuantityEvidence> quantities;  // kNumQuantities, in Quantity order
};

// `checks` in any order (sorted by t_start_s here); those before reference.activated_s ignored.
DriftAssessment AssessDrift(const std::vector<HealthCheck>& checks, const DriftReference& reference,
                            const DriftOptions& options = {});

// The in-control average run length of a one-sided CUSUM of N(0, 1) increments with reference k
// and threshold h: Siegmund's approximation, and Brook and Evans's Markov chain (60 cells), which
// the threshold uses: at k = 1.5-2.5 and ARL0 1e4-1e5 Siegmund's overstates it 1.1-1.8 times.
double SiegmundArl0(double k, double h);
double CusumArl0(double k, double h);
// The h whose chain ARL0 is `arl0` (Siegmund's h refined by the secant on log ARL0).
double CusumThreshold(double k, double arl0);

}  // namespace imucal::core::health

#endif  // IMUCAL_CORE_HEALTH_DRIFT_H_
