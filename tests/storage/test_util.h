// Helpers shared by the storage tests.
#ifndef IMUCAL_TESTS_STORAGE_TEST_UTIL_H_
#define IMUCAL_TESTS_STORAGE_TEST_UTIL_H_

#include <unistd.h>

#include <filesystem>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "gtest/gtest.h"

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
  const std::string path = ::testing::TempDir() + "imucal_" + info->test_suite_name() + "_" +
                           info->name() + "_" + name + "_" + std::to_string(::getpid()) + ".db";
  for (const char* suffix : {"", "-wal", "-shm"}) std::filesystem::remove(path + suffix);
  return path;
}

}  // namespace imucal::storage

#endif  // IMUCAL_TESTS_STORAGE_TEST_UTIL_H_
