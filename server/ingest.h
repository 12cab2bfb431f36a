// Ingest of one SampleBatch: validate -> encode -> store (durable before the ack) -> segment.
//
// Checks (server/validate.h), each naming the batch, sample and field at fault
// (INVALID_ARGUMENT), the limit (RESOURCE_EXHAUSTED) or the state (FAILED_PRECONDITION):
//   seq          >= 1; a gap is FailedPrecondition naming the expected seq; seq <= last acked is
//                a retransmission, a no-op when the content is the same (Store compares)
//   t_s          1..max_batch_samples, finite, strictly increasing, after the session's last t
//   accel, gyro  exactly 3 per sample, finite, within the unit's physical range
//   temp_c       empty or 1 per sample, finite, within -60..150 degC
//   the session  at most max_session_samples in all
#ifndef IMUCAL_SERVER_INGEST_H_
#define IMUCAL_SERVER_INGEST_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "formats/sample_digest.h"
#include "imucal/v1/imucal.pb.h"
#include "server/session_hub.h"
#include "server/validate.h"
#include "storage/sample_codec.h"
#include "storage/store.h"

namespace imucal::server {

std::vector<storage::ImuSample> ToSamples(const v1::SampleBatch& batch);

struct IngestResult {
  v1::SampleAck ack;
  std::vector<v1::SessionEvent> events;  // for the watchers
};

// A batch checked against the session and encoded, ready for the store.
struct PreparedBatch {
  int64_t seq = 0;
  bool retransmission = false;  // seq <= the session's last acked: the store compares it
  std::string payload;          // EncodeSamples(samples)
  std::vector<storage::ImuSample> samples;
  // The session's sample digest once this batch is stored (not for a retransmission); hashed
  // here, off the store's committer thread.
  formats::SampleDigest digest_after;
};

// The three steps of one batch; the caller holds `session.mu` during the first and the last.
// StreamSamples runs them asynchronously (the store's group commit in between, so that many
// streams share a commit); IngestBatch runs them in a row.
absl::StatusOr<PreparedBatch> PrepareBatch(const LiveSession& session, const v1::SampleBatch& batch,
                                           const IngestLimits& limits = {});
// After the store acknowledged the batch: the session's state, the online segmentation (its
// poses and pair verdicts stored as they are judged) and the events for the watchers.
IngestResult CompleteBatch(storage::Store& store, LiveSession& session, const PreparedBatch& batch,
                           const storage::BatchAck& ack);
absl::StatusOr<IngestResult> IngestBatch(storage::Store& store, LiveSession& session,
                                         const v1::SampleBatch& batch,
                                         const IngestLimits& limits = {});

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_INGEST_H_
