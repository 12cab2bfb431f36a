// Tests of the ROS 2 bag importer (importers/rosbag2.cc) on bags written here with the raw
// SQLite C API and a CDR serialiser of their own, independent of the decoder under test.
#include "importers/rosbag2.h"

#include <sqlite3.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <vector>

#include "absl/strings/escaping.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "importers/registry.h"
#include "util/str_util.h"

namespace imucal::importers {
namespace {

using ::testing::AllOf;
using ::testing::Contains;
using ::testing::HasSubstr;
using ::testing::Pair;

constexpr char kImu[] = "sensor_msgs/msg/Imu";

// ---------------------------------------------------------------------------------------------
// An independent CDR writer: XCDR1, primitives aligned to their size counted from the first
// byte after the 4-byte encapsulation header.

class CdrWriter {
 public:
  explicit CdrWriter(bool little_endian) : little_(little_endian) {
    bytes_ = {0x00, static_cast<char>(little_endian ? 0x01 : 0x00), 0x00, 0x00};
  }
  void Align(size_t n) {
    while ((bytes_.size() - 4) % n != 0) bytes_.push_back('\0');
  }
  template <typename T>
  void Put(T value) {
    Align(sizeof(T));
    char raw[sizeof(T)];
    std::memcpy(raw, &value, sizeof(T));
    for (size_t i = 0; i < sizeof(T); ++i) {
      bytes_.push_back(little_ ? raw[i] : raw[sizeof(T) - 1 - i]);  // the test host is LE
    }
  }
  void PutString(std::string_view s) {
    Put(static_cast<uint32_t>(s.size() + 1));
    bytes_.append(s);
    bytes_.push_back('\0');
  }
  const std::string& bytes() const { return bytes_; }

 private:
  bool little_;
  std::string bytes_;
};

struct TestImu {
  int32_t sec = 0;
  uint32_t nanosec = 0;
  std::string frame_id = "imu_link";
  double w[3] = {0, 0, 0};
  double a[3] = {0, 0, 9.81};
};

std::string SerializeImu(const TestImu& m, bool little_endian = true) {
  CdrWriter w(little_endian);
  w.Put(m.sec);
  w.Put(m.nanosec);
  w.PutString(m.frame_id);
  for (double q : {0.0, 0.0, 0.0, 1.0}) w.Put(q);  // orientation
  for (int i = 0; i < 9; ++i) w.Put(-1.0);         // orientation_covariance
  for (double v : m.w) w.Put(v);                   // angular_velocity
  for (int i = 0; i < 9; ++i) w.Put(0.01);         // angular_velocity_covariance
  for (double v : m.a) w.Put(v);                   // linear_acceleration
  for (int i = 0; i < 9; ++i) w.Put(0.02);         // linear_acceleration_covariance
  return w.bytes();
}

// ---------------------------------------------------------------------------------------------
// An independent bag writer: rosbag2's sqlite3 schema and metadata.yaml.

struct TestTopic {
  int id;
  std::string name;
  std::string type;
  std::string format = "cdr";
};

struct TestMessage {
  int topic_id;
  int64_t timestamp;
  std::string data;
};

void Exec(sqlite3* db, const char* sql) {
  char* error = nullptr;
  ASSERT_EQ(sqlite3_exec(db, sql, nullptr, nullptr, &error), SQLITE_OK) << error;
}

void WriteDb3(const std::string& path, const std::vector<TestTopic>& topics,
              const std::vector<TestMessage>& messages) {
  std::filesystem::remove(path);
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  Exec(db,
       "CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);"
       "INSERT INTO schema VALUES (3, 'humble');"
       "CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL, "
       "metadata TEXT NOT NULL);"
       "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, "
       "serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);"
       "CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, "
       "timestamp INTEGER NOT NULL, data BLOB NOT NULL);"
       "CREATE INDEX timestamp_idx ON messages (timestamp ASC);"
       "BEGIN;");
  sqlite3_stmt* stmt = nullptr;
  ASSERT_EQ(
      sqlite3_prepare_v2(db, "INSERT INTO topics VALUES (?, ?, ?, ?, '')", -1, &stmt, nullptr),
      SQLITE_OK);
  for (const TestTopic& t : topics) {
    sqlite3_bind_int(stmt, 1, t.id);
    sqlite3_bind_text(stmt, 2, t.name.c_str(), -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(stmt, 3, t.type.c_str(), -1, SQLITE_TRANSIENT);
    sqlite3_bind_text(stmt, 4, t.format.c_str(), -1, SQLITE_TRANSIENT);
    ASSERT_EQ(sqlite3_step(stmt), SQLITE_DONE);
    sqlite3_reset(stmt);
  }
  sqlite3_finalize(stmt);
  ASSERT_EQ(sqlite3_prepare_v2(db,
                               "INSERT INTO messages (topic_id, timestamp, data) "
                               "VALUES (?, ?, ?)",
                               -1, &stmt, nullptr),
            SQLITE_OK);
  for (const TestMessage& m : messages) {
    sqlite3_bind_int(stmt, 1, m.topic_id);
    sqlite3_bind_int64(stmt, 2, m.timestamp);
    sqlite3_bind_blob(stmt, 3, m.data.data(), static_cast<int>(m.data.size()), SQLITE_TRANSIENT);
    ASSERT_EQ(sqlite3_step(stmt), SQLITE_DONE);
    sqlite3_reset(stmt);
  }
  sqlite3_finalize(stmt);
  Exec(db, "COMMIT;");
  ASSERT_EQ(sqlite3_close(db), SQLITE_OK);
}

// A bag directory `name` with metadata.yaml listing `files` (written by the caller).
std::string BagDir(const std::string& name) {
  const std::filesystem::path dir = std::filesystem::path(testing::TempDir()) / name;
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir.string();
}

void WriteMetadata(const std::string& dir, const std::vector<std::string>& files,
                   const std::string& storage = "sqlite3") {
  std::ofstream out(std::filesystem::path(dir) / "metadata.yaml");
  out << "rosbag2_bagfile_information:\n"
      << "  version: 5\n"
      << "  storage_identifier: " << storage << "\n"
      << "  relative_file_paths:\n";
  for (const std::string& f : files) out << "    - " << f << "\n";
  out << "  duration:\n    nanoseconds: 0\n";
  ASSERT_TRUE(out.good());
}

// One-file bag with a single Imu topic "/imu" (id 1) and the given messages.
std::string WriteSimpleBag(const std::string& name, const std::vector<TestImu>& imus,
                           int64_t first_bag_ns = 1'700'000'000'000'000'000) {
  const std::string dir = BagDir(name);
  std::vector<TestMessage> messages;
  for (size_t i = 0; i < imus.size(); ++i) {
    messages.push_back(
        {1, first_bag_ns + static_cast<int64_t>(i) * 5'000'000, SerializeImu(imus[i])});
  }
  WriteDb3(dir + "/" + name + "_0.db3", {{1, "/imu", kImu}}, messages);
  WriteMetadata(dir, {name + "_0.db3"});
  return dir;
}

TestImu Imu(int32_t sec, uint32_t nanosec, double k, std::string frame = "imu_link") {
  TestImu m;
  m.sec = sec;
  m.nanosec = nanosec;
  m.frame_id = std::move(frame);
  m.w[0] = 0.001 * k, m.w[1] = -0.002 * k, m.w[2] = 0.25 + k;
  m.a[0] = 0.1 + k, m.a[1] = -0.2, m.a[2] = 9.80665 - 1e-3 * k;
  return m;
}

// ---------------------------------------------------------------------------------------------
// CDR decoding.

TEST(ImuCdrTest, WriterLayoutMatchesTheHandComputedOffsets) {
  // frame_id "imu" (length 4 with NUL): stamp 8 + length 4 + 4 bytes = payload offset 16, a
  // multiple of 8: orientation at 16, orientation_covariance at 48, angular_velocity at 120;
  // +4 for the encapsulation header.
  const std::string bytes = SerializeImu(Imu(1, 2, 0.5, "imu"));
  ASSERT_EQ(bytes.size(), 4u + 16 + 32 + 72 + 24 + 72 + 24 + 72);
  double w_x = 0;
  std::memcpy(&w_x, bytes.data() + 4 + 120, 8);
  EXPECT_EQ(w_x, 0.0005);
  // frame_id "ab" (length 3): 8 + 4 + 3 = 15, padded to 16 by one zero byte.
  const std::string padded = SerializeImu(Imu(1, 2, 0.5, "ab"));
  EXPECT_EQ(padded.size(), bytes.size());
  EXPECT_EQ(padded[4 + 15], '\0');
}

TEST(ImuCdrTest, DecodesEveryFrameIdLengthInBothByteOrders) {
  for (bool little : {true, false}) {
    for (size_t length = 0; length <= 17; ++length) {
      SCOPED_TRACE(testing::Message() << "little=" << little << " frame_id length " << length);
      TestImu m = Imu(1'700'000'000, 999'999'999, 0.25 * static_cast<double>(length),
                      std::string(length, 'f'));
      absl::StatusOr<ImuMessage> decoded = DecodeImuCdr(SerializeImu(m, little));
      ASSERT_TRUE(decoded.ok()) << decoded.status();
      EXPECT_EQ(decoded->stamp_sec, m.sec);
      EXPECT_EQ(decoded->stamp_nanosec, m.nanosec);
      EXPECT_EQ(decoded->frame_id, m.frame_id);
      EXPECT_EQ(decoded->angular_velocity, Eigen::Vector3d(m.w[0], m.w[1], m.w[2]));
      EXPECT_EQ(decoded->linear_acceleration, Eigen::Vector3d(m.a[0], m.a[1], m.a[2]));
    }
  }
}

TEST(ImuCdrTest, EveryTruncationIsAnErrorNamingAField) {
  for (size_t length : {0u, 3u, 8u}) {
    const std::string full = SerializeImu(Imu(3, 4, 1.0, std::string(length, 'x')));
    for (size_t cut = 0; cut < full.size(); ++cut) {
      absl::StatusOr<ImuMessage> decoded = DecodeImuCdr(std::string_view(full.data(), cut));
      ASSERT_FALSE(decoded.ok()) << "cut at " << cut;
      EXPECT_THAT(decoded.status().message(), HasSubstr("truncated in ")) << "cut at " << cut;
    }
  }
  const std::string full = SerializeImu(Imu(3, 4, 1.0, "imu"));
  // Cut inside angular_velocity.y: payload 120 + 8 = offset 132 of the message.
  EXPECT_EQ(DecodeImuCdr(std::string_view(full.data(), 135)).status().message(),
            "truncated in angular_velocity.y (needs 8 bytes at offset 132, message has 135)");
}

TEST(ImuCdrTest, MalformedFields) {
  std::string bad_length = SerializeImu(Imu(0, 0, 1.0, "imu"));
  const uint32_t huge = 1'000'000;
  std::memcpy(bad_length.data() + 4 + 8, &huge, 4);
  EXPECT_THAT(DecodeImuCdr(bad_length).status().message(),
              HasSubstr("truncated in header.frame_id (length 1000000 at offset 12"));

  std::string no_nul = SerializeImu(Imu(0, 0, 1.0, "imu"));
  no_nul[4 + 12 + 3] = 'X';
  EXPECT_THAT(DecodeImuCdr(no_nul).status().message(),
              HasSubstr("header.frame_id (length 4 at offset 12) is not NUL-terminated"));

  std::string xcdr2 = SerializeImu(Imu(0, 0, 1.0));
  xcdr2[1] = 0x07;
  EXPECT_THAT(DecodeImuCdr(xcdr2).status().message(),
              HasSubstr("unsupported CDR encapsulation 0x0007"));

  TestImu nan_message = Imu(0, 0, 1.0);
  nan_message.a[2] = std::nan("");
  EXPECT_THAT(DecodeImuCdr(SerializeImu(nan_message)).status().message(),
              HasSubstr("linear_acceleration.z is not finite"));

  TestImu bad_nanosec = Imu(0, 1'000'000'000, 1.0);
  EXPECT_THAT(DecodeImuCdr(SerializeImu(bad_nanosec)).status().message(),
              HasSubstr("header.stamp.nanosec 1000000000 is not below 1e9"));
}

// ---------------------------------------------------------------------------------------------
// metadata.yaml (yaml-cpp).

TEST(BagMetadataTest, ReadsRosbag2Layouts) {
  absl::StatusOr<BagMetadata> m = ParseBagMetadata(
      "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n"
      "  relative_file_paths:\n    - \"bag_0.mcap\"\n    - 'bag_1.mcap'\n"
      "  files:\n    - path: bag_0.mcap\n  custom_data: ~\n");
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->storage_identifier, "mcap");
  EXPECT_EQ(m->relative_file_paths, (std::vector<std::string>{"bag_0.mcap", "bag_1.mcap"}));
  // Flow style and CRLF line ends are YAML too.
  m = ParseBagMetadata(
      "rosbag2_bagfile_information: {storage_identifier: sqlite3,\r\n"
      "  relative_file_paths: [a.db3, b.db3]}\r\n");
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->relative_file_paths, (std::vector<std::string>{"a.db3", "b.db3"}));
}

TEST(BagMetadataTest, ErrorsNameTheFileAndLine) {
  EXPECT_EQ(ParseBagMetadata("a: [1,\n", "bag/metadata.yaml").status().message().substr(0, 20),
            "bag/metadata.yaml:2:");
  EXPECT_THAT(ParseBagMetadata("- 1\n- 2\n").status().message(),
              HasSubstr("metadata.yaml:1: not a rosbag2 metadata file (not a YAML mapping)"));
  EXPECT_THAT(ParseBagMetadata("version: 5\n").status().message(),
              HasSubstr("no rosbag2_bagfile_information mapping"));
  EXPECT_THAT(ParseBagMetadata("rosbag2_bagfile_information:\n  storage_identifier: [a]\n")
                  .status()
                  .message(),
              HasSubstr("metadata.yaml:2: storage_identifier is not a one-line name"));
  EXPECT_THAT(ParseBagMetadata("rosbag2_bagfile_information:\n  relative_file_paths:\n"
                               "    - {path: a}\n")
                  .status()
                  .message(),
              HasSubstr("metadata.yaml:3: a relative_file_paths entry is not a file name"));
  // A line break or a control character in a quoted scalar is YAML, but no file name.
  EXPECT_THAT(ParseBagMetadata("rosbag2_bagfile_information:\n  relative_file_paths:\n"
                               "    - \"bag_0\\n.db3\"\n")
                  .status()
                  .message(),
              HasSubstr("metadata.yaml:3: a relative_file_paths entry is not a file name"));
}

// A name is printable UTF-8 on one line, so the capture CSV and a YAML rewrite carry it unchanged
// (the fuzzer found a storage_identifier with a vertical tab and stray bytes that did not).
TEST(BagMetadataTest, NamesAreOneLineOfPrintableUtf8) {
  const auto storage = [](std::string_view value) {
    return ParseBagMetadata(
        Cat("rosbag2_bagfile_information:\n  storage_identifier: ", value, "\n"));
  };
  for (const std::string_view bad :
       {"sqlite3\v", "sql\xD7\xDBite3", "\"sq\\x7Flite3\"", "\"sq\\u0085lite3\"",
        "sq\xE2\x80\xA8lite3", "\xC0\xAFsqlite3", "\xED\xA0\x80", "sqlite3\xF0\x9F"}) {
    EXPECT_THAT(storage(bad).status().message(),
                HasSubstr("metadata.yaml:2: storage_identifier is not a one-line name"))
        << absl::CEscape(std::string(bad));
  }
  // Printable UTF-8 beyond ASCII is a name.
  const absl::StatusOr<BagMetadata> m = storage("m\xC3\xA9tadonn\xC3\xA9\x65s_\xF0\x9F\x9A\x80");
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->storage_identifier, "m\xC3\xA9tadonn\xC3\xA9\x65s_\xF0\x9F\x9A\x80");
  EXPECT_THAT(ParseBagMetadata("rosbag2_bagfile_information:\n  relative_file_paths:\n"
                               "    - \"a\\tb.db3\"\n")
                  .status()
                  .message(),
              HasSubstr("metadata.yaml:3: a relative_file_paths entry is not a file name"));
}

// ---------------------------------------------------------------------------------------------
// Bags.

TEST(Rosbag2ImportTest, AutoDetectedDirectoryWithHeaderStamps) {
  std::vector<TestImu> imus;
  for (int i = 0; i < 50; ++i) {
    // 200 Hz sensor time across a second boundary; the frame_id length varies the alignment.
    const int64_t ns = 999'000'000 + int64_t{i} * 5'000'000;
    imus.push_back(Imu(100 + static_cast<int32_t>(ns / 1'000'000'000),
                       static_cast<uint32_t>(ns % 1'000'000'000), i, "imu_link"));
  }
  const std::string dir = WriteSimpleBag("simple_bag", imus);
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({dir}, ImportOptions{}, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(report.format, "rosbag2");
  ASSERT_EQ(c->size(), 50u);
  EXPECT_EQ(c->accel_unit, core::AccelUnit::kMetersPerSecond2);
  EXPECT_EQ(c->gyro_unit, core::GyroUnit::kRadPerSecond);
  for (size_t i = 0; i < c->size(); ++i) {
    ASSERT_EQ(c->t_s[i], static_cast<double>(i) * 5'000'000 / 1e9) << i;
    ASSERT_EQ(c->gyro[i], Eigen::Vector3d(imus[i].w[0], imus[i].w[1], imus[i].w[2])) << i;
    ASSERT_EQ(c->accel[i], Eigen::Vector3d(imus[i].a[0], imus[i].a[1], imus[i].a[2])) << i;
  }
  EXPECT_THAT(c->extra_metadata, Contains(Pair("t0_ns", "100999000000")));
  EXPECT_THAT(c->extra_metadata, Contains(Pair("ros_topic", "/imu")));
  EXPECT_THAT(c->extra_metadata, Contains(Pair("frame_id", "imu_link")));
  EXPECT_THAT(report.notes, Contains(HasSubstr("topic /imu: 50 messages from 1 file")));

  // The .db3 on its own is a bag too.
  absl::StatusOr<core::Capture> db3 = ImportCapture({dir + "/simple_bag_0.db3"}, ImportOptions{});
  ASSERT_TRUE(db3.ok()) << db3.status();
  EXPECT_EQ(db3->accel, c->accel);
}

TEST(Rosbag2ImportTest, ZeroStampsFallBackToBagTime) {
  const std::string dir = WriteSimpleBag("unstamped", {Imu(0, 0, 1), Imu(0, 0, 2), Imu(0, 0, 3)});
  ImportOptions options;
  options.format = "rosbag2";
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({dir}, options, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->t_s, (std::vector<double>{0.0, 0.005, 0.01}));
  EXPECT_THAT(report.notes, Contains(HasSubstr("every header.stamp is zero")));
}

TEST(Rosbag2ImportTest, TopicChoice) {
  const std::string dir = BagDir("two_imus");
  WriteDb3(dir + "/two_imus_0.db3",
           {{1, "/imu/data", kImu}, {2, "/tf", "tf2_msgs/msg/TFMessage"}, {3, "/imu2", kImu}},
           {{1, 10, SerializeImu(Imu(1, 0, 1))},
            {3, 11, SerializeImu(Imu(1, 1, 7))},
            {1, 20, SerializeImu(Imu(1, 5'000'000, 2))},
            {2, 21, "not cdr"}});
  WriteMetadata(dir, {"two_imus_0.db3"});
  ImportOptions options;
  absl::StatusOr<core::Capture> ambiguous = ImportCapture({dir}, options);
  ASSERT_FALSE(ambiguous.ok());
  EXPECT_THAT(ambiguous.status().message(),
              HasSubstr("2 sensor_msgs/msg/Imu topics, choose one with --topic: /imu/data "
                        "(sensor_msgs/msg/Imu), /imu2 (sensor_msgs/msg/Imu)"));
  options.topic = "/imu/data";
  absl::StatusOr<core::Capture> chosen = ImportCapture({dir}, options);
  ASSERT_TRUE(chosen.ok()) << chosen.status();
  ASSERT_EQ(chosen->size(), 2u);
  EXPECT_EQ(chosen->gyro[1].z(), 2.25);
  options.topic = "/tf";
  EXPECT_THAT(ImportCapture({dir}, options).status().message(),
              HasSubstr("topic '/tf' has type tf2_msgs/msg/TFMessage, not sensor_msgs/msg/Imu"));
  options.topic = "/camera";
  EXPECT_THAT(ImportCapture({dir}, options).status().message(),
              HasSubstr("no topic '/camera' (topics: /imu/data (sensor_msgs/msg/Imu), /tf "));
}

TEST(Rosbag2ImportTest, NoImuTopic) {
  const std::string dir = BagDir("no_imu");
  WriteDb3(dir + "/no_imu_0.db3", {{1, "/tf", "tf2_msgs/msg/TFMessage"}}, {});
  WriteMetadata(dir, {"no_imu_0.db3"});
  absl::StatusOr<core::Capture> c = ImportCapture({dir}, ImportOptions{});
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(c.status().message(),
              HasSubstr("no sensor_msgs/msg/Imu topic (topics: /tf (tf2_msgs/msg/TFMessage))"));
}

TEST(Rosbag2ImportTest, SplitBagReadsTheFilesInOrder) {
  const std::string dir = BagDir("split");
  WriteDb3(dir + "/split_1.db3", {{4, "/imu", kImu}},
           {{4, 30, SerializeImu(Imu(2, 0, 3))}, {4, 40, SerializeImu(Imu(3, 0, 4))}});
  WriteDb3(dir + "/split_0.db3", {{1, "/imu", kImu}},
           {{1, 10, SerializeImu(Imu(0, 0, 1))}, {1, 20, SerializeImu(Imu(1, 0, 2))}});
  WriteMetadata(dir, {"split_0.db3", "split_1.db3"});
  ImportReport report;
  absl::StatusOr<core::Capture> c = ImportCapture({dir}, ImportOptions{}, &report);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->t_s, (std::vector<double>{0, 1, 2, 3}));
  EXPECT_EQ(c->gyro[3].z(), 4.25);
  EXPECT_THAT(report.notes, Contains(HasSubstr("4 messages from 2 files")));
}

TEST(Rosbag2ImportTest, BadMessagesNameTheirIndexAndTime) {
  const std::string dir = BagDir("truncated");
  std::vector<TestMessage> messages;
  for (int i = 0; i < 5; ++i) messages.push_back({1, 1000 + i, SerializeImu(Imu(1, i, i))});
  messages[3].data.resize(100);
  WriteDb3(dir + "/truncated_0.db3", {{1, "/imu", kImu}}, messages);
  WriteMetadata(dir, {"truncated_0.db3"});
  absl::StatusOr<core::Capture> c = ImportCapture({dir}, ImportOptions{});
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(c.status().message(),
              AllOf(HasSubstr("truncated_0.db3: message 3 (t=1003 ns) on /imu: truncated in "
                              "orientation_covariance")));

  const std::string back = WriteSimpleBag("backwards", {Imu(5, 0, 1), Imu(6, 0, 2), Imu(5, 0, 3)});
  absl::StatusOr<core::Capture> b = ImportCapture({back}, ImportOptions{});
  ASSERT_FALSE(b.ok());
  EXPECT_THAT(b.status().message(),
              HasSubstr("message 2 (t=1700000000010000000 ns) on /imu: header.stamp "
                        "5000000000 ns does not increase (message 1: 6000000000 ns)"));
}

TEST(Rosbag2ImportTest, NotABagOrUnsupportedStorage) {
  const std::string hdf5 = BagDir("hdf5_bag");
  WriteMetadata(hdf5, {"hdf5_bag_0.h5"}, "hdf5");
  absl::StatusOr<core::Capture> c = ImportCapture({hdf5}, ImportOptions{});
  ASSERT_FALSE(c.ok());
  EXPECT_THAT(c.status().message(),
              HasSubstr("storage 'hdf5' is not supported (sqlite3 and mcap are"));

  const std::string bad_yaml = BagDir("bad_yaml");
  {
    std::ofstream out(std::filesystem::path(bad_yaml) / "metadata.yaml");
    out << "rosbag2_bagfile_information:\n  version: 5\n  relative_file_paths: [a.db3\n";
  }
  absl::StatusOr<core::Capture> y = ImportCapture({bad_yaml}, ImportOptions{});
  ASSERT_FALSE(y.ok());
  EXPECT_THAT(y.status().message(), HasSubstr("bad_yaml/metadata.yaml:"));

  const std::string empty_dir = BagDir("not_a_bag");
  absl::StatusOr<core::Capture> d = ImportCapture({empty_dir}, ImportOptions{});
  ASSERT_FALSE(d.ok());
  EXPECT_THAT(d.status().message(), AllOf(HasSubstr("unrecognised capture format"),
                                          HasSubstr("rosbag2: a directory without metadata.yaml")));

  const std::string wrong_db = BagDir("wrong_db") + "/other.db3";
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(wrong_db.c_str(), &db), SQLITE_OK);
  Exec(db, "CREATE TABLE t(x INTEGER);");
  sqlite3_close(db);
  absl::StatusOr<core::Capture> w = ImportCapture({wrong_db}, ImportOptions{});
  ASSERT_FALSE(w.ok());
  EXPECT_THAT(w.status().message(), HasSubstr("other.db3: not a rosbag2 sqlite3 file"));
}

}  // namespace
}  // namespace imucal::importers
