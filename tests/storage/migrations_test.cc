#include "storage/migrations.h"

#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/pg_db.h"
#include "storage/store.h"
#include "storage/tokens.h"
#include "tests/pg_test_cluster.h"
#include "tests/storage/test_util.h"
#include "util/sqlite_db.h"

namespace imucal::storage {
namespace {

using ::testing::HasSubstr;

absl::StatusOr<std::unique_ptr<sql::SqliteConnection>> OpenRaw(const std::string& path) {
  return sql::SqliteConnection::Open(path, sql::ConnectionOptions{});
}

// One text value of a one-row query.
absl::StatusOr<std::string> QueryText(sql::Connection& conn, const char* sql) {
  absl::StatusOr<sql::ScopedStatement> st = conn.Prepare(sql);
  if (!st.ok()) return st.status();
  absl::StatusOr<bool> row = (*st)->Step();
  if (!row.ok()) return row.status();
  if (!*row) return absl::NotFoundError("no row");
  return (*st)->ColumnText(0);
}

int CountTables(sql::Connection& conn) {
  auto count = QueryText(conn, "SELECT COUNT(*) FROM sqlite_master WHERE type = 'table'");
  return count.ok() ? std::stoi(*count) : -1;
}

TEST(MigrationsTest, VersionsAreNumberedFromOneAndEachSetsItsOwnVersion) {
  const auto migrations = Migrations();
  ASSERT_FALSE(migrations.empty());
  for (size_t i = 0; i < migrations.size(); ++i) {
    EXPECT_EQ(migrations[i].version, static_cast<int>(i) + 1);
    EXPECT_THAT(migrations[i].sql,
                HasSubstr("PRAGMA user_version = " + std::to_string(i + 1) + ";"));
  }
  EXPECT_EQ(LatestSchemaVersion(), static_cast<int>(migrations.size()));
}

TEST(MigrationsTest, FreshFileMigratesToLatest) {
  const std::string path = TempDbPath("db");
  ASSERT_OK_AND_ASSIGN(auto conn, OpenRaw(path));
  ASSERT_OK_AND_ASSIGN(int before, SchemaVersion(*conn));
  EXPECT_EQ(before, 0);
  ASSERT_OK(Migrate(*conn));
  ASSERT_OK_AND_ASSIGN(int after, SchemaVersion(*conn));
  EXPECT_EQ(after, LatestSchemaVersion());
  EXPECT_EQ(CountTables(*conn), 11);  // devices sessions sample_batches poses solves
                                      // param_versions audit_log pose_pairs tokens
                                      // stream_claims token_changes
}

TEST(MigrationsTest, OpeningTwiceIsIdempotentAndKeepsData) {
  const std::string path = TempDbPath("db");
  {
    ASSERT_OK_AND_ASSIGN(auto store, Store::Open(path));
    Device d;
    d.id = "robot-1";
    ASSERT_OK(store->CreateDevice(d, "test").status());
  }
  for (int i = 0; i < 2; ++i) {
    ASSERT_OK_AND_ASSIGN(auto store, Store::Open(path));
    ASSERT_OK_AND_ASSIGN(std::vector<Device> devices, store->ListDevices());
    ASSERT_EQ(devices.size(), 1u);
    EXPECT_EQ(devices[0].id, "robot-1");
  }
  ASSERT_OK_AND_ASSIGN(auto conn, OpenRaw(path));
  ASSERT_OK(Migrate(*conn));  // again, directly: nothing to do
  ASSERT_OK_AND_ASSIGN(int version, SchemaVersion(*conn));
  EXPECT_EQ(version, LatestSchemaVersion());
}

TEST(MigrationsTest, TwoStoresOpenTheSameFileAtOnce) {
  const std::string path = TempDbPath("db");
  ASSERT_OK_AND_ASSIGN(auto a, Store::Open(path));
  ASSERT_OK_AND_ASSIGN(auto b, Store::Open(path));
  Device d;
  d.id = "robot-1";
  ASSERT_OK(a->CreateDevice(d, "test").status());
  ASSERT_OK(b->GetDevice("robot-1").status());
}

// A version-1 file (as the first release wrote it) upgrades to migration 2's pair table, its rows
// kept, and the store then saves and lists poses and pairs in it.
TEST(MigrationsTest, VersionOneFileUpgradesToPosePairs) {
  const std::string path = TempDbPath("db");
  {
    ASSERT_OK_AND_ASSIGN(auto conn, OpenRaw(path));
    ASSERT_OK(Migrate(*conn, Migrations().first(1)));
    ASSERT_OK_AND_ASSIGN(int version, SchemaVersion(*conn));
    ASSERT_EQ(version, 1);
    ASSERT_OK(
        conn->Exec("INSERT INTO devices (id, sensor_model, nominal_rate_hz, accel_unit, gyro_unit, "
                   "created_at_us) VALUES ('d1', 'm', 200, 'm/s^2', 'rad/s', 0)"));
    ASSERT_OK(conn->Exec(
        "INSERT INTO sessions (id, device_id, state, protocol, gravity_m_s2, created_at_us, "
        "updated_at_us) VALUES ('s1', 'd1', 'open', 'six-face', 9.8, 0, 0)"));
  }
  ASSERT_OK_AND_ASSIGN(auto store, Store::Open(path));
  ASSERT_OK_AND_ASSIGN(Session s, store->GetSession("s1"));
  EXPECT_EQ(s.device_id, "d1");
  Pose a, b;
  a.index = 0, a.t_start_s = 1, a.t_end_s = 3;
  b.index = 1, b.t_start_s = 5, b.t_end_s = 7;
  PosePair pair;
  pair.pose_a = 0, pair.pose_b = 1, pair.face = "Z+", pair.reason = "not turned";
  ASSERT_OK(store->SavePoses("s1", {a, b}, {pair}));
  ASSERT_OK_AND_ASSIGN(std::vector<PosePair> pairs, store->ListPairs("s1"));
  ASSERT_EQ(pairs.size(), 1u);
  EXPECT_EQ(pairs[0].reason, "not turned");
  ASSERT_OK_AND_ASSIGN(auto conn, OpenRaw(path));
  ASSERT_OK_AND_ASSIGN(int version, SchemaVersion(*conn));
  EXPECT_EQ(version, LatestSchemaVersion());
}

// A later migration, as a future schema change would add one.
const int kNext = LatestSchemaVersion() + 1;
const std::string kTestNext =
    "ALTER TABLE devices ADD COLUMN site TEXT NOT NULL DEFAULT "
    "'unknown'; PRAGMA user_version = " +
    std::to_string(kNext) + ";";

TEST(MigrationsTest, UpgradeKeepsExistingRows) {
  const std::string path = TempDbPath("db");
  {
    ASSERT_OK_AND_ASSIGN(auto store, Store::Open(path));
    Device d;
    d.id = "robot-1";
    ASSERT_OK(store->CreateDevice(d, "test").status());
  }
  std::vector<Migration> migrations(Migrations().begin(), Migrations().end());
  migrations.push_back({kNext, kTestNext.c_str()});
  ASSERT_OK_AND_ASSIGN(auto conn, OpenRaw(path));
  ASSERT_OK(Migrate(*conn, migrations));
  ASSERT_OK(Migrate(*conn, migrations));
  ASSERT_OK_AND_ASSIGN(int version, SchemaVersion(*conn));
  EXPECT_EQ(version, kNext);
  ASSERT_OK_AND_ASSIGN(std::string site,
                       QueryText(*conn, "SELECT site FROM devices WHERE id = 'robot-1'"));
  EXPECT_EQ(site, "unknown");
}

TEST(MigrationsTest, AFailedMigrationLeavesTheWholePreviousVersion) {
  const std::string path = TempDbPath("db");
  ASSERT_OK_AND_ASSIGN(auto conn, OpenRaw(path));
  ASSERT_OK(Migrate(*conn));
  const int tables = CountTables(*conn);

  std::vector<Migration> broken(Migrations().begin(), Migrations().end());
  const std::string broken_sql =
      "CREATE TABLE half_done (x INTEGER); SELECT no_such_column FROM devices; "
      "PRAGMA user_version = " +
      std::to_string(kNext) + ";";
  broken.push_back({kNext, broken_sql.c_str()});
  EXPECT_FALSE(Migrate(*conn, broken).ok());
  ASSERT_OK_AND_ASSIGN(int version, SchemaVersion(*conn));
  EXPECT_EQ(version, LatestSchemaVersion());
  EXPECT_EQ(CountTables(*conn), tables);  // half_done rolled back

  std::vector<Migration> forgetful(Migrations().begin(), Migrations().end());
  forgetful.push_back({kNext, "CREATE TABLE half_done (x INTEGER);"});
  absl::Status status = Migrate(*conn, forgetful);
  EXPECT_EQ(status.code(), absl::StatusCode::kInternal) << status;
  EXPECT_THAT(status.message(), HasSubstr("did not set the schema version"));
  EXPECT_EQ(CountTables(*conn), tables);
}

TEST(MigrationsTest, ANewerDatabaseIsRefused) {
  const std::string path = TempDbPath("db");
  {
    ASSERT_OK_AND_ASSIGN(auto conn, OpenRaw(path));
    ASSERT_OK(conn->Exec("PRAGMA user_version = 99"));
  }
  absl::StatusOr<std::unique_ptr<Store>> store = Store::Open(path);
  EXPECT_EQ(store.status().code(), absl::StatusCode::kFailedPrecondition) << store.status();
  EXPECT_THAT(store.status().message(), HasSubstr("schema version 99"));
}

TEST(MigrationsTest, AFileThatIsNotADatabaseIsDataLoss) {
  const std::string path = TempDbPath("db");
  {
    std::ofstream out(path, std::ios::binary);
    out << std::string(8192, 'x');
  }
  absl::StatusOr<std::unique_ptr<Store>> store = Store::Open(path);
  EXPECT_EQ(store.status().code(), absl::StatusCode::kDataLoss) << store.status();
}

TEST(MigrationsTest, AnUnreachableDirectoryIsUnavailable) {
  absl::StatusOr<std::unique_ptr<Store>> store =
      Store::Open(::testing::TempDir() + "no/such/dir/imucal.db");
  EXPECT_EQ(store.status().code(), absl::StatusCode::kUnavailable) << store.status();
}

TEST(MigrationsTest, StoreFileIsWalWithForeignKeysEnforced) {
  const std::string path = TempDbPath("db");
  ASSERT_OK(Store::Open(path).status());
  ASSERT_OK_AND_ASSIGN(auto conn, OpenRaw(path));
  ASSERT_OK_AND_ASSIGN(std::string mode, QueryText(*conn, "PRAGMA journal_mode"));
  EXPECT_EQ(mode, "wal");
  ASSERT_OK_AND_ASSIGN(std::string fk, QueryText(*conn, "PRAGMA foreign_keys"));
  EXPECT_EQ(fk, "1");

  // A session of a device that does not exist: the database itself refuses it.
  absl::Status orphan = conn->Exec(
      "INSERT INTO sessions (id, device_id, state, protocol, gravity_m_s2, created_at_us, "
      "updated_at_us) "
      "VALUES ('s1', 'ghost', 'open', 'six-face', 9.8, 0, 0)");
  EXPECT_EQ(orphan.code(), absl::StatusCode::kFailedPrecondition) << orphan;
  EXPECT_THAT(orphan.message(), HasSubstr("FOREIGN KEY"));

  ASSERT_OK(
      conn->Exec("INSERT INTO devices (id, sensor_model, nominal_rate_hz, accel_unit, gyro_unit, "
                 "created_at_us) VALUES ('d1', 'm', 200, 'g', 'rad/s', 0)"));
  ASSERT_OK(conn->Exec(
      "INSERT INTO sessions (id, device_id, state, protocol, gravity_m_s2, created_at_us, "
      "updated_at_us) "
      "VALUES ('s1', 'd1', 'open', 'six-face', 9.8, 0, 0)"));
  // A second open session of the same device: refused by the partial unique index.
  absl::Status second_open = conn->Exec(
      "INSERT INTO sessions (id, device_id, state, protocol, gravity_m_s2, created_at_us, "
      "updated_at_us) "
      "VALUES ('s2', 'd1', 'open', 'six-face', 9.8, 0, 0)");
  EXPECT_EQ(second_open.code(), absl::StatusCode::kAlreadyExists) << second_open;
  // A version that names another device's session.
  ASSERT_OK(
      conn->Exec("INSERT INTO devices (id, sensor_model, nominal_rate_hz, accel_unit, gyro_unit, "
                 "created_at_us) VALUES ('d2', 'm', 200, 'g', 'rad/s', 0)"));
  absl::Status cross = conn->Exec(
      "INSERT INTO param_versions (device_id, version, created_at_us, session_id, verdict, "
      "state, provenance, params_json, report_json) "
      "VALUES ('d2', 1, 0, 's1', 'pass', 'candidate', '', '{}', '{}')");
  EXPECT_EQ(cross.code(), absl::StatusCode::kFailedPrecondition) << cross;
  // A state the schema does not know.
  absl::Status bad_state = conn->Exec(
      "INSERT INTO param_versions (device_id, version, created_at_us, verdict, state, "
      "provenance, params_json, report_json) "
      "VALUES ('d2', 1, 0, 'pass', 'bogus', '', '{}', '{}')");
  EXPECT_EQ(bad_state.code(), absl::StatusCode::kFailedPrecondition) << bad_state;
}

TEST(MigrationsTest, ActiveVersionLookupUsesThePartialIndex) {
  const std::string path = TempDbPath("db");
  ASSERT_OK(Store::Open(path).status());
  ASSERT_OK_AND_ASSIGN(auto conn, OpenRaw(path));
  // The same statement as store.cc's kSelectActiveVersion.
  ASSERT_OK_AND_ASSIGN(sql::ScopedStatement st,
                       conn->Prepare("EXPLAIN QUERY PLAN "
                                     "SELECT device_id, version, created_at_us, session_id, "
                                     "verdict, accel_rms, state, provenance, params_json FROM "
                                     "param_versions WHERE device_id = ?1 AND state = 'active'"));
  st->BindText(1, "robot-1");
  std::string plan;
  for (;;) {
    ASSERT_OK_AND_ASSIGN(bool row, st->Step());
    if (!row) break;
    plan += st->ColumnText(3) + "\n";
  }
  EXPECT_THAT(plan, HasSubstr("USING INDEX param_versions_active")) << plan;
}

// ---- PostgreSQL: the same versions, on a real server (tests/pg_test_cluster.h) ---------------

// table -> its columns in order, as one text: "devices(id,sensor_model,...) sessions(...)".
std::string Columns(sql::Connection& conn) {
  const char* sql =
      conn.dialect() == sql::Dialect::kPostgres
          ? "SELECT table_name, column_name FROM information_schema.columns WHERE table_schema = "
            "'public' AND table_name <> 'imucal_schema' AND NOT (table_name = 'sessions' AND "
            "column_name = 'rowid') ORDER BY table_name, ordinal_position"
          : "SELECT m.name, p.name FROM sqlite_master m, pragma_table_info(m.name) p WHERE "
            "m.type = 'table' ORDER BY m.name, p.cid";
  auto rows = sql::ReadRows(conn, sql, [](const sql::Statement& st) {
    return std::pair(st.ColumnText(0), st.ColumnText(1));
  });
  if (!rows.ok()) return rows.status().ToString();
  std::string out, table;
  for (const auto& [t, column] : *rows) {
    if (t != table) {
      out += (table.empty() ? "" : ") ") + t + "(";
      table = t;
    } else {
      out += ",";
    }
    out += column;
  }
  return out + ")";
}

TEST(PgMigrationsTest, EveryVersionHasSQLitesTablesAndColumns) {
  const auto pg_list = Migrations(sql::Dialect::kPostgres);
  ASSERT_EQ(pg_list.size(), Migrations().size());
  for (size_t v = 1; v <= pg_list.size(); ++v) {
    EXPECT_EQ(pg_list[v - 1].version, static_cast<int>(v));
    EXPECT_THAT(pg_list[v - 1].sql,
                HasSubstr("UPDATE imucal_schema SET version = " + std::to_string(v) + ";"));
    ASSERT_OK_AND_ASSIGN(auto db, testing_util::PgTestDatabase::Create());
    ASSERT_OK_AND_ASSIGN(auto pg, PgConnection::Open(db->url(), {}));
    ASSERT_OK_AND_ASSIGN(int before, SchemaVersion(*pg));
    EXPECT_EQ(before, 0);
    ASSERT_OK(Migrate(*pg, pg_list.first(v)));
    ASSERT_OK_AND_ASSIGN(int after, SchemaVersion(*pg));
    EXPECT_EQ(after, static_cast<int>(v));

    ASSERT_OK_AND_ASSIGN(auto lite, OpenRaw(TempDbPath("v" + std::to_string(v))));
    ASSERT_OK(Migrate(*lite, Migrations().first(v)));
    EXPECT_EQ(Columns(*pg), Columns(*lite)) << "schema version " << v;
  }
}

// Replicas start together: the migrations run once (under an advisory lock) and both serve.
TEST(PgMigrationsTest, StoresOpeningAFreshDatabaseTogetherMigrateItOnce) {
  ASSERT_OK_AND_ASSIGN(auto db, testing_util::PgTestDatabase::Create());
  std::vector<std::thread> openers;
  std::vector<absl::StatusOr<std::unique_ptr<Store>>> stores(4);
  for (int i = 0; i < 4; ++i)
    openers.emplace_back([&, i] { stores[i] = Store::Open(db->url()); });
  for (auto& t : openers) t.join();
  for (auto& s : stores) ASSERT_OK(s.status());
  ASSERT_OK(stores[0].value()->CreateDevice(MakeDevice("robot-1"), "test").status());
  ASSERT_OK(stores[3].value()->GetDevice("robot-1").status());
  ASSERT_OK_AND_ASSIGN(auto pg, PgConnection::Open(db->url(), {}));
  ASSERT_OK_AND_ASSIGN(int version, SchemaVersion(*pg));
  EXPECT_EQ(version, LatestSchemaVersion());
}

TEST(PgMigrationsTest, ANewerDatabaseIsRefused) {
  ASSERT_OK_AND_ASSIGN(auto db, testing_util::PgTestDatabase::Create());
  ASSERT_OK(Store::Open(db->url()).status());
  {
    ASSERT_OK_AND_ASSIGN(auto pg, PgConnection::Open(db->url(), {}));
    ASSERT_OK(pg->Exec("UPDATE imucal_schema SET version = 99"));
  }
  absl::Status s = Store::Open(db->url()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kFailedPrecondition) << s;
  EXPECT_THAT(s.message(), HasSubstr("upgrade the program"));
}

TEST(PgMigrationsTest, AnUnreachableServerIsUnavailableAndNamesItWithoutThePassword) {
  absl::Status s = Store::Open("postgresql://imucal:secret@127.0.0.1:1/imucal").status();
  EXPECT_EQ(s.code(), absl::StatusCode::kUnavailable) << s;
  EXPECT_THAT(s.message(), HasSubstr("127.0.0.1:1"));
  EXPECT_THAT(std::string(s.message()), ::testing::Not(HasSubstr("secret")));
  // Named once: "cannot connect to URL", not "open URL: cannot connect to URL".
  const std::string message(s.message());
  EXPECT_EQ(message.find("127.0.0.1:1"), message.rfind("127.0.0.1:1")) << message;
  // A password given as a URL parameter is hidden too.
  s = Store::Open("postgresql://imucal@127.0.0.1:1/imucal?password=secret&sslmode=disable")
          .status();
  EXPECT_EQ(s.code(), absl::StatusCode::kUnavailable) << s;
  EXPECT_THAT(std::string(s.message()), ::testing::Not(HasSubstr("secret")));
}

// PostgreSQL restarted (or failed over): every connection of the store is cut, and the store's
// next reads and writes go through on new ones instead of failing once each.
TEST(PgMigrationsTest, AStoreCarriesOnAfterTheServerCutsItsConnections) {
  ASSERT_OK_AND_ASSIGN(auto db, testing_util::PgTestDatabase::Create());
  StoreOptions options;
  options.read_connections = 2;
  ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> store, Store::Open(db->url(), options));
  ASSERT_OK(store->CreateDevice(MakeDevice("robot-1"), "test").status());
  ASSERT_OK(store->GetDevice("robot-1").status());
  ASSERT_OK_AND_ASSIGN(auto admin, PgConnection::Open(db->url(), {}));
  for (int round = 0; round < 2; ++round) {
    // What a restart does to each of them: FATAL 57P01, "terminating connection due to
    // administrator command".
    ASSERT_OK(admin->Exec(
        "SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE datname = "
        "current_database() AND pid <> pg_backend_pid() AND application_name = 'imucald'"));
    for (int i = 0; i < 3; ++i) {  // more reads than connections: each one was cut
      const absl::Status read = store->GetDevice("robot-1").status();
      EXPECT_TRUE(read.ok()) << "read " << i << " of round " << round << ": " << read;
    }
    EXPECT_OK(store->CreateDevice(MakeDevice(absl::StrCat("robot-", round + 2)), "test").status());
  }
  ASSERT_OK_AND_ASSIGN(std::vector<Device> devices, store->ListDevices());
  EXPECT_EQ(devices.size(), 3u);
}

// A mistyped URL is refused, naming what is expected, instead of becoming a SQLite file named
// after it; its password is not shown.
TEST(PgMigrationsTest, AMistypedUrlIsRefusedAndNoFileIsMade) {
  for (const std::string url :
       {"postgresql:imucal:secret@127.0.0.1:5432/imucal", "postgres:/imucal:secret@host/db",
        "mysql://imucal:secret@127.0.0.1/imucal", "PostgreSQL://imucal:secret@host/db"}) {
    absl::Status s = Store::Open(url).status();
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << url << ": " << s;
    EXPECT_THAT(std::string(s.message()), HasSubstr("postgresql://USER[:PASSWORD]@HOST")) << s;
    EXPECT_THAT(std::string(s.message()), ::testing::Not(HasSubstr("secret"))) << s;
    EXPECT_FALSE(std::filesystem::exists(url)) << url;
    EXPECT_FALSE(TokenStore::Open(url).ok()) << url;
  }
  EXPECT_EQ(sql::RedactedLocation("postgresql://u:pw@h/db?password=pw2&x=1"),
            "postgresql://u:***@h/db?password=***&x=1");
  EXPECT_EQ(sql::RedactedLocation("host=h Password=pw dbname=d"), "host=h Password=*** dbname=d");
  EXPECT_EQ(sql::RedactedLocation("/var/lib/imucald/imucal.db"), "/var/lib/imucald/imucal.db");
}

}  // namespace
}  // namespace imucal::storage
