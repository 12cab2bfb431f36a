// The parameter cache file: round trip, atomic replace, and every kind of damage -> DataLoss.
#include "client/sdk/param_cache.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "absl/strings/str_cat.h"
#include "formats/crc32c.h"
#include "formats/params_json.h"

namespace imucal::sdk {
namespace {

namespace fs = std::filesystem;

StoredParams MakeStored(const std::string& device, int version) {
  core::ParamSet p;
  p.device = device;
  p.version = version;
  p.accel.bias = Eigen::Vector3d(0.01, -0.02, 0.03);
  p.accel.scale = Eigen::Vector3d(1.01, 0.99, 1.0);
  StoredParams s;
  s.device_id = device;
  s.version = version;
  s.json = formats::ParamSetToJson(p);
  s.crc32c = formats::Crc32c(s.json);
  return s;
}

class ParamCacheTest : public testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::path(testing::TempDir()) /
           absl::StrCat("imucal_param_cache_test_",
                        testing::UnitTest::GetInstance()->current_test_info()->name(), "_",
                        ::getpid());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    path_ = (dir_ / "params.cache").string();
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string ReadText() const {
    std::ifstream f(path_, std::ios::binary);
    std::stringstream ss;
    ss << f.rdbuf();
    return ss.str();
  }
  void WriteText(const std::string& text) const {
    std::ofstream f(path_, std::ios::binary | std::ios::trunc);
    f << text;
  }

  fs::path dir_;
  std::string path_;
};

TEST_F(ParamCacheTest, RoundTrip) {
  const StoredParams stored = MakeStored("robot-0042", 7);
  ASSERT_TRUE(SaveParamCache(path_, stored).ok());
  absl::StatusOr<LoadedParams> loaded = LoadParamCache(path_);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->stored.device_id, "robot-0042");
  EXPECT_EQ(loaded->stored.version, 7);
  EXPECT_EQ(loaded->stored.crc32c, stored.crc32c);
  EXPECT_EQ(loaded->stored.json, stored.json);
  EXPECT_EQ(loaded->params.accel.bias, Eigen::Vector3d(0.01, -0.02, 0.03));
  EXPECT_EQ(ReadText().rfind("imucal-param-cache v1\n", 0), 0u);
}

TEST_F(ParamCacheTest, SaveReplacesAndLeavesNoTempFile) {
  ASSERT_TRUE(SaveParamCache(path_, MakeStored("robot-0042", 7)).ok());
  ASSERT_TRUE(SaveParamCache(path_, MakeStored("robot-0042", 8)).ok());
  absl::StatusOr<LoadedParams> loaded = LoadParamCache(path_);
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->stored.version, 8);
  int files = 0;
  for (const auto& entry : fs::directory_iterator(dir_)) files += entry.is_regular_file();
  EXPECT_EQ(files, 1);
}

TEST_F(ParamCacheTest, SaveRefusesAWrongChecksum) {
  StoredParams stored = MakeStored("robot-0042", 7);
  stored.crc32c ^= 1;
  EXPECT_TRUE(absl::IsInvalidArgument(SaveParamCache(path_, stored)));
  EXPECT_FALSE(fs::exists(path_));
}

TEST_F(ParamCacheTest, MissingFileIsNotFound) {
  EXPECT_TRUE(absl::IsNotFound(LoadParamCache(path_).status()));
}

TEST_F(ParamCacheTest, FlippedByteInJsonIsDataLoss) {
  ASSERT_TRUE(SaveParamCache(path_, MakeStored("robot-0042", 7)).ok());
  std::string text = ReadText();
  text[text.size() - 20] ^= 0x04;
  WriteText(text);
  absl::Status s = LoadParamCache(path_).status();
  EXPECT_TRUE(absl::IsDataLoss(s)) << s;
  EXPECT_NE(s.message().find("checksum mismatch"), std::string::npos) << s;
}

TEST_F(ParamCacheTest, EveryFlippedByteIsDetected) {
  ASSERT_TRUE(SaveParamCache(path_, MakeStored("robot-0042", 7)).ok());
  const std::string good = ReadText();
  for (size_t i = 0; i < good.size(); i += 7) {
    std::string bad = good;
    bad[i] ^= 0x10;
    WriteText(bad);
    absl::StatusOr<LoadedParams> loaded = LoadParamCache(path_);
    // A flip in the device line may still be a consistent file only if the JSON agrees, which
    // it cannot: the JSON names the device too.
    EXPECT_FALSE(loaded.ok()) << "byte " << i << " flipped went unnoticed";
    if (!loaded.ok()) {
      EXPECT_TRUE(absl::IsDataLoss(loaded.status())) << loaded.status();
    }
  }
}

TEST_F(ParamCacheTest, TruncatedIsDataLoss) {
  ASSERT_TRUE(SaveParamCache(path_, MakeStored("robot-0042", 7)).ok());
  std::string text = ReadText();
  WriteText(text.substr(0, text.size() - 10));
  absl::Status s = LoadParamCache(path_).status();
  EXPECT_TRUE(absl::IsDataLoss(s)) << s;
  EXPECT_NE(s.message().find("truncated"), std::string::npos) << s;
}

TEST_F(ParamCacheTest, WrongFormatVersionIsDataLoss) {
  ASSERT_TRUE(SaveParamCache(path_, MakeStored("robot-0042", 7)).ok());
  std::string text = ReadText();
  text.replace(0, std::string("imucal-param-cache v1").size(), "imucal-param-cache v2");
  WriteText(text);
  absl::Status s = LoadParamCache(path_).status();
  EXPECT_TRUE(absl::IsDataLoss(s)) << s;
  EXPECT_NE(s.message().find("v2"), std::string::npos) << s;
}

TEST_F(ParamCacheTest, NotACacheFileIsDataLoss) {
  WriteText("{\"format\": \"imucal-params v1\"}");
  absl::Status s = LoadParamCache(path_).status();
  EXPECT_TRUE(absl::IsDataLoss(s)) << s;
  EXPECT_NE(s.message().find("not an imucal parameter cache"), std::string::npos) << s;
}

TEST_F(ParamCacheTest, HeaderVersionDisagreeingWithJsonIsDataLoss) {
  ASSERT_TRUE(SaveParamCache(path_, MakeStored("robot-0042", 7)).ok());
  std::string text = ReadText();
  const size_t at = text.find("version 7\n");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, 9, "version 6");
  WriteText(text);
  absl::Status s = LoadParamCache(path_).status();
  EXPECT_TRUE(absl::IsDataLoss(s)) << s;
  EXPECT_NE(s.message().find("version"), std::string::npos) << s;
}

}  // namespace
}  // namespace imucal::sdk
