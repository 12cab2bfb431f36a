// Plots of a calibration report, as SVG files a browser or any image viewer opens. They are drawn
// from the report JSON ("imucal-report v1" with its `effect_diagnostics`), so the offline
// `calibrate --plots DIR` and the server's `report --plots DIR` draw the same pictures:
//
//   residual_accel_per_pose.svg   |a| - g per used pose (mg), before and after the effects
//   residual_gyro_per_pose.svg    static rate magnitude per used pose (deg/s), before and after
//   residual_stages_per_pose.svg  |a| - g per used pose (mg) after each solver stage (ls, bsas,
//       lm, effects): what each stage changed, pose by pose
//   coverage.svg                  the gravity direction of each pose in the body frame on the
//       sphere (Lambert equal-area, one disc per hemisphere; used poses filled, others hollow)
//   allan_accel.svg, allan_gyro.svg   Allan deviation per axis against tau, log-log, over the
//       rest the noise figures were measured on (m/s^2 and rad/s), with the lines of the fitted
//       figures (parameters.noise): N / sqrt(tau), 0.664 B and K sqrt(tau / 3), dashed
// Every plot has units on its axes and a one-line caption under it saying what good looks like;
// the per-pose plots draw the verdict's thresholds and the noise floor as lines and number the
// poses (formats/plots.cc says where each line comes from).
//   effect_N_<sensor>_<axis>_<regressor>.svg   for effect N: the residual it explains against
//       its regressor (partial residual: every other effect removed), before and after, with
//       the fitted line. For the accelerometer the abscissa is the regressor times the pose's
//       gravity-direction component on the effect's axis, the way the term reaches |a| - g.
#ifndef IMUCAL_FORMATS_PLOTS_H_
#define IMUCAL_FORMATS_PLOTS_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "nlohmann/json.hpp"

namespace imucal::formats {

// Writes the plots into `dir` (created if missing) and returns the paths written. Each plot is
// drawn when the report holds its data (a report without any gives an empty list).
// InvalidArgument names the JSON field that is malformed.
absl::StatusOr<std::vector<std::string>> WriteReportPlots(const nlohmann::json& report,
                                                          const std::string& dir);

// The report's files in `dir` (created if missing): report.json (`report_text`, as given),
// summary.txt (`summary`) and the plots. Returns every path written.
absl::StatusOr<std::vector<std::string>> WriteReportBundle(const nlohmann::json& report,
                                                           const std::string& report_text,
                                                           const std::string& summary,
                                                           const std::string& dir);

// One scatter plot (exposed for tests): series of points, optionally joined by lines.
struct PlotSeries {
  std::string label;
  std::vector<double> x, y;
  std::string colour = "#1f77b4";
  bool line = false;    // join the points in order instead of drawing markers
  bool hollow = false;  // open markers
  bool dashed = false;  // a dashed line (fitted or reference curves)
  // A small label beside each point (pose numbers); empty, or one per point.
  std::vector<std::string> point_labels = {};
};
// A horizontal reference line across the plot (a threshold, a noise floor), labelled at its end.
struct RefLine {
  double y = 0;
  std::string label;
  std::string colour = "#555555";
};
struct Plot {
  std::string title, x_label, y_label;
  std::vector<PlotSeries> series;
  bool log_x = false, log_y = false;  // decades; non-positive values are left out
  bool equal_aspect = false;          // one unit is as long on both axes (maps)
  bool axes = true;                   // false: no grid, ticks or frame (maps)
  std::vector<RefLine> ref_lines = {};
  std::string caption = {};  // one line under the plot: what good looks like
};
std::string RenderSvg(const Plot& plot);

}  // namespace imucal::formats

#endif  // IMUCAL_FORMATS_PLOTS_H_
