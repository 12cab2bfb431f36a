// Streams a robot's raw samples to a calibration session (SessionService.StreamSamples) and
// survives dropped connections.
//
// Protocol (imucal.proto): batches carry seq 1, 2, 3, ... per session; the server acknowledges
// the highest seq it has durably stored. A session holds one capture, so the session's stored
// sample count says where this capture resumes: on (re)connecting the Uploader reads GetSession
// (samples, last_acked_seq) and sends samples [samples, total) as batches last_acked_seq + 1,
// + 2, ... Uploading the same capture again to a session that already holds part of it resumes
// after the last acknowledged batch; every sample reaches the server exactly once.
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

struct UploadOptions {
  int batch_samples = 2000;  // samples per batch (the last one may be shorter)
  int max_in_flight = 8;     // batches sent and not yet acknowledged
  // Reconnects after a dropped stream, counted since the last attempt that made progress.
  int max_retries = 5;
  absl::Duration initial_backoff = absl::Milliseconds(200);  // doubles per retry
  absl::Duration max_backoff = absl::Seconds(5);
  absl::Duration call_deadline = absl::Seconds(10);  // for GetSession
  // Deadline of one StreamSamples stream. A stream that reaches it ends with DEADLINE_EXCEEDED
  // and the upload resumes on a new one (a stalled server does not hold the robot for ever).
  absl::Duration stream_deadline = absl::Minutes(10);
  // Called on the calling thread after each acknowledgement: samples of this capture stored in
  // the session, and the capture's total.
  std::function<void(int64_t acked_samples, int64_t total_samples)> progress;
};

struct UploadResult {
  int64_t total_samples = 0;
  int64_t skipped_samples = 0;  // already in the session when Upload started (a resume)
  int64_t sent_samples = 0;     // acknowledged during this Upload
  int64_t last_acked_seq = 0;
  int reconnects = 0;  // streams re-opened after a drop
};

class Uploader {
 public:
  explicit Uploader(std::shared_ptr<grpc::Channel> channel, UploadOptions options = {});
  ~Uploader();
  Uploader(const Uploader&) = delete;
  Uploader& operator=(const Uploader&) = delete;

  // Uploads `samples` into `session_id` (resuming if the session holds a prefix of them) and
  // returns when every sample is acknowledged. Errors: InvalidArgument for malformed columns or
  // options; FailedPrecondition if the session is not open or holds more samples than given;
  // the server's status for a non-retryable error (INVALID_ARGUMENT, NOT_FOUND, ...);
  // UNAVAILABLE after max_retries reconnects without progress; Cancelled after Cancel().
  absl::StatusOr<UploadResult> Upload(const std::string& session_id, const SampleColumns& samples);
  absl::StatusOr<UploadResult> Upload(const std::string& session_id, const core::Capture& capture);

  // Thread-safe. Stops the current Upload, which returns Cancelled (what was acknowledged stays
  // in the session; a later Upload resumes after it).
  void Cancel();
  // Thread-safe. Breaks the current stream as a network failure would; Upload reconnects and
  // resumes. For tests and for a robot's watchdog.
  void DropStream();

 private:
  struct Attempt;
  absl::Status StreamOnce(const std::string& session_id, const SampleColumns& samples,
                          int64_t first_sample, int64_t first_seq, UploadResult* result);
  absl::StatusOr<imucal::v1::Session> GetSession(const std::string& session_id);
  bool WaitBackoff(absl::Duration backoff);  // false when cancelled meanwhile

  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<imucal::v1::SessionService::Stub> stub_;
  UploadOptions options_;

  std::mutex mu_;
  std::condition_variable cancel_cv_;
  bool cancelled_ = false;                         // guarded by mu_
  grpc::ClientContext* stream_context_ = nullptr;  // guarded by mu_
};

}  // namespace imucal::sdk

#endif  // IMUCAL_CLIENT_SDK_UPLOADER_H_
