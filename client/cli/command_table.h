// Every imucal command's flags in one table: the parser (util/flags.h, on CLI11), `imucal help
// COMMAND`, and the bash and zsh completion scripts (`imucal completion bash|zsh`) all read it,
// so a flag a command accepts is one the shell offers, and the reverse.
#ifndef IMUCAL_CLIENT_CLI_COMMAND_TABLE_H_
#define IMUCAL_CLIENT_CLI_COMMAND_TABLE_H_

#include <set>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "client/cli/args.h"

namespace imucal::cli {

struct CommandSpec {
  // The table's key. Two commands share a word when the flags decide which runs: `export`
  // (a file with --params, or the server's --device) and `demo` (offline, or with --server).
  std::string_view id;
  std::string_view word;                  // what the user types: imucal WORD
  std::string_view summary;               // one line
  std::vector<std::string_view> actions = {};  // first positionals: session start|list|...
  bool positional_files = false;          // takes file names (completion offers files)
  bool server = false;                    // talks to the server: takes the connection flags
  std::set<std::string> valued = {};      // flags that take a value (without "--")
  std::set<std::string> switches = {};    // flags that do not ("help" is also -h)
};

const std::vector<CommandSpec>& CommandTable();

// The command with this id; aborts on an id not in the table (a programming error).
const CommandSpec& CommandById(std::string_view id);

// Parses a command's arguments with the table's flags for `id`.
absl::StatusOr<Args> ParseCommandFlags(std::string_view id, const std::vector<std::string>& argv);

// The connection flags every server command takes wherever they stand (commands.h,
// TakeConnectionFlags).
inline const std::set<std::string>& ConnectionFlags() {
  static const std::set<std::string> flags = {"token", "token-file", "ca-cert"};
  return flags;
}

// Completion scripts for the shells, from the table. Installed by deploy/install.sh.
std::string BashCompletion();
std::string ZshCompletion();

}  // namespace imucal::cli

#endif  // IMUCAL_CLIENT_CLI_COMMAND_TABLE_H_
