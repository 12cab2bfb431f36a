// Moving a site from SQLite to PostgreSQL: every row of an imucal SQLite file copied into an
// empty PostgreSQL database, for `imucald migrate` (server/daemon_commands.h).
//
// What it does, in order:
//   1. The source: an existing imucal SQLite file at this binary's latest schema version,
//      opened read-only (never written, nor its WAL checkpointed). An older file is refused:
//      start this imucald on it once (that migrates it), stop it, and copy then; a newer one is
//      refused too (use the imucald that wrote it). The copy never migrates the source itself,
//      so a failed or abandoned copy leaves the site exactly as it was.
//   2. The destination: the PostgreSQL migrations are applied (storage::Migrate), then ONE
//      transaction locks imucal's tables against other writers and checks that every one is
//      empty. A destination holding any row is refused, naming the tables: the copy never
//      merges into a live database.
//   3. Every table in foreign-key order (kCopyTables below), read from SQLite inside ONE read
//      transaction: the copy is the consistent snapshot of the moment it began, even while an
//      imucald keeps writing the file (WAL readers never block it); whatever it writes after
//      that is not copied. Rows are read and written a page at a time (keyset pages of at most
//      ~8 MiB), never a whole table in memory. Values go across as they are stored: integers as
//      BIGINT, REAL as DOUBLE PRECISION bit for bit, text as text, blobs (sample payloads, token
//      hashes) as bytea, NULL as NULL. Ids are kept: sessions' rowid (their creation order),
//      solves.id, audit_log.id, tokens.id; the identity sequences are then moved past the
//      largest, so new rows continue after the copied ones.
//   4. Verified before the commit: each table is read back from PostgreSQL (inside the same
//      transaction, in key order) and its row count and SHA-256 over its rows must equal the
//      count and SHA-256 of the rows read from SQLite (and SQLite's count(*) in the snapshot).
//      Any difference, or any error, rolls the whole transaction back and names the table:
//      the destination keeps its (empty) tables and no row.
#ifndef IMUCAL_STORAGE_COPY_H_
#define IMUCAL_STORAGE_COPY_H_

#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/time/time.h"

namespace imucal::storage {

// How a column's values are read, written and hashed (SQLite's storage classes).
enum class CopyColumnType { kInteger, kReal, kText, kBlob };

struct CopyColumn {
  const char* name;
  CopyColumnType type;
};

// One table of the copy. Its SQL is the store's common SQL (?N parameters), the same text on
// both backends except `reset_identity`, which is PostgreSQL's alone.
struct CopyTable {
  const char* name;
  std::span<const CopyColumn> columns;  // in the order the SELECT returns them
  int key_columns;                      // the first `key_columns` columns: the page order
  // The next page after key (?1..?k) in key order, at most ?k+1 rows.
  const char* select_page;
  const char* insert;          // ?1..?n: the columns in order
  const char* count;           // SELECT count(*)
  const char* reset_identity;  // moves the identity sequence past the largest id; or null
  // The column that is SQLite's implicit rowid (sessions): not in PRAGMA table_info there.
  const char* sqlite_rowid_column;
};

// Every table of the schema, parents before children.
std::span<const CopyTable> CopyTables();

struct TableCopyReport {
  std::string table;
  int64_t rows = 0;
  // The stored values' bytes: 8 for a number, the length of a text or a blob.
  int64_t bytes = 0;
  std::string sha256_hex;  // over the rows in key order; equal on both sides
};

struct CopyReport {
  int schema_version = 0;
  std::vector<TableCopyReport> tables;  // in CopyTables() order
  absl::Duration took;
  int64_t rows() const;
  int64_t bytes() const;
};

struct CopyProgress {
  std::string_view table;
  std::string_view phase;  // "copy", then "verify"
  int64_t rows_done = 0;
  int64_t rows_total = 0;  // the table's rows in the snapshot
};

// Called after every page, on the calling thread.
using CopyProgressFn = std::function<void(const CopyProgress&)>;

// Copies the SQLite file `sqlite_path` into the PostgreSQL database at `pg_url` (a
// postgresql:// URL; the database must exist) as described above; returns what was copied.
// Errors: InvalidArgument for a path that is a URL or a URL that is not PostgreSQL's; NotFound
// for a missing file; FailedPrecondition for a file that is not imucal's or not at the latest
// schema version, and for a destination that holds rows; Unavailable when either database
// cannot be reached or the destination's tables are locked by another writer; DataLoss when a
// table read back differs. Messages name the file or the redacted URL and the table, never SQL.
absl::StatusOr<CopyReport> CopySqliteToPostgres(const std::string& sqlite_path,
                                                const std::string& pg_url,
                                                const CopyProgressFn& progress = nullptr);

}  // namespace imucal::storage

#endif  // IMUCAL_STORAGE_COPY_H_
