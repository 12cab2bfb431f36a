#include "server/convert.h"

#include "absl/strings/str_cat.h"
#include "formats/crc32c.h"

namespace imucal::server {

std::string ProtocolName(v1::Protocol protocol) {
  switch (protocol) {
    case v1::PROTOCOL_SIX_FACE:
      return "six-face";
    case v1::PROTOCOL_POSITIONS:
      return "positions";
    case v1::PROTOCOL_FREE:
      return "free";
    case v1::PROTOCOL_FERRARIS:
      return "ferraris";
    default:
      return "auto";
  }
}

v1::Protocol ParseProtocol(std::string_view stored) {
  if (stored == "six-face") return v1::PROTOCOL_SIX_FACE;
  if (stored == "positions") return v1::PROTOCOL_POSITIONS;
  if (stored == "free") return v1::PROTOCOL_FREE;
  if (stored == "ferraris") return v1::PROTOCOL_FERRARIS;
  return v1::PROTOCOL_UNSPECIFIED;
}

void ToTimestamp(absl::Time t, google::protobuf::Timestamp* out) {
  const absl::Duration since = t - absl::UnixEpoch();
  const int64_t seconds = absl::ToInt64Seconds(since);
  out->set_seconds(seconds);
  out->set_nanos(static_cast<int32_t>(absl::ToInt64Nanoseconds(since - absl::Seconds(seconds))));
}

v1::Device ToProto(const storage::Device& device) {
  v1::Device out;
  out.set_id(device.id);
  out.set_sensor_model(device.sensor_model);
  out.set_nominal_rate_hz(device.nominal_rate_hz);
  out.set_accel_unit(device.accel_unit);
  out.set_gyro_unit(device.gyro_unit);
  ToTimestamp(device.created_at, out.mutable_created_at());
  out.set_active_version(device.active_version);
  return out;
}

storage::Device FromProto(const v1::Device& device) {
  storage::Device out;
  out.id = device.id();
  out.sensor_model = device.sensor_model();
  out.nominal_rate_hz = device.nominal_rate_hz();
  out.accel_unit = device.accel_unit();
  out.gyro_unit = device.gyro_unit();
  return out;
}

v1::SessionState ToProto(storage::SessionState state) {
  switch (state) {
    case storage::SessionState::kOpen:
      return v1::SESSION_STATE_OPEN;
    case storage::SessionState::kSolving:
      return v1::SESSION_STATE_SOLVING;
    case storage::SessionState::kSolved:
      return v1::SESSION_STATE_SOLVED;
    case storage::SessionState::kFailed:
      return v1::SESSION_STATE_FAILED;
    case storage::SessionState::kCancelled:
      return v1::SESSION_STATE_CANCELLED;
  }
  return v1::SESSION_STATE_UNSPECIFIED;
}

absl::StatusOr<storage::SessionState> FromProto(v1::SessionState state) {
  switch (state) {
    case v1::SESSION_STATE_OPEN:
      return storage::SessionState::kOpen;
    case v1::SESSION_STATE_SOLVING:
      return storage::SessionState::kSolving;
    case v1::SESSION_STATE_SOLVED:
      return storage::SessionState::kSolved;
    case v1::SESSION_STATE_FAILED:
      return storage::SessionState::kFailed;
    case v1::SESSION_STATE_CANCELLED:
      return storage::SessionState::kCancelled;
    default:
      return absl::InvalidArgumentError("state: unknown session state");
  }
}

core::ProtocolKind ToProtocolKind(v1::Protocol protocol) {
  switch (protocol) {
    case v1::PROTOCOL_SIX_FACE:
      return core::ProtocolKind::kSixFace;
    case v1::PROTOCOL_POSITIONS:
      return core::ProtocolKind::kPositions;
    case v1::PROTOCOL_FREE:
      return core::ProtocolKind::kFree;
    case v1::PROTOCOL_FERRARIS:
      return core::ProtocolKind::kFerraris;
    default:
      return core::ProtocolKind::kAuto;
  }
}

v1::Session ToProto(const storage::Session& session, int live_poses_accepted) {
  v1::Session out;
  out.set_id(session.id);
  out.set_device_id(session.device_id);
  out.set_state(ToProto(session.state));
  out.set_protocol(ParseProtocol(session.protocol));
  ToTimestamp(session.created_at, out.mutable_created_at());
  ToTimestamp(session.updated_at, out.mutable_updated_at());
  out.set_last_acked_seq(session.last_acked_seq);
  out.set_samples(session.samples);
  out.set_poses_accepted(live_poses_accepted >= 0 ? live_poses_accepted : session.poses_accepted);
  out.set_version(session.version);
  out.set_source(session.source);
  return out;
}

storage::Verdict ToStorage(core::Verdict verdict) {
  switch (verdict) {
    case core::Verdict::kPass:
      return storage::Verdict::kPass;
    case core::Verdict::kWarn:
      return storage::Verdict::kWarn;
    case core::Verdict::kFail:
    // A refused calibration never becomes a version (SolveJobs::Solve): no case of
    // its own in storage.
    case core::Verdict::kRefused:
      return storage::Verdict::kFail;
  }
  return storage::Verdict::kFail;
}

core::Verdict ToCore(storage::Verdict verdict) {
  switch (verdict) {
    case storage::Verdict::kPass:
      return core::Verdict::kPass;
    case storage::Verdict::kWarn:
      return core::Verdict::kWarn;
    case storage::Verdict::kFail:
      return core::Verdict::kFail;
  }
  return core::Verdict::kFail;
}

v1::Verdict ToProto(core::Verdict verdict) {
  switch (verdict) {
    case core::Verdict::kPass:
      return v1::VERDICT_PASS;
    case core::Verdict::kWarn:
      return v1::VERDICT_WARN;
    case core::Verdict::kFail:
      return v1::VERDICT_FAIL;
    case core::Verdict::kRefused:
      return v1::VERDICT_REFUSED;
  }
  return v1::VERDICT_UNSPECIFIED;
}

v1::VersionState ToProto(storage::VersionState state) {
  switch (state) {
    case storage::VersionState::kCandidate:
      return v1::VERSION_STATE_CANDIDATE;
    case storage::VersionState::kActive:
      return v1::VERSION_STATE_ACTIVE;
    case storage::VersionState::kSuperseded:
      return v1::VERSION_STATE_SUPERSEDED;
    // The API has no "rejected" state yet: a rejected version is a candidate that never was.
    case storage::VersionState::kRejected:
      return v1::VERSION_STATE_CANDIDATE;
  }
  return v1::VERSION_STATE_UNSPECIFIED;
}

v1::ParameterSet ToProto(const storage::ParamVersion& version, bool with_json,
                         ParamCrcCache* crc_cache) {
  v1::ParameterSet out;
  out.set_device_id(version.device_id);
  out.set_version(version.version);
  out.set_state(ToProto(version.state));
  ToTimestamp(version.created_at, out.mutable_created_at());
  out.set_session_id(version.session_id);
  SetVerdict(ToCore(version.verdict), &out);
  out.set_accel_rms_m_s2(version.accel_rms);
  out.set_crc32c(crc_cache != nullptr ? crc_cache->Get(version)
                                      : formats::Crc32c(version.params_json));
  if (with_json) out.set_json(version.params_json);
  return out;
}

uint32_t ParamCrcCache::Get(const storage::ParamVersion& version) {
  // Listings do not load the JSON: nothing worth caching (and no entry to poison).
  if (version.params_json.empty()) return formats::Crc32c(version.params_json);
  std::pair<std::string, int> key(version.device_id, version.version);
  {
    std::lock_guard lock(mu_);
    auto it = entries_.find(key);
    if (it != entries_.end() && it->second.json_size == version.params_json.size()) {
      ++hits_;
      return it->second.crc;
    }
  }
  const uint32_t crc = formats::Crc32c(version.params_json);  // outside the lock
  std::lock_guard lock(mu_);
  if (entries_.size() >= kMaxEntries && entries_.find(key) == entries_.end()) entries_.clear();
  entries_[std::move(key)] = Entry{version.params_json.size(), crc};
  return crc;
}

size_t ParamCrcCache::hits() const {
  std::lock_guard lock(mu_);
  return hits_;
}

}  // namespace imucal::server
