// Streams a robot's raw samples to a calibration session (SessionService.StreamSamples) and
// survives dropped connections and server restarts.
//
// Protocol (imucal.proto): batches carry seq 1, 2, 3, ... per session; the server acknowledges
// the highest seq it has durably stored. A session holds one capture, so the session's stored
// sample count says where this capture resumes: on (re)connecting the Uploader reads GetSession
// (samples, last_acked_seq) and sends samples [samples, total) as batches last_acked_seq + 1,
// + 2, ... The first batch of a stream that continues a session carries the SHA-256 of this
// capture's first `samples` samples (SampleBatch.resume_sha256, sample_digest.h): the server
// refuses the stream when the session holds another capture's start, naming both
// (UploadOptions::source names this one). Uploading the same capture again to a session that
// already holds part of it resumes after the last acknowledged batch; every sample reaches the
// server exactly once.
//
// Retry policy (the CLI's `upload` is this Uploader on sdk::MakeChannel, so the same): a failed
// call or a dropped stream is retried until `retry_for` has passed without a batch
// acknowledged. Every call waits for the channel to be connected (gRPC wait-for-ready) rather
// than failing at once while the channel is between reconnect attempts, and MakeChannel caps
// those attempts' backoff (ClientOptions::max_reconnect_backoff, 2 s), so the upload goes on
// within seconds of the server coming back however long it was away. Between attempts that
// reached the server and failed (RESOURCE_EXHAUSTED while the server has not yet seen the
// previous stream end, a draining server) the Uploader backs off exponentially with +-20%
// jitter, so that a fleet does not retry in step. bench/outage_bench.cc measures the resume
// after outages of 0 to 60 s; tests/server/outage_test.cc kills the real server for as long.
//
// Batches are sent up to `max_in_flight` ahead of the acks (a writer thread; acks are read on
// the calling thread), so throughput does not wait on the round trip.
#ifndef IMUCAL_CLIENT_SDK_UPLOADER_H_
#define IMUCAL_CLIENT_SDK_UPLOADER_H_

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "core/capture.h"
#include "imucal/v1/imucal.grpc.pb.h"

namespace grpc {
class Channel;
class ClientContext;
}  // namespace grpc

namespace imucal::sdk {

// Raw samples as the wire's packed columns, in the device's input units.
struct SampleColumns {
  std::vector<double> t_s;     // seconds, strictly increasing
  std::vector<double> accel;   // 3 per sample: ax0, ay0, az0, ax1, ...
  std::vector<double> gyro;    // 3 per sample
  std::vector<double> temp_c;  // empty, or 1 per sample, degC
  int64_t size() const { return static_cast<int64_t>(t_s.size()); }
};

// The capture's samples as columns. Temperature is included when the capture has it in degC
// (a temperature in counts has no meaning to the server and is left out).
SampleColumns ColumnsFromCapture(const core::Capture& capture);

// Why a capture without a gyroscope (core::Capture::has_gyro false) is not uploaded: a session
// streams both sensors (proto SampleBatch), and the server's calibration needs the gyroscope.
inline constexpr char kNoGyroUploadMessage[] =
    "the capture has no gyroscope: the service's sessions stream accelerometer and gyroscope "
    "together; calibrate an accelerometer-only capture offline (imucal calibrate)";

struct UploadOptions {
  int batch_samples = 2000;  // samples per batch (the last one may be shorter)
  int max_in_flight = 8;     // batches sent and not yet acknowledged
  // 0: batches go as fast as the server acknowledges them (a backlog). X > 0: a batch is sent
  // no earlier than its last sample's t_s after the stream's first, divided by X, from the
  // stream's start: X = 1 streams as a robot does while it captures, X = 20 twenty times as
  // fast (to test beside a live guide without waiting the capture's length).
  double pace = 0;
  // The upload gives up when no batch has been acknowledged for this long (see the retry
  // policy above): a server restart of a minute, or several, is ridden out.
  absl::Duration retry_for = absl::Minutes(5);
  // Backoff between attempts: doubles from initial_backoff up to max_backoff, each wait
  // jittered by +-20%; back to initial_backoff after an attempt that stored something.
  absl::Duration initial_backoff = absl::Milliseconds(100);
  absl::Duration max_backoff = absl::Seconds(2);
  // Deadline of one GetSession call, including its wait for the channel to connect.
  absl::Duration call_deadline = absl::Seconds(10);
  // Deadline of one StreamSamples stream. A stream that reaches it ends with DEADLINE_EXCEEDED
  // and the upload resumes on a new one (a stalled server does not hold the robot for ever).
  absl::Duration stream_deadline = absl::Minutes(10);
  // The capture's name, sent as SampleBatch.source: a file name, a boot or capture label. The
  // session keeps the first stream's; a refusal to splice names both.
  std::string source;
  // Called on the calling thread after each acknowledgement: samples of this capture stored in
  // the session, and the capture's total.
  std::function<void(int64_t acked_samples, int64_t total_samples)> progress;
};

struct UploadResult {
  int64_t total_samples = 0;
  int64_t skipped_samples = 0;  // already in the session when Upload started (a resume)
  int64_t sent_samples = 0;     // acknowledged during this Upload
  int64_t last_acked_seq = 0;
  int reconnects = 0;  // attempts after the first (a dropped stream, a failed call)
};

class Uploader {
 public:
  explicit Uploader(std::shared_ptr<grpc::Channel> channel, UploadOptions options = {});
  ~Uploader();
  Uploader(const Uploader&) = delete;
  Uploader& operator=(const Uploader&) = delete;

  // Uploads `samples` into `session_id` (resuming if the session holds a prefix of them) and
  // returns when every sample is acknowledged. Errors: InvalidArgument for malformed columns or
  // options; FailedPrecondition if the session is not open, holds more samples than given, or
  // holds the start of another capture; the server's status for a non-retryable error
  // (INVALID_ARGUMENT, NOT_FOUND, ...); the last attempt's UNAVAILABLE or DEADLINE_EXCEEDED
  // once retry_for has passed without an acknowledgement; Cancelled after Cancel().
  absl::StatusOr<UploadResult> Upload(const std::string& session_id, const SampleColumns& samples);
  absl::StatusOr<UploadResult> Upload(const std::string& session_id, const core::Capture& capture);

  // Thread-safe. Stops the current Upload, which returns Cancelled (what was acknowledged stays
  // in the session; a later Upload resumes after it).
  void Cancel();
  // Thread-safe. Breaks the current stream as a network failure would; Upload reconnects and
  // resumes. For tests and for a robot's watchdog.
  void DropStream();

 private:
  struct Attempt;  // uploader.cc: what Upload carries from one attempt to the next
  bool Cancelled();
  // Where `session` (just read) stands for this capture: updates the resume digest and the
  // result's counts. True when it holds every sample already; FailedPrecondition when it cannot
  // take the rest (it holds more than this capture, or it is not open).
  absl::StatusOr<bool> CatchUp(const std::string& session_id, const imucal::v1::Session& session,
                               const SampleColumns& samples, Attempt* attempt,
                               UploadResult* result);
  // After an attempt that failed with `failed`: OK once the backoff has been waited (the next
  // attempt may go), else what Upload returns (Cancelled, a status no retry cures, or the give-up
  // after retry_for without an acknowledgement).
  absl::Status BackOff(const std::string& session_id, const absl::Status& failed, bool stored_some,
                       Attempt* attempt, UploadResult* result);
  // One stream: samples [first_sample, total) as batches first_seq, ...; the first batch
  // carries `resume_sha256` (empty when the session holds nothing).
  absl::Status StreamOnce(const std::string& session_id, const SampleColumns& samples,
                          int64_t first_sample, int64_t first_seq, const std::string& resume_sha256,
                          UploadResult* result);
  absl::StatusOr<imucal::v1::Session> GetSession(const std::string& session_id);
  bool WaitBackoff(absl::Duration backoff);   // false when cancelled meanwhile
  absl::Duration Jittered(absl::Duration d);  // d times a uniform factor in [0.8, 1.2]

  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<imucal::v1::SessionService::Stub> stub_;
  UploadOptions options_;

  std::mt19937_64 rng_;  // the backoff's jitter; used by Upload's thread only
  std::mutex mu_;
  std::condition_variable cancel_cv_;
  bool cancelled_ = false;                         // guarded by mu_
  grpc::ClientContext* stream_context_ = nullptr;  // guarded by mu_
};

}  // namespace imucal::sdk

#endif  // IMUCAL_CLIENT_SDK_UPLOADER_H_
