#include "formats/plots.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>

#include "absl/strings/str_format.h"
#include "core/calibrate/verdict.h"
#include "core/regressor.h"
#include "util/file.h"
#include "util/units.h"

namespace imucal::formats {
namespace {

using nlohmann::json;

constexpr double kW = 720, kH = 460;                                // canvas, px
constexpr double kLeft = 80, kRight = 20, kTop = 40, kBottom = 80;  // margins, px
constexpr double kMg = 9.80665e-3;                                  // m/s^2 per mg

std::string Escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (c == '<')
      out += "&lt;";
    else if (c == '>')
      out += "&gt;";
    else if (c == '&')
      out += "&amp;";
    else
      out += c;
  }
  return out;
}

// Round tick step for a span: 1, 2 or 5 times a power of ten, about 6 ticks.
double TickStep(double span) {
  const double raw = span / 6;
  const double p = std::pow(10.0, std::floor(std::log10(raw)));
  for (double m : {1.0, 2.0, 5.0, 10.0})
    if (m * p >= raw) return m * p;
  return 10 * p;
}

struct Range {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  void Add(double v) {
    if (std::isfinite(v)) lo = std::min(lo, v), hi = std::max(hi, v);
  }
  void Pad() {
    if (!std::isfinite(lo)) lo = 0, hi = 1;
    if (hi - lo < 1e-12 * (std::abs(lo) + 1))
      lo -= 0.5 * (std::abs(lo) + 1e-9), hi += 0.5 * (std::abs(hi) + 1e-9);
    const double pad = 0.05 * (hi - lo);
    lo -= pad, hi += pad;
  }
};

json Get(const json& j, const char* key) { return j.contains(key) ? j.at(key) : json(); }

double Num(const json& j) {
  return j.is_number() ? j.get<double>() : std::numeric_limits<double>::quiet_NaN();
}

using PlotWriter = std::function<absl::Status(const std::string&, const Plot&)>;

const char* const kColours[] = {"#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b"};

// The accelerometer's reference lines on a |a| - g [mg] plot: the verdict's RMS gates
// (core/calibrate/verdict.h; a pose above them alone does not fail a calibration, but many do)
// and the noise floor the residuals cannot go below (report.residual.accel_noise_floor, m/s^2).
std::vector<RefLine> AccelRefLines(const json& report) {
  std::vector<RefLine> lines = {
      {core::kAccelPassRmsM_s2 / kMg,
       absl::StrFormat("warn: RMS above %.1f mg", core::kAccelPassRmsM_s2 / kMg), "#e69f00"},
      {core::kAccelFailRmsM_s2 / kMg,
       absl::StrFormat("fail: RMS above %.1f mg", core::kAccelFailRmsM_s2 / kMg), "#d62728"},
      {-core::kAccelPassRmsM_s2 / kMg, "", "#e69f00"},
      {-core::kAccelFailRmsM_s2 / kMg, "", "#d62728"}};
  const double floor = Num(Get(Get(report, "residual"), "accel_noise_floor"));
  if (floor > 0) {
    lines.push_back({floor / kMg, absl::StrFormat("noise floor %.2g mg", floor / kMg), "#555555"});
    lines.push_back({-floor / kMg, "", "#555555"});
  }
  return lines;
}

// A regressor's unit, from its factors' (core/regressor.h): "degC*m/s^2", "(rad/s)^2".
std::string RegressorUnit(const core::Regressor& reg) {
  static constexpr const char* kUnits[core::kNumSignals] = {"degC",  "s",     "m/s^2", "m/s^2",
                                                            "m/s^2", "rad/s", "rad/s", "rad/s"};
  std::vector<std::string> parts;
  for (int i = 0; i < reg.num_factors; ++i) parts.push_back(kUnits[reg.factors[i]]);
  std::string out;
  for (size_t i = 0; i < parts.size(); ++i) {
    size_t run = 1;
    while (i + run < parts.size() && parts[i + run] == parts[i]) ++run;
    const bool compound = parts[i].find('/') != std::string::npos;
    std::string unit = run > 1 && compound ? "(" + parts[i] + ")" : parts[i];
    if (run > 1) unit += absl::StrFormat("^%d", static_cast<int>(run));
    if (!out.empty()) out += "*";
    out += unit;
    i += run - 1;
  }
  return out;
}

// |a| - g per used pose after each stage, one line per stage.
absl::Status WriteStagePlot(const json& report, const PlotWriter& write) {
  const json stages = Get(report, "stages");
  Plot plot{"Accelerometer |a| - g per pose after each stage", "pose number", "|a| - g [mg]", {}};
  plot.ref_lines = AccelRefLines(report);
  plot.caption =
      "Good: the last stage's points near 0, inside the noise floor lines, far below the gates";
  for (size_t k = 0; stages.is_array() && k < stages.size(); ++k) {
    const json poses = Get(stages[k], "poses"), res = Get(stages[k], "pose_residual");
    if (!poses.is_array()) continue;
    if (!res.is_array() || res.size() != poses.size()) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "stages[%d].pose_residual: expected one number per entry of poses", static_cast<int>(k)));
    }
    std::vector<std::pair<double, double>> pts;
    for (size_t i = 0; i < poses.size(); ++i) pts.emplace_back(Num(poses[i]), Num(res[i]) / kMg);
    std::sort(pts.begin(), pts.end());
    const std::string name =
        Get(stages[k], "name").is_string() ? Get(stages[k], "name").get<std::string>() : "";
    PlotSeries line{
        absl::StrFormat("after %s (rms %.3g mg)", name, Num(Get(stages[k], "accel_rms")) / kMg),
        {},
        {},
        kColours[k % 6],
        true};
    for (const auto& [x, y] : pts) line.x.push_back(x), line.y.push_back(y);
    PlotSeries dots = line;
    dots.line = false;
    dots.label = "";
    plot.series.push_back(std::move(line));
    plot.series.push_back(std::move(dots));
  }
  if (plot.series.empty()) return absl::OkStatus();
  return write("residual_stages_per_pose.svg", plot);
}

// Each pose's gravity direction on the sphere: Lambert azimuthal equal-area projection of each
// hemisphere of the body frame onto a unit disc, +z (left) and -z (right), seen from outside.
absl::Status WriteCoveragePlot(const json& report, const PlotWriter& write) {
  const json poses = Get(report, "poses");
  if (!poses.is_array() || poses.empty()) return absl::OkStatus();
  constexpr double kOffset = 1.2;  // disc centres at -+kOffset
  auto project = [](double x, double y, double z, double* u, double* v) {
    const double k = std::sqrt(1.0 / (1.0 + std::abs(z)));  // equator -> radius 1
    *u = (z >= 0 ? -kOffset : kOffset) + k * x;
    *v = k * y;
  };
  PlotSeries rims{"hemisphere rims (left +z, right -z)", {}, {}, "#888888", true};
  PlotSeries faces{"the six faces' directions", {}, {}, "#aaaaaa", false, true};
  PlotSeries used{"pose used", {}, {}, "#1f77b4"},
      unused{"pose not used", {}, {}, "#d62728", false, true};
  for (double side : {-kOffset, kOffset}) {
    for (int i = 0; i <= 72; ++i) {
      const double t = 2 * M_PI * i / 72;
      rims.x.push_back(side + std::cos(t)), rims.y.push_back(std::sin(t));
    }
    rims.x.push_back(kNaN), rims.y.push_back(kNaN);
  }
  for (int a = 0; a < 3; ++a) {
    for (double sign : {1.0, -1.0}) {
      double dir[3] = {0, 0, 0}, u = 0, v = 0;
      dir[a] = sign;
      project(dir[0], dir[1], dir[2], &u, &v);
      faces.x.push_back(u), faces.y.push_back(v);
    }
  }
  for (size_t i = 0; i < poses.size(); ++i) {
    const json up = Get(poses[i], "up");
    if (!up.is_array() || up.size() != 3) {
      return absl::InvalidArgumentError(
          absl::StrFormat("poses[%d].up: expected 3 numbers", static_cast<int>(i)));
    }
    const double n = std::hypot(Num(up[0]), std::hypot(Num(up[1]), Num(up[2])));
    if (!(n > 0)) continue;  // a pose without a direction (not calibrated)
    double u = 0, v = 0;
    project(Num(up[0]) / n, Num(up[1]) / n, Num(up[2]) / n, &u, &v);
    PlotSeries& s =
        Get(poses[i], "used").is_boolean() && Get(poses[i], "used").get<bool>() ? used : unused;
    s.x.push_back(u), s.y.push_back(v);
    const double index = Num(Get(poses[i], "index"));
    s.point_labels.push_back(std::isfinite(index) ? absl::StrFormat("%.0f", index) : "");
  }
  Plot plot{"Pose coverage: gravity direction in the body frame (equal-area)",
            "left: +z hemisphere (x right, y up); right: -z hemisphere",
            "",
            {}};
  // Room above the discs for the legend: an invisible point.
  const PlotSeries headroom{"", {0.0}, {1.9}, "none"};
  plot.series = {rims, faces, used, unused, headroom};
  plot.caption = "Good: poses on both discs, at or near all six grey face marks (numbers: pose)";
  plot.equal_aspect = true;
  plot.axes = false;
  return write("coverage.svg", plot);
}

// Allan deviation per axis, log-log.
absl::Status WriteAllanPlots(const json& report, const PlotWriter& write) {
  const json allan = Get(report, "allan");
  if (!allan.is_object()) return absl::OkStatus();
  const json tau = Get(allan, "tau");
  if (!tau.is_array()) return absl::InvalidArgumentError("allan.tau: expected an array");
  for (const char* sensor : {"accel", "gyro"}) {
    const json curves = Get(allan, sensor);
    // An accelerometer-only report has no gyro curves (absent, not empty): no gyro plot.
    if (std::string(sensor) == "gyro" && !allan.contains(sensor)) continue;
    if (!curves.is_array() || curves.size() != tau.size()) {
      return absl::InvalidArgumentError(
          absl::StrFormat("allan.%s: expected one [x, y, z] per tau", sensor));
    }
    const bool accel = std::string(sensor) == "accel";
    Plot plot{absl::StrFormat("Allan deviation, %s (calibrated, at rest)",
                              accel ? "accelerometer" : "gyroscope"),
              "cluster time tau [s]",
              accel ? "Allan deviation [m/s^2]" : "Allan deviation [rad/s]",
              {}};
    plot.log_x = plot.log_y = true;
    plot.caption =
        "Good: falls with slope -1/2 (white noise) to a flat floor (bias instability); dashed: "
        "the fitted N, B, K";
    for (int a = 0; a < 3; ++a) {
      PlotSeries s{std::string(1, "xyz"[a]), {}, {}, kColours[a], true};
      for (size_t i = 0; i < tau.size(); ++i) {
        s.x.push_back(Num(tau[i]));
        s.y.push_back(curves[i].is_array() && curves[i].size() == 3
                          ? Num(curves[i][static_cast<size_t>(a)])
                          : kNaN);
      }
      plot.series.push_back(std::move(s));
    }
    // The fitted figures (parameters.noise.<sensor>, core/allan.h): N / sqrt(tau) for white
    // noise, 0.664 B for the flicker floor, K sqrt(tau / 3) for the rate random walk, dashed in
    // the axis' colour over the plotted cluster times. A figure not reached is null: no line.
    const json noise = Get(Get(Get(report, "parameters"), "noise"), sensor);
    const double tau_lo = tau.empty() ? kNaN : Num(tau.front());
    const double tau_hi = tau.empty() ? kNaN : Num(tau.back());
    bool labelled = false;
    for (int a = 0; a < 3 && noise.is_object(); ++a) {
      auto figure = [&](const char* key) {
        const json v = Get(noise, key);
        return v.is_array() && v.size() == 3 ? Num(v[static_cast<size_t>(a)]) : kNaN;
      };
      auto fit = [&](double value, double (*curve)(double, double)) {
        if (!(value > 0) || !(tau_lo > 0) || !(tau_hi > tau_lo)) return;
        PlotSeries line{labelled ? "" : "dashed: fitted N, B, K",
                        {},
                        {},
                        kColours[a],
                        true};
        line.dashed = true;
        labelled = true;
        for (int i = 0; i <= 20; ++i) {
          const double t = tau_lo * std::pow(tau_hi / tau_lo, i / 20.0);
          line.x.push_back(t), line.y.push_back(curve(value, t));
        }
        plot.series.push_back(std::move(line));
      };
      fit(figure("noise_density"), [](double v, double t) { return v / std::sqrt(t); });
      fit(figure("bias_instability"), [](double v, double) { return 0.664 * v; });
      fit(figure("random_walk"), [](double v, double t) { return v * std::sqrt(t / 3); });
    }
    if (absl::Status s = write(absl::StrFormat("allan_%s.svg", sensor), plot); !s.ok()) return s;
  }
  return absl::OkStatus();
}

}  // namespace

namespace {

// The plot's area and its axes' ranges: where a value is drawn. Log axes work on log10 of the
// value; tx/ty give the axis coordinate, px/py the pixel of a value, gx/gy of an axis coordinate.
struct Canvas {
  explicit Canvas(const Plot& p) : plot(p) {
    for (const PlotSeries& s : plot.series) {
      for (double v : s.x) xr.Add(tx(v));
      for (double v : s.y) yr.Add(ty(v));
    }
    for (const RefLine& r : plot.ref_lines) yr.Add(ty(r.y));
    xr.Pad();
    yr.Pad();
    if (plot.equal_aspect) {  // widen the tighter axis
      const double ux = (xr.hi - xr.lo) / pw, uy = (yr.hi - yr.lo) / ph;
      Range& r = ux < uy ? xr : yr;
      const double half = 0.5 * std::max(ux, uy) * (ux < uy ? pw : ph), mid = 0.5 * (r.lo + r.hi);
      r.lo = mid - half, r.hi = mid + half;
    }
  }
  double tx(double x) const { return plot.log_x ? (x > 0 ? std::log10(x) : kNaN) : x; }
  double ty(double y) const { return plot.log_y ? (y > 0 ? std::log10(y) : kNaN) : y; }
  double gx(double x) const { return kLeft + (x - xr.lo) / (xr.hi - xr.lo) * pw; }
  double gy(double y) const { return kTop + (yr.hi - y) / (yr.hi - yr.lo) * ph; }
  double px(double x) const { return gx(tx(x)); }
  double py(double y) const { return gy(ty(y)); }

  const Plot& plot;
  Range xr, yr;
  const double pw = kW - kLeft - kRight, ph = kH - kTop - kBottom;
};

std::string TickLabel(double v, bool log, double step) {
  if (log) return absl::StrFormat("%.2g", std::pow(10.0, v));
  return absl::StrFormat("%.4g", std::abs(v) < 1e-9 * step ? 0.0 : v);
}

// Grid and ticks (log axes: one per decade when the span allows), the zero line, the frame, the
// axis labels and the caption.
void DrawFrame(const Canvas& c, std::string* out) {
  std::string& s = *out;
  const Plot& plot = c.plot;
  const Range &xr = c.xr, &yr = c.yr;
  const double pw = c.pw, ph = c.ph;
  const double xs = plot.log_x && xr.hi - xr.lo >= 2 ? 1.0 : TickStep(xr.hi - xr.lo);
  const double ys = plot.log_y && yr.hi - yr.lo >= 2 ? 1.0 : TickStep(yr.hi - yr.lo);
  for (double x = std::ceil(xr.lo / xs) * xs; plot.axes && x <= xr.hi; x += xs) {
    absl::StrAppendFormat(&s,
                          "<line x1=\"%.1f\" y1=\"%.0f\" x2=\"%.1f\" y2=\"%.0f\" stroke=\"#ddd\"/>"
                          "<text x=\"%.1f\" y=\"%.0f\" text-anchor=\"middle\">%s</text>\n",
                          c.gx(x), kTop, c.gx(x), kTop + ph, c.gx(x), kTop + ph + 16,
                          TickLabel(x, plot.log_x, xs));
  }
  for (double y = std::ceil(yr.lo / ys) * ys; plot.axes && y <= yr.hi; y += ys) {
    absl::StrAppendFormat(&s,
                          "<line x1=\"%.0f\" y1=\"%.1f\" x2=\"%.0f\" y2=\"%.1f\" stroke=\"#ddd\"/>"
                          "<text x=\"%.0f\" y=\"%.1f\" text-anchor=\"end\">%s</text>\n",
                          kLeft, c.gy(y), kLeft + pw, c.gy(y), kLeft - 6, c.gy(y) + 4,
                          TickLabel(y, plot.log_y, ys));
  }
  if (plot.axes && !plot.log_y && yr.lo < 0 && yr.hi > 0) {
    absl::StrAppendFormat(
        &s, "<line x1=\"%.0f\" y1=\"%.1f\" x2=\"%.0f\" y2=\"%.1f\" stroke=\"#888\"/>\n", kLeft,
        c.gy(0), kLeft + pw, c.gy(0));
  }
  if (plot.axes) {
    absl::StrAppendFormat(&s,
                          "<rect x=\"%.0f\" y=\"%.0f\" width=\"%.0f\" height=\"%.0f\" "
                          "fill=\"none\" stroke=\"black\"/>\n",
                          kLeft, kTop, pw, ph);
  }
  absl::StrAppendFormat(&s,
                        "<text x=\"%.0f\" y=\"%.0f\" text-anchor=\"middle\">%s</text>\n"
                        "<text transform=\"translate(18 %.0f) rotate(-90)\" "
                        "text-anchor=\"middle\">%s</text>\n",
                        kLeft + pw / 2, kTop + ph + 34, Escape(plot.x_label), kTop + ph / 2,
                        Escape(plot.y_label));
  if (!plot.caption.empty()) {
    absl::StrAppendFormat(&s,
                          "<text x=\"%.0f\" y=\"%.0f\" text-anchor=\"middle\" fill=\"#444\" "
                          "font-style=\"italic\">%s</text>\n",
                          kW / 2, kH - 12, Escape(plot.caption));
  }
  for (const RefLine& r : plot.ref_lines) {
    const double y = c.py(r.y);
    if (!std::isfinite(y)) continue;
    absl::StrAppendFormat(&s,
                          "<line x1=\"%.0f\" y1=\"%.1f\" x2=\"%.0f\" y2=\"%.1f\" stroke=\"%s\" "
                          "stroke-dasharray=\"2 3\"/><text x=\"%.0f\" y=\"%.1f\" "
                          "text-anchor=\"start\" font-size=\"10\" fill=\"%s\">%s</text>\n",
                          kLeft, y, kLeft + pw, y, r.colour, kLeft + 4, y - 3, r.colour,
                          Escape(r.label));
  }
}

// A series as a line; a point that cannot be drawn (NaN, or <= 0 on a log axis) breaks it.
void DrawLine(const Canvas& c, const PlotSeries& ser, std::string* s) {
  std::string pts;
  auto flush = [&] {
    if (!pts.empty())
      absl::StrAppendFormat(
          s, "<polyline points=\"%s\" fill=\"none\" stroke=\"%s\" stroke-width=\"1.5\"%s/>\n", pts,
          ser.colour, ser.dashed ? " stroke-dasharray=\"6 4\"" : "");
    pts.clear();
  };
  for (size_t i = 0; i < ser.x.size() && i < ser.y.size(); ++i) {
    if (std::isfinite(c.px(ser.x[i])) && std::isfinite(c.py(ser.y[i])))
      absl::StrAppendFormat(&pts, "%.1f,%.1f ", c.px(ser.x[i]), c.py(ser.y[i]));
    else
      flush();
  }
  flush();
}

// A series as points, each with its label if it has one.
void DrawPoints(const Canvas& c, const PlotSeries& ser, std::string* s) {
  for (size_t i = 0; ser.colour != "none" && i < ser.x.size() && i < ser.y.size(); ++i) {
    if (!std::isfinite(c.px(ser.x[i])) || !std::isfinite(c.py(ser.y[i]))) continue;
    absl::StrAppendFormat(
        s, "<circle cx=\"%.1f\" cy=\"%.1f\" r=\"%s\" fill=\"%s\" stroke=\"%s\"/>\n", c.px(ser.x[i]),
        c.py(ser.y[i]), ser.hollow ? "4.5" : "3", ser.hollow ? "none" : ser.colour, ser.colour);
    if (i < ser.point_labels.size() && !ser.point_labels[i].empty()) {
      absl::StrAppendFormat(s,
                            "<text x=\"%.1f\" y=\"%.1f\" font-size=\"9\" fill=\"#333\">%s</text>\n",
                            c.px(ser.x[i]) + 4, c.py(ser.y[i]) - 4, Escape(ser.point_labels[i]));
    }
  }
}

}  // namespace

std::string RenderSvg(const Plot& plot) {
  const Canvas c(plot);
  std::string s = absl::StrFormat(
      "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%.0f\" height=\"%.0f\" "
      "viewBox=\"0 0 %.0f %.0f\" font-family=\"sans-serif\" font-size=\"12\">\n"
      "<rect width=\"100%%\" height=\"100%%\" fill=\"white\"/>\n"
      "<text x=\"%.0f\" y=\"22\" font-size=\"15\" text-anchor=\"middle\">%s</text>\n",
      kW, kH, kW, kH, kW / 2, Escape(plot.title));
  DrawFrame(c, &s);
  // Series and legend.
  double legend_y = kTop + 14;
  for (const PlotSeries& ser : plot.series) {
    if (ser.line)
      DrawLine(c, ser, &s);
    else
      DrawPoints(c, ser, &s);
    if (ser.label.empty()) continue;
    absl::StrAppendFormat(&s,
                          "<rect x=\"%.0f\" y=\"%.0f\" width=\"10\" height=\"10\" fill=\"%s\"/>"
                          "<text x=\"%.0f\" y=\"%.0f\">%s</text>\n",
                          kLeft + c.pw - 230, legend_y - 9, ser.colour, kLeft + c.pw - 214,
                          legend_y, Escape(ser.label));
    legend_y += 16;
  }
  s += "</svg>\n";
  return s;
}

namespace {

// Per-pose residuals, before and after the effects.
absl::Status WritePosePlots(const json& report, const json& diag, const json& rows,
                            const PlotWriter& write) {
  Plot accel{"Accelerometer |a| - g per pose", "pose number", "|a| - g [mg]", {}};
  Plot gyro{"Gyroscope static rate per pose", "pose number", "|rate| [deg/s]", {}};
  accel.ref_lines = AccelRefLines(report);
  accel.caption = "Good: the filled points (after effects) inside the noise floor lines";
  if (const double floor = Num(Get(diag, "gyro_noise_floor")); floor > 0) {
    gyro.ref_lines.push_back(
        {floor * kRadToDeg, absl::StrFormat("noise floor %.2g deg/s", floor * kRadToDeg)});
  }
  gyro.caption = "Good: every pose near the noise floor line (at rest, bias removed)";
  PlotSeries ab{"before effects", {}, {}, "#d62728", false, true},
      aa{"after effects", {}, {}, "#1f77b4"};
  PlotSeries gb = ab, ga = aa;
  auto norm = [](const json& v) {
    double s = 0;
    for (const json& c : v) s += Num(c) * Num(c);
    return std::sqrt(s) * kRadToDeg;
  };
  for (size_t i = 0; i < rows.size(); ++i) {
    const json& r = rows[i];
    const double index = Num(Get(r, "index"));
    const std::string number = std::isfinite(index) ? absl::StrFormat("%.0f", index) : "";
    aa.point_labels.push_back(number), ga.point_labels.push_back(number);
    ab.x.push_back(index), ab.y.push_back(Num(Get(r, "accel_before")) / kMg);
    aa.x.push_back(index), aa.y.push_back(Num(Get(r, "accel_after")) / kMg);
    gb.x.push_back(index), gb.y.push_back(norm(Get(r, "gyro_before")));
    ga.x.push_back(index), ga.y.push_back(norm(Get(r, "gyro_after")));
  }
  accel.series = {aa, ab};  // hollow markers drawn last, on top
  gyro.series = {ga, gb};
  if (absl::Status s = write("residual_accel_per_pose.svg", accel); !s.ok()) return s;
  return write("residual_gyro_per_pose.svg", gyro);
}

// Effect k's plot file: `*` as x, `^` as p, `|gz|` as absgz.
std::string EffectPlotFile(size_t k, const std::string& sensor, const std::string& axis,
                           const std::string& name) {
  std::string safe;
  bool open_bar = false;
  for (const char ch : name) {
    if (ch == '|') {
      if (!open_bar) safe += "abs";
      open_bar = !open_bar;
      continue;
    }
    safe += ch == '*' ? 'x' : ch == '^' ? 'p' : ch;
  }
  return absl::StrFormat("effect_%d_%s_%s_%s.svg", static_cast<int>(k) + 1, sensor, axis, safe);
}

// A rate term does nothing at rest: its figure is the moves'. Each move's gravity-direction
// error held out by move, without and with the rate terms found.
Plot RateEffectPlot(const json& diag, const std::string& sensor, const std::string& axis,
                    const std::string& name) {
  const json ms = Get(diag, "move_search");
  const json hb = Get(ms, "heldout_before_per_move"), ha = Get(ms, "heldout_after_per_move");
  PlotSeries mb{"without the rate terms", {}, {}, "#d62728", false, true},
      ma{"with them", {}, {}, "#1f77b4"};
  for (size_t i = 0; hb.is_array() && ha.is_array() && i < hb.size() && i < ha.size(); ++i) {
    mb.x.push_back(static_cast<double>(i + 1)), mb.y.push_back(Num(hb[i]) * kRadToDeg);
    ma.x.push_back(static_cast<double>(i + 1)), ma.y.push_back(Num(ha[i]) * kRadToDeg);
  }
  Plot p{absl::StrFormat("%s %s ~ %s (on the moves)", sensor, axis, name),
         "move number",
         "gravity-direction error after the move, held out [deg]",
         {ma, mb}};
  if (const double floor = Num(Get(ms, "noise_floor")); floor > 0)
    p.ref_lines.push_back(
        {floor * kRadToDeg, absl::StrFormat("noise %.2g deg", floor * kRadToDeg)});
  p.caption = "Good: the filled points (with the rate terms) down near the noise line";
  return p;
}

// A static effect's partial residual against its regressor, with and without it.
Plot PartialResidualPlot(const json& e, const json& rows, const core::Regressor& reg,
                         const std::string& sensor, const std::string& axis, int ax,
                         const std::string& name) {
  const bool is_accel = sensor == "accel";
  const double c = Num(Get(e, "coefficient"));
  const bool applied = !Get(e, "applied").is_boolean() || Get(e, "applied").get<bool>();
  const double unit = is_accel ? kMg : 1.0 / kRadToDeg;  // plotted in mg or deg/s
  PlotSeries before{"without this effect", {}, {}, "#d62728", false, true},
      after{"with it", {}, {}, "#1f77b4"}, line{"fitted term", {}, {}, "#2ca02c", true};
  for (const json& r : rows) {
    core::SignalArray sig{};
    const json s = Get(r, "signals");
    for (int q = 0; q < core::kNumSignals; ++q)
      sig[static_cast<size_t>(q)] =
          Num(Get(s, std::string(core::kSignalNames[static_cast<size_t>(q)]).c_str()));
    double x = reg.Evaluate(sig);
    double res = 0;
    if (is_accel) {
      const double n = std::hypot(sig[2], std::hypot(sig[3], sig[4]));
      x *= sig[static_cast<size_t>(2 + ax)] / n;  // how the term reaches |a| - g
      res = Num(Get(r, "accel_all"));
    } else {
      res = Num(Get(r, "gyro_all")[static_cast<size_t>(ax)]);
    }
    // `all`: the fit with every effect found, the one this coefficient comes from.
    before.x.push_back(x), before.y.push_back((res + c * x) / unit);
    after.x.push_back(x), after.y.push_back(res / unit);
  }
  if (!before.x.empty()) {
    const auto [lo, hi] = std::minmax_element(before.x.begin(), before.x.end());
    line.x = {*lo, *hi};
    line.y = {c * *lo / unit, c * *hi / unit};
  }
  const std::string unit_x = RegressorUnit(reg);
  Plot p{absl::StrFormat("%s %s ~ %s%s", sensor, axis, name,
                         applied ? "" : " (reported, not applied)"),
         is_accel ? absl::StrFormat("%s x gravity direction on %s [%s]", name, axis, unit_x)
                  : absl::StrFormat("%s [%s]", name, unit_x),
         is_accel ? "|a| - g [mg]" : absl::StrFormat("rate %s [deg/s]", axis),
         {after, before, line}};
  p.caption =
      "Good: the filled points (with the effect) flat around 0; the hollow ones on the "
      "fitted line";
  return p;
}

// One plot per effect.
absl::Status WriteEffectPlots(const json& report, const json& diag, const json& rows,
                              const PlotWriter& write) {
  const json effects = Get(report, "effects");
  for (size_t k = 0; effects.is_array() && k < effects.size(); ++k) {
    const json& e = effects[k];
    const std::string field = absl::StrFormat("effects[%d]", static_cast<int>(k));
    const std::string sensor =
        Get(e, "sensor").is_string() ? Get(e, "sensor").get<std::string>() : "";
    const std::string axis = Get(e, "axis").is_string() ? Get(e, "axis").get<std::string>() : "";
    const std::string name =
        Get(e, "regressor").is_string() ? Get(e, "regressor").get<std::string>() : "";
    const std::optional<core::Regressor> reg = core::ParseRegressor(name);
    const int ax = axis == "x" ? 0 : axis == "y" ? 1 : axis == "z" ? 2 : -1;
    if (!reg || ax < 0 || (sensor != "accel" && sensor != "gyro")) {
      return absl::InvalidArgumentError(field + ": sensor, axis or regressor malformed");
    }
    bool rate = false;
    for (int f = 0; f < reg->num_factors; ++f)
      rate |= reg->factors[static_cast<size_t>(f)] >= static_cast<int>(core::Signal::kGx);
    const Plot p = sensor == "gyro" && rate
                       ? RateEffectPlot(diag, sensor, axis, name)
                       : PartialResidualPlot(e, rows, *reg, sensor, axis, ax, name);
    if (absl::Status s = write(EffectPlotFile(k, sensor, axis, name), p); !s.ok()) return s;
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::vector<std::string>> WriteReportPlots(const json& report,
                                                          const std::string& dir) {
  std::vector<std::string> written;
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec)
    return absl::InvalidArgumentError(absl::StrFormat("%s: cannot create (%s)", dir, ec.message()));
  auto write = [&](const std::string& name, const Plot& plot) -> absl::Status {
    const std::string path = (std::filesystem::path(dir) / name).string();
    std::ofstream f(path, std::ios::trunc);
    f << RenderSvg(plot);
    if (!f) return absl::InternalError(absl::StrFormat("%s: cannot write", path));
    written.push_back(path);
    return absl::OkStatus();
  };

  if (absl::Status s = WriteStagePlot(report, write); !s.ok()) return s;
  if (absl::Status s = WriteCoveragePlot(report, write); !s.ok()) return s;
  if (absl::Status s = WriteAllanPlots(report, write); !s.ok()) return s;
  const json diag = Get(report, "effect_diagnostics");
  if (!diag.is_object()) return written;
  // Only notes: the search did not run (an accelerometer-only capture), nothing to plot.
  if (diag.size() == 1 && diag.contains("notes")) return written;
  const json rows = Get(diag, "poses");
  if (!rows.is_array()) {
    return absl::InvalidArgumentError("effect_diagnostics.poses: expected an array");
  }
  if (absl::Status s = WritePosePlots(report, diag, rows, write); !s.ok()) return s;
  if (absl::Status s = WriteEffectPlots(report, diag, rows, write); !s.ok()) return s;
  return written;
}

absl::StatusOr<std::vector<std::string>> WriteReportBundle(const json& report,
                                                           const std::string& report_text,
                                                           const std::string& summary,
                                                           const std::string& dir) {
  absl::StatusOr<std::vector<std::string>> written = WriteReportPlots(report, dir);
  if (!written.ok()) return written.status();
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);  // WriteReportPlots made it if it drew anything
  if (ec)
    return absl::InvalidArgumentError(absl::StrFormat("%s: cannot create (%s)", dir, ec.message()));
  for (const auto& [name, text] :
       {std::pair<const char*, const std::string*>{"report.json", &report_text},
        {"summary.txt", &summary}}) {
    const std::string path = (std::filesystem::path(dir) / name).string();
    if (absl::Status s = WriteFileDurably(path, *text); !s.ok()) return s;
    written->insert(written->begin(), path);
  }
  return written;
}

}  // namespace imucal::formats
