#include "formats/report_json.h"

#include <cmath>

#include "formats/params_json.h"
#include "nlohmann/json.hpp"

namespace imucal::formats {
namespace {

using nlohmann::json;

json Num(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

json Vec(const Eigen::Vector3d& v) { return json::array({Num(v.x()), Num(v.y()), Num(v.z())}); }

// `has_gyro` false (an accelerometer-only capture): the gyro mean is left out, not written as
// the zero nothing measured.
json PoseJson(const core::PoseReport& p, bool has_gyro) {
  const core::StaticInterval& s = p.interval;
  json j = {{"index", p.index},
            {"t_start", s.t_start_s},
            {"t_end", s.t_end_s},
            {"samples", s.samples()},
            {"accel_mean", Vec(s.accel_mean)},
            {"gyro_mean", Vec(s.gyro_mean)},
            {"temp_mean", Num(s.temp_mean)},
            {"used", s.used},
            {"reason", s.reason},
            {"issue", std::string(core::IntervalIssueName(s.issue))},
            {"face", p.face},
            {"up", Vec(p.up)},
            {"residual", Num(p.residual_m_s2)},
            {"residual_heldout", Num(p.heldout_m_s2)}};
  if (!has_gyro) j.erase("gyro_mean");
  if (!p.file.empty()) j["file"] = p.file;
  if (p.first_line > 0) j["lines"] = {p.first_line, p.last_line};
  return j;
}

}  // namespace

// What the effect search examined, and per used pose the signals and the residuals without and
// with the effects (the data of the plots).
// The gyroscope's bias between poses (core/bias_wander.h), rad/s.
json WanderJson(const core::BiasWander& w) {
  json j;
  j["poses"] = w.poses;
  j["static_rms"] = w.static_rms_rad_s;
  j["noise_floor"] = w.noise_floor_rad_s;
  j["heldout_before"] = w.heldout_before_rad_s;
  j["heldout_after"] = w.heldout_after_rad_s;
  j["step_rms"] = w.step_rms_rad_s;
  j["median_dt_s"] = w.median_dt_s;
  j["allan_step"] = Num(w.allan_step_rad_s);
  j["allan_is_bound"] = w.allan_is_bound;
  j["within_pose_ratio"] = Num(w.within_pose_ratio);
  j["drift_within_pose_ratio"] = Num(w.drift_within_pose_ratio);
  j["axes"] = json::array();
  for (const core::AxisWander& a : w.axes) {
    j["axes"].push_back({{"model", core::WanderModelName(a.model)},
                         {"shift", a.shift_rad_s},
                         {"walk", a.walk_rad_s},
                         {"bic", a.bic},
                         {"heldout_before", a.heldout_before_rad_s},
                         {"heldout_after", a.heldout_after_rad_s}});
  }
  j["smoothed"] = json::array();  // per used pose: the persistent bias c + x_k
  for (const auto& v : w.smoothed_rad_s) j["smoothed"].push_back(Vec(v));
  j["units"] = "rad/s (walk: the step per move); bic per model none, shift, walk, shift+walk";
  j["note"] = w.note;
  return j;
}

// What a capture could not have missed (core/move_effects.h DetectionBound): coefficient in SI
// per regressor unit, null where the capture does not excite the form.
json DetectionBoundsJson(const std::vector<core::DetectionBound>& bounds) {
  json out = json::array();
  for (const core::DetectionBound& b : bounds) {
    out.push_back({{"sensor", b.sensor == core::Sensor::kAccel ? "accel" : "gyro"},
                   {"axis", std::string(1, "xyz"[b.axis])},
                   {"regressor", b.regressor},
                   {"coefficient", Num(b.coefficient)},
                   {"human", std::isfinite(b.coefficient)
                                 ? core::HumanValue(b.sensor, b.regressor, b.coefficient)
                                 : std::string("not excited")},
                   {"from", b.from}});
  }
  return out;
}

namespace {

// The rate-dependent gyroscope terms tested on the moves (core/move_effects.h).
json MoveSearchJson(const core::MoveEffectDiagnostics& m) {
  json ms;
  ms["ran"] = m.ran;
  ms["units"] =
      "gravity-direction error after the moves, RMS over them, rad; coefficients rad/s per "
      "regressor unit";
  ms["moves"] = m.moves;
  ms["candidates"] = m.candidates;
  ms["not_excited"] = m.not_excited;
  ms["rounds"] = m.rounds;
  ms["heldout_before"] = Num(m.heldout_before_rad);
  ms["heldout_after"] = Num(m.heldout_after_rad);
  ms["in_sample_before"] = Num(m.in_sample_before_rad);
  ms["in_sample_after"] = Num(m.in_sample_after_rad);
  ms["noise_floor"] = Num(m.noise_floor_rad);
  ms["heldout_before_per_move"] = json::array();
  for (double e : m.heldout_before_per_move_rad) ms["heldout_before_per_move"].push_back(Num(e));
  ms["heldout_after_per_move"] = json::array();
  for (double e : m.heldout_after_per_move_rad) ms["heldout_after_per_move"].push_back(Num(e));
  ms["top_candidates"] = json::array();
  for (const core::MoveCandidateScore& c : m.top) {
    ms["top_candidates"].push_back({{"sensor", "gyro"},
                                    {"axis", std::string(1, "xyz"[c.axis])},
                                    {"regressor", c.regressor},
                                    {"f", Num(c.f)},
                                    {"f_threshold", Num(c.f_threshold)},
                                    {"delta_bic", Num(c.delta_bic)},
                                    {"heldout_gain", Num(c.press_gain)},
                                    {"heldout_gain_without_best_2", Num(c.trimmed_gain)},
                                    {"coefficient", Num(c.coefficient)},
                                    {"passed", c.passed}});
  }
  ms["turn_angles_moves_only"] = json::array();
  for (double a : m.turn_angle_moves_only_rad) ms["turn_angles_moves_only"].push_back(Num(a));
  ms["detection_bounds"] = DetectionBoundsJson(m.detection_bounds);
  return ms;
}

// Each pose's signals and residuals before, after and with every effect found.
json EffectRowsJson(const std::vector<core::EffectPoseRow>& rows) {
  json out = json::array();
  for (const core::EffectPoseRow& row : rows) {
    json signals;
    for (int s = 0; s < core::kNumSignals; ++s)
      signals[std::string(core::kSignalNames[static_cast<size_t>(s)])] =
          Num(row.signals[static_cast<size_t>(s)]);
    out.push_back({{"index", row.pose_index},
                   {"signals", std::move(signals)},
                   {"accel_before", Num(row.accel_before_m_s2)},
                   {"accel_after", Num(row.accel_after_m_s2)},
                   {"accel_all", Num(row.accel_all_m_s2)},
                   {"gyro_before", Vec(row.gyro_before_rad_s)},
                   {"gyro_after", Vec(row.gyro_after_rad_s)},
                   {"gyro_all", Vec(row.gyro_all_rad_s)}});
  }
  return out;
}

}  // namespace

json DiagnosticsJson(const core::EffectDiagnostics& d) {
  json j;
  j["ran"] = d.ran;
  j["rounds"] = d.rounds;
  j["candidates"] = d.candidates;
  j["absorbed_by_model"] = d.absorbed;
  j["not_excited"] = d.not_excited;
  j["accel_noise_floor"] = Num(d.accel_noise_floor_m_s2);
  j["gyro_noise_floor"] = Num(d.gyro_noise_floor_rad_s);
  j["accel_heldout_before"] = Num(d.accel_heldout_before_m_s2);
  j["accel_heldout_after"] = Num(d.accel_heldout_after_m_s2);
  j["gyro_heldout_before"] = Num(d.gyro_heldout_before_rad_s);
  j["gyro_heldout_after"] = Num(d.gyro_heldout_after_rad_s);
  j["units"] =
      "accel m/s^2, gyro rad/s; signals: temperature degC, time s, ax..az m/s^2, gx..gz rad/s; "
      "per pose: _before without effects, _after the stored model (applied effects), _all every "
      "effect found";
  j["top_candidates"] = json::array();
  for (const core::CandidateScore& c : d.top) {
    j["top_candidates"].push_back({{"sensor", c.sensor == core::Sensor::kGyro ? "gyro" : "accel"},
                                   {"axis", std::string(1, "xyz"[c.axis])},
                                   {"regressor", c.regressor},
                                   {"f", Num(c.f)},
                                   {"f_threshold", Num(c.f_threshold)},
                                   {"delta_bic", Num(c.delta_bic)},
                                   {"heldout_gain", Num(c.press_gain)},
                                   {"coefficient", Num(c.coefficient)},
                                   {"passed", c.passed}});
  }
  j["poses"] = EffectRowsJson(d.rows);
  j["faces"] = json::array();
  for (const core::FaceResidual& f : d.faces)
    j["faces"].push_back({{"face", f.face}, {"residual", Vec(f.residual_m_s2)}});
  // The gravity-direction error after the moves regressed on each signal of the moves (the
  // rotation residuals; effects.h MoveTrend): slope and standard error in `unit`.
  j["move_trends"] = json::array();
  for (const core::MoveTrend& t : d.move_trends) {
    j["move_trends"].push_back({{"signal", t.signal},
                                {"unit", t.unit},
                                {"slope", Num(t.slope_deg)},
                                {"stderr", Num(t.slope_std_error_deg)},
                                {"f", Num(t.f)},
                                {"f_threshold", Num(t.f_threshold)},
                                {"significant", t.significant}});
  }
  j["move_search"] = MoveSearchJson(d.move_search);
  j["detection_bounds"] = DetectionBoundsJson(d.detection_bounds);
  j["notes"] = d.notes;
  return j;
}

namespace {

// The pairs, the moves between poses, the solver's stages and the full turns.
void PosesAndMovesJson(const core::CalibrationReport& r, json* out) {
  json& j = *out;
  j["pairs"] = json::array();
  for (const auto& p : r.pairs) {
    j["pairs"].push_back({{"poses", {p.pose_a, p.pose_b}},
                          {"status", p.ok ? "ok" : "rejected"},
                          {"face", p.face},
                          {"tilt_deg", p.tilt_deg},
                          {"rotation_deg", Num(p.rotation_deg)},
                          {"turn_checked", p.turn_checked},
                          {"reason", p.reason}});
  }
  j["moves"] = json::array();
  for (const auto& m : r.moves) {
    j["moves"].push_back({{"poses", {m.from_pose, m.to_pose}},
                          {"rotation_deg", m.rotation_deg},
                          {"gravity_error_deg", m.error_deg},
                          {"gravity_error_heldout_deg", Num(m.heldout_error_deg)}});
  }
  j["stages"] = json::array();
  for (const auto& s : r.stages) {
    json stage = {{"name", s.name},
                  {"accel_rms", s.accel_rms_m_s2},
                  {"iterations", s.iterations},
                  {"evaluations", s.evaluations},
                  {"ms", s.ms}};
    // |a| - g per used pose after the stage (m/s^2): the per-pose plot's data.
    if (!s.pose_indices.empty()) {
      stage["poses"] = s.pose_indices;
      json residuals = json::array();
      for (double v : s.pose_residual_m_s2) residuals.push_back(Num(v));
      stage["pose_residual"] = std::move(residuals);
    }
    j["stages"].push_back(std::move(stage));
  }
  // Full turns about one axis (Ferraris): the known 360-degree angles that fix the gyro scale.
  j["turns"] = json::array();
  for (const auto& t : r.turns) {
    j["turns"].push_back({{"t_start", t.t_start_s},
                          {"t_end", t.t_end_s},
                          {"turns", t.turns},
                          {"axis", t.axis},
                          {"axis_body", Vec(t.axis_body)},
                          {"angle_deg", Num(t.angle_deg)},
                          {"error_deg", Num(t.error_deg)}});
  }
}

// The residuals of the fit, and what each prior did to its term.
void FitJson(const core::CalibrationReport& r, json* out) {
  json& j = *out;
  const bool has_gyro = r.params.has_gyro;
  const core::Residuals& res = r.residual;
  j["residual"] = {{"accel_rms", res.accel_rms_m_s2},
                   {"accel_max", res.accel_max_m_s2},
                   {"accel_noise_floor", Num(res.accel_noise_floor_m_s2)},
                   {"accel_heldout_rms", Num(res.accel_heldout_rms_m_s2)},
                   {"accel_heldout_max", Num(res.accel_heldout_max_m_s2)},
                   {"accel_chi2_reduced", r.accel_chi2_reduced},
                   {"gyro_static_rms", res.gyro_static_rms_rad_s},
                   {"gravity_direction_rms_deg", Num(res.move_rms_deg)},
                   {"gravity_direction_max_deg", Num(res.move_max_deg)},
                   {"gravity_direction_fit_rms_deg", Num(res.move_fit_rms_deg)},
                   {"gravity_direction_heldout_rms_deg", Num(res.move_heldout_rms_deg)},
                   {"gravity_direction_heldout_max_deg", Num(res.move_heldout_max_deg)}};
  if (!has_gyro) j["residual"].erase("gyro_static_rms");
  // Beside the spec's fields: what each prior did to its term (parameter units; data_sigma null
  // when the poses add nothing beyond the prior).
  j["term_priors"] = json::array();
  for (const core::TermPriorEffect& e : r.term_priors) {
    j["term_priors"].push_back({{"name", e.name},
                                {"source", e.source},
                                {"estimate", e.estimate},
                                {"prior_value", e.prior_value},
                                {"prior_sigma", e.prior_sigma},
                                {"posterior_sigma", e.posterior_sigma},
                                {"data_sigma", Num(e.data_sigma)},
                                {"data_weight", e.data_weight}});
  }
}

}  // namespace

std::string ReportToJson(const core::CalibrationReport& r) {
  json j;
  j["format"] = "imucal-report v1";
  j["device"] = r.device;
  j["gravity"] = r.gravity_m_s2;
  j["protocol"] = std::string(core::ProtocolKindName(r.protocol));
  j["protocol_detected"] = r.protocol_detected;
  j["noise"] = {{"accel_std", Vec(r.noise.accel_std)},
                {"gyro_std", Vec(r.noise.gyro_std)},
                {"units", "input units per sample"},
                {"source", r.noise.source},
                {"static_threshold_multiplier", r.threshold_multiplier}};
  j["poses"] = json::array();
  const bool has_gyro = r.params.has_gyro;
  if (!has_gyro) j["noise"].erase("gyro_std");
  for (const auto& p : r.poses) j["poses"].push_back(PoseJson(p, has_gyro));
  PosesAndMovesJson(r, &j);
  // Allan deviation of the calibrated signals over the rest the noise block was measured on.
  if (!r.allan.tau_s.empty()) {
    json accel = json::array(), gyro = json::array();
    for (const auto& v : r.allan.accel_m_s2) accel.push_back(Vec(v));
    for (const auto& v : r.allan.gyro_rad_s) gyro.push_back(Vec(v));
    j["allan"] = {{"tau", r.allan.tau_s},
                  {"accel", std::move(accel)},
                  {"gyro", std::move(gyro)},
                  {"units", "tau s; accel m/s^2; gyro rad/s (Allan deviation, per axis x y z)"}};
    if (!has_gyro) j["allan"].erase("gyro");
  }
  FitJson(r, &j);
  json params = json::parse(ParamSetToJson(r.params));
  j["effects"] = params.contains("effects") ? params["effects"] : json::array();
  // Beside the spec's fields: the coefficient in an engineer's units (mg/degC, deg/s/g, ...).
  for (size_t k = 0; k < r.params.effects.size() && k < j["effects"].size(); ++k)
    j["effects"][k]["human"] = core::HumanCoefficient(r.params.effects[k]);
  // Without a gyroscope the search did not run: only its notes say why (no gyro figures).
  if (!has_gyro && !r.effect_diagnostics.notes.empty())
    j["effect_diagnostics"] = {{"notes", r.effect_diagnostics.notes}};
  else if (r.effect_diagnostics.ran || !r.effect_diagnostics.notes.empty())
    j["effect_diagnostics"] = DiagnosticsJson(r.effect_diagnostics);
  if (r.gyro_wander.ran) j["gyro_wander"] = WanderJson(r.gyro_wander);
  // A refused capture has no parameters to apply: the report says why, not a confident number.
  if (r.verdict != core::Verdict::kRefused) j["parameters"] = std::move(params);
  j["verdict"] = std::string(core::VerdictName(r.verdict));
  j["verdict_reasons"] = r.verdict_reasons;
  // Beside the spec's fields: the units the capture was read in and how each was decided
  // ("declared": --accel-unit/--gyro-unit; "file": the format or its header; "inferred":
  // importers/unit_inference.h; "unstated": a device's registration or a capture in memory).
  auto source = [](const std::string& s) { return s.empty() ? std::string("unstated") : s; };
  j["input_units"] = {{"accel", std::string(core::AccelUnitName(r.input_units.accel))},
                      {"gyro", std::string(core::GyroUnitName(r.input_units.gyro))},
                      {"accel_source", source(r.input_units.accel_source)},
                      {"gyro_source", source(r.input_units.gyro_source)}};
  if (r.refusal) {
    j["refusal"] = {{"reason", std::string(core::RefusalReasonName(r.refusal->reason))},
                    {"message", r.refusal->message}};
  }
  j["warnings"] = r.warnings;
  j["ms"] = r.total_ms;
  for (const auto& [phase, ms] : r.phase_ms) j["phase_ms"][phase] = ms;
  return j.dump(2) + "\n";
}

}  // namespace imucal::formats
