#include "storage/copy.h"

#include <openssl/evp.h>
#include <sqlite3.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <limits>
#include <memory>
#include <optional>
#include <set>
#include <utility>

#include "storage/backup.h"
#include "storage/migrations.h"
#include "storage/pg_db.h"
#include "storage/status_macros.h"
#include "util/sqlite_db.h"
#include "util/str_util.h"

namespace imucal::storage {
namespace {

using T = CopyColumnType;

// ---- The tables ------------------------------------------------------------------------------
// Each table's columns as migrations.cc makes them (the latest version), its key first. Pages
// are keyset pages: `(key) > (last key read)` in key order, which both backends answer from the
// primary key's index (PostgreSQL's text keys are COLLATE "C", SQLite's BINARY: the same byte
// order, so both sides list rows in the same order).

constexpr CopyColumn kDeviceColumns[] = {
    {"id", T::kText},         {"sensor_model", T::kText}, {"nominal_rate_hz", T::kReal},
    {"accel_unit", T::kText}, {"gyro_unit", T::kText},    {"created_at_us", T::kInteger},
};
constexpr CopyColumn kSessionColumns[] = {
    {"rowid", T::kInteger},         {"id", T::kText},
    {"device_id", T::kText},        {"state", T::kText},
    {"protocol", T::kText},         {"gravity_m_s2", T::kReal},
    {"created_at_us", T::kInteger}, {"updated_at_us", T::kInteger},
    {"source", T::kText},
};
constexpr CopyColumn kBatchColumns[] = {
    {"session_id", T::kText}, {"seq", T::kInteger},   {"first_t_s", T::kReal},
    {"last_t_s", T::kReal},   {"count", T::kInteger}, {"end_sample", T::kInteger},
    {"payload", T::kBlob},
};
constexpr CopyColumn kPoseColumns[] = {
    {"session_id", T::kText},  {"pose_index", T::kInteger}, {"t_start_s", T::kReal},
    {"t_end_s", T::kReal},     {"used", T::kInteger},       {"reason", T::kText},
    {"detail_json", T::kText}, {"face", T::kText},
};
constexpr CopyColumn kPairColumns[] = {
    {"session_id", T::kText}, {"pose_a", T::kInteger}, {"pose_b", T::kInteger},
    {"ok", T::kInteger},      {"face", T::kText},      {"rotation_deg", T::kReal},
    {"tilt_deg", T::kReal},   {"reason", T::kText},
};
constexpr CopyColumn kSolveColumns[] = {
    {"id", T::kInteger},
    {"session_id", T::kText},
    {"state", T::kText},
    {"actor", T::kText},
    {"started_at_us", T::kInteger},
    {"finished_at_us", T::kInteger},
    {"version", T::kInteger},
    {"error", T::kText},
    {"report_json", T::kText},
    {"owner", T::kText},
    {"lease_until_us", T::kInteger},
    {"seed", T::kInteger},
    {"attempts", T::kInteger},
};
constexpr CopyColumn kVersionColumns[] = {
    {"device_id", T::kText},   {"version", T::kInteger}, {"created_at_us", T::kInteger},
    {"session_id", T::kText},  {"verdict", T::kText},    {"accel_rms", T::kReal},
    {"state", T::kText},       {"provenance", T::kText}, {"params_json", T::kText},
    {"report_json", T::kText},
};
constexpr CopyColumn kAuditColumns[] = {
    {"id", T::kInteger},  {"time_us", T::kInteger}, {"actor", T::kText},
    {"action", T::kText}, {"target", T::kText},     {"detail", T::kText},
};
constexpr CopyColumn kTokenColumns[] = {
    {"id", T::kInteger},
    {"secret_sha256", T::kBlob},
    {"role", T::kText},
    {"device_id", T::kText},
    {"label", T::kText},
    {"created_at_us", T::kInteger},
    {"revoked_at_us", T::kInteger},
};

constexpr CopyTable kTables[] = {
    {"devices", kDeviceColumns, 1,
     "SELECT id, sensor_model, nominal_rate_hz, accel_unit, gyro_unit, created_at_us "
     "FROM devices WHERE id > ?1 ORDER BY id LIMIT ?2",
     "INSERT INTO devices (id, sensor_model, nominal_rate_hz, accel_unit, gyro_unit, "
     "created_at_us) VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
     "SELECT count(*) FROM devices", nullptr, nullptr},
    // By rowid, kept: PostgreSQL's sessions.rowid stands in for SQLite's (creation order).
    {"sessions", kSessionColumns, 1,
     "SELECT rowid, id, device_id, state, protocol, gravity_m_s2, created_at_us, updated_at_us, "
     "source FROM sessions WHERE rowid > ?1 ORDER BY rowid LIMIT ?2",
     "INSERT INTO sessions (rowid, id, device_id, state, protocol, gravity_m_s2, created_at_us, "
     "updated_at_us, source) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
     "SELECT count(*) FROM sessions",
     "SELECT setval(pg_get_serial_sequence('sessions', 'rowid'), max(rowid)) FROM sessions",
     "rowid"},
    {"sample_batches", kBatchColumns, 2,
     "SELECT session_id, seq, first_t_s, last_t_s, count, end_sample, payload "
     "FROM sample_batches WHERE (session_id, seq) > (?1, ?2) ORDER BY session_id, seq LIMIT ?3",
     "INSERT INTO sample_batches (session_id, seq, first_t_s, last_t_s, count, end_sample, "
     "payload) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
     "SELECT count(*) FROM sample_batches", nullptr, nullptr},
    {"poses", kPoseColumns, 2,
     "SELECT session_id, pose_index, t_start_s, t_end_s, used, reason, detail_json, face "
     "FROM poses WHERE (session_id, pose_index) > (?1, ?2) ORDER BY session_id, pose_index "
     "LIMIT ?3",
     "INSERT INTO poses (session_id, pose_index, t_start_s, t_end_s, used, reason, detail_json, "
     "face) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
     "SELECT count(*) FROM poses", nullptr, nullptr},
    {"pose_pairs", kPairColumns, 3,
     "SELECT session_id, pose_a, pose_b, ok, face, rotation_deg, tilt_deg, reason "
     "FROM pose_pairs WHERE (session_id, pose_a, pose_b) > (?1, ?2, ?3) "
     "ORDER BY session_id, pose_a, pose_b LIMIT ?4",
     "INSERT INTO pose_pairs (session_id, pose_a, pose_b, ok, face, rotation_deg, tilt_deg, "
     "reason) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
     "SELECT count(*) FROM pose_pairs", nullptr, nullptr},
    {"solves", kSolveColumns, 1,
     "SELECT id, session_id, state, actor, started_at_us, finished_at_us, version, error, "
     "report_json, owner, lease_until_us, seed, attempts FROM solves WHERE id > ?1 ORDER BY id "
     "LIMIT ?2",
     "INSERT INTO solves (id, session_id, state, actor, started_at_us, finished_at_us, version, "
     "error, report_json, owner, lease_until_us, seed, attempts) "
     "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13)",
     "SELECT count(*) FROM solves",
     "SELECT setval(pg_get_serial_sequence('solves', 'id'), max(id)) FROM solves", nullptr},
    {"param_versions", kVersionColumns, 2,
     "SELECT device_id, version, created_at_us, session_id, verdict, accel_rms, state, "
     "provenance, params_json, report_json FROM param_versions "
     "WHERE (device_id, version) > (?1, ?2) ORDER BY device_id, version LIMIT ?3",
     "INSERT INTO param_versions (device_id, version, created_at_us, session_id, verdict, "
     "accel_rms, state, provenance, params_json, report_json) "
     "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
     "SELECT count(*) FROM param_versions", nullptr, nullptr},
    {"audit_log", kAuditColumns, 1,
     "SELECT id, time_us, actor, action, target, detail FROM audit_log WHERE id > ?1 "
     "ORDER BY id LIMIT ?2",
     "INSERT INTO audit_log (id, time_us, actor, action, target, detail) "
     "VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
     "SELECT count(*) FROM audit_log",
     "SELECT setval(pg_get_serial_sequence('audit_log', 'id'), max(id)) FROM audit_log", nullptr},
    {"tokens", kTokenColumns, 1,
     "SELECT id, secret_sha256, role, device_id, label, created_at_us, revoked_at_us "
     "FROM tokens WHERE id > ?1 ORDER BY id LIMIT ?2",
     "INSERT INTO tokens (id, secret_sha256, role, device_id, label, created_at_us, "
     "revoked_at_us) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
     "SELECT count(*) FROM tokens",
     "SELECT setval(pg_get_serial_sequence('tokens', 'id'), max(id)) FROM tokens", nullptr},
};

// Every table at once, so that no other writer (another imucald already pointed at the
// destination) adds a row between the emptiness check and the commit. Readers may still read.
// Tables of migration 7 that belong to the running servers, not to the site: the servers' stream
// claims (leases; none is live while imucald is stopped for the copy) and the token change log
// (each server reads it from its end when it starts; the copy's own token rows are logged again
// by the destination's triggers).
constexpr const char* kNotCopied[] = {"stream_claims", "token_changes"};

constexpr char kLockTables[] =
    "LOCK TABLE devices, sessions, sample_batches, poses, pose_pairs, solves, param_versions, "
    "audit_log, tokens IN EXCLUSIVE MODE";

// imucal's tables never start with "sqlite" (SQLite's own do).
constexpr char kSqliteTables[] =
    "SELECT name FROM sqlite_schema WHERE type = 'table' AND name NOT LIKE 'sqlite%'";
constexpr char kSqliteColumns[] = "SELECT name FROM pragma_table_info(?1)";
constexpr char kPgColumns[] =
    "SELECT CAST(column_name AS TEXT) FROM information_schema.columns "
    "WHERE table_schema = current_schema() AND table_name = ?1";
constexpr char kPgTableExists[] = "SELECT to_regclass(?1) IS NOT NULL";

// A page holds about this many bytes of values (the first page of a table: kFirstPageRows
// rows), so that neither side holds much of a table at once: PostgreSQL returns a whole result
// at once, and a sample batch may be over a megabyte.
constexpr int64_t kPageBytes = int64_t{8} << 20;
constexpr int64_t kFirstPageRows = 64;
constexpr int64_t kMaxPageRows = 4096;

// ---- Rows ------------------------------------------------------------------------------------

// SHA-256 over a table's rows, each value tagged with its type and, for text and blobs, its
// length (so that no two different rows hash the same bytes):
//   NULL 'N' | integer 'I' + 8 bytes LE | real 'R' + the 8 bytes of its IEEE bits, LE |
//   text 'T' + 8-byte LE length + bytes | blob 'B' + 8-byte LE length + bytes.
class RowHash {
 public:
  RowHash() : ctx_(EVP_MD_CTX_new()) { EVP_DigestInit_ex(ctx_.get(), EVP_sha256(), nullptr); }

  // Hashes the current row of `st`; returns its values' bytes (see TableCopyReport).
  int64_t Add(const sql::Statement& st, const CopyTable& table) {
    int64_t bytes = 0;
    for (size_t i = 0; i < table.columns.size(); ++i) {
      const int c = static_cast<int>(i);
      if (st.ColumnIsNull(c)) {
        Update("N", 1);
        continue;
      }
      switch (table.columns[i].type) {
        case T::kInteger:
          Tagged('I', static_cast<uint64_t>(st.ColumnInt64(c)));
          bytes += 8;
          break;
        case T::kReal: {
          uint64_t bits;
          const double value = st.ColumnDouble(c);
          std::memcpy(&bits, &value, sizeof bits);
          Tagged('R', bits);
          bytes += 8;
          break;
        }
        case T::kText:
        case T::kBlob: {
          const std::string_view value = st.ColumnBlobView(c);
          Tagged(table.columns[i].type == T::kText ? 'T' : 'B', value.size());
          Update(value.data(), value.size());
          bytes += static_cast<int64_t>(value.size());
          break;
        }
      }
    }
    return bytes;
  }

  std::string Hex() {
    unsigned char digest[EVP_MAX_MD_SIZE];
    unsigned int size = 0;
    EVP_DigestFinal_ex(ctx_.get(), digest, &size);
    static constexpr char kHex[] = "0123456789abcdef";
    std::string hex;
    for (unsigned int i = 0; i < size; ++i) {
      hex.push_back(kHex[digest[i] >> 4]);
      hex.push_back(kHex[digest[i] & 15]);
    }
    return hex;
  }

 private:
  struct Free {
    void operator()(EVP_MD_CTX* ctx) const { EVP_MD_CTX_free(ctx); }
  };
  void Update(const void* data, size_t size) { EVP_DigestUpdate(ctx_.get(), data, size); }
  void Tagged(char tag, uint64_t value) {
    std::array<unsigned char, 9> buf;
    buf[0] = static_cast<unsigned char>(tag);
    for (int i = 0; i < 8; ++i) buf[1 + i] = static_cast<unsigned char>(value >> (8 * i));
    Update(buf.data(), buf.size());
  }
  std::unique_ptr<EVP_MD_CTX, Free> ctx_;
};

// SQLite keeps any value in any column; a value whose storage class is not its column's (text
// in an INTEGER column, a blob in a TEXT one) would be converted on the way and so arrive
// changed. Only a file written outside imucal holds one: it is refused, naming it.
absl::Status CheckStorageClasses(const sql::Statement& st, const CopyTable& table) {
  const auto* lite = dynamic_cast<const sql::SqliteStatement*>(&st);
  if (lite == nullptr) return absl::OkStatus();
  for (size_t i = 0; i < table.columns.size(); ++i) {
    const int type = sqlite3_column_type(lite->get(), static_cast<int>(i));
    if (type == SQLITE_NULL) continue;  // NOT NULL is the schema's to keep
    int want = SQLITE_TEXT;
    switch (table.columns[i].type) {
      case T::kInteger:
        want = SQLITE_INTEGER;
        break;
      case T::kReal:
        want = SQLITE_FLOAT;
        break;
      case T::kText:
        want = SQLITE_TEXT;
        break;
      case T::kBlob:
        want = SQLITE_BLOB;
        break;
    }
    if (type != want) {
      static constexpr const char* kClass[] = {"", "an integer", "a real", "text", "a blob"};
      return absl::FailedPreconditionError(
          Cat("column ", table.columns[i].name, " holds ", kClass[type], " where the schema says ",
              kClass[want], " (the file was changed outside imucal): nothing was copied"));
    }
  }
  return absl::OkStatus();
}

// The key of the current row, for messages: "(S1, 3)".
std::string KeyOf(const sql::Statement& st, const CopyTable& table) {
  std::vector<std::string> parts;
  for (int i = 0; i < table.key_columns; ++i) {
    parts.push_back(table.columns[static_cast<size_t>(i)].type == T::kInteger
                        ? Cat(st.ColumnInt64(i))
                        : Cat("'", st.ColumnText(i), "'"));
  }
  return Cat("(", Join(parts, ", "), ")");
}

// Binds the current row of `row` as the parameters of `insert`, value for value.
void BindRow(const sql::Statement& row, const CopyTable& table, sql::Statement& insert) {
  for (size_t i = 0; i < table.columns.size(); ++i) {
    const int c = static_cast<int>(i);
    if (row.ColumnIsNull(c)) {
      insert.BindNull(c + 1);
      continue;
    }
    switch (table.columns[i].type) {
      case T::kInteger:
        insert.BindInt64(c + 1, row.ColumnInt64(c));
        break;
      case T::kReal:
        insert.BindDouble(c + 1, row.ColumnDouble(c));  // PostgreSQL: shortest exact text
        break;
      case T::kText:
        insert.BindText(c + 1, row.ColumnBlobView(c));  // the text's bytes, unconverted
        break;
      case T::kBlob:
        insert.BindBlob(c + 1, row.ColumnBlobView(c));
        break;
    }
  }
}

// Calls `on_row` with every row of `table` on `conn`, in key order, a page at a time (see
// kPageBytes), and `on_page` with the rows read so far after each page.
template <typename OnRow, typename OnPage>
absl::Status ForEachRow(sql::Connection& conn, const CopyTable& table, OnRow&& on_row,
                        OnPage&& on_page) {
  const size_t k = static_cast<size_t>(table.key_columns);
  // Before the first row: below every integer and every non-empty text (no key is empty; one
  // would be skipped, and the verification's counts would say so).
  std::vector<int64_t> key_int(k, std::numeric_limits<int64_t>::min());
  std::vector<std::string> key_text(k);
  int64_t page_rows = kFirstPageRows;
  int64_t total = 0;
  for (;;) {
    int64_t rows = 0;
    int64_t bytes = 0;
    {
      IMUCAL_ASSIGN_OR_RETURN(sql::ScopedStatement st, conn.Prepare(table.select_page));
      for (size_t i = 0; i < k; ++i) {
        if (table.columns[i].type == T::kInteger) {
          st->BindInt64(static_cast<int>(i) + 1, key_int[i]);
        } else {
          st->BindText(static_cast<int>(i) + 1, key_text[i]);
        }
      }
      st->BindInt64(static_cast<int>(k) + 1, page_rows);
      for (;;) {
        IMUCAL_ASSIGN_OR_RETURN(bool more, st->Step());
        if (!more) break;
        IMUCAL_ASSIGN_OR_RETURN(int64_t row_bytes, on_row(*st));
        bytes += row_bytes;
        ++rows;
        for (size_t i = 0; i < k; ++i) {
          if (table.columns[i].type == T::kInteger) {
            key_int[i] = st->ColumnInt64(static_cast<int>(i));
          } else {
            key_text[i] = st->ColumnText(static_cast<int>(i));
          }
        }
      }
    }
    total += rows;
    on_page(total);
    if (rows < page_rows) return absl::OkStatus();
    page_rows =
        std::clamp<int64_t>(kPageBytes / std::max<int64_t>(1, bytes / rows), 1, kMaxPageRows);
  }
}

// ---- Checks ----------------------------------------------------------------------------------

absl::StatusOr<std::set<std::string>> TextSet(sql::Connection& conn, const char* sql,
                                              std::string_view param) {
  IMUCAL_ASSIGN_OR_RETURN(std::vector<std::string> names,
                          sql::ReadRows(conn, sql, sql::FirstColumnText, param));
  return std::set<std::string>(names.begin(), names.end());
}

// This file's tables and columns are the schema's, on `conn`'s side: a migration that adds a
// table or a column and forgets this copy fails here, before anything is copied.
absl::Status CheckCoversSchema(sql::Connection& conn) {
  const bool lite = conn.dialect() == sql::Dialect::kSqlite;
  const std::string_view side = lite ? "the SQLite file" : "the PostgreSQL database";
  if (lite) {
    IMUCAL_ASSIGN_OR_RETURN(std::vector<std::string> tables,
                            sql::ReadRows(conn, kSqliteTables, sql::FirstColumnText));
    std::set<std::string> known(std::begin(kNotCopied), std::end(kNotCopied));
    for (const CopyTable& t : kTables) known.insert(t.name);
    for (const std::string& table : tables) {
      if (!known.contains(table)) {
        return absl::InternalError(
            Cat(side, " has table ", table, ", which this imucald's copy does not know"));
      }
    }
  }
  for (const CopyTable& t : kTables) {
    IMUCAL_ASSIGN_OR_RETURN(std::set<std::string> have,
                            TextSet(conn, lite ? kSqliteColumns : kPgColumns, t.name));
    std::set<std::string> want;
    for (const CopyColumn& c : t.columns) {
      if (!lite || t.sqlite_rowid_column == nullptr ||
          t.sqlite_rowid_column != std::string_view(c.name))
        want.insert(c.name);
    }
    if (have != want) {
      return absl::InternalError(Cat(side, ": table ", t.name, " has columns (", Join(have, ", "),
                                     "); this imucald's copy knows (", Join(want, ", "), ")"));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<int64_t> Count(sql::Connection& conn, const CopyTable& table) {
  IMUCAL_ASSIGN_OR_RETURN(std::optional<int64_t> n,
                          sql::ReadRow(conn, table.count, sql::FirstColumnInt64));
  return n.value_or(0);
}

// FailedPrecondition naming every table of imucal's that holds rows on `conn`; those that do
// not exist yet (an older schema) hold none.
absl::Status CheckEmpty(sql::Connection& conn, std::string_view where) {
  std::vector<std::string> full;
  for (const CopyTable& t : kTables) {
    IMUCAL_ASSIGN_OR_RETURN(std::optional<int64_t> exists,
                            sql::ReadRow(conn, kPgTableExists, sql::FirstColumnInt64, t.name));
    if (exists.value_or(0) == 0) continue;
    IMUCAL_ASSIGN_OR_RETURN(int64_t rows, Count(conn, t));
    if (rows > 0) full.push_back(Cat(t.name, " (", rows, rows == 1 ? " row)" : " rows)"));
  }
  if (full.empty()) return absl::OkStatus();
  return absl::FailedPreconditionError(
      Cat(where, " already holds data: ", Join(full, ", "),
          ". migrate copies into an empty database only and never merges into one in use: "
          "create a new database for it (createdb), or drop this one if it is a failed "
          "earlier attempt. Nothing was changed there"));
}

// The source as the copy wants it: an imucal file at the latest schema version.
absl::Status CheckSource(const std::string& path) {
  IMUCAL_ASSIGN_OR_RETURN(DatabaseInfo info, InspectDatabase(path, /*check_integrity=*/false));
  if (info.schema_version < LatestSchemaVersion()) {
    return absl::FailedPreconditionError(
        Cat(path, ": schema version ", info.schema_version, ", older than this imucald's ",
            LatestSchemaVersion(),
            ": start this imucald on the file once (it migrates it), stop it, then migrate. The "
            "copy never changes its source"));
  }
  return absl::OkStatus();
}

// A read transaction on the source: every table read inside it comes from one snapshot.
class ReadSnapshot {
 public:
  static absl::StatusOr<ReadSnapshot> Begin(sql::Connection& conn) {
    IMUCAL_RETURN_IF_ERROR(conn.Exec("BEGIN DEFERRED"));
    return ReadSnapshot(&conn);
  }
  ReadSnapshot(ReadSnapshot&& other) noexcept : conn_(std::exchange(other.conn_, nullptr)) {}
  ~ReadSnapshot() {
    if (conn_ != nullptr) (void)conn_->Exec("ROLLBACK");
  }

 private:
  explicit ReadSnapshot(sql::Connection* conn) : conn_(conn) {}
  sql::Connection* conn_;
};

// Opens the destination: refused before anything changes there if it holds rows (at whatever
// schema version), then migrated and checked against this file's tables.
absl::StatusOr<std::unique_ptr<PgConnection>> OpenDestination(const std::string& url,
                                                              const std::string& dest) {
  IMUCAL_ASSIGN_OR_RETURN(std::unique_ptr<PgConnection> pg,
                          PgConnection::Open(url, sql::ConnectionOptions{}));
  IMUCAL_ASSIGN_OR_RETURN(int version, Annotate(dest, SchemaVersion(*pg)));
  if (version > 0) IMUCAL_RETURN_IF_ERROR(CheckEmpty(*pg, dest));
  IMUCAL_RETURN_IF_ERROR(Annotate(Cat("migrate ", dest), Migrate(*pg)));
  IMUCAL_RETURN_IF_ERROR(Annotate(dest, CheckCoversSchema(*pg)));
  return pg;
}

// In the copy's transaction: no other writer until it ends, and still no row anywhere.
absl::Status LockEmptyDestination(sql::Connection& pg, const std::string& dest) {
  if (absl::Status s = pg.Exec(kLockTables); !s.ok()) {
    if (!absl::IsUnavailable(s)) return Annotate(dest, s);
    return absl::UnavailableError(Cat(dest,
                                      ": imucal's tables are in use by another writer (is an "
                                      "imucald serving from it?): ",
                                      s.message()));
  }
  return CheckEmpty(pg, dest);
}

// Copies table `t` from the snapshot on `lite` into `pg`, hashing every row read into `hash`.
absl::StatusOr<TableCopyReport> CopyRows(sql::Connection& lite, sql::Connection& pg,
                                         const CopyTable& t, int64_t snapshot_rows, RowHash& hash,
                                         const CopyProgressFn& progress) {
  TableCopyReport table;
  table.table = t.name;
  const auto copy_row = [&](const sql::Statement& row) -> absl::StatusOr<int64_t> {
    {
      absl::Status s = CheckStorageClasses(row, t);
      IMUCAL_ASSIGN_OR_RETURN(sql::ScopedStatement insert, pg.Prepare(t.insert));
      if (s.ok()) {
        BindRow(row, t, *insert);
        s = insert->Run();
      }
      if (!s.ok()) return WithContext(Cat("row ", KeyOf(row, t)), s);
    }
    const int64_t bytes = hash.Add(row, t);
    ++table.rows;
    table.bytes += bytes;
    return bytes;
  };
  const auto on_page = [&](int64_t done) {
    if (progress) {
      progress({.table = t.name, .phase = "copy", .rows_done = done, .rows_total = snapshot_rows});
    }
  };
  IMUCAL_RETURN_IF_ERROR(ForEachRow(lite, t, copy_row, on_page));
  return table;
}

// Reads table `t` back from `pg` (in the copy's transaction) and compares it with what was
// copied: as many rows as the snapshot's count(*) and as were copied, and the same SHA-256.
absl::Status VerifyRows(sql::Connection& pg, const CopyTable& t, int64_t snapshot_rows,
                        TableCopyReport& copied, RowHash& source_hash, const std::string& dest,
                        const CopyProgressFn& progress) {
  RowHash dest_hash;
  int64_t dest_rows = 0;
  const auto hash_row = [&](const sql::Statement& row) -> absl::StatusOr<int64_t> {
    ++dest_rows;
    return dest_hash.Add(row, t);
  };
  const auto on_page = [&](int64_t done) {
    if (progress) {
      progress({.table = t.name, .phase = "verify", .rows_done = done, .rows_total = copied.rows});
    }
  };
  IMUCAL_RETURN_IF_ERROR(ForEachRow(pg, t, hash_row, on_page));
  copied.sha256_hex = source_hash.Hex();
  const std::string dest_hex = dest_hash.Hex();
  if (dest_rows == copied.rows && copied.rows == snapshot_rows && dest_hex == copied.sha256_hex) {
    return absl::OkStatus();
  }
  return absl::DataLossError(Cat("the rows read back from ", dest,
                                 " differ from the SQLite source (", snapshot_rows,
                                 " rows in the snapshot, ", copied.rows, " copied, ", dest_rows,
                                 " read back; SHA-256 ", copied.sha256_hex.substr(0, 16), " vs ",
                                 dest_hex.substr(0, 16), "): rolled back, nothing was committed"));
}

}  // namespace

std::span<const CopyTable> CopyTables() { return kTables; }

int64_t CopyReport::rows() const {
  int64_t n = 0;
  for (const TableCopyReport& t : tables) n += t.rows;
  return n;
}

int64_t CopyReport::bytes() const {
  int64_t n = 0;
  for (const TableCopyReport& t : tables) n += t.bytes;
  return n;
}

absl::StatusOr<CopyReport> CopySqliteToPostgres(const std::string& sqlite_path,
                                                const std::string& pg_url,
                                                const CopyProgressFn& progress) {
  const absl::Time start = absl::Now();
  if (sql::IsPostgresUrl(sqlite_path)) {
    return absl::InvalidArgumentError("the source must be a SQLite file, not a URL");
  }
  if (!sql::IsPostgresUrl(pg_url)) {
    return absl::InvalidArgumentError(Cat("the destination must be a postgresql:// URL, got '",
                                          sql::RedactedLocation(pg_url), "'"));
  }
  const std::string dest = sql::RedactedLocation(pg_url);
  IMUCAL_RETURN_IF_ERROR(CheckSource(sqlite_path));
  IMUCAL_ASSIGN_OR_RETURN(std::unique_ptr<PgConnection> pg, OpenDestination(pg_url, dest));

  IMUCAL_ASSIGN_OR_RETURN(
      std::unique_ptr<sql::SqliteConnection> lite,
      Annotate(sqlite_path, sql::SqliteConnection::Open(
                                sqlite_path, sql::ConnectionOptions{.read_only = true})));
  IMUCAL_ASSIGN_OR_RETURN(ReadSnapshot snapshot, Annotate(sqlite_path, ReadSnapshot::Begin(*lite)));
  // The snapshot begins with this first read; every read below is from it.
  IMUCAL_ASSIGN_OR_RETURN(int version, Annotate(sqlite_path, SchemaVersion(*lite)));
  if (version != LatestSchemaVersion()) {
    return absl::FailedPreconditionError(
        Cat(sqlite_path, ": its schema version became ", version, " after it was checked"));
  }
  IMUCAL_RETURN_IF_ERROR(Annotate(sqlite_path, CheckCoversSchema(*lite)));
  std::vector<int64_t> snapshot_rows;
  for (const CopyTable& t : kTables) {
    IMUCAL_ASSIGN_OR_RETURN(int64_t rows, Annotate(sqlite_path, Count(*lite, t)));
    snapshot_rows.push_back(rows);
  }

  IMUCAL_ASSIGN_OR_RETURN(sql::Transaction txn, Annotate(dest, sql::Transaction::Begin(*pg)));
  IMUCAL_RETURN_IF_ERROR(LockEmptyDestination(*pg, dest));
  CopyReport report;
  report.schema_version = version;
  std::vector<RowHash> source_hash(std::size(kTables));
  for (size_t i = 0; i < std::size(kTables); ++i) {
    IMUCAL_ASSIGN_OR_RETURN(
        TableCopyReport table,
        Annotate(Cat("copy ", kTables[i].name),
                 CopyRows(*lite, *pg, kTables[i], snapshot_rows[i], source_hash[i], progress)));
    report.tables.push_back(std::move(table));
  }
  for (size_t i = 0; i < std::size(kTables); ++i) {
    IMUCAL_RETURN_IF_ERROR(Annotate(Cat("verify ", kTables[i].name),
                                    VerifyRows(*pg, kTables[i], snapshot_rows[i], report.tables[i],
                                               source_hash[i], dest, progress)));
  }
  // New rows continue after the copied ids (an empty table's sequence stays where it is).
  for (const CopyTable& t : kTables) {
    if (t.reset_identity == nullptr) continue;
    IMUCAL_RETURN_IF_ERROR(Annotate(
        Cat("copy ", t.name), sql::ReadRow(*pg, t.reset_identity, sql::FirstColumnInt64).status()));
  }
  IMUCAL_RETURN_IF_ERROR(Annotate(Cat("commit to ", dest), txn.Commit()));
  report.took = absl::Now() - start;
  return report;
}

}  // namespace imucal::storage
