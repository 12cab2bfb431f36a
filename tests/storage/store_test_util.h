// The fixtures of the Store's tests (store_test.cc and store_<table>_test.cc, which mirror the
// store's files): a fresh database per test, and one with a device and an open session.
//
// Every test runs on both backends, unchanged: a SQLite file, and a database of its own on a
// real PostgreSQL (tests/pg_test_cluster.h). `path_` is the file's path or the database's URL.
#ifndef IMUCAL_TESTS_STORAGE_STORE_TEST_UTIL_H_
#define IMUCAL_TESTS_STORAGE_STORE_TEST_UTIL_H_

#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "gtest/gtest.h"
#include "storage/store.h"
#include "storage/types.h"
#include "tests/pg_test_cluster.h"
#include "tests/storage/test_util.h"

namespace imucal::storage {

inline constexpr char kActor[] = "tech:alice";

enum class Backend { kSqlite, kPostgres };

inline std::string BackendName(const ::testing::TestParamInfo<Backend>& info) {
  return info.param == Backend::kSqlite ? "Sqlite" : "Postgres";
}

class StoreTest : public ::testing::TestWithParam<Backend> {
 protected:
  void SetUp() override {
    if (GetParam() == Backend::kPostgres) {
      auto db = testing_util::PgTestDatabase::Create();
      ASSERT_TRUE(db.ok()) << db.status();
      pg_ = *std::move(db);
      path_ = pg_->url();
    } else {
      path_ = TempDbPath("db");
    }
    Reopen();
  }
  void TearDown() override { store_.reset(); }

  void Reopen() {
    store_.reset();
    auto store = Store::Open(path_);
    ASSERT_TRUE(store.ok()) << store.status();
    store_ = *std::move(store);
  }

  std::vector<std::string> AuditActions(const std::string& target) {
    AuditQuery q;
    q.target = target;
    absl::StatusOr<std::vector<AuditEntry>> entries = store_->ListAudit(q);
    EXPECT_TRUE(entries.ok()) << entries.status();
    std::vector<std::string> actions;
    if (entries.ok()) {
      for (const AuditEntry& e : *entries) actions.push_back(e.action);
    }
    return actions;
  }

  size_t AuditCount() { return store_->ListAudit().value().size(); }

  std::unique_ptr<testing_util::PgTestDatabase> pg_;  // declared first: dropped last
  std::string path_;
  std::unique_ptr<Store> store_;
};

// A store with device "robot-1" and its open session "S1".
class BatchTest : public StoreTest {
 protected:
  void SetUp() override {
    StoreTest::SetUp();
    ASSERT_OK(store_->CreateDevice(MakeDevice("robot-1"), kActor).status());
    ASSERT_OK(store_->CreateSession(MakeSession("robot-1", "S1"), kActor).status());
  }
};

}  // namespace imucal::storage

#endif  // IMUCAL_TESTS_STORAGE_STORE_TEST_UTIL_H_
