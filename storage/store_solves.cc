// Store: solves (store.h "Solves"), the unit of work that turns a session's raw data into a
// parameter version, with the session state changes each step makes.
#include <cstdint>
#include <optional>
#include <utility>
#include <vector>

#include "storage/status_macros.h"
#include "storage/store.h"
#include "storage/store_internal.h"
#include "util/db.h"
#include "util/str_util.h"

namespace imucal::storage {
namespace {

// The columns ReadSolve maps.
#define IMUCAL_SELECT_SOLVE_COLUMNS                                                      \
  "SELECT id, session_id, state, actor, started_at_us, finished_at_us, version, error, " \
  "report_json, owner, lease_until_us, seed, attempts "
constexpr char kSelectSolve[] = IMUCAL_SELECT_SOLVE_COLUMNS "FROM solves WHERE id = ?1";
constexpr char kSelectSolvesOfSession[] =
    IMUCAL_SELECT_SOLVE_COLUMNS "FROM solves WHERE session_id = ?1 ORDER BY id";
constexpr char kSelectRunningSolves[] =
    IMUCAL_SELECT_SOLVE_COLUMNS "FROM solves WHERE state = 'running' ORDER BY id";
constexpr char kSelectOrphanedSolves[] = IMUCAL_SELECT_SOLVE_COLUMNS
    "FROM solves WHERE state = 'running' AND ((owner = ?1 AND ?1 <> '') OR lease_until_us < ?2) "
    "ORDER BY id";
#undef IMUCAL_SELECT_SOLVE_COLUMNS
// The oldest running solve whose lease has ended. PostgreSQL: locked for this transaction, and
// one another server's transaction has locked is skipped, so that concurrent claimers each get
// a different one (or none); SQLite's write lock lets one claimer in at a time anyway.
#define IMUCAL_SELECT_LAPSED_SOLVE \
  "SELECT id FROM solves WHERE state = 'running' AND lease_until_us < ?1 ORDER BY id LIMIT 1"
constexpr char kSelectLapsedSolvePg[] = IMUCAL_SELECT_LAPSED_SOLVE " FOR UPDATE SKIP LOCKED";
constexpr char kSelectLapsedSolveSqlite[] = IMUCAL_SELECT_LAPSED_SOLVE;
#undef IMUCAL_SELECT_LAPSED_SOLVE
// Ends the leases of the running solves ?1 claimed (?2: LeaseMicros(InfinitePast())).
constexpr char kReleaseClaims[] =
    "UPDATE solves SET lease_until_us = ?2 WHERE state = 'running' AND owner = ?1 RETURNING id";
constexpr char kClaimSolve[] =
    "UPDATE solves SET owner = ?2, lease_until_us = ?3, attempts = attempts + 1 WHERE id = ?1";
constexpr char kInsertSolve[] =
    "INSERT INTO solves (session_id, state, actor, started_at_us, owner, lease_until_us, seed) "
    "VALUES (?1, 'running', ?2, ?3, ?4, ?5, ?6) RETURNING id";
constexpr char kRenewLeases[] =
    "UPDATE solves SET lease_until_us = ?2 WHERE state = 'running' AND owner = ?1 RETURNING id";
constexpr char kFinishSolve[] =
    "UPDATE solves SET state = ?2, finished_at_us = ?3, version = ?4, error = ?5, "
    "report_json = ?6 WHERE id = ?1";
constexpr char kAbandonRunningSolves[] =
    "UPDATE solves SET state = 'failed', finished_at_us = ?2, error = ?3 "
    "WHERE session_id = ?1 AND state = 'running'";

// Leases that never end or have always ended are stored as the largest and smallest times.
int64_t LeaseMicros(absl::Time until) {
  if (until == absl::InfiniteFuture()) return INT64_MAX;
  if (until == absl::InfinitePast()) return INT64_MIN;
  return Micros(until);
}
absl::Time LeaseFromMicros(int64_t us) {
  if (us == INT64_MAX) return absl::InfiniteFuture();
  if (us == INT64_MIN) return absl::InfinitePast();
  return FromMicros(us);
}

// Columns as in kSelectSolve.
absl::StatusOr<Solve> ReadSolve(const sql::Statement& st) {
  Solve s;
  s.id = st.ColumnInt64(0);
  s.session_id = st.ColumnText(1);
  IMUCAL_ASSIGN_OR_RETURN(s.state, FromColumn(ParseSolveState(st.ColumnText(2))));
  s.actor = st.ColumnText(3);
  s.started_at = FromMicros(st.ColumnInt64(4));
  if (!st.ColumnIsNull(5)) s.finished_at = FromMicros(st.ColumnInt64(5));
  s.version = static_cast<int>(st.ColumnInt64(6));
  s.error = st.ColumnText(7);
  s.report_json = st.ColumnText(8);
  s.owner = st.ColumnText(9);
  s.lease_until = LeaseFromMicros(st.ColumnInt64(10));
  s.seed = static_cast<uint64_t>(st.ColumnInt64(11));  // stored as its 64 bits, signed
  s.attempts = static_cast<int>(st.ColumnInt64(12));
  return s;
}

absl::StatusOr<Solve> LoadSolve(sql::Connection& conn, int64_t id) {
  IMUCAL_ASSIGN_OR_RETURN(std::optional<Solve> s, sql::ReadRow(conn, kSelectSolve, ReadSolve, id));
  if (!s) return absl::NotFoundError(Cat("no solve ", id));
  return *std::move(s);
}

// The running solve `solve_id`: FailedPrecondition once it has finished, or when `owner` (if
// given) no longer holds its claim (another server claimed it after the lease lapsed: only the
// claim's holder may end it, so a version is written once).
absl::StatusOr<Solve> LoadRunningSolve(sql::Connection& conn, int64_t solve_id,
                                       std::string_view owner = {}) {
  IMUCAL_ASSIGN_OR_RETURN(Solve solve, LoadSolve(conn, solve_id));
  if (solve.state != SolveState::kRunning) {
    return absl::FailedPreconditionError(
        Cat("solve ", solve_id, " is ", SolveStateName(solve.state), ", not running"));
  }
  if (!owner.empty() && solve.owner != owner) {
    return absl::FailedPreconditionError(Cat("solve ", solve_id, " is claimed by '", solve.owner,
                                             "' now, not '", owner, "' (its lease lapsed)"));
  }
  return solve;
}

// Ends solve `solve_id` as `state` (succeeded with `version`, or failed with `error`).
absl::Status FinishSolveRow(sql::Connection& conn, int64_t solve_id, SolveState state,
                            absl::Time now, int version, std::string_view error,
                            std::string_view report_json) {
  return sql::RunStatement(conn, kFinishSolve, solve_id, SolveStateName(state), Micros(now),
                           version, error, report_json);
}

}  // namespace

absl::Status AbandonRunningSolve(sql::Connection& conn, std::string_view session_id, absl::Time now,
                                 std::string_view error) {
  return sql::RunStatement(conn, kAbandonRunningSolves, session_id, Micros(now), error);
}

absl::StatusOr<Solve> Store::StartSolve(std::string_view session_id, std::string_view actor,
                                        const SolveClaim& claim, uint64_t seed) {
  constexpr std::string_view kOp = "StartSolve";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<Solve> {
    IMUCAL_ASSIGN_OR_RETURN(Session session, LoadSession(conn, session_id));
    const absl::Time now = Now();
    IMUCAL_RETURN_IF_ERROR(ChangeSessionState(conn, session, SessionState::kSolving, actor, now));
    IMUCAL_ASSIGN_OR_RETURN(
        std::optional<int64_t> inserted,
        sql::ReadRow(conn, kInsertSolve, sql::FirstColumnInt64, session_id, actor, Micros(now),
                     claim.owner, LeaseMicros(claim.lease_until), static_cast<int64_t>(seed)));
    if (!inserted) return absl::InternalError("INSERT ... RETURNING id returned no row");
    const int64_t id = *inserted;
    IMUCAL_RETURN_IF_ERROR(
        InsertAudit(conn, now, actor, "solve.start", SessionTarget(session_id), Cat("solve ", id)));
    return LoadSolve(conn, id);
  });
}

absl::StatusOr<ParamVersion> Store::FinishSolve(int64_t solve_id, const ParamVersion& version,
                                                std::string_view actor,
                                                const RenderVersion& render,
                                                std::string_view owner) {
  constexpr std::string_view kOp = "FinishSolve";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return NotifyIfActive(
      InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<ParamVersion> {
        IMUCAL_ASSIGN_OR_RETURN(Solve solve, LoadRunningSolve(conn, solve_id, owner));
        IMUCAL_ASSIGN_OR_RETURN(Session session, LoadSession(conn, solve.session_id));
        ParamVersion v = version;
        if (v.device_id.empty()) v.device_id = session.device_id;
        if (v.session_id.empty()) v.session_id = session.id;
        if (v.device_id != session.device_id || v.session_id != session.id) {
          return absl::InvalidArgumentError(Cat("solve ", solve_id, " is of session '", session.id,
                                                "' of device '", session.device_id, "', not of '",
                                                v.session_id, "' of '", v.device_id, "'"));
        }
        const absl::Time now = Now();
        IMUCAL_ASSIGN_OR_RETURN(ParamVersion added, InsertVersion(conn, v, actor, now, render));
        // The report is the version's.
        IMUCAL_RETURN_IF_ERROR(
            FinishSolveRow(conn, solve_id, SolveState::kSucceeded, now, added.version, "", ""));
        IMUCAL_RETURN_IF_ERROR(
            ChangeSessionState(conn, session, SessionState::kSolved, actor, now));
        IMUCAL_RETURN_IF_ERROR(InsertAudit(conn, now, actor, "solve.finish",
                                           SessionTarget(session.id),
                                           Cat("solve ", solve_id, " -> version ", added.version)));
        return added;
      }));
}

absl::StatusOr<Solve> Store::FailSolve(int64_t solve_id, std::string_view error,
                                       std::string_view report_json, std::string_view actor,
                                       SessionState next, std::string_view owner) {
  constexpr std::string_view kOp = "FailSolve";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  if (next != SessionState::kFailed && next != SessionState::kOpen) {
    return absl::InvalidArgumentError(Cat(
        kOp, ": after a failed solve a session is failed or open, not ", SessionStateName(next)));
  }
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<Solve> {
    IMUCAL_ASSIGN_OR_RETURN(Solve solve, LoadRunningSolve(conn, solve_id, owner));
    IMUCAL_ASSIGN_OR_RETURN(Session session, LoadSession(conn, solve.session_id));
    const absl::Time now = Now();
    IMUCAL_RETURN_IF_ERROR(
        FinishSolveRow(conn, solve_id, SolveState::kFailed, now, 0, error, report_json));
    IMUCAL_RETURN_IF_ERROR(ChangeSessionState(conn, session, next, actor, now));
    IMUCAL_RETURN_IF_ERROR(InsertAudit(conn, now, actor, "solve.fail", SessionTarget(session.id),
                                       Cat("solve ", solve_id, ": ", error)));
    return LoadSolve(conn, solve_id);
  });
}

absl::StatusOr<Solve> Store::GetSolve(int64_t solve_id) {
  ReadLease lease = AcquireReader();
  return Annotate("GetSolve", LoadSolve(lease.conn(), solve_id));
}

absl::StatusOr<std::vector<Solve>> Store::ListSolves(std::string_view session_id) {
  ReadLease lease = AcquireReader();
  auto list = [&]() -> absl::StatusOr<std::vector<Solve>> {
    IMUCAL_RETURN_IF_ERROR(CheckSessionExists(lease.conn(), session_id));
    return sql::ReadRows(lease.conn(), kSelectSolvesOfSession, ReadSolve, session_id);
  };
  return Annotate("ListSolves", list());
}

absl::StatusOr<int> Store::RenewSolveLeases(std::string_view owner, absl::Time until) {
  constexpr std::string_view kOp = "RenewSolveLeases";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(owner, "owner")));
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<int> {
    IMUCAL_ASSIGN_OR_RETURN(
        std::vector<int64_t> renewed,
        sql::ReadRows(conn, kRenewLeases, sql::FirstColumnInt64, owner, LeaseMicros(until)));
    return static_cast<int>(renewed.size());
  });
}

absl::StatusOr<std::vector<Solve>> Store::ListOrphanedSolves(absl::Time now,
                                                             std::string_view restarted) {
  ReadLease lease = AcquireReader();
  return Annotate("ListOrphanedSolves", sql::ReadRows(lease.conn(), kSelectOrphanedSolves,
                                                      ReadSolve, restarted, Micros(now)));
}

absl::StatusOr<int> Store::ReleaseSolveClaims(std::string_view owner) {
  constexpr std::string_view kOp = "ReleaseSolveClaims";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(owner, "owner")));
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<int> {
    IMUCAL_ASSIGN_OR_RETURN(std::vector<int64_t> ids,
                            sql::ReadRows(conn, kReleaseClaims, sql::FirstColumnInt64, owner,
                                          LeaseMicros(absl::InfinitePast())));
    for (int64_t id : ids) {
      IMUCAL_ASSIGN_OR_RETURN(Solve solve, LoadSolve(conn, id));
      IMUCAL_RETURN_IF_ERROR(InsertAudit(conn, Now(), owner, "solve.release",
                                         SessionTarget(solve.session_id),
                                         Cat("solve ", id, ": its server restarted")));
    }
    return static_cast<int>(ids.size());
  });
}

absl::StatusOr<std::optional<Solve>> Store::ClaimLapsedSolve(absl::Time now,
                                                              const SolveClaim& claim) {
  constexpr std::string_view kOp = "ClaimLapsedSolve";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(claim.owner, "owner")));
  std::lock_guard lock(write_mu_);
  return InTransaction(
      kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<std::optional<Solve>> {
        IMUCAL_ASSIGN_OR_RETURN(
            std::optional<int64_t> id,
            sql::ReadRow(conn,
                         conn.dialect() == sql::Dialect::kPostgres ? kSelectLapsedSolvePg
                                                                   : kSelectLapsedSolveSqlite,
                         sql::FirstColumnInt64, Micros(now)));
        if (!id) return std::nullopt;
        IMUCAL_ASSIGN_OR_RETURN(Solve before, LoadSolve(conn, *id));
        IMUCAL_RETURN_IF_ERROR(
            sql::RunStatement(conn, kClaimSolve, *id, claim.owner, LeaseMicros(claim.lease_until)));
        IMUCAL_RETURN_IF_ERROR(
            InsertAudit(conn, Now(), claim.owner, "solve.claim", SessionTarget(before.session_id),
                        Cat("solve ", *id, " from '", before.owner, "', whose lease lapsed")));
        IMUCAL_ASSIGN_OR_RETURN(Solve claimed, LoadSolve(conn, *id));
        return std::optional<Solve>(std::move(claimed));
      });
}

absl::StatusOr<std::vector<Solve>> Store::ListRunningSolves() {
  ReadLease lease = AcquireReader();
  return Annotate("ListRunningSolves",
                  sql::ReadRows(lease.conn(), kSelectRunningSolves, ReadSolve));
}

}  // namespace imucal::storage
