// A WatchSession stream read on its own thread (as `imucal guide` reads it), for tests that
// wait on a session's live events with a deadline instead of sleeping.
#ifndef IMUCAL_TESTS_SERVER_WATCH_H_
#define IMUCAL_TESTS_SERVER_WATCH_H_

#include <chrono>
#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"

namespace imucal::testing_util {

class Watch {
 public:
  Watch(v1::SessionService::Stub* stub, const std::string& session_id) {
    ctx_.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    v1::WatchSessionRequest req;
    req.set_session_id(session_id);
    reader_ = stub->WatchSession(&ctx_, req);
    thread_ = std::thread([this] {
      v1::SessionEvent e;
      while (reader_->Read(&e)) {
        std::lock_guard lock(mu_);
        events_.push_back(e);
        cv_.notify_all();
      }
      grpc::Status s = reader_->Finish();
      std::lock_guard lock(mu_);
      status_ = s;
      ended_ = true;
      cv_.notify_all();
    });
  }
  ~Watch() {
    ctx_.TryCancel();
    thread_.join();
  }
  // Waits until pred(events, ended) holds; false on timeout.
  bool WaitFor(const std::function<bool(const std::vector<v1::SessionEvent>&, bool)>& pred,
               std::chrono::seconds timeout = std::chrono::seconds(20)) {
    std::unique_lock lock(mu_);
    return cv_.wait_for(lock, timeout, [&] { return pred(events_, ended_); });
  }
  std::vector<v1::SessionEvent> events() {
    std::lock_guard lock(mu_);
    return events_;
  }
  grpc::Status status() {
    std::lock_guard lock(mu_);
    return status_;
  }

 private:
  grpc::ClientContext ctx_;
  std::unique_ptr<grpc::ClientReader<v1::SessionEvent>> reader_;
  std::thread thread_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::vector<v1::SessionEvent> events_;
  bool ended_ = false;
  grpc::Status status_;
};

// Follows the session's event stream until the server ends it (the session closed: solved,
// cancelled, failed) or `timeout` passes; the stream's final status.
inline grpc::Status FollowToEnd(v1::SessionService::Stub* stub, const std::string& session_id,
                                std::chrono::seconds timeout) {
  grpc::ClientContext c;
  c.set_deadline(std::chrono::system_clock::now() + timeout);
  v1::WatchSessionRequest req;
  req.set_session_id(session_id);
  auto reader = stub->WatchSession(&c, req);
  v1::SessionEvent e;
  while (reader->Read(&e)) {
  }
  return reader->Finish();
}

// Follows the session's events until it is no longer solving (a solve another server, or this
// one after its restart, runs on its own: Store::ClaimLapsedSolve) or the server ends the
// watch; false when `timeout` passes first. The watch's first event is the session as it is,
// so a solve that ended before the watch began is seen too, whatever the session's state after.
inline bool FollowWhileSolving(v1::SessionService::Stub* stub, const std::string& session_id,
                               std::chrono::seconds timeout) {
  Watch watch(stub, session_id);
  return watch.WaitFor(
      [](const std::vector<v1::SessionEvent>& events, bool ended) {
        if (ended) return true;
        for (const v1::SessionEvent& e : events)
          if (e.has_session() && e.session().state() != v1::SESSION_STATE_SOLVING) return true;
        return false;
      },
      timeout);
}

inline int AcceptedPoses(const std::vector<v1::SessionEvent>& events) {
  int n = 0;
  for (const auto& e : events) n += e.has_pose() && e.pose().accepted();
  return n;
}

}  // namespace imucal::testing_util

#endif  // IMUCAL_TESTS_SERVER_WATCH_H_
