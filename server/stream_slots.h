// Counts concurrent streams per key (a device's StreamSamples, a session's WatchSession) so that
// one robot or one runaway client cannot hold more than its share of the server.
#ifndef IMUCAL_SERVER_STREAM_SLOTS_H_
#define IMUCAL_SERVER_STREAM_SLOTS_H_

#include <map>
#include <mutex>
#include <string>
#include <string_view>

namespace imucal::server {

class StreamSlots {
 public:
  // Takes one of `key`'s `limit` slots; false when all are taken.
  bool TryAcquire(std::string_view key, int limit) {
    std::lock_guard lock(mu_);
    auto it = held_.find(key);
    if (it == held_.end()) {
      if (limit < 1) return false;
      held_.emplace(std::string(key), 1);
      return true;
    }
    if (it->second >= limit) return false;
    ++it->second;
    return true;
  }

  // Gives back a slot taken by TryAcquire (keys without streams are forgotten: the map holds
  // only keys with a stream open).
  void Release(std::string_view key) {
    std::lock_guard lock(mu_);
    auto it = held_.find(key);
    if (it == held_.end()) return;
    if (--it->second <= 0) held_.erase(it);
  }

  int Total() {  // slots held over every key
    std::lock_guard lock(mu_);
    int total = 0;
    for (const auto& [key, held] : held_) total += held;
    return total;
  }

  int Held(std::string_view key) {
    std::lock_guard lock(mu_);
    auto it = held_.find(key);
    return it == held_.end() ? 0 : it->second;
  }

 private:
  std::mutex mu_;
  std::map<std::string, int, std::less<>> held_;  // guarded by mu_
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_STREAM_SLOTS_H_
