// imucald's configuration: one table of options (config.cc, ConfigOptions()), each settable
// from four places. Later ones win:
//
//   built-in defaults  <  TOML file  <  environment  <  command-line flags
//
// The file is `--config PATH` or, without that flag, $IMUCALD_CONFIG; none is read when neither
// is given. Every option has a TOML key (`solve_threads = 4`), a flag with dashes
// (`--solve-threads 4` or `--solve-threads=4`) and an environment variable
// (IMUCALD_SOLVE_THREADS=4). Keys are flat: no tables. An unknown key, a value of the wrong TOML
// type or a value out of range is an error naming the file, line and key (or the variable, or
// the flag) and what was expected; imucald then exits 2 without starting.
#ifndef IMUCAL_SERVER_CONFIG_H_
#define IMUCAL_SERVER_CONFIG_H_

#include <functional>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "server/log.h"
#include "server/server.h"

namespace imucal::server {

// Everything imucald is run with.
struct DaemonConfig {
  DaemonConfig() { server.log_rpcs = true; }  // the daemon logs every RPC; tests need not
  ServerOptions server;
  LogOptions log;
  std::string config_path;  // the file that was read; empty if none
};

// The TOML type an option's value has in the file. Flags and environment variables are text,
// parsed by the same rules (an integer in decimal, a duration as "30s", "1m30s", "500ms").
enum class OptionType { kString, kInteger, kBoolean, kDuration };

struct ConfigOption {
  std::string_view key;  // TOML key; the flag is "--" + key with '_' -> '-'
  std::string_view env;  // environment variable, IMUCALD_<KEY>
  OptionType type;
  std::string_view value_name;  // for --help: HOST:PORT, PATH, N, ...
  std::string_view help;        // one line; says the default
  // Parses `text` into `config`: InvalidArgument saying what was expected (without the key:
  // the caller prefixes where the value came from).
  std::function<absl::Status(std::string_view text, DaemonConfig& config)> set;
};

// Every option, in --help order.
std::span<const ConfigOption> ConfigOptions();

// Looks up an environment variable; nullopt when unset.
using EnvLookup = std::function<std::optional<std::string>(std::string_view name)>;
EnvLookup ProcessEnvironment();

// What LoadConfig made of the command line.
struct LoadedConfig {
  DaemonConfig config;
  bool help = false;     // --help / -h: print HelpText() and exit 0
  bool version = false;  // --version: print the version and exit 0
};

// `args` excludes the program name. InvalidArgument for an unknown flag, a missing value, a bad
// value from any source, an unreadable or malformed file, or an unknown key in it.
absl::StatusOr<LoadedConfig> LoadConfig(std::span<const std::string> args, const EnvLookup& env);

// The file part alone (for tests and `--config` checks): applies `path`'s keys onto `config`.
absl::Status ApplyConfigFile(const std::string& path, DaemonConfig& config);

// imucald --help: usage, subcommands, then every option with its flag, key and variable.
std::string HelpText();

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_CONFIG_H_
