// Store: the audit log (store.h "Audit log"). Storage's own actions write their entries with
// InsertAudit inside their transaction; AppendAudit is for actions outside storage.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "storage/status_macros.h"
#include "storage/store.h"
#include "storage/store_internal.h"
#include "util/db.h"

namespace imucal::storage {
namespace {

constexpr char kInsertAudit[] =
    "INSERT INTO audit_log (time_us, actor, action, target, detail) "
    "VALUES (?1, ?2, ?3, ?4, ?5) RETURNING id";
constexpr char kSelectAudit[] =
    "SELECT id, time_us, actor, action, target, detail FROM audit_log "
    "WHERE id > ?1 ORDER BY id LIMIT ?2";
constexpr char kSelectAuditOfTarget[] =
    "SELECT id, time_us, actor, action, target, detail FROM audit_log "
    "WHERE target = ?3 AND id > ?1 ORDER BY id LIMIT ?2";
constexpr char kSelectLastAuditId[] = "SELECT COALESCE(MAX(id), 0) FROM audit_log";
constexpr char kSelectAuditActions[] =
    "SELECT id, action, target FROM audit_log WHERE id > ?1 ORDER BY id LIMIT 1000";

// Columns as in kSelectAudit.
AuditEntry ReadAudit(const sql::Statement& st) {
  AuditEntry e;
  e.id = st.ColumnInt64(0);
  e.time = FromMicros(st.ColumnInt64(1));
  e.actor = st.ColumnText(2);
  e.action = st.ColumnText(3);
  e.target = st.ColumnText(4);
  e.detail = st.ColumnText(5);
  return e;
}

}  // namespace

absl::Status InsertAudit(sql::Connection& conn, absl::Time time, std::string_view actor,
                         std::string_view action, std::string_view target,
                         std::string_view detail) {
  return sql::RunStatement(conn, kInsertAudit, Micros(time), actor, action, target, detail);
}

absl::StatusOr<AuditEntry> Store::AppendAudit(const AuditEntry& entry) {
  constexpr std::string_view kOp = "AppendAudit";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(entry.actor, "actor")));
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(entry.action, "action")));
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<AuditEntry> {
    AuditEntry e = entry;
    e.time = Now();
    IMUCAL_ASSIGN_OR_RETURN(std::optional<int64_t> id,
                            sql::ReadRow(conn, kInsertAudit, sql::FirstColumnInt64, Micros(e.time),
                                         e.actor, e.action, e.target, e.detail));
    if (!id) return absl::InternalError("INSERT ... RETURNING id returned no row");
    e.id = *id;
    return e;
  });
}

absl::StatusOr<Store::ActiveChanges> Store::ActiveChangesSince(int64_t after_id) {
  constexpr std::string_view kOp = "ActiveChangesSince";
  ReadLease lease = AcquireReader();
  ActiveChanges out;
  out.last_id = after_id;
  if (after_id < 0) {
    IMUCAL_ASSIGN_OR_RETURN(
        std::optional<int64_t> last,
        Annotate(kOp, sql::ReadRow(lease.conn(), kSelectLastAuditId, sql::FirstColumnInt64)));
    out.last_id = last.value_or(0);
    return out;
  }
  struct Row {
    int64_t id;
    std::string action, target;
  };
  IMUCAL_ASSIGN_OR_RETURN(
      std::vector<Row> rows,
      Annotate(kOp, sql::ReadRows(
                        lease.conn(), kSelectAuditActions,
                        [](const sql::Statement& st) {
                          return Row{st.ColumnInt64(0), st.ColumnText(1), st.ColumnText(2)};
                        },
                        after_id)));
  constexpr std::string_view kDevice = "device:";
  for (const Row& r : rows) {
    out.last_id = r.id;
    if (r.action != "version.add" && r.action != "version.promote" &&
        r.action != "version.rollback")
      continue;
    if (r.target.starts_with(kDevice)) out.devices.push_back(r.target.substr(kDevice.size()));
  }
  return out;
}

absl::StatusOr<std::vector<AuditEntry>> Store::ListAudit(const AuditQuery& query) {
  if (query.limit < 1) {
    return absl::InvalidArgumentError("ListAudit: limit must be at least 1");
  }
  ReadLease lease = AcquireReader();
  if (query.target.empty()) {
    return Annotate("ListAudit", sql::ReadRows(lease.conn(), kSelectAudit, ReadAudit,
                                               query.after_id, query.limit));
  }
  return Annotate("ListAudit", sql::ReadRows(lease.conn(), kSelectAuditOfTarget, ReadAudit,
                                             query.after_id, query.limit, query.target));
}

}  // namespace imucal::storage
