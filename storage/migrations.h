// The schema as numbered migrations, tracked in SQLite's `PRAGMA user_version`.
//
// Migration N takes the schema from version N-1 to N; its script ends by setting user_version
// to N. Never edit a migration that has shipped: append a new one.
#ifndef IMUCAL_STORAGE_MIGRATIONS_H_
#define IMUCAL_STORAGE_MIGRATIONS_H_

#include <span>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "storage/sqlite_db.h"

namespace imucal::storage {

struct Migration {
  int version;      // 1, 2, 3, ...
  const char* sql;  // a constant script; must end with "PRAGMA user_version = <version>;"
};

// imucal's migrations, oldest first.
std::span<const Migration> Migrations();
int LatestSchemaVersion();

// PRAGMA user_version of the connection's database (0 for a new file).
absl::StatusOr<int> SchemaVersion(Connection& conn);

// Applies every migration newer than the database's version, each in its own BEGIN IMMEDIATE
// transaction, so concurrent openers apply it once and a crash leaves a whole version.
// Idempotent. FailedPrecondition if the file's version is newer than `migrations` knows (an
// older binary on a newer database), Internal if a script does not set its own version.
absl::Status Migrate(Connection& conn, std::span<const Migration> migrations = Migrations());

}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_MIGRATIONS_H_
