#include "server/stream_registry.h"

#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"

namespace imucal::server {
namespace {

// What the allocator holds free goes back to the system: glibc keeps freed memory in its arenas
// (one per thread that allocated, gRPC's included) and returns only what lies at an arena's
// top; malloc_trim releases the free pages anywhere in every arena.
void GiveMemoryBack() {
#if defined(__GLIBC__)
  ::malloc_trim(0);
#endif
}

}  // namespace

StreamRegistry::StreamRegistry(Options options) : options_(options) {
  sweeper_ = std::thread([this] { Sweep(); });
}

StreamRegistry::~StreamRegistry() {
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  cv_.notify_all();
  sweeper_.join();
}

absl::Status StreamRegistry::Add(const std::shared_ptr<Stream>& stream, const std::string& caller,
                                 int64_t token_id, bool silent) {
  std::shared_ptr<Stream> gives_way;
  {
    std::lock_guard lock(mu_);
    if (token_id != 0 && revoked_.contains(token_id))
      return absl::UnauthenticatedError(absl::StrCat("token ", token_id, " was revoked"));
    const auto known = per_caller_.find(caller);
    const int held = known == per_caller_.end() ? 0 : known->second.held;
    if (!caller.empty() && held >= options_.max_per_caller) {
      return absl::ResourceExhaustedError(
          absl::StrCat(caller.starts_with("token:") ? "token " : "client certificate ",
                       caller.substr(caller.find(':') + 1), " already has ", held,
                       " streams open, the most one caller may have "
                       "(max_streams_per_token); end one first"));
    }
    if (streams_.size() - giving_way_ >= static_cast<size_t>(options_.max_streams)) {
      if (!TakePlaceLocked(caller, held, &gives_way)) {
        return absl::ResourceExhaustedError(
            absl::StrCat("the server has ", streams_.size() - giving_way_,
                         " streams open, the most it takes (max_streams); "
                         "retry later"));
      }
    }
    if (!caller.empty()) {
      Caller& mine = per_caller_[caller];
      const bool had_silent = !mine.silent.empty();
      ++mine.held;
      if (silent) mine.silent.insert(stream.get());
      ReindexLocked(caller, mine, mine.held - 1, had_silent);
    }
    streams_.emplace(stream.get(), Entry{stream, caller, token_id});
  }
  // Without the lock, as RevokeToken calls it.
  if (gives_way != nullptr) {
    gives_way->Revoke(grpc::Status(
        grpc::StatusCode::RESOURCE_EXHAUSTED,
        "the server is full (max_streams) and this stream had sent no batch: its place went to "
        "a caller with fewer streams open; open a stream when there are samples to send"));
  }
  return absl::OkStatus();
}

bool StreamRegistry::TakePlaceLocked(const std::string& caller, int held,
                                     std::shared_ptr<Stream>* gives_way) {
  if (caller.empty() || by_held_.empty()) return false;
  const auto& [most, top] = *by_held_.rbegin();
  if (top == caller || held >= most) return false;  // only a caller with fewer streams
  const std::string victim_caller = top;            // by_held_ changes below
  Caller& c = per_caller_[victim_caller];
  const Stream* victim = *c.silent.begin();
  c.silent.erase(c.silent.begin());
  ReindexLocked(victim_caller, c, c.held, /*had_silent=*/true);
  Entry& entry = streams_.at(victim);
  entry.giving_way = true;
  ++giving_way_;
  // Its place is free from now on; its caller's share stays taken until it has ended (Remove).
  // (Null when it is ending anyway.)
  *gives_way = entry.stream.lock();
  return true;
}

void StreamRegistry::ReindexLocked(const std::string& caller, const Caller& now, int held_before,
                                   bool had_silent) {
  if (had_silent) by_held_.erase({held_before, caller});
  if (!now.silent.empty()) by_held_.insert({now.held, caller});
}

void StreamRegistry::Heard(const Stream* stream) {
  std::lock_guard lock(mu_);
  auto it = streams_.find(stream);
  if (it == streams_.end() || it->second.caller.empty()) return;
  auto c = per_caller_.find(it->second.caller);
  if (c == per_caller_.end() || !c->second.silent.contains(stream)) return;
  c->second.silent.erase(stream);
  ReindexLocked(c->first, c->second, c->second.held, /*had_silent=*/true);
}

void StreamRegistry::Remove(const Stream* stream) {
  std::lock_guard lock(mu_);
  auto it = streams_.find(stream);
  if (it == streams_.end()) return;
  if (!it->second.caller.empty()) {
    auto c = per_caller_.find(it->second.caller);
    if (c != per_caller_.end()) {
      const bool had_silent = !c->second.silent.empty();
      c->second.silent.erase(stream);
      --c->second.held;
      ReindexLocked(c->first, c->second, c->second.held + 1, had_silent);
      if (c->second.held <= 0) per_caller_.erase(c);
    }
  }
  if (it->second.giving_way) --giving_way_;
  streams_.erase(it);
  ++ended_since_trim_;
}

void StreamRegistry::RevokeToken(int64_t token_id, const grpc::Status& status) {
  std::vector<std::shared_ptr<Stream>> revoked;
  {
    std::lock_guard lock(mu_);
    revoked_.insert(token_id);
    for (auto& [key, entry] : streams_) {
      if (entry.token_id != token_id) continue;
      if (std::shared_ptr<Stream> s = entry.stream.lock()) revoked.push_back(std::move(s));
    }
  }
  for (const std::shared_ptr<Stream>& s : revoked) s->Revoke(status);
}

size_t StreamRegistry::size() {
  std::lock_guard lock(mu_);
  return streams_.size();
}

int64_t StreamRegistry::trims() {
  std::lock_guard lock(mu_);
  return trims_;
}

void StreamRegistry::Sweep() {
  absl::Time last_trim = absl::InfinitePast();
  std::unique_lock lock(mu_);
  while (!stopping_) {
    cv_.wait_for(lock, absl::ToChronoNanoseconds(options_.tick), [this] { return stopping_; });
    if (stopping_) break;
    const absl::Time now = absl::Now();
    std::vector<std::shared_ptr<Stream>> expired;
    for (auto& [key, entry] : streams_) {
      if (!key->PastDeadline(now)) continue;
      if (std::shared_ptr<Stream> s = entry.stream.lock()) expired.push_back(std::move(s));
    }
    // Many streams ended (a flood went): give their memory back, at most once per interval.
    const bool trim = options_.trim_after_ends > 0 &&
                      ended_since_trim_ >= options_.trim_after_ends &&
                      now - last_trim >= options_.trim_interval;
    if (trim) {
      ended_since_trim_ = 0;
      last_trim = now;
      ++trims_;
    }
    lock.unlock();
    for (const std::shared_ptr<Stream>& s : expired) s->Expire(now);
    expired.clear();  // the last reference to a stream that ended meanwhile goes here, unlocked
    if (trim) GiveMemoryBack();
    lock.lock();
  }
}

}  // namespace imucal::server
