// What SessionService may hold and for how long: solves and their leases, ingest limits,
// streams and their timeouts, the solve jobs kept in memory. Filled from imucald's
// configuration (server/config.cc); read by the service, its stream reactors and SolveJobs.
#ifndef IMUCAL_SERVER_SESSION_OPTIONS_H_
#define IMUCAL_SERVER_SESSION_OPTIONS_H_

#include <cstddef>
#include <string>

#include "absl/time/time.h"
#include "server/validate.h"

namespace imucal::server {

struct SessionServiceOptions {
  // Several servers may share one database: each claims the solves it runs as `replica_id`
  // (Server::Start fills it in when empty: the host name and the listen address) and renews
  // the claim every solve_lease / 3; a solve whose claim lapses is an orphan that any of them
  // ends (storage/store.h "Solves"). Servers sharing a database need distinct ids.
  // A solve whose server stopped is claimed and run again by another (or by the same server
  // once restarted), with its seed, up to max_solve_attempts starts in all; then it is failed
  // and its session reopened, so that a solve that stops every server that runs it is not
  // passed on for ever (ResumeLapsedSolves).
  std::string replica_id;
  absl::Duration solve_lease = absl::Seconds(30);
  int max_solve_attempts = 3;
  int solve_threads = 2;
  size_t solve_queue_limit = 16;  // solves waiting for a worker; RESOURCE_EXHAUSTED beyond
  IngestLimits ingest;            // samples per batch and per session (server/validate.h)
  // Concurrent StreamSamples per device (RESOURCE_EXHAUSTED beyond); a stream holds its slot
  // from its first batch until it ends (a dead peer is found by keepalive, see ServerOptions).
  int max_streams_per_device = 1;
  // Across the servers sharing the database, a device's streams are on one server at a time:
  // the first takes the device's claim in the database, renewed every stream_lease / 3 while
  // its streams are open (server/stream_claims.h). A killed server's claim lapses after
  // stream_lease; until then its device's robot is refused elsewhere (its uploader retries).
  absl::Duration stream_lease = absl::Seconds(10);
  int max_watchers_per_session = 16;  // concurrent WatchSession streams (RESOURCE_EXHAUSTED)

  // Calls that hold a place without using it (server/stream_registry.h). A StreamSamples stream
  // sends its first batch within first_batch_timeout of opening and each next one within
  // stream_idle_timeout of the previous ack (a robot batches every 0.1-1 s), else the server
  // ends it DEADLINE_EXCEEDED; one whose ack is not read for stream_idle_timeout, or a watch
  // whose event is not read for watch_stall_timeout (its client stopped reading), or a
  // ReadSamples whose message is not read for stream_idle_timeout, is cancelled. Counted from
  // the moment they open: at most max_streams StreamSamples, WatchSession and ReadSamples
  // calls on the server (about 13 kB each while silent, so 10000 cost ~130 MB; a ReadSamples
  // also holds its page, at most ~2.5 MB at the default max_batch_samples)
  // and max_streams_per_token per token or robot client certificate (RESOURCE_EXHAUSTED
  // beyond; a robot needs one stream, a technician's laptop a few).
  absl::Duration first_batch_timeout = absl::Seconds(30);
  absl::Duration stream_idle_timeout = absl::Seconds(60);
  absl::Duration watch_stall_timeout = absl::Seconds(60);
  int max_streams = 10000;
  int max_streams_per_token = 16;

  // GetSolveJob answers from memory for jobs queued, running, or finished within
  // finished_job_ttl, the newest finished_jobs_kept of them; older ones from storage.
  size_t finished_jobs_kept = 1000;
  absl::Duration finished_job_ttl = absl::Minutes(10);
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_SESSION_OPTIONS_H_
