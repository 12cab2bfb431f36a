// What the service benchmarks share: a real imucald server in a forked child (ingest_bench,
// fetch_bench; several of them on one database with --replicas) or the imucald binary in a
// process of its own (load_bench, misuse_bench, outage_bench), so client and server CPU and
// memory are measured apart; CPU and load accounting (a local PostgreSQL's too), percentiles;
// connections of their own, the TLS set-up's certificate and admin token, the bench device.
#ifndef IMUCAL_BENCH_SERVICE_BENCH_UTIL_H_
#define IMUCAL_BENCH_SERVICE_BENCH_UTIL_H_

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <sched.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "core/simulator.h"
#include "grpcpp/grpcpp.h"
#include "server/server.h"
#include "storage/pg_db.h"
#include "storage/types.h"
#include "util/db.h"

namespace imucal::bench {

// ---- The samples: one simulated capture as flat columns, replayed lap after lap.
struct Columns {
  std::vector<double> t, accel, gyro, temp;
  size_t n = 0;
  double lap_s = 0;  // time shift per lap
};

// The capture `o` simulates, as columns; exits with the simulator's message if it fails.
inline Columns MakeColumns(const core::SimOptions& o) {
  absl::StatusOr<core::SimResult> sim = core::Simulate(o);
  if (!sim.ok()) {
    std::fprintf(stderr, "simulate: %s\n", std::string(sim.status().message()).c_str());
    std::exit(1);
  }
  const core::Capture& c = sim->capture;
  Columns col;
  col.n = c.size();
  for (size_t i = 0; i < c.size(); ++i) {
    col.t.push_back(c.t_s[i]);
    for (int k = 0; k < 3; ++k) {
      col.accel.push_back(c.accel[i](k));
      col.gyro.push_back(c.gyro[i](k));
    }
    col.temp.push_back(c.has_temp() ? c.temp[i] : 25.0);
  }
  col.lap_s = c.t_s.back() - c.t_s.front() + 1.0 / o.rate_hz;
  return col;
}

using Clock = std::chrono::steady_clock;

inline double Seconds(Clock::duration d) { return std::chrono::duration<double>(d).count(); }

// CPU seconds (user + system) of this process.
inline double SelfCpuS() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_utime.tv_sec + u.ru_stime.tv_sec + 1e-6 * (u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

// Fields 3.. of /proc/PID/stat (after "pid (comm) "): [0] is field 3 (state), [1] field 4
// (ppid), [11]/[12] fields 14/15 (utime/stime), [13]/[14] fields 16/17 (cutime/cstime, the
// reaped children's). Empty if the process is gone.
inline std::vector<std::string> ProcStatFields(pid_t pid) {
  std::ifstream f("/proc/" + std::to_string(pid) + "/stat");
  std::string s((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  const size_t close_paren = s.rfind(')');
  if (close_paren == std::string::npos || close_paren + 2 > s.size()) return {};
  std::istringstream rest(s.substr(close_paren + 2));
  std::vector<std::string> fields;
  for (std::string field; fields.size() < 15 && rest >> field;) fields.push_back(field);
  return fields;
}

// CPU seconds (utime + stime, fields 14 and 15 of /proc/PID/stat) of another process; with
// `reaped_children`, also those of its children it has waited for (cutime + cstime).
inline double ProcCpuS(pid_t pid, bool reaped_children = false) {
  const std::vector<std::string> f = ProcStatFields(pid);
  if (f.size() < 15) return 0;
  double ticks = std::atof(f[11].c_str()) + std::atof(f[12].c_str());
  if (reaped_children) ticks += std::atof(f[13].c_str()) + std::atof(f[14].c_str());
  return ticks / static_cast<double>(sysconf(_SC_CLK_TCK));
}

inline std::string LoadAvg() {
  std::ifstream f("/proc/loadavg");
  std::string a, b, c;
  f >> a >> b >> c;
  return a + " " + b + " " + c;
}

// The p-quantile (0..1) by partial sort; 0 for no samples.
inline double Percentile(std::vector<double>& v, double p) {
  if (v.empty()) return 0;
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(p * static_cast<double>(v.size())));
  std::nth_element(v.begin(), v.begin() + static_cast<long>(k), v.end());
  return v[k];
}

// Pins the calling process (all its threads created afterwards, and the children it forks) to
// one CPU; cpu < 0 leaves it alone. For measuring the server and the load client on separate
// cores of a small machine.
inline void PinToCpu(int cpu) {
  if (cpu < 0) return;
  cpu_set_t set;
  CPU_ZERO(&set);
  CPU_SET(cpu, &set);
  if (sched_setaffinity(0, sizeof set, &set) != 0) std::perror("sched_setaffinity");
}

// imucald (server::Server) on 127.0.0.1:0 with its database at db_path (a SQLite file or a
// postgresql:// URL), in a child process (pinned to `cpu` when >= 0).
struct Child {
  pid_t pid = -1;
  int port = 0;
  int stop_fd = -1;  // closing it tells the child to shut down
};

// `metrics_listen`: ServerOptions::metrics_listen (empty: no metrics kept). `replica_id`: the
// server's name to the others on its database (empty: its default). `siblings`: servers forked
// before this one, whose stop pipes the child must not hold open (else closing one's stop_fd
// would not reach it).
inline Child ForkServer(const std::string& db_path, int cpu = -1,
                        const std::string& metrics_listen = "", const std::string& replica_id = "",
                        const std::vector<Child>& siblings = {}) {
  int port_pipe[2], stop_pipe[2];
  if (pipe(port_pipe) != 0 || pipe(stop_pipe) != 0) {
    std::perror("pipe");
    std::exit(1);
  }
  const pid_t pid = fork();
  if (pid < 0) {
    std::perror("fork");
    std::exit(1);
  }
  if (pid == 0) {
    close(port_pipe[0]);
    close(stop_pipe[1]);
    for (const Child& sibling : siblings) close(sibling.stop_fd);
    PinToCpu(cpu);
    server::ServerOptions options;
    options.listen = "127.0.0.1:0";
    options.security.insecure = true;  // plaintext on loopback, no tokens
    options.db_path = db_path;
    options.drain_deadline = absl::Seconds(5);
    options.metrics_listen = metrics_listen;
    options.sessions.replica_id = replica_id;
    absl::StatusOr<std::unique_ptr<server::Server>> server = server::Server::Start(options);
    const int port = server.ok() ? (*server)->port() : 0;
    if (!server.ok())
      std::fprintf(stderr, "server: %s\n", std::string(server.status().message()).c_str());
    if (write(port_pipe[1], &port, sizeof port) != sizeof port) _exit(1);
    close(port_pipe[1]);
    char c;
    while (read(stop_pipe[0], &c, 1) > 0) {
    }
    if (server.ok()) server->reset();  // ~Server: Shutdown (drains), checkpoint on close
    _exit(0);
  }
  close(port_pipe[1]);
  close(stop_pipe[0]);
  Child child;
  child.pid = pid;
  child.stop_fd = stop_pipe[1];
  if (read(port_pipe[0], &child.port, sizeof child.port) != sizeof child.port || child.port == 0) {
    std::fprintf(stderr, "the server did not start\n");
    std::exit(1);
  }
  close(port_pipe[0]);
  return child;
}

inline void StopServer(Child& child) {
  close(child.stop_fd);
  waitpid(child.pid, nullptr, 0);
}

// ---- Several servers on one database (--replicas; README "Several servers on one database").

// `replicas` servers (at least 1) on the database `db` (a SQLite file or a postgresql:// URL),
// forked one after another (the first applies the migrations), named "bench-1", "bench-2", ...
// as their replica_id, all pinned to `cpu` when >= 0. Fork them before any gRPC object exists
// in this process.
inline std::vector<Child> ForkServers(const std::string& db, int replicas, int cpu = -1,
                                      const std::string& metrics_listen = "") {
  std::vector<Child> servers;
  for (int i = 1; i <= std::max(1, replicas); ++i) {
    servers.push_back(ForkServer(db, cpu, metrics_listen, absl::StrCat("bench-", i), servers));
  }
  return servers;
}

// Stops them all at once (each drains meanwhile), then waits for each.
inline void StopServers(std::vector<Child>& servers) {
  for (Child& child : servers) close(child.stop_fd);
  for (Child& child : servers) waitpid(child.pid, nullptr, 0);
}

// Their CPU seconds, one entry per server.
inline std::vector<double> ServersCpuS(const std::vector<Child>& servers) {
  std::vector<double> cpu;
  for (const Child& child : servers) cpu.push_back(ProcCpuS(child.pid));
  return cpu;
}

inline double Sum(const std::vector<double>& v) {
  double sum = 0;
  for (double x : v) sum += x;
  return sum;
}

// A channel to `target` on a connection of its own: distinct channel args (its `index`) and a
// local subchannel pool keep gRPC from sharing one connection between channels.
inline std::shared_ptr<grpc::Channel> BenchChannel(
    const std::string& target, const std::shared_ptr<grpc::ChannelCredentials>& credentials,
    int index) {
  grpc::ChannelArguments args;
  args.SetInt("imucal.bench.channel", index);
  args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  return grpc::CreateCustomChannel(target, credentials, args);
}

// `per_server` HTTP/2 connections (at least 1) to each of `servers` on loopback, round robin:
// connection k goes to server k % servers.size(), so a client that spreads its calls or streams
// over the connections in turn spreads them evenly over the servers.
inline std::vector<std::shared_ptr<grpc::Channel>> RoundRobinChannels(
    const std::vector<Child>& servers, int per_server) {
  std::vector<std::shared_ptr<grpc::Channel>> channels;
  const int total = std::max(1, per_server) * static_cast<int>(servers.size());
  for (int k = 0; k < total; ++k) {
    channels.push_back(BenchChannel(
        absl::StrCat("127.0.0.1:", servers[static_cast<size_t>(k) % servers.size()].port),
        grpc::InsecureChannelCredentials(), k));
  }
  return channels;
}

// "SQLite file PATH" or "PostgreSQL URL" (without its password), for the bench's header line.
inline std::string DescribeDb(const std::string& db) {
  return sql::IsPostgresUrl(db) ? "PostgreSQL " + sql::RedactedLocation(db) : "SQLite file " + db;
}

// The CPU of a PostgreSQL cluster on this machine, for the database's share of a run: its
// postmaster is the parent of the backend that serves a connection to the URL; its CPU is the
// postmaster's own, that of its live children (the backends serving the servers, the WAL
// writer, the checkpointer, ...) and that of the children it has reaped (cutime, cstime: a
// backend that exited counts there). nullopt when the cluster is not on this machine or cannot
// be reached.
class PostgresCpu {
 public:
  static std::optional<PostgresCpu> Find(const std::string& url) {
    absl::StatusOr<std::unique_ptr<storage::PgConnection>> conn =
        storage::PgConnection::Open(url, {});
    if (!conn.ok()) return std::nullopt;
    absl::StatusOr<std::optional<int64_t>> backend =
        sql::ReadRow(**conn, "SELECT CAST(pg_backend_pid() AS BIGINT)", sql::FirstColumnInt64);
    if (!backend.ok() || !backend->has_value()) return std::nullopt;
    const std::vector<std::string> f = ProcStatFields(static_cast<pid_t>(**backend));
    if (f.size() < 2) return std::nullopt;  // not a process of this machine
    const pid_t postmaster = static_cast<pid_t>(std::atoll(f[1].c_str()));
    std::ifstream comm("/proc/" + std::to_string(postmaster) + "/comm");
    std::string name;
    if (!std::getline(comm, name) || name != "postgres") return std::nullopt;
    return PostgresCpu(postmaster);
  }

  pid_t postmaster() const { return postmaster_; }

  double CpuS() const {
    double cpu = ProcCpuS(postmaster_, /*reaped_children=*/true);
    std::error_code ec;
    for (const auto& entry : std::filesystem::directory_iterator("/proc", ec)) {
      const std::string name = entry.path().filename().string();
      if (name.empty() || !std::isdigit(static_cast<unsigned char>(name[0]))) continue;
      const pid_t pid = static_cast<pid_t>(std::atoll(name.c_str()));
      const std::vector<std::string> f = ProcStatFields(pid);
      if (f.size() >= 2 && std::atoll(f[1].c_str()) == postmaster_) cpu += ProcCpuS(pid);
    }
    return cpu;
  }

 private:
  explicit PostgresCpu(pid_t postmaster) : postmaster_(postmaster) {}
  pid_t postmaster_;
};

// ---- The real imucald binary in a process of its own (load_bench, misuse_bench,
// outage_bench): its CPU and memory are its own, and it can be killed and started again.

// A loopback port that was free a moment ago (the kernel's pick for port 0).
inline int FreeLoopbackPort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof addr;
  int port = 0;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0 &&
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len) == 0)
    port = ntohs(addr.sin_port);
  ::close(fd);
  return port;
}

// Whether something accepts TCP connections on 127.0.0.1:port now.
inline bool Listening(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  addr.sin_port = htons(static_cast<uint16_t>(port));
  const bool ok = ::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0;
  ::close(fd);
  return ok;
}

// fork + exec `imucald --listen LISTEN --db DB args...`, pinned to `cpu` when >= 0, its log
// (stderr) appended to `log_path` when given. The child only execs, so other threads of this
// process (gRPC's) may run meanwhile.
inline pid_t StartImucald(const std::string& imucald, const std::string& db,
                          const std::string& listen, const std::vector<std::string>& extra,
                          int cpu = -1, const std::string& log_path = "") {
  std::vector<std::string> args = {imucald, "--listen", listen, "--db", db};
  args.insert(args.end(), extra.begin(), extra.end());
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  const pid_t pid = fork();
  if (pid == 0) {
    PinToCpu(cpu);
    if (!log_path.empty()) {
      const int fd = ::open(log_path.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0600);
      if (fd >= 0) ::dup2(fd, STDERR_FILENO);
    }
    ::execv(imucald.c_str(), argv.data());
    std::perror("exec imucald");
    ::_exit(127);
  }
  return pid;
}

// A field of /proc/PID/status in kB ("VmHWM", "VmRSS"); 0 if absent.
inline int64_t ProcStatusKb(pid_t pid, const std::string& field) {
  std::ifstream f("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind(field + ":", 0) == 0) return std::atoll(line.c_str() + field.size() + 1);
  }
  return 0;
}

// A throwaway certificate for 127.0.0.1 in `dir` (the openssl CLI) and imucald's flags to
// serve it with its first admin token written to `token_file`; empty when openssl failed.
inline std::vector<std::string> TlsServerArgs(const std::string& dir,
                                              const std::string& token_file) {
  const std::string cert = dir + "/server.crt", key = dir + "/server.key";
  const std::string openssl =
      "openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 1 "
      "-subj /CN=localhost -addext subjectAltName=IP:127.0.0.1 -keyout '" +
      key + "' -out '" + cert + "' 2>/dev/null";
  if (std::system(openssl.c_str()) != 0) return {};
  return {"--tls-cert", cert, "--tls-key", key, "--admin-token-file", token_file};
}

// The SSL options that trust the certificate TlsServerArgs(dir, ...) made (dir/server.crt).
inline grpc::SslCredentialsOptions TrustBenchCertificate(const std::string& dir) {
  std::ifstream cert_in(dir + "/server.crt");
  grpc::SslCredentialsOptions ssl;
  ssl.pem_root_certs.assign(std::istreambuf_iterator<char>(cert_in),
                            std::istreambuf_iterator<char>());
  return ssl;
}

// imucald started with TlsServerArgs writes its first admin token before it listens: waits up
// to 60 s for a TLS connection to `listen` (without the token, which is a per-call credential)
// and then reads the token's file (its first line, empty if it has none). nullopt when imucald
// did not come up.
inline std::optional<std::string> AwaitAdminToken(const std::string& listen,
                                                  const grpc::SslCredentialsOptions& ssl,
                                                  const std::string& token_file) {
  auto probe = grpc::CreateChannel(listen, grpc::SslCredentials(ssl));
  if (!probe->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(60)))
    return std::nullopt;
  std::string token;
  std::getline(std::ifstream(token_file), token);
  return token;
}

// A storage device as the benches register them: an MPU-6050 at 200 Hz, in m/s^2 and rad/s.
inline storage::Device BenchDevice(const std::string& id) {
  storage::Device d;
  d.id = id;
  d.sensor_model = "MPU-6050";
  d.nominal_rate_hz = 200;
  d.accel_unit = "m/s^2";
  d.gyro_unit = "rad/s";
  return d;
}

}  // namespace imucal::bench

#endif  // IMUCAL_BENCH_SERVICE_BENCH_UTIL_H_
