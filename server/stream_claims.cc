#include "server/stream_claims.h"

#include <algorithm>
#include <random>
#include <set>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "server/log.h"

namespace imucal::server {

namespace {

std::string InstanceName(const std::string& replica_id) {
  std::random_device device;
  return absl::StrCat(replica_id, " ",
                      absl::Hex((uint64_t{device()} << 32) ^ device(), absl::kZeroPad16));
}

}  // namespace

StreamClaims::StreamClaims(storage::Store* store, const std::string& replica_id,
                           absl::Duration lease)
    : store_(store),
      holder_(InstanceName(replica_id.empty() ? "imucald" : replica_id)),
      lease_(lease) {
  absl::StatusOr<int> released =
      store_->ReleaseStreamClaimsOfReplica(replica_id.empty() ? "imucald" : replica_id);
  if (!released.ok()) {
    Log(LogLevel::kWarning, "stream_claims_release",
        {{"replica_id", replica_id},
         {"error", std::string(released.status().message())},
         {"note", "a previous life's claims lapse with their leases"}});
  }
  renewer_ = std::thread([this] { Run(); });
}

StreamClaims::~StreamClaims() {
  std::map<std::string, int> held;
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
    held.swap(held_);
  }
  cv_.notify_all();
  if (renewer_.joinable()) renewer_.join();
  // The streams have ended with the server's calls; what is left is given up, best effort (a
  // claim left behind lapses after the lease).
  for (const auto& [device, count] : held)
    store_->ReleaseStreamClaim(device, holder_).IgnoreError();
}

absl::Status StreamClaims::Acquire(const std::string& device, const std::string& session) {
  std::lock_guard lock(mu_);
  if (auto it = held_.find(device); it != held_.end() && !lost_.contains(device)) {
    ++it->second;  // this server's local slots bound how many
    return absl::OkStatus();
  }
  absl::StatusOr<storage::StreamClaim> claim =
      store_->ClaimStream(device, holder_, session, absl::Now() + lease_);
  if (!claim.ok()) return claim.status();
  if (claim->holder != holder_) {
    return absl::ResourceExhaustedError(absl::StrCat(
        "device ", device, " already has a sample stream open on another server (",
        claim->holder.substr(0, claim->holder.rfind(' ')), ", session ", claim->session_id,
        "), the most a device may have; end it (or wait up to ", absl::FormatDuration(lease_),
        " for the servers to see that it broke) and resume from GetSession().last_acked_seq + 1"));
  }
  lost_.erase(device);
  ++held_[device];
  return absl::OkStatus();
}

void StreamClaims::Release(const std::string& device) {
  std::lock_guard lock(mu_);
  auto it = held_.find(device);
  if (it == held_.end() || --it->second > 0) return;
  held_.erase(it);
  const bool lost = lost_.erase(device) > 0;
  if (lost) return;  // another server's claim now: not ours to delete (the SQL checks too)
  if (absl::Status s = store_->ReleaseStreamClaim(device, holder_); !s.ok()) {
    Log(LogLevel::kWarning, "stream_claim_release",
        {{"device", device},
         {"error", std::string(s.message())},
         {"note", absl::StrCat("the claim lapses within ", absl::FormatDuration(lease_))}});
  }
}

bool StreamClaims::Held(const std::string& device) {
  std::lock_guard lock(mu_);
  return !lost_.contains(device);
}

bool StreamClaims::HeldHere(const std::string& device) {
  std::lock_guard lock(mu_);
  return held_.contains(device) && !lost_.contains(device);
}

void StreamClaims::Run() {
  std::unique_lock lock(mu_);
  while (!stopping_) {
    cv_.wait_for(lock, absl::ToChronoMilliseconds(lease_ / 3), [this] { return stopping_; });
    if (stopping_) return;
    if (!held_.empty()) RenewLocked();
  }
}

void StreamClaims::RenewLocked() {
  absl::StatusOr<std::vector<std::string>> renewed =
      store_->RenewStreamClaims(holder_, absl::Now() + lease_);
  if (!renewed.ok()) {
    Log(LogLevel::kWarning, "stream_claims_renew",
        {{"holder", holder_}, {"error", std::string(renewed.status().message())}});
    return;  // the next round tries again; the claims hold until their leases end
  }
  const std::set<std::string> still(renewed->begin(), renewed->end());
  for (const auto& [device, count] : held_) {
    if (still.contains(device) || lost_.contains(device)) continue;
    lost_.insert(device);
    Log(LogLevel::kWarning, "stream_claim_lost",
        {{"device", device},
         {"note",
          "another server took the device's stream after this one's claim lapsed: its "
          "stream here ends at its next batch"}});
  }
}

}  // namespace imucal::server
