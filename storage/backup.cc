#include "storage/backup.h"

#include <fcntl.h>
#include <sqlite3.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <memory>
#include <optional>
#include <system_error>
#include <vector>

#include "storage/migrations.h"
#include "storage/pg_db.h"
#include "storage/status_macros.h"
#include "util/file.h"
#include "util/sqlite_db.h"
#include "util/str_util.h"

namespace imucal::storage {
namespace {

absl::Status NotForPostgres(std::string_view what, std::string_view tool) {
  return absl::FailedPreconditionError(
      Cat(what, " copies SQLite files; a PostgreSQL database is backed up and restored with ",
          "PostgreSQL's own tools (", tool, ")"));
}


// The tables every imucal schema since version 1 has: a file without them is not imucal's.
constexpr const char* kRequiredTables[] = {"devices", "sessions", "sample_batches",
                                           "param_versions"};

// The first column of the first row of a constant query.
absl::StatusOr<int64_t> QueryInt(sql::Connection& conn, std::string_view sql) {
  IMUCAL_ASSIGN_OR_RETURN(std::optional<int64_t> value,
                          sql::ReadRow(conn, sql, sql::FirstColumnInt64));
  if (!value) return absl::InternalError(Cat("no row from ", sql));
  return *value;
}

// PRAGMA integrity_check: "ok", or up to three of its complaints.
absl::Status CheckIntegrity(sql::Connection& conn) {
  IMUCAL_ASSIGN_OR_RETURN(std::vector<std::string> lines,
                          sql::ReadRows(conn, "PRAGMA integrity_check(3)", sql::FirstColumnText));
  if (lines.size() == 1 && lines[0] == "ok") return absl::OkStatus();
  return absl::DataLossError(Cat("integrity_check failed: ", Join(lines, "; ")));
}

absl::StatusOr<int64_t> CountTables(sql::Connection& conn) {
  int64_t found = 0;
  for (const char* table : kRequiredTables) {
    IMUCAL_ASSIGN_OR_RETURN(
        std::optional<int64_t> count,
        sql::ReadRow(conn, "SELECT count(*) FROM sqlite_schema WHERE type = 'table' AND name = ?1",
                     sql::FirstColumnInt64, table));
    found += count.value_or(0);
  }
  return found;
}

absl::StatusOr<DatabaseInfo> Inspect(sql::Connection& conn, bool check_integrity) {
  DatabaseInfo info;
  // The first read of the file: a file that is not SQLite fails here with NOTADB (DataLoss).
  IMUCAL_ASSIGN_OR_RETURN(info.schema_version, SchemaVersion(conn));
  if (check_integrity) IMUCAL_RETURN_IF_ERROR(CheckIntegrity(conn));
  if (info.schema_version <= 0) {
    return absl::FailedPreconditionError(
        "not an imucal database (schema version 0: no imucal migration was ever applied)");
  }
  if (info.schema_version > LatestSchemaVersion()) {
    return absl::FailedPreconditionError(
        Cat("schema version ", info.schema_version, " is newer than this imucald knows (",
            LatestSchemaVersion(), "): use the imucald that wrote it, or a newer one"));
  }
  IMUCAL_ASSIGN_OR_RETURN(int64_t tables, CountTables(conn));
  if (tables != static_cast<int64_t>(std::size(kRequiredTables))) {
    return absl::FailedPreconditionError(
        "not an imucal database (tables devices, sessions, sample_batches, param_versions "
        "missing)");
  }
  IMUCAL_ASSIGN_OR_RETURN(info.page_count, QueryInt(conn, "PRAGMA page_count"));
  IMUCAL_ASSIGN_OR_RETURN(info.page_size_bytes, QueryInt(conn, "PRAGMA page_size"));
  IMUCAL_ASSIGN_OR_RETURN(info.devices, QueryInt(conn, "SELECT count(*) FROM devices"));
  IMUCAL_ASSIGN_OR_RETURN(info.param_versions,
                          QueryInt(conn, "SELECT count(*) FROM param_versions"));
  return info;
}

absl::Status CheckExists(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return absl::NotFoundError(Cat(path, ": no such file"));
  }
  return absl::OkStatus();
}

// Copies every page of `src` into `dest` in one step (one read transaction on `src`).
absl::Status CopyPages(sql::SqliteConnection& src, sql::SqliteConnection& dest,
                       std::string_view what) {
  sqlite3_backup* backup = sqlite3_backup_init(dest.db(), "main", src.db(), "main");
  if (backup == nullptr) {
    return sql::SqliteStatus(sqlite3_extended_errcode(dest.db()), what, dest.db());
  }
  const int step_rc = sqlite3_backup_step(backup, -1);
  const int finish_rc = sqlite3_backup_finish(backup);
  if (step_rc != SQLITE_DONE) {
    // READONLY here means the page sizes differ and the destination is in WAL mode.
    return sql::SqliteStatus(
        step_rc, what, step_rc == SQLITE_BUSY || step_rc == SQLITE_LOCKED ? src.db() : dest.db());
  }
  if (finish_rc != SQLITE_OK) return sql::SqliteStatus(finish_rc, what, dest.db());
  return absl::OkStatus();
}

// The directory that is to hold `path` exists: SQLite's own error for a missing one ("unable
// to open database file") names neither the directory nor what to do.
absl::Status CheckDirectoryOf(const std::string& path) {
  const std::string dir = DirectoryOf(path);
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec)) {
    return absl::NotFoundError(
        Cat(path, ": the directory ", dir, " does not exist (nothing creates it: make it first)"));
  }
  return absl::OkStatus();
}

// Makes a standalone copy of `src` at `path` (replacing it), in rollback-journal mode so that
// it is one file; verifies it and makes it durable.
absl::Status WriteStandaloneCopy(sql::SqliteConnection& src, const std::string& path) {
  const std::string tmp = Cat(path, ".tmp");
  std::error_code ec;
  std::filesystem::remove(tmp, ec);
  {
    IMUCAL_ASSIGN_OR_RETURN(std::unique_ptr<sql::SqliteConnection> dest,
                            sql::SqliteConnection::Open(tmp, sql::ConnectionOptions{}));
    IMUCAL_RETURN_IF_ERROR(CopyPages(src, *dest, Cat("copy to ", tmp)));
    // The pages came from a WAL database and say so in their header: make the copy a plain
    // rollback-journal database, so that it is complete without a -wal beside it.
    IMUCAL_ASSIGN_OR_RETURN(
        std::optional<std::string> mode,
        sql::ReadRow(*dest, "PRAGMA journal_mode = DELETE", sql::FirstColumnText));
    if (mode.value_or("") != "delete") {
      return absl::InternalError(Cat(tmp, ": cannot leave WAL mode"));
    }
  }
  {
    IMUCAL_ASSIGN_OR_RETURN(
        std::unique_ptr<sql::SqliteConnection> check,
        sql::SqliteConnection::Open(tmp, sql::ConnectionOptions{.read_only = true}));
    IMUCAL_RETURN_IF_ERROR(Annotate(tmp, Inspect(*check, /*check_integrity=*/true).status()));
  }
  IMUCAL_RETURN_IF_ERROR(FsyncPath(tmp, /*directory=*/false));
  std::filesystem::rename(tmp, path, ec);
  if (ec) return absl::UnavailableError(Cat("rename ", tmp, " to ", path, ": ", ec.message()));
  return FsyncPath(DirectoryOf(path), /*directory=*/true);
}

}  // namespace

absl::StatusOr<DatabaseInfo> InspectDatabase(const std::string& path, bool check_integrity) {
  IMUCAL_RETURN_IF_ERROR(CheckExists(path));
  absl::StatusOr<std::unique_ptr<sql::SqliteConnection>> conn =
      sql::SqliteConnection::Open(path, sql::ConnectionOptions{.read_only = true});
  if (!conn.ok()) return Annotate(path, conn.status());
  absl::StatusOr<DatabaseInfo> info = Inspect(**conn, check_integrity);
  if (!info.ok()) return Annotate(path, info.status());
  return info;
}

absl::StatusOr<int> SchemaVersionOf(const std::string& path) {
  if (sql::IsPostgresUrl(path)) {
    absl::StatusOr<std::unique_ptr<PgConnection>> pg =
        PgConnection::Open(path, sql::ConnectionOptions{.read_only = true});
    if (!pg.ok()) return pg.status();
    return SchemaVersion(**pg);
  }
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return 0;
  absl::StatusOr<std::unique_ptr<sql::SqliteConnection>> conn =
      sql::SqliteConnection::Open(path, sql::ConnectionOptions{.read_only = true});
  if (!conn.ok()) return Annotate(path, conn.status());
  absl::StatusOr<int> version = SchemaVersion(**conn);
  if (!version.ok()) return Annotate(path, version.status());
  return version;
}

absl::StatusOr<DatabaseInfo> BackupDatabase(const std::string& db_path,
                                            const std::string& out_path) {
  if (sql::IsPostgresUrl(db_path)) return NotForPostgres("backup", "pg_dump --format=custom");
  if (out_path.empty()) return absl::InvalidArgumentError("backup: empty output path");
  IMUCAL_RETURN_IF_ERROR(CheckExists(db_path));
  IMUCAL_RETURN_IF_ERROR(CheckDirectoryOf(out_path));
  // Read-only: the backup never writes the live database (nor checkpoints its WAL).
  absl::StatusOr<std::unique_ptr<sql::SqliteConnection>> src =
      sql::SqliteConnection::Open(db_path, sql::ConnectionOptions{.read_only = true});
  if (!src.ok()) return Annotate(db_path, src.status());
  if (absl::Status s = Annotate(db_path, Inspect(**src, false).status()); !s.ok()) return s;
  IMUCAL_RETURN_IF_ERROR(WriteStandaloneCopy(**src, out_path));
  return InspectDatabase(out_path, /*check_integrity=*/false);
}

absl::StatusOr<DatabaseInfo> RestoreDatabase(const std::string& backup_path,
                                             const std::string& db_path) {
  if (sql::IsPostgresUrl(db_path)) return NotForPostgres("restore", "pg_restore");
  absl::StatusOr<DatabaseInfo> source = InspectDatabase(backup_path, /*check_integrity=*/true);
  if (!source.ok()) {
    return absl::Status(source.status().code(),
                        Cat("refusing to restore: ", source.status().message()));
  }
  IMUCAL_RETURN_IF_ERROR(CheckDirectoryOf(db_path));
  std::error_code ec;
  const bool replacing = std::filesystem::exists(db_path, ec);
  {
    // Exclusive locking mode takes an EXCLUSIVE lock on the database file at the first access
    // and keeps it until the connection closes. Every other connection, even an idle one of a
    // running imucald (WAL connections hold a SHARED lock while open), makes that fail at once
    // (busy timeout 0): restore never changes a database under a live server.
    sql::ConnectionOptions options;
    options.busy_timeout = absl::ZeroDuration();
    absl::StatusOr<std::unique_ptr<sql::SqliteConnection>> dest =
        sql::SqliteConnection::Open(db_path, options);
    if (!dest.ok()) return Annotate(db_path, dest.status());
    IMUCAL_RETURN_IF_ERROR((*dest)->Exec("PRAGMA locking_mode = EXCLUSIVE"));
    if (absl::Status s = (*dest)->Exec("BEGIN EXCLUSIVE; COMMIT"); !s.ok()) {
      if (absl::IsUnavailable(s)) {
        return absl::FailedPreconditionError(
            Cat(db_path, " is in use (is imucald running?): stop it before restoring"));
      }
      return Annotate(db_path, s);
    }
    if (replacing) {
      // Keep what was there: a restore of the wrong file can itself be undone.
      IMUCAL_RETURN_IF_ERROR(WriteStandaloneCopy(**dest, Cat(db_path, ".pre-restore")));
    }
    absl::StatusOr<std::unique_ptr<sql::SqliteConnection>> src =
        sql::SqliteConnection::Open(backup_path, sql::ConnectionOptions{.read_only = true});
    if (!src.ok()) return Annotate(backup_path, src.status());
    IMUCAL_RETURN_IF_ERROR(CopyPages(**src, **dest, Cat("restore into ", db_path)));
  }
  absl::StatusOr<DatabaseInfo> restored = InspectDatabase(db_path, /*check_integrity=*/true);
  if (!restored.ok()) {
    return absl::Status(restored.status().code(),
                        Cat("restored database failed its check: ", restored.status().message()));
  }
  return restored;
}

}  // namespace imucal::storage
