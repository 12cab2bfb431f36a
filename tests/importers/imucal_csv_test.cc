// Tests of the imucal capture CSV (importers/imucal_csv.h): reading, errors, writing, files.
#include "importers/imucal_csv.h"

#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <optional>
#include <random>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include "core/capture.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/core/test_captures.h"
#include "tests/importers/test_files.h"

namespace imucal::importers {
namespace {

using core::test_captures::AwkwardCapture;
using core::test_captures::ExpectSameCapture;
using core::test_captures::SameBits;
using test_files::kHeader;
using test_files::kSpecExample;
using test_files::ReadText;
using test_files::TempPath;
using test_files::WriteText;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::Not;
using ::testing::Pair;
using ::testing::StartsWith;

// The error message of a parse that must fail.
std::string ParseError(std::string_view text) {
  absl::StatusOr<core::Capture> capture = ParseImucalCsv(text, "cap.csv");
  EXPECT_FALSE(capture.ok()) << "parsed " << text;
  if (capture.ok()) return "";
  EXPECT_EQ(capture.status().code(), absl::StatusCode::kInvalidArgument);
  return std::string(capture.status().message());
}

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
            "cap.csv:4: missing required column 'gz' (give all of gx, gy, gz, or none for an "
            "accelerometer-only capture)");
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

// ---------------------------------------------------------------------------------------------
// Accelerometer-only captures: no gx,gy,gz columns (and then no gyro_unit needed).

TEST(ImucalCsvAccelOnlyTest, NoGyroColumnsIsACaptureWithoutGyro) {
  absl::StatusOr<core::Capture> c = ParseImucalCsv(
      "# imucal-capture v1\n# accel_unit=m/s^2\nt,ax,ay,az,temp\n0,1,2,3,25\n0.1,1,2,3.5,25\n",
      "acc.csv");
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_FALSE(c->has_gyro);
  EXPECT_TRUE(c->gyro.empty());
  ASSERT_EQ(c->size(), 2u);
  EXPECT_DOUBLE_EQ(c->accel[1].z(), 3.5);
  EXPECT_TRUE(c->has_temp());
  EXPECT_TRUE(core::ValidateCapture(*c).ok());
}

TEST(ImucalCsvAccelOnlyTest, GyroUnitStillRequiredWithGyroColumns) {
  EXPECT_EQ(ParseError("# imucal-capture v1\n# accel_unit=g\nt,ax,ay,az,gx,gy,gz\n"),
            "cap.csv:3: missing required header 'gyro_unit'");
}

TEST(ImucalCsvAccelOnlyTest, WrittenWithoutGyroColumnsAndReadBackTheSame) {
  core::Capture c;
  c.has_gyro = false;
  c.t_s = {0.0, 0.005};
  c.accel = {Eigen::Vector3d(0.1, 0.2, 9.8), Eigen::Vector3d(0.1, 0.25, 9.81)};
  const std::string text = FormatImucalCsv(c);
  EXPECT_THAT(text, HasSubstr("\nt,ax,ay,az\n"));
  EXPECT_THAT(text, Not(HasSubstr("gyro")));
  absl::StatusOr<core::Capture> back = ParseImucalCsv(text, "back.csv");
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_FALSE(back->has_gyro);
  EXPECT_EQ(FormatImucalCsv(*back), text);
}

TEST(ImucalCsvAccelOnlyTest, ValidateCaptureRefusesGyroSamplesWithoutGyro) {
  core::Capture c;
  c.has_gyro = false;
  c.t_s = {0.0};
  c.accel = {Eigen::Vector3d(0, 0, 9.8)};
  c.gyro = {Eigen::Vector3d::Zero()};
  EXPECT_THAT(core::ValidateCapture(c).message(), HasSubstr("no gyroscope but holds 1"));
}

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

}  // namespace
}  // namespace imucal::importers
