// Online backup and restore (storage/backup.h) on real SQLite files: a backup taken while
// another connection keeps writing is a consistent snapshot that restores to equal data; a
// restore refuses a live database and files that are not good imucal backups.
#include "storage/backup.h"

#include <sqlite3.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/migrations.h"
#include "storage/store.h"
#include "tests/storage/test_util.h"

namespace imucal::storage {
namespace {

using ::testing::HasSubstr;

constexpr char kActor[] = "backup-test";

// absl::string_view (not std::) on this Debian: matchers want a std::string.
std::string Message(const absl::Status& s) { return std::string(s.message()); }

std::string WriterId(int i) {
  char id[32];
  std::snprintf(id, sizeof id, "robot-w-%06d", i);  // zero-padded: id order is creation order
  return id;
}

absl::StatusOr<std::unique_ptr<Store>> OpenStore(const std::string& path) {
  StoreOptions options;
  options.durability = Durability::kNormal;  // no fsync per commit: the writer runs fast
  return Store::Open(path, options);
}

std::vector<std::string> DeviceIds(Store& store) {
  absl::StatusOr<std::vector<Device>> devices = store.ListDevices();
  EXPECT_TRUE(devices.ok()) << devices.status();
  std::vector<std::string> ids;
  if (devices.ok()) {
    for (const Device& d : *devices) ids.push_back(d.id);
  }
  return ids;
}

// Runs raw SQL on a new file (for foreign and future databases).
void MakeSqliteFile(const std::string& path, const char* sql) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  char* error = nullptr;
  const int rc = sqlite3_exec(db, sql, nullptr, nullptr, &error);
  const std::string message = error ? error : "";
  sqlite3_free(error);
  sqlite3_close(db);
  ASSERT_EQ(rc, SQLITE_OK) << message;
}

// A writer on its own Store (its own connections) creating devices robot-w-000000, -000001, ...
// in order, one transaction each, until stopped. Waiters block until it has committed n.
class Writer {
 public:
  explicit Writer(Store* store) : store_(store), thread_([this] { Run(); }) {}
  ~Writer() { Stop(); }

  void Stop() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }
  int committed() {
    std::lock_guard lock(mu_);
    return committed_;
  }
  // Until at least `n` devices are committed (or the writer failed).
  void WaitFor(int n) {
    std::unique_lock lock(mu_);
    cv_.wait(lock, [&] { return committed_ >= n || !error_.ok(); });
  }
  absl::Status error() {
    std::lock_guard lock(mu_);
    return error_;
  }

 private:
  void Run() {
    for (int i = 0; !stop_; ++i) {
      absl::Status s = store_->CreateDevice(MakeDevice(WriterId(i)), kActor).status();
      std::lock_guard lock(mu_);
      if (!s.ok()) {
        error_ = s;
        cv_.notify_all();
        return;
      }
      committed_ = i + 1;
      cv_.notify_all();
    }
  }

  Store* store_;
  std::atomic<bool> stop_{false};
  std::mutex mu_;
  std::condition_variable cv_;
  int committed_ = 0;
  absl::Status error_;
  std::thread thread_;  // last: starts after the members it uses
};

TEST(BackupTest, BackupWhileAnotherConnectionWritesIsASnapshotThatRestoresEqual) {
  const std::string db = TempDbPath("live");
  const std::string out = TempDbPath("backup");
  const std::string restored_path = TempDbPath("restored");
  ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> store, OpenStore(db));
  ASSERT_OK(store->CreateDevice(MakeDevice("robot-a"), kActor).status());

  Writer writer(store.get());
  writer.WaitFor(50);  // the writer is well under way before the backup starts
  const int before = writer.committed();
  ASSERT_OK_AND_ASSIGN(DatabaseInfo info, BackupDatabase(db, out));
  const int after = writer.committed();
  writer.WaitFor(after + 20);  // and it went on writing after the backup: the db stayed live
  writer.Stop();
  ASSERT_OK(writer.error());

  EXPECT_EQ(info.schema_version, LatestSchemaVersion());
  // The backup holds robot-a and a prefix robot-w-0..k-1 of the writer's devices: the state
  // at one instant between the backup's start and end, no torn transaction.
  ASSERT_GE(info.devices, 1 + before);
  ASSERT_LE(info.devices, 1 + after);
  EXPECT_FALSE(std::filesystem::exists(out + "-wal")) << "a backup is one self-contained file";
  EXPECT_FALSE(std::filesystem::exists(out + ".tmp"));

  std::vector<std::string> expected = {"robot-a"};
  for (int i = 0; i + 1 < info.devices; ++i) expected.push_back(WriterId(i));
  std::sort(expected.begin(), expected.end());

  // Restore into a fresh path: the same devices.
  ASSERT_OK_AND_ASSIGN(DatabaseInfo restored_info, RestoreDatabase(out, restored_path));
  EXPECT_EQ(restored_info.devices, info.devices);
  {
    ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> restored, OpenStore(restored_path));
    EXPECT_EQ(DeviceIds(*restored), expected);
  }

  // Restore over the live database once its server stopped: back to the snapshot; the
  // devices written after it are in the kept .pre-restore copy.
  const int total = 1 + writer.committed();
  store.reset();
  ASSERT_OK(RestoreDatabase(out, db).status());
  {
    ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> back, OpenStore(db));
    EXPECT_EQ(DeviceIds(*back), expected);
    ASSERT_OK_AND_ASSIGN(Device a, back->GetDevice("robot-a"));
    EXPECT_EQ(a.sensor_model, "ICM-20948");
  }
  ASSERT_OK_AND_ASSIGN(DatabaseInfo kept, InspectDatabase(db + ".pre-restore", true));
  EXPECT_EQ(kept.devices, total);
}

TEST(BackupTest, RestoreRefusesADatabaseThatIsInUse) {
  const std::string db = TempDbPath("live");
  const std::string out = TempDbPath("backup");
  ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> store, OpenStore(db));
  ASSERT_OK(store->CreateDevice(MakeDevice("robot-a"), kActor).status());
  ASSERT_OK(BackupDatabase(db, out).status());
  ASSERT_OK(store->CreateDevice(MakeDevice("robot-b"), kActor).status());

  absl::StatusOr<DatabaseInfo> refused = RestoreDatabase(out, db);
  ASSERT_EQ(refused.status().code(), absl::StatusCode::kFailedPrecondition) << refused.status();
  EXPECT_THAT(Message(refused.status()), HasSubstr("in use"));
  EXPECT_THAT(Message(refused.status()), HasSubstr(db));
  // The live database is untouched and still writable.
  EXPECT_EQ(DeviceIds(*store), (std::vector<std::string>{"robot-a", "robot-b"}));
  EXPECT_OK(store->CreateDevice(MakeDevice("robot-c"), kActor).status());
}

TEST(BackupTest, RestoreRefusesCorruptAndForeignFilesAndLeavesTheDatabaseAlone) {
  const std::string db = TempDbPath("target");
  {
    ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> store, OpenStore(db));
    ASSERT_OK(store->CreateDevice(MakeDevice("robot-keep"), kActor).status());
  }

  const std::string garbage = TempDbPath("garbage");
  std::ofstream(garbage) << std::string(8192, 'x');
  absl::StatusOr<DatabaseInfo> r = RestoreDatabase(garbage, db);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kDataLoss) << r.status();
  EXPECT_THAT(Message(r.status()), HasSubstr(garbage));
  EXPECT_THAT(Message(r.status()), HasSubstr("not a database"));

  const std::string foreign = TempDbPath("foreign");
  MakeSqliteFile(foreign, "CREATE TABLE recipes (name TEXT); INSERT INTO recipes VALUES ('x');");
  r = RestoreDatabase(foreign, db);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kFailedPrecondition) << r.status();
  EXPECT_THAT(Message(r.status()), HasSubstr("not an imucal database"));

  const std::string lookalike = TempDbPath("lookalike");  // a version but none of the tables
  MakeSqliteFile(lookalike, "CREATE TABLE devices (id TEXT); PRAGMA user_version = 1;");
  r = RestoreDatabase(lookalike, db);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kFailedPrecondition) << r.status();
  EXPECT_THAT(Message(r.status()), HasSubstr("tables"));

  const std::string future = TempDbPath("future");
  MakeSqliteFile(future, "CREATE TABLE devices (id TEXT); PRAGMA user_version = 999;");
  r = RestoreDatabase(future, db);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kFailedPrecondition) << r.status();
  EXPECT_THAT(Message(r.status()), HasSubstr("newer"));

  // A real backup with a page overwritten by garbage: integrity_check (or the first read of
  // the page) catches it.
  const std::string good = TempDbPath("good");
  ASSERT_OK(BackupDatabase(db, good).status());
  const std::string corrupt = TempDbPath("corrupt");
  std::filesystem::copy_file(good, corrupt);
  ASSERT_OK_AND_ASSIGN(DatabaseInfo info, InspectDatabase(good, true));
  ASSERT_GE(info.page_count, 4);
  {
    std::fstream f(corrupt, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(2 * info.page_size_bytes);  // the third page: a table's b-tree, not the header
    const std::string noise(static_cast<size_t>(info.page_size_bytes), '\xA5');
    f.write(noise.data(), static_cast<std::streamsize>(noise.size()));
  }
  r = RestoreDatabase(corrupt, db);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kDataLoss) << r.status();
  EXPECT_THAT(Message(r.status()), HasSubstr("refusing to restore"));

  // Every refusal left the target as it was (and kept no .pre-restore: nothing was replaced).
  EXPECT_FALSE(std::filesystem::exists(db + ".pre-restore"));
  ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> store, OpenStore(db));
  EXPECT_EQ(DeviceIds(*store), std::vector<std::string>{"robot-keep"});
}

TEST(BackupTest, BackupOfAMissingDatabaseIsNotFoundAndCreatesNothing) {
  const std::string missing = TempDbPath("missing");
  const std::string out = TempDbPath("out");
  absl::StatusOr<DatabaseInfo> r = BackupDatabase(missing, out);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kNotFound) << r.status();
  EXPECT_THAT(Message(r.status()), HasSubstr(missing));
  EXPECT_FALSE(std::filesystem::exists(out));
  EXPECT_FALSE(std::filesystem::exists(missing)) << "a backup must not create its source";
}

// SQLite alone would say "unable to open database file"; the error names the missing directory,
// and neither call makes it (a typo in a path must not grow a tree).
TEST(BackupTest, AMissingDirectoryIsNamedAndNotCreated) {
  const std::string db = TempDbPath("source");
  { ASSERT_OK(OpenStore(db).status()); }
  const std::string nowhere = TempDbPath("nowhere") + ".d";
  std::filesystem::remove_all(nowhere);
  const std::string out = nowhere + "/backup.db";
  absl::StatusOr<DatabaseInfo> r = BackupDatabase(db, out);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kNotFound) << r.status();
  EXPECT_THAT(Message(r.status()), HasSubstr("the directory " + nowhere + " does not exist"));
  EXPECT_FALSE(std::filesystem::exists(nowhere));

  const std::string backup = TempDbPath("backup");
  ASSERT_OK(BackupDatabase(db, backup).status());
  r = RestoreDatabase(backup, nowhere + "/imucal.db");
  EXPECT_EQ(r.status().code(), absl::StatusCode::kNotFound) << r.status();
  EXPECT_THAT(Message(r.status()), HasSubstr("the directory " + nowhere + " does not exist"));
  EXPECT_FALSE(std::filesystem::exists(nowhere));
}

TEST(BackupTest, SchemaVersionOfANewPathIsZeroAndOfAStoreIsTheLatest) {
  const std::string db = TempDbPath("versions");
  ASSERT_OK_AND_ASSIGN(int none, SchemaVersionOf(db));
  EXPECT_EQ(none, 0);
  EXPECT_FALSE(std::filesystem::exists(db));
  { ASSERT_OK(OpenStore(db).status()); }
  ASSERT_OK_AND_ASSIGN(int latest, SchemaVersionOf(db));
  EXPECT_EQ(latest, LatestSchemaVersion());
}

}  // namespace
}  // namespace imucal::storage
