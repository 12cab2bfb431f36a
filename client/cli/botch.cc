// BotchFirstTurn: a hold a quarter turn into the first 180-degree turn (see botch.h).
#include "client/cli/botch.h"

#include <algorithm>
#include <cstddef>

#include "Eigen/Core"
#include "absl/status/status.h"

namespace imucal::cli {

// The simulator moves every pose by a rotation with no translation, so a reading during the
// turn is the static reading of that orientation plus noise: the inserted hold is the turn's
// midpoint accelerometer reading (a few samples averaged) plus the noise of the first pose's
// hold, and the first pose's gyroscope readings (its bias plus noise).
absl::StatusOr<core::Capture> BotchFirstTurn(const core::SimResult& sim, double hold_s) {
  const core::Capture& in = sim.capture;
  if (sim.poses.size() < 2) return absl::InvalidArgumentError("--botch-turn needs two poses");
  const double t_mid = 0.5 * (sim.poses[0].t_end_s + sim.poses[1].t_start_s);
  size_t mid = 0, first = in.size(), last = 0;
  for (size_t i = 0; i < in.size(); ++i) {
    if (in.t_s[i] <= t_mid) mid = i;
    if (in.t_s[i] >= sim.poses[0].t_start_s && in.t_s[i] <= sim.poses[0].t_end_s) {
      first = std::min(first, i);
      last = i;
    }
  }
  const double dt = in.MedianDt();
  const size_t n = static_cast<size_t>(hold_s / dt);
  if (first >= last || last - first < n || mid < 2 || mid + 3 > in.size())
    return absl::InvalidArgumentError("--botch-turn: the first pose is too short");
  Eigen::Vector3d accel_mid = Eigen::Vector3d::Zero(), accel_mean0 = Eigen::Vector3d::Zero();
  for (size_t i = mid - 2; i <= mid + 2; ++i) accel_mid += in.accel[i] / 5.0;
  const size_t src0 = last + 1 - n;  // the first pose's last n samples
  for (size_t k = 0; k < n; ++k) accel_mean0 += in.accel[src0 + k] / static_cast<double>(n);

  core::Capture out = in;
  out.t_s.resize(mid + 1), out.accel.resize(mid + 1), out.gyro.resize(mid + 1);
  if (in.has_temp()) out.temp.resize(mid + 1);
  for (auto& column : out.extra_columns) column.resize(mid + 1);
  for (size_t k = 0; k < n; ++k) {
    out.t_s.push_back(in.t_s[mid] + static_cast<double>(k + 1) * dt);
    out.accel.push_back(accel_mid + in.accel[src0 + k] - accel_mean0);
    out.gyro.push_back(in.gyro[src0 + k]);
    if (in.has_temp()) out.temp.push_back(in.temp[mid]);
    for (size_t c = 0; c < out.extra_columns.size(); ++c)
      out.extra_columns[c].push_back(in.extra_columns[c][mid]);
  }
  const double shift = static_cast<double>(n) * dt;
  for (size_t i = mid + 1; i < in.size(); ++i) {
    out.t_s.push_back(in.t_s[i] + shift);
    out.accel.push_back(in.accel[i]);
    out.gyro.push_back(in.gyro[i]);
    if (in.has_temp()) out.temp.push_back(in.temp[i]);
    for (size_t c = 0; c < out.extra_columns.size(); ++c)
      out.extra_columns[c].push_back(in.extra_columns[c][i]);
  }
  if (absl::Status s = core::ValidateCapture(out); !s.ok()) return s;
  return out;
}

}  // namespace imucal::cli
