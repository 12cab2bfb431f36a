// Store: raw sample batches (store.h "Raw samples"): AppendBatch, the group commit of
// AppendBatchAsync (its committer thread), ReadBatches and ReadBatchPage.
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "storage/sample_codec.h"
#include "storage/status_macros.h"
#include "storage/store.h"
#include "storage/store_internal.h"
#include "util/db.h"
#include "util/str_util.h"

namespace imucal::storage {
namespace {

// Appends run at READ COMMITTED on PostgreSQL, and lock the session's row first: the appends to
// one session, and its state changes, then take turns whichever server makes them, and every
// check below reads what the previous turn committed. (SQLite: the write lock does the same.)
constexpr char kSelectSessionStateForAppend[] = "SELECT state FROM sessions WHERE id = ?1";
constexpr char kLockSessionStateForAppend[] =
    "SELECT state FROM sessions WHERE id = ?1 FOR NO KEY UPDATE";
constexpr char kSelectLastBatch[] =
    "SELECT seq, last_t_s, end_sample FROM sample_batches WHERE session_id = ?1 "
    "ORDER BY seq DESC LIMIT 1";
constexpr char kSelectBatchPayload[] =
    "SELECT payload FROM sample_batches WHERE session_id = ?1 AND seq = ?2";
constexpr char kInsertBatch[] =
    "INSERT INTO sample_batches (session_id, seq, first_t_s, last_t_s, count, end_sample, "
    "payload) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)";
// PostgreSQL: the same, announcing the session to the other servers (AnnounceSession) in the
// same round trip; every batch is one, and ingest is bound by round trips there.
constexpr char kInsertBatchAnnounced[] =
    "INSERT INTO sample_batches (session_id, seq, first_t_s, last_t_s, count, end_sample, "
    "payload) SELECT ?1, ?2, ?3, ?4, ?5, ?6, ?7 FROM (SELECT pg_notify('imucal_session', "
    "current_setting('imucal.origin', true) || ' ' || ?1)) AS announced";
constexpr char kSelectBatches[] =
    "SELECT seq, first_t_s, last_t_s, count, payload FROM sample_batches "
    "WHERE session_id = ?1 AND seq > ?2 ORDER BY seq";
// A page: seqs are gapless (AppendOne), so `seq <= ?2 + ?3` bounds the rows SQLite visits to the
// page's own; past the first batch, only those that end within ?4 samples of the page's start
// (the end_sample of batch ?2, 0 before the first).
constexpr char kSelectBatchPage[] =
    "SELECT seq, first_t_s, last_t_s, count, payload FROM sample_batches "
    "WHERE session_id = ?1 AND seq > ?2 AND seq <= ?2 + ?3 AND (seq = ?2 + 1 OR end_sample <= ?4 + "
    "COALESCE((SELECT end_sample FROM sample_batches WHERE session_id = ?1 AND seq = ?2), 0)) "
    "ORDER BY seq";

struct LastBatch {
  int64_t seq = 0;  // 0: no batch yet
  double last_t_s = 0.0;
  int64_t end_sample = 0;
};

// Columns as in kSelectLastBatch.
LastBatch ReadLastBatch(const sql::Statement& st) {
  return LastBatch{st.ColumnInt64(0), st.ColumnDouble(1), st.ColumnInt64(2)};
}

absl::StatusOr<LastBatch> FindLastBatch(sql::Connection& conn, std::string_view session_id) {
  IMUCAL_ASSIGN_OR_RETURN(std::optional<LastBatch> last,
                          sql::ReadRow(conn, kSelectLastBatch, ReadLastBatch, session_id));
  return last.value_or(LastBatch{});
}

// Columns as in kSelectSessionStateForAppend.
absl::StatusOr<SessionState> ReadSessionState(const sql::Statement& st) {
  return FromColumn(ParseSessionState(st.ColumnText(0)));
}

// Columns as in kSelectBatches, of `session_id`. The payload is verified on the way out too: a
// damaged file must not feed a solve silently.
absl::StatusOr<SampleBatch> ReadBatch(const sql::Statement& st, std::string_view session_id) {
  SampleBatch b;
  b.session_id = std::string(session_id);
  b.seq = st.ColumnInt64(0);
  b.first_t_s = st.ColumnDouble(1);
  b.last_t_s = st.ColumnDouble(2);
  b.count = st.ColumnInt64(3);
  b.payload = st.ColumnBlob(4);
  absl::StatusOr<EncodedBatchInfo> info = InspectSamples(b.payload);
  if (!info.ok()) {
    return absl::DataLossError(
        Cat("session '", session_id, "' batch ", b.seq, ": ", info.status().message()));
  }
  if (info->count != b.count || info->first_t_s != b.first_t_s || info->last_t_s != b.last_t_s) {
    return absl::DataLossError(
        Cat("session '", session_id, "' batch ", b.seq, ": payload disagrees with its row"));
  }
  return b;
}

// AppendBatch's checks and insert inside the caller's transaction (see store.h).
absl::StatusOr<BatchAck> AppendOne(sql::Connection& conn, std::string_view session_id, int64_t seq,
                                   std::string_view payload, const EncodedBatchInfo& info) {
  IMUCAL_ASSIGN_OR_RETURN(
      std::optional<SessionState> state,
      sql::ReadRow(conn,
                   conn.dialect() == sql::Dialect::kPostgres ? kLockSessionStateForAppend
                                                             : kSelectSessionStateForAppend,
                   ReadSessionState, session_id));
  if (!state) return absl::NotFoundError(Cat("no session '", session_id, "'"));
  IMUCAL_ASSIGN_OR_RETURN(const LastBatch last, FindLastBatch(conn, session_id));
  if (seq <= last.seq) {
    // A retransmission of an acknowledged batch is a no-op, if it is the same batch.
    IMUCAL_ASSIGN_OR_RETURN(std::optional<bool> same, sql::ReadRow(
                                                          conn, kSelectBatchPayload,
                                                          [&](const sql::Statement& st) {
                                                            return st.ColumnBlobView(0) == payload;
                                                          },
                                                          session_id, seq));
    if (same.value_or(false)) return BatchAck{last.seq, last.end_sample};
    return absl::InvalidArgumentError(Cat("session '", session_id, "': batch ", seq,
                                          " was already stored with different content"));
  }
  if (seq != last.seq + 1) {
    return absl::FailedPreconditionError(Cat("session '", session_id, "': batch ", seq,
                                             " is out of order; expected ", last.seq + 1,
                                             " (last acknowledged ", last.seq, ")"));
  }
  if (*state != SessionState::kOpen) {
    return absl::FailedPreconditionError(
        Cat("session '", session_id, "' is ", SessionStateName(*state), ", not open"));
  }
  if (last.seq > 0 && !(info.first_t_s > last.last_t_s)) {
    return absl::InvalidArgumentError(
        Cat("session '", session_id, "': batch ", seq, " starts at t_s ", info.first_t_s,
            ", not after the last sample of batch ", last.seq, " (t_s ", last.last_t_s, ")"));
  }
  const BatchAck ack{seq, last.end_sample + info.count};
  IMUCAL_RETURN_IF_ERROR(sql::RunStatement(
      conn, conn.dialect() == sql::Dialect::kPostgres ? kInsertBatchAnnounced : kInsertBatch,
      session_id, seq, info.first_t_s, info.last_t_s, info.count, ack.samples,
      sql::SqlBlob{payload}));
  return ack;
}

// Checks a batch before any lock: decoding is the costly part and needs no database.
absl::StatusOr<EncodedBatchInfo> CheckBatch(int64_t seq, std::string_view payload) {
  constexpr std::string_view kOp = "AppendBatch";
  if (seq < 1) {
    return WithContext(kOp, absl::InvalidArgumentError(Cat(
                                "batch seq ", seq, " is invalid; batches are numbered from 1")));
  }
  absl::StatusOr<EncodedBatchInfo> info = InspectSamples(payload);
  if (!info.ok()) {
    return WithContext(
        kOp, absl::InvalidArgumentError(Cat("batch ", seq, ": ", info.status().message())));
  }
  if (info->count == 0) {
    return WithContext(kOp, absl::InvalidArgumentError(Cat("batch ", seq, " has no samples")));
  }
  return info;
}

}  // namespace

absl::StatusOr<BatchAck> Store::AppendBatch(std::string_view session_id, int64_t seq,
                                            std::string_view payload) {
  absl::StatusOr<EncodedBatchInfo> info = CheckBatch(seq, payload);
  if (!info.ok()) return info.status();
  std::lock_guard lock(write_mu_);
  return InTransaction(
      "AppendBatch", *writer_,
      [&](sql::Connection& conn) { return AppendOne(conn, session_id, seq, payload, *info); },
      sql::Isolation::kReadCommitted);
}

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
      absl::Status status = InTransaction(
          "AppendBatch", *writer_,
          [&](sql::Connection& conn) {
            results.clear();  // a conflict runs the whole group again
            for (const PendingAppend& p : group) {
              absl::StatusOr<BatchAck> r = AppendOne(conn, p.session_id, p.seq, p.payload, p.info);
              // A database error (not a batch's own) ends the transaction (PostgreSQL will not run
              // another statement in it): the whole group fails, or runs again if it conflicted.
              if (absl::Status doomed = conn.CommitBlocker(); !doomed.ok()) return doomed;
              results.push_back(r.ok() ? r : WithContext("AppendBatch", r.status()));
            }
            return absl::OkStatus();  // a batch's own error fails that batch only
          },
          sql::Isolation::kReadCommitted);
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

absl::StatusOr<std::vector<SampleBatch>> Store::ReadBatches(std::string_view session_id,
                                                            int64_t after_seq) {
  ReadLease lease = AcquireReader();
  auto read = [&]() -> absl::StatusOr<std::vector<SampleBatch>> {
    IMUCAL_RETURN_IF_ERROR(CheckSessionExists(lease.conn(), session_id));
    return sql::ReadRows(
        lease.conn(), kSelectBatches,
        [&](const sql::Statement& st) { return ReadBatch(st, session_id); }, session_id, after_seq);
  };
  return Annotate("ReadBatches", read());
}

absl::StatusOr<std::vector<SampleBatch>> Store::ReadBatchPage(std::string_view session_id,
                                                              int64_t after_seq,
                                                              int64_t max_batches,
                                                              int64_t max_samples) {
  if (after_seq < 0 || max_batches < 1 || max_samples < 1) {
    return absl::InvalidArgumentError(Cat("ReadBatchPage: after_seq ", after_seq, ", max_batches ",
                                          max_batches, ", max_samples ", max_samples,
                                          " (want >= 0, >= 1, >= 1)"));
  }
  ReadLease lease = AcquireReader();
  auto read = [&]() -> absl::StatusOr<std::vector<SampleBatch>> {
    IMUCAL_RETURN_IF_ERROR(CheckSessionExists(lease.conn(), session_id));
    return sql::ReadRows(
        lease.conn(), kSelectBatchPage,
        [&](const sql::Statement& st) { return ReadBatch(st, session_id); }, session_id, after_seq,
        max_batches, max_samples);
  };
  return Annotate("ReadBatchPage", read());
}

}  // namespace imucal::storage
