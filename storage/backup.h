// Online backup and restore of imucald's SQLite database, with SQLite's backup API.
//
// Backup copies a live database (WAL mode, imucald serving and writing) into a single
// self-contained file. It runs the whole copy as one sqlite3_backup_step(-1) inside one read
// transaction: in WAL mode a reader never blocks the writer, so imucald keeps ingesting while
// the copy runs, and the copy is the consistent snapshot of the moment the read began (an
// incremental copy in small steps would restart whenever another connection writes, and under
// steady ingest might never finish). The copy is written to FILE.tmp, switched to
// journal_mode=DELETE (one file, no -wal), checked with PRAGMA integrity_check, fsynced and
// renamed to FILE, so FILE is either the previous one or a complete, verified backup.
//
// Restore checks the backup first (it opens as SQLite, integrity_check says ok, its schema
// version is one this binary knows, and imucal's tables are there), then copies it over the
// database at `db_path` with the backup API, under an exclusive lock: if anything (a running
// imucald) has the database open, restore refuses rather than change a file under a server.
// The database that was there is first kept as `db_path`.pre-restore. An older schema version
// is allowed: imucald migrates it on its next start.
#ifndef IMUCAL_STORAGE_BACKUP_H_
#define IMUCAL_STORAGE_BACKUP_H_

#include <cstdint>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace imucal::storage {

struct DatabaseInfo {
  int schema_version = 0;  // PRAGMA user_version; 0 for a file that does not exist yet
  int64_t page_count = 0;
  int64_t page_size_bytes = 0;
  int64_t devices = 0;  // rows, for the operator's eye after a backup or restore
  int64_t param_versions = 0;
};

// Reads a database file without changing it. NotFound if `path` does not exist; DataLoss if it
// is not an SQLite database or (with `check_integrity`) integrity_check finds a problem;
// FailedPrecondition if it is SQLite but not imucal's (no schema version, or tables missing)
// or its schema is newer than this binary's.
absl::StatusOr<DatabaseInfo> InspectDatabase(const std::string& path, bool check_integrity);

// The schema version of `path` before imucald opens it: 0 if the file does not exist yet.
absl::StatusOr<int> SchemaVersionOf(const std::string& path);

// Online backup of `db_path` (may be in use) to `out_path`; returns what the backup holds.
absl::StatusOr<DatabaseInfo> BackupDatabase(const std::string& db_path,
                                            const std::string& out_path);

// Replaces the database at `db_path` (which no process may have open) with the backup at
// `backup_path`; returns what the restored database holds.
absl::StatusOr<DatabaseInfo> RestoreDatabase(const std::string& backup_path,
                                             const std::string& db_path);

}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_BACKUP_H_
