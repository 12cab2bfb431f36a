#include "server/ingest.h"

#include <cmath>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace imucal::server {
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

absl::StatusOr<PreparedBatch> PrepareBatch(const LiveSession& session, const v1::SampleBatch& batch,
                                           const IngestLimits& limits) {
  // validate
  if (batch.seq() < 1) {
    return absl::InvalidArgumentError(
        absl::StrFormat("batch %d: seq must be 1 or more (1, 2, 3, ... per session)", batch.seq()));
  }
  if (batch.seq() > session.last_acked_seq + 1) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "seq: expected %d (session %s has batches up to %d stored), got %d; resume from %d",
        session.last_acked_seq + 1, session.id, session.last_acked_seq, batch.seq(),
        session.last_acked_seq + 1));
  }
  if (absl::Status s =
          ValidateBatchColumns(batch, session.device.accel_unit, session.device.gyro_unit, limits);
      !s.ok())
    return s;
  PreparedBatch out;
  out.seq = batch.seq();
  out.retransmission = batch.seq() <= session.last_acked_seq;
  if (!out.retransmission) {
    if (absl::Status s = ValidateBatchTimes(batch, session.last_t_s); !s.ok()) return s;
    if (absl::Status s = ValidateSessionRoom(batch, session.id, session.samples, limits); !s.ok())
      return s;
  }
  // convert
  out.samples = ToSamples(batch);
  absl::StatusOr<std::string> payload = storage::EncodeSamples(out.samples);
  if (!payload.ok()) return payload.status();
  out.payload = *std::move(payload);
  if (!out.retransmission) {
    out.digest_after = session.digest;
    out.digest_after.AddRecords(std::string_view(out.payload).substr(storage::kSampleHeaderBytes));
  }
  return out;
}

IngestResult CompleteBatch(storage::Store& store, LiveSession& session, const PreparedBatch& batch,
                           const storage::BatchAck& ack) {
  IngestResult result;
  // A retransmission (or a batch another stream of the session stored first) changes nothing.
  if (!batch.retransmission && ack.last_acked_seq > session.last_acked_seq) {
    const int64_t samples_after = session.samples + static_cast<int64_t>(batch.samples.size());
    session.last_acked_seq = ack.last_acked_seq;
    session.samples = ack.samples;
    session.last_t_s = batch.samples.back().t_s;
    session.digest = batch.digest_after;
    RecordProof(session, batch.seq, samples_after);
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
                                         const v1::SampleBatch& batch, const IngestLimits& limits) {
  absl::StatusOr<PreparedBatch> prepared = PrepareBatch(session, batch, limits);
  if (!prepared.ok()) return prepared.status();
  // call: durable before the ack (a retransmission is compared with the stored batch)
  absl::StatusOr<storage::BatchAck> acked =
      store.AppendBatch(session.id, prepared->seq, prepared->payload);
  if (!acked.ok()) return acked.status();
  return CompleteBatch(store, session, *prepared, *acked);
}

}  // namespace imucal::server
