// ParallelFor: the independent steps of one computation on a few threads, for the offline
// tools (the CLI's calibrate); a server that already runs computations side by side passes 1.
#ifndef IMUCAL_UTIL_PARALLEL_H_
#define IMUCAL_UTIL_PARALLEL_H_

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <thread>
#include <vector>

namespace imucal {

// Calls fn(i) once for every i in [0, n), on up to `threads` threads (the caller's among them;
// 1 or less: in order on the caller's). fn must be safe to call concurrently for distinct i, and
// must not throw; callers write each result at its index, so the outcome is the order's.
template <typename Fn>
void ParallelFor(size_t n, int threads, const Fn& fn) {
  const size_t workers = std::min(n, static_cast<size_t>(std::max(1, threads)));
  if (workers <= 1) {
    for (size_t i = 0; i < n; ++i) fn(i);
    return;
  }
  std::atomic<size_t> next{0};
  auto work = [&] {
    for (size_t i = next.fetch_add(1); i < n; i = next.fetch_add(1)) fn(i);
  };
  std::vector<std::thread> pool;
  pool.reserve(workers - 1);
  for (size_t k = 1; k < workers; ++k) pool.emplace_back(work);
  work();
  for (std::thread& t : pool) t.join();
}

// The threads an offline tool uses by default: the machine's cores, at most 4.
inline int DefaultThreads() {
  return static_cast<int>(std::clamp(std::thread::hardware_concurrency(), 1u, 4u));
}

}  // namespace imucal

#endif  // IMUCAL_UTIL_PARALLEL_H_
