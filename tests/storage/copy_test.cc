// Copying a site from SQLite to PostgreSQL (storage/copy.h), on real files and a real
// PostgreSQL (tests/pg_test_cluster.h):
//   - every row of every table arrives, value for value and bit for bit (read back from both
//     databases with plain SELECTs), and the site reads the same through Store and TokenStore
//     on PostgreSQL; new rows continue after the copied ids and version numbers;
//   - the copy is one snapshot: a writer adding devices (each with its audit row, in one
//     transaction) while it runs leaves devices and audit rows that agree;
//   - refusals change nothing: a destination that holds rows, a missing or older source, a
//     URL that is not PostgreSQL's, one that cannot be reached (its password never shown), a
//     value SQLite stored under the wrong type; and a table that reads back different rolls
//     everything back, naming the table.
#include "storage/copy.h"

#include <atomic>
#include <condition_variable>
#include <cstdio>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/migrations.h"
#include "storage/pg_db.h"
#include "storage/store.h"
#include "storage/tokens.h"
#include "tests/pg_test_cluster.h"
#include "tests/storage/site_fixture.h"
#include "tests/storage/test_util.h"
#include "util/sqlite_db.h"
#include "util/str_util.h"

namespace imucal::storage {
namespace {

using ::testing::AllOf;
using ::testing::ElementsAreArray;
using ::testing::HasSubstr;
using ::testing::Not;

std::string Message(const absl::Status& s) { return std::string(s.message()); }

AuditEntry Action(std::string action) {
  AuditEntry e;
  e.actor = "tech:carol";
  e.action = std::move(action);
  return e;
}

class CopyTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto db = testing_util::PgTestDatabase::Create();
    ASSERT_TRUE(db.ok()) << db.status();
    pg_ = *std::move(db);
    sqlite_path_ = TempDbPath("site");
  }

  std::unique_ptr<sql::Connection> OpenSqlite() {
    auto conn = sql::SqliteConnection::Open(sqlite_path_, {.read_only = true});
    EXPECT_TRUE(conn.ok()) << conn.status();
    return conn.ok() ? std::unique_ptr<sql::Connection>(*std::move(conn)) : nullptr;
  }
  std::unique_ptr<sql::Connection> OpenPg() {
    auto conn = PgConnection::Open(pg_->url(), {});
    EXPECT_TRUE(conn.ok()) << conn.status();
    return conn.ok() ? std::unique_ptr<sql::Connection>(*std::move(conn)) : nullptr;
  }
  std::map<std::string, TableDump> Dump(sql::Connection& conn) {
    absl::StatusOr<std::map<std::string, TableDump>> dump = DumpTables(conn);
    EXPECT_TRUE(dump.ok()) << dump.status();
    return dump.ok() ? *dump : std::map<std::string, TableDump>{};
  }
  // Rows in every table of the destination (0 too when it has no tables yet).
  int64_t DestinationRows() {
    std::unique_ptr<sql::Connection> pg = OpenPg();
    if (SchemaVersion(*pg).value_or(0) == 0) return 0;
    int64_t rows = 0;
    for (const auto& [table, dump] : Dump(*pg)) rows += static_cast<int64_t>(dump.size());
    return rows;
  }

  std::unique_ptr<testing_util::PgTestDatabase> pg_;
  std::string sqlite_path_;
};

// The test's own table list covers the schema on both backends, so the comparisons below
// miss no column (and neither does the copy's list, which it checks at run time too).
TEST_F(CopyTest, TheTablesCoverTheSchemaOnBothBackends) {
  ASSERT_OK(Store::Open(sqlite_path_).status());
  ASSERT_OK(Store::Open(pg_->url()).status());
  std::unique_ptr<sql::Connection> lite = OpenSqlite();
  std::unique_ptr<sql::Connection> pg = OpenPg();
  ASSERT_EQ(DumpSpecs().size(), CopyTables().size());
  for (size_t i = 0; i < DumpSpecs().size(); ++i) {
    const DumpTableSpec& spec = DumpSpecs()[i];
    EXPECT_EQ(std::string(spec.name), CopyTables()[i].name);
    std::set<std::string> columns;
    for (const auto& [name, type] : spec.columns) columns.insert(name);
    EXPECT_EQ(SchemaColumns(*pg, spec.name).value(), columns) << spec.name;
    columns.erase("rowid");  // SQLite's implicit one
    EXPECT_EQ(SchemaColumns(*lite, spec.name).value(), columns) << spec.name;
  }
}

TEST_F(CopyTest, EveryRowArrivesBitForBitAndTheSiteReadsTheSame) {
  ASSERT_OK_AND_ASSIGN(Site site, PopulateSite(sqlite_path_));
  std::vector<std::string> phases;
  ASSERT_OK_AND_ASSIGN(CopyReport report,
                       CopySqliteToPostgres(sqlite_path_, pg_->url(), [&](const CopyProgress& p) {
                         phases.push_back(Cat(p.phase, " ", p.table));
                         EXPECT_LE(p.rows_done, p.rows_total) << p.table;
                       }));
  EXPECT_EQ(report.schema_version, LatestSchemaVersion());
  EXPECT_THAT(phases, AllOf(::testing::Contains("copy sample_batches"),
                            ::testing::Contains("verify tokens")));

  // Plain SELECTs on both sides: the same rows, value for value, bit for bit.
  std::unique_ptr<sql::Connection> lite = OpenSqlite();
  std::unique_ptr<sql::Connection> pg = OpenPg();
  const std::map<std::string, TableDump> source = Dump(*lite);
  const std::map<std::string, TableDump> dest = Dump(*pg);
  ASSERT_EQ(source.size(), CopyTables().size());
  for (const TableCopyReport& t : report.tables) {
    SCOPED_TRACE(t.table);
    ASSERT_TRUE(source.contains(t.table));
    EXPECT_GT(source.at(t.table).size(), 0u) << "the site has rows of every kind";
    EXPECT_EQ(static_cast<int64_t>(source.at(t.table).size()), t.rows);
    EXPECT_THAT(dest.at(t.table), ElementsAreArray(source.at(t.table)));
    EXPECT_EQ(t.sha256_hex.size(), 64u);
  }
  // Counted by hand: 3 devices, 6 sessions of 4 batches, 3 poses and 1 pair each; 3 solves.
  EXPECT_EQ(report.tables[0].rows, 3);
  EXPECT_EQ(report.tables[1].rows, 6);
  EXPECT_EQ(report.tables[2].rows, 24);
  EXPECT_EQ(report.tables[3].rows, 18);
  EXPECT_EQ(report.tables[4].rows, 6);
  EXPECT_EQ(report.tables[5].rows, 3);
  EXPECT_EQ(report.tables[6].rows, 7);
  EXPECT_EQ(report.tables[8].rows, 4);
  EXPECT_GT(report.bytes(), 24 * 40 * 56);

  // Through the store, on each backend: the same answers.
  ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> a, Store::Open(sqlite_path_));
  ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> b, Store::Open(pg_->url()));
  for (const std::string& device : site.devices) {
    SCOPED_TRACE(device);
    absl::StatusOr<ParamVersion> active_a = a->GetActive(device);
    absl::StatusOr<ParamVersion> active_b = b->GetActive(device);
    ASSERT_EQ(active_a.ok(), active_b.ok()) << active_a.status() << active_b.status();
    if (active_a.ok()) {
      EXPECT_EQ(active_b->version, active_a->version);
      EXPECT_EQ(active_b->params_json, active_a->params_json);
      EXPECT_EQ(active_b->created_at, active_a->created_at);
    }
    ASSERT_OK_AND_ASSIGN(auto versions_a, a->ListVersions(device, {.with_documents = true}));
    ASSERT_OK_AND_ASSIGN(auto versions_b, b->ListVersions(device, {.with_documents = true}));
    ASSERT_EQ(versions_b.size(), versions_a.size());
    for (size_t i = 0; i < versions_a.size(); ++i) {
      EXPECT_EQ(versions_b[i].state, versions_a[i].state);
      EXPECT_EQ(versions_b[i].report_json, versions_a[i].report_json);
      EXPECT_EQ(std::isnan(versions_b[i].accel_rms), std::isnan(versions_a[i].accel_rms));
    }
  }
  EXPECT_EQ(b->GetActive("robot-1").value().version, 1) << "rolled back to v1 before the copy";
  EXPECT_EQ(b->GetActive("robot-2").status().code(), absl::StatusCode::kNotFound);
  ASSERT_OK_AND_ASSIGN(std::vector<Session> sessions_b, b->ListSessions());
  std::vector<std::string> order;
  for (const Session& s : sessions_b) order.push_back(s.id);
  EXPECT_EQ(order, site.sessions) << "listed in creation order, as on SQLite";
  for (const std::string& session : site.sessions) {
    SCOPED_TRACE(session);
    ASSERT_OK_AND_ASSIGN(std::vector<SampleBatch> batches_a, a->ReadBatches(session));
    ASSERT_OK_AND_ASSIGN(std::vector<SampleBatch> batches_b, b->ReadBatches(session));
    ASSERT_EQ(batches_b.size(), batches_a.size());
    for (size_t i = 0; i < batches_a.size(); ++i)
      EXPECT_EQ(batches_b[i].payload, batches_a[i].payload) << "batch " << batches_a[i].seq;
    ASSERT_OK_AND_ASSIGN(Session sa, a->GetSession(session));
    ASSERT_OK_AND_ASSIGN(Session sb, b->GetSession(session));
    EXPECT_EQ(sb.state, sa.state);
    EXPECT_EQ(sb.samples, sa.samples);
    EXPECT_EQ(sb.source, sa.source);
    EXPECT_EQ(b->ListPairs(session).value().size(), 1u);
  }
  ASSERT_OK_AND_ASSIGN(std::vector<Solve> running, b->ListRunningSolves());
  ASSERT_EQ(running.size(), 1u);
  EXPECT_EQ(running[0].owner, "host-b/10.0.0.2:50051");
  EXPECT_EQ(running[0].lease_until, absl::FromUnixMicros(1800000000000000));
  EXPECT_EQ(running[0].seed, 0xFEDCBA9876543210ull);
  EXPECT_EQ(running[0].attempts, 2);
  ASSERT_OK_AND_ASSIGN(std::vector<AuditEntry> audit_a, a->ListAudit());
  ASSERT_OK_AND_ASSIGN(std::vector<AuditEntry> audit_b, b->ListAudit());
  ASSERT_EQ(audit_b.size(), audit_a.size());
  for (size_t i = 0; i < audit_a.size(); ++i) {
    EXPECT_EQ(audit_b[i].id, audit_a[i].id);
    EXPECT_EQ(audit_b[i].time, audit_a[i].time);
    EXPECT_EQ(Cat(audit_b[i].actor, "|", audit_b[i].action, "|", audit_b[i].target, "|",
                  audit_b[i].detail),
              Cat(audit_a[i].actor, "|", audit_a[i].action, "|", audit_a[i].target, "|",
                  audit_a[i].detail));
  }
  ASSERT_OK_AND_ASSIGN(std::unique_ptr<TokenStore> tokens, TokenStore::Open(pg_->url()));
  for (const std::string& secret : site.token_secrets) {
    ASSERT_OK_AND_ASSIGN(Token t, tokens->Lookup(HashTokenSecret(secret)));
    EXPECT_EQ(t.revoked(), t.id == site.revoked_token_id) << t.id;
  }

  // New rows continue after the copied ones: version numbers, audit, token and solve ids, and
  // the sessions' creation order.
  const int64_t max_audit = audit_a.back().id;
  ASSERT_OK_AND_ASSIGN(ParamVersion v6, b->AddVersion(MakeVersion("robot-1"), "server"));
  EXPECT_EQ(v6.version, 6);
  ASSERT_OK_AND_ASSIGN(AuditEntry after, b->AppendAudit(Action("after.copy")));
  EXPECT_GT(after.id, max_audit);
  ASSERT_OK_AND_ASSIGN(std::vector<Token> all_tokens, tokens->List());
  ASSERT_OK_AND_ASSIGN(NewToken token, tokens->Create(Role::kTechnician, "", "new", "admin"));
  EXPECT_GT(token.token.id, all_tokens.back().id);
  ASSERT_OK(b->CreateSession(MakeSession("robot-2", "S-new"), "tech").status());
  EXPECT_EQ(b->ListSessions().value().back().id, "S-new");
  ASSERT_OK_AND_ASSIGN(Solve solve, b->StartSolve("S-new", "server"));
  EXPECT_EQ(solve.id, 4);
}

// Tables of many pages, with page boundaries inside and between sessions (compound keys), and
// batches from 1 to 20,000 samples (1.3 MB, the server's largest), so that the pages shrink
// and grow with the rows' size.
TEST_F(CopyTest, TablesOfManyPagesArriveWhole) {
  {
    ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> store,
                         Store::Open(sqlite_path_, {.durability = Durability::kNormal}));
    const int sizes[] = {1, 20000, 7, 300, 2000};
    for (int s = 0; s < 3; ++s) {
      const std::string device = Cat("robot-", s);
      const std::string session = Cat("S", s);
      ASSERT_OK(store->CreateDevice(MakeDevice(device), "admin").status());
      ASSERT_OK(store->CreateSession(MakeSession(device, session), "tech").status());
      for (int64_t seq = 1; seq <= 40; ++seq)
        ASSERT_OK(
            store->AppendBatch(session, seq, SitePayload(seq, sizes[seq % 5], true)).status());
      std::vector<Pose> poses(100);
      for (int i = 0; i < 100; ++i) {
        poses[i].session_id = session;
        poses[i].index = i;
        poses[i].t_start_s = i;
        poses[i].t_end_s = i + 0.5;
      }
      ASSERT_OK(store->SavePoses(session, poses));
    }
  }
  ASSERT_OK_AND_ASSIGN(CopyReport report, CopySqliteToPostgres(sqlite_path_, pg_->url()));
  EXPECT_EQ(report.tables[2].rows, 120);
  EXPECT_EQ(report.tables[3].rows, 300);
  EXPECT_GT(report.tables[2].bytes, 3 * 8 * 20000 * 64);
  const std::map<std::string, TableDump> source = Dump(*OpenSqlite());
  const std::map<std::string, TableDump> dest = Dump(*OpenPg());
  EXPECT_TRUE(dest.at("sample_batches") == source.at("sample_batches"));
  EXPECT_TRUE(dest.at("poses") == source.at("poses"));
}

// A writer keeps adding devices while the copy runs; each device and its audit row are one
// transaction. The copy reads devices first and audit_log later: from one snapshot, the two
// agree; read as they were at each table's turn, audit_log would hold rows for devices the
// copy did not see.
TEST_F(CopyTest, TheCopyIsOneSnapshotWhileAWriterWrites) {
  ASSERT_OK(PopulateSite(sqlite_path_).status());
  ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> live, Store::Open(sqlite_path_));
  std::mutex mu;
  std::condition_variable cv;
  int committed = 0;
  absl::Status writer_error;
  std::atomic<bool> stop{false};
  std::thread writer([&] {
    for (int i = 0; !stop; ++i) {
      char id[32];
      std::snprintf(id, sizeof id, "robot-w-%06d", i);
      absl::Status s = live->CreateDevice(MakeDevice(id), "admin").status();
      std::lock_guard lock(mu);
      if (!s.ok()) writer_error = s;
      if (s.ok()) ++committed;
      cv.notify_all();
      if (!s.ok()) return;
    }
  });
  bool waited = false;
  absl::StatusOr<CopyReport> report =
      CopySqliteToPostgres(sqlite_path_, pg_->url(), [&](const CopyProgress& p) {
        if (waited || p.table != "devices") return;
        waited = true;  // after the first page of devices: 20 more commits before going on
        std::unique_lock lock(mu);
        const int target = committed + 20;
        cv.wait(lock, [&] { return committed >= target || !writer_error.ok(); });
      });
  stop = true;
  writer.join();
  ASSERT_OK(writer_error);
  ASSERT_OK(report.status());
  std::unique_ptr<sql::Connection> pg = OpenPg();
  const int64_t devices =
      sql::ReadRow(*pg, "SELECT count(*) FROM devices WHERE id LIKE 'robot-w-%'",
                   sql::FirstColumnInt64)
          .value()
          .value();
  const int64_t audited =
      sql::ReadRow(*pg,
                   "SELECT count(*) FROM audit_log WHERE action = 'device.create' "
                   "AND target LIKE 'device:robot-w-%'",
                   sql::FirstColumnInt64)
          .value()
          .value();
  EXPECT_EQ(audited, devices);
  EXPECT_LE(devices + 20, committed) << "the writes during the copy are not in it";
}

TEST_F(CopyTest, ADestinationThatHoldsRowsIsRefusedAndLeftAsItWas) {
  ASSERT_OK(PopulateSite(sqlite_path_).status());
  ASSERT_OK(CopySqliteToPostgres(sqlite_path_, pg_->url()).status());
  std::unique_ptr<sql::Connection> pg = OpenPg();
  const std::map<std::string, TableDump> before = Dump(*pg);
  absl::Status again = CopySqliteToPostgres(sqlite_path_, pg_->url()).status();
  EXPECT_EQ(again.code(), absl::StatusCode::kFailedPrecondition) << again;
  EXPECT_THAT(Message(again), AllOf(HasSubstr("already holds data"), HasSubstr("devices (3 rows)"),
                                    HasSubstr("tokens (4 rows)"), HasSubstr("never merges")));
  EXPECT_EQ(Dump(*pg), before);

  // A server started on a new database makes its first admin token: that is data too.
  auto fresh = testing_util::PgTestDatabase::Create();
  ASSERT_OK(fresh.status());
  ASSERT_OK_AND_ASSIGN(auto tokens, TokenStore::Open((*fresh)->url()));
  ASSERT_OK(tokens->CreateFirstAdmin("first", "imucald").status());
  absl::Status one = CopySqliteToPostgres(sqlite_path_, (*fresh)->url()).status();
  EXPECT_EQ(one.code(), absl::StatusCode::kFailedPrecondition) << one;
  EXPECT_THAT(Message(one), AllOf(HasSubstr("tokens (1 row)"), HasSubstr("audit_log (1 row)"),
                                  Not(HasSubstr("devices"))));
}

TEST_F(CopyTest, AMissingOrOlderSourceIsRefusedBeforeTheDestinationChanges) {
  absl::Status missing = CopySqliteToPostgres(sqlite_path_, pg_->url()).status();
  EXPECT_EQ(missing.code(), absl::StatusCode::kNotFound) << missing;
  EXPECT_THAT(Message(missing), HasSubstr(sqlite_path_));
  EXPECT_EQ(SchemaVersion(*OpenPg()).value(), 0) << "not even migrated";

  {  // A file of schema version 4 (before solve leases).
    auto conn = sql::SqliteConnection::Open(sqlite_path_, {});
    ASSERT_OK(conn.status());
    ASSERT_OK(Migrate(**conn, Migrations().first(4)));
  }
  absl::Status older = CopySqliteToPostgres(sqlite_path_, pg_->url()).status();
  EXPECT_EQ(older.code(), absl::StatusCode::kFailedPrecondition) << older;
  EXPECT_THAT(Message(older), AllOf(HasSubstr("schema version 4"),
                                    HasSubstr("start this imucald on the file once")));
  EXPECT_EQ(SchemaVersion(*OpenPg()).value(), 0);
  EXPECT_EQ(SchemaVersion(*OpenSqlite()).value(), 4) << "the source is never changed";
}

TEST_F(CopyTest, URLsThatAreNotAReachablePostgresAreRefusedWithoutTheirPassword) {
  ASSERT_OK(PopulateSite(sqlite_path_).status());
  absl::Status not_pg = CopySqliteToPostgres(sqlite_path_, "/tmp/other.db").status();
  EXPECT_EQ(not_pg.code(), absl::StatusCode::kInvalidArgument) << not_pg;
  absl::Status backwards = CopySqliteToPostgres(pg_->url(), pg_->url()).status();
  EXPECT_EQ(backwards.code(), absl::StatusCode::kInvalidArgument) << backwards;
  // Port 1 on loopback: nothing listens.
  absl::Status unreachable =
      CopySqliteToPostgres(sqlite_path_, "postgresql://imucal:s3cret-pw@127.0.0.1:1/imucal")
          .status();
  EXPECT_EQ(unreachable.code(), absl::StatusCode::kUnavailable) << unreachable;
  EXPECT_THAT(Message(unreachable), AllOf(HasSubstr("postgresql://imucal:***@127.0.0.1:1/imucal"),
                                          Not(HasSubstr("s3cret-pw"))));
}

// A trigger on the destination changes one column of one row on its way in: the verification
// finds it, names the table, and nothing is committed.
TEST_F(CopyTest, ATableThatReadsBackDifferentRollsEverythingBack) {
  ASSERT_OK(PopulateSite(sqlite_path_).status());
  ASSERT_OK(Store::Open(pg_->url()).status());  // the schema, empty
  ASSERT_OK(OpenPg()->Exec(
      "CREATE FUNCTION tamper() RETURNS trigger AS $$ BEGIN "
      "IF NEW.pose_index = 2 AND NEW.session_id = 'S-mid' THEN NEW.reason := 'moved'; END IF; "
      "RETURN NEW; END $$ LANGUAGE plpgsql; "
      "CREATE TRIGGER tamper BEFORE INSERT ON poses FOR EACH ROW EXECUTE FUNCTION tamper()"));
  absl::Status s = CopySqliteToPostgres(sqlite_path_, pg_->url()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_THAT(Message(s), AllOf(HasSubstr("verify poses"), HasSubstr("18 rows in the snapshot"),
                                HasSubstr("nothing was committed")));
  EXPECT_EQ(DestinationRows(), 0);
}

// SQLite stores any value in any column; one of the wrong type would be converted on the way.
TEST_F(CopyTest, AValueOfTheWrongTypeInTheSourceIsRefusedNamingIt) {
  ASSERT_OK(PopulateSite(sqlite_path_).status());
  {
    auto conn = sql::SqliteConnection::Open(sqlite_path_, {});
    ASSERT_OK(conn.status());
    ASSERT_OK((*conn)->Exec("UPDATE audit_log SET time_us = 'yesterday' WHERE id = 3"));
  }
  absl::Status s = CopySqliteToPostgres(sqlite_path_, pg_->url()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kFailedPrecondition) << s;
  EXPECT_THAT(Message(s), AllOf(HasSubstr("copy audit_log"), HasSubstr("row (3)"),
                                HasSubstr("column time_us holds text")));
  EXPECT_EQ(DestinationRows(), 0);
}

// A site with no rows at all copies too (and its sequences start at 1).
TEST_F(CopyTest, AnEmptySiteCopies) {
  ASSERT_OK(Store::Open(sqlite_path_).status());
  ASSERT_OK_AND_ASSIGN(CopyReport report, CopySqliteToPostgres(sqlite_path_, pg_->url()));
  EXPECT_EQ(report.rows(), 0);
  ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> b, Store::Open(pg_->url()));
  ASSERT_OK_AND_ASSIGN(AuditEntry first, b->AppendAudit(Action("after.copy")));
  EXPECT_EQ(first.id, 1);
}

}  // namespace
}  // namespace imucal::storage
