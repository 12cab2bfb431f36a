// imucald: the imucal calibration service. Reads its configuration (server/config.h), serves
// until SIGTERM or SIGINT, then shuts down gracefully (in-flight calls and queued solves
// finish) and exits 0. `imucald --help` lists the options; server/daemon_commands.h has the
// health-check, backup, restore and migrate commands.
#include <semaphore.h>
#include <sys/stat.h>

#include <csignal>
#include <cstdio>
#include <cstring>
#include <span>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/synchronization/mutex.h"
#include "server/config.h"
#include "server/daemon_commands.h"
#include "server/log.h"
#include "server/server.h"
#include "storage/backup.h"
#include "storage/migrations.h"

namespace {

using imucal::server::Log;
using imucal::server::LogLevel;

sem_t g_stop;  // posted by the signal handler: sem_post is async-signal-safe

void OnSignal(int) { sem_post(&g_stop); }

void WaitForStopSignal() {
  sem_init(&g_stop, 0, 0);
  struct sigaction sa;
  std::memset(&sa, 0, sizeof(sa));
  sa.sa_handler = OnSignal;
  sigaction(SIGTERM, &sa, nullptr);
  sigaction(SIGINT, &sa, nullptr);
  while (sem_wait(&g_stop) != 0) {
  }
}

int Serve(const imucal::server::DaemonConfig& config) {
  imucal::server::ConfigureLog(config.log);
  // The schema version before Store::Open migrates it: the start line says what was applied.
  absl::StatusOr<int> before = imucal::storage::SchemaVersionOf(config.server.db_path);
  const absl::Time start = absl::Now();
  auto server = imucal::server::Server::Start(config.server);
  if (!server.ok()) {
    Log(LogLevel::kError, "server_start_failed",
        {{"db", imucal::sql::RedactedLocation(config.server.db_path)},
         {"error", server.status().message()}});
    return 1;
  }
  const int schema_version = imucal::storage::LatestSchemaVersion();
  Log(LogLevel::kInfo, "server_start",
      {{"address", (*server)->address()},
       {"db", imucal::sql::RedactedLocation(config.server.db_path)},
       {"config", config.config_path},
       {"version", IMUCAL_VERSION},
       {"schema_version", schema_version},
       {"migrations_applied", before.ok() ? schema_version - *before : -1},
       {"solve_threads", config.server.sessions.solve_threads},
       {"metrics",
        (*server)->metrics_port() == 0
            ? std::string("off")
            : absl::StrCat("http://",
                           (*server)->address().substr(0, (*server)->address().rfind(':')), ":",
                           (*server)->metrics_port(), "/metrics")},
       {"startup_ms", absl::ToDoubleMilliseconds(absl::Now() - start)}});
  WaitForStopSignal();
  Log(LogLevel::kInfo, "shutdown_begin",
      {{"drain_deadline_s", absl::ToDoubleSeconds(config.server.drain_deadline)}});
  const absl::Time stop = absl::Now();
  (*server)->Shutdown();
  Log(LogLevel::kInfo, "shutdown_done",
      {{"drain_ms", absl::ToDoubleMilliseconds(absl::Now() - stop)}});
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  // The database, its WAL files and backups hold every calibration and the tokens' hashes:
  // never world-readable, nor group-writable, whatever umask imucald is started with (by hand,
  // in a container; the systemd unit sets UMask=0077 too). A stricter umask is kept. Set first:
  // every command (serve, backup, restore) creates files.
  ::umask(::umask(0) | 027);
  // absl::Mutex deadlock detection (on by default in non-NDEBUG builds; gRPC's locks are
  // absl::Mutex) keeps a lock-order graph updated on every acquisition: that bookkeeping cost
  // ~5% of the server's CPU in the GetActiveParameters fetch benchmark. Only imucald turns it
  // off: the test binaries (which never run this main) keep detecting lock-order cycles.
  absl::SetMutexDeadlockDetectionMode(absl::OnDeadlockCycle::kIgnore);
  const std::vector<std::string> args(argv + 1, argv + argc);
  const std::span<const std::string> rest = std::span(args).subspan(args.empty() ? 0 : 1);
  if (!args.empty() && args[0] == "backup") return imucal::server::RunBackupCommand(rest);
  if (!args.empty() && args[0] == "restore") return imucal::server::RunRestoreCommand(rest);
  if (!args.empty() && args[0] == "migrate") return imucal::server::RunMigrateCommand(rest);
  if (!args.empty() && args[0] == "completion") {
    const std::string script = rest.size() == 1 ? imucal::server::DaemonCompletion(rest[0]) : "";
    if (script.empty()) {
      std::fputs("usage: imucald completion bash|zsh   (a completion script, on stdout)\n", stderr);
      return 2;
    }
    std::fputs(script.c_str(), stdout);
    return 0;
  }
  if (!args.empty() && args[0] == "--health-check") {
    return imucal::server::RunHealthCheckCommand(rest);
  }
  absl::StatusOr<imucal::server::LoadedConfig> loaded =
      imucal::server::LoadConfig(args, imucal::server::ProcessEnvironment());
  if (!loaded.ok()) {
    std::fprintf(stderr, "imucald: %s\n(imucald --help lists the options)\n",
                 std::string(loaded.status().message()).c_str());
    return 2;
  }
  if (loaded->help) {
    std::fputs(imucal::server::HelpText().c_str(), stdout);
    return 0;
  }
  if (loaded->version) {
    std::puts("imucald " IMUCAL_VERSION);
    return 0;
  }
  return Serve(loaded->config);
}
