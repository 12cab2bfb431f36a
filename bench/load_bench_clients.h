// The load test's clients (load_bench.cc): robots streaming paced batches, technicians watching
// sessions, fleet startup fetches, as gRPC callback reactors that tally into one Stats.
#ifndef IMUCAL_BENCH_LOAD_BENCH_CLIENTS_H_
#define IMUCAL_BENCH_LOAD_BENCH_CLIENTS_H_

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "bench/service_bench_util.h"
#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/log.h"

namespace imucal::bench {

// Batch `seq` (1-based) of `per` samples: samples [(seq-1)*per, seq*per) of the replayed
// capture, started at `offset` samples (robots start at different points of the capture).
void FillBatch(const Columns& col, int per, int64_t seq, int64_t offset, v1::SampleBatch* b) {
  b->clear_t_s();
  b->clear_accel();
  b->clear_gyro();
  b->clear_temp_c();
  b->set_seq(seq);
  const int64_t first = offset + (seq - 1) * per;
  for (int j = 0; j < per; ++j) {
    const int64_t g = first + j;
    const size_t i = static_cast<size_t>(g % static_cast<int64_t>(col.n));
    const double shift = static_cast<double>(g / static_cast<int64_t>(col.n)) * col.lap_s;
    b->add_t_s(col.t[i] + shift);
    b->add_temp_c(col.temp[i]);
    for (int k = 0; k < 3; ++k) {
      b->add_accel(col.accel[3 * i + k]);
      b->add_gyro(col.gyro[3 * i + k]);
    }
  }
}

// ---- Results shared by every reactor.
struct Stats {
  std::mutex mu;
  std::condition_variable cv;
  std::vector<double> ack_us, fetch_us, event_us;  // guarded by mu
  std::map<std::string, int64_t> errors;           // "what CODE" -> count; guarded by mu
  std::string first_error;                         // guarded by mu
  int64_t acked_batches = 0, acked_samples = 0, sent_batches = 0, late_sends = 0;
  int64_t max_behind = 0;  // most batches a robot was behind its schedule
  int64_t events = 0, fetches_sent = 0, fetches_done = 0, fetch_bytes = 0;
  int robots_running = 0, watchers_running = 0, fetches_in_flight = 0;  // guarded by mu

  void Error(const std::string& what, const grpc::Status& s) {
    errors[absl::StrCat(what, " ", std::string(imucal::server::CodeName(s.error_code())))]++;
    if (first_error.empty()) first_error = absl::StrCat(what, ": ", s.error_message());
  }
};

// One robot: a StreamSamples stream; Due() (from the pacer) queues the next batch, written
// as soon as the previous write is done. Latency: StartWrite of seq -> the ack covering seq.
class Robot final : public grpc::ClientBidiReactor<v1::SampleBatch, v1::SampleAck> {
 public:
  Robot(Stats* stats, const Columns* col, int per, v1::SessionService::Stub* stub,
        std::string session_id, int64_t offset)
      : stats_(stats),
        col_(col),
        per_(per),
        stub_(stub),
        session_id_(std::move(session_id)),
        offset_(offset) {
    ack_us_.reserve(1 << 12);
  }

  void Start() {
    stub_->async()->StreamSamples(&context_, this);
    StartRead(&ack_);
    StartCall();
  }

  // The pacer's tick for this robot: one more batch is due.
  void Due() {
    std::lock_guard lock(mu_);
    if (stopping_) return;
    ++due_;
    if (writing_) ++late_;
    max_behind_ = std::max(max_behind_, due_);
    MaybeWriteLocked();
  }

  // At the deadline: no more batches; half-close once the last write is done.
  void Stop() {
    std::lock_guard lock(mu_);
    stopping_ = true;
    due_ = 0;
    MaybeWriteLocked();
  }

  void OnWriteDone(bool ok) override {
    std::lock_guard lock(mu_);
    writing_ = false;
    if (ok) MaybeWriteLocked();
  }

  void OnReadDone(bool ok) override {
    if (!ok) return;  // the server finished: OnDone follows
    const Clock::time_point now = Clock::now();
    {
      std::lock_guard lock(mu_);
      while (!sent_at_.empty() && first_unacked_ <= ack_.last_acked_seq()) {
        ack_us_.push_back(1e6 * Seconds(now - sent_at_.front()));
        sent_at_.pop_front();
        ++first_unacked_;
        ++acked_batches_;
      }
      acked_samples_ = ack_.samples();
    }
    StartRead(&ack_);
  }

  void OnDone(const grpc::Status& status) override {
    std::lock_guard lock(stats_->mu);
    if (!status.ok()) stats_->Error("StreamSamples", status);
    stats_->ack_us.insert(stats_->ack_us.end(), ack_us_.begin(), ack_us_.end());
    stats_->acked_batches += acked_batches_;
    stats_->acked_samples += acked_samples_;
    stats_->sent_batches += next_seq_ - 1;
    stats_->late_sends += late_;
    stats_->max_behind = std::max(stats_->max_behind, max_behind_);
    --stats_->robots_running;
    stats_->cv.notify_all();
  }

 private:
  void MaybeWriteLocked() {
    if (writing_ || writes_done_) return;
    if (due_ == 0) {
      if (stopping_) {
        writes_done_ = true;
        StartWritesDone();
      }
      return;
    }
    --due_;
    if (next_seq_ == 1)
      batch_.set_session_id(session_id_);
    else
      batch_.clear_session_id();
    FillBatch(*col_, per_, next_seq_, offset_, &batch_);
    sent_at_.push_back(Clock::now());
    ++next_seq_;
    writing_ = true;
    StartWrite(&batch_);
  }

  Stats* stats_;
  const Columns* col_;
  int per_;
  v1::SessionService::Stub* stub_;
  std::string session_id_;
  int64_t offset_;
  grpc::ClientContext context_;
  v1::SampleAck ack_;  // the read path only

  std::mutex mu_;
  v1::SampleBatch batch_;  // guarded by mu_; untouched while a write is in flight
  bool writing_ = false, writes_done_ = false, stopping_ = false;
  int64_t due_ = 0, late_ = 0, max_behind_ = 0;
  int64_t next_seq_ = 1, first_unacked_ = 1;
  std::deque<Clock::time_point> sent_at_;  // batches first_unacked_, first_unacked_ + 1, ...
  int64_t acked_batches_ = 0, acked_samples_ = 0;
  std::vector<double> ack_us_;
};

// A technician following a session: WatchSession until cancelled at the end.
class Watcher final : public grpc::ClientReadReactor<v1::SessionEvent> {
 public:
  Watcher(Stats* stats, v1::SessionService::Stub* stub, const std::string& session_id)
      : stats_(stats) {
    request_.set_session_id(session_id);
    stub->async()->WatchSession(&context_, &request_, this);
  }
  void Start() {
    StartRead(&event_);
    StartCall();
  }
  void Stop() {
    stopped_ = true;
    context_.TryCancel();
  }

  void OnReadDone(bool ok) override {
    if (!ok) return;
    const absl::Time sent =
        absl::FromUnixSeconds(event_.time().seconds()) + absl::Nanoseconds(event_.time().nanos());
    delays_us_.push_back(absl::ToDoubleMicroseconds(absl::Now() - sent));
    StartRead(&event_);
  }

  void OnDone(const grpc::Status& status) override {
    std::lock_guard lock(stats_->mu);
    if (!status.ok() && !(stopped_ && status.error_code() == grpc::StatusCode::CANCELLED))
      stats_->Error("WatchSession", status);
    stats_->events += static_cast<int64_t>(delays_us_.size());
    stats_->event_us.insert(stats_->event_us.end(), delays_us_.begin(), delays_us_.end());
    --stats_->watchers_running;
    stats_->cv.notify_all();
  }

 private:
  Stats* stats_;
  grpc::ClientContext context_;
  v1::WatchSessionRequest request_;
  v1::SessionEvent event_;
  std::atomic<bool> stopped_{false};
  std::vector<double> delays_us_;  // the reactor's reads are serialised
};

// One robot's startup fetch: GetActiveParameters, deletes itself when done.
class Fetch {
 public:
  static void Send(Stats* stats, v1::ParameterService::Stub* stub, const std::string& device) {
    auto* f = new Fetch(stats);
    f->request_.set_device_id(device);
    f->context_.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    f->start_ = Clock::now();
    stub->async()->GetActiveParameters(&f->context_, &f->request_, &f->response_,
                                       [f](grpc::Status s) { f->Done(s); });
  }

 private:
  explicit Fetch(Stats* stats) : stats_(stats) {}
  void Done(const grpc::Status& status) {
    const double us = 1e6 * Seconds(Clock::now() - start_);
    {
      std::lock_guard lock(stats_->mu);
      if (status.ok()) {
        stats_->fetch_us.push_back(us);
        stats_->fetch_bytes += static_cast<int64_t>(response_.json().size());
      } else {
        stats_->Error("GetActiveParameters", status);
      }
      ++stats_->fetches_done;
      --stats_->fetches_in_flight;
      stats_->cv.notify_all();
    }
    delete this;
  }

  Stats* stats_;
  grpc::ClientContext context_;
  v1::GetActiveParametersRequest request_;
  v1::ParameterSet response_;
  Clock::time_point start_;
};

}  // namespace imucal::bench

#endif  // IMUCAL_BENCH_LOAD_BENCH_CLIENTS_H_
