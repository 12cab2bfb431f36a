// Store: sessions (store.h "Sessions") and their state machine (types.h). A session's
// last_acked_seq, samples, poses_accepted and version are derived from the batches, poses and
// solves tables.
#include <cmath>
#include <cstdint>
#include <optional>
#include <random>
#include <string>
#include <utility>

#include "absl/strings/str_format.h"
#include "storage/status_macros.h"
#include "storage/store.h"
#include "storage/store_internal.h"
#include "util/db.h"
#include "util/str_util.h"

namespace imucal::storage {
namespace {

// The columns ReadSession maps, for the three statements below. The derived ones are the last
// batch's seq and running sample total (seeks backwards on the batches' primary key), the
// accepted poses, and the version of the latest successful solve.
#define IMUCAL_SELECT_SESSION_COLUMNS                                                \
  "SELECT s.id, s.device_id, s.state, s.protocol, s.gravity_m_s2, s.created_at_us, " \
  "s.updated_at_us, "                                                                \
  "COALESCE((SELECT b.seq FROM sample_batches b WHERE b.session_id = s.id "          \
  "ORDER BY b.seq DESC LIMIT 1), 0), "                                               \
  "COALESCE((SELECT b.end_sample FROM sample_batches b WHERE b.session_id = s.id "   \
  "ORDER BY b.seq DESC LIMIT 1), 0), "                                               \
  "(SELECT COUNT(*) FROM poses p WHERE p.session_id = s.id AND p.used = 1), "        \
  "COALESCE((SELECT v.version FROM solves v WHERE v.session_id = s.id "              \
  "AND v.state = 'succeeded' ORDER BY v.id DESC LIMIT 1), 0), s.source "
constexpr char kAnnounceSession[] =
    "SELECT pg_notify('imucal_session', current_setting('imucal.origin', true) || ' ' || ?1)";
constexpr char kSelectSession[] = IMUCAL_SELECT_SESSION_COLUMNS "FROM sessions s WHERE s.id = ?1";
// Lists page by rowid (creation order): ?3 is the rowid of the previous page's last session.
constexpr char kSelectSessionsOfDevice[] = IMUCAL_SELECT_SESSION_COLUMNS
    "FROM sessions s WHERE s.device_id = ?1 AND (CAST(?2 AS TEXT) IS NULL OR s.state = ?2) AND s.rowid > ?3 "
    "ORDER BY s.rowid LIMIT ?4";
// ?1 is unused (bound to the empty device id): the same parameters as kSelectSessionsOfDevice.
constexpr char kSelectSessionsAll[] = IMUCAL_SELECT_SESSION_COLUMNS
    "FROM sessions s WHERE (CAST(?2 AS TEXT) IS NULL OR s.state = ?2) AND s.rowid > ?3 "
    "ORDER BY s.rowid LIMIT ?4";
#undef IMUCAL_SELECT_SESSION_COLUMNS
constexpr char kSelectSessionRowid[] = "SELECT rowid FROM sessions WHERE id = ?1";
constexpr char kSelectOpenSessionOfDevice[] =
    "SELECT id FROM sessions WHERE device_id = ?1 AND state = 'open'";
constexpr char kInsertSession[] =
    "INSERT INTO sessions (id, device_id, state, protocol, gravity_m_s2, created_at_us, "
    "updated_at_us) VALUES (?1, ?2, 'open', ?3, ?4, ?5, ?5)";
constexpr char kUpdateSessionState[] =
    "UPDATE sessions SET state = ?2, updated_at_us = ?3 WHERE id = ?1";
constexpr char kUpdateSessionSource[] =
    "UPDATE sessions SET source = ?2 WHERE id = ?1 AND state = 'open' AND NOT EXISTS "
    "(SELECT 1 FROM sample_batches b WHERE b.session_id = ?1)";
constexpr char kSessionExists[] = "SELECT 1 FROM sessions WHERE id = ?1";

// Columns as in kSelectSession.
absl::StatusOr<Session> ReadSession(const sql::Statement& st) {
  Session s;
  s.id = st.ColumnText(0);
  s.device_id = st.ColumnText(1);
  IMUCAL_ASSIGN_OR_RETURN(s.state, FromColumn(ParseSessionState(st.ColumnText(2))));
  s.protocol = st.ColumnText(3);
  s.gravity_m_s2 = st.ColumnDouble(4);
  s.created_at = FromMicros(st.ColumnInt64(5));
  s.updated_at = FromMicros(st.ColumnInt64(6));
  s.last_acked_seq = st.ColumnInt64(7);
  s.samples = st.ColumnInt64(8);
  s.poses_accepted = static_cast<int>(st.ColumnInt64(9));
  s.version = static_cast<int>(st.ColumnInt64(10));
  s.source = st.ColumnText(11);
  return s;
}

absl::StatusOr<std::optional<std::string>> FindOpenSession(sql::Connection& conn,
                                                           std::string_view device_id) {
  return sql::ReadRow(conn, kSelectOpenSessionOfDevice, sql::FirstColumnText, device_id);
}

std::string GenerateSessionId() {
  // 128 random bits: unguessable and collision-free in practice. random_device is slow but
  // sessions are rare.
  std::random_device rd;
  uint64_t hi = (uint64_t{rd()} << 32) | rd();
  uint64_t lo = (uint64_t{rd()} << 32) | rd();
  return absl::StrFormat("s-%016x%016x", hi, lo);
}

// ---- The state machine (types.h) -------------------------------------------------------------

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

}  // namespace

absl::StatusOr<Session> LoadSession(sql::Connection& conn, std::string_view id) {
  IMUCAL_ASSIGN_OR_RETURN(std::optional<Session> s,
                          sql::ReadRow(conn, kSelectSession, ReadSession, id));
  if (!s) return absl::NotFoundError(Cat("no session '", id, "'"));
  return *std::move(s);
}

absl::Status CheckSessionExists(sql::Connection& conn, std::string_view id) {
  IMUCAL_ASSIGN_OR_RETURN(
      std::optional<bool> found,
      sql::ReadRow(
          conn, kSessionExists, [](const sql::Statement&) { return true; }, id));
  if (!found) return absl::NotFoundError(Cat("no session '", id, "'"));
  return absl::OkStatus();
}

absl::Status AnnounceSession(sql::Connection& conn, std::string_view session_id) {
  if (conn.dialect() != sql::Dialect::kPostgres) return absl::OkStatus();
  return sql::RunStatement(conn, kAnnounceSession, session_id);
}

absl::Status ChangeSessionState(sql::Connection& conn, const Session& session, SessionState to,
                                std::string_view actor, absl::Time now) {
  if (!TransitionAllowed(session.state, to)) {
    return absl::FailedPreconditionError(Cat(
        "session '", session.id, "' is ", SessionStateName(session.state), "; it cannot become ",
        SessionStateName(to), " (allowed: ", AllowedFrom(session.state), ")"));
  }
  if (to == SessionState::kOpen) {
    IMUCAL_ASSIGN_OR_RETURN(std::optional<std::string> open,
                            FindOpenSession(conn, session.device_id));
    if (open) {
      return absl::FailedPreconditionError(
          Cat("device '", session.device_id, "' already has an open session '", *open, "'"));
    }
  }
  IMUCAL_RETURN_IF_ERROR(
      sql::RunStatement(conn, kUpdateSessionState, session.id, SessionStateName(to), Micros(now)));
  IMUCAL_RETURN_IF_ERROR(AnnounceSession(conn, session.id));
  return InsertAudit(conn, now, actor, "session.state", SessionTarget(session.id),
                     Cat(SessionStateName(session.state), " -> ", SessionStateName(to)));
}

absl::StatusOr<Session> Store::CreateSession(const Session& session, std::string_view actor) {
  constexpr std::string_view kOp = "CreateSession";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(session.device_id, "device_id")));
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  if (!std::isfinite(session.gravity_m_s2) || session.gravity_m_s2 <= 0) {
    return WithContext(kOp, absl::InvalidArgumentError(Cat("gravity_m_s2 ", session.gravity_m_s2,
                                                           " is not a positive number")));
  }
  const std::string id = session.id.empty() ? GenerateSessionId() : session.id;
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<Session> {
    IMUCAL_RETURN_IF_ERROR(LoadDevice(conn, session.device_id).status());
    IMUCAL_ASSIGN_OR_RETURN(std::optional<std::string> open,
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
    IMUCAL_RETURN_IF_ERROR(sql::RunStatement(conn, kInsertSession, id, session.device_id,
                                             session.protocol, session.gravity_m_s2, Micros(now)));
    IMUCAL_RETURN_IF_ERROR(
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
  sql::Connection& conn = lease.conn();
  auto list = [&]() -> absl::StatusOr<std::vector<Session>> {
    int64_t after_rowid = 0;
    if (!query.after_id.empty()) {
      IMUCAL_ASSIGN_OR_RETURN(
          std::optional<int64_t> rowid,
          sql::ReadRow(conn, kSelectSessionRowid, sql::FirstColumnInt64, query.after_id));
      if (!rowid) {
        return absl::InvalidArgumentError(Cat("page after unknown session '", query.after_id, "'"));
      }
      after_rowid = *rowid;
    }
    const bool of_device = !query.device_id.empty();
    if (of_device) IMUCAL_RETURN_IF_ERROR(LoadDevice(conn, query.device_id).status());
    std::optional<std::string_view> state;
    if (query.state) state = SessionStateName(*query.state);
    return sql::ReadRows(conn, of_device ? kSelectSessionsOfDevice : kSelectSessionsAll,
                         ReadSession, query.device_id, state, after_rowid, SqlLimit(query.limit));
  };
  return Annotate("ListSessions", list());
}

absl::StatusOr<Session> Store::SetSessionState(std::string_view id, SessionState state,
                                               std::string_view actor) {
  constexpr std::string_view kOp = "SetSessionState";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<Session> {
    IMUCAL_ASSIGN_OR_RETURN(Session session, LoadSession(conn, id));
    const absl::Time now = Now();
    IMUCAL_RETURN_IF_ERROR(ChangeSessionState(conn, session, state, actor, now));
    if (session.state == SessionState::kSolving) {
      // Leaving `solving` by hand abandons its running solve: it can no longer finish.
      IMUCAL_RETURN_IF_ERROR(AbandonRunningSolve(
          conn, id, now,
          Cat("abandoned: session set to ", SessionStateName(state), " by ", actor)));
    }
    return LoadSession(conn, id);
  });
}

absl::Status Store::SetSessionSource(std::string_view id, std::string_view source) {
  constexpr std::string_view kOp = "SetSessionSource";
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::Status {
    IMUCAL_ASSIGN_OR_RETURN(Session session, LoadSession(conn, id));
    if (session.state != SessionState::kOpen || session.samples > 0) {
      return absl::FailedPreconditionError(Cat("session '", id, "' is ",
                                               SessionStateName(session.state), " and holds ",
                                               session.samples, " samples: its source is set"));
    }
    return sql::RunStatement(conn, kUpdateSessionSource, id, source);
  });
}

}  // namespace imucal::storage
