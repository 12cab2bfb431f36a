// The schema as numbered migrations, one list per backend with the same numbers: version N is
// the same tables on SQLite and on PostgreSQL. SQLite tracks it in `PRAGMA user_version`,
// PostgreSQL in the one-row table `imucal_schema`.
//
// Migration N takes the schema from version N-1 to N; its script ends by setting the version to
// N. Never edit a migration that has shipped: append a new one, to both lists.
#ifndef IMUCAL_STORAGE_MIGRATIONS_H_
#define IMUCAL_STORAGE_MIGRATIONS_H_

#include <span>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "util/db.h"

namespace imucal::storage {

struct Migration {
  int version;      // 1, 2, 3, ...
  // A constant script; ends with "PRAGMA user_version = <version>;" (SQLite) or
  // "UPDATE imucal_schema SET version = <version>;" (PostgreSQL).
  const char* sql;
};

// imucal's migrations for a backend, oldest first.
std::span<const Migration> Migrations(sql::Dialect dialect = sql::Dialect::kSqlite);
int LatestSchemaVersion();

// The schema version of the connection's database (0 for a new one).
absl::StatusOr<int> SchemaVersion(sql::Connection& conn);

// Applies every migration newer than the database's version, each in its own transaction (on
// PostgreSQL under an advisory lock held throughout), so concurrent openers apply it once and a
// crash leaves a whole version.
// Idempotent. FailedPrecondition if the file's version is newer than `migrations` knows (an
// older binary on a newer database), Internal if a script does not set its own version.
absl::Status Migrate(sql::Connection& conn);  // the connection's backend's list
absl::Status Migrate(sql::Connection& conn, std::span<const Migration> migrations);

}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_MIGRATIONS_H_
