// Store: a session's poses and six-face pair verdicts (store.h "Poses"): PutPoses replaces the
// list as a whole, SavePoses upserts what the online segmentation judged.
#include <cmath>
#include <string>
#include <vector>

#include "storage/status_macros.h"
#include "storage/store.h"
#include "storage/store_internal.h"
#include "util/db.h"
#include "util/str_util.h"

namespace imucal::storage {
namespace {

constexpr char kDeletePoses[] = "DELETE FROM poses WHERE session_id = ?1";
constexpr char kInsertPose[] =
    "INSERT INTO poses (session_id, pose_index, t_start_s, t_end_s, used, reason, detail_json, "
    "face) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)";
constexpr char kUpsertPose[] =
    "INSERT INTO poses (session_id, pose_index, t_start_s, t_end_s, used, reason, detail_json, "
    "face) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8) ON CONFLICT (session_id, pose_index) DO UPDATE "
    "SET t_start_s = excluded.t_start_s, t_end_s = excluded.t_end_s, used = excluded.used, "
    "reason = excluded.reason, detail_json = excluded.detail_json, face = excluded.face";
constexpr char kUpsertPair[] =
    "INSERT INTO pose_pairs (session_id, pose_a, pose_b, ok, face, rotation_deg, tilt_deg, "
    "reason) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8) ON CONFLICT (session_id, pose_a, pose_b) DO "
    "UPDATE SET ok = excluded.ok, face = excluded.face, rotation_deg = excluded.rotation_deg, "
    "tilt_deg = excluded.tilt_deg, reason = excluded.reason";
constexpr char kSelectPairs[] =
    "SELECT pose_a, pose_b, ok, face, rotation_deg, tilt_deg, reason FROM pose_pairs "
    "WHERE session_id = ?1 ORDER BY pose_a, pose_b";
constexpr char kSelectPoses[] =
    "SELECT pose_index, t_start_s, t_end_s, used, reason, detail_json, face FROM poses "
    "WHERE session_id = ?1 ORDER BY pose_index";

// Writes pose `p` of `session_id` with kInsertPose or kUpsertPose (the same parameters).
absl::Status WritePose(sql::Connection& conn, const char* sql, std::string_view session_id,
                       const Pose& p) {
  return sql::RunStatement(conn, sql, session_id, p.index, p.t_start_s, p.t_end_s, p.used, p.reason,
                           p.detail_json, p.face);
}

// Columns as in kSelectPoses, of `session_id`.
Pose ReadPose(const sql::Statement& st, std::string_view session_id) {
  Pose p;
  p.session_id = std::string(session_id);
  p.index = static_cast<int>(st.ColumnInt64(0));
  p.t_start_s = st.ColumnDouble(1);
  p.t_end_s = st.ColumnDouble(2);
  p.used = st.ColumnInt64(3) != 0;
  p.reason = st.ColumnText(4);
  p.detail_json = st.ColumnText(5);
  p.face = st.ColumnText(6);
  return p;
}

// Columns as in kSelectPairs, of `session_id`.
PosePair ReadPair(const sql::Statement& st, std::string_view session_id) {
  PosePair p;
  p.session_id = std::string(session_id);
  p.pose_a = static_cast<int>(st.ColumnInt64(0));
  p.pose_b = static_cast<int>(st.ColumnInt64(1));
  p.ok = st.ColumnInt64(2) != 0;
  p.face = st.ColumnText(3);
  p.rotation_deg = st.ColumnDouble(4);
  p.tilt_deg = st.ColumnDouble(5);
  p.reason = st.ColumnText(6);
  return p;
}

}  // namespace

absl::Status Store::PutPoses(std::string_view session_id, const std::vector<Pose>& poses,
                             std::string_view actor) {
  constexpr std::string_view kOp = "PutPoses";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  int used = 0;
  for (size_t i = 0; i < poses.size(); ++i) {
    const Pose& p = poses[i];
    if (p.index != static_cast<int>(i)) {
      return WithContext(kOp, absl::InvalidArgumentError(
                                  Cat("pose #", i, " has index ", p.index, "; expected ", i)));
    }
    if (!p.session_id.empty() && p.session_id != session_id) {
      return WithContext(kOp, absl::InvalidArgumentError(
                                  Cat("pose ", i, " belongs to session '", p.session_id, "'")));
    }
    if (!std::isfinite(p.t_start_s) || !std::isfinite(p.t_end_s) || p.t_end_s < p.t_start_s) {
      return WithContext(kOp, absl::InvalidArgumentError(Cat("pose ", i, " has bad times [",
                                                             p.t_start_s, ", ", p.t_end_s, "]")));
    }
    used += p.used ? 1 : 0;
  }
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::Status {
    IMUCAL_RETURN_IF_ERROR(CheckSessionExists(conn, session_id));
    IMUCAL_RETURN_IF_ERROR(sql::RunStatement(conn, kDeletePoses, session_id));
    for (const Pose& p : poses) {
      IMUCAL_RETURN_IF_ERROR(WritePose(conn, kInsertPose, session_id, p));
    }
    return InsertAudit(conn, Now(), actor, "session.poses", SessionTarget(session_id),
                       Cat(poses.size(), " poses, ", used, " used"));
  });
}

absl::StatusOr<std::vector<Pose>> Store::ListPoses(std::string_view session_id) {
  ReadLease lease = AcquireReader();
  auto list = [&]() -> absl::StatusOr<std::vector<Pose>> {
    IMUCAL_RETURN_IF_ERROR(CheckSessionExists(lease.conn(), session_id));
    return sql::ReadRows(
        lease.conn(), kSelectPoses,
        [&](const sql::Statement& st) { return ReadPose(st, session_id); }, session_id);
  };
  return Annotate("ListPoses", list());
}

absl::Status Store::SavePoses(std::string_view session_id, const std::vector<Pose>& poses,
                              const std::vector<PosePair>& pairs) {
  constexpr std::string_view kOp = "SavePoses";
  for (const Pose& p : poses) {
    if (p.index < 0 || !std::isfinite(p.t_start_s) || !std::isfinite(p.t_end_s) ||
        p.t_end_s < p.t_start_s) {
      return WithContext(
          kOp, absl::InvalidArgumentError(Cat("pose ", p.index, " has a bad index or times [",
                                              p.t_start_s, ", ", p.t_end_s, "]")));
    }
  }
  for (const PosePair& p : pairs) {
    if (p.pose_a < 0 || p.pose_b <= p.pose_a) {
      return WithContext(kOp,
                         absl::InvalidArgumentError(Cat("pair (", p.pose_a, ", ", p.pose_b,
                                                        ") is not two increasing pose indexes")));
    }
  }
  if (poses.empty() && pairs.empty()) return absl::OkStatus();
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::Status {
    IMUCAL_RETURN_IF_ERROR(CheckSessionExists(conn, session_id));
    for (const Pose& p : poses) {
      IMUCAL_RETURN_IF_ERROR(WritePose(conn, kUpsertPose, session_id, p));
    }
    for (const PosePair& p : pairs) {
      IMUCAL_RETURN_IF_ERROR(sql::RunStatement(conn, kUpsertPair, session_id, p.pose_a, p.pose_b,
                                               p.ok, p.face, p.rotation_deg, p.tilt_deg, p.reason));
    }
    return absl::OkStatus();
  });
}

absl::StatusOr<std::vector<PosePair>> Store::ListPairs(std::string_view session_id) {
  ReadLease lease = AcquireReader();
  auto list = [&]() -> absl::StatusOr<std::vector<PosePair>> {
    IMUCAL_RETURN_IF_ERROR(CheckSessionExists(lease.conn(), session_id));
    return sql::ReadRows(
        lease.conn(), kSelectPairs,
        [&](const sql::Statement& st) { return ReadPair(st, session_id); }, session_id);
  };
  return Annotate("ListPairs", list());
}

}  // namespace imucal::storage
