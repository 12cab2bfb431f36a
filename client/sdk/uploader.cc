#include "client/sdk/uploader.h"

#include <algorithm>
#include <cmath>
#include <condition_variable>
#include <mutex>
#include <thread>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/sdk/grpc_status.h"
#include "formats/sample_digest.h"
#include "grpcpp/grpcpp.h"

namespace imucal::sdk {
namespace {

namespace pb = imucal::v1;
using formats::SampleDigest;

absl::Status CheckColumns(const SampleColumns& s) {
  const size_t n = s.t_s.size();
  if (s.accel.size() != 3 * n || s.gyro.size() != 3 * n)
    return absl::InvalidArgumentError("samples: accel and gyro need 3 values per sample");
  if (!s.temp_c.empty() && s.temp_c.size() != n)
    return absl::InvalidArgumentError("samples: temp_c needs 0 or 1 value per sample");
  return absl::OkStatus();
}

absl::Status CheckOptions(const UploadOptions& o) {
  if (o.batch_samples < 1) return absl::InvalidArgumentError("batch_samples must be >= 1");
  if (o.max_in_flight < 1) return absl::InvalidArgumentError("max_in_flight must be >= 1");
  if (!(o.pace >= 0) || !std::isfinite(o.pace))
    return absl::InvalidArgumentError("pace must be 0 or a positive number");
  if (o.retry_for < absl::ZeroDuration())
    return absl::InvalidArgumentError("retry_for must not be negative");
  return absl::OkStatus();
}

// Codes after which the same batches may be sent again on a new stream: the connection broke
// or the server went away (or ended a stream it found idle); the session's last_acked_seq says
// what survived. RESOURCE_EXHAUSTED too: after a reconnect the server may not have ended this
// device's previous stream yet (one stream per device), and backing off lets it.
bool IsRetryable(const absl::Status& s) {
  return absl::IsUnavailable(s) || absl::IsDeadlineExceeded(s) || absl::IsAborted(s) ||
         absl::IsCancelled(s) || absl::IsUnknown(s) || absl::IsResourceExhausted(s);
}

// Adds samples [begin, end) of `s` to `digest`.
void AddToDigest(const SampleColumns& s, int64_t begin, int64_t end, SampleDigest* digest) {
  const bool temp = !s.temp_c.empty();
  for (int64_t i = begin; i < end; ++i) {
    const size_t k = static_cast<size_t>(i);
    digest->AddSample(s.t_s[k], &s.accel[3 * k], &s.gyro[3 * k], temp ? &s.temp_c[k] : nullptr);
  }
}

pb::SampleBatch MakeBatch(const std::string& session_id, const SampleColumns& s, int64_t begin,
                          int64_t end, int64_t seq) {
  pb::SampleBatch b;
  b.set_session_id(session_id);
  b.set_seq(seq);
  b.mutable_t_s()->Add(s.t_s.begin() + begin, s.t_s.begin() + end);
  b.mutable_accel()->Add(s.accel.begin() + 3 * begin, s.accel.begin() + 3 * end);
  b.mutable_gyro()->Add(s.gyro.begin() + 3 * begin, s.gyro.begin() + 3 * end);
  if (!s.temp_c.empty()) b.mutable_temp_c()->Add(s.temp_c.begin() + begin, s.temp_c.begin() + end);
  return b;
}

// One stream's share of the upload: samples [first_sample, total) as batches first_seq ..
// last_seq of batch_samples each (the last one may be shorter).
struct StreamPlan {
  int64_t total = 0;
  int64_t batch_samples = 0;
  int64_t first_sample = 0;
  int64_t first_seq = 0;
  int64_t batches = 0;
  int64_t last_seq = 0;
};

// What the writer thread and the reading thread of one stream share.
struct StreamWindow {
  std::mutex mu;
  std::condition_variable cv;
  int64_t acked_seq = 0;      // guarded by mu
  bool reading_done = false;  // guarded by mu
};

// The writer thread of a stream: sends the plan's batches, each up to options.max_in_flight
// ahead of the acks and (options.pace > 0) no earlier than its last sample was captured,
// counted from `started`; then WritesDone. Stops early when the reading side is done or a
// write fails. The first batch carries `resume_sha256` and the capture's source.
void WriteBatches(grpc::ClientReaderWriter<pb::SampleBatch, pb::SampleAck>* stream,
                  const std::string& session_id, const SampleColumns& samples,
                  const StreamPlan& plan, const UploadOptions& options,
                  const std::string& resume_sha256, absl::Time started, StreamWindow* window) {
  for (int64_t k = 0; k < plan.batches; ++k) {
    const int64_t seq = plan.first_seq + k;
    const int64_t begin = plan.first_sample + k * plan.batch_samples;
    const int64_t end = std::min(plan.total, begin + plan.batch_samples);
    {
      std::unique_lock<std::mutex> lock(window->mu);
      window->cv.wait(lock, [&] {
        return window->reading_done || seq - window->acked_seq <= options.max_in_flight;
      });
      if (options.pace > 0) {  // the batch's last sample has been captured
        const double capture_s = samples.t_s[static_cast<size_t>(end - 1)] -
                                 samples.t_s[static_cast<size_t>(plan.first_sample)];
        window->cv.wait_until(lock,
                              absl::ToChronoTime(started + absl::Seconds(capture_s / options.pace)),
                              [&] { return window->reading_done; });
      }
      if (window->reading_done) return;
    }
    pb::SampleBatch batch = MakeBatch(session_id, samples, begin, end, seq);
    if (k == 0) {
      batch.set_resume_sha256(resume_sha256);
      batch.set_source(options.source);
    }
    if (!stream->Write(batch)) return;
  }
  stream->WritesDone();
}

}  // namespace

SampleColumns ColumnsFromCapture(const core::Capture& capture) {
  SampleColumns s;
  const size_t n = capture.size();
  s.t_s = capture.t_s;
  s.accel.reserve(3 * n);
  s.gyro.reserve(3 * n);
  for (size_t i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) s.accel.push_back(capture.accel[i][k]);
    if (capture.has_gyro) {  // else none: Upload refuses a capture without a gyroscope
      for (int k = 0; k < 3; ++k) s.gyro.push_back(capture.gyro[i][k]);
    }
  }
  if (capture.has_temp() && capture.temp_unit == core::TempUnit::kCelsius) s.temp_c = capture.temp;
  return s;
}

Uploader::Uploader(std::shared_ptr<grpc::Channel> channel, UploadOptions options)
    : channel_(std::move(channel)),
      stub_(pb::SessionService::NewStub(channel_)),
      options_(std::move(options)),
      rng_(std::random_device{}()) {}

Uploader::~Uploader() = default;

void Uploader::Cancel() {
  std::lock_guard<std::mutex> lock(mu_);
  cancelled_ = true;
  if (stream_context_ != nullptr) stream_context_->TryCancel();
  cancel_cv_.notify_all();
}

void Uploader::DropStream() {
  std::lock_guard<std::mutex> lock(mu_);
  if (stream_context_ != nullptr) stream_context_->TryCancel();
}

absl::Duration Uploader::Jittered(absl::Duration d) {
  return d * std::uniform_real_distribution<double>(0.8, 1.2)(rng_);
}

bool Uploader::WaitBackoff(absl::Duration backoff) {
  std::unique_lock<std::mutex> lock(mu_);
  return !cancel_cv_.wait_for(lock, absl::ToChronoNanoseconds(backoff),
                              [this] { return cancelled_; });
}

absl::StatusOr<pb::Session> Uploader::GetSession(const std::string& session_id) {
  grpc::ClientContext context;
  context.set_wait_for_ready(true);  // through a restart: wait for the channel, not fail
  context.set_deadline(absl::ToChronoTime(absl::Now() + options_.call_deadline));
  pb::GetSessionRequest request;
  request.set_session_id(session_id);
  pb::Session session;
  if (grpc::Status s = stub_->GetSession(&context, request, &session); !s.ok())
    return FromGrpcStatus(s);
  return session;
}

absl::StatusOr<UploadResult> Uploader::Upload(const std::string& session_id,
                                              const core::Capture& capture) {
  if (!capture.has_gyro) return absl::InvalidArgumentError(kNoGyroUploadMessage);
  return Upload(session_id, ColumnsFromCapture(capture));
}

// What Upload carries from one attempt to the next.
struct Uploader::Attempt {
  explicit Attempt(const UploadOptions& options)
      : backoff(options.initial_backoff), last_progress(absl::Now()) {}
  bool first = true;
  absl::Duration backoff;
  absl::Time last_progress;  // of the last attempt that stored something, or the start
  // The digest of this capture's first `digested` samples: what the session must hold to be
  // continued.
  SampleDigest digest;
  int64_t digested = 0;
};

bool Uploader::Cancelled() {
  std::lock_guard<std::mutex> lock(mu_);
  return cancelled_;
}

absl::StatusOr<bool> Uploader::CatchUp(const std::string& session_id, const pb::Session& session,
                                       const SampleColumns& samples, Attempt* attempt,
                                       UploadResult* result) {
  const int64_t stored = session.samples();
  if (stored > samples.size()) {
    return absl::FailedPreconditionError(
        absl::StrFormat("session %s already holds %d samples, more than the %d of this capture",
                        session_id, stored, samples.size()));
  }
  if (stored < attempt->digested) {  // never in practice: what the server holds only grows
    attempt->digest = SampleDigest();
    attempt->digested = 0;
  }
  if (stored > attempt->digested) {
    AddToDigest(samples, attempt->digested, stored, &attempt->digest);
    attempt->digested = stored;
  }
  if (attempt->first) result->skipped_samples = stored;
  attempt->first = false;
  result->last_acked_seq = session.last_acked_seq();
  if (stored == samples.size()) {
    if (options_.progress) options_.progress(stored, samples.size());
    return true;
  }
  if (session.state() != pb::SESSION_STATE_OPEN) {
    return absl::FailedPreconditionError(
        absl::StrFormat("session %s is %s and takes no more samples", session_id,
                        absl::AsciiStrToLower(pb::SessionState_Name(session.state()).substr(14))));
  }
  return false;
}

absl::Status Uploader::BackOff(const std::string& session_id, const absl::Status& failed,
                               bool stored_some, Attempt* attempt, UploadResult* result) {
  if (Cancelled()) return absl::CancelledError("upload cancelled");
  if (!IsRetryable(failed)) return failed;
  const absl::Time now = absl::Now();
  if (stored_some) {
    attempt->last_progress = now;
    attempt->backoff = options_.initial_backoff;
  }
  if (now - attempt->last_progress >= options_.retry_for) {
    return absl::Status(
        failed.code(),
        absl::StrFormat("upload to session %s gave up after %s without an acknowledgement (%d "
                        "attempts): %s",
                        session_id, absl::FormatDuration(options_.retry_for),
                        result->reconnects + 1, failed.message()));
  }
  const absl::Duration wait =
      std::min(Jittered(attempt->backoff), attempt->last_progress + options_.retry_for - now);
  if (!WaitBackoff(wait)) return absl::CancelledError("upload cancelled");
  attempt->backoff = std::min(attempt->backoff * 2, options_.max_backoff);
  ++result->reconnects;
  return absl::OkStatus();
}

absl::StatusOr<UploadResult> Uploader::Upload(const std::string& session_id,
                                              const SampleColumns& samples) {
  if (absl::Status s = CheckColumns(samples); !s.ok()) return s;
  if (absl::Status s = CheckOptions(options_); !s.ok()) return s;
  {
    std::lock_guard<std::mutex> lock(mu_);
    cancelled_ = false;
  }
  UploadResult result;
  result.total_samples = samples.size();
  Attempt attempt(options_);
  for (;;) {
    if (Cancelled()) return absl::CancelledError("upload cancelled");
    const int64_t sent_before = result.sent_samples;
    absl::Status failed;
    if (absl::StatusOr<pb::Session> session = GetSession(session_id); !session.ok()) {
      failed = session.status();
    } else {
      absl::StatusOr<bool> complete = CatchUp(session_id, *session, samples, &attempt, &result);
      if (!complete.ok()) return complete.status();
      if (*complete) return result;
      const int64_t stored = session->samples();
      // The proof that this capture is the one the session holds (the server checks it).
      const std::string resume = stored > 0 ? attempt.digest.Sha256() : std::string();
      failed =
          StreamOnce(session_id, samples, stored, session->last_acked_seq() + 1, resume, &result);
      if (failed.ok()) return result;
    }
    if (absl::Status s =
            BackOff(session_id, failed, result.sent_samples > sent_before, &attempt, &result);
        !s.ok())
      return s;
  }
}

absl::Status Uploader::StreamOnce(const std::string& session_id, const SampleColumns& samples,
                                  int64_t first_sample, int64_t first_seq,
                                  const std::string& resume_sha256, UploadResult* result) {
  StreamPlan plan;
  plan.total = samples.size();
  plan.batch_samples = options_.batch_samples;
  plan.first_sample = first_sample;
  plan.first_seq = first_seq;
  plan.batches = (plan.total - first_sample + plan.batch_samples - 1) / plan.batch_samples;
  plan.last_seq = first_seq + plan.batches - 1;

  grpc::ClientContext context;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (cancelled_) return absl::CancelledError("upload cancelled");
    stream_context_ = &context;
  }
  context.set_wait_for_ready(true);
  context.set_deadline(absl::ToChronoTime(absl::Now() + options_.stream_deadline));
  auto stream = stub_->StreamSamples(&context);

  StreamWindow window;
  window.acked_seq = first_seq - 1;
  const absl::Time started = absl::Now();
  std::thread writer([&] {
    WriteBatches(stream.get(), session_id, samples, plan, options_, resume_sha256, started,
                 &window);
  });

  pb::SampleAck ack;
  while (stream->Read(&ack)) {
    const int64_t seq = std::min(ack.last_acked_seq(), plan.last_seq);
    const int64_t acked_samples =
        std::min(plan.total, first_sample + (seq - first_seq + 1) * plan.batch_samples);
    {
      std::lock_guard<std::mutex> lock(window.mu);
      if (seq <= window.acked_seq) continue;
      window.acked_seq = seq;
    }
    window.cv.notify_all();
    result->sent_samples = acked_samples - result->skipped_samples;
    result->last_acked_seq = seq;
    if (options_.progress) options_.progress(acked_samples, plan.total);
  }
  {
    std::lock_guard<std::mutex> lock(window.mu);
    window.reading_done = true;
  }
  window.cv.notify_all();
  writer.join();
  const grpc::Status finish = stream->Finish();
  {
    std::lock_guard<std::mutex> lock(mu_);
    stream_context_ = nullptr;
  }
  if (!finish.ok()) return FromGrpcStatus(finish);
  if (window.acked_seq < plan.last_seq) {
    return absl::UnavailableError(absl::StrFormat(
        "the stream ended with batch %d of %d acknowledged", window.acked_seq, plan.last_seq));
  }
  return absl::OkStatus();
}
}  // namespace imucal::sdk
