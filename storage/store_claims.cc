// Store: stream claims (store.h "Stream claims"), one open sample stream per device across the
// servers sharing the database.
#include <optional>
#include <string>
#include <vector>

#include "storage/status_macros.h"
#include "storage/store.h"
#include "storage/store_internal.h"
#include "util/db.h"

namespace imucal::storage {
namespace {

// Taken when free, held by ?2 already, or lapsed (?5: now); otherwise left as it is.
constexpr char kClaimStream[] =
    "INSERT INTO stream_claims (device_id, holder, session_id, lease_until_us) "
    "VALUES (?1, ?2, ?3, ?4) ON CONFLICT (device_id) DO UPDATE SET holder = excluded.holder, "
    "session_id = excluded.session_id, lease_until_us = excluded.lease_until_us "
    "WHERE stream_claims.holder = excluded.holder OR stream_claims.lease_until_us < ?5";
constexpr char kSelectClaim[] =
    "SELECT device_id, holder, session_id, lease_until_us FROM stream_claims WHERE device_id = ?1";
constexpr char kRenewClaims[] =
    "UPDATE stream_claims SET lease_until_us = ?2 WHERE holder = ?1 RETURNING device_id";
constexpr char kReleaseClaim[] = "DELETE FROM stream_claims WHERE device_id = ?1 AND holder = ?2";
// ?1: "<replica id> ", the start of each of the replica's holder names.
constexpr char kReleaseReplicaClaims[] =
    "DELETE FROM stream_claims WHERE substr(holder, 1, length(?1)) = ?1 RETURNING device_id";

StreamClaim ReadClaim(const sql::Statement& st) {
  StreamClaim c;
  c.device_id = st.ColumnText(0);
  c.holder = st.ColumnText(1);
  c.session_id = st.ColumnText(2);
  c.lease_until = FromMicros(st.ColumnInt64(3));
  return c;
}

}  // namespace

absl::StatusOr<StreamClaim> Store::ClaimStream(std::string_view device_id, std::string_view holder,
                                               std::string_view session_id, absl::Time until) {
  constexpr std::string_view kOp = "ClaimStream";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(holder, "holder")));
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<StreamClaim> {
    IMUCAL_RETURN_IF_ERROR(sql::RunStatement(conn, kClaimStream, device_id, holder, session_id,
                                             Micros(until), Micros(Now())));
    IMUCAL_ASSIGN_OR_RETURN(std::optional<StreamClaim> claim,
                            sql::ReadRow(conn, kSelectClaim, ReadClaim, device_id));
    if (!claim) return absl::InternalError("the stream claim just written is not there");
    return *std::move(claim);
  });
}

absl::StatusOr<std::optional<StreamClaim>> Store::GetStreamClaim(std::string_view device_id) {
  ReadLease lease = AcquireReader();
  absl::StatusOr<std::optional<StreamClaim>> claim =
      sql::ReadRow(lease.conn(), kSelectClaim, ReadClaim, device_id);
  if (!claim.ok()) return Annotate("GetStreamClaim", claim.status());
  if (*claim && (*claim)->lease_until < Now()) return std::nullopt;  // lapsed: nobody streams
  return claim;
}

absl::StatusOr<std::vector<std::string>> Store::RenewStreamClaims(std::string_view holder,
                                                                  absl::Time until) {
  constexpr std::string_view kOp = "RenewStreamClaims";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(holder, "holder")));
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) {
    return sql::ReadRows(conn, kRenewClaims, sql::FirstColumnText, holder, Micros(until));
  });
}

absl::Status Store::ReleaseStreamClaim(std::string_view device_id, std::string_view holder) {
  constexpr std::string_view kOp = "ReleaseStreamClaim";
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) {
    return sql::RunStatement(conn, kReleaseClaim, device_id, holder);
  });
}

absl::StatusOr<int> Store::ReleaseStreamClaimsOfReplica(std::string_view replica_id) {
  constexpr std::string_view kOp = "ReleaseStreamClaimsOfReplica";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(replica_id, "replica_id")));
  const std::string prefix = std::string(replica_id) + " ";
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<int> {
    IMUCAL_ASSIGN_OR_RETURN(
        std::vector<std::string> devices,
        sql::ReadRows(conn, kReleaseReplicaClaims, sql::FirstColumnText, prefix));
    return static_cast<int>(devices.size());
  });
}

}  // namespace imucal::storage
