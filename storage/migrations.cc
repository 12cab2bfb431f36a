#include "storage/migrations.h"

#include <optional>

#include "util/str_util.h"

namespace imucal::storage {
namespace {

// Version 1: the whole service schema.
// - Times are INTEGER microseconds since the Unix epoch (UTC).
// - State names match types.cc; CHECK constraints keep garbage out of the indexed columns.
// - Partial unique indexes state invariants in the database itself: at most one open session
//   per device, one running solve per session, one active parameter version per device. The
//   last is also the hot path: GetActive is a single lookup in `param_versions_active`.
// - A session's last acknowledged seq is MAX(seq) of its batches and its sample count the
//   last batch's end_sample (a running total), so an append writes one row and nothing else: no
//   counter in `sessions` to keep in sync, and no page of it rewritten per batch.
// - param_versions: a rowid table (rows hold kilobytes of JSON, too big for WITHOUT ROWID);
//   report_json is the last column, which the hot path never reads. (session_id, device_id)
//   references sessions so a version cannot claim another device's session.
constexpr char kSchemaV1[] = R"sql(
CREATE TABLE devices (
  id TEXT NOT NULL PRIMARY KEY,
  sensor_model TEXT NOT NULL,
  nominal_rate_hz REAL NOT NULL CHECK (nominal_rate_hz >= 0),
  accel_unit TEXT NOT NULL,
  gyro_unit TEXT NOT NULL,
  created_at_us INTEGER NOT NULL
);

CREATE TABLE sessions (
  id TEXT NOT NULL PRIMARY KEY,
  device_id TEXT NOT NULL REFERENCES devices (id),
  state TEXT NOT NULL CHECK (state IN ('open', 'solving', 'solved', 'cancelled', 'failed')),
  protocol TEXT NOT NULL,
  gravity_m_s2 REAL NOT NULL CHECK (gravity_m_s2 > 0),
  created_at_us INTEGER NOT NULL,
  updated_at_us INTEGER NOT NULL,
  UNIQUE (id, device_id)
);
CREATE INDEX sessions_by_device ON sessions (device_id);
CREATE UNIQUE INDEX sessions_one_open ON sessions (device_id) WHERE state = 'open';

CREATE TABLE sample_batches (
  session_id TEXT NOT NULL REFERENCES sessions (id),
  seq INTEGER NOT NULL CHECK (seq >= 1),
  first_t_s REAL NOT NULL,
  last_t_s REAL NOT NULL CHECK (last_t_s >= first_t_s),
  count INTEGER NOT NULL CHECK (count >= 1),
  end_sample INTEGER NOT NULL CHECK (end_sample >= count),
  payload BLOB NOT NULL,
  PRIMARY KEY (session_id, seq)
);

CREATE TABLE poses (
  session_id TEXT NOT NULL REFERENCES sessions (id),
  pose_index INTEGER NOT NULL CHECK (pose_index >= 0),
  t_start_s REAL NOT NULL,
  t_end_s REAL NOT NULL,
  used INTEGER NOT NULL CHECK (used IN (0, 1)),
  reason TEXT NOT NULL,
  detail_json TEXT NOT NULL,
  PRIMARY KEY (session_id, pose_index)
) WITHOUT ROWID;

CREATE TABLE solves (
  id INTEGER PRIMARY KEY,
  session_id TEXT NOT NULL REFERENCES sessions (id),
  state TEXT NOT NULL CHECK (state IN ('running', 'succeeded', 'failed')),
  actor TEXT NOT NULL,
  started_at_us INTEGER NOT NULL,
  finished_at_us INTEGER,
  version INTEGER NOT NULL DEFAULT 0,
  error TEXT NOT NULL DEFAULT '',
  report_json TEXT NOT NULL DEFAULT ''
);
CREATE INDEX solves_by_session ON solves (session_id);
CREATE UNIQUE INDEX solves_one_running ON solves (session_id) WHERE state = 'running';

CREATE TABLE param_versions (
  device_id TEXT NOT NULL REFERENCES devices (id),
  version INTEGER NOT NULL CHECK (version >= 1),
  created_at_us INTEGER NOT NULL,
  session_id TEXT,
  verdict TEXT NOT NULL CHECK (verdict IN ('pass', 'warn', 'fail')),
  accel_rms REAL,
  state TEXT NOT NULL CHECK (state IN ('candidate', 'active', 'superseded', 'rejected')),
  provenance TEXT NOT NULL,
  params_json TEXT NOT NULL,
  report_json TEXT NOT NULL,
  UNIQUE (device_id, version),
  FOREIGN KEY (session_id, device_id) REFERENCES sessions (id, device_id)
);
CREATE UNIQUE INDEX param_versions_active ON param_versions (device_id) WHERE state = 'active';

CREATE TABLE audit_log (
  id INTEGER PRIMARY KEY,
  time_us INTEGER NOT NULL,
  actor TEXT NOT NULL,
  action TEXT NOT NULL,
  target TEXT NOT NULL,
  detail TEXT NOT NULL
);
CREATE INDEX audit_by_target ON audit_log (target, id);

PRAGMA user_version = 1;
)sql";

// Version 2: the online segmentation's poses and six-face pair verdicts, stored as the server
// judges them. A pose's face ("Z+", "" off the faces) becomes a column (the guide lists it);
// pair verdicts are keyed by their two pose indexes: a pair is judged once, so a replay after a
// restart rewrites the same rows.
constexpr char kSchemaV2[] = R"sql(
ALTER TABLE poses ADD COLUMN face TEXT NOT NULL DEFAULT '';

CREATE TABLE pose_pairs (
  session_id TEXT NOT NULL REFERENCES sessions (id),
  pose_a INTEGER NOT NULL CHECK (pose_a >= 0),
  pose_b INTEGER NOT NULL CHECK (pose_b > pose_a),
  ok INTEGER NOT NULL CHECK (ok IN (0, 1)),
  face TEXT NOT NULL,
  rotation_deg REAL NOT NULL,
  tilt_deg REAL NOT NULL,
  reason TEXT NOT NULL,
  PRIMARY KEY (session_id, pose_a, pose_b)
) WITHOUT ROWID;

PRAGMA user_version = 2;
)sql";

// Version 3: API tokens (storage/tokens.h). Only the SHA-256 of a token's secret is stored: the
// secret is a random 256-bit value, so a plain hash cannot be reversed by guessing and needs no
// salt or slow KDF, and a lookup is one probe of the unique index on the hash. A robot token is
// bound to one device (no foreign key: a robot may be provisioned before it first registers);
// the other roles are bound to none. Revocation keeps the row (the audit log refers to it).
constexpr char kSchemaV3[] = R"sql(
CREATE TABLE tokens (
  id INTEGER PRIMARY KEY,
  secret_sha256 BLOB NOT NULL UNIQUE CHECK (length(secret_sha256) = 32),
  role TEXT NOT NULL CHECK (role IN ('robot', 'technician', 'admin')),
  device_id TEXT,
  label TEXT NOT NULL,
  created_at_us INTEGER NOT NULL,
  revoked_at_us INTEGER,
  CHECK ((role = 'robot') = (device_id IS NOT NULL))
);
PRAGMA user_version = 3;
)sql";

// Version 4: a session's source, the name of the capture it holds (a file the CLI uploaded, a
// robot's capture label), so that a stream that tries to continue it with another capture is
// refused naming both (server/ingest_reactor.cc).
constexpr char kSchemaV4[] = R"sql(
ALTER TABLE sessions ADD COLUMN source TEXT NOT NULL DEFAULT '';
PRAGMA user_version = 4;
)sql";

// Version 5: who runs a solve, and until when it has said so. Several servers may share one
// database; a solve whose server stopped renewing its lease is an orphan any of them may end,
// while another server's live solve is left alone (store.h "Solves").
constexpr char kSchemaV5[] = R"sql(
ALTER TABLE solves ADD COLUMN owner TEXT NOT NULL DEFAULT '';
ALTER TABLE solves ADD COLUMN lease_until_us INTEGER NOT NULL DEFAULT 0;
PRAGMA user_version = 5;
)sql";

// Version 6: what a server needs to run a solve again when the server that started it stopped
// (Store::ClaimLapsedSolve): the seed it was asked for, so that the result is the one the request
// would have had, and how many servers have started it, so that a solve that stops every server
// that runs it is failed rather than passed on for ever.
constexpr char kSchemaV6[] = R"sql(
ALTER TABLE solves ADD COLUMN seed INTEGER NOT NULL DEFAULT 1;
ALTER TABLE solves ADD COLUMN attempts INTEGER NOT NULL DEFAULT 1 CHECK (attempts >= 1);
PRAGMA user_version = 6;
)sql";

// Version 7: what servers sharing one database must agree on as it happens.
// - stream_claims: the one open sample stream of a device, whichever server has it (store.h
//   "Stream claims"): the holder (a server's instance) renews its lease while the stream is
//   open and deletes the row when it ends; a row whose lease lapsed (its server died) may be
//   taken by another.
// - token_changes: every change to a token row, by anyone (a server, a tool, SQL typed by
//   hand), logged by triggers, so that each server finds the revocations it has not made
//   itself by reading what follows the last entry it read (TokenStore::ChangesSince). On
//   PostgreSQL the same triggers also NOTIFY imucal_token.
constexpr char kSchemaV7[] = R"sql(
CREATE TABLE stream_claims (
  device_id TEXT NOT NULL PRIMARY KEY,
  holder TEXT NOT NULL,
  session_id TEXT NOT NULL,
  lease_until_us INTEGER NOT NULL
);
CREATE INDEX stream_claims_by_holder ON stream_claims (holder);

CREATE TABLE token_changes (
  id INTEGER PRIMARY KEY,
  token_id INTEGER NOT NULL
);
CREATE TRIGGER tokens_inserted AFTER INSERT ON tokens
BEGIN INSERT INTO token_changes (token_id) VALUES (NEW.id); END;
CREATE TRIGGER tokens_updated AFTER UPDATE ON tokens
BEGIN INSERT INTO token_changes (token_id) VALUES (NEW.id); END;
CREATE TRIGGER tokens_deleted AFTER DELETE ON tokens
BEGIN INSERT INTO token_changes (token_id) VALUES (OLD.id); END;

PRAGMA user_version = 7;
)sql";

constexpr Migration kMigrations[] = {
    {1, kSchemaV1}, {2, kSchemaV2}, {3, kSchemaV3}, {4, kSchemaV4},
    {5, kSchemaV5}, {6, kSchemaV6}, {7, kSchemaV7},
};

// ---- PostgreSQL: the same schema, version for version ------------------------------------------
// Each migration N here makes the schema that SQLite's migration N makes, in PostgreSQL's types:
// INTEGER -> BIGINT, REAL -> DOUBLE PRECISION, BLOB -> BYTEA, INTEGER PRIMARY KEY -> an identity
// column. Keys that the store pages through (device ids) compare byte by byte (COLLATE "C"), as
// SQLite's BINARY collation does, whatever the database's locale. `sessions.rowid` stands in for
// SQLite's implicit rowid (sessions are listed in creation order). The version is kept in the
// one-row table imucal_schema, which Migrate creates.
constexpr char kPgSchemaV1[] = R"sql(
CREATE TABLE devices (
  id TEXT COLLATE "C" NOT NULL PRIMARY KEY,
  sensor_model TEXT NOT NULL,
  nominal_rate_hz DOUBLE PRECISION NOT NULL CHECK (nominal_rate_hz >= 0),
  accel_unit TEXT NOT NULL,
  gyro_unit TEXT NOT NULL,
  created_at_us BIGINT NOT NULL
);

CREATE TABLE sessions (
  rowid BIGINT GENERATED BY DEFAULT AS IDENTITY UNIQUE,
  id TEXT COLLATE "C" NOT NULL PRIMARY KEY,
  device_id TEXT COLLATE "C" NOT NULL REFERENCES devices (id),
  state TEXT NOT NULL CHECK (state IN ('open', 'solving', 'solved', 'cancelled', 'failed')),
  protocol TEXT NOT NULL,
  gravity_m_s2 DOUBLE PRECISION NOT NULL CHECK (gravity_m_s2 > 0),
  created_at_us BIGINT NOT NULL,
  updated_at_us BIGINT NOT NULL,
  UNIQUE (id, device_id)
);
CREATE INDEX sessions_by_device ON sessions (device_id);
CREATE UNIQUE INDEX sessions_one_open ON sessions (device_id) WHERE state = 'open';

CREATE TABLE sample_batches (
  session_id TEXT COLLATE "C" NOT NULL REFERENCES sessions (id),
  seq BIGINT NOT NULL CHECK (seq >= 1),
  first_t_s DOUBLE PRECISION NOT NULL,
  last_t_s DOUBLE PRECISION NOT NULL CHECK (last_t_s >= first_t_s),
  count BIGINT NOT NULL CHECK (count >= 1),
  end_sample BIGINT NOT NULL CHECK (end_sample >= count),
  payload BYTEA NOT NULL,
  PRIMARY KEY (session_id, seq)
);

CREATE TABLE poses (
  session_id TEXT COLLATE "C" NOT NULL REFERENCES sessions (id),
  pose_index BIGINT NOT NULL CHECK (pose_index >= 0),
  t_start_s DOUBLE PRECISION NOT NULL,
  t_end_s DOUBLE PRECISION NOT NULL,
  used BIGINT NOT NULL CHECK (used IN (0, 1)),
  reason TEXT NOT NULL,
  detail_json TEXT NOT NULL,
  PRIMARY KEY (session_id, pose_index)
);

CREATE TABLE solves (
  id BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY,
  session_id TEXT COLLATE "C" NOT NULL REFERENCES sessions (id),
  state TEXT NOT NULL CHECK (state IN ('running', 'succeeded', 'failed')),
  actor TEXT NOT NULL,
  started_at_us BIGINT NOT NULL,
  finished_at_us BIGINT,
  version BIGINT NOT NULL DEFAULT 0,
  error TEXT NOT NULL DEFAULT '',
  report_json TEXT NOT NULL DEFAULT ''
);
CREATE INDEX solves_by_session ON solves (session_id);
CREATE UNIQUE INDEX solves_one_running ON solves (session_id) WHERE state = 'running';

CREATE TABLE param_versions (
  device_id TEXT COLLATE "C" NOT NULL REFERENCES devices (id),
  version BIGINT NOT NULL CHECK (version >= 1),
  created_at_us BIGINT NOT NULL,
  session_id TEXT COLLATE "C",
  verdict TEXT NOT NULL CHECK (verdict IN ('pass', 'warn', 'fail')),
  accel_rms DOUBLE PRECISION,
  state TEXT NOT NULL CHECK (state IN ('candidate', 'active', 'superseded', 'rejected')),
  provenance TEXT NOT NULL,
  params_json TEXT NOT NULL,
  report_json TEXT NOT NULL,
  UNIQUE (device_id, version),
  FOREIGN KEY (session_id, device_id) REFERENCES sessions (id, device_id)
);
CREATE UNIQUE INDEX param_versions_active ON param_versions (device_id) WHERE state = 'active';

CREATE TABLE audit_log (
  id BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY,
  time_us BIGINT NOT NULL,
  actor TEXT NOT NULL,
  action TEXT NOT NULL,
  target TEXT COLLATE "C" NOT NULL,
  detail TEXT NOT NULL
);
CREATE INDEX audit_by_target ON audit_log (target, id);

UPDATE imucal_schema SET version = 1;
)sql";

constexpr char kPgSchemaV2[] = R"sql(
ALTER TABLE poses ADD COLUMN face TEXT NOT NULL DEFAULT '';

CREATE TABLE pose_pairs (
  session_id TEXT COLLATE "C" NOT NULL REFERENCES sessions (id),
  pose_a BIGINT NOT NULL CHECK (pose_a >= 0),
  pose_b BIGINT NOT NULL CHECK (pose_b > pose_a),
  ok BIGINT NOT NULL CHECK (ok IN (0, 1)),
  face TEXT NOT NULL,
  rotation_deg DOUBLE PRECISION NOT NULL,
  tilt_deg DOUBLE PRECISION NOT NULL,
  reason TEXT NOT NULL,
  PRIMARY KEY (session_id, pose_a, pose_b)
);

UPDATE imucal_schema SET version = 2;
)sql";

constexpr char kPgSchemaV3[] = R"sql(
CREATE TABLE tokens (
  id BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY,
  secret_sha256 BYTEA NOT NULL UNIQUE CHECK (length(secret_sha256) = 32),
  role TEXT NOT NULL CHECK (role IN ('robot', 'technician', 'admin')),
  device_id TEXT COLLATE "C",
  label TEXT NOT NULL,
  created_at_us BIGINT NOT NULL,
  revoked_at_us BIGINT,
  CHECK ((role = 'robot') = (device_id IS NOT NULL))
);
UPDATE imucal_schema SET version = 3;
)sql";

constexpr char kPgSchemaV4[] = R"sql(
ALTER TABLE sessions ADD COLUMN source TEXT NOT NULL DEFAULT '';
UPDATE imucal_schema SET version = 4;
)sql";

constexpr char kPgSchemaV5[] = R"sql(
ALTER TABLE solves ADD COLUMN owner TEXT NOT NULL DEFAULT '';
ALTER TABLE solves ADD COLUMN lease_until_us BIGINT NOT NULL DEFAULT 0;
UPDATE imucal_schema SET version = 5;
)sql";

constexpr char kPgSchemaV6[] = R"sql(
ALTER TABLE solves ADD COLUMN seed BIGINT NOT NULL DEFAULT 1;
ALTER TABLE solves ADD COLUMN attempts BIGINT NOT NULL DEFAULT 1 CHECK (attempts >= 1);
UPDATE imucal_schema SET version = 6;
)sql";

// The trigger runs in the writing transaction: the change is logged, and the NOTIFY sent, only
// if it commits (a NOTIFY is delivered at commit, to every listener).
constexpr char kPgSchemaV7[] = R"sql(
CREATE TABLE stream_claims (
  device_id TEXT COLLATE "C" NOT NULL PRIMARY KEY,
  holder TEXT NOT NULL,
  session_id TEXT COLLATE "C" NOT NULL,
  lease_until_us BIGINT NOT NULL
);
CREATE INDEX stream_claims_by_holder ON stream_claims (holder);

CREATE TABLE token_changes (
  id BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY,
  token_id BIGINT NOT NULL
);
CREATE FUNCTION imucal_token_changed() RETURNS trigger LANGUAGE plpgsql AS $$
DECLARE
  changed BIGINT;
BEGIN
  IF TG_OP = 'DELETE' THEN changed := OLD.id; ELSE changed := NEW.id; END IF;
  INSERT INTO token_changes (token_id) VALUES (changed);
  PERFORM pg_notify('imucal_token', changed::text);
  RETURN NULL;
END;
$$;
CREATE TRIGGER tokens_changed AFTER INSERT OR UPDATE OR DELETE ON tokens
  FOR EACH ROW EXECUTE FUNCTION imucal_token_changed();

UPDATE imucal_schema SET version = 7;
)sql";

constexpr Migration kPgMigrations[] = {
    {1, kPgSchemaV1}, {2, kPgSchemaV2}, {3, kPgSchemaV3}, {4, kPgSchemaV4},
    {5, kPgSchemaV5}, {6, kPgSchemaV6}, {7, kPgSchemaV7},
};

// Held for the whole of Migrate on PostgreSQL (a session-level advisory lock), so that replicas
// starting together create imucal_schema and apply each migration once.
constexpr char kPgMigrateLock[] = "SELECT pg_advisory_lock(7305310)";
constexpr char kPgMigrateUnlock[] = "SELECT pg_advisory_unlock(7305310)";
constexpr char kPgCreateVersionTable[] =
    "CREATE TABLE IF NOT EXISTS imucal_schema (version INTEGER NOT NULL); "
    "INSERT INTO imucal_schema (version) SELECT 0 WHERE NOT EXISTS (SELECT 1 FROM imucal_schema)";

absl::Status ApplyOne(sql::Connection& conn, const Migration& m) {
  absl::StatusOr<sql::Transaction> txn = sql::Transaction::Begin(conn);
  if (!txn.ok()) return txn.status();
  // Read inside the write lock: another process may have applied it meanwhile.
  absl::StatusOr<int> current = SchemaVersion(conn);
  if (!current.ok()) return current.status();
  if (*current >= m.version) return absl::OkStatus();
  if (absl::Status s = conn.Exec(m.sql); !s.ok()) {
    return absl::Status(s.code(), Cat("migration ", m.version, ": ", s.message()));
  }
  absl::StatusOr<int> after = SchemaVersion(conn);
  if (!after.ok()) return after.status();
  if (*after != m.version) {
    return absl::InternalError(
        Cat("migration ", m.version, " did not set the schema version to its number (got ", *after,
            ")"));
  }
  return txn->Commit();
}

}  // namespace

absl::Status MigrateLocked(sql::Connection& conn, std::span<const Migration> migrations);

std::span<const Migration> Migrations(sql::Dialect dialect) {
  if (dialect == sql::Dialect::kPostgres) return kPgMigrations;
  return kMigrations;
}

int LatestSchemaVersion() { return Migrations().back().version; }

absl::StatusOr<int> SchemaVersion(sql::Connection& conn) {
  if (conn.dialect() == sql::Dialect::kPostgres) {
    absl::StatusOr<std::optional<int64_t>> exists = sql::ReadRow(
        conn, "SELECT to_regclass('imucal_schema') IS NOT NULL", sql::FirstColumnInt64);
    if (!exists.ok()) return exists.status();
    if (exists->value_or(0) == 0) return 0;
  }
  const char* sql = conn.dialect() == sql::Dialect::kPostgres ? "SELECT version FROM imucal_schema"
                                                              : "PRAGMA user_version";
  absl::StatusOr<std::optional<int64_t>> version = sql::ReadRow(conn, sql, sql::FirstColumnInt64);
  if (!version.ok()) return version.status();
  if (!*version) return absl::InternalError(Cat(sql, " returned no row"));
  return static_cast<int>(**version);
}

absl::Status Migrate(sql::Connection& conn) { return Migrate(conn, Migrations(conn.dialect())); }

absl::Status Migrate(sql::Connection& conn, std::span<const Migration> migrations) {
  if (conn.dialect() == sql::Dialect::kPostgres) {
    if (absl::Status s = conn.Exec(kPgMigrateLock); !s.ok()) return s;
    absl::Status s = conn.Exec(kPgCreateVersionTable);
    if (s.ok()) s = MigrateLocked(conn, migrations);
    if (absl::Status u = conn.Exec(kPgMigrateUnlock); s.ok()) s = u;
    return s;
  }
  return MigrateLocked(conn, migrations);
}

absl::Status MigrateLocked(sql::Connection& conn, std::span<const Migration> migrations) {
  for (size_t i = 0; i < migrations.size(); ++i) {
    if (migrations[i].version != static_cast<int>(i) + 1) {
      return absl::InternalError(
          Cat("migration #", i, " has version ", migrations[i].version, ", expected ", i + 1));
    }
  }
  absl::StatusOr<int> current = SchemaVersion(conn);
  if (!current.ok()) return current.status();
  const int latest = static_cast<int>(migrations.size());
  if (*current > latest) {
    return absl::FailedPreconditionError(Cat("the database has schema version ", *current,
                                             ", newer than this program's ", latest,
                                             ": upgrade the program"));
  }
  for (const Migration& m : migrations) {
    if (m.version <= *current) continue;
    if (absl::Status s = ApplyOne(conn, m); !s.ok()) return s;
  }
  return absl::OkStatus();
}

}  // namespace imucal::storage
