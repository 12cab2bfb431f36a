// The verdict of a calibration and the quality gates that decide it, in one place.
//
//   pass     every gate passed and the model is complete
//   warn     usable, but worse than a field calibration should be, or the capture left part of
//            the model undetermined or assumed (the reasons say which)
//   fail     a gate failed: the parameters must not be applied
//   refused  the capture cannot determine the model: no parameters (the report says why and
//            which poses were found)
//
// The gates, on the figures of the final parameter set (effects included, as the SDK applies it):
//   accelerometer |a| - g RMS, in-sample      warn > 0.02 m/s^2 (about 2 mg), fail > 0.05 m/s^2
//   accelerometer |a| - g RMS, held out       fail when it exceeds 5 x what a sound fit leaves:
//                                             k x the in-sample RMS or sqrt(k) x the noise floor,
//                                             whichever is larger, with k = N / (N - p) (N poses,
//                                             p free parameters: a least-squares fit's held-out
//                                             residuals exceed its in-sample ones by about k);
//                                             fail when above 0.05 m/s^2 after dividing by
//                                             sqrt(k) (the noise a held-out residual stands for)
//   gravity direction after moves, in-sample  warn > 1 degree RMS, fail > 5 degrees RMS
//   gravity direction after moves, held out   fail > 5 degrees RMS, or > 5 x the gyroscope fit's
//                                             own in-sample RMS when above 1 degree (the held-out
//                                             figure is the fit's, a refit without the move)
//   every estimated parameter                 fail when its standard error is wider than the range
//                                             a sensor plausibly has (the data did not determine
//                                             it; accel_solver.h AccelPlausibleRange, and
//                                             kGyroPlausibleRelative of the gyroscope's scale)
//   a model the capture left incomplete       at best warn (undetermined first-order parameters,
//   or assumed                                an uncalibrated gyroscope, a rejected six-face pair,
//                                             a floor assumed level, no redundancy to check a fit)
// A few mg is what a field calibration of a MEMS unit should reach; a gravity-direction error
// above a degree after a move ruins a heading within minutes. A sound fit predicts the poses it
// was not fitted to about as well as k says: on every simulated and real capture measured
// (README "Quality gates") the held-out RMS is 1.2-2 x the in-sample one, within k. Five times
// that means the fit explains its own poses and nothing else: a pose fragment, a missing face, a
// wrong model.
#ifndef IMUCAL_CORE_CALIBRATE_VERDICT_H_
#define IMUCAL_CORE_CALIBRATE_VERDICT_H_

#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace imucal::core {

enum class Verdict { kPass, kWarn, kFail, kRefused };

// "pass", "warn", "fail", "refused": the names of the report (../shared/spec/report.md) and the
// service.
std::string_view VerdictName(Verdict verdict);
std::optional<Verdict> ParseVerdict(std::string_view name);

inline constexpr double kAccelPassRmsM_s2 = 0.02;
inline constexpr double kAccelFailRmsM_s2 = 0.05;
inline constexpr double kMovePassRmsDeg = 1.0;
inline constexpr double kMoveFailRmsDeg = 5.0;
inline constexpr double kHeldOutFailRatio = 5.0;
// A MEMS gyroscope's scale factor is specified within a few percent and its axes within tens of
// milliradians: a matrix entry known no better than 5 % of the scale is not a calibration.
inline constexpr double kGyroPlausibleRelative = 0.05;

// One estimated parameter's standard error against the range a sensor plausibly has.
struct ParameterSpread {
  std::string name;  // "accel bias_x", "gyro matrix (y,y)"
  double std_error = 0;
  double plausible = 0;  // same unit
};

// What the gates read. NaN: the figure was not computed (no gate).
struct VerdictInputs {
  static constexpr double kNone = std::numeric_limits<double>::quiet_NaN();
  double accel_rms_m_s2 = 0;
  double accel_heldout_rms_m_s2 = kNone;
  double accel_noise_floor_m_s2 = kNone;
  // N / (N - p): the held-out residuals' expected inflation over the in-sample ones (1 when
  // unknown).
  double accel_heldout_inflation = 1;
  double move_rms_deg = kNone;
  double move_fit_rms_deg = kNone;  // the fit's own in-sample figure, beside its held-out one
  double move_heldout_rms_deg = kNone;
  std::vector<ParameterSpread> parameters;
  // Poses that alone determine part of the model (leverage 0.95 or more: a face held once), as
  // "X+ (pose 4)". Left out, nothing else fixes that part, so their held-out residuals are large
  // whatever the fit: they judge the capture, not the fit. When they alone fail the held-out
  // gate, it reads the other poses' figure (the held-out RMS scaled by the ratio of the poses'
  // own held-out RMS without and with the lone ones) and the verdict warns, naming them.
  std::vector<std::string> lone_poses;
  // How many of them are faces of the protocol (a face held once, without its pair): they warn
  // even when the held-out figure passes, since nothing checks them.
  int lone_faces = 0;
  double accel_heldout_checked_rms_m_s2 = kNone;
  double accel_heldout_lone_rms_m_s2 = kNone;
  // Why the model is incomplete or assumed (at best warn), in a technician's words.
  std::vector<std::string> incomplete;
};

struct VerdictResult {
  Verdict verdict = Verdict::kPass;
  // Every gate that failed or warned, and every incompleteness, in a technician's words.
  std::vector<std::string> reasons;
};

VerdictResult JudgeVerdict(const VerdictInputs& in);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_CALIBRATE_VERDICT_H_
