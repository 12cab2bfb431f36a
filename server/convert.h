// Conversions between the API's messages (imucal/v1/imucal.proto) and storage's domain types.
// Pure functions: no I/O, no validation beyond what a conversion itself needs.
#ifndef IMUCAL_SERVER_CONVERT_H_
#define IMUCAL_SERVER_CONVERT_H_

#include <cstddef>
#include <cstdint>
#include <map>
#include <mutex>
#include <string>
#include <string_view>
#include <utility>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "core/calibrate/verdict.h"
#include "core/capture.h"
#include "core/protocol.h"
#include "google/protobuf/timestamp.pb.h"
#include "imucal/v1/imucal.pb.h"
#include "storage/types.h"

namespace imucal::server {

void ToTimestamp(absl::Time t, google::protobuf::Timestamp* out);

v1::Device ToProto(const storage::Device& device);
storage::Device FromProto(const v1::Device& device);

// Session. `live_poses_accepted` (the online segmenter's count) replaces the stored count
// when the session is live in memory (-1: use the stored one).
v1::Session ToProto(const storage::Session& session, int live_poses_accepted = -1);
v1::SessionState ToProto(storage::SessionState state);
absl::StatusOr<storage::SessionState> FromProto(v1::SessionState state);
// The stored protocol names: "six-face", "positions", "free", "auto" (unspecified).
std::string ProtocolName(v1::Protocol protocol);
v1::Protocol ParseProtocol(std::string_view stored);
core::ProtocolKind ToProtocolKind(v1::Protocol protocol);

// CRC-32C (formats/crc32c.h, the checksum the SDK's cache checks) of each version's params JSON,
// computed once: a version's JSON never changes, and a robot fleet fetching its active
// parameters would otherwise re-hash the same kilobytes on every call. Keyed by (device, version)
// and checked against the JSON's length; bounded (cleared when full). One per Store (a
// ParameterServiceImpl owns one): (device, version) names one JSON only within one database.
// Thread-safe.
class ParamCrcCache {
 public:
  static constexpr size_t kMaxEntries = 4096;
  // formats::Crc32c(version.params_json), from the cache when it holds it.
  uint32_t Get(const storage::ParamVersion& version);
  size_t hits() const;

 private:
  struct Entry {
    size_t json_size = 0;
    uint32_t crc = 0;
  };
  mutable std::mutex mu_;
  std::map<std::pair<std::string, int>, Entry> entries_;  // guarded by mu_
  size_t hits_ = 0;                                       // guarded by mu_
};

// Parameter versions. `with_json` false leaves json empty (listings, if_not_version hits).
// `crc_cache` (optional) supplies the crc32c.
v1::ParameterSet ToProto(const storage::ParamVersion& version, bool with_json,
                         ParamCrcCache* crc_cache = nullptr);
v1::VersionState ToProto(storage::VersionState state);
// The calibration's verdict as stored, and back.
storage::Verdict ToStorage(core::Verdict verdict);
core::Verdict ToCore(storage::Verdict verdict);
v1::Verdict ToProto(core::Verdict verdict);
// Sets a message's verdict (SolveJob, ParameterSet): the enum and its text, always together.
template <typename Message>
void SetVerdict(core::Verdict verdict, Message* message) {
  message->set_verdict(std::string(core::VerdictName(verdict)));
  message->set_verdict_kind(ToProto(verdict));
}

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_CONVERT_H_
