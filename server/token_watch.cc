#include "server/token_watch.h"

#include <utility>

#include "server/log.h"

namespace imucal::server {

absl::StatusOr<std::unique_ptr<TokenWatch>> TokenWatch::Start(Authorizer* auth,
                                                              storage::TokenStore* tokens,
                                                              absl::Duration poll) {
  std::unique_ptr<TokenWatch> w(new TokenWatch(auth, tokens, poll));
  if (poll > absl::ZeroDuration()) {
    absl::StatusOr<storage::TokenStore::Changes> now = tokens->ChangesSince(-1);
    if (!now.ok()) return now.status();
    w->last_change_ = now->last_id;
  }
  w->thread_ = std::thread([p = w.get()] { p->Run(); });
  return w;
}

TokenWatch::~TokenWatch() {
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void TokenWatch::Changed(int64_t id) {
  {
    std::lock_guard lock(mu_);
    changed_.push_back(id);
  }
  cv_.notify_all();
}

void TokenWatch::Gap() {
  {
    std::lock_guard lock(mu_);
    gap_ = true;
  }
  cv_.notify_all();
}

void TokenWatch::Run() {
  const bool polling = poll_ > absl::ZeroDuration();
  absl::Time next_poll = polling ? absl::Now() + poll_ : absl::InfiniteFuture();
  std::unique_lock lock(mu_);
  while (!stopping_) {
    cv_.wait_until(lock, absl::ToChronoTime(next_poll),
                   [this] { return stopping_ || gap_ || !changed_.empty(); });
    if (stopping_) return;
    std::vector<int64_t> changed;
    changed.swap(changed_);
    const bool gap = std::exchange(gap_, false);
    lock.unlock();
    if (gap) auth_->ForgetCachedTokens();
    for (int64_t id : changed) auth_->TokenChanged(id);
    if (polling && absl::Now() >= next_poll) {
      Poll();
      next_poll = absl::Now() + poll_;
    }
    lock.lock();
  }
}

void TokenWatch::Poll() {
  // Each round reads at most a page of the log; a longer backlog (thousands of tokens made at
  // once) is read on the following rounds.
  absl::StatusOr<storage::TokenStore::Changes> changes = tokens_->ChangesSince(last_change_);
  if (!changes.ok()) {
    Log(LogLevel::kWarning, "token_watch", {{"error", std::string(changes.status().message())}});
    return;
  }
  for (int64_t id : changes->token_ids) auth_->TokenChanged(id);
  last_change_ = changes->last_id;
}

}  // namespace imucal::server
