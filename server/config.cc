#include "server/config.h"

#include <cerrno>
#include <charconv>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <set>
#include <utility>
#include <vector>

#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "toml++/toml.h"
#include "util/flags.h"
#include "util/str_util.h"

namespace imucal::server {
namespace {

// ---- Value parsers shared by the file, the environment and the flags.

template <typename Int>
absl::StatusOr<Int> ParseInteger(std::string_view text, Int min, Int max) {
  long long value = 0;
  const auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (text.empty() || ec != std::errc() || ptr != text.data() + text.size()) {
    return absl::InvalidArgumentError(Cat("expected an integer, got '", text, "'"));
  }
  if (value < static_cast<long long>(min) ||
      static_cast<unsigned long long>(value) > static_cast<unsigned long long>(max)) {
    return absl::InvalidArgumentError(Cat("must be between ", static_cast<long long>(min), " and ",
                                          static_cast<unsigned long long>(max), ", got ", value));
  }
  return static_cast<Int>(value);
}

absl::StatusOr<absl::Duration> ParseNonNegativeDuration(std::string_view text) {
  absl::Duration d;
  if (!absl::ParseDuration(absl::string_view(text.data(), text.size()), &d) ||
      d == absl::InfiniteDuration()) {
    return absl::InvalidArgumentError(
        Cat("expected a duration such as \"30s\", \"1m30s\" or \"500ms\", got '", text, "'"));
  }
  if (d < absl::ZeroDuration()) {
    return absl::InvalidArgumentError(Cat("must not be negative, got '", text, "'"));
  }
  return d;
}

absl::StatusOr<bool> ParseBool(std::string_view text) {
  if (text == "true" || text == "1" || text == "yes") return true;
  if (text == "false" || text == "0" || text == "no") return false;
  return absl::InvalidArgumentError(Cat("expected true or false, got '", text, "'"));
}

// ---- Option builders: each binds a key to one field of DaemonConfig.

template <typename T>
using Field = T& (*)(DaemonConfig&);

ConfigOption StringOption(std::string_view key, std::string_view env, std::string_view value_name,
                          std::string_view help, Field<std::string> field,
                          bool allow_empty = false) {
  return {key,
          env,
          OptionType::kString,
          value_name,
          help,
          [field, allow_empty](std::string_view text, DaemonConfig& c) -> absl::Status {
            if (text.empty() && !allow_empty) {
              return absl::InvalidArgumentError("must not be empty");
            }
            field(c) = std::string(text);
            return absl::OkStatus();
          }};
}

template <typename Int>
ConfigOption IntegerOption(std::string_view key, std::string_view env, std::string_view help,
                           Int min, Int max, Field<Int> field) {
  return {key,
          env,
          OptionType::kInteger,
          "N",
          help,
          [field, min, max](std::string_view text, DaemonConfig& c) -> absl::Status {
            absl::StatusOr<Int> value = ParseInteger<Int>(text, min, max);
            if (!value.ok()) return value.status();
            field(c) = *value;
            return absl::OkStatus();
          }};
}

ConfigOption DurationOption(std::string_view key, std::string_view env, std::string_view help,
                            Field<absl::Duration> field) {
  return {key,
          env,
          OptionType::kDuration,
          "DURATION",
          help,
          [field](std::string_view text, DaemonConfig& c) -> absl::Status {
            absl::StatusOr<absl::Duration> value = ParseNonNegativeDuration(text);
            if (!value.ok()) return value.status();
            field(c) = *value;
            return absl::OkStatus();
          }};
}

ConfigOption BoolOption(std::string_view key, std::string_view env, std::string_view help,
                        Field<bool> field) {
  return {key,
          env,
          OptionType::kBoolean,
          "BOOL",
          help,
          [field](std::string_view text, DaemonConfig& c) -> absl::Status {
            absl::StatusOr<bool> value = ParseBool(text);
            if (!value.ok()) return value.status();
            field(c) = *value;
            return absl::OkStatus();
          }};
}

// A string option whose text `parse` turns into an enum.
template <typename E>
ConfigOption ChoiceOption(std::string_view key, std::string_view env, std::string_view value_name,
                          std::string_view help, absl::StatusOr<E> (*parse)(std::string_view),
                          Field<E> field) {
  return {key,
          env,
          OptionType::kString,
          value_name,
          help,
          [field, parse](std::string_view text, DaemonConfig& c) -> absl::Status {
            absl::StatusOr<E> value = parse(text);
            if (!value.ok()) return value.status();
            field(c) = *value;
            return absl::OkStatus();
          }};
}

absl::StatusOr<storage::Durability> ParseDurability(std::string_view text) {
  if (text == "full") return storage::Durability::kFull;
  if (text == "normal") return storage::Durability::kNormal;
  return absl::InvalidArgumentError(Cat("expected full or normal, got '", text, "'"));
}

// ---- THE OPTION TABLE. To add an option: give ServerOptions (or DaemonConfig) a field, then
// append one entry to its group below with a builder above (StringOption, IntegerOption,
// DurationOption, BoolOption, ChoiceOption): the TOML key, the flag (--key-with-dashes), the
// environment variable, --help, deploy/imucald.toml and the errors all follow from it. Keep the
// help one line and say the default; add the key, commented, to deploy/imucald.toml.

// Where the server listens and keeps its state.
std::vector<ConfigOption> ServeOptions() {
  return {
      StringOption("listen", "IMUCALD_LISTEN", "HOST:PORT",
                   "address to serve gRPC on; port 0 picks a free one (default 127.0.0.1:50051)",
                   [](DaemonConfig& c) -> std::string& { return c.server.listen; }),
      StringOption("metrics_listen", "IMUCALD_METRICS_LISTEN", "HOST:PORT",
                   "address to serve Prometheus metrics on, http://HOST:PORT/metrics; port 0 "
                   "picks a free one (default: none)",
                   [](DaemonConfig& c) -> std::string& { return c.server.metrics_listen; }),
      StringOption(
          "db", "IMUCALD_DB", "PATH",
          "SQLite database file, or a postgresql:// URL shared by several servers; created "
          "(a file) and migrated on start (default imucal.db)",
          [](DaemonConfig& c) -> std::string& { return c.server.db_path; }),
      ChoiceOption<storage::Durability>(
          "durability", "IMUCALD_DURABILITY", "full|normal",
          "full: fsync every commit, acknowledged data survives a power cut; normal: survives "
          "a killed process only (default full)",
          &ParseDurability,
          [](DaemonConfig& c) -> storage::Durability& { return c.server.durability; }),
  };
}

// The solves, and the servers that share a database.
std::vector<ConfigOption> SolveOptions() {
  return {
      IntegerOption<int>("solve_threads", "IMUCALD_SOLVE_THREADS",
                         "threads that run calibration solves (default 2)", 1, 256,
                         [](DaemonConfig& c) -> int& { return c.server.sessions.solve_threads; }),
      IntegerOption<size_t>(
          "solve_queue_limit", "IMUCALD_SOLVE_QUEUE_LIMIT",
          "solves that may wait for a thread; more are refused with RESOURCE_EXHAUSTED "
          "(default 16)",
          1, 100000,
          [](DaemonConfig& c) -> size_t& { return c.server.sessions.solve_queue_limit; }),
      StringOption("replica_id", "IMUCALD_REPLICA_ID", "ID",
                   "this server's name to others sharing its database, for the solves it claims "
                   "(default: host name/listen address)",
                   [](DaemonConfig& c) -> std::string& { return c.server.sessions.replica_id; }),
      DurationOption(
          "solve_lease", "IMUCALD_SOLVE_LEASE",
          "how long a solve's claim holds without renewal (renewed every third of "
          "it); a lapsed one is claimed and run again by a server sharing the "
          "database (default 30s)",
          [](DaemonConfig& c) -> absl::Duration& { return c.server.sessions.solve_lease; }),
      DurationOption(
          "stream_lease", "IMUCALD_STREAM_LEASE",
          "how long a device's claim to its one sample stream holds without renewal "
          "(renewed every third of it); a server that dies holding one keeps the "
          "device from streaming through the others for up to this long "
          "(default 10s)",
          [](DaemonConfig& c) -> absl::Duration& { return c.server.sessions.stream_lease; }),
      IntegerOption<int>(
          "max_solve_attempts", "IMUCALD_MAX_SOLVE_ATTEMPTS",
          "servers that may start one solve: one whose server stops (killed, crashed) is run "
          "again by another, or by the same one restarted, until this many have; then it is "
          "failed and its session reopened (default 3)",
          1, 100, [](DaemonConfig& c) -> int& { return c.server.sessions.max_solve_attempts; }),
  };
}

// The server at work: other servers' changes, the database's pings, shutdown, logs and
// connections.
std::vector<ConfigOption> RunOptions() {
  return {
      DurationOption("active_cache_sync", "IMUCALD_ACTIVE_CACHE_SYNC",
                     "SQLite shared by several servers: how often the database is read for the "
                     "others' promotes and rollbacks (the bound on a stale fetch from this "
                     "server); 0s: never, when it is alone on its database (default 250ms). "
                     "PostgreSQL: not used (changes are heard as they commit)",
                     [](DaemonConfig& c) -> absl::Duration& { return c.server.active_cache_sync; }),
      DurationOption("database_ping", "IMUCALD_DATABASE_PING",
                     "how often the database is pinged: health answers NOT_SERVING from the "
                     "first ping that cannot reach it until one does again, parameter fetches "
                     "are answered from the cache meanwhile (default 1s)",
                     [](DaemonConfig& c) -> absl::Duration& { return c.server.database_ping; }),
      DurationOption("drain_deadline", "IMUCALD_DRAIN_DEADLINE",
                     "on SIGTERM, how long in-flight calls may run before they are cancelled "
                     "(default 30s); queued solves then finish",
                     [](DaemonConfig& c) -> absl::Duration& { return c.server.drain_deadline; }),
      ChoiceOption<LogFormat>("log_format", "IMUCALD_LOG_FORMAT", "json|text",
                              "log lines as JSON objects or logfmt text (default json)",
                              &ParseLogFormat,
                              [](DaemonConfig& c) -> LogFormat& { return c.log.format; }),
      ChoiceOption<LogLevel>("log_level", "IMUCALD_LOG_LEVEL", "debug|info|warning|error",
                             "least severe level logged; debug adds each robot's parameter "
                             "fetch (default info)",
                             &ParseLogLevel,
                             [](DaemonConfig& c) -> LogLevel& { return c.log.level; }),
      BoolOption("log_rpcs", "IMUCALD_LOG_RPCS",
                 "log each RPC's method, status code and duration (default true)",
                 [](DaemonConfig& c) -> bool& { return c.server.log_rpcs; }),
      IntegerOption<int>(
          "max_receive_message_bytes", "IMUCALD_MAX_RECEIVE_MESSAGE_BYTES",
          "largest request message taken, RESOURCE_EXHAUSTED above (default 4194304)", 1024,
          1 << 30, [](DaemonConfig& c) -> int& { return c.server.max_receive_message_bytes; }),
      DurationOption("keepalive_time", "IMUCALD_KEEPALIVE_TIME",
                     "ping a connection idle this long, to notice robots gone (default 30s)",
                     [](DaemonConfig& c) -> absl::Duration& { return c.server.keepalive_time; }),
      DurationOption("keepalive_timeout", "IMUCALD_KEEPALIVE_TIMEOUT",
                     "close a connection whose ping is not answered within this (default 10s)",
                     [](DaemonConfig& c) -> absl::Duration& { return c.server.keepalive_timeout; }),
  };
}

// Transport security and tokens (server/tls.h, server/auth.h; README "Security").
std::vector<ConfigOption> SecurityOptions() {
  return {
      StringOption("tls_cert", "IMUCALD_TLS_CERT", "PATH",
                   "PEM certificate (chain) the server presents; required unless insecure",
                   [](DaemonConfig& c) -> std::string& { return c.server.security.tls_cert_path; }),
      StringOption("tls_key", "IMUCALD_TLS_KEY", "PATH",
                   "PEM private key of tls_cert; required unless insecure",
                   [](DaemonConfig& c) -> std::string& { return c.server.security.tls_key_path; }),
      StringOption(
          "client_ca", "IMUCALD_CLIENT_CA", "PATH",
          "PEM CA of robots' client certificates: robots may then authenticate with one "
          "(common name = device id) instead of a token (default none)",
          [](DaemonConfig& c) -> std::string& { return c.server.security.client_ca_path; }),
      BoolOption("insecure", "IMUCALD_INSECURE",
                 "plaintext without authentication, refused unless listen is a loopback address; "
                 "for tests and development only (default false)",
                 [](DaemonConfig& c) -> bool& { return c.server.security.insecure; }),
      StringOption("admin_token_file", "IMUCALD_ADMIN_TOKEN_FILE", "PATH",
                   "where the first admin token is written (mode 0600) when the token table is "
                   "empty (default <db>.admin-token)",
                   [](DaemonConfig& c) -> std::string& { return c.server.admin_token_file; }),
  };
}

// Limits (README "## Robustness"; server/validate.h, SessionServiceOptions), and streams that
// hold a place without using it (SessionServiceOptions, stream_registry.h).
std::vector<ConfigOption> LimitOptions() {
  return {
      IntegerOption<int64_t>(
          "max_batch_samples", "IMUCALD_MAX_BATCH_SAMPLES",
          "samples in one SampleBatch; more are refused with RESOURCE_EXHAUSTED (default 20000)", 1,
          10'000'000,
          [](DaemonConfig& c) -> int64_t& { return c.server.sessions.ingest.max_batch_samples; }),
      IntegerOption<int64_t>(
          "max_session_samples", "IMUCALD_MAX_SESSION_SAMPLES",
          "samples one session may hold; more are refused with RESOURCE_EXHAUSTED "
          "(default 10000000)",
          1, int64_t{1} << 40,
          [](DaemonConfig& c) -> int64_t& { return c.server.sessions.ingest.max_session_samples; }),
      IntegerOption<int>(
          "max_streams_per_device", "IMUCALD_MAX_STREAMS_PER_DEVICE",
          "concurrent StreamSamples streams of one device; more are refused with "
          "RESOURCE_EXHAUSTED (default 1)",
          1, 1000,
          [](DaemonConfig& c) -> int& { return c.server.sessions.max_streams_per_device; }),
      IntegerOption<int>(
          "max_watchers_per_session", "IMUCALD_MAX_WATCHERS_PER_SESSION",
          "concurrent WatchSession streams of one session; more are refused with "
          "RESOURCE_EXHAUSTED (default 16)",
          1, 100000,
          [](DaemonConfig& c) -> int& { return c.server.sessions.max_watchers_per_session; }),
      // Streams that hold a place without using it (SessionServiceOptions, stream_registry.h).
      IntegerOption<int>(
          "max_streams", "IMUCALD_MAX_STREAMS",
          "StreamSamples, WatchSession and ReadSamples calls open on the server at once, counted "
          "from the "
          "moment they open; more are refused with RESOURCE_EXHAUSTED (default 10000)",
          1, 1000000, [](DaemonConfig& c) -> int& { return c.server.sessions.max_streams; }),
      IntegerOption<int>(
          "max_streams_per_token", "IMUCALD_MAX_STREAMS_PER_TOKEN",
          "StreamSamples, WatchSession and ReadSamples calls one token (or robot client "
          "certificate) may "
          "have open; more are refused with RESOURCE_EXHAUSTED (default 16)",
          1, 1000000,
          [](DaemonConfig& c) -> int& { return c.server.sessions.max_streams_per_token; }),
      DurationOption(
          "first_batch_timeout", "IMUCALD_FIRST_BATCH_TIMEOUT",
          "a sample stream that sends no batch this long after it opens is ended "
          "DEADLINE_EXCEEDED (default 30s)",
          [](DaemonConfig& c) -> absl::Duration& { return c.server.sessions.first_batch_timeout; }),
      DurationOption(
          "stream_idle_timeout", "IMUCALD_STREAM_IDLE_TIMEOUT",
          "a sample stream that sends no batch this long after an ack is ended "
          "DEADLINE_EXCEEDED; one that does not read its ack this long, or a ReadSamples "
          "that does not read its samples this long, is cancelled (default 1m)",
          [](DaemonConfig& c) -> absl::Duration& { return c.server.sessions.stream_idle_timeout; }),
      DurationOption(
          "watch_stall_timeout", "IMUCALD_WATCH_STALL_TIMEOUT",
          "a WatchSession whose client reads no event this long is cancelled and its "
          "slot freed (default 1m)",
          [](DaemonConfig& c) -> absl::Duration& { return c.server.sessions.watch_stall_timeout; }),
  };
}

// The table, in the order --help lists it: the groups above, one after the other.
std::vector<ConfigOption> BuildOptions() {
  std::vector<ConfigOption> options;
  for (std::vector<ConfigOption> group :
       {ServeOptions(), SolveOptions(), RunOptions(), SecurityOptions(), LimitOptions()}) {
    options.insert(options.end(), std::make_move_iterator(group.begin()),
                   std::make_move_iterator(group.end()));
  }
  return options;
}

std::string FlagOf(std::string_view key) {
  std::string flag = Cat("--", key);
  for (char& ch : flag) {
    if (ch == '_') ch = '-';
  }
  return flag;
}

const ConfigOption* FindByKey(std::string_view key) {
  for (const ConfigOption& option : ConfigOptions()) {
    if (option.key == key) return &option;
  }
  return nullptr;
}

std::string_view TomlTypeName(toml::node_type type) {
  switch (type) {
    case toml::node_type::table:
      return "a table";
    case toml::node_type::array:
      return "an array";
    case toml::node_type::string:
      return "a string";
    case toml::node_type::integer:
      return "an integer";
    case toml::node_type::floating_point:
      return "a float";
    case toml::node_type::boolean:
      return "a boolean";
    case toml::node_type::date:
      return "a date";
    case toml::node_type::time:
      return "a time";
    case toml::node_type::date_time:
      return "a date-time";
    default:
      return "nothing";
  }
}

// The option's value in the file as the text its parser takes, or what was expected instead.
absl::StatusOr<std::string> TomlValueText(const ConfigOption& option, const toml::node& node) {
  switch (option.type) {
    case OptionType::kString:
    case OptionType::kDuration:
      if (const auto* s = node.as_string()) return s->get();
      return absl::InvalidArgumentError(
          Cat("expected a string", option.type == OptionType::kDuration ? " such as \"30s\"" : "",
              ", got ", TomlTypeName(node.type())));
    case OptionType::kInteger:
      if (const auto* i = node.as_integer()) return Cat(static_cast<int64_t>(i->get()));
      return absl::InvalidArgumentError(
          Cat("expected an integer, got ", TomlTypeName(node.type())));
    case OptionType::kBoolean:
      if (const auto* b = node.as_boolean()) return std::string(b->get() ? "true" : "false");
      return absl::InvalidArgumentError(
          Cat("expected true or false, got ", TomlTypeName(node.type())));
  }
  return absl::InternalError("unknown option type");
}

std::string Where(const std::string& path, const toml::source_region& region) {
  return Cat(path, ":", static_cast<int64_t>(region.begin.line), ":",
             static_cast<int64_t>(region.begin.column));
}

}  // namespace

std::span<const ConfigOption> ConfigOptions() {
  static const std::vector<ConfigOption>* options = new std::vector<ConfigOption>(BuildOptions());
  return *options;
}

EnvLookup ProcessEnvironment() {
  return [](std::string_view name) -> std::optional<std::string> {
    const char* value = std::getenv(std::string(name).c_str());
    if (value == nullptr) return std::nullopt;
    return std::string(value);
  };
}

absl::Status ApplyConfigFile(const std::string& path, DaemonConfig& config) {
  {
    std::ifstream probe(path);
    if (!probe) {
      return absl::InvalidArgumentError(
          Cat("config file ", path, ": cannot read it: ", std::strerror(errno)));
    }
  }
  toml::table table;
  try {
    table = toml::parse_file(path);
  } catch (const toml::parse_error& e) {
    return absl::InvalidArgumentError(Cat(Where(path, e.source()), ": ", e.description()));
  }
  for (const auto& [key, node] : table) {
    const std::string where = Where(path, key.source());
    const ConfigOption* option = FindByKey(key.str());
    if (option == nullptr) {
      return absl::InvalidArgumentError(
          Cat(where, ": unknown key '", key.str(), "' (imucald --help lists the keys)"));
    }
    absl::StatusOr<std::string> text = TomlValueText(*option, node);
    absl::Status status = text.ok() ? option->set(*text, config) : text.status();
    if (!status.ok()) {
      return absl::InvalidArgumentError(Cat(where, ": ", key.str(), ": ", status.message()));
    }
  }
  config.config_path = path;
  return absl::OkStatus();
}

absl::StatusOr<LoadedConfig> LoadConfig(std::span<const std::string> args, const EnvLookup& env) {
  // The command line first (util/flags.h): the file named by --config is applied before any
  // flag. A BOOL option stands alone (true) or takes its value: "--insecure true" as --help
  // shows it ("--insecure BOOL"), or --insecure=false.
  std::set<std::string> valued = {"config"}, booleans;
  for (const ConfigOption& option : ConfigOptions()) {
    (option.type == OptionType::kBoolean ? booleans : valued).insert(FlagOf(option.key).substr(2));
  }
  absl::StatusOr<flags::Args> flags = flags::Args::Parse(
      std::vector<std::string>(args.begin(), args.end()), valued, {"help", "version"}, booleans);
  if (!flags.ok()) {
    const std::string message(flags.status().message());
    return absl::InvalidArgumentError(
        message.starts_with("unknown flag") ? Cat(message, " (imucald --help lists the flags)")
                                            : message);
  }
  if (!flags->positional().empty()) {
    return absl::InvalidArgumentError(Cat("unexpected argument '", flags->positional()[0],
                                          "' (imucald --help lists the commands)"));
  }
  LoadedConfig loaded;
  loaded.help = flags->Has("help");
  loaded.version = flags->Has("version");
  std::optional<std::string> config_path = flags->Get("config");
  if (!config_path.has_value()) config_path = env("IMUCALD_CONFIG");
  if (config_path.has_value()) {
    if (config_path->empty()) return absl::InvalidArgumentError("--config: empty path");
    if (absl::Status s = ApplyConfigFile(*config_path, loaded.config); !s.ok()) return s;
  }
  for (const ConfigOption& option : ConfigOptions()) {
    const std::optional<std::string> value = env(option.env);
    if (!value.has_value()) continue;
    if (absl::Status s = option.set(*value, loaded.config); !s.ok()) {
      return absl::InvalidArgumentError(Cat("environment ", option.env, ": ", s.message()));
    }
  }
  for (const ConfigOption& option : ConfigOptions()) {
    const std::string flag = FlagOf(option.key);
    const std::optional<std::string> value = flags->Get(flag.substr(2));
    if (!value.has_value()) continue;
    if (absl::Status s = option.set(*value, loaded.config); !s.ok()) {
      return absl::InvalidArgumentError(Cat(flag, ": ", s.message()));
    }
  }
  return loaded;
}

std::string HelpText() {
  std::string text =
      "imucald: the imucal calibration service (gRPC; state in one SQLite file, or in a\n"
      "PostgreSQL database that several replicas share)\n"
      "\n"
      "usage:\n"
      "  imucald [--config FILE] [OPTIONS]       serve until SIGTERM/SIGINT, then drain and exit "
      "0\n"
      "  imucald --version                      the version\n"
      "  imucald completion bash|zsh            a shell completion script (deploy/install.sh)\n"
      "  imucald --health-check HOST:PORT       exit 0 if the server there is SERVING, else 1\n"
      "  imucald backup --db PATH --out FILE    online backup of a live database\n"
      "  imucald restore --from FILE --db PATH  restore a backup (imucald must be stopped)\n"
      "  imucald migrate --from sqlite:PATH --to postgresql://URL\n"
      "                                        copy a SQLite site into an empty PostgreSQL "
      "database\n"
      "\n"
      "Settings are read from, later ones winning: built-in defaults, the TOML file\n"
      "(--config FILE, else $IMUCALD_CONFIG), the environment, the flags: --name value or\n"
      "--name=value; a BOOL flag alone means true. Each command takes -h/--help.\n"
      "\n"
      "options (flag / file key / environment variable):\n"
      "  --config FILE  (-)  IMUCALD_CONFIG\n"
      "      TOML file of the keys below (see deploy/imucald.toml)\n";
  for (const ConfigOption& option : ConfigOptions()) {
    AppendTo(&text, "  ", FlagOf(option.key), " ", option.value_name, "  ", option.key, "  ",
             option.env, "\n      ", option.help, "\n");
  }
  return text;
}

}  // namespace imucal::server
