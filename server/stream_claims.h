// One open StreamSamples stream per device across the servers sharing a database: the database
// holds each device's claim (storage/store.h "Stream claims"), this server's part of it here.
//
// A stream of a device opens (its first batch) with Acquire: the device's claim is taken for
// this server unless another server holds it, in which case the stream is refused
// RESOURCE_EXHAUSTED naming that server, as a second stream on one server is. The server's
// local slots (SessionServiceOptions::max_streams_per_device) count its own streams of the
// device; the claim is taken by the first and given up with the last (Release). A thread
// renews every claim held every lease / 3; a server that is killed stops renewing, and
// `lease` after its last renewal another server may take the device (the robot's uploader
// retries RESOURCE_EXHAUSTED until then). A claim this server failed to renew in time (the
// database was out for longer than the lease) and that another server has taken since is lost:
// Held() turns false and the stream ends at its next batch.
//
// Threads: every call from any thread. Acquire and Release write the database (a few ms);
// they are serialised with the renewals by one lock, so that a renewal never races a claim.
#ifndef IMUCAL_SERVER_STREAM_CLAIMS_H_
#define IMUCAL_SERVER_STREAM_CLAIMS_H_

#include <condition_variable>
#include <map>
#include <mutex>
#include <set>
#include <string>
#include <thread>

#include "absl/status/status.h"
#include "absl/time/time.h"
#include "storage/store.h"

namespace imucal::server {

class StreamClaims {
 public:
  // Claims are named "<replica_id> <random>": this server's instance (a restarted server is not
  // its previous life). Gives up the previous life's claims first (best effort): that life's
  // streams cannot be open, and its robots need not wait for those leases.
  StreamClaims(storage::Store* store, const std::string& replica_id, absl::Duration lease);
  ~StreamClaims();  // stops renewing; gives up the claims still held
  StreamClaims(const StreamClaims&) = delete;
  StreamClaims& operator=(const StreamClaims&) = delete;

  // A stream of `device` for `session` opens here. ResourceExhausted when another server's
  // stream holds the device; Unavailable when the database cannot say.
  absl::Status Acquire(const std::string& device, const std::string& session);
  // The stream ended: the last of the device's here gives up its claim.
  void Release(const std::string& device);
  // False once another server took a claim this server held (its renewal came too late).
  bool Held(const std::string& device);
  // A stream of the device is open here, and the claim is still this server's.
  bool HeldHere(const std::string& device);

  const std::string& holder() const { return holder_; }

 private:
  void Run();
  void RenewLocked();

  storage::Store* store_;
  const std::string holder_;
  const absl::Duration lease_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::map<std::string, int> held_;  // guarded by mu_: device -> streams open here
  std::set<std::string> lost_;       // guarded by mu_: held devices another server took
  bool stopping_ = false;            // guarded by mu_
  std::thread renewer_;
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_STREAM_CLAIMS_H_
