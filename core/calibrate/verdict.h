// The verdict of a calibration and the quality gates that decide it, in one place.
//
//   pass  every gate passed and the model is complete
//   warn  the calibration is usable but worse than a field calibration should be, or the capture
//         left part of the model undetermined (the warnings say which)
//   fail  a gate failed: the parameters must not be applied
//
// The gates, on the report's figures (in-sample, with the final parameters):
//   accelerometer |a| - g RMS       pass <= 0.02 m/s^2 (about 2 mg), fail > 0.05 m/s^2 (5 mg)
//   gravity direction after moves   pass <= 1 degree RMS, fail > 5 degrees RMS
// A few mg is what a field calibration of a MEMS unit should reach; a gravity-direction error
// above a degree after a move ruins a heading within minutes.
#ifndef IMUCAL_CORE_CALIBRATE_VERDICT_H_
#define IMUCAL_CORE_CALIBRATE_VERDICT_H_

#include <optional>
#include <string_view>

namespace imucal::core {

enum class Verdict { kPass, kWarn, kFail };

// "pass", "warn", "fail": the names of the report (../shared/spec/report.md) and the service.
std::string_view VerdictName(Verdict verdict);
std::optional<Verdict> ParseVerdict(std::string_view name);

inline constexpr double kAccelPassRmsM_s2 = 0.02;
inline constexpr double kAccelFailRmsM_s2 = 0.05;
inline constexpr double kMovePassRmsDeg = 1.0;
inline constexpr double kMoveFailRmsDeg = 5.0;

// What the gates read.
struct VerdictInputs {
  double accel_rms_m_s2 = 0;
  double move_rms_deg = 0;  // NaN when no move was fitted (no gate)
  // The capture left a first-order parameter undetermined, the gyroscope uncalibrated or a
  // six-face pair rejected: at best warn.
  bool degraded = false;
};

Verdict JudgeVerdict(const VerdictInputs& in);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_CALIBRATE_VERDICT_H_
