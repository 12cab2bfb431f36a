#include "server/solve_pool.h"

#include <utility>

namespace imucal::server {

SolvePool::SolvePool(int threads, size_t queue_limit) : queue_limit_(queue_limit) {
  for (int i = 0; i < threads; ++i) workers_.emplace_back([this] { Work(); });
}

SolvePool::~SolvePool() { Shutdown(); }

bool SolvePool::Reserve() {
  std::lock_guard lock(mu_);
  if (stopping_ || queue_.size() + reserved_ >= queue_limit_) return false;
  ++reserved_;
  return true;
}

size_t SolvePool::queued() {
  std::lock_guard lock(mu_);
  return queue_.size();
}

void SolvePool::Release() {
  std::lock_guard lock(mu_);
  --reserved_;
}

void SolvePool::Submit(std::function<void()> job) {
  {
    std::lock_guard lock(mu_);
    --reserved_;
    queue_.push_back(std::move(job));
  }
  cv_.notify_one();
}

void SolvePool::Shutdown() {
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  cv_.notify_all();
  for (std::thread& t : workers_)
    if (t.joinable()) t.join();
}

void SolvePool::Work() {
  for (;;) {
    std::function<void()> job;
    {
      std::unique_lock lock(mu_);
      cv_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (queue_.empty()) return;  // stopping, and every queued job is done
      job = std::move(queue_.front());
      queue_.pop_front();
    }
    job();
  }
}

}  // namespace imucal::server
