// The CLI's command table (client/cli/command_table.h) against what the commands and the
// shells do with it: every command answers -h and --help, lists every flag it accepts in its
// help, names an unknown flag; `imucal help COMMAND` is the command's own help; the bash and zsh
// completion scripts, run by bash and zsh themselves, offer the table's commands and flags.
#include "client/cli/command_table.h"

#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include "client/cli/commands.h"

namespace imucal::cli {
namespace {

using Runner = int (*)(const std::vector<std::string>&);

const std::map<std::string_view, Runner>& Runners() {
  static const std::map<std::string_view, Runner> runners = {
      {"calibrate", RunCalibrate},
      {"apply", RunApply},
      {"simulate", RunSimulate},
      {"noise", RunNoise},
      {"learn", RunLearn},
      {"demo", RunDemo},
      {"demo-server", RunServerDemo},
      {"export-file", RunExportFile},
      {"export-server", RunExport},
      {"devices", RunDevices},
      {"session", RunSession},
      {"upload", RunUpload},
      {"guide", RunGuide},
      {"solve", RunSolve},
      {"report", RunReport},
      {"params", RunParams},
      {"admin", RunAdmin},
  };
  return runners;
}

struct Ran {
  int code;
  std::string out, err;
};

Ran RunCommand(Runner runner, const std::vector<std::string>& args) {
  testing::internal::CaptureStdout();
  testing::internal::CaptureStderr();
  const int code = runner(args);
  return {code, testing::internal::GetCapturedStdout(), testing::internal::GetCapturedStderr()};
}

// stdout of a shell command line.
std::string Shell(const std::string& command) {
  std::string out;
  FILE* pipe = ::popen(command.c_str(), "r");
  if (pipe == nullptr) return out;
  std::array<char, 4096> buffer;
  for (size_t n; (n = std::fread(buffer.data(), 1, buffer.size(), pipe)) > 0;)
    out.append(buffer.data(), n);
  ::pclose(pipe);
  return out;
}

TEST(CommandTableTest, EveryCommandIsRunnableAndEveryIdUnique) {
  std::set<std::string_view> ids;
  for (const CommandSpec& c : CommandTable()) {
    EXPECT_TRUE(ids.insert(c.id).second) << c.id;
    EXPECT_TRUE(Runners().contains(c.id)) << "no runner for " << c.id;
    EXPECT_TRUE(c.switches.contains("help")) << c.id;
  }
  EXPECT_EQ(ids.size(), Runners().size());
}

TEST(CommandTableTest, DashHAndHelpPrintTheUsageAndListEveryFlag) {
  for (const CommandSpec& c : CommandTable()) {
    const Runner run = Runners().at(c.id);
    for (const std::string flag : {"-h", "--help"}) {
      // demo-server and export-server are chosen by their flags: give them.
      std::vector<std::string> args = {flag};
      if (c.id == "demo-server") args.push_back("--server=127.0.0.1:1");
      const Ran ran = RunCommand(run, args);
      EXPECT_EQ(ran.code, kExitOk) << c.id << " " << flag << ": " << ran.err;
      EXPECT_EQ(ran.out.substr(0, 13), "usage: imucal") << c.id << " " << flag;
      for (const std::set<std::string>* names : {&c.valued, &c.switches}) {
        for (const std::string& name : *names) {
          if (name == "help") continue;
          EXPECT_NE(ran.out.find("--" + name), std::string::npos)
              << "imucal " << c.word << " " << flag << " does not mention --" << name << " ("
              << c.id << ")";
        }
      }
    }
  }
}

TEST(CommandTableTest, AnUnknownFlagIsNamedWithExitCodeOne) {
  for (const CommandSpec& c : CommandTable()) {
    const Ran ran = RunCommand(Runners().at(c.id), {"--no-such-flag=1", "x"});
    EXPECT_EQ(ran.code, kExitUsage) << c.id;
    EXPECT_NE(ran.err.find("unknown flag --no-such-flag"), std::string::npos)
        << c.id << ": " << ran.err;
  }
}

TEST(CommandTableTest, HelpCommandIsTheCommandsOwnHelpAndVersionAnswers) {
  const std::string imucal = IMUCAL_CLI_PATH;
  EXPECT_EQ(Shell(imucal + " help calibrate"), Shell(imucal + " calibrate --help"));
  EXPECT_EQ(Shell(imucal + " help session"), Shell(imucal + " session -h"));
  EXPECT_EQ(Shell(imucal + " --version"), "imucal " IMUCAL_VERSION "\n");
  EXPECT_NE(Shell(imucal + " help").find("help [COMMAND]"), std::string::npos);
  EXPECT_NE(Shell(imucal + " help nosuch 2>&1; echo rc=$?").find("rc=1"), std::string::npos);
}

// Runs the bash script in bash: `words` as typed, the last one being completed.
std::string BashComplete(const std::string& words) {
  return Shell("bash -c 'source <(" IMUCAL_CLI_PATH
               " completion bash); COMP_WORDS=(" + words +
               "); COMP_CWORD=$((${#COMP_WORDS[@]}-1)); _imucal; echo \"${COMPREPLY[*]}\"'");
}

TEST(CommandTableTest, BashCompletesCommandsActionsAndFlagsFromTheTable) {
  EXPECT_EQ(BashComplete("imucal cal"), "calibrate\n");
  EXPECT_EQ(BashComplete("imucal --server h:1 sess"), "session\n");
  EXPECT_EQ(BashComplete("imucal session \"\""), "start list show poses cancel\n");
  EXPECT_EQ(BashComplete("imucal calibrate --no-he"), "--no-header --no-heldout\n");
  EXPECT_EQ(BashComplete("imucal upload --token-f"), "--token-file\n");
  EXPECT_EQ(BashComplete("imucal help expo"), "export\n");
  EXPECT_EQ(BashComplete("imucal completion z"), "zsh\n");
  // Every flag of every command is offered after its word.
  for (const CommandSpec& c : CommandTable()) {
    std::string offered = " " + BashComplete("imucal " + std::string(c.word) + " --");
    offered.back() = ' ';  // the newline
    for (const std::set<std::string>* names : {&c.valued, &c.switches}) {
      for (const std::string& name : *names) {
        EXPECT_NE(offered.find(" --" + name + " "), std::string::npos)
            << c.word << " --" << name << " not offered: " << offered;
      }
    }
  }
}

// The zsh script in zsh, with compadd, _describe and _files stubbed to print what they are given
// (zsh's completion system itself needs a terminal).
std::string ZshComplete(const std::string& words) {
  return Shell("zsh -f -c 'compadd() { [[ $1 == -- ]] && shift; print -r -- \"$@\"; }; "
               "_describe() { print -r -- \"${(@P)4%%:*}\"; }; _files() { print -r -- FILES; }; "
               "source <(" IMUCAL_CLI_PATH " completion zsh) >/dev/null; words=(" + words +
               "); CURRENT=$#words; PREFIX=$words[CURRENT]; _imucal'");
}

TEST(CommandTableTest, ZshCompletesCommandsActionsFlagsAndFiles) {
  ASSERT_NE(Shell("command -v zsh"), "") << "zsh is not installed (deploy/install-deps.sh)";
  const std::string commands = ZshComplete("imucal \"\"");
  for (const CommandSpec& c : CommandTable())
    EXPECT_NE(commands.find(std::string(c.word)), std::string::npos) << c.word;
  EXPECT_EQ(ZshComplete("imucal params \"\""), "get list promote rollback upload\n");
  EXPECT_NE(ZshComplete("imucal solve --").find("--wait"), std::string::npos);
  EXPECT_EQ(ZshComplete("imucal calibrate --out \"\""), "FILES\n");
  EXPECT_EQ(ZshComplete("imucal calibrate \"\""), "FILES\n");
}

}  // namespace
}  // namespace imucal::cli

namespace imucal::cli {
namespace {

// imucald's manners, from the same parser: --version, -h on each command, unknown flags named,
// and its completion scripts.
TEST(DaemonCommandLineTest, VersionHelpUnknownFlagsAndCompletion) {
  const std::string imucald = IMUCALD_PATH;
  EXPECT_EQ(Shell(imucald + " --version"), "imucald " IMUCAL_VERSION "\n");
  for (const std::string command : {"", "backup", "restore", "migrate", "--health-check"}) {
    const std::string out = Shell(imucald + " " + command + " -h; echo rc=$?");
    EXPECT_NE(out.find("usage"), std::string::npos) << command << ": " << out;
    EXPECT_NE(out.find("rc=0"), std::string::npos) << command << ": " << out;
    const std::string bad = Shell(imucald + " " + command + " --nope=1 2>&1; echo rc=$?");
    EXPECT_NE(bad.find("unknown flag --nope"), std::string::npos) << command << ": " << bad;
    EXPECT_NE(bad.find("rc=2"), std::string::npos) << command << ": " << bad;
  }
  const auto bash = [&](const std::string& words) {
    return Shell("bash -c 'source <(" + imucald + " completion bash); COMP_WORDS=(" + words +
                 "); COMP_CWORD=$((${#COMP_WORDS[@]}-1)); _imucald; echo \"${COMPREPLY[*]}\"'");
  };
  EXPECT_EQ(bash("imucald --solve-th"), "--solve-threads\n");
  EXPECT_EQ(bash("imucald --insec"), "--insecure\n");
  EXPECT_EQ(bash("imucald back"), "backup\n");
  EXPECT_EQ(bash("imucald backup --out"), "--out --out-dir\n");
  EXPECT_EQ(bash("imucald mig"), "migrate\n");
  EXPECT_EQ(bash("imucald migrate --t"), "--to\n");
  EXPECT_EQ(bash("imucald --health-check --in"), "--insecure\n");
  EXPECT_EQ(Shell(imucald + " completion zsh | zsh -n && echo ok"), "ok\n");
  EXPECT_NE(Shell(imucald + " completion fish 2>&1; echo rc=$?").find("rc=2"), std::string::npos);
}

}  // namespace
}  // namespace imucal::cli
