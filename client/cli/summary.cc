#include "client/cli/summary.h"

#include <cmath>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "util/units.h"

namespace imucal::cli {
namespace {

// m/s^2 with its equivalent in micro-g (what accelerometer datasheets use).
std::string Accel(double v, double g) {
  if (!std::isfinite(v)) return "n/a";
  return absl::StrFormat("%.6f m/s^2 (%.1f ug)", v, 1e6 * v / g);
}

std::string Vec(const Eigen::Vector3d& v, int digits) {
  return absl::StrFormat("[%.*g, %.*g, %.*g]", digits, v.x(), digits, v.y(), digits, v.z());
}

// One figure's three axes: "%.3g", "<%.3g" for an upper bound (bound given, value NaN), "n/a".
std::string Figure(const Eigen::Vector3d& v, const Eigen::Vector3d* bound, bool* bounded) {
  std::string out = "[";
  for (int i = 0; i < 3; ++i) {
    if (i > 0) out += ", ";
    if (std::isfinite(v(i))) {
      absl::StrAppendFormat(&out, "%.3g", v(i));
    } else if (bound != nullptr && std::isfinite((*bound)(i))) {
      absl::StrAppendFormat(&out, "<%.3g", (*bound)(i));
      *bounded = true;
    } else {
      out += "n/a";
    }
  }
  return out + "]";
}

void AppendSensorFigures(const char* sensor, const core::SensorNoise& s, const char* unit_n,
                         const char* unit_b, const char* unit_k, std::string* out) {
  bool bounded = false;
  const std::string n = Figure(s.noise_density, nullptr, &bounded);
  const std::string b = Figure(s.bias_instability, nullptr, &bounded);
  const std::string k = Figure(s.random_walk, &s.random_walk_bound, &bounded);
  absl::StrAppendFormat(out, "  %-5s N   %s %s  white-noise density\n", sensor, n, unit_n);
  absl::StrAppendFormat(out, "  %-5s B   %s %s  bias instability\n", sensor, b, unit_b);
  absl::StrAppendFormat(
      out, "  %-5s K   %s %s  rate random walk%s\n", sensor, k, unit_k,
      bounded ? "; <: UPPER BOUND, not reached by the rest (not a measurement)" : "");
}

}  // namespace

std::string FormatAllanFigures(const std::optional<core::NoiseFigures>& noise, bool has_gyro) {
  if (!noise.has_value()) {
    return "allan       no noise figures (no used static interval long enough for an Allan "
           "deviation)\n";
  }
  const core::NoiseFigures& n = *noise;
  std::string s = absl::StrFormat(
      "allan       Allan deviation over the rest %.1f-%.1f s (%d samples at %g Hz), calibrated, "
      "continuous-time; n/a: not reached\n",
      n.t_start_s, n.t_end_s, static_cast<int>(n.samples), n.rate_hz);
  AppendSensorFigures("accel", n.accel, "m/s^2/sqrt(Hz)", "m/s^2", "m/s^3/sqrt(Hz)", &s);
  if (has_gyro) {
    AppendSensorFigures("gyro", n.gyro, "rad/s/sqrt(Hz)", "rad/s", "rad/s^2/sqrt(Hz)", &s);
  }
  for (const std::string& note : n.notes) absl::StrAppendFormat(&s, "  note: %s\n", note);
  return s;
}

namespace {

// What the capture held: the device, the protocol, the noise, the poses and the pairs.
void AppendCapture(const core::CalibrationReport& r, std::string* out) {
  std::string& s = *out;
  const core::ParamSet& p = r.params;
  int used = 0;
  for (const auto& pose : r.poses) used += pose.interval.used;
  absl::StrAppendFormat(&s, "device      %s\n", r.device.empty() ? "(unnamed)" : r.device);
  absl::StrAppendFormat(&s, "protocol    %s%s\n", core::ProtocolKindName(r.protocol),
                        r.protocol_detected ? " (detected)" : " (declared)");
  if (p.has_gyro) {
    absl::StrAppendFormat(&s, "noise       accel %s %s, gyro %s %s per sample; from the %s\n",
                          Vec(r.noise.accel_std, 3), core::AccelUnitName(p.accel_unit),
                          Vec(r.noise.gyro_std, 3), core::GyroUnitName(p.gyro_unit),
                          r.noise.source);
  } else {
    absl::StrAppendFormat(&s, "sensors     accelerometer only (the capture has no gyroscope)\n");
    absl::StrAppendFormat(&s, "noise       accel %s %s per sample; from the %s\n",
                          Vec(r.noise.accel_std, 3), core::AccelUnitName(p.accel_unit),
                          r.noise.source);
  }
  s += FormatAllanFigures(p.noise, p.has_gyro);
  absl::StrAppendFormat(&s, "poses       %d static intervals, %d used (threshold %.0fx noise)\n",
                        static_cast<int>(r.poses.size()), used, r.threshold_multiplier);
  for (const auto& pose : r.poses) {
    if (pose.interval.used) continue;
    absl::StrAppendFormat(&s, "  pose %-3d  %6.1f-%6.1f s  not used: %s\n", pose.index,
                          pose.interval.t_start_s, pose.interval.t_end_s, pose.interval.reason);
  }
  for (const auto& pair : r.pairs) {
    const std::string turn = pair.turn_checked
                                 ? absl::StrFormat("turn %6.1f deg", pair.rotation_deg)
                                 : std::string("turn not checked");
    absl::StrAppendFormat(&s, "  pair %2d+%-2d %-3s %-8s %s, tilt %.2f deg %s\n", pair.pose_a,
                          pair.pose_b, pair.face, pair.ok ? "ok" : "REJECTED", turn, pair.tilt_deg,
                          pair.reason);
  }
}

// The fit: each stage, the residuals, the turns and the moves.
void AppendFit(const core::CalibrationReport& r, std::string* out) {
  std::string& s = *out;
  const double g = r.gravity_m_s2;
  const core::ParamSet& p = r.params;
  // Each stage's unweighted |a| - g RMS over the used poses; bsas and lm minimise the cost
  // weighted by each pose's noise (and the face references' priors), so theirs may sit above ls.
  s += "stages      (|a|-g RMS, unweighted; ls fits it, bsas and lm the noise-weighted cost)\n";
  s += "            ";
  for (const auto& st : r.stages)
    absl::StrAppendFormat(&s, "%s %.1f ug (%.1f ms)   ", st.name, 1e6 * st.accel_rms_m_s2 / g,
                          st.ms);
  s += "\n";
  const core::Residuals& res = r.residual;
  absl::StrAppendFormat(&s, "accel       |a|-g RMS %s, max %s\n", Accel(res.accel_rms_m_s2, g),
                        Accel(res.accel_max_m_s2, g));
  absl::StrAppendFormat(&s, "            held out (leave one pose out) RMS %s, max %s\n",
                        Accel(res.accel_heldout_rms_m_s2, g), Accel(res.accel_heldout_max_m_s2, g));
  if (!p.has_gyro) {
    // Nothing to print: an accelerometer-only parameter set has no gyro figure, not a zero one.
  } else if (p.gyro_unit == core::GyroUnit::kCounts && !p.gyro_calibrated) {
    // No scale was determined: the residual rate is still in the sensor's counts.
    absl::StrAppendFormat(&s, "gyro        static rate RMS %.3g counts (scale not calibrated)\n",
                          res.gyro_static_rms_rad_s);
  } else {
    absl::StrAppendFormat(&s, "gyro        static rate RMS %.3g deg/s\n",
                          res.gyro_static_rms_rad_s * kRadToDeg);
  }
  for (const auto& t : r.turns) {
    // A turn is measured with the calibrated gyroscope: without its scale (raw counts, only the
    // bias calibrated) there is no angle to print, and "nan deg" said nothing true.
    const std::string measured =
        std::isfinite(t.angle_deg)
            ? absl::StrFormat("measured %.2f deg, error %.2f deg", t.angle_deg, t.error_deg)
            : std::string("not measured (the gyroscope's scale was not calibrated)");
    absl::StrAppendFormat(&s, "  turn      %6.1f-%6.1f s  %d x 360 deg about %s: %s\n", t.t_start_s,
                          t.t_end_s, t.turns, t.axis, measured);
  }
  if (std::isfinite(res.move_rms_deg)) {
    absl::StrAppendFormat(
        &s,
        "            gravity direction after %d moves, final parameters as a robot applies them: "
        "RMS %.3f deg, max %.3f deg\n",
        static_cast<int>(r.moves.size()), res.move_rms_deg, res.move_max_deg);
    // The gyroscope's own fit has no figure when only its bias was calibrated: say so, not nan.
    if (std::isfinite(res.move_fit_rms_deg)) {
      absl::StrAppendFormat(&s,
                            "            the gyroscope fit's own (bias between poses): RMS %.3f "
                            "deg; held out RMS %.3f deg, max %.3f deg\n",
                            res.move_fit_rms_deg, res.move_heldout_rms_deg,
                            res.move_heldout_max_deg);
    } else {
      s += "            the gyroscope fit's own: none (only its bias was calibrated)\n";
    }
  }
}

// The parameters, in the inverse model's units.
void AppendParameters(const core::CalibrationReport& r, std::string* out) {
  std::string& s = *out;
  const core::ParamSet& p = r.params;
  absl::StrAppendFormat(&s, "parameters  (inverse model raw -> SI; see `model` in the JSON)\n");
  absl::StrAppendFormat(&s, "  accel bias     %s %s\n", Vec(p.accel.bias, 6),
                        core::AccelUnitName(p.accel_unit));
  absl::StrAppendFormat(&s, "  accel scale    %s m/s^2 per %s\n", Vec(p.accel.scale, 6),
                        core::AccelUnitName(p.accel_unit));
  absl::StrAppendFormat(&s, "  accel t_yx,t_zx,t_zy %s rad; frame %s rad; quadratic %s 1/(m/s^2)\n",
                        Vec(p.accel.tri_angles, 3), Vec(p.accel.frame_angles, 3),
                        Vec(p.accel.quadratic, 3));
  if (p.has_gyro) {
    absl::StrAppendFormat(&s, "  gyro bias      %s %s\n", Vec(p.gyro.bias, 6),
                          core::GyroUnitName(p.gyro_unit));
    absl::StrAppendFormat(&s, "  gyro scale     %s rad/s per %s%s\n",
                          Vec(p.gyro.matrix.diagonal(), 6), core::GyroUnitName(p.gyro_unit),
                          p.gyro_calibrated ? "" : " (NOT calibrated: nominal)");
  } else {
    s += "  gyro           none (accelerometer-only capture)\n";
  }
}

// The effects found, with their evidence, and the search's notes.
void AppendEffects(const core::CalibrationReport& r, std::string* out) {
  std::string& s = *out;
  const double g = r.gravity_m_s2;
  const core::ParamSet& p = r.params;
  const core::EffectDiagnostics& d = r.effect_diagnostics;
  if (d.ran) {
    absl::StrAppendFormat(
        &s,
        "effects     %d found among %d candidates (%d are the model's own terms, %d not "
        "testable at rest%s)\n",
        static_cast<int>(p.effects.size()), d.candidates, d.absorbed, d.not_excited,
        d.move_search.ran ? absl::StrFormat("; %d rate terms tested on the %d moves",
                                            d.move_search.candidates, d.move_search.moves)
                          : "");
    for (const core::Effect& e : p.effects) {
      const bool accel = e.sensor == core::Sensor::kAccel;
      if (!accel && std::isnan(e.error_before)) {  // a rate term: the moves are its figure
        absl::StrAppendFormat(
            &s, "  gyro  %c ~ %-16s %s; held out by move, gravity direction %.3f -> %.3f deg\n",
            "xyz"[e.axis], e.regressor, core::HumanCoefficient(e),
            d.move_search.heldout_before_rad * kRadToDeg,
            d.move_search.heldout_after_rad * kRadToDeg);
        continue;
      }
      absl::StrAppendFormat(&s, "  %s %c ~ %-16s %s; held-out %s %s -> %s%s\n",
                            accel ? "accel" : "gyro ", "xyz"[e.axis], e.regressor,
                            core::HumanCoefficient(e), accel ? "|a|-g" : "rate",
                            accel ? absl::StrFormat("%.3f mg", 1e3 * e.error_before / g)
                                  : absl::StrFormat("%.4f deg/s", e.error_before * kRadToDeg),
                            accel ? absl::StrFormat("%.3f mg", 1e3 * e.error_after / g)
                                  : absl::StrFormat("%.4f deg/s", e.error_after * kRadToDeg),
                            e.applied ? "" : "  (reported, not applied)");
    }
    for (const auto& n : d.notes) absl::StrAppendFormat(&s, "  %s\n", n);
    if (!d.faces.empty()) {
      s += "  per-axis residual of each verified face (along its turn axis), mg:";
      for (const core::FaceResidual& f : d.faces)
        absl::StrAppendFormat(&s, " %s %s", f.face, Vec(f.residual_m_s2 * (1e3 / g), 2));
      s += "\n";
    }
  }
}

}  // namespace

std::string FormatSummary(const core::CalibrationReport& r) {
  std::string s;
  AppendCapture(r, &s);
  // A refused capture has no fit and no parameters: the verdict and its reasons say why.
  if (r.verdict != core::Verdict::kRefused) {
    AppendFit(r, &s);
    AppendParameters(r, &s);
    AppendEffects(r, &s);
  }
  absl::StrAppendFormat(&s, "verdict     %s   (%.0f ms)\n", core::VerdictName(r.verdict),
                        r.total_ms);
  for (const auto& reason : r.verdict_reasons)
    absl::StrAppendFormat(&s, "reason      %s\n", reason);
  for (const auto& w : r.warnings) absl::StrAppendFormat(&s, "warning     %s\n", w);
  return s;
}

}  // namespace imucal::cli
