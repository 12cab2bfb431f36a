// A directory of the running test's own, for its databases, certificates and files.
#ifndef IMUCAL_TESTS_TEST_DIR_H_
#define IMUCAL_TESTS_TEST_DIR_H_

#include <unistd.h>

#include <filesystem>
#include <string>
#include <string_view>
#include <system_error>

#include "gtest/gtest.h"

namespace imucal::testing_util {

// <TempDir>/<prefix>_<test name>_<pid>, empty when handed out and removed with the object.
//
// The name keeps apart the tests that ctest runs in parallel processes; it is emptied first
// because a name is not unique over time: the pid of an earlier process (an earlier CI stage,
// a crashed run) may come round again, and a database found there would hand the test another
// test's devices and sessions. Construct it in the fixture (or the test body): the test's name
// is known there.
class TestDir {
 public:
  explicit TestDir(std::string_view prefix) {
    const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string name(prefix);
    if (info != nullptr) name += std::string("_") + info->test_suite_name() + "_" + info->name();
    name += "_" + std::to_string(::getpid());
    for (char& c : name)
      if (c == '/') c = '_';  // parameterised tests are named "Suite/Name/0"
    path_ = std::filesystem::path(::testing::TempDir()) / name;
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  ~TestDir() {
    std::error_code ignored;  // a file still open elsewhere must not fail the test here
    std::filesystem::remove_all(path_, ignored);
  }
  TestDir(const TestDir&) = delete;
  TestDir& operator=(const TestDir&) = delete;

  const std::filesystem::path& path() const { return path_; }
  // The path of `name` inside the directory.
  std::string File(std::string_view name) const { return (path_ / name).string(); }

 private:
  std::filesystem::path path_;
};

}  // namespace imucal::testing_util

#endif  // IMUCAL_TESTS_TEST_DIR_H_
