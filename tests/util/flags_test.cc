// util/flags.h: the parser every executable shares (CLI11 underneath), on the contract the
// commands rely on.
#include "util/flags.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace imucal::flags {
namespace {

const std::set<std::string> kValued = {"out", "gravity", "effect"};
const std::set<std::string> kSwitches = {"json", "help"};

absl::StatusOr<Args> Parse(const std::vector<std::string>& argv) {
  return Args::Parse(argv, kValued, kSwitches);
}

TEST(FlagsTest, BothValueSpellingsAndPositionalsAnywhere) {
  absl::StatusOr<Args> a = Parse({"a.csv", "--out", "r.json", "b.csv", "--gravity=9.80665"});
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ(a->positional(), (std::vector<std::string>{"a.csv", "b.csv"}));
  EXPECT_EQ(a->Get("out"), "r.json");
  EXPECT_EQ(*a->GetDouble("gravity", 0), 9.80665);
  EXPECT_FALSE(a->Has("json"));
  EXPECT_FALSE(a->Get("effect").has_value());
}

TEST(FlagsTest, RepeatsKeepEveryValueAndNegativeNumbersAreValues) {
  absl::StatusOr<Args> a =
      Parse({"--effect", "-0.5", "--effect=x", "--gravity", "-9.81", "--gravity", "9.81"});
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ(a->GetAll("effect"), (std::vector<std::string>{"-0.5", "x"}));
  EXPECT_EQ(a->Get("gravity"), "9.81");  // the last one
  EXPECT_TRUE(a->positional().empty());
}

TEST(FlagsTest, SwitchesAloneOrWithATruthValueAndDashHIsHelp) {
  absl::StatusOr<Args> a = Parse({"--json", "-h"});
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_TRUE(a->Has("json"));
  EXPECT_TRUE(a->Has("help"));
  a = Parse({"--json=false", "--help=true"});
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_FALSE(a->Has("json"));
  EXPECT_TRUE(a->Has("help"));
  EXPECT_EQ(Parse({"--json=perhaps"}).status().code(), absl::StatusCode::kInvalidArgument);
  // -h is help only where the command declares it.
  EXPECT_EQ(Args::Parse({"-h"}, kValued, {"json"}).status().message(), "unknown flag -h");
}

TEST(FlagsTest, BooleansStandAloneOrTakeTheNextWord) {
  const auto parse = [](const std::vector<std::string>& argv) {
    return Args::Parse(argv, {"listen"}, {"help"}, {"insecure", "log-rpcs"});
  };
  absl::StatusOr<Args> a = parse({"--insecure", "--listen", "h:1"});
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ(a->Get("insecure"), "true");
  EXPECT_FALSE(a->Has("log-rpcs"));
  a = parse({"--insecure", "false", "--log-rpcs=no"});
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ(a->Get("insecure"), "false");
  EXPECT_EQ(a->Get("log-rpcs"), "no");  // the caller parses the word
  EXPECT_TRUE(a->positional().empty());
  a = parse({"--log-rpcs"});
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ(a->Get("log-rpcs"), "true");
}

TEST(FlagsTest, DoubleDashEndsTheFlags) {
  absl::StatusOr<Args> a = Parse({"--json", "--", "--out", "-x.csv"});
  ASSERT_TRUE(a.ok()) << a.status();
  EXPECT_EQ(a->positional(), (std::vector<std::string>{"--out", "-x.csv"}));
  EXPECT_FALSE(a->Get("out").has_value());
}

TEST(FlagsTest, ErrorsNameTheFlag) {
  EXPECT_EQ(Parse({"a.csv", "--jsno"}).status().message(), "unknown flag --jsno");
  EXPECT_EQ(Parse({"--colour=red", "a.csv"}).status().message(), "unknown flag --colour");
  EXPECT_EQ(Parse({"a.csv", "--out"}).status().message(), "--out needs a value");
  // As getopt does, the word after a valued flag is its value, whatever it looks like.
  absl::StatusOr<Args> a = Parse({"--out", "--json"});
  ASSERT_TRUE(a.ok());
  EXPECT_EQ(a->Get("out"), "--json");
  EXPECT_FALSE(a->Has("json"));
  a = Parse({"--gravity", "g"});
  ASSERT_TRUE(a.ok());
  EXPECT_EQ(a->GetDouble("gravity", 0).status().message(), "--gravity: 'g' is not a number");
  EXPECT_EQ(a->GetInt("gravity", 0).status().message(), "--gravity: 'g' is not an integer");
}

}  // namespace
}  // namespace imucal::flags
