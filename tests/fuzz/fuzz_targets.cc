#include "tests/fuzz/fuzz_targets.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "core/capture.h"
#include "google/protobuf/stubs/logging.h"
#include "importers/columns.h"
#include "importers/euroc.h"
#include "importers/imucal_csv.h"
#include "importers/imutk.h"
#include "importers/mcap.h"
#include "importers/registry.h"
#include "importers/ros_imu.h"
#include "imucal/v1/imucal.pb.h"
#include "server/validate.h"
#include "storage/sample_codec.h"
#include "yaml-cpp/yaml.h"

namespace imucal::fuzz {
namespace {

// A violated property: a crash that libFuzzer records (and the regression test reports).
[[noreturn]] void Fail(const char* target, const std::string& what) {
  std::fprintf(stderr, "fuzz property violated in %s: %s\n", target, what.c_str());
  std::abort();
}

bool SameDouble(double a, double b) { return a == b || (std::isnan(a) && std::isnan(b)); }

bool SameVector(const std::vector<double>& a, const std::vector<double>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (!SameDouble(a[i], b[i])) return false;
  return true;
}

bool SameVector3(const std::vector<Eigen::Vector3d>& a, const std::vector<Eigen::Vector3d>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    for (int k = 0; k < 3; ++k)
      if (!SameDouble(a[i][k], b[i][k])) return false;
  return true;
}

// The fields a round trip must keep, first difference named.
std::string CaptureDifference(const core::Capture& a, const core::Capture& b) {
  if (a.device != b.device) return "device";
  if (a.accel_unit != b.accel_unit) return "accel_unit";
  if (a.has_gyro != b.has_gyro) return "has_gyro";
  // Without a gyroscope the gyro unit means nothing, and is not written.
  if (a.has_gyro && a.gyro_unit != b.gyro_unit) return "gyro_unit";
  if (a.temp_unit != b.temp_unit) return "temp_unit";
  if (!SameDouble(a.gravity_m_s2, b.gravity_m_s2)) return "gravity_m_s2";
  if (!SameDouble(a.rate_hz, b.rate_hz)) return "rate_hz";
  if (a.extra_metadata != b.extra_metadata) return "extra_metadata";
  if (!SameVector(a.t_s, b.t_s)) return "t_s";
  if (!SameVector3(a.accel, b.accel)) return "accel";
  if (!SameVector3(a.gyro, b.gyro)) return "gyro";
  if (!SameVector(a.temp, b.temp)) return "temp";
  if (a.extra_column_names != b.extra_column_names) return "extra_column_names";
  if (a.extra_columns.size() != b.extra_columns.size()) return "extra_columns";
  for (size_t c = 0; c < a.extra_columns.size(); ++c)
    if (!SameVector(a.extra_columns[c], b.extra_columns[c])) return "extra_columns values";
  return "";
}

// Every importer promises a capture that satisfies ValidateCapture, or an error.
void CheckImported(const char* target, const absl::StatusOr<core::Capture>& capture) {
  if (!capture.ok()) {
    if (capture.status().message().empty()) Fail(target, "an error without a message");
    return;
  }
  if (absl::Status s = core::ValidateCapture(*capture); !s.ok())
    Fail(target, "accepted a capture that ValidateCapture refuses: " + s.ToString());
}

}  // namespace

void FuzzCaptureCsv(std::string_view data) {
  const absl::StatusOr<core::Capture> capture = importers::ParseImucalCsv(data, "fuzz.csv");
  CheckImported("capture_csv", capture);
  if (!capture.ok() || !importers::CheckCaptureWritable(*capture).ok()) return;
  // A writable capture formats and parses back to itself, exactly.
  const std::string text = importers::FormatImucalCsv(*capture);
  const absl::StatusOr<core::Capture> again = importers::ParseImucalCsv(text, "formatted.csv");
  if (!again.ok())
    Fail("capture_csv", "its own output does not parse: " + again.status().ToString());
  if (const std::string diff = CaptureDifference(*capture, *again); !diff.empty())
    Fail("capture_csv", "format -> parse changed " + diff);
}

void FuzzImuTk(std::string_view data) {
  // The accelerometer file, a NUL, the gyroscope file (no NUL: cut in half).
  size_t cut = data.find('\0');
  std::string_view accel, gyro;
  if (cut == std::string_view::npos) {
    cut = data.size() / 2;
    accel = data.substr(0, cut);
    gyro = data.substr(cut);
  } else {
    accel = data.substr(0, cut);
    gyro = data.substr(cut + 1);
  }
  importers::ImportOptions options;
  std::vector<std::string> notes;
  CheckImported("imutk",
                importers::ParseImuTkPair(accel, "acc.txt", gyro, "gyr.txt", options, &notes));
}

void FuzzColumns(std::string_view data) {
  if (data.empty()) return;
  // Byte 0 picks one of the option sets the CLI's --columns flags make.
  const unsigned char pick = static_cast<unsigned char>(data[0]);
  data.remove_prefix(1);
  importers::ImportOptions options;
  importers::ColumnCsvOptions& c = options.columns;
  switch (pick % 6) {
    case 0:  // named columns, time in seconds, temperature
      c.map = "t=t,ax=ax,ay=ay,az=az,gx=gx,gy=gy,gz=gz,temp=temp";
      break;
    case 1:  // numbered columns, no header, sample counter at a rate
      c.map = "t=1,ax=2,ay=3,az=4,gx=5,gy=6,gz=7";
      c.no_header = true;
      c.delimiter = ",";
      c.time_unit = importers::ColumnTimeUnit::kSampleIndex;
      c.rate_hz = 100;
      break;
    case 2:  // no time column: rate from a preamble line ("Fs,100"), units given
      c.map = "ax=acc_x,ay=acc_y,az=acc_z,gx=gyr_x,gy=gyr_y,gz=gyr_z";
      c.rate_from_preamble = "Fs";
      options.accel_unit = core::AccelUnit::kCounts;
      options.gyro_unit = core::GyroUnit::kCounts;
      break;
    case 3:  // a file saved part by part: sorted by time, in milliseconds
      c.map = "t=time,ax=ax,ay=ay,az=az,gx=gx,gy=gy,gz=gz";
      c.time_unit = importers::ColumnTimeUnit::kMilliseconds;
      c.sort_by_time = true;
      break;
    case 5:  // an accelerometer-only interleaved log with quoted labels: rows with empty fields
      c.map = "t=t,ax=ax,ay=ay,az=az";
      c.skip_incomplete_rows = true;
      options.accel_unit = core::AccelUnit::kMetersPerSecond2;
      break;
    default:  // ';' after one skipped line, nanoseconds
      c.map = "t=1,ax=2,ay=3,az=4,gx=5,gy=6,gz=7";
      c.delimiter = ";";
      c.skip_lines = 1;
      c.time_unit = importers::ColumnTimeUnit::kNanoseconds;
      break;
  }
  if (!importers::CheckColumnCsvOptions(c).ok())
    Fail("columns", "an option set of the fuzzer is invalid");
  std::vector<std::string> notes;
  CheckImported("columns", importers::ParseColumnCsv(data, "vendor.csv", options, &notes));
}

void FuzzEuroc(std::string_view data) {
  importers::ImportOptions options;
  std::vector<std::string> notes;
  CheckImported("euroc", importers::ParseEurocCsv(data, "data.csv", options, &notes));
}

void FuzzRosbag2Cdr(std::string_view data) {
  const absl::StatusOr<importers::ImuMessage> m = importers::DecodeImuCdr(data);
  if (!m.ok()) {
    if (m.status().message().empty()) Fail("rosbag2_cdr", "an error without a message");
    return;
  }
  if (m->stamp_nanosec >= 1'000'000'000u) Fail("rosbag2_cdr", "nanosec not below 1e9 accepted");
  if (m->frame_id.size() > data.size()) Fail("rosbag2_cdr", "frame_id longer than the message");
}

void FuzzRosbag2Metadata(std::string_view data) {
  const absl::StatusOr<importers::BagMetadata> m = importers::ParseBagMetadata(data);
  if (!m.ok()) {
    if (m.status().message().substr(0, 14) != "metadata.yaml:")
      Fail("rosbag2_metadata", "an error that does not name the file: " + m.status().ToString());
    return;
  }
  for (const std::string& path : m->relative_file_paths)
    if (path.empty()) Fail("rosbag2_metadata", "an empty relative_file_paths entry accepted");
  // What it read, written back in rosbag2's layout by yaml-cpp's emitter, reads back the same.
  YAML::Emitter out;
  out << YAML::BeginMap << YAML::Key << "rosbag2_bagfile_information" << YAML::Value
      << YAML::BeginMap << YAML::Key << "version" << YAML::Value << 5;
  if (!m->storage_identifier.empty())
    out << YAML::Key << "storage_identifier" << YAML::Value << m->storage_identifier;
  out << YAML::Key << "relative_file_paths" << YAML::Value << YAML::BeginSeq;
  for (const std::string& path : m->relative_file_paths) out << path;
  out << YAML::EndSeq << YAML::EndMap << YAML::EndMap;
  if (!out.good()) return;  // a value the emitter cannot write (not UTF-8): nothing to compare
  const absl::StatusOr<importers::BagMetadata> again = importers::ParseBagMetadata(out.c_str());
  if (!again.ok())
    Fail("rosbag2_metadata", "its own rewrite does not parse: " + again.status().ToString());
  if (again->storage_identifier != m->storage_identifier)
    Fail("rosbag2_metadata", "storage_identifier changed in a write -> parse round trip");
  if (again->relative_file_paths != m->relative_file_paths)
    Fail("rosbag2_metadata", "relative_file_paths changed in a write -> parse round trip");
}

void FuzzMcap(std::string_view data) {
  absl::StatusOr<std::unique_ptr<importers::McapReader>> reader =
      importers::McapReader::FromBytes(data, "fuzz.mcap");
  if (!reader.ok()) {
    if (reader.status().message().empty()) Fail("mcap", "an error without a message");
    return;
  }
  absl::StatusOr<std::vector<importers::BagTopic>> topics = (*reader)->Topics();
  if (!topics.ok()) {
    if (topics.status().message().empty()) Fail("mcap", "an error without a message");
    return;
  }
  // Every Imu topic read to a capture: it satisfies ValidateCapture, or is an error.
  for (const importers::BagTopic& topic : *topics) {
    if (topic.type != importers::kRosImuType) continue;
    importers::ImuMessages messages;
    const absl::Status s = (*reader)->ReadTopic(topic.name, &messages);
    if (!s.ok()) {
      if (s.message().empty()) Fail("mcap", "an error without a message");
      continue;
    }
    messages.SortByBagTime();
    std::vector<std::string> notes;
    CheckImported(
        "mcap", messages.ToCapture("fuzz.mcap", topic.name, 1, importers::ImportOptions{}, &notes));
  }
}

void FuzzSampleBatch(std::string_view data) {
  // Invalid UTF-8 in session_id is a parse error that protobuf also logs: keep the runs quiet.
  static const bool quiet = (google::protobuf::SetLogHandler(nullptr), true);
  (void)quiet;
  v1::SampleBatch batch;
  if (!batch.ParseFromArray(data.data(), static_cast<int>(data.size()))) return;
  server::IngestLimits limits;
  limits.max_batch_samples = 4096;
  const char* units[][2] = {{"m/s^2", "rad/s"}, {"g", "deg/s"}, {"counts", "counts"}};
  for (const auto& u : units) {
    absl::Status s = server::ValidateBatchColumns(batch, u[0], u[1], limits);
    if (s.ok()) s = server::ValidateBatchTimes(batch, std::numeric_limits<double>::quiet_NaN());
    if (!s.ok()) {
      if (s.message().empty()) Fail("sample_batch", "an error without a message");
      continue;
    }
    // What validation accepts, the storage codec stores and gives back bit for bit.
    const int n = batch.t_s_size();
    std::vector<storage::ImuSample> samples(static_cast<size_t>(n));
    for (int i = 0; i < n; ++i) {
      storage::ImuSample& x = samples[static_cast<size_t>(i)];
      x.t_s = batch.t_s(i);
      for (int k = 0; k < 3; ++k) {
        x.accel[static_cast<size_t>(k)] = batch.accel(3 * i + k);
        x.gyro[static_cast<size_t>(k)] = batch.gyro(3 * i + k);
      }
      if (batch.temp_c_size() != 0) x.temp = batch.temp_c(i);
    }
    const absl::StatusOr<std::string> payload = storage::EncodeSamples(samples);
    if (!payload.ok())
      Fail("sample_batch", "validated but the codec refuses it: " + payload.status().ToString());
    const absl::StatusOr<std::vector<storage::ImuSample>> back = storage::DecodeSamples(*payload);
    if (!back.ok() || back->size() != samples.size())
      Fail("sample_batch", "its payload does not decode");
    for (size_t i = 0; i < samples.size(); ++i) {
      const storage::ImuSample &a = samples[i], &b = (*back)[i];
      bool same = SameDouble(a.t_s, b.t_s) && SameDouble(a.temp, b.temp);
      for (size_t k = 0; k < 3; ++k)
        same = same && SameDouble(a.accel[k], b.accel[k]) && SameDouble(a.gyro[k], b.gyro[k]);
      if (!same) Fail("sample_batch", "sample " + std::to_string(i) + " changed in the codec");
    }
  }
}

}  // namespace imucal::fuzz
