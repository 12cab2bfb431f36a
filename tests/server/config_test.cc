// imucald's configuration (server/config.h): defaults < file < environment < flags, and errors
// that name where the bad value came from (file:line and key, variable, flag).
#include "server/config.h"

#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace imucal::server {
namespace {

using ::testing::HasSubstr;
using ::testing::StartsWith;

// A TOML file in the test's temporary directory.
std::string WriteFile(const std::string& name, const std::string& text) {
  const std::string path =
      ::testing::TempDir() + "imucald_config_" + std::to_string(::getpid()) + "_" + name;
  std::ofstream(path) << text;
  return path;
}

// absl::string_view (not std::) on this Debian: matchers want a std::string.
std::string Message(const absl::Status& s) { return std::string(s.message()); }

EnvLookup FakeEnv(std::map<std::string, std::string> vars) {
  return [vars = std::move(vars)](std::string_view name) -> std::optional<std::string> {
    auto it = vars.find(std::string(name));
    if (it == vars.end()) return std::nullopt;
    return it->second;
  };
}

absl::StatusOr<LoadedConfig> Load(std::vector<std::string> args,
                                  std::map<std::string, std::string> env = {}) {
  return LoadConfig(args, FakeEnv(std::move(env)));
}

TEST(ConfigTest, DefaultsWithoutFileEnvironmentOrFlags) {
  absl::StatusOr<LoadedConfig> loaded = Load({});
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  const ServerOptions defaults;
  EXPECT_EQ(loaded->config.server.listen, defaults.listen);
  EXPECT_EQ(loaded->config.server.db_path, defaults.db_path);
  EXPECT_EQ(loaded->config.server.sessions.solve_threads, defaults.sessions.solve_threads);
  EXPECT_EQ(loaded->config.server.drain_deadline, defaults.drain_deadline);
  EXPECT_TRUE(loaded->config.server.log_rpcs);  // the daemon logs RPCs; the library does not
  EXPECT_FALSE(defaults.log_rpcs);
  EXPECT_EQ(loaded->config.log.format, LogFormat::kJson);
  EXPECT_EQ(loaded->config.config_path, "");
  EXPECT_FALSE(loaded->help);
}

TEST(ConfigTest, FileThenEnvironmentThenFlagsEachOverrideTheOneBefore) {
  const std::string file = WriteFile("precedence.toml",
                                     "# every layer sets some of these\n"
                                     "listen = \"127.0.0.1:7001\"\n"
                                     "db = \"/var/lib/imucald/file.db\"\n"
                                     "solve_threads = 3\n"
                                     "drain_deadline = \"45s\"\n"
                                     "log_format = \"text\"\n"
                                     "durability = \"normal\"\n");
  absl::StatusOr<LoadedConfig> loaded =
      Load({"--config", file, "--solve-threads=7", "--log-level", "debug"},
           {{"IMUCALD_LISTEN", "127.0.0.1:7002"},
            {"IMUCALD_SOLVE_THREADS", "5"},
            {"IMUCALD_LOG_LEVEL", "error"}});
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  const DaemonConfig& c = loaded->config;
  EXPECT_EQ(c.config_path, file);
  EXPECT_EQ(c.server.db_path, "/var/lib/imucald/file.db");       // file only
  EXPECT_EQ(c.server.drain_deadline, absl::Seconds(45));         // file only
  EXPECT_EQ(c.log.format, LogFormat::kText);                     // file only
  EXPECT_EQ(c.server.durability, storage::Durability::kNormal);  // file only
  EXPECT_EQ(c.server.listen, "127.0.0.1:7002");                  // env over file
  EXPECT_EQ(c.server.sessions.solve_threads, 7);                 // flag over env over file
  EXPECT_EQ(c.log.level, LogLevel::kDebug);                      // flag over env
  EXPECT_EQ(c.server.sessions.solve_queue_limit, ServerOptions().sessions.solve_queue_limit);
}

TEST(ConfigTest, ConfigFileFromEnvironmentUnlessTheFlagNamesOne) {
  const std::string from_env = WriteFile("env.toml", "solve_threads = 4\n");
  const std::string from_flag = WriteFile("flag.toml", "solve_threads = 6\n");
  absl::StatusOr<LoadedConfig> loaded = Load({}, {{"IMUCALD_CONFIG", from_env}});
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->config.server.sessions.solve_threads, 4);
  EXPECT_EQ(loaded->config.config_path, from_env);

  loaded = Load({"--config=" + from_flag}, {{"IMUCALD_CONFIG", from_env}});
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->config.server.sessions.solve_threads, 6);
  EXPECT_EQ(loaded->config.config_path, from_flag);
}

TEST(ConfigTest, UnknownKeyNamesFileLineAndKey) {
  const std::string file = WriteFile("unknown.toml",
                                     "listen = \"127.0.0.1:7001\"\n"
                                     "\n"
                                     "solve_thread = 4\n");
  absl::StatusOr<LoadedConfig> loaded = Load({"--config", file});
  ASSERT_EQ(loaded.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(Message(loaded.status()), StartsWith(file + ":3:"));
  EXPECT_THAT(Message(loaded.status()), HasSubstr("unknown key 'solve_thread'"));
}

TEST(ConfigTest, TablesAreUnknownKeysToo) {
  const std::string file = WriteFile("table.toml", "db = \"x.db\"\n[server]\nlisten = \"a:1\"\n");
  absl::StatusOr<LoadedConfig> loaded = Load({"--config", file});
  ASSERT_EQ(loaded.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(Message(loaded.status()), StartsWith(file + ":2:"));
  EXPECT_THAT(Message(loaded.status()), HasSubstr("unknown key 'server'"));
}

TEST(ConfigTest, BadValuesInTheFileNameLineKeyAndWhatWasExpected) {
  struct Case {
    std::string text;
    std::string where;  // "file:line:"
    std::string says;
  };
  const std::vector<Case> cases = {
      {"db = \"a.db\"\nsolve_threads = \"four\"\n",
       ":2:", "solve_threads: expected an integer, got a string"},
      {"solve_threads = 0\n", ":1:", "solve_threads: must be between 1 and 256, got 0"},
      {"listen = 50051\n", ":1:", "listen: expected a string, got an integer"},
      {"\n\ndrain_deadline = \"soon\"\n", ":3:", "drain_deadline: expected a duration"},
      {"drain_deadline = \"-5s\"\n", ":1:", "drain_deadline: must not be negative"},
      {"log_format = \"xml\"\n", ":1:", "log_format: expected json or text, got 'xml'"},
      {"log_rpcs = \"yes\"\n", ":1:", "log_rpcs: expected true or false, got a string"},
      {"db = \"\"\n", ":1:", "db: must not be empty"},
      {"db = \"a.db\"\nlisten = \"unterminated\n", ":2:", "string"},  // a TOML syntax error
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    const std::string file = WriteFile("bad" + std::to_string(i) + ".toml", cases[i].text);
    absl::StatusOr<LoadedConfig> loaded = Load({"--config", file});
    ASSERT_EQ(loaded.status().code(), absl::StatusCode::kInvalidArgument) << cases[i].text;
    EXPECT_THAT(Message(loaded.status()), StartsWith(file + cases[i].where)) << cases[i].text;
    EXPECT_THAT(Message(loaded.status()), HasSubstr(cases[i].says)) << cases[i].text;
  }
}

TEST(ConfigTest, BadValuesFromEnvironmentAndFlagsNameTheVariableOrFlag) {
  absl::StatusOr<LoadedConfig> loaded = Load({}, {{"IMUCALD_SOLVE_QUEUE_LIMIT", "lots"}});
  ASSERT_EQ(loaded.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(Message(loaded.status()),
            "environment IMUCALD_SOLVE_QUEUE_LIMIT: expected an integer, got 'lots'");

  loaded = Load({"--drain-deadline", "3 fortnights"});
  ASSERT_EQ(loaded.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(Message(loaded.status()), StartsWith("--drain-deadline: expected a duration"));

  loaded = Load({"--solve-threads"});
  ASSERT_EQ(loaded.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(Message(loaded.status()), "--solve-threads needs a value");

  loaded = Load({"--listne", "x:1"});
  ASSERT_EQ(loaded.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(Message(loaded.status()), HasSubstr("unknown flag --listne"));

  loaded = Load({"--config", "/nonexistent/imucald.toml"});
  ASSERT_EQ(loaded.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(Message(loaded.status()), HasSubstr("/nonexistent/imucald.toml"));
  EXPECT_THAT(Message(loaded.status()), HasSubstr("cannot read"));
}

TEST(ConfigTest, TheOriginalFlagsStillWorkAndBooleanFlagsStandAlone) {
  absl::StatusOr<LoadedConfig> loaded =
      Load({"--listen", "127.0.0.1:0", "--db=/tmp/x.db", "--log-rpcs=false", "--help"});
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_EQ(loaded->config.server.listen, "127.0.0.1:0");
  EXPECT_EQ(loaded->config.server.db_path, "/tmp/x.db");
  EXPECT_FALSE(loaded->config.server.log_rpcs);
  EXPECT_TRUE(loaded->help);
  loaded = Load({"--log-rpcs=false", "--log-rpcs"});  // a bare boolean flag means true
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_TRUE(loaded->config.server.log_rpcs);
}

// --help shows "--insecure BOOL": the value may follow as the next word, as for every other
// option (true/false/1/0/yes/no), or be left out (true); the word after a bare flag that is
// not a boolean is the next flag.
TEST(ConfigTest, BooleanFlagsTakeTheirValueAsTheNextWordToo) {
  for (const auto& [word, expected] : std::vector<std::pair<std::string, bool>>{{"true", true},
                                                                                {"1", true},
                                                                                {"yes", true},
                                                                                {"false", false},
                                                                                {"0", false},
                                                                                {"no", false}}) {
    SCOPED_TRACE(word);
    absl::StatusOr<LoadedConfig> loaded = Load({"--insecure", word, "--listen", "127.0.0.1:0"});
    ASSERT_TRUE(loaded.ok()) << loaded.status();
    EXPECT_EQ(loaded->config.server.security.insecure, expected);
    EXPECT_EQ(loaded->config.server.listen, "127.0.0.1:0");
  }
  absl::StatusOr<LoadedConfig> loaded = Load({"--insecure", "--db", "x.db"});
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_TRUE(loaded->config.server.security.insecure);
  EXPECT_EQ(loaded->config.server.db_path, "x.db");
  loaded = Load({"--db", "x.db", "--insecure"});  // last on the line
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  EXPECT_TRUE(loaded->config.server.security.insecure);
  // A word that is neither a boolean nor a flag after a boolean flag is not taken silently.
  loaded = Load({"--insecure", "maybe"});
  ASSERT_FALSE(loaded.ok());
  EXPECT_THAT(Message(loaded.status()), HasSubstr("maybe"));
}

TEST(ConfigTest, EveryOptionHasItsVariableFlagAndHelpLine) {
  const std::string help = HelpText();
  for (const ConfigOption& option : ConfigOptions()) {
    std::string env = "IMUCALD_";
    std::string flag = "--";
    for (const char ch : option.key) {
      env.push_back(static_cast<char>(std::toupper(static_cast<unsigned char>(ch))));
      flag.push_back(ch == '_' ? '-' : ch);
    }
    EXPECT_EQ(option.env, env) << option.key;
    EXPECT_THAT(help, HasSubstr(flag + " ")) << option.key;
    EXPECT_THAT(help, HasSubstr(env)) << option.key;
    EXPECT_FALSE(option.help.empty()) << option.key;
  }
}

// deploy/imucald.toml documents every option as a commented line "# key = value". With the
// comment marks removed it must be a valid configuration that sets every key.
TEST(ConfigTest, TheExampleFileHasEveryOptionAndItsValuesParse) {
  const std::string example = std::string(IMUCAL_SOURCE_DIR) + "/deploy/imucald.toml";
  std::ifstream in(example);
  ASSERT_TRUE(in) << example;
  std::stringstream uncommented;
  std::vector<std::string> keys;
  std::string line;
  while (std::getline(in, line)) {
    // "#key = ..." or "# key = ..." where key is an option: the example value.
    size_t start = line.starts_with("# ") ? 2 : line.starts_with("#") ? 1 : 0;
    const std::string body = line.substr(start);
    const size_t eq = body.find(" = ");
    const std::string key = eq == std::string::npos ? "" : body.substr(0, eq);
    bool is_option = false;
    for (const ConfigOption& option : ConfigOptions()) is_option |= option.key == key;
    if (is_option) {
      keys.push_back(key);
      uncommented << body << "\n";
    } else if (start == 0) {
      uncommented << line << "\n";
    }
  }
  for (const ConfigOption& option : ConfigOptions()) {
    EXPECT_EQ(std::count(keys.begin(), keys.end(), std::string(option.key)), 1)
        << option.key << " should appear once in " << example;
  }
  const std::string file = WriteFile("example.toml", uncommented.str());
  DaemonConfig config;
  absl::Status status = ApplyConfigFile(file, config);
  EXPECT_TRUE(status.ok()) << status << "\n" << uncommented.str();
}

}  // namespace
}  // namespace imucal::server
