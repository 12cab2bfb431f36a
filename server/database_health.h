// Whether the server can reach its database, as a monitor that pings it (Store::Ping) every
// `interval` on a thread of its own. The server's health follows it (grpc.health.v1: NOT_SERVING
// while the database is unreachable, SERVING again once it answers), the active-parameter
// fetch answers from its cache while it is down (ParameterSet.served_from_cache), and the
// imucal_database_up gauge reads it. Each change is logged once, with why the ping failed (for
// the operator; clients are told only "the calibration service's database is unavailable").
//
// Only an unreachable database counts as down (a ping that fails UNAVAILABLE): another error of
// a trivial query is logged but does not take the server out of its load balancer.
#ifndef IMUCAL_SERVER_DATABASE_HEALTH_H_
#define IMUCAL_SERVER_DATABASE_HEALTH_H_

#include <atomic>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <thread>

#include "absl/status/status.h"
#include "absl/time/time.h"

namespace imucal::server {

class DatabaseHealth {
 public:
  // `ping` reaches the database (Store::Ping); `on_change(up)` is called on the monitor's
  // thread at each change of state (not at the start: the database is up then, the server
  // having just opened it).
  DatabaseHealth(std::function<absl::Status()> ping, std::function<void(bool up)> on_change,
                 absl::Duration interval);
  ~DatabaseHealth();  // Stop()
  DatabaseHealth(const DatabaseHealth&) = delete;
  DatabaseHealth& operator=(const DatabaseHealth&) = delete;

  void Start();  // the monitor's thread; once
  void Stop();   // joins it; on_change is not called after it returns

  // The last ping's answer; true until a ping has failed. Any thread, lock-free.
  bool up() const { return up_.load(std::memory_order_relaxed); }

 private:
  void Run();
  void Check();

  const std::function<absl::Status()> ping_;
  const std::function<void(bool up)> on_change_;
  const absl::Duration interval_;
  std::atomic<bool> up_{true};
  std::mutex mu_;
  std::condition_variable cv_;
  bool stopping_ = false;  // guarded by mu_
  std::thread thread_;
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_DATABASE_HEALTH_H_
