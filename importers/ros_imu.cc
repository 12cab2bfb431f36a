#include "importers/ros_imu.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "importers/registry.h"
#include "importers/text_scan.h"
#include "util/str_util.h"
#include "yaml-cpp/yaml.h"

namespace imucal::importers {
namespace {

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

std::string ListTopics(const std::vector<BagTopic>& topics) {
  std::vector<std::string> names;
  for (const BagTopic& t : topics) names.push_back(Cat(t.name, " (", t.type, ")"));
  return names.empty() ? std::string("none") : Join(names, ", ");
}

// A name read from a bag (storage identifier, file name, topic, frame id) that the capture CSV
// and YAML both carry unchanged: not empty, no surrounding spaces, well-formed UTF-8 (no overlong
// form, no surrogate, at most U+10FFFF) of printable characters on one line: no C0 or C1 control,
// no DEL, no U+2028/U+2029 separator and no U+FEFF byte-order mark.
bool IsOneLineName(std::string_view value) {
  if (value.empty() || TrimSpaces(value) != value) return false;
  const auto byte = [&](std::size_t k) { return static_cast<unsigned char>(value[k]); };
  for (std::size_t i = 0; i < value.size();) {
    const unsigned char lead = byte(i);
    const std::size_t length = lead < 0x80 ? 1 : (lead >> 5) == 0x6 ? 2 : (lead >> 4) == 0xE ? 3
                               : (lead >> 3) == 0x1E                ? 4
                                                                    : 0;
    if (length == 0 || i + length > value.size()) return false;
    std::uint32_t code = length == 1 ? lead : lead & (0x7F >> length);
    for (std::size_t k = 1; k < length; ++k) {
      if ((byte(i + k) & 0xC0) != 0x80) return false;
      code = (code << 6) | (byte(i + k) & 0x3F);
    }
    constexpr std::uint32_t kSmallest[] = {0, 0, 0x80, 0x800, 0x10000};
    if (code < kSmallest[length] || code > 0x10FFFF || (code >= 0xD800 && code <= 0xDFFF) ||
        code < 0x20 || (code >= 0x7F && code <= 0x9F) || code == 0x2028 || code == 0x2029 ||
        code == 0xFEFF) {
      return false;
    }
    i += length;
  }
  return true;
}

// "SOURCE:LINE: what" for a YAML node (yaml-cpp counts lines from 0).
absl::Status YamlError(std::string_view source, const YAML::Mark& mark, std::string_view what) {
  return absl::InvalidArgumentError(mark.is_null() ? Cat(source, ": ", what)
                                                   : Cat(source, ":", mark.line + 1, ": ", what));
}

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

absl::StatusOr<BagMetadata> ParseBagMetadata(std::string_view yaml, std::string_view source) {
  // yaml-cpp reports errors by exception; nothing past this function sees one.
  try {
    const YAML::Node root = YAML::Load(std::string(yaml));
    if (!root.IsMap()) {
      return YamlError(source, root.Mark(), "not a rosbag2 metadata file (not a YAML mapping)");
    }
    const YAML::Node info = root["rosbag2_bagfile_information"];
    // An absent key gives an invalid node, on which only IsDefined may be called.
    if (!info.IsDefined() || !info.IsMap()) {
      return YamlError(source, info.IsDefined() ? info.Mark() : root.Mark(),
                       "not a rosbag2 metadata file (no rosbag2_bagfile_information mapping)");
    }
    BagMetadata metadata;
    if (const YAML::Node storage = info["storage_identifier"]; storage.IsDefined()) {
      if (!storage.IsScalar() || !IsOneLineName(storage.Scalar())) {
        return YamlError(source, storage.Mark(), "storage_identifier is not a one-line name");
      }
      metadata.storage_identifier = storage.Scalar();
    }
    if (const YAML::Node files = info["relative_file_paths"]; files.IsDefined()) {
      if (!files.IsSequence() && !files.IsNull()) {
        return YamlError(source, files.Mark(), "relative_file_paths is not a list");
      }
      for (const YAML::Node& file : files) {
        // A quoted scalar may fold lines or hold escapes; no bag names its files so.
        if (!file.IsScalar() || !IsOneLineName(file.Scalar())) {
          return YamlError(source, file.Mark(), "a relative_file_paths entry is not a file name");
        }
        metadata.relative_file_paths.push_back(file.Scalar());
      }
    }
    return metadata;
  } catch (const YAML::Exception& e) {
    return YamlError(source, e.mark, e.msg);
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(Cat(source, ": ", e.what()));
  }
}

absl::StatusOr<BagTopic> ChooseImuTopic(const std::vector<BagTopic>& topics,
                                        std::string_view wanted, std::string_view file) {
  const BagTopic* chosen = nullptr;
  if (!wanted.empty()) {
    const auto it = std::find_if(topics.begin(), topics.end(),
                                 [&](const BagTopic& t) { return t.name == wanted; });
    if (it == topics.end()) {
      return absl::InvalidArgumentError(
          Cat(file, ": no topic '", wanted, "' (topics: ", ListTopics(topics), ")"));
    }
    if (it->type != kRosImuType) {
      return absl::InvalidArgumentError(
          Cat(file, ": topic '", wanted, "' has type ", it->type, ", not ", kRosImuType));
    }
    chosen = &*it;
  } else {
    std::vector<BagTopic> imu;
    for (const BagTopic& t : topics) {
      if (t.type == kRosImuType && std::none_of(imu.begin(), imu.end(), [&](const BagTopic& i) {
            return i.name == t.name;
          })) {
        imu.push_back(t);
      }
    }
    if (imu.empty()) {
      return absl::InvalidArgumentError(
          Cat(file, ": no ", kRosImuType, " topic (topics: ", ListTopics(topics), ")"));
    }
    if (imu.size() > 1) {
      return absl::InvalidArgumentError(Cat(file, ": ", imu.size(), " ", kRosImuType,
                                            " topics, choose one with --topic: ", ListTopics(imu)));
    }
    chosen = &*std::find_if(topics.begin(), topics.end(),
                            [&](const BagTopic& t) { return t.name == imu[0].name; });
  }
  if (chosen->serialization_format != "cdr") {
    return absl::InvalidArgumentError(Cat(file, ": topic ", chosen->name, " is serialised as '",
                                          chosen->serialization_format, "', not cdr"));
  }
  return *chosen;
}

absl::Status ImuMessages::Add(std::string_view data, int64_t bag_ns, std::string_view file,
                              std::string_view topic) {
  absl::StatusOr<ImuMessage> message = DecodeImuCdr(data);
  if (!message.ok()) {
    return absl::InvalidArgumentError(Cat(file, ": message ", samples_.size(), " (t=", bag_ns,
                                          " ns) on ", topic, ": ", message.status().message()));
  }
  const int64_t stamp_ns =
      int64_t{message->stamp_sec} * 1'000'000'000 + int64_t{message->stamp_nanosec};
  samples_.push_back(
      Sample{stamp_ns, bag_ns, message->angular_velocity, message->linear_acceleration});
  if (frame_ids_.empty() || frame_ids_.back() != message->frame_id) {
    if (std::find(frame_ids_.begin(), frame_ids_.end(), message->frame_id) == frame_ids_.end()) {
      frame_ids_.push_back(message->frame_id);
    }
  }
  return absl::OkStatus();
}

void ImuMessages::SortByBagTime() {
  std::stable_sort(samples_.begin(), samples_.end(),
                   [](const Sample& a, const Sample& b) { return a.bag_ns < b.bag_ns; });
}

absl::StatusOr<core::Capture> ImuMessages::ToCapture(std::string_view path, std::string_view topic,
                                                     size_t file_count,
                                                     const ImportOptions& options,
                                                     std::vector<std::string>* notes) const {
  if (samples_.empty()) {
    return absl::InvalidArgumentError(Cat(path, ": topic ", topic, " has no messages"));
  }
  const bool stamped = std::any_of(samples_.begin(), samples_.end(),
                                   [](const Sample& s) { return s.stamp_ns != 0; });
  auto time_of = [&](const Sample& s) { return stamped ? s.stamp_ns : s.bag_ns; };
  const std::string_view clock = stamped ? "header.stamp" : "bag timestamp";
  core::Capture capture;
  capture.accel_unit = core::AccelUnit::kMetersPerSecond2;
  capture.gyro_unit = core::GyroUnit::kRadPerSecond;
  capture.t_s.reserve(samples_.size());
  capture.accel.reserve(samples_.size());
  capture.gyro.reserve(samples_.size());
  capture.line.reserve(samples_.size());
  const int64_t t0_ns = time_of(samples_[0]);
  for (size_t i = 0; i < samples_.size(); ++i) {
    const int64_t ns = time_of(samples_[i]);
    if (i > 0 && ns <= time_of(samples_[i - 1])) {
      return absl::InvalidArgumentError(Cat(
          path, ": message ", i, " (t=", samples_[i].bag_ns, " ns) on ", topic, ": ", clock, " ",
          ns, " ns does not increase (message ", i - 1, ": ", time_of(samples_[i - 1]), " ns)"));
    }
    // Integer difference first: a 1.7e18 ns origin would cost double precision.
    capture.line.push_back(static_cast<uint32_t>(i + 1));  // the message's ordinal on the topic
    capture.t_s.push_back(static_cast<double>(ns - t0_ns) / 1e9);
    capture.gyro.push_back(samples_[i].gyro);
    capture.accel.push_back(samples_[i].accel);
  }
  capture.extra_metadata.emplace_back("t0_ns", Cat(t0_ns));
  if (IsOneLineName(topic)) capture.extra_metadata.emplace_back("ros_topic", topic);
  if (frame_ids_.size() == 1 && IsOneLineName(frame_ids_[0])) {
    capture.extra_metadata.emplace_back("frame_id", frame_ids_[0]);
  }
  notes->push_back(Cat("topic ", topic, ": ", samples_.size(), " messages from ", file_count,
                       " file", file_count == 1 ? "" : "s", "; time = ", clock, " from ", t0_ns,
                       " ns (kept as t0_ns)"));
  if (!stamped) notes->push_back("every header.stamp is zero: used the bag's receive time");
  if (frame_ids_.size() > 1) {
    notes->push_back(
        Cat("the messages name ", frame_ids_.size(), " frames: ", Join(frame_ids_, ", ")));
  }
  ApplyImportOverrides(options, &capture, notes);
  NoteTimeGaps(capture, notes);
  return capture;
}

}  // namespace imucal::importers
