// What the end-to-end tests against real imucald processes (crash_test, daemon_test,
// replicas_test) share as clients: the seeded test's seed, and the simulated robot's device.
#ifndef IMUCAL_TESTS_SERVER_DAEMON_CLIENTS_H_
#define IMUCAL_TESTS_SERVER_DAEMON_CLIENTS_H_

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "absl/strings/numbers.h"
#include "gtest/gtest.h"
#include "imucal/v1/imucal.grpc.pb.h"

namespace imucal::testing_util {

// The test's seed, or IMUCAL_CRASH_SEED when set (to replay a failing run's kill points); said
// on stdout so that a failure's log gives the replay.
inline uint64_t SeedOr(uint64_t fallback) {
  uint64_t seed = fallback;
  if (const char* env = std::getenv("IMUCAL_CRASH_SEED"); env != nullptr) {
    EXPECT_TRUE(absl::SimpleAtoi(env, &seed)) << "IMUCAL_CRASH_SEED=" << env;
  }
  std::printf("[ seed     ] %llu (IMUCAL_CRASH_SEED=%llu replays these kill points)\n",
              static_cast<unsigned long long>(seed), static_cast<unsigned long long>(seed));
  std::fflush(stdout);
  return seed;
}

// Registers `device` as the simulator's robot: 200 Hz, in SI units (core::Simulate's capture).
inline v1::RegisterDeviceRequest SimDeviceRequest(const std::string& device) {
  v1::RegisterDeviceRequest req;
  req.mutable_device()->set_id(device);
  req.mutable_device()->set_sensor_model("sim");
  req.mutable_device()->set_nominal_rate_hz(200);
  req.mutable_device()->set_accel_unit("m/s^2");
  req.mutable_device()->set_gyro_unit("rad/s");
  return req;
}

}  // namespace imucal::testing_util

#endif  // IMUCAL_TESTS_SERVER_DAEMON_CLIENTS_H_
