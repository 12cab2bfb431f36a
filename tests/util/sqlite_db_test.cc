#include "util/sqlite_db.h"

#include <cmath>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/storage/test_util.h"

namespace imucal::storage {
namespace {

using ::testing::HasSubstr;

class SqliteDbTest : public ::testing::Test {
 protected:
  void SetUp() override {
    path_ = TempDbPath("db");
    auto conn = sql::SqliteConnection::Open(path_, sql::ConnectionOptions{});
    ASSERT_TRUE(conn.ok()) << conn.status();
    conn_ = *std::move(conn);
    ASSERT_OK(conn_->Exec("PRAGMA journal_mode = WAL"));
    ASSERT_OK(
        conn_->Exec("CREATE TABLE t (k INTEGER PRIMARY KEY, v TEXT NOT NULL, "
                    "d REAL, b BLOB, CHECK (length(v) < 10))"));
  }

  int64_t Count() {
    auto st = conn_->Prepare("SELECT COUNT(*) FROM t");
    EXPECT_TRUE(st.ok());
    EXPECT_TRUE((*st)->Step().value_or(false));
    return (*st)->ColumnInt64(0);
  }

  absl::Status Insert(int64_t k, std::string_view v) {
    auto st = conn_->Prepare("INSERT INTO t (k, v) VALUES (?1, ?2)");
    if (!st.ok()) return st.status();
    (*st)->BindInt64(1, k);
    (*st)->BindText(2, v);
    return (*st)->Run();
  }

  std::string path_;
  std::unique_ptr<sql::SqliteConnection> conn_;
};

TEST_F(SqliteDbTest, StatementsArePreparedOncePerConnection) {
  sqlite3_stmt* first = nullptr;
  {
    ASSERT_OK_AND_ASSIGN(sql::ScopedStatement st, conn_->Prepare("SELECT 1"));
    first = static_cast<sql::SqliteStatement&>(*st).get();
  }
  ASSERT_OK_AND_ASSIGN(sql::ScopedStatement st, conn_->Prepare("SELECT 1"));
  EXPECT_EQ(static_cast<sql::SqliteStatement&>(*st).get(), first);
  // Lent out already: a nested use would clobber its bindings and cursor.
  EXPECT_EQ(conn_->Prepare("SELECT 1").status().code(), absl::StatusCode::kInternal);
}

TEST_F(SqliteDbTest, ValuesRoundTripAndNanIsNull) {
  {
    ASSERT_OK_AND_ASSIGN(sql::ScopedStatement st,
                         conn_->Prepare("INSERT INTO t (k, v, d, b) VALUES (?1, ?2, ?3, ?4)"));
    st->BindInt64(1, int64_t{1} << 40);
    st->BindText(2, std::string_view("a\0b", 3));
    st->BindDouble(3, std::nan(""));
    st->BindBlob(4, "");
    ASSERT_OK(st->Run());
  }
  ASSERT_OK_AND_ASSIGN(sql::ScopedStatement st,
                       conn_->Prepare("SELECT k, v, d, b, typeof(d), typeof(b) FROM t"));
  ASSERT_OK_AND_ASSIGN(bool row, st->Step());
  ASSERT_TRUE(row);
  EXPECT_EQ(st->ColumnInt64(0), int64_t{1} << 40);
  EXPECT_EQ(st->ColumnText(1), std::string("a\0b", 3));
  EXPECT_TRUE(std::isnan(st->ColumnDouble(2)));
  EXPECT_EQ(st->ColumnText(4), "null");
  EXPECT_EQ(st->ColumnText(5), "blob");  // empty, not NULL
  EXPECT_EQ(st->ColumnBlob(3), "");
}

TEST_F(SqliteDbTest, TransactionRollsBackUnlessCommitted) {
  {
    ASSERT_OK_AND_ASSIGN(sql::Transaction txn, sql::Transaction::Begin(*conn_));
    ASSERT_OK(Insert(1, "x"));
  }
  EXPECT_EQ(Count(), 0);
  {
    ASSERT_OK_AND_ASSIGN(sql::Transaction txn, sql::Transaction::Begin(*conn_));
    ASSERT_OK(Insert(1, "x"));
    ASSERT_OK(txn.Commit());
    EXPECT_FALSE(txn.Commit().ok());
  }
  EXPECT_EQ(Count(), 1);
}

TEST_F(SqliteDbTest, ConstraintCodesMapToStatuses) {
  ASSERT_OK(Insert(1, "x"));
  EXPECT_EQ(Insert(1, "y").code(), absl::StatusCode::kAlreadyExists);
  EXPECT_EQ(Insert(2, "much too long").code(), absl::StatusCode::kFailedPrecondition);
  // A bind error (index out of range) surfaces at Step.
  ASSERT_OK_AND_ASSIGN(sql::ScopedStatement st, conn_->Prepare("SELECT ?1"));
  st->BindInt64(7, 1);
  EXPECT_EQ(st->Step().status().code(), absl::StatusCode::kInternal);
}

TEST_F(SqliteDbTest, LockedDatabaseIsUnavailable) {
  sql::ConnectionOptions impatient;
  impatient.busy_timeout = absl::ZeroDuration();
  ASSERT_OK_AND_ASSIGN(auto other, sql::SqliteConnection::Open(path_, impatient));
  ASSERT_OK_AND_ASSIGN(sql::Transaction holding, sql::Transaction::Begin(*conn_));
  absl::StatusOr<sql::Transaction> blocked = sql::Transaction::Begin(*other);
  EXPECT_EQ(blocked.status().code(), absl::StatusCode::kUnavailable) << blocked.status();
  EXPECT_THAT(blocked.status().message(), HasSubstr("locked"));
}

// ---- Whole statements: ReadRows, ReadRow, RunStatement ----------------------------------------

struct Row {
  int64_t k = 0;
  std::string v;
  double d = 0.0;
  std::string b;
  std::string type_of_b;
};

Row ReadRowOfT(const sql::Statement& st) {
  return Row{st.ColumnInt64(0), st.ColumnText(1), st.ColumnDouble(2), st.ColumnBlob(3),
             st.ColumnText(4)};
}

constexpr char kInsertRow[] = "INSERT INTO t (k, v, d, b) VALUES (?1, ?2, ?3, ?4)";
constexpr char kSelectRows[] = "SELECT k, v, d, b, typeof(b) FROM t WHERE k > ?1 ORDER BY k";

TEST_F(SqliteDbTest, ParametersBindInOrderByType) {
  ASSERT_OK(sql::RunStatement(*conn_, kInsertRow, 1, "one", 1.5, sql::SqlBlob{"\x01\x02"}));
  ASSERT_OK(sql::RunStatement(*conn_, kInsertRow, int64_t{2}, std::string("two"), std::nullopt,
                              std::optional<std::string_view>()));
  ASSERT_OK(
      sql::RunStatement(*conn_, kInsertRow, 3, std::string_view("3"), 0.25, "text, not blob"));
  ASSERT_OK_AND_ASSIGN(std::vector<Row> rows, sql::ReadRows(*conn_, kSelectRows, ReadRowOfT, 0));
  ASSERT_EQ(rows.size(), 3u);
  EXPECT_EQ(rows[0].k, 1);
  EXPECT_EQ(rows[0].v, "one");
  EXPECT_EQ(rows[0].d, 1.5);
  EXPECT_EQ(rows[0].b, "\x01\x02");
  EXPECT_EQ(rows[0].type_of_b, "blob");
  EXPECT_EQ(rows[1].v, "two");
  EXPECT_TRUE(std::isnan(rows[1].d));  // NULL
  EXPECT_EQ(rows[1].type_of_b, "null");
  EXPECT_EQ(rows[2].type_of_b, "text");
  // A bool binds as 0/1.
  ASSERT_OK_AND_ASSIGN(
      std::optional<int64_t> one,
      sql::ReadRow(
          *conn_, "SELECT ?1 + ?2", [](const sql::Statement& st) { return st.ColumnInt64(0); },
          true, false));
  EXPECT_EQ(one, 1);
}

TEST_F(SqliteDbTest, ReadRowsMapsEveryRowInOrder) {
  for (int k : {3, 1, 2}) ASSERT_OK(Insert(k, "x"));
  ASSERT_OK_AND_ASSIGN(std::vector<Row> after_one,
                       sql::ReadRows(*conn_, kSelectRows, ReadRowOfT, 1));
  ASSERT_EQ(after_one.size(), 2u);
  EXPECT_EQ(after_one[0].k, 2);
  EXPECT_EQ(after_one[1].k, 3);
  ASSERT_OK_AND_ASSIGN(std::vector<Row> none, sql::ReadRows(*conn_, kSelectRows, ReadRowOfT, 3));
  EXPECT_TRUE(none.empty());
}

TEST_F(SqliteDbTest, AMapperErrorEndsTheRead) {
  for (int k : {1, 2, 3}) ASSERT_OK(Insert(k, "x"));
  int mapped = 0;
  auto fail_on_two = [&](const sql::Statement& st) -> absl::StatusOr<int64_t> {
    ++mapped;
    if (st.ColumnInt64(0) == 2) return absl::DataLossError("row 2 is damaged");
    return st.ColumnInt64(0);
  };
  absl::StatusOr<std::vector<int64_t>> rows = sql::ReadRows(*conn_, kSelectRows, fail_on_two, 0);
  EXPECT_EQ(rows.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(rows.status().message(), HasSubstr("row 2"));
  EXPECT_EQ(mapped, 2);
}

TEST_F(SqliteDbTest, ReadRowIsTheFirstRowOrNothing) {
  ASSERT_OK_AND_ASSIGN(std::optional<Row> missing,
                       sql::ReadRow(*conn_, kSelectRows, ReadRowOfT, 0));
  EXPECT_FALSE(missing.has_value());
  for (int k : {1, 2}) ASSERT_OK(Insert(k, "x"));
  ASSERT_OK_AND_ASSIGN(std::optional<Row> first, sql::ReadRow(*conn_, kSelectRows, ReadRowOfT, 0));
  ASSERT_TRUE(first.has_value());
  EXPECT_EQ(first->k, 1);
  // Stopped half-way, yet returned and reset: no read transaction stays open behind it.
  ASSERT_OK_AND_ASSIGN(sql::ScopedStatement st, conn_->Prepare(kSelectRows));
  EXPECT_FALSE(sqlite3_stmt_busy(static_cast<sql::SqliteStatement&>(*st).get()));
}

TEST_F(SqliteDbTest, WholeStatementsReturnSqliteErrorsAsStatuses) {
  ASSERT_OK(sql::RunStatement(*conn_, kInsertRow, 1, "x", 0.0, sql::SqlBlob{""}));
  EXPECT_EQ(sql::RunStatement(*conn_, kInsertRow, 1, "y", 0.0, sql::SqlBlob{""}).code(),
            absl::StatusCode::kAlreadyExists);
  EXPECT_EQ(sql::RunStatement(*conn_, kInsertRow, 2, "much too long", 0.0, sql::SqlBlob{""}).code(),
            absl::StatusCode::kFailedPrecondition);
  // Invalid SQL fails at prepare; a parameter past the statement's fails at the step.
  EXPECT_EQ(sql::ReadRows(*conn_, "SELECT nonsense FROM", ReadRowOfT).status().code(),
            absl::StatusCode::kInternal);
  EXPECT_EQ(sql::ReadRow(*conn_, kSelectRows, ReadRowOfT, 0, 1).status().code(),
            absl::StatusCode::kInternal);
}

TEST(SqliteStatusTest, CodesMapAsDocumented) {
  EXPECT_EQ(sql::SqliteStatus(SQLITE_BUSY, "x", nullptr).code(), absl::StatusCode::kUnavailable);
  EXPECT_EQ(sql::SqliteStatus(SQLITE_CONSTRAINT_UNIQUE, "x", nullptr).code(),
            absl::StatusCode::kAlreadyExists);
  EXPECT_EQ(sql::SqliteStatus(SQLITE_CONSTRAINT_PRIMARYKEY, "x", nullptr).code(),
            absl::StatusCode::kAlreadyExists);
  EXPECT_EQ(sql::SqliteStatus(SQLITE_CONSTRAINT_FOREIGNKEY, "x", nullptr).code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(sql::SqliteStatus(SQLITE_CORRUPT, "x", nullptr).code(), absl::StatusCode::kDataLoss);
  EXPECT_EQ(sql::SqliteStatus(SQLITE_NOTADB, "x", nullptr).code(), absl::StatusCode::kDataLoss);
  EXPECT_EQ(sql::SqliteStatus(SQLITE_FULL, "x", nullptr).code(),
            absl::StatusCode::kResourceExhausted);
  EXPECT_EQ(sql::SqliteStatus(SQLITE_IOERR_WRITE, "x", nullptr).code(),
            absl::StatusCode::kUnavailable);
  EXPECT_EQ(sql::SqliteStatus(SQLITE_MISUSE, "x", nullptr).code(), absl::StatusCode::kInternal);
  EXPECT_THAT(sql::SqliteStatus(SQLITE_BUSY, "AppendBatch", nullptr).message(),
              HasSubstr("AppendBatch: "));
}

}  // namespace
}  // namespace imucal::storage
