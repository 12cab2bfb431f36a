// A robot's startup: get the IMU calibration from the service (or, when it is unreachable, from
// the local cache), build the corrector, correct samples.
//   robot_startup [SERVER] [DEVICE] [CACHE] [CA_PEM TOKEN_FILE]
//   (defaults 127.0.0.1:50051 robot-0042 ./params.cache; without CA_PEM and TOKEN_FILE the
//   channel is plaintext, for a server run with `insecure` on loopback)
#include <cstdio>
#include <string>

#include "absl/time/time.h"
#include "client/sdk/client.h"
#include "client/sdk/corrector.h"

int main(int argc, char** argv) {
  using namespace imucal;
  const std::string server = argc > 1 ? argv[1] : "127.0.0.1:50051";
  const std::string device = argc > 2 ? argv[2] : "robot-0042";
  const std::string cache = argc > 3 ? argv[3] : "params.cache";
  // TLS with the fleet's CA, and the robot's token (bound to this device) on every call.
  absl::StatusOr<sdk::ClientOptions> tls =
      argc > 5 ? sdk::ClientOptionsFromFiles(argv[4], argv[5]) : sdk::ClientOptions();
  if (!tls.ok()) return std::fprintf(stderr, "%s\n", tls.status().ToString().c_str()), 1;

  auto client = sdk::ParamClient::Create(server, *tls);
  if (!client.ok()) return std::fprintf(stderr, "%s\n", client.status().ToString().c_str()), 1;
  // A short deadline: a robot must boot even when the service is down (then from the cache).
  auto boot = sdk::LoadOrFetch(*client, device, cache, absl::Seconds(2));
  if (!boot.ok())
    return std::fprintf(stderr, "no IMU calibration: %s\n", boot.status().ToString().c_str()), 1;
  std::printf("%s\n", boot->note.c_str());

  auto corrector = sdk::Corrector::Create(boot->loaded.params);
  if (!corrector.ok())
    return std::fprintf(stderr, "bad parameters: %s\n", corrector.status().ToString().c_str()), 1;

  sdk::RawSample raw;  // in the parameter set's input units, e.g. from the IMU driver
  raw.accel[2] = 9.81;
  raw.temp_c = 25.0;
  sdk::CalibratedSample out;
  corrector->Apply(raw, &out);  // allocation-free, noexcept: fine in the IMU's real-time loop
  std::printf("accel [%.4f %.4f %.4f] m/s^2  gyro [%.5f %.5f %.5f] rad/s\n", out.accel_m_s2[0],
              out.accel_m_s2[1], out.accel_m_s2[2], out.gyro_rad_s[0], out.gyro_rad_s[1],
              out.gyro_rad_s[2]);
  return 0;
}
