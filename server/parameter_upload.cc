#include "server/parameter_upload.h"

#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/motion/learn.h"
#include "formats/params_check.h"
#include "formats/params_json.h"

namespace imucal::server {
namespace {

// The block's held-out proof: the mean AOE of the recordings it was held out of, static and
// learnt. Empty (count 0) when no recording states both figures.
struct HeldOut {
  int count = 0;
  double static_deg = 0;
  double learnt_deg = 0;
};

HeldOut HeldOutOf(const core::DynamicGyro& block) {
  HeldOut h;
  for (const core::DynamicGyroRecording& r : block.training) {
    if (!std::isfinite(r.aoe_static_deg) || !std::isfinite(r.aoe_learnt_deg)) continue;
    ++h.count;
    h.static_deg += r.aoe_static_deg;
    h.learnt_deg += r.aoe_learnt_deg;
  }
  if (h.count > 0) {
    h.static_deg /= h.count;
    h.learnt_deg /= h.count;
  }
  return h;
}

// Empty when the block has proven itself on held-out recordings by `imucal learn`'s own rule
// (core::motion::JudgeHeldOut); else why not.
std::string DynamicGyroGateFailure(const core::DynamicGyro& block) {
  std::vector<core::DynamicGyroRecording> held_out;
  for (const core::DynamicGyroRecording& r : block.training) {
    if (std::isfinite(r.aoe_static_deg) && std::isfinite(r.aoe_learnt_deg)) held_out.push_back(r);
  }
  if (held_out.empty()) {
    return "dynamic_gyro: no recording it was held out of (training[].aoe_static_deg and "
           "aoe_learnt_deg): a learnt block must beat the static model on recordings it was not "
           "fitted on";
  }
  const core::motion::HeldOutVerdict v = core::motion::JudgeHeldOut(held_out);
  return v.passed ? "" : "dynamic_gyro: " + v.reason;
}

absl::Status UnitMismatch(const char* path, std::string_view stated, const storage::Device& d,
                          const std::string& delivered) {
  return absl::InvalidArgumentError(absl::StrCat(
      path, ": \"", std::string(stated), "\" but device ", d.id, " delivers \"", delivered, "\""));
}

}  // namespace

absl::StatusOr<core::ParamSet> ParseUploadedParams(std::string_view json,
                                                   const storage::Device& device) {
  absl::StatusOr<core::ParamSet> params = formats::ParamSetFromJson(json);
  if (!params.ok()) return params.status();
  // What every robot's SDK would refuse is never stored (formats/params_check.h).
  if (absl::Status s = formats::ModelIsApplicable(*params); !s.ok()) return s;
  if (params->device.empty()) params->device = device.id;
  if (params->device != device.id) {
    return absl::InvalidArgumentError(
        absl::StrCat("device: \"", params->device, "\" but the upload is for device ", device.id));
  }
  if (const std::string_view accel = formats::UnitName(params->accel_unit);
      accel != device.accel_unit) {
    return UnitMismatch("accel.input_unit", accel, device, device.accel_unit);
  }
  if (params->has_gyro) {
    if (const std::string_view gyro = formats::UnitName(params->gyro_unit);
        gyro != device.gyro_unit) {
      return UnitMismatch("gyro.input_unit", gyro, device, device.gyro_unit);
    }
  }
  return params;
}

core::VerdictResult JudgeUploadedParams(const core::ParamSet& params) {
  core::VerdictInputs in;
  in.accel_rms_m_s2 = params.quality_accel_rms_m_s2;
  if (!std::isfinite(params.quality_accel_rms_m_s2)) {
    in.incomplete.push_back(
        "the document states no accelerometer residual (quality.accel_rms): nothing to gate");
  }
  if (params.has_gyro && !params.gyro_calibrated) {
    in.incomplete.push_back("the gyroscope matrix is nominal: only its bias was calibrated");
  }
  core::VerdictResult out = core::JudgeVerdict(in);
  if (params.dynamic_gyro) {
    if (std::string failure = DynamicGyroGateFailure(*params.dynamic_gyro); !failure.empty()) {
      out.verdict = core::Verdict::kFail;
      out.reasons.insert(out.reasons.begin(), std::move(failure));
    }
  }
  return out;
}

std::string UploadProvenance(const core::ParamSet& params, std::string_view actor) {
  std::string out = absl::StrCat("uploaded by ", std::string(actor), "; software ",
                                 params.software.empty() ? "(not stated)" : params.software);
  if (!params.source_session.empty()) absl::StrAppend(&out, "; source ", params.source_session);
  if (!params.dynamic_gyro) return out;
  const core::DynamicGyro& b = *params.dynamic_gyro;
  absl::StrAppendFormat(&out, "; dynamic_gyro at %g Hz, %d taps, dilation %d, ridge %g", b.rate_hz,
                        b.taps, b.dilation, b.ridge_lambda);
  const HeldOut h = HeldOutOf(b);
  if (h.count > 0) {
    absl::StrAppendFormat(&out, ", held-out AOE static %.3g deg learnt %.3g deg (%d recordings)",
                          h.static_deg, h.learnt_deg, h.count);
  }
  absl::StrAppend(&out, "; trained on");
  for (const core::DynamicGyroRecording& r : b.training) {
    absl::StrAppend(&out, " ", r.name, " (sha256 ", r.sha256.empty() ? "?" : r.sha256, ")");
  }
  return out;
}

}  // namespace imucal::server
