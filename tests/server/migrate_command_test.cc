// `imucald migrate` as an operator runs it, through the real binary (server/main.cc,
// server/daemon_commands.cc): a site copied into a fresh PostgreSQL database with a per-table
// summary, the password never printed; each wrong flag refused naming it (exit 2); a copy that
// cannot be made refused with the reason (exit 1) and the destination left as it was.
#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/copy.h"
#include "storage/migrations.h"
#include "storage/pg_db.h"
#include "storage/store.h"
#include "tests/pg_test_cluster.h"
#include "tests/storage/site_fixture.h"
#include "tests/storage/test_util.h"

#ifndef IMUCAL_IMUCALD_PATH
#error "IMUCAL_IMUCALD_PATH must name the imucald binary (tests/CMakeLists.txt defines it)"
#endif

namespace imucal::storage {
namespace {

using ::testing::AllOf;
using ::testing::HasSubstr;
using ::testing::Not;

struct CommandResult {
  int exit_code = -1;
  std::string out, err;
};

std::string ReadFile(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

std::string Quoted(const std::string& word) {
  std::string q = "'";
  for (char c : word) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

// Runs `imucald migrate args...`, its output captured in files named for the running test and
// process: ctest runs this binary's tests side by side, so a shared name would mix their output.
CommandResult Migrate(const std::vector<std::string>& args) {
  const std::string out = TempDbPath("migrate") + ".out";
  const std::string err = TempDbPath("migrate") + ".err";
  std::string command = Quoted(IMUCAL_IMUCALD_PATH) + " migrate";
  for (const std::string& arg : args) command += " " + Quoted(arg);
  command += " >" + Quoted(out) + " 2>" + Quoted(err);
  const int status = std::system(command.c_str());
  CommandResult result;
  if (WIFEXITED(status)) result.exit_code = WEXITSTATUS(status);
  result.out = ReadFile(out);
  result.err = ReadFile(err);
  return result;
}

std::string Describe(const CommandResult& r) {
  return "exit " + std::to_string(r.exit_code) + "\nstdout:\n" + r.out + "\nstderr:\n" + r.err;
}

// The cluster trusts local connections, so a password in the URL is accepted and unused: the
// command must still never print it.
std::string WithPassword(const std::string& url) {
  const size_t at = url.find('@');
  return url.substr(0, at) + ":hunter2-pw" + url.substr(at);
}

class MigrateCommandTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto db = testing_util::PgTestDatabase::Create();
    ASSERT_TRUE(db.ok()) << db.status();
    pg_ = *std::move(db);
    sqlite_path_ = TempDbPath("site");
  }
  std::unique_ptr<testing_util::PgTestDatabase> pg_;
  std::string sqlite_path_;
};

TEST_F(MigrateCommandTest, CopiesASiteAndPrintsEachTable) {
  ASSERT_OK(PopulateSite(sqlite_path_).status());
  const std::string url = WithPassword(pg_->url());
  const CommandResult r = Migrate({"--from", "sqlite:" + sqlite_path_, "--to", url});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  EXPECT_THAT(r.out, AllOf(HasSubstr("sqlite:" + sqlite_path_), HasSubstr(":***@"),
                           HasSubstr("consistent snapshot"), HasSubstr("stop imucald"),
                           HasSubstr("done in"), HasSubstr("SHA-256")))
      << Describe(r);
  for (const CopyTable& t : CopyTables()) EXPECT_THAT(r.out, HasSubstr(t.name));
  EXPECT_THAT(r.out, ::testing::ContainsRegex("sample_batches +24 "));
  EXPECT_THAT(r.out + r.err, Not(HasSubstr("hunter2-pw")));

  ASSERT_OK_AND_ASSIGN(std::unique_ptr<Store> store, Store::Open(pg_->url()));
  EXPECT_EQ(store->GetActive("robot-1").value().version, 1);
  store.reset();

  // Again into the same database: refused, naming what it holds; nothing changed.
  const CommandResult again = Migrate({"--from=sqlite:" + sqlite_path_, "--to=" + url});
  EXPECT_EQ(again.exit_code, 1) << Describe(again);
  EXPECT_THAT(again.err, AllOf(HasSubstr("imucald migrate: "), HasSubstr("already holds data"),
                               HasSubstr("devices (3 rows)"), Not(HasSubstr("hunter2-pw"))))
      << Describe(again);
  ASSERT_OK_AND_ASSIGN(store, Store::Open(pg_->url()));
  EXPECT_EQ(store->ListDevices().value().size(), 3u);

  // The URL form of an absolute path, into a second database.
  auto second = testing_util::PgTestDatabase::Create();
  ASSERT_OK(second.status());
  const CommandResult url_form =
      Migrate({"--from", "sqlite://" + sqlite_path_, "--to", (*second)->url()});
  EXPECT_EQ(url_form.exit_code, 0) << Describe(url_form);
}

TEST_F(MigrateCommandTest, WrongFlagsAreRefusedNamingTheFlag) {
  const std::string url = WithPassword(pg_->url());
  struct Case {
    std::vector<std::string> args;
    std::string says;
  };
  const std::vector<Case> cases = {
      {{"--to", url}, "--from sqlite:PATH is required"},
      {{"--from", sqlite_path_, "--to", url}, "--from: expected sqlite:PATH"},
      {{"--from", "sqlite:", "--to", url}, "--from: expected sqlite:PATH"},
      {{"--from", "sqlite://imucal.db", "--to", url}, "--from: expected sqlite:PATH"},
      {{"--from", "sqlite:" + sqlite_path_}, "--to postgresql://... is required"},
      {{"--from", "sqlite:" + sqlite_path_, "--to", "/tmp/x.db"},
       "--to: expected a postgresql:// URL"},
      {{"--from", "sqlite:" + sqlite_path_, "--to", url, "extra"}, "unexpected 'extra'"},
      {{"--from", "sqlite:" + sqlite_path_, "--to", url, "--db", "x"}, "unknown flag --db"},
  };
  for (const Case& c : cases) {
    const CommandResult r = Migrate(c.args);
    EXPECT_EQ(r.exit_code, 2) << Describe(r);
    EXPECT_THAT(r.err, AllOf(HasSubstr(c.says), HasSubstr("usage: imucald migrate")))
        << Describe(r);
    EXPECT_THAT(r.out + r.err, Not(HasSubstr("hunter2-pw"))) << Describe(r);
  }
  const CommandResult help = Migrate({"--help"});
  EXPECT_EQ(help.exit_code, 0) << Describe(help);
  EXPECT_THAT(help.out, HasSubstr("usage: imucald migrate --from sqlite:PATH --to postgresql://"));
}

TEST_F(MigrateCommandTest, ACopyThatCannotBeMadeExitsOneWithTheReason) {
  const std::string url = WithPassword(pg_->url());
  const CommandResult missing = Migrate({"--from", "sqlite:" + sqlite_path_, "--to", url});
  EXPECT_EQ(missing.exit_code, 1) << Describe(missing);
  EXPECT_THAT(missing.err, AllOf(HasSubstr(sqlite_path_), HasSubstr("no such file")))
      << Describe(missing);
  EXPECT_THAT(missing.out + missing.err, Not(HasSubstr("hunter2-pw")));

  ASSERT_OK(PopulateSite(sqlite_path_).status());
  const CommandResult unreachable = Migrate(
      {"--from", "sqlite:" + sqlite_path_, "--to", "postgresql://u:hunter2-pw@127.0.0.1:1/x"});
  EXPECT_EQ(unreachable.exit_code, 1) << Describe(unreachable);
  EXPECT_THAT(unreachable.err,
              AllOf(HasSubstr("cannot connect to postgresql://u:***@127.0.0.1:1/x"),
                    Not(HasSubstr("hunter2-pw"))))
      << Describe(unreachable);
  auto pg = PgConnection::Open(pg_->url(), {});
  ASSERT_OK(pg.status());
  EXPECT_EQ(SchemaVersion(**pg).value(), 0) << "the destination was never touched";
}

}  // namespace
}  // namespace imucal::storage
