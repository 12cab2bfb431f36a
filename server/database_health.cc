#include "server/database_health.h"

#include <string>
#include <utility>

#include "absl/time/clock.h"
#include "server/log.h"

namespace imucal::server {

DatabaseHealth::DatabaseHealth(std::function<absl::Status()> ping,
                               std::function<void(bool up)> on_change, absl::Duration interval)
    : ping_(std::move(ping)), on_change_(std::move(on_change)), interval_(interval) {}

DatabaseHealth::~DatabaseHealth() { Stop(); }

void DatabaseHealth::Start() {
  if (thread_.joinable()) return;
  thread_ = std::thread([this] { Run(); });
}

void DatabaseHealth::Stop() {
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void DatabaseHealth::Run() {
  std::unique_lock lock(mu_);
  while (!stopping_) {
    cv_.wait_for(lock, absl::ToChronoNanoseconds(interval_), [this] { return stopping_; });
    if (stopping_) break;
    lock.unlock();
    Check();
    lock.lock();
  }
}

void DatabaseHealth::Check() {
  const absl::Time started = absl::Now();
  const absl::Status status = ping_();
  const bool up = !absl::IsUnavailable(status);
  if (!status.ok() && up) {
    Log(LogLevel::kWarning, "database_ping",
        {{"error", std::string(status.message())}, {"note", "answered, with an error"}});
  }
  if (up == up_.load(std::memory_order_relaxed)) return;
  up_.store(up, std::memory_order_relaxed);
  if (up) {
    Log(LogLevel::kInfo, "database_reachable",
        {{"note", "the database answers again: health SERVING"}});
  } else {
    Log(LogLevel::kError, "database_unreachable",
        {{"error", std::string(status.message())},
         {"ping_ms", absl::ToInt64Milliseconds(absl::Now() - started)},
         {"note",
          "health NOT_SERVING until it answers; parameter fetches are answered from the "
          "cache, marked served_from_cache"}});
  }
  on_change_(up);
}

}  // namespace imucal::server
