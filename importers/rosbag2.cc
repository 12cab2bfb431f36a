#include "importers/rosbag2.h"

#include <sys/stat.h>

#include <algorithm>
#include <cstdint>
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
#include "importers/mcap.h"
#include "importers/registry.h"
#include "importers/ros_imu.h"
#include "importers/text_scan.h"
#include "util/sqlite_db.h"
#include "util/str_util.h"

namespace imucal::importers {
namespace {

// util/sqlite_db.h: the RAII layer over the SQLite C API.
using sql::Connection;
using sql::ConnectionOptions;
using sql::ScopedStatement;
using sql::SqliteConnection;

constexpr std::string_view kMetadataFile = "metadata.yaml";
constexpr std::string_view kSqliteMagic = std::string_view("SQLite format 3\0", 16);

// ---------------------------------------------------------------------------------------------
// The bag: files, topics, messages.

// A topic of a .db3: its row id and what it is.
struct Topic {
  int64_t id = 0;
  BagTopic topic;
};

bool IsDirectory(const std::string& path) {
  struct stat info;
  return ::stat(path.c_str(), &info) == 0 && S_ISDIR(info.st_mode);
}

// The trailing split index of "bag_12.db3" (12), for ordering; -1 when there is none.
long SplitIndex(std::string_view name) {
  name.remove_suffix(
      std::min(name.size(), std::filesystem::path(name).extension().string().size()));
  size_t digits = name.size();
  while (digits > 0 && name[digits - 1] >= '0' && name[digits - 1] <= '9') --digits;
  if (digits == name.size() || name.size() - digits > 9) return -1;
  return std::stol(std::string(name.substr(digits)));
}

// The files of a bag and their storage.
struct BagFileList {
  std::string storage;  // "sqlite3" or "mcap"
  std::vector<std::string> files;
};

// The files of the bag at `path`, in split order.
absl::StatusOr<BagFileList> BagFiles(const std::string& path) {
  if (!IsDirectory(path)) {
    absl::StatusOr<std::string> head = ReadFileBytes(path, kMcapMagic.size());
    if (!head.ok()) return head.status();
    return BagFileList{head->starts_with(kMcapMagic) ? "mcap" : "sqlite3", {path}};
  }
  const std::filesystem::path dir(path);
  const std::string metadata_path = (dir / kMetadataFile).string();
  absl::StatusOr<std::string> yaml = ReadFileBytes(metadata_path);
  if (!yaml.ok()) {
    return absl::InvalidArgumentError(
        Cat(path, ": not a rosbag2 directory (", yaml.status().message(), ")"));
  }
  absl::StatusOr<BagMetadata> metadata = ParseBagMetadata(*yaml, metadata_path);
  if (!metadata.ok()) return metadata.status();
  BagFileList list;
  list.storage = metadata->storage_identifier.empty() ? "sqlite3" : metadata->storage_identifier;
  if (list.storage != "sqlite3" && list.storage != "mcap") {
    return absl::InvalidArgumentError(Cat(path, ": storage '", list.storage,
                                          "' is not supported (sqlite3 and mcap are; convert "
                                          "with 'ros2 bag convert')"));
  }
  for (const std::string& relative : metadata->relative_file_paths) {
    list.files.push_back((dir / relative).string());
  }
  const std::string extension = list.storage == "mcap" ? ".mcap" : ".db3";
  if (list.files.empty()) {  // an older or hand-made metadata.yaml: every file of the storage
    std::error_code error;
    for (const auto& entry : std::filesystem::directory_iterator(dir, error)) {
      if (entry.path().extension() == extension) list.files.push_back(entry.path().string());
    }
    std::sort(list.files.begin(), list.files.end(), [](const std::string& a, const std::string& b) {
      const long ia = SplitIndex(a), ib = SplitIndex(b);
      return ia != ib ? ia < ib : a < b;
    });
  }
  if (list.files.empty()) {
    return absl::InvalidArgumentError(Cat(path, ": the bag has no ", extension, " file"));
  }
  return list;
}

absl::StatusOr<std::unique_ptr<sql::SqliteConnection>> OpenBagFile(const std::string& file) {
  struct stat info;
  if (::stat(file.c_str(), &info) != 0) {
    return absl::ErrnoToStatus(errno, Cat(file, ": cannot open"));
  }
  sql::ConnectionOptions options;
  options.read_only = true;
  absl::StatusOr<std::unique_ptr<sql::SqliteConnection>> connection =
      sql::SqliteConnection::Open(file, options);
  if (!connection.ok()) {
    return absl::Status(connection.status().code(), Cat(file, ": ", connection.status().message()));
  }
  return connection;
}

absl::StatusOr<std::vector<Topic>> ReadTopics(sql::Connection& db, const std::string& file) {
  absl::StatusOr<sql::ScopedStatement> select =
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
    topics.push_back(Topic{
        (*select)->ColumnInt64(0),
        BagTopic{(*select)->ColumnText(1), (*select)->ColumnText(2), (*select)->ColumnText(3)}});
  }
  return topics;
}

absl::Status ReadMessages(sql::Connection& db, const std::string& file, const Topic& topic,
                          ImuMessages* messages) {
  absl::StatusOr<sql::ScopedStatement> select =
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
    if (absl::Status s = messages->Add((*select)->ColumnBlobView(1), (*select)->ColumnInt64(0),
                                       file, topic.topic.name);
        !s.ok()) {
      return s;
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<core::Capture> ReadSqliteBag(const std::string& path,
                                            const std::vector<std::string>& files,
                                            const ImportOptions& options,
                                            std::vector<std::string>* notes) {
  std::string topic_name = options.topic;
  ImuMessages messages;
  for (const std::string& file : files) {
    absl::StatusOr<std::unique_ptr<sql::SqliteConnection>> db = OpenBagFile(file);
    if (!db.ok()) return db.status();
    absl::StatusOr<std::vector<Topic>> topics = ReadTopics(**db, file);
    if (!topics.ok()) return topics.status();
    std::vector<BagTopic> listed;
    for (const Topic& t : *topics) listed.push_back(t.topic);
    // Split files repeat the topics table; the topic is chosen by name, so its id may differ.
    absl::StatusOr<BagTopic> chosen = ChooseImuTopic(listed, topic_name, file);
    if (!chosen.ok()) return chosen.status();
    topic_name = chosen->name;
    const Topic& topic = *std::find_if(topics->begin(), topics->end(),
                                       [&](const Topic& t) { return t.topic.name == topic_name; });
    if (absl::Status s = ReadMessages(**db, file, topic, &messages); !s.ok()) return s;
  }
  return messages.ToCapture(path, topic_name, files.size(), options, notes);
}

class Rosbag2ImporterImpl final : public CaptureImporter {
 public:
  std::string_view name() const override { return "rosbag2"; }
  std::string_view description() const override {
    return "ROS 2 bag (directory with metadata.yaml, sqlite3 or mcap storage; or a .db3), "
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

absl::StatusOr<core::Capture> ReadRosbag2Imu(const std::string& path, const ImportOptions& options,
                                             std::vector<std::string>* notes) {
  absl::StatusOr<BagFileList> bag = BagFiles(path);
  if (!bag.ok()) return bag.status();
  if (bag->storage == "mcap") return ReadMcapImu(path, bag->files, options, notes);
  return ReadSqliteBag(path, bag->files, options, notes);
}

const CaptureImporter* Rosbag2Importer() {
  static const auto* const kImporter = new Rosbag2ImporterImpl();
  return kImporter;
}

}  // namespace imucal::importers
