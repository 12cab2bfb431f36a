// imucald's operator commands besides serving, so that a host or a container image needs only
// the one binary:
//
//   imucald --health-check [HOST:PORT] [--config FILE] [--ca FILE] [--server-name NAME]
//                          [--insecure] [--timeout 5s]
//       grpc.health.v1.Health/Check of the whole server: exit 0 when SERVING, 1 otherwise
//       (NOT_SERVING while it drains, unreachable, TLS refused, deadline passed). Over TLS
//       trusting --ca (default: the config's tls_cert, right for a self-signed certificate),
//       or plaintext with --insecure or the config's `insecure = true`. Without HOST:PORT, the
//       config's `listen` (a wildcard host probes 127.0.0.1). For Docker's HEALTHCHECK,
//       Kubernetes exec probes and scripts.
//   imucald backup [--db PATH | --config FILE] (--out FILE | --out-dir DIR [--keep N])
//       online backup of the database (storage/backup.h) while imucald serves. --out-dir writes
//       DIR/imucal-<UTC time>.db and keeps the newest N (default 7) of those.
//   imucald restore --from FILE [--db PATH | --config FILE]
//       checks FILE and restores it over the database; imucald must be stopped.
//   imucald migrate --from sqlite:PATH --to postgresql://USER[:PASSWORD]@HOST[:PORT]/DB
//       copies every row of the SQLite file into the empty PostgreSQL database, verified, in
//       one transaction (storage/copy.h); prints each table's rows, bytes and SHA-256.
//
// Without --db, the database is the one imucald would use: --config FILE, else $IMUCALD_CONFIG,
// then $IMUCALD_DB (config.h's precedence).
#ifndef IMUCAL_SERVER_DAEMON_COMMANDS_H_
#define IMUCAL_SERVER_DAEMON_COMMANDS_H_

#include <span>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"

namespace imucal::server {

struct HealthCheckOptions {
  absl::Duration timeout = absl::Seconds(5);
  bool insecure = false;    // plaintext; else TLS
  std::string ca_path;      // PEM roots to trust; empty: the system's
  std::string server_name;  // TLS name to verify when it differs from the address's host
};

// grpc.health.v1.Health/Check of service "" at `address`: OK when SERVING; Unavailable naming
// the status or the RPC error otherwise.
absl::Status CheckHealth(const std::string& address, const HealthCheckOptions& options);

// Each returns the process exit code (0 done, 1 failed, 2 usage); `args` follow the command
// word. Messages go to stdout (result) and stderr (errors).
int RunHealthCheckCommand(std::span<const std::string> args);
int RunBackupCommand(std::span<const std::string> args);

// `imucald completion bash|zsh`: the completion script for that shell, from the option table
// and the commands' flags; empty for another shell.
std::string DaemonCompletion(std::string_view shell);
int RunRestoreCommand(std::span<const std::string> args);
int RunMigrateCommand(std::span<const std::string> args);

// Deletes the oldest `imucal-*.db` backups in `dir` beyond the newest `keep`; returns how many.
absl::StatusOr<int> PruneBackups(const std::string& dir, int keep);

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_DAEMON_COMMANDS_H_
