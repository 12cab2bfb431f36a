// A bounded worker pool for solve jobs: `threads` workers, at most `queue_limit` jobs waiting.
// Shutdown() stops new submissions, lets the workers finish every queued job, and joins them.
#ifndef IMUCAL_SERVER_SOLVE_POOL_H_
#define IMUCAL_SERVER_SOLVE_POOL_H_

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace imucal::server {

class SolvePool {
 public:
  SolvePool(int threads, size_t queue_limit);
  ~SolvePool();  // Shutdown()
  SolvePool(const SolvePool&) = delete;
  SolvePool& operator=(const SolvePool&) = delete;

  // Reserves a queue slot; false when the queue is full or the pool is shutting down. A
  // reservation must be followed by exactly one Submit() or Release().
  bool Reserve();
  void Release();
  void Submit(std::function<void()> job);  // uses a reservation

  void Shutdown();

  size_t queued();  // jobs waiting for a worker (not those running)

 private:
  void Work();

  const size_t queue_limit_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> queue_;  // guarded by mu_
  size_t reserved_ = 0;                      // guarded by mu_
  bool stopping_ = false;                    // guarded by mu_
  std::vector<std::thread> workers_;
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_SOLVE_POOL_H_
