// Conversions between the API's messages (imucal/v1/imucal.proto) and storage's domain types.
// Pure functions: no I/O, no validation beyond what a conversion itself needs.
#ifndef IMUCAL_SERVER_CONVERT_H_
#define IMUCAL_SERVER_CONVERT_H_

#include <cstdint>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
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

// Parameter versions. `with_json` false leaves json empty (listings, if_not_version hits).
v1::ParameterSet ToProto(const storage::ParamVersion& version, bool with_json);
v1::VersionState ToProto(storage::VersionState state);

// CRC-32C (Castagnoli) of ParameterSet.json, as the SDK's cache checks it.
uint32_t Crc32c(std::string_view data);

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_CONVERT_H_
