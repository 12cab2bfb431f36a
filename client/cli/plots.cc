#include "client/cli/plots.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>

#include "absl/strings/str_format.h"
#include "core/regressor.h"

namespace imucal::cli {
namespace {

using nlohmann::json;

constexpr double kW = 720, kH = 440;                          // canvas, px
constexpr double kLeft = 80, kRight = 20, kTop = 40, kBottom = 60;  // margins, px
constexpr double kMg = 9.80665e-3;                            // m/s^2 per mg
constexpr double kRadToDeg = 180.0 / M_PI;

std::string Escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (c == '<') out += "&lt;";
    else if (c == '>') out += "&gt;";
    else if (c == '&') out += "&amp;";
    else out += c;
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
    if (hi - lo < 1e-12 * (std::abs(lo) + 1)) lo -= 0.5 * (std::abs(lo) + 1e-9), hi += 0.5 * (std::abs(hi) + 1e-9);
    const double pad = 0.05 * (hi - lo);
    lo -= pad, hi += pad;
  }
};

json Get(const json& j, const char* key) {
  return j.contains(key) ? j.at(key) : json();
}

double Num(const json& j) {
  return j.is_number() ? j.get<double>() : std::numeric_limits<double>::quiet_NaN();
}

}  // namespace

std::string RenderSvg(const Plot& plot) {
  Range xr, yr;
  for (const PlotSeries& s : plot.series) {
    for (double v : s.x) xr.Add(v);
    for (double v : s.y) yr.Add(v);
  }
  xr.Pad();
  yr.Pad();
  const double pw = kW - kLeft - kRight, ph = kH - kTop - kBottom;
  auto px = [&](double x) { return kLeft + (x - xr.lo) / (xr.hi - xr.lo) * pw; };
  auto py = [&](double y) { return kTop + (yr.hi - y) / (yr.hi - yr.lo) * ph; };
  std::string s = absl::StrFormat(
      "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%.0f\" height=\"%.0f\" "
      "viewBox=\"0 0 %.0f %.0f\" font-family=\"sans-serif\" font-size=\"12\">\n"
      "<rect width=\"100%%\" height=\"100%%\" fill=\"white\"/>\n"
      "<text x=\"%.0f\" y=\"22\" font-size=\"15\" text-anchor=\"middle\">%s</text>\n",
      kW, kH, kW, kH, kW / 2, Escape(plot.title));
  // Grid and ticks.
  const double xs = TickStep(xr.hi - xr.lo), ys = TickStep(yr.hi - yr.lo);
  for (double x = std::ceil(xr.lo / xs) * xs; x <= xr.hi; x += xs) {
    absl::StrAppendFormat(&s,
                          "<line x1=\"%.1f\" y1=\"%.0f\" x2=\"%.1f\" y2=\"%.0f\" stroke=\"#ddd\"/>"
                          "<text x=\"%.1f\" y=\"%.0f\" text-anchor=\"middle\">%.4g</text>\n",
                          px(x), kTop, px(x), kTop + ph, px(x), kTop + ph + 16,
                          std::abs(x) < 1e-9 * xs ? 0.0 : x);
  }
  for (double y = std::ceil(yr.lo / ys) * ys; y <= yr.hi; y += ys) {
    absl::StrAppendFormat(&s,
                          "<line x1=\"%.0f\" y1=\"%.1f\" x2=\"%.0f\" y2=\"%.1f\" stroke=\"#ddd\"/>"
                          "<text x=\"%.0f\" y=\"%.1f\" text-anchor=\"end\">%.4g</text>\n",
                          kLeft, py(y), kLeft + pw, py(y), kLeft - 6, py(y) + 4,
                          std::abs(y) < 1e-9 * ys ? 0.0 : y);
  }
  if (yr.lo < 0 && yr.hi > 0) {
    absl::StrAppendFormat(&s, "<line x1=\"%.0f\" y1=\"%.1f\" x2=\"%.0f\" y2=\"%.1f\" stroke=\"#888\"/>\n",
                          kLeft, py(0), kLeft + pw, py(0));
  }
  absl::StrAppendFormat(&s,
                        "<rect x=\"%.0f\" y=\"%.0f\" width=\"%.0f\" height=\"%.0f\" fill=\"none\" "
                        "stroke=\"black\"/>\n"
                        "<text x=\"%.0f\" y=\"%.0f\" text-anchor=\"middle\">%s</text>\n"
                        "<text transform=\"translate(18 %.0f) rotate(-90)\" "
                        "text-anchor=\"middle\">%s</text>\n",
                        kLeft, kTop, pw, ph, kLeft + pw / 2, kH - 18, Escape(plot.x_label),
                        kTop + ph / 2, Escape(plot.y_label));
  // Series and legend.
  double legend_y = kTop + 14;
  for (const PlotSeries& ser : plot.series) {
    if (ser.line) {
      std::string pts;
      for (size_t i = 0; i < ser.x.size() && i < ser.y.size(); ++i)
        if (std::isfinite(ser.x[i]) && std::isfinite(ser.y[i]))
          absl::StrAppendFormat(&pts, "%.1f,%.1f ", px(ser.x[i]), py(ser.y[i]));
      absl::StrAppendFormat(&s, "<polyline points=\"%s\" fill=\"none\" stroke=\"%s\" stroke-width=\"1.5\"/>\n",
                            pts, ser.colour);
    } else {
      for (size_t i = 0; i < ser.x.size() && i < ser.y.size(); ++i) {
        if (!std::isfinite(ser.x[i]) || !std::isfinite(ser.y[i])) continue;
        absl::StrAppendFormat(&s, "<circle cx=\"%.1f\" cy=\"%.1f\" r=\"%s\" fill=\"%s\" stroke=\"%s\"/>\n",
                              px(ser.x[i]), py(ser.y[i]), ser.hollow ? "4.5" : "3",
                              ser.hollow ? "none" : ser.colour, ser.colour);
      }
    }
    absl::StrAppendFormat(&s,
                          "<rect x=\"%.0f\" y=\"%.0f\" width=\"10\" height=\"10\" fill=\"%s\"/>"
                          "<text x=\"%.0f\" y=\"%.0f\">%s</text>\n",
                          kLeft + pw - 230, legend_y - 9, ser.colour, kLeft + pw - 214, legend_y,
                          Escape(ser.label));
    legend_y += 16;
  }
  s += "</svg>\n";
  return s;
}

absl::StatusOr<std::vector<std::string>> WriteReportPlots(const json& report,
                                                          const std::string& dir) {
  std::vector<std::string> written;
  const json diag = Get(report, "effect_diagnostics");
  if (!diag.is_object()) return written;
  const json rows = Get(diag, "poses");
  if (!rows.is_array()) {
    return absl::InvalidArgumentError("effect_diagnostics.poses: expected an array");
  }
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return absl::InvalidArgumentError(absl::StrFormat("%s: cannot create (%s)", dir, ec.message()));
  auto write = [&](const std::string& name, const Plot& plot) -> absl::Status {
    const std::string path = (std::filesystem::path(dir) / name).string();
    std::ofstream f(path, std::ios::trunc);
    f << RenderSvg(plot);
    if (!f) return absl::InternalError(absl::StrFormat("%s: cannot write", path));
    written.push_back(path);
    return absl::OkStatus();
  };

  // Per-pose residuals, before and after the effects.
  Plot accel{"Accelerometer |a| - g per pose", "pose", "|a| - g [mg]", {}};
  Plot gyro{"Gyroscope static rate per pose", "pose", "|rate| [deg/s]", {}};
  PlotSeries ab{"before effects", {}, {}, "#d62728", false, true},
      aa{"after effects", {}, {}, "#1f77b4"};
  PlotSeries gb = ab, ga = aa;
  for (size_t i = 0; i < rows.size(); ++i) {
    const json& r = rows[i];
    const double index = Num(Get(r, "index"));
    ab.x.push_back(index), ab.y.push_back(Num(Get(r, "accel_before")) / kMg);
    aa.x.push_back(index), aa.y.push_back(Num(Get(r, "accel_after")) / kMg);
    auto norm = [](const json& v) {
      double s = 0;
      for (const json& c : v) s += Num(c) * Num(c);
      return std::sqrt(s) * kRadToDeg;
    };
    gb.x.push_back(index), gb.y.push_back(norm(Get(r, "gyro_before")));
    ga.x.push_back(index), ga.y.push_back(norm(Get(r, "gyro_after")));
  }
  accel.series = {aa, ab};  // hollow markers drawn last, on top
  gyro.series = {ga, gb};
  if (absl::Status s = write("residual_accel_per_pose.svg", accel); !s.ok()) return s;
  if (absl::Status s = write("residual_gyro_per_pose.svg", gyro); !s.ok()) return s;

  // One plot per effect: its partial residual against its regressor.
  const json effects = Get(report, "effects");
  for (size_t k = 0; effects.is_array() && k < effects.size(); ++k) {
    const json& e = effects[k];
    const std::string field = absl::StrFormat("effects[%d]", static_cast<int>(k));
    const std::string sensor = Get(e, "sensor").is_string() ? Get(e, "sensor").get<std::string>() : "";
    const std::string axis = Get(e, "axis").is_string() ? Get(e, "axis").get<std::string>() : "";
    const std::string name = Get(e, "regressor").is_string() ? Get(e, "regressor").get<std::string>() : "";
    const std::optional<core::Regressor> reg = core::ParseRegressor(name);
    const int ax = axis == "x" ? 0 : axis == "y" ? 1 : axis == "z" ? 2 : -1;
    if (!reg || ax < 0 || (sensor != "accel" && sensor != "gyro")) {
      return absl::InvalidArgumentError(field + ": sensor, axis or regressor malformed");
    }
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
        sig[static_cast<size_t>(q)] = Num(Get(s, std::string(core::kSignalNames[static_cast<size_t>(q)]).c_str()));
      double x = reg->Evaluate(sig);
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
    std::string safe = name;
    for (char& ch : safe)
      if (ch == '*') ch = 'x';
      else if (ch == '^') ch = 'p';
    Plot p{absl::StrFormat("%s %s ~ %s%s", sensor, axis, name, applied ? "" : " (reported, not applied)"),
           is_accel ? absl::StrFormat("%s x gravity direction on %s", name, axis) : name,
           is_accel ? "|a| - g [mg]" : absl::StrFormat("rate %s [deg/s]", axis),
           {after, before, line}};
    const std::string file = absl::StrFormat("effect_%d_%s_%s_%s.svg", static_cast<int>(k) + 1,
                                             sensor, axis, safe);
    if (absl::Status s = write(file, p); !s.ok()) return s;
  }
  return written;
}

}  // namespace imucal::cli
