// Reads raw samples from stdin and writes them corrected to stdout, for both consumers.
//   stdin:  one sample a line: t ax ay az gx gy gz temp (temp `nan` when not measured)
//   stdout: one line a sample: t ax ay az gx gy gz, m/s^2 and rad/s, %.17g
// The first sample's t is the time origin, as `imucal apply` takes the capture's first.
#ifndef SDK_CONSUMER_SAMPLES_H_
#define SDK_CONSUMER_SAMPLES_H_

#include <cstdio>
#include <optional>
#include <vector>

#include "client/sdk/corrector.h"
#include "core/params.h"

inline int CorrectStdin(const imucal::core::ParamSet& params) {
  std::vector<imucal::sdk::RawSample> raw;
  imucal::sdk::RawSample s;
  while (std::scanf("%lf %lf %lf %lf %lf %lf %lf %lf", &s.t_s, &s.accel[0], &s.accel[1],
                    &s.accel[2], &s.gyro[0], &s.gyro[1], &s.gyro[2], &s.temp_c) == 8) {
    raw.push_back(s);
  }
  if (raw.empty()) return std::fprintf(stderr, "no samples on stdin\n"), 1;
  auto corrector = imucal::sdk::Corrector::Create(params, raw.front().t_s);
  if (!corrector.ok())
    return std::fprintf(stderr, "%s\n", corrector.status().ToString().c_str()), 1;
  std::vector<imucal::sdk::CalibratedSample> out(raw.size());
  if (auto st = corrector->ApplyBatch(raw, out); !st.ok())
    return std::fprintf(stderr, "%s\n", st.ToString().c_str()), 1;
  for (size_t i = 0; i < raw.size(); ++i) {
    const auto& c = out[i];
    std::printf("%.17g %.17g %.17g %.17g %.17g %.17g %.17g\n", raw[i].t_s, c.accel_m_s2[0],
                c.accel_m_s2[1], c.accel_m_s2[2], c.gyro_rad_s[0], c.gyro_rad_s[1],
                c.gyro_rad_s[2]);
  }
  return 0;
}

#endif  // SDK_CONSUMER_SAMPLES_H_
