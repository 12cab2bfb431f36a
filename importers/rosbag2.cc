#include "importers/rosbag2.h"

#include <sys/stat.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "importers/registry.h"
#include "importers/text_scan.h"
#include "storage/sqlite_db.h"
#include "util/str_util.h"

namespace imucal::importers {
namespace {

// storage/sqlite_db.h: the RAII layer over the SQLite C API.
using storage::Connection;
using storage::ConnectionOptions;
using storage::ScopedStatement;

constexpr std::string_view kImuType = "sensor_msgs/msg/Imu";
constexpr std::string_view kMetadataFile = "metadata.yaml";
constexpr std::string_view kSqliteMagic = std::string_view("SQLite format 3\0", 16);
constexpr size_t kEncapsulationBytes = 4;

// ---------------------------------------------------------------------------------------------
// CDR (XCDR1) reading: bounds-checked, aligned relative to the payload start.

class CdrReader {
 public:
  CdrReader(std::string_view message, bool little_endian)
      : message_(message), little_endian_(little_endian) {}

  // Reads one primitive of sizeof(T) bytes, aligned to its size.
  template <typename T>
  absl::Status Get(std::string_view field, T* out) {
    static_assert(std::is_arithmetic_v<T>);
    if (absl::Status s = Take(sizeof(T), sizeof(T), field); !s.ok()) return s;
    unsigned char bytes[sizeof(T)];
    std::memcpy(bytes, message_.data() + pos_ - sizeof(T), sizeof(T));
    if (little_endian_ != (std::endian::native == std::endian::little)) {
      std::reverse(bytes, bytes + sizeof(T));
    }
    std::memcpy(out, bytes, sizeof(T));
    return absl::OkStatus();
  }

  absl::Status GetFinite(std::string_view field, double* out) {
    if (absl::Status s = Get(field, out); !s.ok()) return s;
    if (!std::isfinite(*out)) {
      return absl::InvalidArgumentError(Cat(field, " is not finite (", *out, ")"));
    }
    return absl::OkStatus();
  }

  // A CDR string: uint32 length including the terminating NUL, then the bytes.
  absl::Status GetString(std::string_view field, std::string* out) {
    uint32_t length = 0;
    if (absl::Status s = Get(Cat(field, ".length"), &length); !s.ok()) return s;
    const size_t left = message_.size() - pos_;
    if (length > left) {
      return absl::InvalidArgumentError(Cat("truncated in ", field, " (length ", length,
                                            " at offset ", pos_ - 4, ", but only ", left,
                                            " bytes follow)"));
    }
    if (length == 0) {  // not what ROS writes, but unambiguous: an empty string
      out->clear();
      return absl::OkStatus();
    }
    if (message_[pos_ + length - 1] != '\0') {
      return absl::InvalidArgumentError(
          Cat(field, " (length ", length, " at offset ", pos_ - 4, ") is not NUL-terminated"));
    }
    out->assign(message_.data() + pos_, length - 1);
    pos_ += length;
    return absl::OkStatus();
  }

  // Skips `count` primitives of `size` bytes (e.g. a covariance array), bounds-checked.
  absl::Status Skip(size_t size, size_t count, std::string_view field) {
    return Take(size * count, size, field);
  }

 private:
  // Aligns to `align` relative to the payload (after the encapsulation header) and consumes
  // `size` bytes.
  absl::Status Take(size_t size, size_t align, std::string_view field) {
    size_t payload_pos = pos_ - kEncapsulationBytes;
    payload_pos = (payload_pos + align - 1) / align * align;
    const size_t at = payload_pos + kEncapsulationBytes;
    if (at > message_.size() || message_.size() - at < size) {
      return absl::InvalidArgumentError(Cat("truncated in ", field, " (needs ", size,
                                            " bytes at offset ", at, ", message has ",
                                            message_.size(), ")"));
    }
    pos_ = at + size;
    return absl::OkStatus();
  }

  std::string_view message_;
  bool little_endian_;
  size_t pos_ = kEncapsulationBytes;
};

absl::Status ReadVector3(CdrReader& reader, std::string_view field, Eigen::Vector3d* out) {
  static constexpr std::string_view kAxes[3] = {".x", ".y", ".z"};
  for (int axis = 0; axis < 3; ++axis) {
    if (absl::Status s = reader.GetFinite(Cat(field, kAxes[axis]), &(*out)[axis]); !s.ok()) {
      return s;
    }
  }
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------------------------
// The bag: files, topics, messages.

struct Topic {
  int64_t id = 0;
  std::string name;
  std::string type;
  std::string serialization_format;
};

bool IsDirectory(const std::string& path) {
  struct stat info;
  return ::stat(path.c_str(), &info) == 0 && S_ISDIR(info.st_mode);
}

// The trailing split index of "bag_12.db3" (12), for ordering; -1 when there is none.
long SplitIndex(std::string_view name) {
  name.remove_suffix(std::min(name.size(), std::string_view(".db3").size()));
  size_t digits = name.size();
  while (digits > 0 && name[digits - 1] >= '0' && name[digits - 1] <= '9') --digits;
  if (digits == name.size() || name.size() - digits > 9) return -1;
  return std::stol(std::string(name.substr(digits)));
}

std::string_view Unquoted(std::string_view s) {
  s = TrimSpaces(s);
  if (s.size() >= 2 && (s.front() == '"' || s.front() == '\'') && s.back() == s.front()) {
    s = s.substr(1, s.size() - 2);
  }
  return s;
}

}  // namespace

BagMetadata ParseBagMetadata(std::string_view yaml) {
  BagMetadata metadata;
  LineCursor lines(yaml);
  std::string_view line;
  bool in_paths = false;
  while (lines.Next(&line)) {
    const std::string_view trimmed = TrimSpaces(line);
    if (trimmed.starts_with("storage_identifier:")) {
      metadata.storage_identifier =
          std::string(Unquoted(trimmed.substr(std::string_view("storage_identifier:").size())));
    }
    if (trimmed == "relative_file_paths:") {
      in_paths = true;
      continue;
    }
    if (in_paths) {
      if (trimmed.starts_with("- ")) {
        metadata.relative_file_paths.emplace_back(Unquoted(trimmed.substr(2)));
      } else if (!trimmed.empty()) {
        in_paths = false;
      }
    }
  }
  return metadata;
}

namespace {

// The .db3 files of the bag at `path`, in split order.
absl::StatusOr<std::vector<std::string>> BagFiles(const std::string& path) {
  if (!IsDirectory(path)) return std::vector<std::string>{path};
  const std::filesystem::path dir(path);
  absl::StatusOr<std::string> yaml = ReadFileBytes((dir / kMetadataFile).string());
  if (!yaml.ok()) {
    return absl::InvalidArgumentError(
        Cat(path, ": not a rosbag2 directory (", yaml.status().message(), ")"));
  }
  const BagMetadata metadata = ParseBagMetadata(*yaml);
  if (!metadata.storage_identifier.empty() && metadata.storage_identifier != "sqlite3") {
    return absl::InvalidArgumentError(Cat(path, ": storage '", metadata.storage_identifier,
                                          "' is not supported (only sqlite3; convert with "
                                          "'ros2 bag convert')"));
  }
  std::vector<std::string> files;
  for (const std::string& relative : metadata.relative_file_paths) {
    files.push_back((dir / relative).string());
  }
  if (files.empty()) {  // an older or hand-made metadata.yaml: every .db3 in the directory
    std::error_code error;
    for (const auto& entry : std::filesystem::directory_iterator(dir, error)) {
      if (entry.path().extension() == ".db3") files.push_back(entry.path().string());
    }
    std::sort(files.begin(), files.end(), [](const std::string& a, const std::string& b) {
      const long ia = SplitIndex(a), ib = SplitIndex(b);
      return ia != ib ? ia < ib : a < b;
    });
  }
  if (files.empty()) return absl::InvalidArgumentError(Cat(path, ": the bag has no .db3 file"));
  return files;
}

absl::StatusOr<std::unique_ptr<Connection>> OpenBagFile(const std::string& file) {
  struct stat info;
  if (::stat(file.c_str(), &info) != 0) {
    return absl::ErrnoToStatus(errno, Cat(file, ": cannot open"));
  }
  ConnectionOptions options;
  options.read_only = true;
  absl::StatusOr<std::unique_ptr<Connection>> connection = Connection::Open(file, options);
  if (!connection.ok()) {
    return absl::Status(connection.status().code(), Cat(file, ": ", connection.status().message()));
  }
  return connection;
}

absl::StatusOr<std::vector<Topic>> ReadTopics(Connection& db, const std::string& file) {
  absl::StatusOr<ScopedStatement> select =
      db.Prepare("SELECT id, name, type, serialization_format FROM topics ORDER BY id");
  if (!select.ok()) {
    return absl::InvalidArgumentError(
        Cat(file, ": not a rosbag2 sqlite3 file (", select.status().message(), ")"));
  }
  std::vector<Topic> topics;
  while (true) {
    absl::StatusOr<bool> row = (*select)->Step();
    if (!row.ok())
      return absl::Status(row.status().code(), Cat(file, ": ", row.status().message()));
    if (!*row) break;
    topics.push_back(Topic{(*select)->ColumnInt64(0), (*select)->ColumnText(1),
                           (*select)->ColumnText(2), (*select)->ColumnText(3)});
  }
  return topics;
}

std::string ListTopics(const std::vector<Topic>& topics) {
  std::vector<std::string> names;
  for (const Topic& t : topics) names.push_back(Cat(t.name, " (", t.type, ")"));
  return names.empty() ? std::string("none") : Join(names, ", ");
}

absl::StatusOr<Topic> ChooseTopic(const std::vector<Topic>& topics, std::string_view wanted,
                                  const std::string& file) {
  if (!wanted.empty()) {
    const auto it = std::find_if(topics.begin(), topics.end(),
                                 [&](const Topic& t) { return t.name == wanted; });
    if (it == topics.end()) {
      return absl::InvalidArgumentError(
          Cat(file, ": no topic '", wanted, "' (topics: ", ListTopics(topics), ")"));
    }
    if (it->type != kImuType) {
      return absl::InvalidArgumentError(
          Cat(file, ": topic '", wanted, "' has type ", it->type, ", not ", kImuType));
    }
    return *it;
  }
  std::vector<Topic> imu;
  for (const Topic& t : topics) {
    if (t.type == kImuType) imu.push_back(t);
  }
  if (imu.size() == 1) return imu[0];
  if (imu.empty()) {
    return absl::InvalidArgumentError(
        Cat(file, ": no ", kImuType, " topic (topics: ", ListTopics(topics), ")"));
  }
  return absl::InvalidArgumentError(Cat(file, ": ", imu.size(), " ", kImuType,
                                        " topics, choose one with --topic: ", ListTopics(imu)));
}

// A metadata value that survives the capture CSV (one line, no surrounding spaces).
bool SafeMetadataValue(std::string_view value) {
  return !value.empty() && value.find_first_of("\r\n") == std::string_view::npos &&
         TrimSpaces(value) == value;
}

struct Sample {
  int64_t stamp_ns;
  int64_t bag_ns;
  Eigen::Vector3d gyro;
  Eigen::Vector3d accel;
};

absl::Status ReadMessages(Connection& db, const std::string& file, const Topic& topic,
                          size_t* index, std::vector<Sample>* samples,
                          std::vector<std::string>* frame_ids) {
  absl::StatusOr<ScopedStatement> select =
      db.Prepare("SELECT timestamp, data FROM messages WHERE topic_id = ?1 ORDER BY timestamp, id");
  if (!select.ok()) {
    return absl::InvalidArgumentError(
        Cat(file, ": not a rosbag2 sqlite3 file (", select.status().message(), ")"));
  }
  (*select)->BindInt64(1, topic.id);
  while (true) {
    absl::StatusOr<bool> row = (*select)->Step();
    if (!row.ok())
      return absl::Status(row.status().code(), Cat(file, ": ", row.status().message()));
    if (!*row) break;
    const int64_t bag_ns = (*select)->ColumnInt64(0);
    absl::StatusOr<ImuMessage> message = DecodeImuCdr((*select)->ColumnBlobView(1));
    if (!message.ok()) {
      return absl::InvalidArgumentError(Cat(file, ": message ", *index, " (t=", bag_ns, " ns) on ",
                                            topic.name, ": ", message.status().message()));
    }
    const int64_t stamp_ns =
        int64_t{message->stamp_sec} * 1'000'000'000 + int64_t{message->stamp_nanosec};
    samples->push_back(
        Sample{stamp_ns, bag_ns, message->angular_velocity, message->linear_acceleration});
    if (frame_ids->empty() || frame_ids->back() != message->frame_id) {
      if (std::find(frame_ids->begin(), frame_ids->end(), message->frame_id) == frame_ids->end()) {
        frame_ids->push_back(message->frame_id);
      }
    }
    ++*index;
  }
  return absl::OkStatus();
}

class Rosbag2ImporterImpl final : public CaptureImporter {
 public:
  std::string_view name() const override { return "rosbag2"; }
  std::string_view description() const override {
    return "ROS 2 bag (sqlite3 storage: directory with metadata.yaml, or a .db3), "
           "sensor_msgs/msg/Imu topic (--topic)";
  }
  absl::Status Sniff(std::span<const std::string> paths,
                     std::span<const std::string> heads) const override {
    if (paths.size() != 1) return absl::InvalidArgumentError("a bag is one path");
    if (IsDirectory(paths[0])) {
      struct stat info;
      const std::string metadata = (std::filesystem::path(paths[0]) / kMetadataFile).string();
      if (::stat(metadata.c_str(), &info) == 0) return absl::OkStatus();
      return absl::InvalidArgumentError("a directory without metadata.yaml");
    }
    if (heads[0].starts_with(kSqliteMagic)) return absl::OkStatus();
    return absl::InvalidArgumentError("neither a bag directory nor an SQLite (.db3) file");
  }
  absl::StatusOr<core::Capture> Import(const std::vector<std::string>& paths,
                                       const ImportOptions& options,
                                       std::vector<std::string>* used_paths,
                                       std::vector<std::string>* notes) const override {
    if (absl::Status s = CheckOnePath("rosbag2", "bag", paths); !s.ok()) return s;
    *used_paths = paths;
    return ReadRosbag2Imu(paths[0], options, notes);
  }
};

}  // namespace

absl::StatusOr<ImuMessage> DecodeImuCdr(std::string_view data) {
  if (data.size() < kEncapsulationBytes) {
    return absl::InvalidArgumentError(Cat("truncated in the CDR encapsulation header (needs ",
                                          kEncapsulationBytes, " bytes at offset 0, message has ",
                                          data.size(), ")"));
  }
  const unsigned char kind_hi = static_cast<unsigned char>(data[0]);
  const unsigned char kind_lo = static_cast<unsigned char>(data[1]);
  if (kind_hi != 0 || kind_lo > 1) {
    constexpr std::string_view kHex = "0123456789abcdef";
    const std::string kind = {kHex[kind_hi >> 4], kHex[kind_hi & 15], kHex[kind_lo >> 4],
                              kHex[kind_lo & 15]};
    return absl::InvalidArgumentError(
        Cat("unsupported CDR encapsulation 0x", kind,
            " (expected plain CDR: 0x0000 big-endian or 0x0001 little-endian)"));
  }
  CdrReader reader(data, /*little_endian=*/kind_lo == 1);
  ImuMessage message;
  if (absl::Status s = reader.Get("header.stamp.sec", &message.stamp_sec); !s.ok()) return s;
  if (absl::Status s = reader.Get("header.stamp.nanosec", &message.stamp_nanosec); !s.ok()) {
    return s;
  }
  if (message.stamp_nanosec >= 1'000'000'000u) {
    return absl::InvalidArgumentError(
        Cat("header.stamp.nanosec ", message.stamp_nanosec, " is not below 1e9"));
  }
  if (absl::Status s = reader.GetString("header.frame_id", &message.frame_id); !s.ok()) return s;
  if (absl::Status s = reader.Skip(8, 4, "orientation"); !s.ok()) return s;
  if (absl::Status s = reader.Skip(8, 9, "orientation_covariance"); !s.ok()) return s;
  if (absl::Status s = ReadVector3(reader, "angular_velocity", &message.angular_velocity);
      !s.ok()) {
    return s;
  }
  if (absl::Status s = reader.Skip(8, 9, "angular_velocity_covariance"); !s.ok()) return s;
  if (absl::Status s = ReadVector3(reader, "linear_acceleration", &message.linear_acceleration);
      !s.ok()) {
    return s;
  }
  if (absl::Status s = reader.Skip(8, 9, "linear_acceleration_covariance"); !s.ok()) return s;
  return message;
}

absl::StatusOr<core::Capture> ReadRosbag2Imu(const std::string& path, const ImportOptions& options,
                                             std::vector<std::string>* notes) {
  absl::StatusOr<std::vector<std::string>> files = BagFiles(path);
  if (!files.ok()) return files.status();

  std::optional<Topic> topic;
  std::vector<Sample> samples;
  std::vector<std::string> frame_ids;
  size_t index = 0;
  for (const std::string& file : *files) {
    absl::StatusOr<std::unique_ptr<Connection>> db = OpenBagFile(file);
    if (!db.ok()) return db.status();
    absl::StatusOr<std::vector<Topic>> topics = ReadTopics(**db, file);
    if (!topics.ok()) return topics.status();
    // Split files repeat the topics table; the topic is chosen by name, so its id may differ.
    absl::StatusOr<Topic> chosen = ChooseTopic(*topics, topic ? topic->name : options.topic, file);
    if (!chosen.ok()) return chosen.status();
    if (chosen->serialization_format != "cdr") {
      return absl::InvalidArgumentError(Cat(file, ": topic ", chosen->name, " is serialised as '",
                                            chosen->serialization_format, "', not cdr"));
    }
    topic = *chosen;
    if (absl::Status s = ReadMessages(**db, file, *topic, &index, &samples, &frame_ids); !s.ok()) {
      return s;
    }
  }
  if (samples.empty()) {
    return absl::InvalidArgumentError(Cat(path, ": topic ", topic->name, " has no messages"));
  }

  const bool stamped =
      std::any_of(samples.begin(), samples.end(), [](const Sample& s) { return s.stamp_ns != 0; });
  auto time_of = [&](const Sample& s) { return stamped ? s.stamp_ns : s.bag_ns; };
  const std::string_view clock = stamped ? "header.stamp" : "bag timestamp";
  core::Capture capture;
  capture.accel_unit = core::AccelUnit::kMetersPerSecond2;
  capture.gyro_unit = core::GyroUnit::kRadPerSecond;
  capture.t_s.reserve(samples.size());
  capture.accel.reserve(samples.size());
  capture.gyro.reserve(samples.size());
  const int64_t t0_ns = time_of(samples[0]);
  for (size_t i = 0; i < samples.size(); ++i) {
    const int64_t ns = time_of(samples[i]);
    if (i > 0 && ns <= time_of(samples[i - 1])) {
      return absl::InvalidArgumentError(Cat(path, ": message ", i, " (t=", samples[i].bag_ns,
                                            " ns) on ", topic->name, ": ", clock, " ", ns,
                                            " ns does not increase (message ", i - 1, ": ",
                                            time_of(samples[i - 1]), " ns)"));
    }
    // Integer difference first: a 1.7e18 ns origin would cost double precision.
    capture.line.push_back(static_cast<uint32_t>(i + 1));  // the message's ordinal on the topic
    capture.t_s.push_back(static_cast<double>(ns - t0_ns) / 1e9);
    capture.gyro.push_back(samples[i].gyro);
    capture.accel.push_back(samples[i].accel);
  }
  capture.extra_metadata.emplace_back("t0_ns", Cat(t0_ns));
  if (SafeMetadataValue(topic->name)) capture.extra_metadata.emplace_back("ros_topic", topic->name);
  if (frame_ids.size() == 1 && SafeMetadataValue(frame_ids[0])) {
    capture.extra_metadata.emplace_back("frame_id", frame_ids[0]);
  }
  notes->push_back(Cat("topic ", topic->name, ": ", samples.size(), " messages from ",
                       files->size(), " file", files->size() == 1 ? "" : "s", "; time = ", clock,
                       " from ", t0_ns, " ns (kept as t0_ns)"));
  if (!stamped) notes->push_back("every header.stamp is zero: used the bag's receive time");
  if (frame_ids.size() > 1) {
    notes->push_back(
        Cat("the messages name ", frame_ids.size(), " frames: ", Join(frame_ids, ", ")));
  }
  ApplyImportOverrides(options, &capture, notes);
  NoteTimeGaps(capture, notes);
  return capture;
}

const CaptureImporter* Rosbag2Importer() {
  static const auto* const kImporter = new Rosbag2ImporterImpl();
  return kImporter;
}

}  // namespace imucal::importers
