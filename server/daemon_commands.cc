#include "server/daemon_commands.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <future>
#include <map>
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
#include "util/str_util.h"

namespace imucal::server {
namespace {

constexpr char kBackupPrefix[] = "imucal-";
constexpr char kBackupSuffix[] = ".db";

// "--name value" / "--name=value" pairs, each name from `allowed`; InvalidArgument otherwise.
absl::StatusOr<std::map<std::string, std::string>> ParseFlags(
    std::span<const std::string> args, const std::set<std::string>& allowed) {
  std::map<std::string, std::string> flags;
  for (size_t i = 0; i < args.size(); ++i) {
    std::string name = args[i];
    std::string value;
    if (const size_t eq = name.find('='); eq != std::string::npos) {
      value = name.substr(eq + 1);
      name.resize(eq);
    } else if (i + 1 < args.size()) {
      value = args[++i];
    } else {
      return absl::InvalidArgumentError(Cat(name, ": missing value"));
    }
    if (!allowed.contains(name)) {
      return absl::InvalidArgumentError(Cat("unknown flag ", name));
    }
    flags[name] = value;
  }
  return flags;
}

int Fail(std::string_view command, const absl::Status& status) {
  std::fprintf(stderr, "imucald %.*s: %.*s\n", static_cast<int>(command.size()), command.data(),
               static_cast<int>(status.message().size()), status.message().data());
  return 1;
}

int UsageError(std::string_view command, const absl::Status& status, const char* usage) {
  Fail(command, status);
  std::fprintf(stderr, "usage: %s\n", usage);
  return 2;
}

// --db, else the database the configuration names (--config, $IMUCALD_CONFIG, $IMUCALD_DB).
absl::StatusOr<std::string> DatabasePath(const std::map<std::string, std::string>& flags) {
  if (auto it = flags.find("--db"); it != flags.end()) return it->second;
  std::vector<std::string> args;
  if (auto it = flags.find("--config"); it != flags.end()) args = {"--config", it->second};
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
  std::string address;
  if (!args.empty() && !args[0].starts_with("-")) {
    address = args[0];
    args = args.subspan(1);
  }
  // --insecure takes no value: turn it into a pair for ParseFlags.
  std::vector<std::string> pairs;
  HealthCheckOptions options;
  bool insecure_flag = false;
  for (const std::string& arg : args) {
    if (arg == "--insecure") {
      insecure_flag = true;
    } else {
      pairs.push_back(arg);
    }
  }
  absl::StatusOr<std::map<std::string, std::string>> flags =
      ParseFlags(pairs, {"--config", "--ca-cert", "--ca", "--server-name", "--timeout"});
  if (!flags.ok()) return UsageError("--health-check", flags.status(), kUsage);
  if (auto it = flags->find("--timeout"); it != flags->end()) {
    if (!absl::ParseDuration(it->second, &options.timeout) ||
        options.timeout <= absl::ZeroDuration()) {
      return UsageError(
          "--health-check",
          absl::InvalidArgumentError(
              Cat("--timeout: expected a positive duration such as 5s, got '", it->second, "'")),
          kUsage);
    }
  }
  // The rest comes from the configuration imucald itself reads (file, environment).
  std::vector<std::string> config_args;
  if (auto it = flags->find("--config"); it != flags->end()) config_args = {"--config", it->second};
  absl::StatusOr<LoadedConfig> loaded = LoadConfig(config_args, ProcessEnvironment());
  if (!loaded.ok()) return Fail("--health-check", loaded.status());
  const ServerOptions& server = loaded->config.server;
  if (address.empty()) address = ProbeAddress(server.listen);
  options.insecure = insecure_flag || server.security.insecure;
  options.ca_path = server.security.tls_cert_path;
  // --ca-cert as the imucal CLI spells it; --ca, its first name, still works.
  for (const char* flag : {"--ca", "--ca-cert"})
    if (auto it = flags->find(flag); it != flags->end()) options.ca_path = it->second;
  if (auto it = flags->find("--server-name"); it != flags->end()) {
    options.server_name = it->second;
  }
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
  absl::StatusOr<std::map<std::string, std::string>> flags =
      ParseFlags(args, {"--db", "--config", "--out", "--out-dir", "--keep"});
  if (!flags.ok()) return UsageError("backup", flags.status(), kUsage);
  const bool to_file = flags->contains("--out");
  const bool to_dir = flags->contains("--out-dir");
  if (to_file == to_dir) {
    return UsageError("backup", absl::InvalidArgumentError("give one of --out and --out-dir"),
                      kUsage);
  }
  int keep = 7;
  if (auto it = flags->find("--keep"); it != flags->end()) {
    if (!to_dir || !absl::SimpleAtoi(it->second, &keep) || keep < 1) {
      return UsageError("backup",
                        absl::InvalidArgumentError(Cat("--keep: expected a count of at least 1 "
                                                       "with --out-dir, got '",
                                                       it->second, "'")),
                        kUsage);
    }
  }
  absl::StatusOr<std::string> db = DatabasePath(*flags);
  if (!db.ok()) return Fail("backup", db.status());
  std::string out;
  if (to_file) {
    out = flags->at("--out");
  } else {
    std::error_code ec;
    std::filesystem::create_directories(flags->at("--out-dir"), ec);
    if (ec)
      return Fail("backup",
                  absl::UnavailableError(Cat(flags->at("--out-dir"), ": ", ec.message())));
    out = (std::filesystem::path(flags->at("--out-dir")) / BackupFileName(absl::Now())).string();
  }
  absl::StatusOr<storage::DatabaseInfo> info = storage::BackupDatabase(*db, out);
  if (!info.ok()) return Fail("backup", info.status());
  std::printf("backup: %s -> %s (%s)\n", db->c_str(), out.c_str(), Describe(*info).c_str());
  if (to_dir) {
    absl::StatusOr<int> removed = PruneBackups(flags->at("--out-dir"), keep);
    if (!removed.ok()) return Fail("backup", removed.status());
    if (*removed > 0) std::printf("backup: removed %d old backups (keeping %d)\n", *removed, keep);
  }
  return 0;
}

int RunRestoreCommand(std::span<const std::string> args) {
  constexpr char kUsage[] = "imucald restore --from FILE [--db PATH | --config FILE]";
  absl::StatusOr<std::map<std::string, std::string>> flags =
      ParseFlags(args, {"--from", "--db", "--config"});
  if (!flags.ok()) return UsageError("restore", flags.status(), kUsage);
  if (!flags->contains("--from")) {
    return UsageError("restore", absl::InvalidArgumentError("--from FILE is required"), kUsage);
  }
  absl::StatusOr<std::string> db = DatabasePath(*flags);
  if (!db.ok()) return Fail("restore", db.status());
  absl::StatusOr<storage::DatabaseInfo> info = storage::RestoreDatabase(flags->at("--from"), *db);
  if (!info.ok()) return Fail("restore", info.status());
  std::printf("restore: %s -> %s (%s); the previous database, if any, is %s.pre-restore\n",
              flags->at("--from").c_str(), db->c_str(), Describe(*info).c_str(), db->c_str());
  return 0;
}

}  // namespace imucal::server
