#include "client/cli/export_flags.h"

#include <cmath>

#include "absl/strings/str_format.h"

namespace imucal::cli {

const char kExportOptionsHelp[] =
    "  --rostopic TOPIC        the IMU topic written (default /imu0)\n"
    "  --rate HZ               update_rate (default: the rate of the rest the noise came from)\n"
    "  --openvins-model kalibr|rpng   OpenVINS's intrinsic model (default kalibr)\n"
    "  --accel-noise-density V [m/s^2/sqrt(Hz)]   --accel-random-walk V [m/s^3/sqrt(Hz)]\n"
    "  --gyro-noise-density V [rad/s/sqrt(Hz)]    --gyro-random-walk V [rad/s^2/sqrt(Hz)]\n"
    "                          continuous-time values (e.g. the datasheet's) for figures the\n"
    "                          parameter set's noise block lacks; used only for those. A random\n"
    "                          walk the capture's rest did not reach is otherwise written as the\n"
    "                          upper bound the data gives, and the output says so\n";

std::set<std::string> WithExportValuedFlags(std::set<std::string> flags) {
  for (const char* f : {"rostopic", "rate", "openvins-model", "accel-noise-density",
                        "accel-random-walk", "gyro-noise-density", "gyro-random-walk"})
    flags.insert(f);
  return flags;
}

absl::StatusOr<core::ExportOptions> ExportOptionsFrom(const Args& a) {
  core::ExportOptions o;
  if (auto t = a.Get("rostopic")) o.rostopic = *t;
  struct Flag {
    const char* name;
    double* value;
  };
  for (const Flag& f :
       {Flag{"rate", &o.update_rate_hz}, Flag{"accel-noise-density", &o.accel_noise_density},
        Flag{"accel-random-walk", &o.accel_random_walk},
        Flag{"gyro-noise-density", &o.gyro_noise_density},
        Flag{"gyro-random-walk", &o.gyro_random_walk}}) {
    auto v = a.GetDouble(f.name, core::ExportOptions::kUnset);
    if (!v.ok()) return v.status();
    if (a.Get(f.name) && !(*v > 0 && std::isfinite(*v)))
      return absl::InvalidArgumentError(absl::StrFormat("--%s: must be a positive number", f.name));
    *f.value = *v;
  }
  if (auto m = a.Get("openvins-model")) {
    if (*m == "kalibr") {
      o.openvins_model = core::OpenVinsModel::kKalibr;
    } else if (*m == "rpng") {
      o.openvins_model = core::OpenVinsModel::kRpng;
    } else {
      return absl::InvalidArgumentError("--openvins-model: expected kalibr or rpng");
    }
  }
  return o;
}

}  // namespace imucal::cli
