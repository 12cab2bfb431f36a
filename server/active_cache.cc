#include "server/active_cache.h"

#include <unordered_set>
#include <utility>

namespace imucal::server {

std::shared_ptr<const ActiveParamCache::Entry> ActiveParamCache::Find(
    std::string_view device_id) const {
  const absl::string_view key(device_id.data(), device_id.size());  // Debian's absl::string_view
  std::lock_guard lock(mu_);
  auto it = entries_.find(key);
  return it == entries_.end() || it->second.epoch != epoch_ ? nullptr : it->second.entry;
}

std::shared_ptr<const ActiveParamCache::Entry> ActiveParamCache::FindLastKnown(
    std::string_view device_id) const {
  const absl::string_view key(device_id.data(), device_id.size());
  std::lock_guard lock(mu_);
  auto it = entries_.find(key);
  return it == entries_.end() ? nullptr : it->second.entry;
}

uint64_t ActiveParamCache::generation() const {
  std::lock_guard lock(mu_);
  return generation_;
}

void ActiveParamCache::Insert(std::string_view device_id, std::shared_ptr<const Entry> entry,
                              uint64_t generation) {
  std::lock_guard lock(mu_);
  if (generation != generation_) return;  // an invalidation may concern this fill
  std::string key(device_id);
  const size_t cost = Cost(key, *entry);
  if (cost > max_bytes_) return;
  auto [it, inserted] = entries_.try_emplace(key);
  if (!inserted) bytes_ -= Cost(key, *it->second.entry);
  it->second = Slot{std::move(entry), epoch_};
  bytes_ += cost;
  if (inserted) order_.push_back(std::move(key));
  EvictLocked();
}

void ActiveParamCache::Invalidate(std::string_view device_id) {
  std::lock_guard lock(mu_);
  ++generation_;
  auto it = entries_.find(absl::string_view(device_id.data(), device_id.size()));
  if (it == entries_.end()) return;
  bytes_ -= Cost(it->first, *it->second.entry);
  entries_.erase(it);
}

void ActiveParamCache::Clear() {
  std::lock_guard lock(mu_);
  ++generation_;
  ++epoch_;  // every entry is now a last known answer only
}

void ActiveParamCache::EvictLocked() {
  // Over budget: drop the oldest entries (a key re-inserted after an invalidation may be found
  // by its older place in the queue: approximately oldest first).
  while (bytes_ > max_bytes_ && !order_.empty()) {
    auto it = entries_.find(order_.front());
    if (it != entries_.end()) {
      bytes_ -= Cost(it->first, *it->second.entry);
      entries_.erase(it);
    }
    order_.pop_front();
  }
  // Keys of invalidated entries linger in the queue: compact it when they dominate.
  if (order_.size() > 2 * entries_.size() + 1024) {
    std::deque<std::string> live;
    std::unordered_set<std::string> seen;
    for (std::string& key : order_)
      if (entries_.contains(key) && seen.insert(key).second) live.push_back(std::move(key));
    order_ = std::move(live);
  }
}

size_t ActiveParamCache::size() const {
  std::lock_guard lock(mu_);
  return entries_.size();
}

size_t ActiveParamCache::bytes() const {
  std::lock_guard lock(mu_);
  return bytes_;
}

}  // namespace imucal::server
