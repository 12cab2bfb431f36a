// ReadSamples, a session's samples as stored: the stream reactor that pages them out of
// storage (server/stream_reactor.h has the life it shares with the others).
#include <algorithm>
#include <cmath>
#include <deque>
#include <iterator>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "server/session_streams.h"
#include "server/status_util.h"
#include "server/stream_reactor.h"
#include "storage/sample_codec.h"

namespace imucal::server {
namespace {

// ReadSamples: the session's stored batches, paged out of storage (Store::ReadBatchPage) as
// the client reads them, one message in flight: the server holds one page of stored payloads
// (at most kPageSamples samples past its first batch) and one decoded batch, whatever the
// session's length. The end is the session's last stored batch when the call started (an open
// session may grow meanwhile). A client that reads no message for stream_idle_timeout is
// cancelled. Storage is read on the thread of the write that finished, as unary handlers read it:
// a page is a short read of the file.
class ReadReactor final : public SessionWriter<ReadReactor, v1::SampleBatch> {
 public:
  static constexpr int64_t kMaxMessageSamples = 10000;  // 0.6 MB with temperature
  static constexpr int64_t kPageBatches = 256;
  static constexpr int64_t kPageSamples = 20000;

  ReadReactor(const StreamEnv& env, grpc::CallbackServerContext* context, PrincipalRef who,
              std::string session_id)
      : SessionWriter(env, context, std::move(who), std::move(session_id),
                      env.options->stream_idle_timeout, "reader") {}

  void Start() override {
    if (!Registered()) return;
    absl::StatusOr<storage::Session> session = env_.store->GetSession(session_id_);
    if (!session.ok()) {
      End(ToGrpcStatus(session.status()));
      return;
    }
    std::lock_guard lock(mu_);
    end_seq_ = session->last_acked_seq;
    WriteNextLocked();
  }

 private:
  void FinishingLocked() override {  // the page and the batch being sent
    page_.clear();
    samples_.clear();
    samples_.shrink_to_fit();
  }

  const v1::SampleBatch* NextLocked() override { return NextMessageLocked() ? &message_ : nullptr; }

  // Makes the next message: the next (at most kMaxMessageSamples) samples of the current
  // batch, decoding the page's next batch or reading the next page when needed. false: no
  // samples are left (or an error ended the call).
  bool NextMessageLocked() {
    while (offset_ >= samples_.size()) {
      if (page_.empty()) {
        if (after_seq_ >= end_seq_) return false;
        absl::StatusOr<std::vector<storage::SampleBatch>> page = env_.store->ReadBatchPage(
            session_id_, after_seq_, std::min(kPageBatches, end_seq_ - after_seq_), kPageSamples);
        if (!page.ok()) {
          FinishLocked(ToGrpcStatus(page.status()));
          return false;
        }
        if (page->empty()) return false;
        after_seq_ = page->back().seq;
        page_.assign(std::make_move_iterator(page->begin()), std::make_move_iterator(page->end()));
      }
      storage::SampleBatch batch = std::move(page_.front());
      page_.pop_front();
      samples_.clear();
      if (absl::Status s = storage::DecodeSamplesInto(batch.payload, &samples_); !s.ok()) {
        FinishLocked(ToGrpcStatus(absl::DataLossError(
            absl::StrCat("session ", session_id_, " batch ", batch.seq, ": ", s.message()))));
        return false;
      }
      offset_ = 0;
      seq_ = batch.seq;
    }
    const size_t n = std::min(samples_.size() - offset_, static_cast<size_t>(kMaxMessageSamples));
    const bool temp = !std::isnan(samples_[offset_].temp);  // a batch has it for all or none
    message_.Clear();
    message_.set_session_id(session_id_);
    message_.set_seq(seq_);
    message_.mutable_t_s()->Reserve(static_cast<int>(n));
    message_.mutable_accel()->Reserve(static_cast<int>(3 * n));
    message_.mutable_gyro()->Reserve(static_cast<int>(3 * n));
    if (temp) message_.mutable_temp_c()->Reserve(static_cast<int>(n));
    for (size_t i = offset_; i < offset_ + n; ++i) {
      const storage::ImuSample& x = samples_[i];
      message_.add_t_s(x.t_s);
      for (int k = 0; k < 3; ++k) message_.add_accel(x.accel[k]);
      for (int k = 0; k < 3; ++k) message_.add_gyro(x.gyro[k]);
      if (temp) message_.add_temp_c(x.temp);
    }
    offset_ += n;
    return true;
  }

  int64_t end_seq_ = 0;                      // guarded by mu_: the last batch to send
  int64_t after_seq_ = 0;                    // guarded by mu_: the last batch read from storage
  std::deque<storage::SampleBatch> page_;    // guarded by mu_: read, not yet decoded
  std::vector<storage::ImuSample> samples_;  // guarded by mu_: the batch being sent
  size_t offset_ = 0;                        // guarded by mu_: its first sample not yet sent
  int64_t seq_ = 0;                          // guarded by mu_: its seq
  v1::SampleBatch message_;                  // guarded by mu_; the one being written
};

}  // namespace

grpc::ServerWriteReactor<v1::SampleBatch>* StartReadSamples(const StreamEnv& env,
                                                            grpc::CallbackServerContext* context,
                                                            const v1::ReadSamplesRequest& request) {
  return ReadReactor::Open(env, context, Rpc::kReadSamples, request.session_id());
}

}  // namespace imucal::server
