#include "storage/store.h"

#include <chrono>
#include <cmath>
#include <random>
#include <type_traits>
#include <utility>

#include "absl/strings/str_format.h"
#include "storage/migrations.h"
#include "storage/sample_codec.h"
#include "storage/sqlite_db.h"
#include "storage/status_macros.h"
#include "storage/str_util.h"

namespace imucal::storage {
namespace {

// ---- SQL. Every statement is a constant, prepared once per connection. ---------------------

// active_version: a lookup in the partial index param_versions_active.
constexpr char kSelectDevice[] =
    "SELECT d.id, d.sensor_model, d.nominal_rate_hz, d.accel_unit, d.gyro_unit, "
    "d.created_at_us, COALESCE((SELECT v.version FROM param_versions v "
    "WHERE v.device_id = d.id AND v.state = 'active'), 0) "
    "FROM devices d WHERE d.id = ?1";
constexpr char kSelectDevices[] =
    "SELECT d.id, d.sensor_model, d.nominal_rate_hz, d.accel_unit, d.gyro_unit, "
    "d.created_at_us, COALESCE((SELECT v.version FROM param_versions v "
    "WHERE v.device_id = d.id AND v.state = 'active'), 0) "
    "FROM devices d WHERE d.id > ?1 ORDER BY d.id LIMIT ?2";
constexpr char kInsertDevice[] =
    "INSERT INTO devices (id, sensor_model, nominal_rate_hz, accel_unit, gyro_unit, "
    "created_at_us) VALUES (?1, ?2, ?3, ?4, ?5, ?6)";

// Sessions: three statements with the same columns (ReadSession). The derived ones are the last
// batch's seq and running sample total (seeks backwards on the batches' primary key), the
// accepted poses, and the version of the latest successful solve.
constexpr char kSelectSession[] =
    "SELECT s.id, s.device_id, s.state, s.protocol, s.gravity_m_s2, s.created_at_us, "
    "s.updated_at_us, "
    "COALESCE((SELECT b.seq FROM sample_batches b WHERE b.session_id = s.id "
    "ORDER BY b.seq DESC LIMIT 1), 0), "
    "COALESCE((SELECT b.end_sample FROM sample_batches b WHERE b.session_id = s.id "
    "ORDER BY b.seq DESC LIMIT 1), 0), "
    "(SELECT COUNT(*) FROM poses p WHERE p.session_id = s.id AND p.used = 1), "
    "COALESCE((SELECT v.version FROM solves v WHERE v.session_id = s.id "
    "AND v.state = 'succeeded' ORDER BY v.id DESC LIMIT 1), 0) "
    "FROM sessions s WHERE s.id = ?1";
// Lists page by rowid (creation order): ?3 is the rowid of the previous page's last session.
constexpr char kSelectSessionsOfDevice[] =
    "SELECT s.id, s.device_id, s.state, s.protocol, s.gravity_m_s2, s.created_at_us, "
    "s.updated_at_us, "
    "COALESCE((SELECT b.seq FROM sample_batches b WHERE b.session_id = s.id "
    "ORDER BY b.seq DESC LIMIT 1), 0), "
    "COALESCE((SELECT b.end_sample FROM sample_batches b WHERE b.session_id = s.id "
    "ORDER BY b.seq DESC LIMIT 1), 0), "
    "(SELECT COUNT(*) FROM poses p WHERE p.session_id = s.id AND p.used = 1), "
    "COALESCE((SELECT v.version FROM solves v WHERE v.session_id = s.id "
    "AND v.state = 'succeeded' ORDER BY v.id DESC LIMIT 1), 0) "
    "FROM sessions s WHERE s.device_id = ?1 AND (?2 IS NULL OR s.state = ?2) AND s.rowid > ?3 "
    "ORDER BY s.rowid LIMIT ?4";
constexpr char kSelectSessionsAll[] =
    "SELECT s.id, s.device_id, s.state, s.protocol, s.gravity_m_s2, s.created_at_us, "
    "s.updated_at_us, "
    "COALESCE((SELECT b.seq FROM sample_batches b WHERE b.session_id = s.id "
    "ORDER BY b.seq DESC LIMIT 1), 0), "
    "COALESCE((SELECT b.end_sample FROM sample_batches b WHERE b.session_id = s.id "
    "ORDER BY b.seq DESC LIMIT 1), 0), "
    "(SELECT COUNT(*) FROM poses p WHERE p.session_id = s.id AND p.used = 1), "
    "COALESCE((SELECT v.version FROM solves v WHERE v.session_id = s.id "
    "AND v.state = 'succeeded' ORDER BY v.id DESC LIMIT 1), 0) "
    "FROM sessions s WHERE (?2 IS NULL OR s.state = ?2) AND s.rowid > ?3 "
    "ORDER BY s.rowid LIMIT ?4";
constexpr char kSelectSessionRowid[] = "SELECT rowid FROM sessions WHERE id = ?1";
constexpr char kSelectOpenSessionOfDevice[] =
    "SELECT id FROM sessions WHERE device_id = ?1 AND state = 'open'";
constexpr char kInsertSession[] =
    "INSERT INTO sessions (id, device_id, state, protocol, gravity_m_s2, created_at_us, "
    "updated_at_us) VALUES (?1, ?2, 'open', ?3, ?4, ?5, ?5)";
constexpr char kUpdateSessionState[] =
    "UPDATE sessions SET state = ?2, updated_at_us = ?3 WHERE id = ?1";
constexpr char kSessionExists[] = "SELECT 1 FROM sessions WHERE id = ?1";
constexpr char kSelectSessionStateForAppend[] = "SELECT state FROM sessions WHERE id = ?1";

constexpr char kSelectLastBatch[] =
    "SELECT seq, last_t_s, end_sample FROM sample_batches WHERE session_id = ?1 "
    "ORDER BY seq DESC LIMIT 1";
constexpr char kSelectBatchPayload[] =
    "SELECT payload FROM sample_batches WHERE session_id = ?1 AND seq = ?2";
constexpr char kInsertBatch[] =
    "INSERT INTO sample_batches (session_id, seq, first_t_s, last_t_s, count, end_sample, "
    "payload) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)";
constexpr char kSelectBatches[] =
    "SELECT seq, first_t_s, last_t_s, count, payload FROM sample_batches "
    "WHERE session_id = ?1 AND seq > ?2 ORDER BY seq";

constexpr char kDeletePoses[] = "DELETE FROM poses WHERE session_id = ?1";
constexpr char kInsertPose[] =
    "INSERT INTO poses (session_id, pose_index, t_start_s, t_end_s, used, reason, detail_json, "
    "face) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)";
constexpr char kUpsertPose[] =
    "INSERT OR REPLACE INTO poses (session_id, pose_index, t_start_s, t_end_s, used, reason, "
    "detail_json, face) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)";
constexpr char kUpsertPair[] =
    "INSERT OR REPLACE INTO pose_pairs (session_id, pose_a, pose_b, ok, face, rotation_deg, "
    "tilt_deg, reason) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)";
constexpr char kSelectPairs[] =
    "SELECT pose_a, pose_b, ok, face, rotation_deg, tilt_deg, reason FROM pose_pairs "
    "WHERE session_id = ?1 ORDER BY pose_a, pose_b";
constexpr char kSelectPoses[] =
    "SELECT pose_index, t_start_s, t_end_s, used, reason, detail_json, face FROM poses "
    "WHERE session_id = ?1 ORDER BY pose_index";

constexpr char kSelectSolve[] =
    "SELECT id, session_id, state, actor, started_at_us, finished_at_us, version, error, "
    "report_json FROM solves WHERE id = ?1";
constexpr char kSelectSolvesOfSession[] =
    "SELECT id, session_id, state, actor, started_at_us, finished_at_us, version, error, "
    "report_json FROM solves WHERE session_id = ?1 ORDER BY id";
constexpr char kSelectRunningSolves[] =
    "SELECT id, session_id, state, actor, started_at_us, finished_at_us, version, error, "
    "report_json FROM solves WHERE state = 'running' ORDER BY id";
constexpr char kInsertSolve[] =
    "INSERT INTO solves (session_id, state, actor, started_at_us) VALUES (?1, 'running', ?2, ?3)";
constexpr char kFinishSolve[] =
    "UPDATE solves SET state = ?2, finished_at_us = ?3, version = ?4, error = ?5, "
    "report_json = ?6 WHERE id = ?1";
constexpr char kAbandonRunningSolves[] =
    "UPDATE solves SET state = 'failed', finished_at_us = ?2, error = ?3 "
    "WHERE session_id = ?1 AND state = 'running'";

// The hot path. `state = 'active'` is a literal so the planner can use the partial index
// param_versions_active (migrations_test checks the plan). report_json is not read.
constexpr char kSelectActiveVersion[] =
    "SELECT device_id, version, created_at_us, session_id, verdict, accel_rms, state, "
    "provenance, params_json FROM param_versions WHERE device_id = ?1 AND state = 'active'";
constexpr char kSelectVersion[] =
    "SELECT device_id, version, created_at_us, session_id, verdict, accel_rms, state, "
    "provenance, params_json, report_json FROM param_versions "
    "WHERE device_id = ?1 AND version = ?2";
constexpr char kSelectVersionsOfDevice[] =
    "SELECT device_id, version, created_at_us, session_id, verdict, accel_rms, state, "
    "provenance, params_json, report_json FROM param_versions "
    "WHERE device_id = ?1 AND version > ?2 ORDER BY version LIMIT ?3";
// The same without the documents, which are most of each row's bytes.
constexpr char kSelectVersionHeadersOfDevice[] =
    "SELECT device_id, version, created_at_us, session_id, verdict, accel_rms, state, "
    "provenance FROM param_versions "
    "WHERE device_id = ?1 AND version > ?2 ORDER BY version LIMIT ?3";
constexpr char kSelectNextVersion[] =
    "SELECT COALESCE(MAX(version), 0) + 1 FROM param_versions WHERE device_id = ?1";
constexpr char kInsertVersion[] =
    "INSERT INTO param_versions (device_id, version, created_at_us, session_id, verdict, "
    "accel_rms, state, provenance, params_json, report_json) "
    "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)";
constexpr char kSupersedeActive[] =
    "UPDATE param_versions SET state = 'superseded' WHERE device_id = ?1 AND state = 'active'";
constexpr char kSetVersionState[] =
    "UPDATE param_versions SET state = ?3 WHERE device_id = ?1 AND version = ?2";

constexpr char kInsertAudit[] =
    "INSERT INTO audit_log (time_us, actor, action, target, detail) "
    "VALUES (?1, ?2, ?3, ?4, ?5)";
constexpr char kSelectAudit[] =
    "SELECT id, time_us, actor, action, target, detail FROM audit_log "
    "WHERE id > ?1 ORDER BY id LIMIT ?2";
constexpr char kSelectAuditOfTarget[] =
    "SELECT id, time_us, actor, action, target, detail FROM audit_log "
    "WHERE target = ?3 AND id > ?1 ORDER BY id LIMIT ?2";

// ---- Helpers ---------------------------------------------------------------------------------

int64_t Micros(absl::Time t) { return absl::ToUnixMicros(t); }
absl::Time FromMicros(int64_t us) { return absl::FromUnixMicros(us); }

absl::Status WithContext(std::string_view op, const absl::Status& s) {
  return absl::Status(s.code(), Cat(op, ": ", s.message()));
}

// A stored enum name that does not parse means the file was tampered with.
template <typename T>
absl::StatusOr<T> FromColumn(absl::StatusOr<T> parsed) {
  if (!parsed.ok()) return absl::DataLossError(parsed.status().message());
  return parsed;
}

absl::Status NonEmpty(std::string_view value, std::string_view what) {
  if (value.empty()) return absl::InvalidArgumentError(Cat(what, " is empty"));
  return absl::OkStatus();
}

const absl::Status& StatusOf(const absl::Status& s) { return s; }
template <typename T>
const absl::Status& StatusOf(const absl::StatusOr<T>& s) {
  return s.status();
}

// Runs `body(conn)` in one BEGIN IMMEDIATE transaction, committing only if it succeeds.
// `body` returns absl::Status or absl::StatusOr<T>; errors are prefixed with `op`.
template <typename F>
std::invoke_result_t<F, Connection&> InTransaction(std::string_view op, Connection& conn,
                                                   F&& body) {
  absl::StatusOr<Transaction> txn = Transaction::Begin(conn);
  if (!txn.ok()) return WithContext(op, txn.status());
  auto result = body(conn);
  if (!result.ok()) return WithContext(op, StatusOf(result));
  if (absl::Status s = txn->Commit(); !s.ok()) return WithContext(op, s);
  return result;
}

template <typename T>
absl::StatusOr<T> Annotate(std::string_view op, absl::StatusOr<T> result) {
  if (!result.ok()) return WithContext(op, result.status());
  return result;
}
absl::Status Annotate(std::string_view op, absl::Status result) {
  if (!result.ok()) return WithContext(op, result);
  return result;
}

std::string GenerateSessionId() {
  // 128 random bits: unguessable and collision-free in practice. random_device is slow but
  // sessions are rare.
  std::random_device rd;
  uint64_t hi = (uint64_t{rd()} << 32) | rd();
  uint64_t lo = (uint64_t{rd()} << 32) | rd();
  return absl::StrFormat("s-%016x%016x", hi, lo);
}

// ---- Row mapping -----------------------------------------------------------------------------

Device ReadDevice(const Statement& st) {
  Device d;
  d.id = st.ColumnText(0);
  d.sensor_model = st.ColumnText(1);
  d.nominal_rate_hz = st.ColumnDouble(2);
  d.accel_unit = st.ColumnText(3);
  d.gyro_unit = st.ColumnText(4);
  d.created_at = FromMicros(st.ColumnInt64(5));
  d.active_version = static_cast<int>(st.ColumnInt64(6));
  return d;
}

absl::StatusOr<Session> ReadSession(const Statement& st) {
  Session s;
  s.id = st.ColumnText(0);
  s.device_id = st.ColumnText(1);
  STORAGE_ASSIGN_OR_RETURN(s.state, FromColumn(ParseSessionState(st.ColumnText(2))));
  s.protocol = st.ColumnText(3);
  s.gravity_m_s2 = st.ColumnDouble(4);
  s.created_at = FromMicros(st.ColumnInt64(5));
  s.updated_at = FromMicros(st.ColumnInt64(6));
  s.last_acked_seq = st.ColumnInt64(7);
  s.samples = st.ColumnInt64(8);
  s.poses_accepted = static_cast<int>(st.ColumnInt64(9));
  s.version = static_cast<int>(st.ColumnInt64(10));
  return s;
}

absl::StatusOr<Solve> ReadSolve(const Statement& st) {
  Solve s;
  s.id = st.ColumnInt64(0);
  s.session_id = st.ColumnText(1);
  STORAGE_ASSIGN_OR_RETURN(s.state, FromColumn(ParseSolveState(st.ColumnText(2))));
  s.actor = st.ColumnText(3);
  s.started_at = FromMicros(st.ColumnInt64(4));
  if (!st.ColumnIsNull(5)) s.finished_at = FromMicros(st.ColumnInt64(5));
  s.version = static_cast<int>(st.ColumnInt64(6));
  s.error = st.ColumnText(7);
  s.report_json = st.ColumnText(8);
  return s;
}

// Which of the JSON documents a version statement selects (after the 8 header columns).
enum class Documents { kNone, kParams, kBoth };

// Columns as in kSelectVersion, up to what `docs` says the statement selects.
absl::StatusOr<ParamVersion> ReadVersion(const Statement& st, Documents docs) {
  ParamVersion v;
  v.device_id = st.ColumnText(0);
  v.version = static_cast<int>(st.ColumnInt64(1));
  v.created_at = FromMicros(st.ColumnInt64(2));
  v.session_id = st.ColumnText(3);
  STORAGE_ASSIGN_OR_RETURN(v.verdict, FromColumn(ParseVerdict(st.ColumnText(4))));
  v.accel_rms = st.ColumnDouble(5);
  STORAGE_ASSIGN_OR_RETURN(v.state, FromColumn(ParseVersionState(st.ColumnText(6))));
  v.provenance = st.ColumnText(7);
  if (docs != Documents::kNone) v.params_json = st.ColumnText(8);
  if (docs == Documents::kBoth) v.report_json = st.ColumnText(9);
  return v;
}

AuditEntry ReadAudit(const Statement& st) {
  AuditEntry e;
  e.id = st.ColumnInt64(0);
  e.time = FromMicros(st.ColumnInt64(1));
  e.actor = st.ColumnText(2);
  e.action = st.ColumnText(3);
  e.target = st.ColumnText(4);
  e.detail = st.ColumnText(5);
  return e;
}

// ---- Queries shared by reads and by writes inside their transaction --------------------------

absl::StatusOr<std::optional<Device>> FindDevice(Connection& conn, std::string_view id) {
  STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSelectDevice));
  st->BindText(1, id);
  STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) return std::nullopt;
  return ReadDevice(*st);
}

absl::StatusOr<Device> LoadDevice(Connection& conn, std::string_view id) {
  STORAGE_ASSIGN_OR_RETURN(std::optional<Device> d, FindDevice(conn, id));
  if (!d) return absl::NotFoundError(Cat("no device '", id, "'"));
  return *std::move(d);
}

absl::StatusOr<Session> LoadSession(Connection& conn, std::string_view id) {
  STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSelectSession));
  st->BindText(1, id);
  STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) return absl::NotFoundError(Cat("no session '", id, "'"));
  return ReadSession(*st);
}

absl::Status CheckSessionExists(Connection& conn, std::string_view id) {
  STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSessionExists));
  st->BindText(1, id);
  STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) return absl::NotFoundError(Cat("no session '", id, "'"));
  return absl::OkStatus();
}

absl::StatusOr<std::optional<std::string>> FindOpenSession(Connection& conn,
                                                           std::string_view device_id) {
  STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSelectOpenSessionOfDevice));
  st->BindText(1, device_id);
  STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) return std::nullopt;
  return st->ColumnText(0);
}

absl::StatusOr<Solve> LoadSolve(Connection& conn, int64_t id) {
  STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSelectSolve));
  st->BindInt64(1, id);
  STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) return absl::NotFoundError(Cat("no solve ", id));
  return ReadSolve(*st);
}

absl::StatusOr<std::optional<ParamVersion>> FindActive(Connection& conn,
                                                       std::string_view device_id) {
  STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSelectActiveVersion));
  st->BindText(1, device_id);
  STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) return std::nullopt;
  return ReadVersion(*st, Documents::kParams);
}

absl::StatusOr<ParamVersion> LoadVersion(Connection& conn, std::string_view device_id,
                                         int version) {
  STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSelectVersion));
  st->BindText(1, device_id);
  st->BindInt64(2, version);
  STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) {
    STORAGE_RETURN_IF_ERROR(LoadDevice(conn, device_id).status());
    return absl::NotFoundError(Cat("device '", device_id, "' has no version ", version));
  }
  return ReadVersion(*st, Documents::kBoth);
}

struct LastBatch {
  int64_t seq = 0;  // 0: no batch yet
  double last_t_s = 0.0;
  int64_t end_sample = 0;
};

absl::StatusOr<LastBatch> FindLastBatch(Connection& conn, std::string_view session_id) {
  STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSelectLastBatch));
  st->BindText(1, session_id);
  STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
  LastBatch last;
  if (row) {
    last.seq = st->ColumnInt64(0);
    last.last_t_s = st->ColumnDouble(1);
    last.end_sample = st->ColumnInt64(2);
  }
  return last;
}

// SQLite's LIMIT -1 is "no limit".
int64_t SqlLimit(int limit) { return limit > 0 ? limit : -1; }

absl::Status InsertAudit(Connection& conn, absl::Time time, std::string_view actor,
                         std::string_view action, std::string_view target,
                         std::string_view detail) {
  STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kInsertAudit));
  st->BindInt64(1, Micros(time));
  st->BindText(2, actor);
  st->BindText(3, action);
  st->BindText(4, target);
  st->BindText(5, detail);
  return st->Run();
}

// A device registering again (robots do at every boot) must say the same thing.
absl::Status SameRegistration(const Device& stored, const Device& again) {
  auto differs = [&](std::string_view field, const auto& was, const auto& now) {
    return absl::AlreadyExistsError(Cat("device '", stored.id, "' is already registered with ",
                                        field, " ", was, ", not ", now));
  };
  if (stored.sensor_model != again.sensor_model) {
    return differs("sensor_model", stored.sensor_model, again.sensor_model);
  }
  if (stored.nominal_rate_hz != again.nominal_rate_hz) {
    return differs("nominal_rate_hz", stored.nominal_rate_hz, again.nominal_rate_hz);
  }
  if (stored.accel_unit != again.accel_unit) {
    return differs("accel_unit", stored.accel_unit, again.accel_unit);
  }
  if (stored.gyro_unit != again.gyro_unit) {
    return differs("gyro_unit", stored.gyro_unit, again.gyro_unit);
  }
  return absl::OkStatus();
}

// ---- Session state machine (types.h) ---------------------------------------------------------

bool TransitionAllowed(SessionState from, SessionState to) {
  using S = SessionState;
  switch (from) {
    case S::kOpen:
      return to == S::kSolving || to == S::kCancelled || to == S::kFailed;
    case S::kSolving:
      return to == S::kSolved || to == S::kFailed || to == S::kOpen;
    case S::kSolved:
    case S::kFailed:
      return to == S::kSolving;
    case S::kCancelled:
      return false;
  }
  return false;
}

std::string AllowedFrom(SessionState from) {
  std::string names;
  for (SessionState to : {SessionState::kOpen, SessionState::kSolving, SessionState::kSolved,
                          SessionState::kCancelled, SessionState::kFailed}) {
    if (TransitionAllowed(from, to)) {
      AppendTo(&names, names.empty() ? "" : ", ", SessionStateName(to));
    }
  }
  return names.empty() ? "none: it is final" : names;
}

// Moves `session` to `to` (checking the transition and the one-open-session rule) and audits.
absl::Status ChangeSessionState(Connection& conn, const Session& session, SessionState to,
                                std::string_view actor, absl::Time now) {
  if (!TransitionAllowed(session.state, to)) {
    return absl::FailedPreconditionError(Cat(
        "session '", session.id, "' is ", SessionStateName(session.state), "; it cannot become ",
        SessionStateName(to), " (allowed: ", AllowedFrom(session.state), ")"));
  }
  if (to == SessionState::kOpen) {
    STORAGE_ASSIGN_OR_RETURN(std::optional<std::string> open,
                             FindOpenSession(conn, session.device_id));
    if (open) {
      return absl::FailedPreconditionError(
          Cat("device '", session.device_id, "' already has an open session '", *open, "'"));
    }
  }
  STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kUpdateSessionState));
  st->BindText(1, session.id);
  st->BindText(2, SessionStateName(to));
  st->BindInt64(3, Micros(now));
  STORAGE_RETURN_IF_ERROR(st->Run());
  return InsertAudit(conn, now, actor, "session.state", SessionTarget(session.id),
                     Cat(SessionStateName(session.state), " -> ", SessionStateName(to)));
}

// ---- Versions --------------------------------------------------------------------------------

absl::Status ValidateNewVersion(const ParamVersion& v) {
  STORAGE_RETURN_IF_ERROR(NonEmpty(v.device_id, "device_id"));
  STORAGE_RETURN_IF_ERROR(NonEmpty(v.params_json, "params_json"));
  if (v.state != VersionState::kCandidate && v.state != VersionState::kActive) {
    return absl::InvalidArgumentError(
        Cat("a new version is a candidate or active, not ", VersionStateName(v.state)));
  }
  if (std::isinf(v.accel_rms) || v.accel_rms < 0) {
    return absl::InvalidArgumentError(
        Cat("accel_rms ", v.accel_rms, " is not a finite non-negative number"));
  }
  return absl::OkStatus();
}

// Makes `version` the device's active one; returns the version it displaced (0 if none).
absl::StatusOr<int> Activate(Connection& conn, std::string_view device_id, int version) {
  STORAGE_ASSIGN_OR_RETURN(std::optional<ParamVersion> active, FindActive(conn, device_id));
  {
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSupersedeActive));
    st->BindText(1, device_id);
    STORAGE_RETURN_IF_ERROR(st->Run());
  }
  STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSetVersionState));
  st->BindText(1, device_id);
  st->BindInt64(2, version);
  st->BindText(3, VersionStateName(VersionState::kActive));
  STORAGE_RETURN_IF_ERROR(st->Run());
  return active ? active->version : 0;
}

std::string Reason(std::string_view reason) {
  return reason.empty() ? std::string() : Cat(": ", reason);
}

std::string Displaced(int previous) {
  return previous == 0 ? std::string() : Cat("; version ", previous, " superseded");
}

absl::StatusOr<ParamVersion> InsertVersion(Connection& conn, const ParamVersion& v,
                                           std::string_view actor, absl::Time now) {
  STORAGE_RETURN_IF_ERROR(ValidateNewVersion(v));
  STORAGE_RETURN_IF_ERROR(LoadDevice(conn, v.device_id).status());
  if (!v.session_id.empty()) {
    STORAGE_ASSIGN_OR_RETURN(Session session, LoadSession(conn, v.session_id));
    if (session.device_id != v.device_id) {
      return absl::InvalidArgumentError(Cat("session '", v.session_id, "' belongs to device '",
                                            session.device_id, "', not '", v.device_id, "'"));
    }
  }
  // The write lock is held (BEGIN IMMEDIATE), so MAX + 1 cannot race another writer.
  int number = 0;
  {
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSelectNextVersion));
    st->BindText(1, v.device_id);
    STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) return absl::InternalError("no next version");
    number = static_cast<int>(st->ColumnInt64(0));
  }
  {
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kInsertVersion));
    st->BindText(1, v.device_id);
    st->BindInt64(2, number);
    st->BindInt64(3, Micros(now));
    if (v.session_id.empty()) {
      st->BindNull(4);
    } else {
      st->BindText(4, v.session_id);
    }
    st->BindText(5, VerdictName(v.verdict));
    st->BindDouble(6, v.accel_rms);
    st->BindText(7, VersionStateName(VersionState::kCandidate));
    st->BindText(8, v.provenance);
    st->BindText(9, v.params_json);
    st->BindText(10, v.report_json);
    STORAGE_RETURN_IF_ERROR(st->Run());
  }
  int displaced = 0;
  if (v.state == VersionState::kActive) {
    STORAGE_ASSIGN_OR_RETURN(displaced, Activate(conn, v.device_id, number));
  }
  STORAGE_RETURN_IF_ERROR(InsertAudit(
      conn, now, actor, "version.add", DeviceTarget(v.device_id),
      Cat("version ", number, " ", VersionStateName(v.state), ", verdict ", VerdictName(v.verdict),
          ", accel_rms ", v.accel_rms, v.session_id.empty() ? "" : Cat(", session ", v.session_id),
          Displaced(displaced))));
  return LoadVersion(conn, v.device_id, number);
}

}  // namespace

// ---- Store -----------------------------------------------------------------------------------

class Store::ReadLease {
 public:
  ReadLease(Store* store, Connection* conn) : store_(store), conn_(conn) {}
  ReadLease(const ReadLease&) = delete;
  ReadLease& operator=(const ReadLease&) = delete;
  ~ReadLease() { store_->ReleaseReader(conn_); }
  Connection& conn() const { return *conn_; }

 private:
  Store* store_;
  Connection* conn_;
};

Store::Store(StoreOptions options, std::unique_ptr<Connection> writer,
             std::unique_ptr<Connection> checkpointer,
             std::vector<std::unique_ptr<Connection>> readers)
    : options_(std::move(options)),
      writer_(std::move(writer)),
      checkpointer_(std::move(checkpointer)),
      readers_(std::move(readers)) {
  for (const auto& r : readers_) free_readers_.push_back(r.get());
}

void Store::StartBackgroundThreads() {
  {
    // From now on the writer's commits no longer checkpoint (SQLite's automatic checkpoint is
    // this hook): count the WAL's pages and let CheckpointLoop do it.
    std::lock_guard lock(write_mu_);
    sqlite3_wal_hook(
        writer_->db(),
        [](void* arg, sqlite3*, const char*, int pages) {
          Store* store = static_cast<Store*>(arg);
          store->wal_pages_.store(pages, std::memory_order_relaxed);
          if (pages >= kCheckpointPages) store->checkpoint_cv_.notify_one();
          return SQLITE_OK;
        },
        this);
  }
  committer_ = std::thread([this] { CommitLoop(); });
  checkpoint_thread_ = std::thread([this] { CheckpointLoop(); });
}

Store::~Store() {
  {
    std::lock_guard lock(commit_mu_);
    stopping_ = true;
  }
  commit_cv_.notify_all();
  checkpoint_cv_.notify_all();
  if (committer_.joinable()) committer_.join();  // after every submitted batch
  if (checkpoint_thread_.joinable()) checkpoint_thread_.join();
  checkpointer_.reset();  // before the writer, which checkpoints as the last one out
}

absl::StatusOr<std::unique_ptr<Store>> Store::Open(const std::string& path, StoreOptions options) {
  if (path.empty() || path == ":memory:") {
    return absl::InvalidArgumentError("Store::Open needs a file path (connections share it)");
  }
  if (options.read_connections < 1) {
    return absl::InvalidArgumentError("StoreOptions::read_connections must be at least 1");
  }
  const std::string op = Cat("open ", path);
  ConnectionOptions conn_options;
  conn_options.synchronous_full = options.durability == Durability::kFull;
  conn_options.busy_timeout = options.busy_timeout;
  STORAGE_ASSIGN_OR_RETURN(std::unique_ptr<Connection> writer,
                           Annotate(op, Connection::Open(path, conn_options)));
  {
    // WAL is a property of the file: set once, kept by every later open.
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st,
                             Annotate(op, writer->Prepare("PRAGMA journal_mode = WAL")));
    STORAGE_ASSIGN_OR_RETURN(bool row, Annotate(op, st->Step()));
    const std::string mode = row ? st->ColumnText(0) : std::string();
    if (mode != "wal") {
      return absl::FailedPreconditionError(
          Cat(op, ": cannot switch to WAL (journal mode is '", mode, "')"));
    }
  }
  // After a checkpoint, cut the -wal file back to 64 MiB instead of leaving it at the size an
  // ingest burst grew it to.
  STORAGE_RETURN_IF_ERROR(Annotate(op, writer->Exec("PRAGMA journal_size_limit = 67108864")));
  STORAGE_RETURN_IF_ERROR(Annotate(op, Migrate(*writer)));
  STORAGE_ASSIGN_OR_RETURN(std::unique_ptr<Connection> checkpointer,
                           Annotate(op, Connection::Open(path, conn_options)));
  std::vector<std::unique_ptr<Connection>> readers;
  conn_options.read_only = true;
  for (int i = 0; i < options.read_connections; ++i) {
    STORAGE_ASSIGN_OR_RETURN(std::unique_ptr<Connection> reader,
                             Annotate(op, Connection::Open(path, conn_options)));
    readers.push_back(std::move(reader));
  }
  return std::unique_ptr<Store>(new Store(std::move(options), std::move(writer),
                                          std::move(checkpointer), std::move(readers)));
}

absl::StatusOr<ParamVersion> Store::NotifyIfActive(absl::StatusOr<ParamVersion> version) {
  if (version.ok() && version->state == VersionState::kActive && options_.on_active_change)
    options_.on_active_change(version->device_id);
  return version;
}

absl::Time Store::Now() const {
  // Microseconds, as stored, so a returned object equals the one read back later.
  return FromMicros(Micros(options_.clock ? options_.clock() : absl::Now()));
}

Store::ReadLease Store::AcquireReader() {
  std::unique_lock lock(readers_mu_);
  reader_free_.wait(lock, [this] { return !free_readers_.empty(); });
  Connection* conn = free_readers_.back();
  free_readers_.pop_back();
  return ReadLease(this, conn);
}

void Store::ReleaseReader(Connection* conn) {
  {
    std::lock_guard lock(readers_mu_);
    free_readers_.push_back(conn);
  }
  reader_free_.notify_one();
}

// ---- Devices ---------------------------------------------------------------------------------

absl::StatusOr<Device> Store::CreateDevice(const Device& device, std::string_view actor) {
  constexpr std::string_view kOp = "CreateDevice";
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(device.id, "device id")));
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  if (!std::isfinite(device.nominal_rate_hz) || device.nominal_rate_hz < 0) {
    return absl::InvalidArgumentError(
        Cat(kOp, ": nominal_rate_hz ", device.nominal_rate_hz, " is not a non-negative number"));
  }
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](Connection& conn) -> absl::StatusOr<Device> {
    STORAGE_ASSIGN_OR_RETURN(std::optional<Device> existing, FindDevice(conn, device.id));
    if (existing) {
      STORAGE_RETURN_IF_ERROR(SameRegistration(*existing, device));
      return *std::move(existing);
    }
    Device d = device;
    d.created_at = Now();
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kInsertDevice));
    st->BindText(1, d.id);
    st->BindText(2, d.sensor_model);
    st->BindDouble(3, d.nominal_rate_hz);
    st->BindText(4, d.accel_unit);
    st->BindText(5, d.gyro_unit);
    st->BindInt64(6, Micros(d.created_at));
    STORAGE_RETURN_IF_ERROR(st->Run());
    STORAGE_RETURN_IF_ERROR(InsertAudit(conn, d.created_at, actor, "device.create",
                                        DeviceTarget(d.id),
                                        Cat("sensor ", d.sensor_model, ", ", d.nominal_rate_hz,
                                            " Hz, accel ", d.accel_unit, ", gyro ", d.gyro_unit)));
    return d;
  });
}

absl::StatusOr<Device> Store::GetDevice(std::string_view id) {
  ReadLease lease = AcquireReader();
  return Annotate("GetDevice", LoadDevice(lease.conn(), id));
}

absl::StatusOr<std::vector<Device>> Store::ListDevices(std::string_view after_id, int limit) {
  ReadLease lease = AcquireReader();
  auto list = [&]() -> absl::StatusOr<std::vector<Device>> {
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, lease.conn().Prepare(kSelectDevices));
    st->BindText(1, after_id);
    st->BindInt64(2, SqlLimit(limit));
    std::vector<Device> out;
    for (;;) {
      STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
      if (!row) return out;
      out.push_back(ReadDevice(*st));
    }
  };
  return Annotate("ListDevices", list());
}

// ---- Sessions --------------------------------------------------------------------------------

absl::StatusOr<Session> Store::CreateSession(const Session& session, std::string_view actor) {
  constexpr std::string_view kOp = "CreateSession";
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(session.device_id, "device_id")));
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  if (!std::isfinite(session.gravity_m_s2) || session.gravity_m_s2 <= 0) {
    return absl::InvalidArgumentError(
        Cat(kOp, ": gravity_m_s2 ", session.gravity_m_s2, " is not a positive number"));
  }
  const std::string id = session.id.empty() ? GenerateSessionId() : session.id;
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](Connection& conn) -> absl::StatusOr<Session> {
    STORAGE_RETURN_IF_ERROR(LoadDevice(conn, session.device_id).status());
    STORAGE_ASSIGN_OR_RETURN(std::optional<std::string> open,
                             FindOpenSession(conn, session.device_id));
    if (open) {
      return absl::FailedPreconditionError(Cat("device '", session.device_id,
                                               "' already has an open session '", *open,
                                               "': finish or cancel it first"));
    }
    if (CheckSessionExists(conn, id).ok()) {
      return absl::AlreadyExistsError(Cat("session '", id, "' already exists"));
    }
    const absl::Time now = Now();
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kInsertSession));
    st->BindText(1, id);
    st->BindText(2, session.device_id);
    st->BindText(3, session.protocol);
    st->BindDouble(4, session.gravity_m_s2);
    st->BindInt64(5, Micros(now));
    STORAGE_RETURN_IF_ERROR(st->Run());
    STORAGE_RETURN_IF_ERROR(
        InsertAudit(conn, now, actor, "session.create", SessionTarget(id),
                    Cat("device ", session.device_id, ", protocol ", session.protocol)));
    return LoadSession(conn, id);
  });
}

absl::StatusOr<Session> Store::GetSession(std::string_view id) {
  ReadLease lease = AcquireReader();
  return Annotate("GetSession", LoadSession(lease.conn(), id));
}

absl::StatusOr<std::vector<Session>> Store::ListSessions(const SessionQuery& query) {
  ReadLease lease = AcquireReader();
  Connection& conn = lease.conn();
  auto list = [&]() -> absl::StatusOr<std::vector<Session>> {
    int64_t after_rowid = 0;
    if (!query.after_id.empty()) {
      STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSelectSessionRowid));
      st->BindText(1, query.after_id);
      STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
      if (!row) {
        return absl::InvalidArgumentError(Cat("page after unknown session '", query.after_id, "'"));
      }
      after_rowid = st->ColumnInt64(0);
    }
    const bool of_device = !query.device_id.empty();
    if (of_device) STORAGE_RETURN_IF_ERROR(LoadDevice(conn, query.device_id).status());
    STORAGE_ASSIGN_OR_RETURN(
        ScopedStatement st, conn.Prepare(of_device ? kSelectSessionsOfDevice : kSelectSessionsAll));
    if (of_device) st->BindText(1, query.device_id);
    if (query.state) {
      st->BindText(2, SessionStateName(*query.state));
    } else {
      st->BindNull(2);
    }
    st->BindInt64(3, after_rowid);
    st->BindInt64(4, SqlLimit(query.limit));
    std::vector<Session> out;
    for (;;) {
      STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
      if (!row) return out;
      STORAGE_ASSIGN_OR_RETURN(Session s, ReadSession(*st));
      out.push_back(std::move(s));
    }
  };
  return Annotate("ListSessions", list());
}

absl::StatusOr<Session> Store::SetSessionState(std::string_view id, SessionState state,
                                               std::string_view actor) {
  constexpr std::string_view kOp = "SetSessionState";
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](Connection& conn) -> absl::StatusOr<Session> {
    STORAGE_ASSIGN_OR_RETURN(Session session, LoadSession(conn, id));
    const absl::Time now = Now();
    STORAGE_RETURN_IF_ERROR(ChangeSessionState(conn, session, state, actor, now));
    if (session.state == SessionState::kSolving) {
      // Leaving `solving` by hand abandons its running solve: it can no longer finish.
      STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kAbandonRunningSolves));
      st->BindText(1, id);
      st->BindInt64(2, Micros(now));
      st->BindText(3, Cat("abandoned: session set to ", SessionStateName(state), " by ", actor));
      STORAGE_RETURN_IF_ERROR(st->Run());
    }
    return LoadSession(conn, id);
  });
}

// ---- Raw samples -----------------------------------------------------------------------------

namespace {

// AppendBatch's checks and insert inside the caller's transaction (see store.h).
absl::StatusOr<BatchAck> AppendOne(Connection& conn, std::string_view session_id, int64_t seq,
                                   std::string_view payload, const EncodedBatchInfo& info_value) {
  const EncodedBatchInfo* info = &info_value;
  SessionState state;
  {
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSelectSessionStateForAppend));
    st->BindText(1, session_id);
    STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) return absl::NotFoundError(Cat("no session '", session_id, "'"));
    STORAGE_ASSIGN_OR_RETURN(state, FromColumn(ParseSessionState(st->ColumnText(0))));
  }
  STORAGE_ASSIGN_OR_RETURN(const LastBatch last, FindLastBatch(conn, session_id));
  if (seq <= last.seq) {
    // A retransmission of an acknowledged batch is a no-op, if it is the same batch.
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSelectBatchPayload));
    st->BindText(1, session_id);
    st->BindInt64(2, seq);
    STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
    if (row && st->ColumnBlobView(0) == payload) return BatchAck{last.seq, last.end_sample};
    return absl::InvalidArgumentError(Cat("session '", session_id, "': batch ", seq,
                                          " was already stored with different content"));
  }
  if (seq != last.seq + 1) {
    return absl::FailedPreconditionError(Cat("session '", session_id, "': batch ", seq,
                                             " is out of order; expected ", last.seq + 1,
                                             " (last acknowledged ", last.seq, ")"));
  }
  if (state != SessionState::kOpen) {
    return absl::FailedPreconditionError(
        Cat("session '", session_id, "' is ", SessionStateName(state), ", not open"));
  }
  if (last.seq > 0 && !(info->first_t_s > last.last_t_s)) {
    return absl::InvalidArgumentError(
        Cat("session '", session_id, "': batch ", seq, " starts at t_s ", info->first_t_s,
            ", not after the last sample of batch ", last.seq, " (t_s ", last.last_t_s, ")"));
  }
  const BatchAck ack{seq, last.end_sample + info->count};
  STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kInsertBatch));
  st->BindText(1, session_id);
  st->BindInt64(2, seq);
  st->BindDouble(3, info->first_t_s);
  st->BindDouble(4, info->last_t_s);
  st->BindInt64(5, info->count);
  st->BindInt64(6, ack.samples);
  st->BindBlob(7, payload);
  STORAGE_RETURN_IF_ERROR(st->Run());
  return ack;
}

// Checks a batch before any lock: decoding is the costly part and needs no database.
absl::StatusOr<EncodedBatchInfo> CheckBatch(int64_t seq, std::string_view payload) {
  constexpr std::string_view kOp = "AppendBatch";
  if (seq < 1) {
    return absl::InvalidArgumentError(
        Cat(kOp, ": batch seq ", seq, " is invalid; batches are numbered from 1"));
  }
  absl::StatusOr<EncodedBatchInfo> info = InspectSamples(payload);
  if (!info.ok()) {
    return absl::InvalidArgumentError(Cat(kOp, ": batch ", seq, ": ", info.status().message()));
  }
  if (info->count == 0) {
    return absl::InvalidArgumentError(Cat(kOp, ": batch ", seq, " has no samples"));
  }
  return info;
}

}  // namespace

absl::StatusOr<BatchAck> Store::AppendBatch(std::string_view session_id, int64_t seq,
                                            std::string_view payload) {
  absl::StatusOr<EncodedBatchInfo> info = CheckBatch(seq, payload);
  if (!info.ok()) return info.status();
  std::lock_guard lock(write_mu_);
  return InTransaction("AppendBatch", *writer_, [&](Connection& conn) {
    return AppendOne(conn, session_id, seq, payload, *info);
  });
}

struct Store::PendingAppend {
  std::string session_id;
  int64_t seq = 0;
  std::string payload;
  EncodedBatchInfo info;
  std::function<void(absl::StatusOr<BatchAck>)> done;
};

void Store::AppendBatchAsync(std::string session_id, int64_t seq, std::string payload,
                             std::function<void(absl::StatusOr<BatchAck>)> done) {
  absl::StatusOr<EncodedBatchInfo> info = CheckBatch(seq, payload);
  if (!info.ok()) {
    done(info.status());
    return;
  }
  std::call_once(threads_started_, [this] { StartBackgroundThreads(); });
  {
    std::lock_guard lock(commit_mu_);
    pending_.push_back(
        PendingAppend{std::move(session_id), seq, std::move(payload), *info, std::move(done)});
  }
  commit_cv_.notify_one();
}

void Store::CommitLoop() {
  std::vector<PendingAppend> group;
  std::vector<absl::StatusOr<BatchAck>> results;
  for (;;) {
    {
      std::unique_lock lock(commit_mu_);
      commit_cv_.wait(lock, [this] { return !pending_.empty() || stopping_; });
      if (pending_.empty()) return;  // stopping, and everything submitted is done
      // Everything that arrived while the previous group committed: one transaction.
      group.swap(pending_);
    }
    results.clear();
    {
      std::lock_guard lock(write_mu_);
      absl::Status status = InTransaction("AppendBatch", *writer_, [&](Connection& conn) {
        for (const PendingAppend& p : group) {
          absl::StatusOr<BatchAck> r = AppendOne(conn, p.session_id, p.seq, p.payload, p.info);
          results.push_back(r.ok() ? r : WithContext("AppendBatch", r.status()));
        }
        return absl::OkStatus();  // a batch's own error fails that batch only
      });
      // No commit: nothing of the group is stored (each batch's own error stays its own).
      if (!status.ok()) {
        results.resize(group.size(), status);  // BEGIN failed: no batch got its own answer
        for (auto& r : results)
          if (r.ok()) r = status;
      }
    }
    for (size_t i = 0; i < group.size(); ++i) group[i].done(std::move(results[i]));
    group.clear();
  }
}

void Store::CheckpointLoop() {
  // WAL checkpoints off the commit path: the writer's automatic checkpoint (which would run
  // inside a commit, holding up every stream's ack) is off; this thread copies the WAL into
  // the database with PASSIVE checkpoints (never blocking the writer or readers) on its own
  // connection, when the WAL has grown by kCheckpointPages or every second.
  std::unique_lock lock(commit_mu_);
  while (!stopping_) {
    checkpoint_cv_.wait_for(lock, std::chrono::seconds(1), [this] {
      return stopping_ || wal_pages_.load(std::memory_order_relaxed) >= kCheckpointPages;
    });
    if (stopping_) return;
    if (wal_pages_.load(std::memory_order_relaxed) == 0) continue;
    lock.unlock();
    wal_pages_.store(0, std::memory_order_relaxed);
    // Best effort: a busy or failed checkpoint is retried at the next round.
    (void)sqlite3_wal_checkpoint_v2(checkpointer_->db(), nullptr, SQLITE_CHECKPOINT_PASSIVE,
                                    nullptr, nullptr);
    lock.lock();
  }
}

absl::StatusOr<std::vector<SampleBatch>> Store::ReadBatches(std::string_view session_id,
                                                            int64_t after_seq) {
  ReadLease lease = AcquireReader();
  auto read = [&]() -> absl::StatusOr<std::vector<SampleBatch>> {
    STORAGE_RETURN_IF_ERROR(CheckSessionExists(lease.conn(), session_id));
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, lease.conn().Prepare(kSelectBatches));
    st->BindText(1, session_id);
    st->BindInt64(2, after_seq);
    std::vector<SampleBatch> out;
    for (;;) {
      STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
      if (!row) return out;
      SampleBatch b;
      b.session_id = std::string(session_id);
      b.seq = st->ColumnInt64(0);
      b.first_t_s = st->ColumnDouble(1);
      b.last_t_s = st->ColumnDouble(2);
      b.count = st->ColumnInt64(3);
      b.payload = st->ColumnBlob(4);
      // Verified on the way out too: a damaged file must not feed a solve silently.
      absl::StatusOr<EncodedBatchInfo> info = InspectSamples(b.payload);
      if (!info.ok()) {
        return absl::DataLossError(
            Cat("session '", session_id, "' batch ", b.seq, ": ", info.status().message()));
      }
      if (info->count != b.count || info->first_t_s != b.first_t_s ||
          info->last_t_s != b.last_t_s) {
        return absl::DataLossError(
            Cat("session '", session_id, "' batch ", b.seq, ": payload disagrees with its row"));
      }
      out.push_back(std::move(b));
    }
  };
  return Annotate("ReadBatches", read());
}

// ---- Poses -----------------------------------------------------------------------------------

absl::Status Store::PutPoses(std::string_view session_id, const std::vector<Pose>& poses,
                             std::string_view actor) {
  constexpr std::string_view kOp = "PutPoses";
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  int used = 0;
  for (size_t i = 0; i < poses.size(); ++i) {
    const Pose& p = poses[i];
    if (p.index != static_cast<int>(i)) {
      return absl::InvalidArgumentError(
          Cat(kOp, ": pose #", i, " has index ", p.index, "; expected ", i));
    }
    if (!p.session_id.empty() && p.session_id != session_id) {
      return absl::InvalidArgumentError(
          Cat(kOp, ": pose ", i, " belongs to session '", p.session_id, "'"));
    }
    if (!std::isfinite(p.t_start_s) || !std::isfinite(p.t_end_s) || p.t_end_s < p.t_start_s) {
      return absl::InvalidArgumentError(
          Cat(kOp, ": pose ", i, " has bad times [", p.t_start_s, ", ", p.t_end_s, "]"));
    }
    used += p.used ? 1 : 0;
  }
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](Connection& conn) -> absl::Status {
    STORAGE_RETURN_IF_ERROR(CheckSessionExists(conn, session_id));
    {
      STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kDeletePoses));
      st->BindText(1, session_id);
      STORAGE_RETURN_IF_ERROR(st->Run());
    }
    for (const Pose& p : poses) {
      STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kInsertPose));
      st->BindText(1, session_id);
      st->BindInt64(2, p.index);
      st->BindDouble(3, p.t_start_s);
      st->BindDouble(4, p.t_end_s);
      st->BindInt64(5, p.used ? 1 : 0);
      st->BindText(6, p.reason);
      st->BindText(7, p.detail_json);
      st->BindText(8, p.face);
      STORAGE_RETURN_IF_ERROR(st->Run());
    }
    return InsertAudit(conn, Now(), actor, "session.poses", SessionTarget(session_id),
                       Cat(poses.size(), " poses, ", used, " used"));
  });
}

absl::StatusOr<std::vector<Pose>> Store::ListPoses(std::string_view session_id) {
  ReadLease lease = AcquireReader();
  auto list = [&]() -> absl::StatusOr<std::vector<Pose>> {
    STORAGE_RETURN_IF_ERROR(CheckSessionExists(lease.conn(), session_id));
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, lease.conn().Prepare(kSelectPoses));
    st->BindText(1, session_id);
    std::vector<Pose> out;
    for (;;) {
      STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
      if (!row) return out;
      Pose p;
      p.session_id = std::string(session_id);
      p.index = static_cast<int>(st->ColumnInt64(0));
      p.t_start_s = st->ColumnDouble(1);
      p.t_end_s = st->ColumnDouble(2);
      p.used = st->ColumnInt64(3) != 0;
      p.reason = st->ColumnText(4);
      p.detail_json = st->ColumnText(5);
      p.face = st->ColumnText(6);
      out.push_back(std::move(p));
    }
  };
  return Annotate("ListPoses", list());
}

absl::Status Store::SavePoses(std::string_view session_id, const std::vector<Pose>& poses,
                              const std::vector<PosePair>& pairs) {
  constexpr std::string_view kOp = "SavePoses";
  for (const Pose& p : poses) {
    if (p.index < 0 || !std::isfinite(p.t_start_s) || !std::isfinite(p.t_end_s) ||
        p.t_end_s < p.t_start_s) {
      return absl::InvalidArgumentError(Cat(kOp, ": pose ", p.index, " has a bad index or times [",
                                            p.t_start_s, ", ", p.t_end_s, "]"));
    }
  }
  for (const PosePair& p : pairs) {
    if (p.pose_a < 0 || p.pose_b <= p.pose_a) {
      return absl::InvalidArgumentError(
          Cat(kOp, ": pair (", p.pose_a, ", ", p.pose_b, ") is not two increasing pose indexes"));
    }
  }
  if (poses.empty() && pairs.empty()) return absl::OkStatus();
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](Connection& conn) -> absl::Status {
    STORAGE_RETURN_IF_ERROR(CheckSessionExists(conn, session_id));
    for (const Pose& p : poses) {
      STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kUpsertPose));
      st->BindText(1, session_id);
      st->BindInt64(2, p.index);
      st->BindDouble(3, p.t_start_s);
      st->BindDouble(4, p.t_end_s);
      st->BindInt64(5, p.used ? 1 : 0);
      st->BindText(6, p.reason);
      st->BindText(7, p.detail_json);
      st->BindText(8, p.face);
      STORAGE_RETURN_IF_ERROR(st->Run());
    }
    for (const PosePair& p : pairs) {
      STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kUpsertPair));
      st->BindText(1, session_id);
      st->BindInt64(2, p.pose_a);
      st->BindInt64(3, p.pose_b);
      st->BindInt64(4, p.ok ? 1 : 0);
      st->BindText(5, p.face);
      st->BindDouble(6, p.rotation_deg);
      st->BindDouble(7, p.tilt_deg);
      st->BindText(8, p.reason);
      STORAGE_RETURN_IF_ERROR(st->Run());
    }
    return absl::OkStatus();
  });
}

absl::StatusOr<std::vector<PosePair>> Store::ListPairs(std::string_view session_id) {
  ReadLease lease = AcquireReader();
  auto list = [&]() -> absl::StatusOr<std::vector<PosePair>> {
    STORAGE_RETURN_IF_ERROR(CheckSessionExists(lease.conn(), session_id));
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, lease.conn().Prepare(kSelectPairs));
    st->BindText(1, session_id);
    std::vector<PosePair> out;
    for (;;) {
      STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
      if (!row) return out;
      PosePair p;
      p.session_id = std::string(session_id);
      p.pose_a = static_cast<int>(st->ColumnInt64(0));
      p.pose_b = static_cast<int>(st->ColumnInt64(1));
      p.ok = st->ColumnInt64(2) != 0;
      p.face = st->ColumnText(3);
      p.rotation_deg = st->ColumnDouble(4);
      p.tilt_deg = st->ColumnDouble(5);
      p.reason = st->ColumnText(6);
      out.push_back(std::move(p));
    }
  };
  return Annotate("ListPairs", list());
}

// ---- Solves ----------------------------------------------------------------------------------

absl::StatusOr<Solve> Store::StartSolve(std::string_view session_id, std::string_view actor) {
  constexpr std::string_view kOp = "StartSolve";
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](Connection& conn) -> absl::StatusOr<Solve> {
    STORAGE_ASSIGN_OR_RETURN(Session session, LoadSession(conn, session_id));
    const absl::Time now = Now();
    STORAGE_RETURN_IF_ERROR(ChangeSessionState(conn, session, SessionState::kSolving, actor, now));
    {
      STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kInsertSolve));
      st->BindText(1, session_id);
      st->BindText(2, actor);
      st->BindInt64(3, Micros(now));
      STORAGE_RETURN_IF_ERROR(st->Run());
    }
    const int64_t id = sqlite3_last_insert_rowid(conn.db());
    STORAGE_RETURN_IF_ERROR(
        InsertAudit(conn, now, actor, "solve.start", SessionTarget(session_id), Cat("solve ", id)));
    return LoadSolve(conn, id);
  });
}

absl::StatusOr<ParamVersion> Store::FinishSolve(int64_t solve_id, const ParamVersion& version,
                                                std::string_view actor) {
  constexpr std::string_view kOp = "FinishSolve";
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return NotifyIfActive(
      InTransaction(kOp, *writer_, [&](Connection& conn) -> absl::StatusOr<ParamVersion> {
        STORAGE_ASSIGN_OR_RETURN(Solve solve, LoadSolve(conn, solve_id));
        if (solve.state != SolveState::kRunning) {
          return absl::FailedPreconditionError(
              Cat("solve ", solve_id, " is ", SolveStateName(solve.state), ", not running"));
        }
        STORAGE_ASSIGN_OR_RETURN(Session session, LoadSession(conn, solve.session_id));
        ParamVersion v = version;
        if (v.device_id.empty()) v.device_id = session.device_id;
        if (v.session_id.empty()) v.session_id = session.id;
        if (v.device_id != session.device_id || v.session_id != session.id) {
          return absl::InvalidArgumentError(Cat("solve ", solve_id, " is of session '", session.id,
                                                "' of device '", session.device_id, "', not of '",
                                                v.session_id, "' of '", v.device_id, "'"));
        }
        const absl::Time now = Now();
        STORAGE_ASSIGN_OR_RETURN(ParamVersion added, InsertVersion(conn, v, actor, now));
        {
          STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kFinishSolve));
          st->BindInt64(1, solve_id);
          st->BindText(2, SolveStateName(SolveState::kSucceeded));
          st->BindInt64(3, Micros(now));
          st->BindInt64(4, added.version);
          st->BindText(5, "");
          st->BindText(6, "");  // the report is the version's
          STORAGE_RETURN_IF_ERROR(st->Run());
        }
        STORAGE_RETURN_IF_ERROR(
            ChangeSessionState(conn, session, SessionState::kSolved, actor, now));
        STORAGE_RETURN_IF_ERROR(
            InsertAudit(conn, now, actor, "solve.finish", SessionTarget(session.id),
                        Cat("solve ", solve_id, " -> version ", added.version)));
        return added;
      }));
}

absl::StatusOr<Solve> Store::FailSolve(int64_t solve_id, std::string_view error,
                                       std::string_view report_json, std::string_view actor,
                                       SessionState next) {
  constexpr std::string_view kOp = "FailSolve";
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  if (next != SessionState::kFailed && next != SessionState::kOpen) {
    return absl::InvalidArgumentError(Cat(
        kOp, ": after a failed solve a session is failed or open, not ", SessionStateName(next)));
  }
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](Connection& conn) -> absl::StatusOr<Solve> {
    STORAGE_ASSIGN_OR_RETURN(Solve solve, LoadSolve(conn, solve_id));
    if (solve.state != SolveState::kRunning) {
      return absl::FailedPreconditionError(
          Cat("solve ", solve_id, " is ", SolveStateName(solve.state), ", not running"));
    }
    STORAGE_ASSIGN_OR_RETURN(Session session, LoadSession(conn, solve.session_id));
    const absl::Time now = Now();
    {
      STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kFinishSolve));
      st->BindInt64(1, solve_id);
      st->BindText(2, SolveStateName(SolveState::kFailed));
      st->BindInt64(3, Micros(now));
      st->BindInt64(4, 0);
      st->BindText(5, error);
      st->BindText(6, report_json);
      STORAGE_RETURN_IF_ERROR(st->Run());
    }
    STORAGE_RETURN_IF_ERROR(ChangeSessionState(conn, session, next, actor, now));
    STORAGE_RETURN_IF_ERROR(InsertAudit(conn, now, actor, "solve.fail", SessionTarget(session.id),
                                        Cat("solve ", solve_id, ": ", error)));
    return LoadSolve(conn, solve_id);
  });
}

absl::StatusOr<Solve> Store::GetSolve(int64_t solve_id) {
  ReadLease lease = AcquireReader();
  return Annotate("GetSolve", LoadSolve(lease.conn(), solve_id));
}

namespace {

absl::StatusOr<std::vector<Solve>> ReadSolves(Statement& st) {
  std::vector<Solve> out;
  for (;;) {
    STORAGE_ASSIGN_OR_RETURN(bool row, st.Step());
    if (!row) return out;
    STORAGE_ASSIGN_OR_RETURN(Solve s, ReadSolve(st));
    out.push_back(std::move(s));
  }
}

}  // namespace

absl::StatusOr<std::vector<Solve>> Store::ListSolves(std::string_view session_id) {
  ReadLease lease = AcquireReader();
  auto list = [&]() -> absl::StatusOr<std::vector<Solve>> {
    STORAGE_RETURN_IF_ERROR(CheckSessionExists(lease.conn(), session_id));
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, lease.conn().Prepare(kSelectSolvesOfSession));
    st->BindText(1, session_id);
    return ReadSolves(*st);
  };
  return Annotate("ListSolves", list());
}

absl::StatusOr<std::vector<Solve>> Store::ListRunningSolves() {
  ReadLease lease = AcquireReader();
  auto list = [&]() -> absl::StatusOr<std::vector<Solve>> {
    STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, lease.conn().Prepare(kSelectRunningSolves));
    return ReadSolves(*st);
  };
  return Annotate("ListRunningSolves", list());
}

// ---- Parameter versions ----------------------------------------------------------------------

absl::StatusOr<ParamVersion> Store::AddVersion(const ParamVersion& version,
                                               std::string_view actor) {
  constexpr std::string_view kOp = "AddVersion";
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return NotifyIfActive(InTransaction(
      kOp, *writer_, [&](Connection& conn) { return InsertVersion(conn, version, actor, Now()); }));
}

absl::StatusOr<ParamVersion> Store::Promote(std::string_view device_id, int version,
                                            std::string_view actor, std::string_view reason) {
  constexpr std::string_view kOp = "Promote";
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return NotifyIfActive(
      InTransaction(kOp, *writer_, [&](Connection& conn) -> absl::StatusOr<ParamVersion> {
        STORAGE_ASSIGN_OR_RETURN(ParamVersion v, LoadVersion(conn, device_id, version));
        if (v.state == VersionState::kActive) return v;
        if (v.state != VersionState::kCandidate) {
          return absl::FailedPreconditionError(Cat(
              "version ", version, " of device '", device_id, "' is ", VersionStateName(v.state),
              "; only a candidate can be promoted (Rollback makes an older version active)"));
        }
        STORAGE_ASSIGN_OR_RETURN(int displaced, Activate(conn, device_id, version));
        STORAGE_RETURN_IF_ERROR(
            InsertAudit(conn, Now(), actor, "version.promote", DeviceTarget(device_id),
                        Cat("version ", version, " active", Displaced(displaced), Reason(reason))));
        return LoadVersion(conn, device_id, version);
      }));
}

absl::StatusOr<ParamVersion> Store::Rollback(std::string_view device_id, int to_version,
                                             std::string_view actor, std::string_view reason) {
  constexpr std::string_view kOp = "Rollback";
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return NotifyIfActive(
      InTransaction(kOp, *writer_, [&](Connection& conn) -> absl::StatusOr<ParamVersion> {
        STORAGE_ASSIGN_OR_RETURN(ParamVersion target, LoadVersion(conn, device_id, to_version));
        STORAGE_ASSIGN_OR_RETURN(std::optional<ParamVersion> active, FindActive(conn, device_id));
        if (!active) {
          return absl::FailedPreconditionError(
              Cat("device '", device_id, "' has no active version to roll back from"));
        }
        if (to_version >= active->version) {
          return absl::FailedPreconditionError(
              Cat("version ", to_version, " is not older than the active version ", active->version,
                  " of device '", device_id, "'"));
        }
        STORAGE_ASSIGN_OR_RETURN(int displaced, Activate(conn, device_id, to_version));
        STORAGE_RETURN_IF_ERROR(
            InsertAudit(conn, Now(), actor, "version.rollback", DeviceTarget(device_id),
                        Cat("version ", to_version, " (was ", VersionStateName(target.state),
                            ") active", Displaced(displaced), Reason(reason))));
        return LoadVersion(conn, device_id, to_version);
      }));
}

absl::StatusOr<ParamVersion> Store::Reject(std::string_view device_id, int version,
                                           std::string_view actor, std::string_view reason) {
  constexpr std::string_view kOp = "Reject";
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](Connection& conn) -> absl::StatusOr<ParamVersion> {
    STORAGE_ASSIGN_OR_RETURN(ParamVersion v, LoadVersion(conn, device_id, version));
    if (v.state != VersionState::kCandidate) {
      return absl::FailedPreconditionError(Cat("version ", version, " of device '", device_id,
                                               "' is ", VersionStateName(v.state),
                                               "; only a candidate can be rejected"));
    }
    {
      STORAGE_ASSIGN_OR_RETURN(ScopedStatement st, conn.Prepare(kSetVersionState));
      st->BindText(1, device_id);
      st->BindInt64(2, version);
      st->BindText(3, VersionStateName(VersionState::kRejected));
      STORAGE_RETURN_IF_ERROR(st->Run());
    }
    STORAGE_RETURN_IF_ERROR(InsertAudit(conn, Now(), actor, "version.reject",
                                        DeviceTarget(device_id),
                                        Cat("version ", version, ": ", reason)));
    return LoadVersion(conn, device_id, version);
  });
}

absl::StatusOr<ParamVersion> Store::GetActive(std::string_view device_id) {
  ReadLease lease = AcquireReader();
  auto get = [&]() -> absl::StatusOr<ParamVersion> {
    STORAGE_ASSIGN_OR_RETURN(std::optional<ParamVersion> active,
                             FindActive(lease.conn(), device_id));
    if (active) return *std::move(active);
    // The miss path only: say whether the device exists at all.
    STORAGE_RETURN_IF_ERROR(LoadDevice(lease.conn(), device_id).status());
    return absl::NotFoundError(Cat("device '", device_id, "' has no active parameter version"));
  };
  return Annotate("GetActive", get());
}

absl::StatusOr<ParamVersion> Store::GetVersion(std::string_view device_id, int version) {
  ReadLease lease = AcquireReader();
  return Annotate("GetVersion", LoadVersion(lease.conn(), device_id, version));
}

absl::StatusOr<std::vector<ParamVersion>> Store::ListVersions(std::string_view device_id,
                                                              const VersionQuery& query) {
  ReadLease lease = AcquireReader();
  auto list = [&]() -> absl::StatusOr<std::vector<ParamVersion>> {
    STORAGE_RETURN_IF_ERROR(LoadDevice(lease.conn(), device_id).status());
    STORAGE_ASSIGN_OR_RETURN(
        ScopedStatement st,
        lease.conn().Prepare(query.with_documents ? kSelectVersionsOfDevice
                                                  : kSelectVersionHeadersOfDevice));
    st->BindText(1, device_id);
    st->BindInt64(2, query.after_version);
    st->BindInt64(3, SqlLimit(query.limit));
    const Documents docs = query.with_documents ? Documents::kBoth : Documents::kNone;
    std::vector<ParamVersion> out;
    for (;;) {
      STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
      if (!row) return out;
      STORAGE_ASSIGN_OR_RETURN(ParamVersion v, ReadVersion(*st, docs));
      out.push_back(std::move(v));
    }
  };
  return Annotate("ListVersions", list());
}

// ---- Audit log -------------------------------------------------------------------------------

absl::StatusOr<AuditEntry> Store::AppendAudit(const AuditEntry& entry) {
  constexpr std::string_view kOp = "AppendAudit";
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(entry.actor, "actor")));
  STORAGE_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(entry.action, "action")));
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](Connection& conn) -> absl::StatusOr<AuditEntry> {
    AuditEntry e = entry;
    e.time = Now();
    STORAGE_RETURN_IF_ERROR(InsertAudit(conn, e.time, e.actor, e.action, e.target, e.detail));
    e.id = sqlite3_last_insert_rowid(conn.db());
    return e;
  });
}

absl::StatusOr<std::vector<AuditEntry>> Store::ListAudit(const AuditQuery& query) {
  if (query.limit < 1) {
    return absl::InvalidArgumentError("ListAudit: limit must be at least 1");
  }
  ReadLease lease = AcquireReader();
  auto list = [&]() -> absl::StatusOr<std::vector<AuditEntry>> {
    STORAGE_ASSIGN_OR_RETURN(
        ScopedStatement st,
        lease.conn().Prepare(query.target.empty() ? kSelectAudit : kSelectAuditOfTarget));
    st->BindInt64(1, query.after_id);
    st->BindInt64(2, query.limit);
    if (!query.target.empty()) st->BindText(3, query.target);
    std::vector<AuditEntry> out;
    for (;;) {
      STORAGE_ASSIGN_OR_RETURN(bool row, st->Step());
      if (!row) return out;
      out.push_back(ReadAudit(*st));
    }
  };
  return Annotate("ListAudit", list());
}

}  // namespace imucal::storage
