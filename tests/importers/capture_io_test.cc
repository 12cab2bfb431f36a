#include "importers/capture_io.h"

#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numbers>
#include <optional>
#include <random>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace imucal::importers {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::Pair;
using ::testing::StartsWith;

constexpr char kSpecExample[] =
    "# imucal-capture v1\n"
    "# device=robot-0042\n"
    "# accel_unit=m/s^2\n"
    "# gyro_unit=rad/s\n"
    "# gravity=9.80665\n"
    "# rate_hz=200\n"
    "t,ax,ay,az,gx,gy,gz,temp\n"
    "0.000000,0.0131,-0.0203,9.8152,0.00102,-0.00031,0.00207,24.81\n"
    "0.005000,0.0127,-0.0199,9.8149,0.00098,-0.00027,0.00211,24.81\n";

// A minimal valid header; tests append their own column line and rows.
constexpr char kHeader[] =
    "# imucal-capture v1\n"
    "# accel_unit=m/s^2\n"
    "# gyro_unit=rad/s\n";

std::string TempPath(std::string_view name) {
  return (std::filesystem::path(testing::TempDir()) / name).string();
}

void WriteText(const std::string& path, std::string_view text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(text.data(), static_cast<std::streamsize>(text.size()));
  ASSERT_TRUE(out.good()) << path;
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// The error message of a parse that must fail.
std::string ParseError(std::string_view text) {
  absl::StatusOr<core::Capture> capture = ParseImucalCsv(text, "cap.csv");
  EXPECT_FALSE(capture.ok()) << "parsed " << text;
  if (capture.ok()) return "";
  EXPECT_EQ(capture.status().code(), absl::StatusCode::kInvalidArgument);
  return std::string(capture.status().message());
}

bool SameBits(double a, double b) { return std::memcmp(&a, &b, sizeof(double)) == 0; }

// Values whose text form is awkward: non-terminating binary fractions, extremes of the exponent
// range, subnormals, negative zero, integers above 2^53 precision.
core::Capture AwkwardCapture() {
  core::Capture c;
  c.device = "robot 0042 (bench)";
  c.accel_unit = core::AccelUnit::kG;
  c.gyro_unit = core::GyroUnit::kDegPerSecond;
  c.temp_unit = core::TempUnit::kCounts;
  c.gravity_m_s2 = 9.80743;
  c.rate_hz = 204.8;
  c.extra_metadata = {{"operator", "ada"}, {"zeta", "last=first"}, {"alpha", ""}};
  const std::vector<double> awkward = {0.1,
                                       1.0 / 3.0,
                                       -0.0,
                                       5e-324,
                                       1.7976931348623157e308,
                                       2e-308,
                                       -1e-300,
                                       1e22,
                                       123456789.123456789,
                                       9007199254740993.0,
                                       32768.0,
                                       -2.5e-7};
  for (size_t i = 0; i < awkward.size(); ++i) {
    c.t_s.push_back(1e9 + 0.001 * static_cast<double>(i) + 1.0 / 7.0);
    c.accel.emplace_back(awkward[i], -awkward[(i + 1) % awkward.size()], std::sqrt(2.0) * i);
    c.gyro.emplace_back(std::numbers::pi * i, -awkward[(i + 5) % awkward.size()], 1e-9 * i);
    c.temp.push_back(24.81 + 0.01 * static_cast<double>(i));
  }
  c.extra_column_names = {"seq", "pressure_pa"};
  c.extra_columns = {{}, {}};
  for (size_t i = 0; i < awkward.size(); ++i) {
    c.extra_columns[0].push_back(static_cast<double>(i));
    c.extra_columns[1].push_back(101325.0 + awkward[(i + 3) % awkward.size()]);
  }
  return c;
}

void ExpectSameCapture(const core::Capture& a, const core::Capture& b) {
  EXPECT_EQ(a.device, b.device);
  EXPECT_EQ(a.accel_unit, b.accel_unit);
  EXPECT_EQ(a.gyro_unit, b.gyro_unit);
  EXPECT_EQ(a.temp_unit, b.temp_unit);
  EXPECT_TRUE(SameBits(a.gravity_m_s2, b.gravity_m_s2));
  EXPECT_TRUE(SameBits(a.rate_hz, b.rate_hz));
  EXPECT_EQ(a.extra_metadata, b.extra_metadata);
  EXPECT_EQ(a.extra_column_names, b.extra_column_names);
  ASSERT_EQ(a.size(), b.size());
  ASSERT_EQ(a.temp.size(), b.temp.size());
  ASSERT_EQ(a.extra_columns.size(), b.extra_columns.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_TRUE(SameBits(a.t_s[i], b.t_s[i])) << "t at " << i;
    for (int k = 0; k < 3; ++k) {
      EXPECT_TRUE(SameBits(a.accel[i][k], b.accel[i][k])) << "accel at " << i << "," << k;
      EXPECT_TRUE(SameBits(a.gyro[i][k], b.gyro[i][k])) << "gyro at " << i << "," << k;
    }
    if (a.has_temp()) {
      EXPECT_TRUE(SameBits(a.temp[i], b.temp[i])) << "temp at " << i;
    }
    for (size_t c = 0; c < a.extra_columns.size(); ++c) {
      EXPECT_TRUE(SameBits(a.extra_columns[c][i], b.extra_columns[c][i])) << "extra " << c;
    }
  }
}

// ---------------------------------------------------------------------------------------------
// capture.h

TEST(CaptureTest, UnitNamesRoundTrip) {
  for (core::AccelUnit u :
       {core::AccelUnit::kMetersPerSecond2, core::AccelUnit::kG, core::AccelUnit::kCounts}) {
    EXPECT_EQ(*core::ParseAccelUnit(core::AccelUnitName(u)), u);
  }
  for (core::GyroUnit u :
       {core::GyroUnit::kRadPerSecond, core::GyroUnit::kDegPerSecond, core::GyroUnit::kCounts}) {
    EXPECT_EQ(*core::ParseGyroUnit(core::GyroUnitName(u)), u);
  }
  for (core::TempUnit u : {core::TempUnit::kCelsius, core::TempUnit::kCounts}) {
    EXPECT_EQ(*core::ParseTempUnit(core::TempUnitName(u)), u);
  }
  EXPECT_EQ(core::AccelUnitName(core::AccelUnit::kMetersPerSecond2), "m/s^2");
  EXPECT_EQ(core::GyroUnitName(core::GyroUnit::kDegPerSecond), "deg/s");
  EXPECT_EQ(core::TempUnitName(core::TempUnit::kCelsius), "C");
  EXPECT_FALSE(core::ParseAccelUnit("m/s2").ok());
  EXPECT_FALSE(core::ParseGyroUnit("dps").ok());
  EXPECT_FALSE(core::ParseTempUnit("F").ok());
  EXPECT_THAT(std::string(core::ParseAccelUnit("G").status().message()), HasSubstr("'G'"));
}

TEST(CaptureTest, NominalFactors) {
  EXPECT_EQ(core::NominalAccelToSi(core::AccelUnit::kMetersPerSecond2, 9.81), 1.0);
  EXPECT_EQ(core::NominalAccelToSi(core::AccelUnit::kG, 9.81), 9.81);
  EXPECT_TRUE(std::isnan(core::NominalAccelToSi(core::AccelUnit::kCounts, 9.81)));
  EXPECT_EQ(core::NominalGyroToSi(core::GyroUnit::kRadPerSecond), 1.0);
  EXPECT_DOUBLE_EQ(core::NominalGyroToSi(core::GyroUnit::kDegPerSecond) * 180.0, std::numbers::pi);
  EXPECT_TRUE(std::isnan(core::NominalGyroToSi(core::GyroUnit::kCounts)));
}

TEST(CaptureTest, MedianDtIgnoresADroppedSample) {
  core::Capture c;
  EXPECT_EQ(c.MedianDt(), 0.0);
  c.t_s = {0.0};
  EXPECT_EQ(c.MedianDt(), 0.0);
  c.t_s = {0.0, 0.01, 0.02, 0.04, 0.05};
  EXPECT_DOUBLE_EQ(c.MedianDt(), 0.01);
}

TEST(CaptureTest, ValidateNamesTheSampleAtFault) {
  core::Capture c = AwkwardCapture();
  EXPECT_TRUE(core::ValidateCapture(c).ok());

  core::Capture shorter = c;
  shorter.gyro.pop_back();
  EXPECT_THAT(std::string(core::ValidateCapture(shorter).message()), HasSubstr("gyro"));

  core::Capture not_finite = c;
  not_finite.accel[3].y() = std::numeric_limits<double>::infinity();
  EXPECT_THAT(std::string(core::ValidateCapture(not_finite).message()), HasSubstr("sample 3"));

  core::Capture backwards = c;
  backwards.t_s[5] = backwards.t_s[4];
  EXPECT_EQ(core::ValidateCapture(backwards).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(core::ValidateCapture(backwards).message()), HasSubstr("sample 5"));

  core::Capture bad_extra = c;
  bad_extra.extra_columns[1].pop_back();
  EXPECT_THAT(std::string(core::ValidateCapture(bad_extra).message()), HasSubstr("pressure_pa"));

  core::Capture bad_gravity = c;
  bad_gravity.gravity_m_s2 = 0.0;
  EXPECT_FALSE(core::ValidateCapture(bad_gravity).ok());
}

// ---------------------------------------------------------------------------------------------
// imucal CSV: reading

TEST(ParseImucalCsvTest, ReadsTheSpecExample) {
  absl::StatusOr<core::Capture> c = ParseImucalCsv(kSpecExample, "cap.csv");
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->device, "robot-0042");
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kMetersPerSecond2);
  EXPECT_EQ(c->gyro_unit, core::GyroUnit::kRadPerSecond);
  EXPECT_EQ(c->temp_unit, core::TempUnit::kCelsius);
  EXPECT_EQ(c->gravity_m_s2, 9.80665);
  EXPECT_EQ(c->rate_hz, 200.0);
  ASSERT_EQ(c->size(), 2u);
  EXPECT_EQ(c->t_s[1], 0.005);
  EXPECT_EQ(c->accel[0], Eigen::Vector3d(0.0131, -0.0203, 9.8152));
  EXPECT_EQ(c->gyro[1], Eigen::Vector3d(0.00098, -0.00027, 0.00211));
  EXPECT_THAT(c->temp, ElementsAre(24.81, 24.81));
  EXPECT_TRUE(c->extra_metadata.empty());
  EXPECT_TRUE(c->extra_column_names.empty());
  EXPECT_TRUE(core::ValidateCapture(*c).ok());
}

TEST(ParseImucalCsvTest, DefaultsWhenOptionalHeadersAreAbsent) {
  absl::StatusOr<core::Capture> c =
      ParseImucalCsv(std::string(kHeader) + "t,ax,ay,az,gx,gy,gz\n0,1,2,3,4,5,6\n", "cap.csv");
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->device, "");
  EXPECT_EQ(c->gravity_m_s2, core::kStandardGravity);
  EXPECT_EQ(c->rate_hz, 0.0);
  EXPECT_EQ(c->temp_unit, core::TempUnit::kCelsius);
  EXPECT_FALSE(c->has_temp());
}

TEST(ParseImucalCsvTest, ColumnsInAnyOrderWithExtraColumns) {
  const std::string text = std::string(kHeader) +
                           "gz, seq ,t,temp,ax,gy,ay,flag,gx,az\n"
                           "6,100,0.5,30,1,5,2,-1,4,3\n"
                           "16,101,0.6,31,11,15,12,-2,14,13\n";
  absl::StatusOr<core::Capture> c = ParseImucalCsv(text, "cap.csv");
  ASSERT_TRUE(c.ok()) << c.status();
  ASSERT_EQ(c->size(), 2u);
  EXPECT_THAT(c->t_s, ElementsAre(0.5, 0.6));
  EXPECT_EQ(c->accel[0], Eigen::Vector3d(1, 2, 3));
  EXPECT_EQ(c->gyro[0], Eigen::Vector3d(4, 5, 6));
  EXPECT_EQ(c->accel[1], Eigen::Vector3d(11, 12, 13));
  EXPECT_EQ(c->gyro[1], Eigen::Vector3d(14, 15, 16));
  EXPECT_THAT(c->temp, ElementsAre(30, 31));
  EXPECT_THAT(c->extra_column_names, ElementsAre("seq", "flag"));
  ASSERT_EQ(c->extra_columns.size(), 2u);
  EXPECT_THAT(c->extra_columns[0], ElementsAre(100, 101));
  EXPECT_THAT(c->extra_columns[1], ElementsAre(-1, -2));
}

TEST(ParseImucalCsvTest, CrlfBlankLinesAndNoTrailingNewline) {
  const std::string text =
      "# imucal-capture v1\r\n"
      "\r\n"
      "# accel_unit = g \r\n"
      "   \r\n"
      "#\r\n"
      "# gyro_unit=deg/s\r\n"
      "t,ax,ay,az,gx,gy,gz\r\n"
      "\r\n"
      "0, 1 ,2,3,4,5,6\r\n"
      "\t \r\n"
      "\r\n"
      "1,+1.5,2,3,4,5,6e-3";
  absl::StatusOr<core::Capture> c = ParseImucalCsv(text, "cap.csv");
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kG);
  EXPECT_EQ(c->gyro_unit, core::GyroUnit::kDegPerSecond);
  ASSERT_EQ(c->size(), 2u);
  EXPECT_EQ(c->accel[0], Eigen::Vector3d(1, 2, 3));
  EXPECT_EQ(c->accel[1], Eigen::Vector3d(1.5, 2, 3));
  EXPECT_EQ(c->gyro[1].z(), 6e-3);
}

// The parser puts a fast path in front of std::from_chars; whatever the text, it must accept
// exactly what from_chars accepts and produce the same bits.
std::optional<double> ReferenceParse(std::string_view field) {
  double value;
  const auto [ptr, ec] = std::from_chars(field.data(), field.data() + field.size(), value);
  if (ec != std::errc() || ptr != field.data() + field.size() || !std::isfinite(value)) {
    return std::nullopt;
  }
  return value;
}

std::string OneValueCapture(std::string_view ax) {
  return std::string(kHeader) + "t,ax,ay,az,gx,gy,gz\n0," + std::string(ax) + ",0,0,0,0,0\n";
}

TEST(ParseImucalCsvTest, NumbersMatchFromCharsOnEdgeCases) {
  const std::vector<std::string> fields = {"0",
                                           "-0",
                                           "0.0",
                                           "-0.000",
                                           "00012",
                                           "1.",
                                           "-1.",
                                           ".5",
                                           "-.5",
                                           ".",
                                           "-",
                                           "-.",
                                           "1e",
                                           "1e+",
                                           "1e-",
                                           "1.e5",
                                           "1E5",
                                           "1e+05",
                                           "1e-05",
                                           "1e0000000001",
                                           "0e99999",
                                           "1e22",
                                           "1e23",
                                           "-1e-22",
                                           "1e-23",
                                           "0.1e-22",
                                           "9007199254740992",
                                           "9007199254740993",
                                           "9007199254740993e-5",
                                           "123456789012345678",
                                           "1234567890123456789",
                                           "12345678901234567890",
                                           "0.000000000000000000000000000001",
                                           "4.9e-324",
                                           "2.4703282292062327e-324",
                                           "1.7976931348623157e308",
                                           "1.7976931348623159e308",
                                           "0x1p3",
                                           "1_000",
                                           "1,5",
                                           "e5",
                                           "--1",
                                           "1.2.3",
                                           "3.2786000e+04",
                                           "2.9840000e-02",
                                           "inf",
                                           "nan",
                                           "1d5",
                                           "1e5.5"};
  for (const std::string& field : fields) {
    if (field.find(',') != std::string::npos) continue;
    const std::optional<double> expected = ReferenceParse(field);
    absl::StatusOr<core::Capture> c = ParseImucalCsv(OneValueCapture(field), "cap.csv");
    ASSERT_EQ(c.ok(), expected.has_value()) << "'" << field << "': " << c.status();
    if (expected.has_value()) {
      EXPECT_TRUE(SameBits(c->accel[0].x(), *expected)) << "'" << field << "'";
    } else {
      EXPECT_THAT(std::string(c.status().message()), StartsWith("cap.csv:5: column 'ax': "));
    }
  }
}

TEST(ParseImucalCsvTest, NumbersMatchFromCharsOnRandomText) {
  constexpr uint32_t kSeed = 20240611;
  SCOPED_TRACE(testing::Message() << "seed " << kSeed);
  std::mt19937_64 rng(kSeed);
  std::uniform_real_distribution<double> exponent(-30.0, 30.0);
  std::uniform_int_distribution<int> precision(0, 18);
  std::uniform_int_distribution<int> style(0, 4);
  std::uniform_int_distribution<int64_t> integer(-(int64_t{1} << 60), int64_t{1} << 60);
  std::string text = std::string(kHeader) + "t,ax,ay,az,gx,gy,gz\n";
  std::vector<std::string> fields;
  constexpr int kRows = 40000;
  for (int i = 0; i < kRows; ++i) {
    const double magnitude = std::pow(10.0, exponent(rng)) * (rng() % 2 == 0 ? 1 : -1);
    char buffer[64];
    const int digits = precision(rng);
    switch (style(rng)) {
      case 0:
        std::snprintf(buffer, sizeof(buffer), "%.*f", digits, magnitude * 1e-20);
        break;
      case 1:
        std::snprintf(buffer, sizeof(buffer), "%.*e", digits, magnitude);
        break;
      case 2:
        std::snprintf(buffer, sizeof(buffer), "%.*g", digits, magnitude);
        break;
      case 3:
        std::snprintf(buffer, sizeof(buffer), "%lld", static_cast<long long>(integer(rng)));
        break;
      default:
        std::snprintf(buffer, sizeof(buffer), "%.*f", digits % 8, magnitude * 1e-25);
        break;
    }
    fields.emplace_back(buffer);
    text += std::to_string(i) + "," + fields.back() + ",0,0,0,0,0\n";
  }
  absl::StatusOr<core::Capture> c = ParseImucalCsv(text, "random.csv");
  ASSERT_TRUE(c.ok()) << c.status();
  ASSERT_EQ(c->size(), static_cast<size_t>(kRows));
  for (int i = 0; i < kRows; ++i) {
    const std::optional<double> expected = ReferenceParse(fields[static_cast<size_t>(i)]);
    ASSERT_TRUE(expected.has_value()) << fields[static_cast<size_t>(i)];
    ASSERT_TRUE(SameBits(c->accel[static_cast<size_t>(i)].x(), *expected))
        << "'" << fields[static_cast<size_t>(i)] << "' read as "
        << c->accel[static_cast<size_t>(i)].x();
  }
}

TEST(ParseImucalCsvTest, AcceptsAByteOrderMark) {
  absl::StatusOr<core::Capture> c =
      ParseImucalCsv(std::string("\xEF\xBB\xBF") + kSpecExample, "cap");
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->size(), 2u);
}

TEST(ParseImucalCsvTest, HeaderAndColumnsWithoutRowsIsAnEmptyCapture) {
  absl::StatusOr<core::Capture> c =
      ParseImucalCsv(std::string(kHeader) + "t,ax,ay,az,gx,gy,gz\n", "c");
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->size(), 0u);
}

TEST(ParseImucalCsvTest, UnknownMetadataKeptInOrder) {
  const std::string text =
      "# imucal-capture v1\n"
      "# zeta=1\n"
      "# accel_unit=m/s^2\n"
      "# operator=ada lovelace\n"
      "# gyro_unit=rad/s\n"
      "# alpha=x=y\n"
      "# zeta=2\n"
      "t,ax,ay,az,gx,gy,gz\n";
  absl::StatusOr<core::Capture> c = ParseImucalCsv(text, "cap.csv");
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_THAT(c->extra_metadata, ElementsAre(Pair("zeta", "1"), Pair("operator", "ada lovelace"),
                                             Pair("alpha", "x=y"), Pair("zeta", "2")));
}

// ---------------------------------------------------------------------------------------------
// imucal CSV: errors name the source, the line, the column and the text.

TEST(ParseImucalCsvErrorTest, MissingMarker) {
  EXPECT_THAT(ParseError("# accel_unit=g\n# gyro_unit=rad/s\nt,ax,ay,az,gx,gy,gz\n"),
              StartsWith("cap.csv:1: missing header marker '# imucal-capture v1'"));
  EXPECT_THAT(ParseError("\n# imucal-capture v1\n"), StartsWith("cap.csv:1: missing header"));
  EXPECT_THAT(ParseError(""), StartsWith("cap.csv:1: empty file"));
}

TEST(ParseImucalCsvErrorTest, UnsupportedVersion) {
  EXPECT_THAT(ParseError("# imucal-capture v2\n"),
              StartsWith("cap.csv:1: unsupported capture version '# imucal-capture v2'"));
}

TEST(ParseImucalCsvErrorTest, MissingRequiredHeader) {
  EXPECT_EQ(ParseError("# imucal-capture v1\n# accel_unit=g\n\nt,ax,ay,az,gx,gy,gz\n"),
            "cap.csv:4: missing required header 'gyro_unit'");
  EXPECT_EQ(ParseError("# imucal-capture v1\n# gyro_unit=rad/s\nt,ax,ay,az,gx,gy,gz\n"),
            "cap.csv:3: missing required header 'accel_unit'");
  // No column line at all: the header check still comes first.
  EXPECT_EQ(ParseError("# imucal-capture v1\n# gyro_unit=rad/s\n"),
            "cap.csv:2: missing required header 'accel_unit'");
}

TEST(ParseImucalCsvErrorTest, MissingColumnLine) {
  EXPECT_EQ(ParseError(std::string(kHeader) + "\n"),
            "cap.csv:4: missing column line (t,ax,ay,az,gx,gy,gz)");
}

TEST(ParseImucalCsvErrorTest, BadHeaderValues) {
  EXPECT_THAT(ParseError("# imucal-capture v1\n# accel_unit=m/s2\n"),
              StartsWith("cap.csv:2: accel_unit: unknown accel unit 'm/s2'"));
  EXPECT_THAT(ParseError(std::string(kHeader) + "# temp_unit=F\n"),
              StartsWith("cap.csv:4: temp_unit: unknown temp unit 'F'"));
  EXPECT_EQ(ParseError(std::string(kHeader) + "# gravity=-9.8\n"),
            "cap.csv:4: gravity: '-9.8' is not a positive number");
  EXPECT_EQ(ParseError(std::string(kHeader) + "# rate_hz=fast\n"),
            "cap.csv:4: rate_hz: 'fast' is not a non-negative number");
  EXPECT_EQ(ParseError(std::string(kHeader) + "# gyro_unit=deg/s\n"),
            "cap.csv:4: duplicate header 'gyro_unit' (first at line 3)");
  EXPECT_EQ(ParseError(std::string(kHeader) + "# just a comment\n"),
            "cap.csv:4: header line is not key=value: '# just a comment'");
  EXPECT_EQ(ParseError(std::string(kHeader) + "# =3\n"),
            "cap.csv:4: header line has no key: '# =3'");
}

TEST(ParseImucalCsvErrorTest, MissingRequiredColumn) {
  EXPECT_EQ(ParseError(std::string(kHeader) + "t,ax,ay,az,gx,gy,temp\n0,1,2,3,4,5,6\n"),
            "cap.csv:4: missing required column 'gz'");
  EXPECT_EQ(ParseError(std::string(kHeader) + "ax,ay,az,gx,gy,gz\n"),
            "cap.csv:4: missing required column 't'");
  // Names are exact: no case folding.
  EXPECT_EQ(ParseError(std::string(kHeader) + "T,ax,ay,az,gx,gy,gz\n"),
            "cap.csv:4: missing required column 't'");
}

TEST(ParseImucalCsvErrorTest, BadColumnNames) {
  EXPECT_EQ(ParseError(std::string(kHeader) + "t,ax,ay,az,gx,gy,gz,ax\n"),
            "cap.csv:4: duplicate column 'ax'");
  EXPECT_EQ(ParseError(std::string(kHeader) + "t,ax,ay,,az,gx,gy,gz\n"),
            "cap.csv:4: column 4 has no name");
}

TEST(ParseImucalCsvErrorTest, NotANumber) {
  std::string text = std::string(kHeader) + "t,ax,ay,az,gx,gy,gz,temp\n";
  for (int i = 0; i < 12; ++i) text += std::to_string(i) + ",0,0,9.8,0,0,0,25\n";
  // Line 17: the 13th data row.
  EXPECT_EQ(ParseError(text + "12,0,0,abc,0,0,0,25\n"),
            "cap.csv:17: column 'az': 'abc' is not a number");
  EXPECT_EQ(ParseError(text + "12,0,0,9.8 x,0,0,0,25\n"),
            "cap.csv:17: column 'az': '9.8 x' is not a number");
  EXPECT_EQ(ParseError(text + "12,0,0,9.8,0,0,0,0x10\n"),
            "cap.csv:17: column 'temp': '0x10' is not a number");
  EXPECT_EQ(ParseError(text + "12,0,0,9.8,0,+-1,0,25\n"),
            "cap.csv:17: column 'gy': '+-1' is not a number");
  EXPECT_EQ(ParseError(text + "12,0,0,9.8,0,0,,25\n"), "cap.csv:17: column 'gz': empty field");
  EXPECT_EQ(ParseError(text + "12,0,0,9.8,0,0,0,1e999\n"),
            "cap.csv:17: column 'temp': '1e999' is out of range");
}

TEST(ParseImucalCsvErrorTest, LongBadTextIsShortened) {
  const std::string junk(500, 'x');
  const std::string message =
      ParseError(std::string(kHeader) + "t,ax,ay,az,gx,gy,gz\n0,1,2,3,4,5," + junk + "\n");
  EXPECT_THAT(message, StartsWith("cap.csv:5: column 'gz': 'xxxx"));
  EXPECT_LT(message.size(), 100u);
}

TEST(ParseImucalCsvErrorTest, NonFiniteRejected) {
  const std::string text = std::string(kHeader) + "t,ax,ay,az,gx,gy,gz\n0,0,0,1,0,0,0\n";
  EXPECT_EQ(ParseError(text + "1,0,0,1,nan,0,0\n"), "cap.csv:6: column 'gx': 'nan' is not finite");
  EXPECT_EQ(ParseError(text + "1,0,0,1,0,-inf,0\n"),
            "cap.csv:6: column 'gy': '-inf' is not finite");
  EXPECT_EQ(ParseError(text + "1,Infinity,0,1,0,0,0\n"),
            "cap.csv:6: column 'ax': 'Infinity' is not finite");
  EXPECT_EQ(ParseError(text + "NaN,0,0,1,0,0,0\n"), "cap.csv:6: column 't': 'NaN' is not finite");
}

TEST(ParseImucalCsvErrorTest, WrongFieldCount) {
  std::string text = std::string(kHeader) + "t,ax,ay,az,gx,gy,gz,temp\n";
  for (int i = 0; i < 7; ++i) text += std::to_string(i) + ",0,0,9.8,0,0,0,25\n";
  EXPECT_EQ(ParseError(text + "7,0,0,9.8,0,0,0\n"), "cap.csv:12: expected 8 fields, found 7");
  EXPECT_EQ(ParseError(text + "7,0,0,9.8,0,0,0,25,\n"), "cap.csv:12: expected 8 fields, found 9");
  // The count is checked before the values, so a short row is not blamed on a column.
  EXPECT_EQ(ParseError(text + "x\n"), "cap.csv:12: expected 8 fields, found 1");
}

TEST(ParseImucalCsvErrorTest, TimeMustIncrease) {
  std::string text = std::string(kHeader) + "t,ax,ay,az,gx,gy,gz\n";
  text += "0.4,0,0,1,0,0,0\n";   // line 5
  text += "0.45,0,0,1,0,0,0\n";  // line 6
  text += "\n";                  // line 7
  text += "0.5,0,0,1,0,0,0\n";   // line 8
  EXPECT_EQ(ParseError(text + "0.5,0,0,1,0,0,0\n"),
            "cap.csv:9: t=0.5 does not increase (previous 0.5 at line 8)");
  EXPECT_EQ(ParseError(text + "0.1,0,0,1,0,0,0\n"),
            "cap.csv:9: t=0.1 does not increase (previous 0.5 at line 8)");
}

TEST(ParseImucalCsvErrorTest, CrlfLineNumbersAreTheSame) {
  const std::string text =
      "# imucal-capture v1\r\n# accel_unit=g\r\n# gyro_unit=rad/s\r\nt,ax,ay,az,gx,gy,gz\r\n"
      "0,0,0,1,0,0,0\r\n1,0,0,1,0,0,zz\r\n";
  EXPECT_EQ(ParseError(text), "cap.csv:6: column 'gz': 'zz' is not a number");
}

// ---------------------------------------------------------------------------------------------
// imucal CSV: writing

TEST(FormatImucalCsvTest, RoundTripIsExact) {
  const core::Capture original = AwkwardCapture();
  ASSERT_TRUE(CheckCaptureWritable(original).ok()) << CheckCaptureWritable(original);
  const std::string text = FormatImucalCsv(original);
  absl::StatusOr<core::Capture> parsed = ParseImucalCsv(text, "roundtrip");
  ASSERT_TRUE(parsed.ok()) << parsed.status() << "\n" << text;
  ExpectSameCapture(original, *parsed);
  // And the text is a fixed point.
  EXPECT_EQ(FormatImucalCsv(*parsed), text);
}

TEST(FormatImucalCsvTest, WritesTheSpecLayout) {
  absl::StatusOr<core::Capture> c = ParseImucalCsv(kSpecExample, "spec");
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(FormatImucalCsv(*c),
            "# imucal-capture v1\n"
            "# device=robot-0042\n"
            "# accel_unit=m/s^2\n"
            "# gyro_unit=rad/s\n"
            "# gravity=9.80665\n"
            "# rate_hz=200\n"
            "# temp_unit=C\n"
            "t,ax,ay,az,gx,gy,gz,temp\n"
            "0,0.0131,-0.0203,9.8152,0.00102,-0.00031,0.00207,24.81\n"
            "0.005,0.0127,-0.0199,9.8149,0.00098,-0.00027,0.00211,24.81\n");
}

TEST(FormatImucalCsvTest, RejectsWhatWouldNotRoundTrip) {
  core::Capture c = AwkwardCapture();
  c.device = "two\nlines";
  EXPECT_FALSE(CheckCaptureWritable(c).ok());
  c = AwkwardCapture();
  c.extra_metadata.emplace_back("accel_unit", "g");
  EXPECT_FALSE(CheckCaptureWritable(c).ok());
  c = AwkwardCapture();
  c.extra_metadata.emplace_back("a=b", "c");
  EXPECT_FALSE(CheckCaptureWritable(c).ok());
  c = AwkwardCapture();
  c.extra_column_names[0] = "a,b";
  EXPECT_FALSE(CheckCaptureWritable(c).ok());
  c = AwkwardCapture();
  c.extra_column_names[0] = "temp";
  EXPECT_FALSE(CheckCaptureWritable(c).ok());
  c = AwkwardCapture();
  c.extra_column_names[1] = c.extra_column_names[0];
  EXPECT_FALSE(CheckCaptureWritable(c).ok());
  c = AwkwardCapture();
  c.accel[2].x() = std::nan("");
  EXPECT_FALSE(CheckCaptureWritable(c).ok());
}

TEST(WriteImucalCsvFileTest, WritesAtomicallyAndReadsBack) {
  const std::string path = TempPath("write_roundtrip.csv");
  const core::Capture original = AwkwardCapture();
  ASSERT_TRUE(WriteImucalCsvFile(original, path).ok());
  EXPECT_FALSE(std::filesystem::exists(path + ".tmp"));
  absl::StatusOr<core::Capture> read = ReadImucalCsvFile(path);
  ASSERT_TRUE(read.ok()) << read.status();
  ExpectSameCapture(original, *read);
}

TEST(WriteImucalCsvFileTest, InvalidCaptureLeavesTheOldFile) {
  const std::string path = TempPath("write_invalid.csv");
  WriteText(path, "old content");
  core::Capture bad = AwkwardCapture();
  bad.t_s[3] = bad.t_s[2];
  const absl::Status status = WriteImucalCsvFile(bad, path);
  EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(ReadText(path), "old content");
  EXPECT_FALSE(std::filesystem::exists(path + ".tmp"));
}

TEST(WriteImucalCsvFileTest, UnwritableDirectoryIsAnError) {
  const std::string path = TempPath("no_such_dir/cap.csv");
  const absl::Status status = WriteImucalCsvFile(AwkwardCapture(), path);
  EXPECT_EQ(status.code(), absl::StatusCode::kNotFound);
  EXPECT_THAT(std::string(status.message()), HasSubstr("cap.csv.tmp"));
  EXPECT_FALSE(std::filesystem::exists(path));
}

TEST(ReadImucalCsvFileTest, MissingFileIsNotFound) {
  absl::StatusOr<core::Capture> c = ReadImucalCsvFile(TempPath("does_not_exist.csv"));
  EXPECT_EQ(c.status().code(), absl::StatusCode::kNotFound);
  EXPECT_THAT(std::string(c.status().message()), HasSubstr("does_not_exist.csv"));
}

TEST(ReadImucalCsvFileTest, ErrorsArePrefixedWithThePath) {
  const std::string path = TempPath("bad_row.csv");
  WriteText(path, std::string(kHeader) + "t,ax,ay,az,gx,gy,gz\n0,1,2,3,4,5\n");
  absl::StatusOr<core::Capture> c = ReadImucalCsvFile(path);
  EXPECT_EQ(c.status().message(), path + ":5: expected 7 fields, found 6");
}

// ---------------------------------------------------------------------------------------------
// Unit inference

std::vector<Eigen::Vector3d> Poses(double magnitude) {
  // Several faces up, as in a calibration: the per-axis median would be near zero, the median
  // magnitude is not.
  std::vector<Eigen::Vector3d> out;
  for (int i = 0; i < 60; ++i) {
    Eigen::Vector3d axis = Eigen::Vector3d::Zero();
    axis[i % 3] = (i % 2 == 0 ? 1.0 : -1.0) * magnitude;
    out.push_back(axis + Eigen::Vector3d(0.01, -0.02, 0.015) * magnitude);
  }
  return out;
}

TEST(InferUnitTest, Accelerometer) {
  std::string reason;
  EXPECT_EQ(InferAccelUnit(Poses(9.81), core::kStandardGravity, &reason),
            core::AccelUnit::kMetersPerSecond2);
  EXPECT_THAT(reason, StartsWith("accel unit inferred as m/s^2: median |a| 9.7"));
  EXPECT_EQ(InferAccelUnit(Poses(1.02), core::kStandardGravity, &reason), core::AccelUnit::kG);
  EXPECT_THAT(reason, StartsWith("accel unit inferred as g"));
  EXPECT_EQ(InferAccelUnit(Poses(16384), core::kStandardGravity, &reason),
            core::AccelUnit::kCounts);
  EXPECT_THAT(reason, StartsWith("accel unit inferred as counts: median |a| 16"));
  std::vector<Eigen::Vector3d> unsigned_counts(10, Eigen::Vector3d(33108, 33329, 36429));
  EXPECT_EQ(InferAccelUnit(unsigned_counts, core::kStandardGravity, nullptr),
            core::AccelUnit::kCounts);
  // An uncalibrated sensor 8% off still reads as m/s^2.
  EXPECT_EQ(InferAccelUnit(Poses(10.6), core::kStandardGravity, nullptr),
            core::AccelUnit::kMetersPerSecond2);
}

TEST(InferUnitTest, Gyroscope) {
  std::vector<Eigen::Vector3d> still(100, Eigen::Vector3d(0.01, -0.02, 0.003));
  std::vector<Eigen::Vector3d> turning_deg = still;
  for (int i = 0; i < 10; ++i) turning_deg[static_cast<size_t>(i) * 10] = {0, 0, 90};
  std::vector<Eigen::Vector3d> turning_rad = still;
  for (int i = 0; i < 10; ++i) turning_rad[static_cast<size_t>(i) * 10] = {0, 0, 1.6};
  std::vector<Eigen::Vector3d> integers(100, Eigen::Vector3d(3, -2, 0));
  std::vector<Eigen::Vector3d> big(100, Eigen::Vector3d(32786.5, 32429, 32499));

  std::string reason;
  EXPECT_EQ(InferGyroUnit(turning_deg, core::AccelUnit::kMetersPerSecond2, &reason),
            core::GyroUnit::kDegPerSecond);
  EXPECT_THAT(reason, StartsWith("gyro unit inferred as deg/s: 99th-percentile |rate| 90"));
  EXPECT_EQ(InferGyroUnit(turning_rad, core::AccelUnit::kG, &reason),
            core::GyroUnit::kRadPerSecond);
  EXPECT_THAT(reason, HasSubstr("cannot tell deg/s from rad/s"));
  EXPECT_EQ(InferGyroUnit(integers, core::AccelUnit::kCounts, &reason), core::GyroUnit::kCounts);
  EXPECT_THAT(reason, HasSubstr("every gyro value is an integer"));
  EXPECT_EQ(InferGyroUnit(big, core::AccelUnit::kCounts, &reason), core::GyroUnit::kCounts);
  // Integer values alone do not make counts when the accelerometer is in physical units.
  EXPECT_EQ(InferGyroUnit(integers, core::AccelUnit::kMetersPerSecond2, nullptr),
            core::GyroUnit::kRadPerSecond);
}

// ---------------------------------------------------------------------------------------------
// imu_tk pair

// A small pair in deg/s and m/s^2: 50 static samples, a rotation, 50 static samples.
std::pair<std::string, std::string> ImuTkTexts() {
  std::string accel, gyro;
  for (int i = 0; i < 120; ++i) {
    const std::string t = std::to_string(0.01 * i);
    const bool turning = i >= 50 && i < 70;
    accel += "  " + t + "  0.01  -0.02  " + (i < 60 ? "9.81" : "-9.79") + "\n";
    gyro += t + "\t0.1\t" + (turning ? "90.0" : "-0.2") + "\t0.05\n";
  }
  return {accel, gyro};
}

TEST(ImuTkTest, ParsesAndInfersPhysicalUnits) {
  const auto [accel, gyro] = ImuTkTexts();
  std::vector<std::string> notes;
  absl::StatusOr<core::Capture> c = ParseImuTkPair(accel, "acc.txt", gyro, "gyr.txt", {}, &notes);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->size(), 120u);
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kMetersPerSecond2);
  EXPECT_EQ(c->gyro_unit, core::GyroUnit::kDegPerSecond);
  EXPECT_EQ(c->gravity_m_s2, core::kStandardGravity);
  EXPECT_EQ(c->accel[70], Eigen::Vector3d(0.01, -0.02, -9.79));
  EXPECT_EQ(c->gyro[55], Eigen::Vector3d(0.1, 90.0, 0.05));
  ASSERT_EQ(notes.size(), 2u);
  EXPECT_THAT(notes[0], StartsWith("accel unit inferred as m/s^2"));
  EXPECT_THAT(notes[1], StartsWith("gyro unit inferred as deg/s"));
  EXPECT_TRUE(core::ValidateCapture(*c).ok());
}

TEST(ImuTkTest, OptionsOverrideInference) {
  const auto [accel, gyro] = ImuTkTexts();
  ImportOptions options;
  options.accel_unit = core::AccelUnit::kCounts;
  options.gyro_unit = core::GyroUnit::kRadPerSecond;
  options.gravity_m_s2 = 9.81744;
  options.device = "xsens";
  std::vector<std::string> notes;
  absl::StatusOr<core::Capture> c = ParseImuTkPair(accel, "a", gyro, "g", options, &notes);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kCounts);
  EXPECT_EQ(c->gyro_unit, core::GyroUnit::kRadPerSecond);
  EXPECT_EQ(c->gravity_m_s2, 9.81744);
  EXPECT_EQ(c->device, "xsens");
  EXPECT_TRUE(notes.empty());
}

TEST(ImuTkTest, MismatchedRowCount) {
  auto [accel, gyro] = ImuTkTexts();
  gyro.resize(gyro.rfind('\n', gyro.size() - 2) + 1);  // drop the last gyro line
  absl::StatusOr<core::Capture> c = ParseImuTkPair(accel, "acc.txt", gyro, "gyr.txt", {});
  EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(c.status().message(),
            "gyr.txt:119: ends after 119 samples, but acc.txt has 120 (sample 120 at "
            "acc.txt:120, t=1.19)");
}

TEST(ImuTkTest, MismatchedTimestamp) {
  auto [accel, gyro] = ImuTkTexts();
  const size_t at = gyro.find("0.300000");  // sample 31, line 31
  ASSERT_NE(at, std::string::npos);
  gyro.replace(at, 8, "0.300500");
  absl::StatusOr<core::Capture> c = ParseImuTkPair(accel, "acc.txt", gyro, "gyr.txt", {});
  EXPECT_EQ(c.status().message(), "gyr.txt:31: t=0.3005 does not match acc.txt:31 (t=0.3)");
}

TEST(ImuTkTest, LineErrors) {
  const std::string good = "0 1 2 3\n0.01 1 2 3\n";
  auto error = [&](const std::string& accel) {
    return std::string(ParseImuTkPair(accel, "acc.txt", good, "gyr.txt", {}).status().message());
  };
  EXPECT_EQ(error("0 1 2 3\n\n0.01 1 2 3 4\n"), "acc.txt:3: expected 4 fields (t x y z), found 5");
  EXPECT_EQ(error("0 1 2 3\n0.01 1 y 3\n"), "acc.txt:2: column 'y': 'y' is not a number");
  EXPECT_EQ(error("0 1 2 3\n0.01 1 2 nan\n"), "acc.txt:2: column 'z': 'nan' is not finite");
  EXPECT_EQ(error("0 1 2 3\n0 1 2 3\n"), "acc.txt:2: t=0 does not increase (previous 0 at line 1)");
  EXPECT_EQ(error("\n\n"), "acc.txt:2: no samples (expected lines of 't x y z')");
}

TEST(ImuTkTest, CrlfAndBlankLines) {
  absl::StatusOr<core::Capture> c =
      ParseImuTkPair("0 0 0 9.8\r\n\r\n0.01 0 0 9.8\r\n", "a", "0 0 0 0\n0.01 0 0 0", "g", {});
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->size(), 2u);
}

// ---------------------------------------------------------------------------------------------
// Importer registry

TEST(ImportCaptureTest, RegistryListsTheFormats) {
  std::vector<std::string_view> names;
  for (const CaptureImporter* importer : CaptureImporters()) {
    names.push_back(importer->name());
    EXPECT_FALSE(importer->description().empty());
  }
  EXPECT_THAT(names, ElementsAre("imucal", "euroc", "imutk", "columns"));
}

TEST(ImportCaptureTest, AutoDetectsImucal) {
  const std::string path = TempPath("auto_imucal.csv");
  WriteText(path, kSpecExample);
  ImportOptions options;
  options.device = "robot-7";
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({path}, options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(report.format, "imucal");
  EXPECT_THAT(report.paths, ElementsAre(path));
  EXPECT_EQ(c->device, "robot-7");
  EXPECT_THAT(report.notes,
              ElementsAre("device 'robot-7' used instead of the file's 'robot-0042'"));
  // The caller that does not want the report.
  EXPECT_TRUE(ImportCapture({path}, ImportOptions{}).ok());
}

TEST(ImportCaptureTest, ImucalOverridesUnitsAndGravity) {
  const std::string path = TempPath("override_imucal.csv");
  WriteText(path, kSpecExample);
  ImportOptions options;
  options.format = "imucal";
  options.accel_unit = core::AccelUnit::kG;
  options.gravity_m_s2 = 9.81;
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({path}, options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kG);
  EXPECT_EQ(c->gravity_m_s2, 9.81);
  EXPECT_THAT(report.notes, ElementsAre("accel unit g used instead of the file's m/s^2",
                                        "gravity 9.81 m/s^2 used instead of the file's 9.80665"));
}

TEST(ImportCaptureTest, AutoDetectsImuTkAndSwapsByName) {
  const auto [accel, gyro] = ImuTkTexts();
  const std::string accel_path = TempPath("pair_Acc.txt");
  const std::string gyro_path = TempPath("pair_GYRO.txt");
  WriteText(accel_path, accel);
  WriteText(gyro_path, gyro);
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({gyro_path, accel_path}, {}, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(report.format, "imutk");
  EXPECT_THAT(report.paths, ElementsAre(accel_path, gyro_path));
  ASSERT_EQ(report.notes.size(), 3u);
  EXPECT_THAT(report.notes[0], StartsWith("swapped the inputs by their names"));
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kMetersPerSecond2);
  EXPECT_EQ(c->gyro_unit, core::GyroUnit::kDegPerSecond);
  EXPECT_EQ(c->accel[0].z(), 9.81);

  // In the right order nothing is swapped.
  ASSERT_TRUE(ImportCapture({accel_path, gyro_path}, {}, &report).ok());
  EXPECT_THAT(report.notes[0], StartsWith("accel unit inferred"));
}

TEST(ImportCaptureTest, ExplicitImuTkPairMismatch) {
  const auto [accel, gyro] = ImuTkTexts();
  const std::string accel_path = TempPath("mismatch_acc.txt");
  const std::string gyro_path = TempPath("mismatch_gyro.txt");
  WriteText(accel_path, accel);
  WriteText(gyro_path, gyro.substr(0, gyro.find("0.500000")));  // 50 rows of 120
  ImportOptions options;
  options.format = "imutk";
  absl::StatusOr<core::Capture> c = ImportCapture({accel_path, gyro_path}, options);
  EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(c.status().message()),
              StartsWith(gyro_path + ":50: ends after 50 samples, but " + accel_path +
                         " has 120 (sample 51 at " + accel_path + ":51"));
}

TEST(ImportCaptureTest, UnrecognisedFormatSaysWhatWasTried) {
  const std::string path = TempPath("vendor.csv");
  WriteText(path, "time,acc_x,acc_y,acc_z\n0,1,2,3\n");
  absl::StatusOr<core::Capture> c = ImportCapture({path}, {});
  EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument);
  const std::string message(c.status().message());
  EXPECT_THAT(message, StartsWith(path + ": unrecognised capture format (tried imucal: "));
  EXPECT_THAT(message, HasSubstr("; imutk: "));
  EXPECT_THAT(message, HasSubstr("'time,acc_x,acc_y,acc_z'"));
}

TEST(ImportCaptureTest, WrongCallsAreClearErrors) {
  const std::string imucal_path = TempPath("count_imucal.csv");
  WriteText(imucal_path, kSpecExample);
  const std::string tk_path = TempPath("count_tk.txt");
  WriteText(tk_path, "0 1 2 3\n");

  EXPECT_THAT(std::string(ImportCapture({}, {}).status().message()), HasSubstr("no input"));
  EXPECT_THAT(std::string(ImportCapture({imucal_path, imucal_path}, {}).status().message()),
              HasSubstr("the imucal format reads one file, got 2"));
  EXPECT_THAT(std::string(ImportCapture({tk_path}, {}).status().message()),
              HasSubstr("the imutk format reads two files"));
  ImportOptions mcap;
  mcap.format = "mcap";
  EXPECT_EQ(ImportCapture({imucal_path}, mcap).status().message(),
            "unknown capture format 'mcap' (known: auto, imucal, euroc, imutk, columns)");
  ImportOptions bad_gravity;
  bad_gravity.gravity_m_s2 = -1.0;
  EXPECT_FALSE(ImportCapture({imucal_path}, bad_gravity).ok());
  EXPECT_EQ(ImportCapture({TempPath("missing.txt")}, {}).status().code(),
            absl::StatusCode::kNotFound);
}

TEST(ImportCaptureTest, ExportThenImportRoundTrip) {
  const std::string path = TempPath("export_import.csv");
  const core::Capture original = AwkwardCapture();
  ASSERT_TRUE(WriteImucalCsvFile(original, path).ok());
  absl::StatusOr<core::Capture> c = ImportCapture({path}, {});
  ASSERT_TRUE(c.ok()) << c.status();
  ExpectSameCapture(original, *c);
}

// ---------------------------------------------------------------------------------------------
// Real data: the Xsens capture shipped with imu_tk (../shared/data/real/xsens-imutk/SOURCE.txt).

TEST(RealDataTest, XsensImuTkPairAutoDetectedAsCounts) {
  const std::string dir = IMUCAL_SHARED_DIR "/data/real/xsens-imutk/";
  const std::string accel_path = dir + "xsens_acc.mat";
  const std::string gyro_path = dir + "xsens_gyro.mat";
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({accel_path, gyro_path}, {}, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(report.format, "imutk");
  EXPECT_EQ(c->size(), 51175u);
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kCounts);
  EXPECT_EQ(c->gyro_unit, core::GyroUnit::kCounts);
  ASSERT_EQ(report.notes.size(), 2u);
  EXPECT_THAT(report.notes[0], StartsWith("accel unit inferred as counts"));
  EXPECT_THAT(report.notes[1], StartsWith("gyro unit inferred as counts"));
  EXPECT_EQ(c->t_s.front(), 2.984e-02);
  EXPECT_EQ(c->accel.front(), Eigen::Vector3d(33108, 33329, 36429));
  EXPECT_EQ(c->gyro.front(), Eigen::Vector3d(32786, 32429, 32499));
  EXPECT_EQ(c->t_s.back(), 511.718);
  EXPECT_EQ(c->accel.back(), Eigen::Vector3d(35290, 35137, 27631));
  EXPECT_NEAR(c->MedianDt(), 0.01, 1e-4);  // 100 Hz
  EXPECT_FALSE(c->has_temp());
  EXPECT_TRUE(core::ValidateCapture(*c).ok());

  // Given in the other order, the names put them right.
  ASSERT_TRUE(ImportCapture({gyro_path, accel_path}, {}, &report).ok());
  EXPECT_THAT(report.paths, ElementsAre(accel_path, gyro_path));
}

}  // namespace
}  // namespace imucal::importers
