#include "server/stream_reactor.h"

#include <memory>
#include <mutex>
#include <string>

#include "absl/strings/str_cat.h"

namespace imucal::server {

std::string CallerKey(const Principal& who) {
  if (who.token_id != 0) return absl::StrCat("token:", who.token_id);
  if (!who.device_id.empty()) return absl::StrCat("cert:", who.device_id);
  return "";
}

absl::Status StreamCall::Register(const std::shared_ptr<StreamRegistry::Stream>& self,
                                  bool silent) {
  return env_.registry->Add(self, CallerKey(*who_), who_->token_id, silent);
}

void StreamCall::MarkDone() {
  {
    std::lock_guard lock(ctx_mu_);
    done_ = true;
  }
  env_.registry->Remove(this);
}

void StreamCall::CancelCall() {
  std::lock_guard lock(ctx_mu_);
  if (!done_) context_->TryCancel();
}

}  // namespace imucal::server
