#include "storage/sample_codec.h"

#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/storage/test_util.h"

namespace imucal::storage {
namespace {

using ::testing::HasSubstr;

constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

std::vector<ImuSample> RandomSamples(size_t n, bool with_temp, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0.0, 1.0);
  std::vector<ImuSample> out(n);
  double t = 1000.0 * noise(rng);
  for (ImuSample& s : out) {
    t += 0.005 + 1e-4 * std::abs(noise(rng));
    s.t_s = t;
    for (int i = 0; i < 3; ++i) {
      s.accel[i] = 9.81 * noise(rng);
      s.gyro[i] = 1e-3 * noise(rng);
    }
    if (with_temp) s.temp = 25.0 + noise(rng);
  }
  return out;
}

// Bitwise: the codec must not change a single bit of what the robot sent.
void ExpectSameBits(const std::vector<ImuSample>& a, const std::vector<ImuSample>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    const double va[8] = {a[i].t_s,     a[i].accel[0], a[i].accel[1], a[i].accel[2],
                          a[i].gyro[0], a[i].gyro[1],  a[i].gyro[2],  a[i].temp};
    const double vb[8] = {b[i].t_s,     b[i].accel[0], b[i].accel[1], b[i].accel[2],
                          b[i].gyro[0], b[i].gyro[1],  b[i].gyro[2],  b[i].temp};
    for (int f = 0; f < 8; ++f) {
      ASSERT_EQ(std::bit_cast<uint64_t>(va[f]), std::bit_cast<uint64_t>(vb[f]))
          << "sample " << i << " field " << f;
    }
  }
}

TEST(SampleCodecTest, RoundTripWithAndWithoutTemperature) {
  for (bool with_temp : {false, true}) {
    for (size_t n : {size_t{1}, size_t{2}, size_t{200}, size_t{5000}}) {
      SCOPED_TRACE(testing::Message() << "with_temp=" << with_temp << " n=" << n);
      const std::vector<ImuSample> samples = RandomSamples(n, with_temp, /*seed=*/42 + n);
      ASSERT_OK_AND_ASSIGN(std::string bytes, EncodeSamples(samples));
      EXPECT_EQ(bytes.size(), kSampleHeaderBytes + n * 8 * (with_temp ? 8 : 7));
      ASSERT_OK_AND_ASSIGN(std::vector<ImuSample> decoded, DecodeSamples(bytes));
      ExpectSameBits(samples, decoded);
      ASSERT_OK_AND_ASSIGN(EncodedBatchInfo info, InspectSamples(bytes));
      EXPECT_EQ(info.count, static_cast<int64_t>(n));
      EXPECT_EQ(info.has_temp, with_temp);
      EXPECT_EQ(info.first_t_s, samples.front().t_s);
      EXPECT_EQ(info.last_t_s, samples.back().t_s);
    }
  }
}

TEST(SampleCodecTest, EmptyBatchIsJustAHeader) {
  ASSERT_OK_AND_ASSIGN(std::string bytes, EncodeSamples({}));
  EXPECT_EQ(bytes.size(), kSampleHeaderBytes);
  ASSERT_OK_AND_ASSIGN(std::vector<ImuSample> decoded, DecodeSamples(bytes));
  EXPECT_TRUE(decoded.empty());
  ASSERT_OK_AND_ASSIGN(EncodedBatchInfo info, InspectSamples(bytes));
  EXPECT_EQ(info.count, 0);
  EXPECT_TRUE(std::isnan(info.first_t_s));
}

TEST(SampleCodecTest, LayoutIsLittleEndianAsDocumented) {
  ImuSample s;
  s.t_s = 1.5;
  s.accel = {1, 2, 3};
  s.gyro = {4, 5, 6};
  s.temp = 7;
  const ImuSample samples[] = {s};
  ASSERT_OK_AND_ASSIGN(std::string bytes, EncodeSamples(samples));
  ASSERT_EQ(bytes.size(), 6u + 64u);
  EXPECT_EQ(static_cast<uint8_t>(bytes[0]), kSampleCodecVersion);
  EXPECT_EQ(static_cast<uint8_t>(bytes[1]), 0x01);  // temperature present
  EXPECT_EQ(bytes.substr(2, 4), std::string("\x01\x00\x00\x00", 4));
  // 1.5 = 0x3FF8000000000000, least significant byte first.
  EXPECT_EQ(bytes.substr(6, 8), std::string("\x00\x00\x00\x00\x00\x00\xf8\x3f", 8));
  // temp = 7.0 = 0x401C000000000000, the last field.
  EXPECT_EQ(bytes.substr(6 + 56, 8), std::string("\x00\x00\x00\x00\x00\x00\x1c\x40", 8));
}

TEST(SampleCodecTest, EncodeRejectsWhatTheCaptureFormatRejects) {
  std::vector<ImuSample> samples = RandomSamples(4, /*with_temp=*/true, 1);

  std::vector<ImuSample> mixed = samples;
  mixed[2].temp = kNan;
  EXPECT_EQ(EncodeSamples(mixed).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(EncodeSamples(mixed).status().message(), HasSubstr("sample 2"));

  std::vector<ImuSample> nan_accel = samples;
  nan_accel[1].accel[2] = kNan;
  EXPECT_THAT(EncodeSamples(nan_accel).status().message(), HasSubstr("sample 1: az"));

  std::vector<ImuSample> inf_t = samples;
  inf_t[0].t_s = kInf;
  EXPECT_THAT(EncodeSamples(inf_t).status().message(), HasSubstr("sample 0: t_s"));

  std::vector<ImuSample> backwards = samples;
  backwards[3].t_s = backwards[2].t_s;
  EXPECT_EQ(EncodeSamples(backwards).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(EncodeSamples(backwards).status().message(), HasSubstr("does not increase"));
}

// Decoding errors are DataLoss and name the byte offset of the fault.
void ExpectDataLossAt(std::string_view bytes, size_t offset, std::string_view what) {
  absl::StatusOr<std::vector<ImuSample>> decoded = DecodeSamples(bytes);
  ASSERT_FALSE(decoded.ok());
  EXPECT_EQ(decoded.status().code(), absl::StatusCode::kDataLoss) << decoded.status();
  EXPECT_THAT(decoded.status().message(), HasSubstr("offset " + std::to_string(offset) + ":"));
  EXPECT_THAT(decoded.status().message(), HasSubstr(what));
  EXPECT_EQ(InspectSamples(bytes).status(), decoded.status());
}

void PutF64(std::string* bytes, size_t offset, double v) {
  const uint64_t bits = std::bit_cast<uint64_t>(v);
  for (int i = 0; i < 8; ++i) (*bytes)[offset + i] = static_cast<char>((bits >> (8 * i)) & 0xff);
}

TEST(SampleCodecTest, GarbageIsDataLossNamingTheOffset) {
  ASSERT_OK_AND_ASSIGN(const std::string good,
                       EncodeSamples(RandomSamples(3, /*with_temp=*/false, 7)));
  ExpectDataLossAt("", 0, "truncated header");
  ExpectDataLossAt(good.substr(0, 4), 4, "truncated header");

  std::string bad_version = good;
  bad_version[0] = 9;
  ExpectDataLossAt(bad_version, 0, "unknown format version 9");

  std::string bad_flags = good;
  bad_flags[1] = static_cast<char>(0x82);
  ExpectDataLossAt(bad_flags, 1, "unknown flag bits 0x82");

  ExpectDataLossAt(good.substr(0, good.size() - 1), good.size() - 1, "truncated");
  ExpectDataLossAt(good + "x", good.size(), "1 unexpected bytes after 3 samples");

  // A header that claims 4 billion samples must fail fast, not allocate.
  std::string huge = good;
  huge[2] = huge[3] = huge[4] = huge[5] = static_cast<char>(0xff);
  ExpectDataLossAt(huge, good.size(), "4294967295 samples");

  // Sample 1's gy (field 5) is NaN: offset 6 + (1 * 7 + 5) * 8.
  std::string nan_value = good;
  PutF64(&nan_value, 6 + (7 + 5) * 8, kNan);
  ExpectDataLossAt(nan_value, 6 + (7 + 5) * 8, "sample 1 gy is not finite");

  // Sample 2's t equals sample 1's: the record of sample 2 starts at 6 + 2 * 56.
  std::string stalled = good;
  PutF64(&stalled, 6 + 2 * 56, DecodeSamples(good).value()[1].t_s);
  ExpectDataLossAt(stalled, 6 + 2 * 56, "sample 2 t_s");
}

TEST(SampleCodecTest, EveryTruncationOfAValidBatchIsDataLoss) {
  ASSERT_OK_AND_ASSIGN(const std::string good,
                       EncodeSamples(RandomSamples(5, /*with_temp=*/true, 3)));
  for (size_t len = 0; len < good.size(); ++len) {
    EXPECT_EQ(InspectSamples(good.substr(0, len)).status().code(), absl::StatusCode::kDataLoss)
        << "length " << len;
  }
}

TEST(SampleCodecTest, RandomBytesNeverCrashAndFailCleanly) {
  const uint64_t seed = 20261122;
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> byte(0, 255);
  std::uniform_int_distribution<int> length(0, 300);
  int accepted = 0;
  for (int trial = 0; trial < 20000; ++trial) {
    std::string bytes(static_cast<size_t>(length(rng)), '\0');
    for (char& c : bytes) c = static_cast<char>(byte(rng));
    // Half the trials get a plausible header so the body checks run too.
    if (trial % 2 == 0 && bytes.size() >= 6) {
      const size_t fields = (trial % 4 == 0) ? 8 : 7;
      const uint32_t count = static_cast<uint32_t>((bytes.size() - 6) / (fields * 8));
      bytes.resize(6 + count * fields * 8);
      bytes[0] = 1;
      bytes[1] = fields == 8 ? 1 : 0;
      for (int i = 0; i < 4; ++i) bytes[2 + i] = static_cast<char>((count >> (8 * i)) & 0xff);
    }
    absl::StatusOr<std::vector<ImuSample>> decoded = DecodeSamples(bytes);
    if (decoded.ok()) {
      ++accepted;
      continue;
    }
    ASSERT_EQ(decoded.status().code(), absl::StatusCode::kDataLoss)
        << "seed " << seed << " trial " << trial << ": " << decoded.status();
    ASSERT_THAT(decoded.status().message(), HasSubstr("offset "))
        << "seed " << seed << " trial " << trial;
  }
  // Only empty-bodied or lucky batches decode; most random doubles fail the time check.
  EXPECT_LT(accepted, 20000);
}

TEST(SampleCodecTest, DecodeIntoAppendsAndLeavesOutputAloneOnError) {
  const std::vector<ImuSample> a = RandomSamples(3, false, 11);
  std::vector<ImuSample> b = RandomSamples(2, false, 12);
  ASSERT_OK_AND_ASSIGN(const std::string ea, EncodeSamples(a));
  ASSERT_OK_AND_ASSIGN(const std::string eb, EncodeSamples(b));
  std::vector<ImuSample> out;
  ASSERT_OK(DecodeSamplesInto(ea, &out));
  ASSERT_OK(DecodeSamplesInto(eb, &out));
  std::vector<ImuSample> expected = a;
  expected.insert(expected.end(), b.begin(), b.end());
  ExpectSameBits(expected, out);

  std::string broken = eb;
  PutF64(&broken, 6 + 56, kInf);  // sample 1's t
  EXPECT_EQ(DecodeSamplesInto(broken, &out).code(), absl::StatusCode::kDataLoss);
  ExpectSameBits(expected, out);
}

}  // namespace
}  // namespace imucal::storage
