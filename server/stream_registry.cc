#include "server/stream_registry.h"

#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"

namespace imucal::server {

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
                                 int64_t token_id) {
  std::lock_guard lock(mu_);
  if (token_id != 0 && revoked_.contains(token_id))
    return absl::UnauthenticatedError(absl::StrCat("token ", token_id, " was revoked"));
  if (streams_.size() >= static_cast<size_t>(options_.max_streams)) {
    return absl::ResourceExhaustedError(
        absl::StrCat("the server has ", streams_.size(),
                     " streams open, the most it takes (max_streams); "
                     "retry later"));
  }
  if (!caller.empty()) {
    int& held = per_caller_[caller];
    if (held >= options_.max_per_caller) {
      return absl::ResourceExhaustedError(
          absl::StrCat(caller.starts_with("token:") ? "token " : "client certificate ",
                       caller.substr(caller.find(':') + 1), " already has ", held,
                       " streams open, the most one caller may have "
                       "(max_streams_per_token); end one first"));
    }
    ++held;
  }
  streams_.emplace(stream.get(), Entry{stream, caller, token_id});
  return absl::OkStatus();
}

void StreamRegistry::Remove(const Stream* stream) {
  std::lock_guard lock(mu_);
  auto it = streams_.find(stream);
  if (it == streams_.end()) return;
  if (!it->second.caller.empty()) {
    auto held = per_caller_.find(it->second.caller);
    if (held != per_caller_.end() && --held->second <= 0) per_caller_.erase(held);
  }
  streams_.erase(it);
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

void StreamRegistry::Sweep() {
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
    lock.unlock();
    for (const std::shared_ptr<Stream>& s : expired) s->Expire(now);
    expired.clear();  // the last reference to a stream that ended meanwhile goes here, unlocked
    lock.lock();
  }
}

}  // namespace imucal::server
