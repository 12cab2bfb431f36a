// A real PostgreSQL for the tests of the PostgreSQL backend, and a fresh database per test.
//
// The cluster is a throwaway one from deploy/pg-throwaway.sh (initdb and pg_ctl in a temporary
// directory, as the postgres system user when run as root). Under ctest, one cluster serves the
// whole run: the fixture tests pg_cluster_start and pg_cluster_stop (tests/CMakeLists.txt) start
// and stop it, and IMUCAL_TEST_PG_URL_FILE names the file that holds its URL. A test binary run
// by hand starts a cluster of its own on first use and stops it at exit.
//
// Nothing here skips: a test that asks for PostgreSQL and cannot have it fails, naming why.
#ifndef IMUCAL_TESTS_PG_TEST_CLUSTER_H_
#define IMUCAL_TESTS_PG_TEST_CLUSTER_H_

#include <unistd.h>

#include <array>
#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <memory>
#include <mutex>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "storage/pg_db.h"

#ifndef IMUCAL_SOURCE_DIR
#error "IMUCAL_SOURCE_DIR must name the source tree (tests/CMakeLists.txt defines it)"
#endif

namespace imucal::testing_util {

namespace pg_internal {

inline std::string RunForOutput(const std::string& command, int* exit_code) {
  std::string out;
  FILE* pipe = ::popen(command.c_str(), "r");
  if (pipe == nullptr) {
    *exit_code = -1;
    return out;
  }
  std::array<char, 512> buf;
  size_t n;
  while ((n = std::fread(buf.data(), 1, buf.size(), pipe)) > 0) out.append(buf.data(), n);
  *exit_code = ::pclose(pipe);
  while (!out.empty() && (out.back() == '\n' || out.back() == ' ')) out.pop_back();
  return out;
}

struct OwnCluster {
  std::string dir;
  std::string url;
};

inline OwnCluster& Own() {
  static OwnCluster own;
  return own;
}

inline void StopOwnCluster() {
  if (Own().dir.empty()) return;
  int rc = 0;
  RunForOutput(std::string("bash ") + IMUCAL_SOURCE_DIR + "/deploy/pg-throwaway.sh stop " +
                   Own().dir + " 2>&1",
               &rc);
}

}  // namespace pg_internal

// The admin URL of the run's cluster (database "imucal"), or why there is none.
inline absl::StatusOr<std::string> PgClusterUrl() {
  static std::mutex mu;
  std::lock_guard lock(mu);
  if (const char* file = std::getenv("IMUCAL_TEST_PG_URL_FILE"); file != nullptr && *file != 0) {
    std::ifstream in(file);
    std::string url;
    if (!std::getline(in, url) || url.empty()) {
      return absl::FailedPreconditionError(std::string("IMUCAL_TEST_PG_URL_FILE=") + file +
                                           " holds no URL: did the ctest fixture "
                                           "pg_cluster_start fail?");
    }
    return url;
  }
  pg_internal::OwnCluster& own = pg_internal::Own();
  if (!own.url.empty()) return own.url;
  char tmpl[] = "/tmp/imucal-test-pg.XXXXXX";
  if (::mkdtemp(tmpl) == nullptr) return absl::InternalError("mkdtemp failed");
  own.dir = tmpl;
  int rc = 0;
  const std::string url = pg_internal::RunForOutput(
      std::string("bash ") + IMUCAL_SOURCE_DIR + "/deploy/pg-throwaway.sh start " + own.dir,
      &rc);
  if (rc != 0 || url.empty()) {
    return absl::FailedPreconditionError("deploy/pg-throwaway.sh could not start a cluster in " +
                                         own.dir + " (its messages are above)");
  }
  own.url = url;
  std::atexit(pg_internal::StopOwnCluster);
  return url;
}

// A database of its own for one test, created empty and dropped (with any connections left)
// when the object goes.
class PgTestDatabase {
 public:
  static absl::StatusOr<std::unique_ptr<PgTestDatabase>> Create() {
    absl::StatusOr<std::string> admin = PgClusterUrl();
    if (!admin.ok()) return admin.status();
    static std::atomic<int> counter{0};
    const std::string name = "t_" + std::to_string(::getpid()) + "_" + std::to_string(++counter);
    absl::StatusOr<std::unique_ptr<storage::PgConnection>> conn =
        storage::PgConnection::Open(*admin, {});
    if (!conn.ok()) return conn.status();
    if (absl::Status s = (*conn)->Exec(("DROP DATABASE IF EXISTS " + name + " WITH (FORCE)").c_str());
        !s.ok())
      return s;
    if (absl::Status s = (*conn)->Exec(("CREATE DATABASE " + name).c_str()); !s.ok()) return s;
    const size_t slash = admin->rfind('/');
    return std::unique_ptr<PgTestDatabase>(
        new PgTestDatabase(*admin, admin->substr(0, slash + 1) + name, name));
  }
  ~PgTestDatabase() {
    absl::StatusOr<std::unique_ptr<storage::PgConnection>> conn =
        storage::PgConnection::Open(admin_, {});
    if (conn.ok()) (void)(*conn)->Exec(("DROP DATABASE IF EXISTS " + name_ + " WITH (FORCE)").c_str());
  }
  PgTestDatabase(const PgTestDatabase&) = delete;
  PgTestDatabase& operator=(const PgTestDatabase&) = delete;

  const std::string& url() const { return url_; }

 private:
  PgTestDatabase(std::string admin, std::string url, std::string name)
      : admin_(std::move(admin)), url_(std::move(url)), name_(std::move(name)) {}
  std::string admin_, url_, name_;
};

}  // namespace imucal::testing_util

#endif  // IMUCAL_TESTS_PG_TEST_CLUSTER_H_
