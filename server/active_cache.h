// The fetch hot path's cache: per device, its active parameter version's GetActiveParameters
// responses, serialised once (the full set, and the header-only answer to if_not_version), so
// that a fetch of an unchanged version reads no SQLite and serialises nothing: a map lookup and
// a reference-counted slice handed to gRPC.
//
// Invalidation: the store reports every commit that changes a device's active version (a solve
// that activates, promote, rollback: StoreOptions::on_active_change) and the device's entry is
// dropped. A fill races with such a commit only if its store read started before the commit; a
// global generation, bumped by every invalidation, makes Insert drop any fill whose read began
// before the last invalidation, so a stale response is never cached.
//
// Through a database outage: when change notifications may have been missed (Clear, on the
// listener's gap, which an outage causes) the entries are kept as the last known answers rather
// than dropped. Find no longer returns them (a fetch reads the database again and refills), but
// FindLastKnown does, for a fetch that cannot reach the database: the robot then gets the
// version as the server last knew it, marked ParameterSet.served_from_cache. An invalidation
// (a change heard of) drops the entry for good.
//
// Memory is bounded by `max_bytes` (the responses' sizes plus a per-entry overhead): beyond it,
// the oldest entries (insertion order) are evicted. With 4-5 KB parameter documents the default
// holds about 25,000 devices.
#ifndef IMUCAL_SERVER_ACTIVE_CACHE_H_
#define IMUCAL_SERVER_ACTIVE_CACHE_H_

#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>

#include "absl/container/flat_hash_map.h"
#include "grpcpp/support/slice.h"

namespace imucal::server {

class ActiveParamCache {
 public:
  struct Entry {
    int version = 0;
    grpc::Slice full;    // a serialised v1::ParameterSet with its json
    grpc::Slice header;  // the same without json (if_not_version == version)
  };

  explicit ActiveParamCache(size_t max_bytes = size_t{128} << 20) : max_bytes_(max_bytes) {}

  std::shared_ptr<const Entry> Find(std::string_view device_id) const;
  // The device's last cached answer, confirmed since the last Clear or not (null if none).
  std::shared_ptr<const Entry> FindLastKnown(std::string_view device_id) const;
  // Read before the store read of a fill; pass to Insert.
  uint64_t generation() const;
  // Caches `entry` unless an invalidation happened since `generation` was read.
  void Insert(std::string_view device_id, std::shared_ptr<const Entry> entry, uint64_t generation);
  void Invalidate(std::string_view device_id);
  // Every device: when changes may have been missed (Store::ListenForActiveChanges's gap).
  // The entries stay as last known answers (FindLastKnown) until refilled or invalidated.
  void Clear();

  size_t size() const;
  size_t bytes() const;

 private:
  struct Slot {
    std::shared_ptr<const Entry> entry;
    uint64_t epoch = 0;  // the Clear it was inserted after: current (Find) or last known only
  };
  static size_t Cost(const std::string& key, const Entry& e) {
    return key.size() + e.full.size() + e.header.size() + 128;
  }
  void EvictLocked();

  const size_t max_bytes_;
  mutable std::mutex mu_;
  uint64_t generation_ = 0;  // guarded by mu_
  uint64_t epoch_ = 0;       // guarded by mu_: Clears so far
  // Looked up by string_view (no key copy on the hot path); open addressing, few cache misses.
  absl::flat_hash_map<std::string, Slot> entries_;  // guarded by mu_
  std::deque<std::string> order_;  // guarded by mu_: insertion order (may hold dropped keys)
  size_t bytes_ = 0;               // guarded by mu_
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_ACTIVE_CACHE_H_
