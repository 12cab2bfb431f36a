// Shared by the tests that kill imucald (durability_test, crash_test): whether a sample read
// back from the store is bit for bit the one the robot sent.
#ifndef IMUCAL_TESTS_SERVER_STORED_SAMPLES_H_
#define IMUCAL_TESTS_SERVER_STORED_SAMPLES_H_

#include <cstddef>
#include <cstring>

#include "core/capture.h"
#include "storage/sample_codec.h"

namespace imucal::testing_util {

// Bit-for-bit equality of a stored sample with the capture's sample i (all eight doubles).
inline bool SameBytes(const storage::ImuSample& s, const core::Capture& cap, size_t i) {
  const double want[8] = {cap.t_s[i],      cap.accel[i].x(), cap.accel[i].y(), cap.accel[i].z(),
                          cap.gyro[i].x(), cap.gyro[i].y(),  cap.gyro[i].z(),  cap.temp[i]};
  const double got[8] = {s.t_s,     s.accel[0], s.accel[1], s.accel[2],
                         s.gyro[0], s.gyro[1],  s.gyro[2],  s.temp};
  return std::memcmp(want, got, sizeof want) == 0;
}

}  // namespace imucal::testing_util

#endif  // IMUCAL_TESTS_SERVER_STORED_SAMPLES_H_
