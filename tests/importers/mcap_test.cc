// Tests of the MCAP reader (importers/mcap.cc) on files that tests/tools/write_mcap.py writes
// from the MCAP specification, compressing chunks with the zstd and lz4 command-line tools: in
// every compression, with and without a summary, unchunked, as a bare file and as a bag
// directory. Each is compared with the sqlite3 bag that tests/tools/write_rosbag2.py writes of
// the same simulated messages: the two storages must give the same capture, to the bit.
#include "importers/mcap.h"

#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "importers/registry.h"

namespace imucal::importers {
namespace {

namespace fs = std::filesystem;
using ::testing::AllOf;
using ::testing::Contains;
using ::testing::HasSubstr;
using ::testing::Not;

// A short simulated session (a 2 s rest, then six faces held 1 s): ~1900 Imu messages.
constexpr char kSim[] = " --seed 7 --first-hold-s 2 --hold-s 1 --move-s 1 --no-extra-poses";

bool HaveTools() {
  return std::system(
             "command -v python3 >/dev/null && command -v zstd >/dev/null && "
             "command -v lz4 >/dev/null") == 0;
}

std::string Dir() {
  static const std::string dir = [] {
    // One directory per process: ctest runs each test case as its own process, two at a time.
    const fs::path d = fs::path(testing::TempDir()) / ("mcap_test_" + std::to_string(::getpid()));
    fs::remove_all(d);
    fs::create_directories(d);
    return d.string();
  }();
  return dir;
}

// Runs a tests/tools writer; returns `out`.
std::string Write(const std::string& tool, const std::string& out, const std::string& flags) {
  fs::remove_all(out);
  const std::string command = "python3 " + std::string(IMUCAL_TOOLS_DIR) + "/" + tool + " " + out +
                              " " + flags + kSim + " >/dev/null";
  EXPECT_EQ(std::system(command.c_str()), 0) << command;
  return out;
}

// The sqlite3 bag of the same messages, written once.
const core::Capture& Reference() {
  static const core::Capture capture = [] {
    const std::string bag = Write("write_rosbag2.py", Dir() + "/reference_bag", "");
    absl::StatusOr<core::Capture> c = ImportCapture({bag}, ImportOptions{});
    EXPECT_TRUE(c.ok()) << c.status();
    return c.ok() ? *c : core::Capture{};
  }();
  return capture;
}

void ExpectSameCapture(const core::Capture& got, const core::Capture& want) {
  ASSERT_GT(want.size(), 1000u);
  ASSERT_EQ(got.size(), want.size());
  EXPECT_EQ(got.t_s, want.t_s);
  EXPECT_EQ(got.accel, want.accel);
  EXPECT_EQ(got.gyro, want.gyro);
  EXPECT_EQ(got.extra_metadata, want.extra_metadata);
  EXPECT_EQ(got.accel_unit, want.accel_unit);
  EXPECT_EQ(got.gyro_unit, want.gyro_unit);
}

std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

class McapFileTest : public testing::TestWithParam<std::tuple<std::string, bool>> {};

TEST_P(McapFileTest, SameCaptureAsTheSqliteBag) {
  if (!HaveTools()) GTEST_SKIP() << "python3, zstd or lz4 not installed";
  const auto& [compression, summary] = GetParam();
  const std::string name = compression + (summary ? "_summary" : "_scan");
  // Small chunks: dozens of them, each message index and chunk boundary exercised.
  const std::string file = Write(
      "write_mcap.py", Dir() + "/" + name + ".mcap",
      "--compression " + compression + " --chunk-bytes 20000" + (summary ? "" : " --no-summary"));
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({file}, ImportOptions{}, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(report.format, "mcap");
  ExpectSameCapture(*c, Reference());
  const auto scanned = Contains(HasSubstr("no MCAP summary"));
  if (summary) {
    EXPECT_THAT(report.notes, Not(scanned));
  } else {
    EXPECT_THAT(report.notes, scanned);
  }

  absl::StatusOr<std::unique_ptr<McapReader>> reader = McapReader::Open(file);
  ASSERT_TRUE(reader.ok()) << reader.status();
  EXPECT_EQ((*reader)->indexed(), summary);
  absl::StatusOr<std::vector<BagTopic>> topics = (*reader)->Topics();
  ASSERT_TRUE(topics.ok()) << topics.status();
  ASSERT_EQ(topics->size(), 2u);
  EXPECT_EQ((*topics)[0].name, "/imu/data");
  EXPECT_EQ((*topics)[0].type, "sensor_msgs/msg/Imu");
  EXPECT_EQ((*topics)[0].serialization_format, "cdr");
  EXPECT_EQ((*topics)[1].name, "/temperature");
  EXPECT_EQ((*topics)[1].type, "sensor_msgs/msg/Temperature");
}

INSTANTIATE_TEST_SUITE_P(EveryCompression, McapFileTest,
                         testing::Combine(testing::Values("none", "zstd", "lz4"), testing::Bool()),
                         [](const auto& param_info) {
                           return std::get<0>(param_info.param) +
                                  (std::get<1>(param_info.param) ? "_summary" : "_no_summary");
                         });

TEST(McapTest, UnchunkedFile) {
  if (!HaveTools()) GTEST_SKIP() << "python3, zstd or lz4 not installed";
  for (const char* summary : {"", " --no-summary"}) {
    SCOPED_TRACE(summary);
    const std::string file =
        Write("write_mcap.py", Dir() + "/unchunked.mcap", std::string("--no-chunks") + summary);
    absl::StatusOr<core::Capture> c = ImportCapture({file}, ImportOptions{});
    ASSERT_TRUE(c.ok()) << c.status();
    ExpectSameCapture(*c, Reference());
  }
}

TEST(McapTest, BagDirectoryWithTwoImuTopics) {
  if (!HaveTools()) GTEST_SKIP() << "python3, zstd or lz4 not installed";
  for (const char* summary : {"", " --no-summary"}) {
    SCOPED_TRACE(summary);
    const std::string bag =
        Write("write_mcap.py", Dir() + "/decoy_bag",
              std::string("--bag-dir --compression zstd --decoy-imu /imu2/data") + summary);
    ImportReport report;
    absl::StatusOr<core::Capture> ambiguous = ImportCapture({bag}, ImportOptions{}, &report);
    ASSERT_FALSE(ambiguous.ok());
    EXPECT_THAT(ambiguous.status().message(),
                HasSubstr("decoy_bag_0.mcap: 2 sensor_msgs/msg/Imu topics, choose one with "
                          "--topic: /imu/data (sensor_msgs/msg/Imu), /imu2/data "
                          "(sensor_msgs/msg/Imu)"));
    ImportOptions options;
    options.topic = "/imu/data";
    absl::StatusOr<core::Capture> c = ImportCapture({bag}, options, &report);
    ASSERT_TRUE(c.ok()) << c.status();
    EXPECT_EQ(report.format, "rosbag2");
    ExpectSameCapture(*c, Reference());
    options.topic = "/imu2/data";
    absl::StatusOr<core::Capture> decoy = ImportCapture({bag}, options);
    ASSERT_TRUE(decoy.ok()) << decoy.status();
    EXPECT_EQ(decoy->size(), (Reference().size() + 9) / 10);
    options.topic = "/temperature";
    EXPECT_THAT(ImportCapture({bag}, options).status().message(),
                HasSubstr("topic '/temperature' has type sensor_msgs/msg/Temperature"));
    // --format mcap on the directory reads it as well.
    options.topic = "/imu/data";
    options.format = "mcap";
    absl::StatusOr<core::Capture> forced = ImportCapture({bag}, options);
    ASSERT_TRUE(forced.ok()) << forced.status();
    EXPECT_EQ(forced->t_s, c->t_s);
  }
}

// Every cut of a file is an error that names a byte offset; so is a flipped byte inside a
// chunk (its CRC-32, or the decompressor, says so): never a shorter capture.
TEST(McapTest, DamagedFilesAreErrorsNamingTheOffset) {
  if (!HaveTools()) GTEST_SKIP() << "python3, zstd or lz4 not installed";
  for (const std::string compression : {"none", "zstd", "lz4"}) {
    SCOPED_TRACE(compression);
    const std::string file = Write("write_mcap.py", Dir() + "/damaged_" + compression + ".mcap",
                                   "--compression " + compression);
    const std::string bytes = ReadAll(file);
    for (size_t cut : {size_t{0}, size_t{5}, size_t{40}, bytes.size() / 3, bytes.size() / 2,
                       bytes.size() - 30, bytes.size() - 1}) {
      SCOPED_TRACE(cut);
      absl::StatusOr<std::unique_ptr<McapReader>> reader =
          McapReader::FromBytes(std::string_view(bytes.data(), cut), "cut.mcap");
      ASSERT_FALSE(reader.ok());
      EXPECT_THAT(reader.status().message(), HasSubstr("cut.mcap: "));
      if (cut >= 8) {
        EXPECT_THAT(reader.status().message(), HasSubstr("byte "));
      }
    }
    // A byte in the middle of the first chunk's records: the chunk follows the magic (8 bytes)
    // and the header record (opcode, u64 length, content).
    std::string flipped = bytes;
    uint64_t header_length = 0;
    for (int i = 0; i < 8; ++i)
      header_length |= uint64_t{static_cast<unsigned char>(bytes[9 + i])} << (8 * i);
    const size_t chunk = 8 + 9 + header_length;
    ASSERT_EQ(bytes[chunk], '\x06');
    flipped[chunk + 200] ^= 0x5a;
    absl::StatusOr<std::unique_ptr<McapReader>> reader =
        McapReader::FromBytes(flipped, "flipped.mcap");
    ASSERT_TRUE(reader.ok()) << reader.status();
    ImuMessages messages;
    const absl::Status s = (*reader)->ReadTopic("/imu/data", &messages);
    ASSERT_FALSE(s.ok());
    EXPECT_THAT(s.message(), AllOf(HasSubstr("flipped.mcap: byte "), HasSubstr("chunk")));
  }
}

TEST(McapTest, NotAnMcapFile) {
  const std::string path = Dir() + "/text.mcap";
  std::ofstream(path) << "t,ax,ay,az\n";
  ImportOptions options;
  options.format = "mcap";
  EXPECT_THAT(ImportCapture({path}, options).status().message(),
              HasSubstr("text.mcap: not an MCAP file (no MCAP magic at the start)"));
}

// A real recording in MCAP: no public MCAP file with an Imu topic could be fetched here (no
// network), so the real rosbag2 sqlite3 bags of ../shared/data/real/imutk-ros2-repeat (recorded
// by others, SOURCE.txt) are carried over message for message into MCAP by write_mcap.py
// --from-db3, as `ros2 bag convert` would. The real messages' CDR (their frame ids, stamps,
// covariances, alignment) then goes through the MCAP reader and must give the capture the sqlite3
// reader gives, to the bit.
TEST(McapTest, RealRecordingsCarriedOverFromTheirSqliteBags) {
  if (!HaveTools()) GTEST_SKIP() << "python3, zstd or lz4 not installed";
  const std::string real = IMUCAL_SHARED_DIR "/data/real/imutk-ros2-repeat/";
  int compared = 0;
  for (const std::string capture : {"capture1-rosbag2", "capture4-rosbag2"}) {
    std::string db3;
    for (const auto& entry : fs::directory_iterator(real + capture))
      if (entry.path().extension() == ".db3") db3 = entry.path().string();
    ASSERT_FALSE(db3.empty()) << "no .db3 in " << real + capture;
    absl::StatusOr<core::Capture> want = ImportCapture({real + capture}, ImportOptions{});
    ASSERT_TRUE(want.ok()) << want.status();
    for (const std::string compression : {"zstd", "lz4"}) {
      const std::string out = Dir() + "/real_" + capture + "_" + compression;
      fs::remove_all(out);
      const std::string command = "python3 " + std::string(IMUCAL_TOOLS_DIR) +
                                  "/write_mcap.py " + out + " --bag-dir --compression " +
                                  compression + " --from-db3 " + db3 + " >/dev/null";
      ASSERT_EQ(std::system(command.c_str()), 0) << command;
      ImportReport report;
      absl::StatusOr<core::Capture> got = ImportCapture({out}, ImportOptions{}, &report);
      ASSERT_TRUE(got.ok()) << got.status();
      EXPECT_EQ(report.format, "rosbag2");  // a bag directory, whatever its storage
      EXPECT_THAT(report.notes, Not(Contains(HasSubstr("no MCAP summary"))));
      ExpectSameCapture(*got, *want);
      ++compared;
    }
  }
  EXPECT_EQ(compared, 4);
}

}  // namespace
}  // namespace imucal::importers
