// Helpers shared by the storage tests.
#ifndef IMUCAL_TESTS_STORAGE_TEST_UTIL_H_
#define IMUCAL_TESTS_STORAGE_TEST_UTIL_H_

#include <unistd.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "gtest/gtest.h"
#include "storage/sample_codec.h"
#include "storage/types.h"

#define STORAGE_TEST_CONCAT_INNER_(a, b) a##b
#define STORAGE_TEST_CONCAT_(a, b) STORAGE_TEST_CONCAT_INNER_(a, b)

#define ASSERT_OK(expr)                                             \
  do {                                                              \
    const absl::Status storage_test_status_ = (expr);               \
    ASSERT_TRUE(storage_test_status_.ok()) << storage_test_status_; \
  } while (false)
#define EXPECT_OK(expr)                                             \
  do {                                                              \
    const absl::Status storage_test_status_ = (expr);               \
    EXPECT_TRUE(storage_test_status_.ok()) << storage_test_status_; \
  } while (false)

// ASSERT_OK_AND_ASSIGN(auto x, F()); fails the test (returning) on error.
#define ASSERT_OK_AND_ASSIGN(lhs, expr) \
  ASSERT_OK_AND_ASSIGN_IMPL_(STORAGE_TEST_CONCAT_(storage_test_or_, __LINE__), lhs, expr)
#define ASSERT_OK_AND_ASSIGN_IMPL_(tmp, lhs, expr) \
  auto tmp = (expr);                               \
  ASSERT_TRUE(tmp.ok()) << tmp.status();           \
  lhs = std::move(*tmp)

namespace imucal::storage {

// A fresh path for a database file in the test's temporary directory (old files removed).
inline std::string TempDbPath(const std::string& name) {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string test = std::string(info->test_suite_name()) + "_" + info->name();
  for (char& c : test)
    if (c == '/') c = '_';  // parameterised tests are named "Suite/Name/Param"
  const std::string path = ::testing::TempDir() + "imucal_" + test + "_" + name + "_" +
                           std::to_string(::getpid()) + ".db";
  for (const char* suffix : {"", "-wal", "-shm"}) std::filesystem::remove(path + suffix);
  return path;
}

// ---- Domain objects as a robot and the server would send them --------------------------------

inline Device MakeDevice(const std::string& id) {
  Device d;
  d.id = id;
  d.sensor_model = "ICM-20948";
  d.nominal_rate_hz = 200;
  d.accel_unit = "m/s^2";
  d.gyro_unit = "rad/s";
  return d;
}

inline Session MakeSession(const std::string& device_id, const std::string& id = "") {
  Session s;
  s.id = id;
  s.device_id = device_id;
  s.protocol = "six-face";
  return s;
}

// The batch a robot would send as `seq`: deterministic, so a reader can check it is intact.
inline std::string BatchPayload(int64_t seq, int samples = 50) {
  std::vector<ImuSample> out(static_cast<size_t>(samples));
  for (int i = 0; i < samples; ++i) {
    ImuSample& s = out[static_cast<size_t>(i)];
    s.t_s = static_cast<double>(seq) + 0.005 * i;
    s.accel = {0.01 * i, -0.02 * static_cast<double>(seq), 9.81};
    s.gyro = {1e-3 * static_cast<double>(seq), 2e-3, -1e-3 * i};
    s.temp = 25.0 + 1e-3 * static_cast<double>(seq);
  }
  return EncodeSamples(out).value();
}

inline ParamVersion MakeVersion(const std::string& device_id, Verdict verdict = Verdict::kPass,
                                VersionState state = VersionState::kCandidate) {
  ParamVersion v;
  v.device_id = device_id;
  v.params_json = R"({"format": "imucal-params v1"})";
  v.report_json = R"({"format": "imucal-report v1", "verdict": "pass"})";
  v.verdict = verdict;
  v.accel_rms = 0.0004;
  v.state = state;
  v.provenance = "imucal 0.1.0 test";
  return v;
}

}  // namespace imucal::storage

#endif  // IMUCAL_TESTS_STORAGE_TEST_UTIL_H_
