// Store: parameter versions (store.h "Parameter versions") and the policy that moves them
// between candidate, active, superseded and rejected; at most one version of a device is active.
#include <cmath>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "storage/status_macros.h"
#include "storage/store.h"
#include "storage/store_internal.h"
#include "util/db.h"
#include "util/str_util.h"

namespace imucal::storage {
namespace {

// The 8 header columns ReadVersion maps; params_json and report_json may follow.
#define IMUCAL_SELECT_VERSION_HEADER \
  "SELECT device_id, version, created_at_us, session_id, verdict, accel_rms, state, provenance"
// The hot path. `state = 'active'` is a literal so the planner can use the partial index
// param_versions_active (migrations_test checks the plan). report_json is not read.
constexpr char kSelectActiveVersion[] = IMUCAL_SELECT_VERSION_HEADER
    ", params_json FROM param_versions WHERE device_id = ?1 AND state = 'active'";
constexpr char kSelectVersion[] = IMUCAL_SELECT_VERSION_HEADER
    ", params_json, report_json FROM param_versions WHERE device_id = ?1 AND version = ?2";
constexpr char kSelectVersionsOfDevice[] = IMUCAL_SELECT_VERSION_HEADER
    ", params_json, report_json FROM param_versions "
    "WHERE device_id = ?1 AND version > ?2 ORDER BY version LIMIT ?3";
// The same without the documents, which are most of each row's bytes.
constexpr char kSelectVersionHeadersOfDevice[] = IMUCAL_SELECT_VERSION_HEADER
    " FROM param_versions WHERE device_id = ?1 AND version > ?2 ORDER BY version LIMIT ?3";
#undef IMUCAL_SELECT_VERSION_HEADER
constexpr char kAnnounceActive[] = "SELECT pg_notify('imucal_active', ?1)";
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

// Which of the JSON documents a version statement selects (after the 8 header columns).
enum class Documents { kNone, kParams, kBoth };

// Columns as in kSelectVersion, up to what `docs` says the statement selects.
absl::StatusOr<ParamVersion> ReadVersion(const sql::Statement& st, Documents docs) {
  ParamVersion v;
  v.device_id = st.ColumnText(0);
  v.version = static_cast<int>(st.ColumnInt64(1));
  v.created_at = FromMicros(st.ColumnInt64(2));
  v.session_id = st.ColumnText(3);
  IMUCAL_ASSIGN_OR_RETURN(v.verdict, FromColumn(ParseVerdict(st.ColumnText(4))));
  v.accel_rms = st.ColumnDouble(5);
  IMUCAL_ASSIGN_OR_RETURN(v.state, FromColumn(ParseVersionState(st.ColumnText(6))));
  v.provenance = st.ColumnText(7);
  if (docs != Documents::kNone) v.params_json = st.ColumnText(8);
  if (docs == Documents::kBoth) v.report_json = st.ColumnText(9);
  return v;
}

// ReadVersion as a row mapper, for statements that select `docs`.
auto VersionWith(Documents docs) {
  return [docs](const sql::Statement& st) { return ReadVersion(st, docs); };
}

absl::StatusOr<std::optional<ParamVersion>> FindActive(sql::Connection& conn,
                                                       std::string_view device_id) {
  return sql::ReadRow(conn, kSelectActiveVersion, VersionWith(Documents::kParams), device_id);
}

absl::StatusOr<ParamVersion> LoadVersion(sql::Connection& conn, std::string_view device_id,
                                         int version) {
  IMUCAL_ASSIGN_OR_RETURN(
      std::optional<ParamVersion> v,
      sql::ReadRow(conn, kSelectVersion, VersionWith(Documents::kBoth), device_id, version));
  if (!v) {
    IMUCAL_RETURN_IF_ERROR(LoadDevice(conn, device_id).status());
    return absl::NotFoundError(Cat("device '", device_id, "' has no version ", version));
  }
  return *std::move(v);
}

// `documents`: whether params_json is checked (a version whose renderer writes it is checked
// again once rendered).
absl::Status ValidateNewVersion(const ParamVersion& v, bool documents) {
  IMUCAL_RETURN_IF_ERROR(NonEmpty(v.device_id, "device_id"));
  if (documents) IMUCAL_RETURN_IF_ERROR(NonEmpty(v.params_json, "params_json"));
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

absl::Status SetVersionState(sql::Connection& conn, std::string_view device_id, int version,
                             VersionState state) {
  return sql::RunStatement(conn, kSetVersionState, device_id, version, VersionStateName(state));
}

// Makes `version` the device's active one; returns the version it displaced (0 if none).
// PostgreSQL: every server listening (Store::ListenForActiveChanges) hears of it when the
// transaction commits, and not at all if it does not.
absl::StatusOr<int> Activate(sql::Connection& conn, std::string_view device_id, int version) {
  IMUCAL_ASSIGN_OR_RETURN(std::optional<ParamVersion> active, FindActive(conn, device_id));
  IMUCAL_RETURN_IF_ERROR(sql::RunStatement(conn, kSupersedeActive, device_id));
  IMUCAL_RETURN_IF_ERROR(SetVersionState(conn, device_id, version, VersionState::kActive));
  if (conn.dialect() == sql::Dialect::kPostgres) {
    IMUCAL_RETURN_IF_ERROR(sql::RunStatement(conn, kAnnounceActive, device_id));
  }
  return active ? active->version : 0;
}

std::string Displaced(int previous) {
  return previous == 0 ? std::string() : Cat("; version ", previous, " superseded");
}

std::string Reason(std::string_view reason) {
  return reason.empty() ? std::string() : Cat(": ", reason);
}

// Promote's and Rollback's change: activates `version`, audits it as `action` ("<what> active",
// the version it displaced, the reason) and returns it as stored.
absl::StatusOr<ParamVersion> ActivateAudited(sql::Connection& conn, std::string_view device_id,
                                             int version, std::string_view action,
                                             std::string_view what, std::string_view actor,
                                             std::string_view reason, absl::Time now) {
  IMUCAL_ASSIGN_OR_RETURN(int displaced, Activate(conn, device_id, version));
  IMUCAL_RETURN_IF_ERROR(InsertAudit(conn, now, actor, action, DeviceTarget(device_id),
                                     Cat(what, " active", Displaced(displaced), Reason(reason))));
  return LoadVersion(conn, device_id, version);
}

}  // namespace

absl::StatusOr<ParamVersion> InsertVersion(sql::Connection& conn, const ParamVersion& given,
                                           std::string_view actor, absl::Time now,
                                           const RenderVersion& render, std::string_view reason) {
  ParamVersion v = given;
  IMUCAL_RETURN_IF_ERROR(ValidateNewVersion(v, /*documents=*/!render));
  IMUCAL_RETURN_IF_ERROR(LoadDevice(conn, v.device_id).status());
  if (!v.session_id.empty()) {
    IMUCAL_ASSIGN_OR_RETURN(Session session, LoadSession(conn, v.session_id));
    if (session.device_id != v.device_id) {
      return absl::InvalidArgumentError(Cat("session '", v.session_id, "' belongs to device '",
                                            session.device_id, "', not '", v.device_id, "'"));
    }
  }
  // SQLite: the write lock is held (BEGIN IMMEDIATE), so MAX + 1 cannot race another writer.
  // PostgreSQL: a concurrent transaction that takes the same number conflicts with this one
  // (SERIALIZABLE, and UNIQUE (device_id, version)); one of them is aborted and runs again.
  IMUCAL_ASSIGN_OR_RETURN(
      std::optional<int64_t> next,
      sql::ReadRow(conn, kSelectNextVersion, sql::FirstColumnInt64, v.device_id));
  if (!next) return absl::InternalError("no next version");
  const int number = static_cast<int>(*next);
  if (render) {
    v.params_json.clear();
    v.report_json.clear();
    IMUCAL_RETURN_IF_ERROR(render(number, &v.params_json, &v.report_json));
    IMUCAL_RETURN_IF_ERROR(ValidateNewVersion(v, /*documents=*/true));
  }
  IMUCAL_RETURN_IF_ERROR(sql::RunStatement(conn, kInsertVersion, v.device_id, number, Micros(now),
                                           NullIfEmpty(v.session_id), VerdictName(v.verdict),
                                           v.accel_rms, VersionStateName(VersionState::kCandidate),
                                           v.provenance, v.params_json, v.report_json));
  int displaced = 0;
  if (v.state == VersionState::kActive) {
    IMUCAL_ASSIGN_OR_RETURN(displaced, Activate(conn, v.device_id, number));
  }
  IMUCAL_RETURN_IF_ERROR(InsertAudit(
      conn, now, actor, "version.add", DeviceTarget(v.device_id),
      Cat("version ", number, " ", VersionStateName(v.state), ", verdict ", VerdictName(v.verdict),
          ", accel_rms ", v.accel_rms, v.session_id.empty() ? "" : Cat(", session ", v.session_id),
          Displaced(displaced), Reason(reason))));
  return LoadVersion(conn, v.device_id, number);
}

absl::StatusOr<ParamVersion> Store::AddVersion(const ParamVersion& version, std::string_view actor,
                                               const RenderVersion& render,
                                               std::string_view reason) {
  constexpr std::string_view kOp = "AddVersion";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return NotifyIfActive(InTransaction(kOp, *writer_, [&](sql::Connection& conn) {
    return InsertVersion(conn, version, actor, Now(), render, reason);
  }));
}

absl::StatusOr<ParamVersion> Store::Promote(std::string_view device_id, int version,
                                            std::string_view actor, std::string_view reason) {
  constexpr std::string_view kOp = "Promote";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return NotifyIfActive(
      InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<ParamVersion> {
        IMUCAL_ASSIGN_OR_RETURN(ParamVersion v, LoadVersion(conn, device_id, version));
        if (v.state == VersionState::kActive) return v;
        if (v.state != VersionState::kCandidate) {
          return absl::FailedPreconditionError(Cat(
              "version ", version, " of device '", device_id, "' is ", VersionStateName(v.state),
              "; only a candidate can be promoted (Rollback makes an older version active)"));
        }
        return ActivateAudited(conn, device_id, version, "version.promote",
                               Cat("version ", version), actor, reason, Now());
      }));
}

absl::StatusOr<ParamVersion> Store::Rollback(std::string_view device_id, int to_version,
                                             std::string_view actor, std::string_view reason) {
  constexpr std::string_view kOp = "Rollback";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return NotifyIfActive(
      InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<ParamVersion> {
        IMUCAL_ASSIGN_OR_RETURN(ParamVersion target, LoadVersion(conn, device_id, to_version));
        IMUCAL_ASSIGN_OR_RETURN(std::optional<ParamVersion> active, FindActive(conn, device_id));
        if (!active) {
          return absl::FailedPreconditionError(
              Cat("device '", device_id, "' has no active version to roll back from"));
        }
        if (to_version >= active->version) {
          return absl::FailedPreconditionError(
              Cat("version ", to_version, " is not older than the active version ", active->version,
                  " of device '", device_id, "'"));
        }
        return ActivateAudited(
            conn, device_id, to_version, "version.rollback",
            Cat("version ", to_version, " (was ", VersionStateName(target.state), ")"), actor,
            reason, Now());
      }));
}

absl::StatusOr<ParamVersion> Store::Reject(std::string_view device_id, int version,
                                           std::string_view actor, std::string_view reason) {
  constexpr std::string_view kOp = "Reject";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<ParamVersion> {
    IMUCAL_ASSIGN_OR_RETURN(ParamVersion v, LoadVersion(conn, device_id, version));
    if (v.state != VersionState::kCandidate) {
      return absl::FailedPreconditionError(Cat("version ", version, " of device '", device_id,
                                               "' is ", VersionStateName(v.state),
                                               "; only a candidate can be rejected"));
    }
    IMUCAL_RETURN_IF_ERROR(SetVersionState(conn, device_id, version, VersionState::kRejected));
    IMUCAL_RETURN_IF_ERROR(InsertAudit(conn, Now(), actor, "version.reject",
                                       DeviceTarget(device_id),
                                       Cat("version ", version, ": ", reason)));
    return LoadVersion(conn, device_id, version);
  });
}

absl::StatusOr<ParamVersion> Store::GetActive(std::string_view device_id) {
  ReadLease lease = AcquireReader();
  auto get = [&]() -> absl::StatusOr<ParamVersion> {
    IMUCAL_ASSIGN_OR_RETURN(std::optional<ParamVersion> active,
                            FindActive(lease.conn(), device_id));
    if (active) return *std::move(active);
    // The miss path only: say whether the device exists at all.
    IMUCAL_RETURN_IF_ERROR(LoadDevice(lease.conn(), device_id).status());
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
    IMUCAL_RETURN_IF_ERROR(LoadDevice(lease.conn(), device_id).status());
    return sql::ReadRows(
        lease.conn(),
        query.with_documents ? kSelectVersionsOfDevice : kSelectVersionHeadersOfDevice,
        VersionWith(query.with_documents ? Documents::kBoth : Documents::kNone), device_id,
        query.after_version, SqlLimit(query.limit));
  };
  return Annotate("ListVersions", list());
}

}  // namespace imucal::storage
