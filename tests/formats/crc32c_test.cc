// CRC-32C against the standard check value, the RFC 3720 (iSCSI) test vectors and the bitwise
// definition. The server and the SDK's cache both call this function (formats/crc32c.h), so
// these vectors pin both ends of ParameterSet.crc32c.
#include "formats/crc32c.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <random>
#include <string>
#include <string_view>

namespace imucal::formats {
namespace {

TEST(Crc32cTest, CheckValue) { EXPECT_EQ(Crc32c("123456789"), 0xE3069283u); }

TEST(Crc32cTest, EmptyIsZero) { EXPECT_EQ(Crc32c(""), 0x00000000u); }

// RFC 3720 appendix B.4 (the CRC bytes there are written in transmission order, lowest first).
TEST(Crc32cTest, Rfc3720Vectors) {
  EXPECT_EQ(Crc32c(std::string(32, '\0')), 0x8A9136AAu);
  EXPECT_EQ(Crc32c(std::string(32, '\xFF')), 0x62A8AB43u);
  std::string ascending;
  std::string descending;
  for (int i = 0; i < 32; ++i) {
    ascending.push_back(static_cast<char>(i));
    descending.push_back(static_cast<char>(31 - i));
  }
  EXPECT_EQ(Crc32c(ascending), 0x46DD794Eu);
  EXPECT_EQ(Crc32c(descending), 0x113FDB5Cu);
}

// The definition, one bit at a time (reflected polynomial 0x82F63B78): independent of the
// table that Crc32c builds.
uint32_t BitwiseCrc32c(std::string_view data) {
  uint32_t c = 0xFFFFFFFFu;
  for (unsigned char b : data) {
    c ^= b;
    for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0x82F63B78u & (0u - (c & 1u)));
  }
  return ~c;
}

TEST(Crc32cTest, TableAgreesWithTheBitwiseDefinition) {
  std::mt19937 rng(20240521);
  std::uniform_int_distribution<int> byte(0, 255);
  for (size_t length = 0; length <= 300; ++length) {
    std::string data(length, '\0');
    for (char& c : data) c = static_cast<char>(byte(rng));
    ASSERT_EQ(Crc32c(data), BitwiseCrc32c(data)) << "length " << length;
  }
}

TEST(Crc32cTest, DetectsAFlippedBit) {
  std::string s = "{\"format\": \"imucal-params v1\"}";
  const uint32_t before = Crc32c(s);
  s[5] ^= 0x01;
  EXPECT_NE(Crc32c(s), before);
}

}  // namespace
}  // namespace imucal::formats
