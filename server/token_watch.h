// Keeps a server's Authorizer in step with the token table when someone else changes it:
// another server sharing the database revokes a token, or a tool or an operator's SQL does.
//
// Every change to a token row is logged by the table's triggers (schema migration 7), and on
// PostgreSQL also sent as a notification (imucal_token, the token id) at its commit. On
// PostgreSQL the server's listener passes each to Changed(); on SQLite this watch reads the
// change log every `poll` (one indexed query; 250 ms by default, so a revocation is honoured
// within about that). Either way the token is read again off the caller's thread and, revoked
// or deleted, dropped from the cache, its open streams and watches ended, and its new calls
// refused (Authorizer::TokenChanged). When PostgreSQL's notifications may have been missed
// (Gap()), the whole cache is dropped: the next call with any token reads the table, and an
// open stream reads it at its next batch.
#ifndef IMUCAL_SERVER_TOKEN_WATCH_H_
#define IMUCAL_SERVER_TOKEN_WATCH_H_

#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "server/auth.h"
#include "storage/tokens.h"

namespace imucal::server {

class TokenWatch {
 public:
  // `auth` and `tokens` outlive the watch. `poll`: how often to read the change log (zero:
  // never, the notifications tell). Reads where the log ends now: earlier changes are known.
  static absl::StatusOr<std::unique_ptr<TokenWatch>> Start(Authorizer* auth,
                                                           storage::TokenStore* tokens,
                                                           absl::Duration poll);
  ~TokenWatch();  // stops; joins the thread
  TokenWatch(const TokenWatch&) = delete;
  TokenWatch& operator=(const TokenWatch&) = delete;

  // Token `id` changed (a notification). Quick: the token is read on the watch's thread.
  void Changed(int64_t id);
  // Changes may have been missed. Quick.
  void Gap();

 private:
  TokenWatch(Authorizer* auth, storage::TokenStore* tokens, absl::Duration poll)
      : auth_(auth), tokens_(tokens), poll_(poll) {}
  void Run();
  void Poll();

  Authorizer* auth_;
  storage::TokenStore* tokens_;
  const absl::Duration poll_;
  int64_t last_change_ = 0;  // the watch thread's: the last change log entry read
  std::mutex mu_;
  std::condition_variable cv_;
  std::vector<int64_t> changed_;  // guarded by mu_
  bool gap_ = false;              // guarded by mu_
  bool stopping_ = false;         // guarded by mu_
  std::thread thread_;
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_TOKEN_WATCH_H_
