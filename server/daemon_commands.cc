#include "server/daemon_commands.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <future>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <system_error>
#include <vector>

#include "absl/strings/numbers.h"
#include "grpcpp/generic/generic_stub.h"
#include "grpcpp/grpcpp.h"
#include "grpcpp/security/credentials.h"
#include "server/config.h"
#include "storage/backup.h"
#include "storage/copy.h"
#include "util/db.h"
#include "util/flags.h"
#include "util/str_util.h"

namespace imucal::server {
namespace {

constexpr char kBackupPrefix[] = "imucal-";
constexpr char kBackupSuffix[] = ".db";

// Each command's flags (without "--"): the parsers below and the completion scripts read these.
const std::set<std::string> kHealthCheckValued = {"config", "ca-cert", "ca", "server-name",
                                                  "timeout"};
const std::set<std::string> kHealthCheckSwitches = {"insecure"};
const std::set<std::string> kBackupValued = {"db", "config", "out", "out-dir", "keep"};
const std::set<std::string> kRestoreValued = {"from", "db", "config"};
const std::set<std::string> kMigrateValued = {"from", "to"};

constexpr char kSqliteScheme[] = "sqlite:";

// A subcommand's flags (util/flags.h): `valued` take a value, `switches` do not; -h/--help too.
absl::StatusOr<flags::Args> ParseFlags(std::span<const std::string> args,
                                       const std::set<std::string>& valued,
                                       std::set<std::string> switches = {}) {
  switches.insert("help");
  return flags::Args::Parse(std::vector<std::string>(args.begin(), args.end()), valued, switches);
}

int Fail(std::string_view command, const absl::Status& status) {
  std::fprintf(stderr, "imucald %.*s: %.*s\n", static_cast<int>(command.size()), command.data(),
               static_cast<int>(status.message().size()), status.message().data());
  return 1;
}

int Help(const char* usage) {
  std::printf("usage: %s\n", usage);
  return 0;
}

int UsageError(std::string_view command, const absl::Status& status, const char* usage) {
  Fail(command, status);
  std::fprintf(stderr, "usage: %s\n", usage);
  return 2;
}

// --db, else the database the configuration names (--config, $IMUCALD_CONFIG, $IMUCALD_DB).
absl::StatusOr<std::string> DatabasePath(const flags::Args& flags) {
  if (auto db = flags.Get("db")) return *db;
  std::vector<std::string> args;
  if (auto config = flags.Get("config")) args = {"--config", *config};
  absl::StatusOr<LoadedConfig> loaded = LoadConfig(args, ProcessEnvironment());
  if (!loaded.ok()) return loaded.status();
  return loaded->config.server.db_path;
}

std::string Describe(const storage::DatabaseInfo& info) {
  return Cat("schema version ", info.schema_version, ", ", info.page_count * info.page_size_bytes,
             " bytes, ", info.devices, " devices, ", info.param_versions, " parameter versions");
}

std::string BackupFileName(absl::Time now) {
  return Cat(kBackupPrefix, absl::FormatTime("%Y%m%dT%H%M%E3SZ", now, absl::UTCTimeZone()),
             kBackupSuffix);
}

// The address to probe a server listening on `listen` at: a wildcard host becomes loopback.
std::string ProbeAddress(const std::string& listen) {
  const size_t colon = listen.rfind(':');
  if (colon == std::string::npos) return listen;
  const std::string host = listen.substr(0, colon);
  if (host.empty() || host == "0.0.0.0") return Cat("127.0.0.1", listen.substr(colon));
  if (host == "[::]" || host == "::") return Cat("[::1]", listen.substr(colon));
  return listen;
}

}  // namespace

absl::Status CheckHealth(const std::string& address, const HealthCheckOptions& options) {
  std::shared_ptr<grpc::ChannelCredentials> credentials;
  if (options.insecure) {
    credentials = grpc::InsecureChannelCredentials();
  } else {
    grpc::SslCredentialsOptions ssl;
    if (!options.ca_path.empty()) {
      std::ifstream in(options.ca_path);
      if (!in) return absl::InvalidArgumentError(Cat("--ca-cert: cannot read ", options.ca_path));
      std::stringstream pem;
      pem << in.rdbuf();
      ssl.pem_root_certs = pem.str();
    }
    credentials = grpc::SslCredentials(ssl);
  }
  grpc::ChannelArguments args;
  if (!options.server_name.empty()) {
    args.SetSslTargetNameOverride(options.server_name);
  }
  auto channel = grpc::CreateCustomChannel(address, credentials, args);
  grpc::GenericStub stub(channel);
  grpc::Slice empty("");  // HealthCheckRequest{service: ""}: the whole server, zero bytes
  grpc::ByteBuffer request(&empty, 1);
  grpc::ByteBuffer response;
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() +
                       absl::ToChronoMilliseconds(options.timeout));
  std::promise<grpc::Status> done;
  stub.UnaryCall(&context, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request, &response,
                 [&done](grpc::Status status) { done.set_value(std::move(status)); });
  const grpc::Status status = done.get_future().get();
  if (!status.ok()) {
    return absl::UnavailableError(Cat(address, ": health check failed: ", status.error_message(),
                                      " (code ", static_cast<int>(status.error_code()), ")"));
  }
  std::vector<grpc::Slice> slices;
  std::string bytes;
  if (response.Dump(&slices).ok()) {
    for (const grpc::Slice& s : slices) {
      bytes.append(reinterpret_cast<const char*>(s.begin()), s.size());
    }
  }
  // HealthCheckResponse{status = 1}: field 1, varint. Absent means UNKNOWN (0).
  const int serving_status = bytes.size() == 2 && bytes[0] == 0x08 ? bytes[1] : 0;
  if (serving_status == 1) return absl::OkStatus();
  static constexpr const char* kNames[] = {"UNKNOWN", "SERVING", "NOT_SERVING", "SERVICE_UNKNOWN"};
  const char* name = serving_status >= 0 && serving_status < 4 ? kNames[serving_status] : "?";
  return absl::UnavailableError(Cat(address, ": ", name));
}

int RunHealthCheckCommand(std::span<const std::string> args) {
  constexpr char kUsage[] =
      "imucald --health-check [HOST:PORT] [--config FILE] [--ca-cert FILE] [--server-name NAME] "
      "[--insecure] [--timeout 5s]";
  absl::StatusOr<flags::Args> flags = ParseFlags(args, kHealthCheckValued, kHealthCheckSwitches);
  if (!flags.ok()) return UsageError("--health-check", flags.status(), kUsage);
  if (flags->Has("help")) return Help(kUsage);
  if (flags->positional().size() > 1) {
    return UsageError("--health-check",
                      absl::InvalidArgumentError(
                          Cat("one HOST:PORT, got '", flags->positional()[1], "' as well")),
                      kUsage);
  }
  std::string address = flags->positional().empty() ? "" : flags->positional()[0];
  HealthCheckOptions options;
  if (auto timeout = flags->Get("timeout")) {
    if (!absl::ParseDuration(*timeout, &options.timeout) ||
        options.timeout <= absl::ZeroDuration()) {
      return UsageError(
          "--health-check",
          absl::InvalidArgumentError(
              Cat("--timeout: expected a positive duration such as 5s, got '", *timeout, "'")),
          kUsage);
    }
  }
  // The rest comes from the configuration imucald itself reads (file, environment).
  std::vector<std::string> config_args;
  if (auto config = flags->Get("config")) config_args = {"--config", *config};
  absl::StatusOr<LoadedConfig> loaded = LoadConfig(config_args, ProcessEnvironment());
  if (!loaded.ok()) return Fail("--health-check", loaded.status());
  const ServerOptions& server = loaded->config.server;
  if (address.empty()) address = ProbeAddress(server.listen);
  options.insecure = flags->Has("insecure") || server.security.insecure;
  options.ca_path = server.security.tls_cert_path;
  // --ca-cert as the imucal CLI spells it; --ca, its first name, still works.
  for (const char* flag : {"ca", "ca-cert"})
    if (auto path = flags->Get(flag)) options.ca_path = *path;
  if (auto name = flags->Get("server-name")) options.server_name = *name;
  if (absl::Status s = CheckHealth(address, options); !s.ok()) return Fail("--health-check", s);
  std::printf("%s: SERVING\n", address.c_str());
  return 0;
}

absl::StatusOr<int> PruneBackups(const std::string& dir, int keep) {
  std::vector<std::filesystem::path> backups;
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator(dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (entry.is_regular_file() && name.starts_with(kBackupPrefix) &&
        name.ends_with(kBackupSuffix)) {
      backups.push_back(entry.path());
    }
  }
  if (ec) return absl::UnavailableError(Cat("list ", dir, ": ", ec.message()));
  // The names hold the UTC time as YYYYmmddTHHMMSS.sssZ: name order is time order.
  std::sort(backups.begin(), backups.end());
  int removed = 0;
  for (size_t i = 0; i + static_cast<size_t>(keep) < backups.size(); ++i) {
    if (!std::filesystem::remove(backups[i], ec) || ec) {
      return absl::UnavailableError(Cat("remove ", backups[i].string(), ": ", ec.message()));
    }
    ++removed;
  }
  return removed;
}

int RunBackupCommand(std::span<const std::string> args) {
  constexpr char kUsage[] =
      "imucald backup [--db PATH | --config FILE] (--out FILE | --out-dir DIR [--keep N])";
  absl::StatusOr<flags::Args> flags =
      ParseFlags(args, kBackupValued);
  if (!flags.ok()) return UsageError("backup", flags.status(), kUsage);
  if (flags->Has("help")) return Help(kUsage);
  if (!flags->positional().empty()) {
    return UsageError(
        "backup", absl::InvalidArgumentError(Cat("unexpected '", flags->positional()[0], "'")),
        kUsage);
  }
  const bool to_file = flags->Has("out");
  const bool to_dir = flags->Has("out-dir");
  if (to_file == to_dir) {
    return UsageError("backup", absl::InvalidArgumentError("give one of --out and --out-dir"),
                      kUsage);
  }
  int keep = 7;
  if (auto keep_text = flags->Get("keep")) {
    if (!to_dir || !absl::SimpleAtoi(*keep_text, &keep) || keep < 1) {
      return UsageError("backup",
                        absl::InvalidArgumentError(Cat("--keep: expected a count of at least 1 "
                                                       "with --out-dir, got '",
                                                       *keep_text, "'")),
                        kUsage);
    }
  }
  absl::StatusOr<std::string> db = DatabasePath(*flags);
  if (!db.ok()) return Fail("backup", db.status());
  std::string out;
  if (to_file) {
    out = *flags->Get("out");
  } else {
    std::error_code ec;
    std::filesystem::create_directories(*flags->Get("out-dir"), ec);
    if (ec)
      return Fail("backup",
                  absl::UnavailableError(Cat(*flags->Get("out-dir"), ": ", ec.message())));
    out = (std::filesystem::path(*flags->Get("out-dir")) / BackupFileName(absl::Now())).string();
  }
  absl::StatusOr<storage::DatabaseInfo> info = storage::BackupDatabase(*db, out);
  if (!info.ok()) return Fail("backup", info.status());
  std::printf("backup: %s -> %s (%s)\n", db->c_str(), out.c_str(), Describe(*info).c_str());
  if (to_dir) {
    absl::StatusOr<int> removed = PruneBackups(*flags->Get("out-dir"), keep);
    if (!removed.ok()) return Fail("backup", removed.status());
    if (*removed > 0) std::printf("backup: removed %d old backups (keeping %d)\n", *removed, keep);
  }
  return 0;
}

int RunRestoreCommand(std::span<const std::string> args) {
  constexpr char kUsage[] = "imucald restore --from FILE [--db PATH | --config FILE]";
  absl::StatusOr<flags::Args> flags = ParseFlags(args, kRestoreValued);
  if (!flags.ok()) return UsageError("restore", flags.status(), kUsage);
  if (flags->Has("help")) return Help(kUsage);
  if (!flags->positional().empty()) {
    return UsageError(
        "restore", absl::InvalidArgumentError(Cat("unexpected '", flags->positional()[0], "'")),
        kUsage);
  }
  if (!flags->Has("from")) {
    return UsageError("restore", absl::InvalidArgumentError("--from FILE is required"), kUsage);
  }
  absl::StatusOr<std::string> db = DatabasePath(*flags);
  if (!db.ok()) return Fail("restore", db.status());
  absl::StatusOr<storage::DatabaseInfo> info = storage::RestoreDatabase(*flags->Get("from"), *db);
  if (!info.ok()) return Fail("restore", info.status());
  std::printf("restore: %s -> %s (%s); the previous database, if any, is %s.pre-restore\n",
              flags->Get("from")->c_str(), db->c_str(), Describe(*info).c_str(), db->c_str());
  return 0;
}

// Prints what a copy is doing to stderr, at most every 2 seconds (a site of gigabytes takes
// minutes): the table, the phase and how far it is.
class MigrateProgress {
 public:
  void operator()(const storage::CopyProgress& p) {
    const absl::Time now = absl::Now();
    if (now - last_ < absl::Seconds(2)) return;
    last_ = now;
    std::fprintf(stderr, "migrate: %s %.*s: %lld of %lld rows\n", std::string(p.phase).c_str(),
                 static_cast<int>(p.table.size()), p.table.data(),
                 static_cast<long long>(p.rows_done), static_cast<long long>(p.rows_total));
  }

 private:
  absl::Time last_ = absl::Now();
};

void PrintCopyReport(const storage::CopyReport& report) {
  std::printf("  %-16s %12s %16s  %s\n", "table", "rows", "bytes", "sha256 (first 16)");
  for (const storage::TableCopyReport& t : report.tables) {
    std::printf("  %-16s %12lld %16lld  %s\n", t.table.c_str(), static_cast<long long>(t.rows),
                static_cast<long long>(t.bytes), t.sha256_hex.substr(0, 16).c_str());
  }
  std::printf("  %-16s %12lld %16lld\n", "total", static_cast<long long>(report.rows()),
              static_cast<long long>(report.bytes()));
}

struct MigrateArgs {
  std::string sqlite_path;
  std::string pg_url;
};

// --from sqlite:PATH (sqlite:///ABSOLUTE too, as in URLs) and --to postgresql://...;
// InvalidArgument naming the flag, the URL's password never repeated.
absl::StatusOr<MigrateArgs> MigrateArgsOf(const flags::Args& flags) {
  if (!flags.positional().empty()) {
    return absl::InvalidArgumentError(
        Cat("unexpected '", sql::RedactedLocation(flags.positional()[0]), "'"));
  }
  const std::optional<std::string> from = flags.Get("from");
  if (!from) return absl::InvalidArgumentError("--from sqlite:PATH is required (the file to copy)");
  MigrateArgs args;
  if (from->starts_with(kSqliteScheme)) args.sqlite_path = from->substr(std::strlen(kSqliteScheme));
  // "sqlite://name" would be a host, not a file: only sqlite:///absolute/path is a URL form.
  if (args.sqlite_path.starts_with("///")) args.sqlite_path.erase(0, 2);
  if (args.sqlite_path.empty() || args.sqlite_path.starts_with("//")) {
    return absl::InvalidArgumentError(
        Cat("--from: expected sqlite:PATH (the SQLite file to copy, e.g. "
            "sqlite:/var/lib/imucald/imucal.db), got '",
            sql::RedactedLocation(*from), "'"));
  }
  const std::optional<std::string> to = flags.Get("to");
  if (!to) {
    return absl::InvalidArgumentError(
        "--to postgresql://... is required (the database to copy into)");
  }
  if (!sql::IsPostgresUrl(*to)) {
    return absl::InvalidArgumentError(
        Cat("--to: expected a postgresql:// URL (the database to copy into), got '",
            sql::RedactedLocation(*to), "'"));
  }
  args.pg_url = *to;
  return args;
}

int RunMigrateCommand(std::span<const std::string> args) {
  constexpr char kUsage[] =
      "imucald migrate --from sqlite:PATH --to postgresql://USER[:PASSWORD]@HOST[:PORT]/DB";
  absl::StatusOr<flags::Args> flags = ParseFlags(args, kMigrateValued);
  if (!flags.ok()) return UsageError("migrate", flags.status(), kUsage);
  if (flags->Has("help")) return Help(kUsage);
  absl::StatusOr<MigrateArgs> migrate = MigrateArgsOf(*flags);
  if (!migrate.ok()) return UsageError("migrate", migrate.status(), kUsage);
  const std::string dest = sql::RedactedLocation(migrate->pg_url);
  std::printf(
      "migrate: sqlite:%s -> %s\n"
      "migrate: the copy is one consistent snapshot (one read transaction on the file): what "
      "imucald writes after it begins is not copied, so stop imucald before moving a site\n",
      migrate->sqlite_path.c_str(), dest.c_str());
  std::fflush(stdout);
  MigrateProgress progress;
  absl::StatusOr<storage::CopyReport> report =
      storage::CopySqliteToPostgres(migrate->sqlite_path, migrate->pg_url, std::ref(progress));
  if (!report.ok()) return Fail("migrate", report.status());
  PrintCopyReport(*report);
  const double seconds = absl::ToDoubleSeconds(report->took);
  const double mb = static_cast<double>(report->bytes()) / 1e6;
  std::printf(
      "migrate: done in %.1f s (%.1f MB, %.1f MB/s); every table read back from PostgreSQL has "
      "the snapshot's row count and SHA-256\n"
      "migrate: next: serve from it (db = \"%s\"); the SQLite file is unchanged\n",
      seconds, mb, seconds > 0 ? mb / seconds : 0.0, dest.c_str());
  return 0;
}

namespace {

// The completion scripts around the lists of DaemonCompletion: `flags` and `valued` (the serve
// options, and those of them that take a value), `cases` (one `case` line per command).
std::string BashCompletion(const std::string& flags, const std::string& valued,
                           const std::string& cases) {
  return Cat(
      "# bash completion for imucald: generated by `imucald completion bash` from its own\n"
      "# option table (server/config.cc, server/daemon_commands.cc). Installed by\n"
      "# deploy/install.sh.\n"
      "_imucald() {\n"
      "  local cur=${COMP_WORDS[COMP_CWORD]} prev=${COMP_WORDS[COMP_CWORD-1]}\n"
      "  local flags=\"",
      flags, "\" valued=\"", valued,
      "\"\n"
      "  case ${COMP_WORDS[1]} in\n",
      cases,
      "  esac\n"
      "  if [[ \" $valued \" == *\" $prev \"* ]]; then\n"
      "    COMPREPLY=($(compgen -f -- \"$cur\"))\n"
      "  elif [[ $COMP_CWORD -eq 1 && $cur != -* ]]; then\n"
      "    COMPREPLY=($(compgen -W \"backup restore migrate completion\" -- \"$cur\"))\n"
      "  elif [[ ${COMP_WORDS[1]} == completion ]]; then\n"
      "    COMPREPLY=($(compgen -W \"bash zsh\" -- \"$cur\"))\n"
      "  else\n"
      "    COMPREPLY=($(compgen -W \"$flags\" -- \"$cur\"))\n"
      "  fi\n"
      "}\n"
      "complete -o filenames -F _imucald imucald\n");
}

std::string ZshCompletion(const std::string& flags, const std::string& valued,
                          const std::string& cases) {
  return Cat(
      "#compdef imucald\n"
      "# zsh completion for imucald: generated by `imucald completion zsh` from its own option\n"
      "# table (server/config.cc, server/daemon_commands.cc). Installed by deploy/install.sh.\n"
      "_imucald() {\n"
      "  local -a flags valued\n"
      "  flags=(",
      flags, ")\n  valued=(", valued,
      ")\n"
      "  case $words[2] in\n",
      cases,
      "  esac\n"
      "  if (( ${valued[(Ie)$words[CURRENT-1]]} )); then\n"
      "    _files\n"
      "  elif (( CURRENT == 2 )) && [[ $PREFIX != -* ]]; then\n"
      "    compadd -- backup restore migrate completion\n"
      "  elif [[ $words[2] == completion ]]; then\n"
      "    compadd -- bash zsh\n"
      "  else\n"
      "    compadd -- $flags\n"
      "  fi\n"
      "}\n"
      "_imucald \"$@\"\n");
}

}  // namespace

std::string DaemonCompletion(std::string_view shell) {
  // What each word offers: the serve options (config.h's table) at the top, each command's own
  // flags after it; every flag but the switches takes a file-like value.
  std::set<std::string> serve = {"--config", "--help", "--version", "--health-check"};
  std::set<std::string> serve_valued = {"--config"};
  for (const ConfigOption& option : ConfigOptions()) {
    std::string flag = Cat("--", option.key);
    std::replace(flag.begin(), flag.end(), '_', '-');
    serve.insert(flag);
    if (option.type != OptionType::kBoolean) serve_valued.insert(flag);
  }
  const auto dashed = [](const std::set<std::string>& names) {
    std::set<std::string> flags = {"--help"};
    for (const std::string& name : names) flags.insert("--" + name);
    return flags;
  };
  struct Word {
    std::string_view word;
    std::set<std::string> flags, valued;
  };
  std::set<std::string> health = dashed(kHealthCheckValued);
  health.insert("--insecure");
  const std::vector<Word> words = {
      {"--health-check", health, dashed(kHealthCheckValued)},
      {"backup", dashed(kBackupValued), dashed(kBackupValued)},
      {"restore", dashed(kRestoreValued), dashed(kRestoreValued)},
      {"migrate", dashed(kMigrateValued), dashed(kMigrateValued)},
  };
  // One `case` line a word: the lists in the shell's syntax, "..." for bash, (...) for zsh.
  const auto cases = [&](std::string_view open, std::string_view close) {
    std::string text;
    for (const Word& w : words) {
      AppendTo(&text, "    ", w.word, ") flags=", open, Join(w.flags, " "), close, " valued=", open,
               Join(w.valued, " "), close, " ;;\n");
    }
    return text;
  };
  if (shell == "bash") {
    return BashCompletion(Join(serve, " "), Join(serve_valued, " "), cases("\"", "\""));
  }
  if (shell == "zsh")
    return ZshCompletion(Join(serve, " "), Join(serve_valued, " "), cases("(", ")"));
  return "";
}

}  // namespace imucal::server
