#include "core/calibrate/verdict.h"

#include <cmath>

namespace imucal::core {

std::string_view VerdictName(Verdict verdict) {
  switch (verdict) {
    case Verdict::kPass:
      return "pass";
    case Verdict::kWarn:
      return "warn";
    case Verdict::kFail:
      return "fail";
  }
  return "fail";
}

std::optional<Verdict> ParseVerdict(std::string_view name) {
  for (Verdict v : {Verdict::kPass, Verdict::kWarn, Verdict::kFail})
    if (VerdictName(v) == name) return v;
  return std::nullopt;
}

Verdict JudgeVerdict(const VerdictInputs& in) {
  const double move = in.move_rms_deg;
  if (in.accel_rms_m_s2 > kAccelFailRmsM_s2 || (std::isfinite(move) && move > kMoveFailRmsDeg))
    return Verdict::kFail;
  if (in.degraded || in.accel_rms_m_s2 > kAccelPassRmsM_s2 ||
      (std::isfinite(move) && move > kMovePassRmsDeg))
    return Verdict::kWarn;
  return Verdict::kPass;
}

}  // namespace imucal::core
