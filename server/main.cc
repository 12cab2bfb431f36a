// imucald: the imucal calibration service. Parses flags and runs the server until SIGTERM or
// SIGINT, then shuts down gracefully (in-flight calls and queued solves finish) and exits 0.
#include <csignal>
#include <cstdio>
#include <cstring>
#include <string>

#include <semaphore.h>

#include "absl/synchronization/mutex.h"
#include "server/server.h"

namespace {

sem_t g_stop;  // posted by the signal handler: sem_post is async-signal-safe

void OnSignal(int) { sem_post(&g_stop); }

int Usage(const char* problem) {
  std::fprintf(stderr,
               "%s\nusage: imucald [--listen HOST:PORT] [--db PATH]\n"
               "  --listen  address to serve on (default 127.0.0.1:50051)\n"
               "  --db      SQLite database file (default imucal.db)\n",
               problem);
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  // absl::Mutex deadlock detection (on by default in non-NDEBUG builds; gRPC's locks are
  // absl::Mutex) keeps a lock-order graph updated on every acquisition: that bookkeeping cost
  // ~5% of the server's CPU in the GetActiveParameters fetch benchmark. Only imucald turns it
  // off: the test binaries (which never run this main) keep detecting lock-order cycles.
  absl::SetMutexDeadlockDetectionMode(absl::OnDeadlockCycle::kIgnore);
  imucal::server::ServerOptions options;
  for (int i = 1; i < argc; ++i) {
    std::string arg = argv[i];
    std::string value;
    const size_t eq = arg.find('=');
    if (eq != std::string::npos) {
      value = arg.substr(eq + 1);
      arg = arg.substr(0, eq);
    } else if (arg == "--listen" || arg == "--db") {
      if (i + 1 >= argc) return Usage(("missing value for " + arg).c_str());
      value = argv[++i];
    }
    if (arg == "--listen") {
      options.listen = value;
    } else if (arg == "--db") {
      options.db_path = value;
    } else if (arg == "--help" || arg == "-h") {
      Usage("imucald: the imucal calibration service");
      return 0;
    } else {
      return Usage(("unknown flag " + arg).c_str());
    }
  }
  sem_init(&g_stop, 0, 0);
  struct sigaction sa;
  std::memset(&sa, 0, sizeof(sa));
  sa.sa_handler = OnSignal;
  sigaction(SIGTERM, &sa, nullptr);
  sigaction(SIGINT, &sa, nullptr);

  auto server = imucal::server::Server::Start(options);
  if (!server.ok()) {
    std::fprintf(stderr, "imucald: %s\n", std::string(server.status().message()).c_str());
    return 1;
  }
  std::fprintf(stderr, "imucald: serving on %s\n", (*server)->address().c_str());
  while (sem_wait(&g_stop) != 0) {
  }
  std::fprintf(stderr, "imucald: shutting down\n");
  (*server)->Shutdown();
  return 0;
}
