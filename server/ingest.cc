#include "server/ingest.h"

#include <cmath>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace imucal::server {
namespace {

// Physical ranges per input unit, well beyond any MEMS IMU (+-32 g, +-4000 deg/s) and any
// register width, so that only corrupt or mis-scaled data is rejected.
double AccelLimit(std::string_view unit) {
  if (unit == "m/s^2") return 100 * core::kStandardGravity;
  if (unit == "g") return 100;
  return 1e9;  // counts
}
double GyroLimit(std::string_view unit) {
  if (unit == "rad/s") return 200;
  if (unit == "deg/s") return 12000;
  return 1e9;  // counts
}
constexpr double kTempMinC = -100, kTempMaxC = 200;

absl::Status CheckColumn(const google::protobuf::RepeatedField<double>& column,
                         std::string_view name, size_t per_sample, size_t samples, double limit,
                         std::string_view unit) {
  if (static_cast<size_t>(column.size()) != per_sample * samples) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: has %d values, expected %d (%d per sample for %d samples in t_s)", name,
        column.size(), per_sample * samples, per_sample, samples));
  }
  for (int i = 0; i < column.size(); ++i) {
    const double v = column[i];
    if (!std::isfinite(v)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s[%d]: not a finite number (sample %d)", name, i, i / static_cast<int>(per_sample)));
    }
    if (std::abs(v) > limit) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s[%d]: %g %s is physically implausible (limit %g)", name, i, v, unit, limit));
    }
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status ValidateBatchColumns(const v1::SampleBatch& batch, std::string_view accel_unit,
                                  std::string_view gyro_unit) {
  const size_t n = static_cast<size_t>(batch.t_s_size());
  if (n == 0) return absl::InvalidArgumentError("t_s: the batch has no samples");
  if (n > kMaxBatchSamples) {
    return absl::InvalidArgumentError(
        absl::StrFormat("t_s: %d samples, at most %d per batch", n, kMaxBatchSamples));
  }
  if (absl::Status s = CheckColumn(batch.accel(), "accel", 3, n, AccelLimit(accel_unit),
                                   accel_unit);
      !s.ok())
    return s;
  if (absl::Status s = CheckColumn(batch.gyro(), "gyro", 3, n, GyroLimit(gyro_unit), gyro_unit);
      !s.ok())
    return s;
  if (batch.temp_c_size() != 0) {
    if (absl::Status s = CheckColumn(batch.temp_c(), "temp_c", 1, n, kTempMaxC, "degC"); !s.ok())
      return s;
    for (int i = 0; i < batch.temp_c_size(); ++i) {
      if (batch.temp_c(i) < kTempMinC) {
        return absl::InvalidArgumentError(absl::StrFormat(
            "temp_c[%d]: %g degC is physically implausible", i, batch.temp_c(i)));
      }
    }
  }
  return absl::OkStatus();
}

absl::Status ValidateBatchTimes(const v1::SampleBatch& batch, double last_t_s) {
  for (int i = 0; i < batch.t_s_size(); ++i) {
    const double t = batch.t_s(i);
    if (!std::isfinite(t) || std::abs(t) > 1e12) {
      return absl::InvalidArgumentError(absl::StrFormat("t_s[%d]: not a finite time", i));
    }
    const double previous = i > 0 ? batch.t_s(i - 1) : last_t_s;
    if (!std::isnan(previous) && !(t > previous)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "t_s[%d]: %.9g s is not after %s (%.9g s); times must strictly increase", i, t,
          i > 0 ? "the previous sample" : "the session's last stored sample", previous));
    }
  }
  return absl::OkStatus();
}

std::vector<storage::ImuSample> ToSamples(const v1::SampleBatch& batch) {
  const int n = batch.t_s_size();
  std::vector<storage::ImuSample> out(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    storage::ImuSample& s = out[static_cast<size_t>(i)];
    s.t_s = batch.t_s(i);
    for (int k = 0; k < 3; ++k) {
      s.accel[static_cast<size_t>(k)] = batch.accel(3 * i + k);
      s.gyro[static_cast<size_t>(k)] = batch.gyro(3 * i + k);
    }
    if (batch.temp_c_size() != 0) s.temp = batch.temp_c(i);
  }
  return out;
}

absl::StatusOr<PreparedBatch> PrepareBatch(const LiveSession& session,
                                           const v1::SampleBatch& batch) {
  // validate
  if (batch.seq() < 1) return absl::InvalidArgumentError("seq: must be 1 or more");
  if (batch.seq() > session.last_acked_seq + 1) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "seq: expected %d (session %s has batches up to %d stored), got %d; resume from %d",
        session.last_acked_seq + 1, session.id, session.last_acked_seq, batch.seq(),
        session.last_acked_seq + 1));
  }
  if (absl::Status s =
          ValidateBatchColumns(batch, session.device.accel_unit, session.device.gyro_unit);
      !s.ok())
    return s;
  PreparedBatch out;
  out.seq = batch.seq();
  out.retransmission = batch.seq() <= session.last_acked_seq;
  if (!out.retransmission) {
    if (absl::Status s = ValidateBatchTimes(batch, session.last_t_s); !s.ok()) return s;
  }
  // convert
  out.samples = ToSamples(batch);
  absl::StatusOr<std::string> payload = storage::EncodeSamples(out.samples);
  if (!payload.ok()) return payload.status();
  out.payload = *std::move(payload);
  return out;
}

IngestResult CompleteBatch(storage::Store& store, LiveSession& session,
                           const PreparedBatch& batch, const storage::BatchAck& ack) {
  IngestResult result;
  // A retransmission (or a batch another stream of the session stored first) changes nothing.
  if (!batch.retransmission && ack.last_acked_seq > session.last_acked_seq) {
    session.last_acked_seq = ack.last_acked_seq;
    session.last_t_s = batch.samples.back().t_s;
    std::vector<LiveEvent> events;
    Segment(session, batch.samples, &events);
    // Poses and pair verdicts are stored as they are judged (a few per minute). The batch is
    // already durable and acknowledged by then, so a failure here must not fail the stream: the
    // segmentation is deterministic and the replay at the session's next load stores them.
    std::vector<storage::Pose> poses;
    std::vector<storage::PosePair> pairs;
    ToRows(events, &poses, &pairs);
    store.SavePoses(session.id, poses, pairs).IgnoreError();
    result.events = SessionHub::ToEvents(events);
  }
  // convert back
  result.ack.set_last_acked_seq(ack.last_acked_seq);
  result.ack.set_samples(ack.samples);
  return result;
}

absl::StatusOr<IngestResult> IngestBatch(storage::Store& store, LiveSession& session,
                                         const v1::SampleBatch& batch) {
  absl::StatusOr<PreparedBatch> prepared = PrepareBatch(session, batch);
  if (!prepared.ok()) return prepared.status();
  // call: durable before the ack (a retransmission is compared with the stored batch)
  absl::StatusOr<storage::BatchAck> acked =
      store.AppendBatch(session.id, prepared->seq, prepared->payload);
  if (!acked.ok()) return acked.status();
  return CompleteBatch(store, session, *prepared, *acked);
}

}  // namespace imucal::server
