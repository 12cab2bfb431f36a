// CRC-32C against the standard check value and RFC 3720 (iSCSI) test vectors.
#include "formats/crc32c.h"

#include <gtest/gtest.h>

#include <string>

namespace imucal::formats {
namespace {

TEST(Crc32cTest, CheckValue) { EXPECT_EQ(Crc32c("123456789"), 0xE3069283u); }

TEST(Crc32cTest, EmptyIsZero) { EXPECT_EQ(Crc32c(""), 0x00000000u); }

TEST(Crc32cTest, Rfc3720Vectors) {
  EXPECT_EQ(Crc32c(std::string(32, '\0')), 0x8A9136AAu);
  EXPECT_EQ(Crc32c(std::string(32, '\xFF')), 0x62A8AB43u);
  std::string ascending;
  for (int i = 0; i < 32; ++i) ascending.push_back(static_cast<char>(i));
  EXPECT_EQ(Crc32c(ascending), 0x46DD794Eu);
}

TEST(Crc32cTest, DetectsAFlippedBit) {
  std::string s = "{\"format\": \"imucal-params v1\"}";
  const uint32_t before = Crc32c(s);
  s[5] ^= 0x01;
  EXPECT_NE(Crc32c(s), before);
}

}  // namespace
}  // namespace imucal::formats
