// API tokens in SQLite (storage/tokens.h): only hashes are stored, roles and devices are
// checked, revocation sticks, and every change is in the audit log.
#include "storage/tokens.h"

#include <string>

#include "gtest/gtest.h"
#include "storage/store.h"
#include "tests/storage/test_util.h"
#include "util/sqlite_db.h"

namespace imucal::storage {
namespace {

TEST(TokensTest, CreateStoresOnlyTheHashAndLookupFindsIt) {
  const std::string path = TempDbPath("db");
  ASSERT_OK_AND_ASSIGN(auto tokens, TokenStore::Open(path));
  ASSERT_OK_AND_ASSIGN(NewToken robot, tokens->Create(Role::kRobot, "robot-7", "arm", "test"));
  EXPECT_EQ(robot.token.id, 1);
  EXPECT_EQ(robot.secret.rfind("imucal_", 0), 0u);
  EXPECT_EQ(robot.secret.size(), 7u + 64u);
  ASSERT_OK_AND_ASSIGN(Token found, tokens->Lookup(HashTokenSecret(robot.secret)));
  EXPECT_EQ(found.id, robot.token.id);
  EXPECT_EQ(found.role, Role::kRobot);
  EXPECT_EQ(found.device_id, "robot-7");
  EXPECT_EQ(found.label, "arm");
  EXPECT_EQ(found.created_at, robot.token.created_at);
  EXPECT_FALSE(found.revoked());
  EXPECT_TRUE(absl::IsNotFound(tokens->Lookup(HashTokenSecret(robot.secret + "x")).status()));
  // Nothing in the file holds the secret: the column is its 32-byte SHA-256.
  ASSERT_OK_AND_ASSIGN(auto conn, sql::SqliteConnection::Open(path, sql::ConnectionOptions{}));
  {
    ASSERT_OK_AND_ASSIGN(sql::ScopedStatement st,
                         conn->Prepare("SELECT secret_sha256, length(secret_sha256) FROM tokens"));
    ASSERT_OK_AND_ASSIGN(bool row, st->Step());
    ASSERT_TRUE(row);
    EXPECT_EQ(st->ColumnInt64(1), 32);
    const TokenHash hash = HashTokenSecret(robot.secret);
    EXPECT_EQ(st->ColumnBlob(0), std::string(reinterpret_cast<const char*>(hash.data()), 32));
  }
  // Two tokens never share a secret.
  ASSERT_OK_AND_ASSIGN(NewToken other, tokens->Create(Role::kRobot, "robot-7", "", "test"));
  EXPECT_NE(other.secret, robot.secret);
}

TEST(TokensTest, RolesAndDevicesAreChecked) {
  ASSERT_OK_AND_ASSIGN(auto tokens, TokenStore::Open(TempDbPath("db")));
  absl::Status s = tokens->Create(Role::kRobot, "", "", "test").status();
  EXPECT_TRUE(absl::IsInvalidArgument(s));
  EXPECT_NE(s.message().find("device_id"), std::string::npos) << s;
  s = tokens->Create(Role::kTechnician, "robot-1", "", "test").status();
  EXPECT_TRUE(absl::IsInvalidArgument(s));
  EXPECT_NE(s.message().find("only robot tokens"), std::string::npos) << s;
  s = tokens->Create(Role::kAdmin, "", std::string(300, 'x'), "test").status();
  EXPECT_NE(s.message().find("label"), std::string::npos) << s;
  s = tokens->Create(Role::kAdmin, "", "two\nlines", "test").status();
  EXPECT_NE(s.message().find("label"), std::string::npos) << s;
  // C1 controls as C0 ones (util/text_check.h): U+0085 is a line break to many readers.
  s = tokens->Create(Role::kAdmin, "", "line 3\u0085laptop", "test").status();
  EXPECT_TRUE(absl::IsInvalidArgument(s)) << s;
  EXPECT_NE(s.message().find("label: a control character at byte 7 (U+0085)"), std::string::npos)
      << s;
  s = tokens->Create(Role::kAdmin, "", "caf\xe9", "test").status();  // Latin-1, not UTF-8
  EXPECT_NE(s.message().find("label: a byte that is not UTF-8 at byte 4 (0xE9)"), std::string::npos)
      << s;
  EXPECT_TRUE(absl::IsInvalidArgument(ParseRole("root").status()));
  ASSERT_OK_AND_ASSIGN(auto all, tokens->List());
  EXPECT_TRUE(all.empty());
}

TEST(TokensTest, RevokeSticksAndIsAudited) {
  const std::string path = TempDbPath("db");
  ASSERT_OK_AND_ASSIGN(auto store, Store::Open(path));
  ASSERT_OK_AND_ASSIGN(auto tokens, TokenStore::Open(path));
  ASSERT_OK_AND_ASSIGN(NewToken t, tokens->Create(Role::kTechnician, "", "laptop", "alice"));
  ASSERT_OK_AND_ASSIGN(Token revoked, tokens->Revoke(t.token.id, "bob"));
  ASSERT_TRUE(revoked.revoked());
  ASSERT_OK_AND_ASSIGN(Token again, tokens->Revoke(t.token.id, "bob"));  // no-op
  EXPECT_EQ(again.revoked_at, revoked.revoked_at);
  EXPECT_TRUE(absl::IsNotFound(tokens->Revoke(99, "bob").status()));
  ASSERT_OK_AND_ASSIGN(Token found, tokens->Lookup(HashTokenSecret(t.secret)));
  EXPECT_TRUE(found.revoked());
  ASSERT_OK_AND_ASSIGN(auto valid, tokens->List(/*include_revoked=*/false));
  EXPECT_TRUE(valid.empty());
  ASSERT_OK_AND_ASSIGN(auto all, tokens->List());
  ASSERT_EQ(all.size(), 1u);
  AuditQuery q;
  q.target = TokenTarget(t.token.id);
  ASSERT_OK_AND_ASSIGN(auto audit, store->ListAudit(q));
  ASSERT_EQ(audit.size(), 2u);
  EXPECT_EQ(audit[0].action, "token.create");
  EXPECT_EQ(audit[0].actor, "alice");
  EXPECT_EQ(audit[1].action, "token.revoke");
  EXPECT_EQ(audit[1].actor, "bob");
  EXPECT_EQ(audit[0].detail.find(t.secret), std::string::npos);
}

TEST(TokensTest, AFirstAdminIsCreatedOnlyWhenNoValidAdminExists) {
  const std::string path = TempDbPath("db");
  ASSERT_OK_AND_ASSIGN(auto a, TokenStore::Open(path));
  ASSERT_OK_AND_ASSIGN(auto b, TokenStore::Open(path));  // a second server on the same file
  ASSERT_OK_AND_ASSIGN(auto first, a->CreateFirstAdmin("bootstrap", "imucald"));
  ASSERT_TRUE(first.has_value());
  EXPECT_EQ(first->token.role, Role::kAdmin);
  ASSERT_OK_AND_ASSIGN(auto second, b->CreateFirstAdmin("bootstrap", "imucald"));
  EXPECT_FALSE(second.has_value());
  // Other roles do not count; a revoked admin does not either: with every admin revoked, the
  // next start makes a new one (how an operator who lost the admin secrets gets back in).
  ASSERT_OK(a->Create(Role::kTechnician, "", "", "test").status());
  ASSERT_OK(a->Revoke(first->token.id, "test").status());
  ASSERT_OK_AND_ASSIGN(auto third, b->CreateFirstAdmin("bootstrap", "imucald"));
  ASSERT_TRUE(third.has_value());
  EXPECT_NE(third->secret, first->secret);
  ASSERT_OK_AND_ASSIGN(auto fourth, b->CreateFirstAdmin("bootstrap", "imucald"));
  EXPECT_FALSE(fourth.has_value());
}

}  // namespace
}  // namespace imucal::storage
