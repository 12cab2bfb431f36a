// Starts the real imucald for end-to-end tests: a free loopback port, a fresh SQLite file in a
// temp directory, readiness by waiting for the channel to connect (no sleeps). The path of the
// binary comes from CMake (IMUCAL_IMUCALD_PATH) once the server target exists.
#ifndef IMUCAL_TESTS_CLIENT_IMUCALD_PROCESS_H_
#define IMUCAL_TESTS_CLIENT_IMUCALD_PROCESS_H_

#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <future>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "grpcpp/grpcpp.h"
#include "gtest/gtest.h"
#include "imucal/v1/imucal.grpc.pb.h"

namespace imucal::testing_util {

// A loopback port that was free a moment ago (the kernel's pick for port 0).
inline int FreeLoopbackPort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  addr.sin_port = 0;
  socklen_t len = sizeof addr;
  int port = 0;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0 &&
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len) == 0) {
    port = ntohs(addr.sin_port);
  }
  ::close(fd);
  return port;
}

inline constexpr bool kHaveImucald =
#ifdef IMUCAL_IMUCALD_PATH
    true;
#else
    false;
#endif

class ImucaldProcess {
 public:
  // Starts imucald with its database in `dir`; Unavailable if it does not come up in 20 s.
  // `extra_args` follow the standard ones (e.g. {"--drain-deadline", "1s"}).
  static absl::StatusOr<std::unique_ptr<ImucaldProcess>> Start(
      const std::string& dir, std::vector<std::string> extra_args = {}) {
    auto p = std::unique_ptr<ImucaldProcess>(new ImucaldProcess);
    p->db_path_ = (std::filesystem::path(dir) / "imucal.db").string();
    p->extra_args_ = std::move(extra_args);
    p->port_ = FreeLoopbackPort();
    if (absl::Status s = p->Launch(); !s.ok()) return s;
    return p;
  }
  // As Start, on an existing database: a file path or a postgresql:// URL (several processes
  // may share one: replicas).
  static absl::StatusOr<std::unique_ptr<ImucaldProcess>> StartOnDatabase(
      const std::string& db, std::vector<std::string> extra_args = {}) {
    auto p = std::unique_ptr<ImucaldProcess>(new ImucaldProcess);
    p->db_path_ = db;
    p->extra_args_ = std::move(extra_args);
    p->port_ = FreeLoopbackPort();
    if (absl::Status s = p->Launch(); !s.ok()) return s;
    return p;
  }
  ~ImucaldProcess() { Stop(SIGTERM); }

  std::string address() const { return absl::StrCat("127.0.0.1:", port_); }
  const std::string& db_path() const { return db_path_; }
  std::shared_ptr<grpc::Channel> NewChannel() const {
    // A channel of its own per call site: after a restart old channels reconnect lazily.
    grpc::ChannelArguments args;
    args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, 100);
    args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, 500);
    return grpc::CreateCustomChannel(address(), grpc::InsecureChannelCredentials(), args);
  }

  // Stops the server (SIGKILL: as a crash or power cut would) and starts it again on the same
  // port and database.
  absl::Status Restart() {
    Stop(SIGKILL);
    return Launch();
  }
  // Starts it again after a Stop(), on the same port and database (an outage of any length).
  absl::Status Relaunch() { return Launch(); }
  void Stop(int signal) {
    if (pid_ <= 0) return;
    ::kill(pid_, signal);
    int status = 0;
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
  }
  // Sends `signal` and waits at most `timeout` for imucald to exit. Returns its wait status
  // (WIFEXITED, WEXITSTATUS), or DeadlineExceeded after which it is SIGKILLed. Either way it
  // has stopped: Restart() starts it again on the same port and database.
  absl::StatusOr<int> SignalAndWait(int signal, std::chrono::milliseconds timeout) {
    if (pid_ <= 0) return absl::FailedPreconditionError("imucald is not running");
    const pid_t pid = pid_;
    pid_ = -1;
    std::future<int> exited = std::async(std::launch::async, [pid] {
      int status = 0;
      ::waitpid(pid, &status, 0);
      return status;
    });
    ::kill(pid, signal);
    if (exited.wait_for(timeout) == std::future_status::ready) return exited.get();
    ::kill(pid, SIGKILL);
    exited.wait();
    return absl::DeadlineExceededError(
        absl::StrCat("imucald did not exit within ", timeout.count(), " ms of signal ", signal));
  }

 private:
  ImucaldProcess() = default;

  absl::Status Launch() {
#ifdef IMUCAL_IMUCALD_PATH
    const std::string listen = address();
    // Plaintext on loopback without tokens: these tests are not about authentication
    // (auth_matrix_test is). Built before fork: the child only execs.
    std::vector<const char*> argv = {IMUCAL_IMUCALD_PATH, "--listen",  listen.c_str(), "--db",
                                     db_path_.c_str(),    "--insecure"};
    for (const std::string& arg : extra_args_) argv.push_back(arg.c_str());
    argv.push_back(nullptr);
    pid_ = ::fork();
    if (pid_ == 0) {
      ::execv(IMUCAL_IMUCALD_PATH, const_cast<char* const*>(argv.data()));
      ::_exit(127);
    }
    if (pid_ < 0) return absl::InternalError("fork failed");
    // The readiness probe gets a connection of its own: through the subchannel it would share
    // with channels to the killed server, it once (in a few hundred crash_test restarts) never
    // saw the new server READY in 20 s while other channels were using it.
    grpc::ChannelArguments args;
    args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
    args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, 100);
    args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, 500);
    auto channel = grpc::CreateCustomChannel(listen, grpc::InsecureChannelCredentials(), args);
    if (!channel->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(20))) {
      Stop(SIGKILL);
      return absl::UnavailableError(absl::StrCat("imucald did not listen on ", listen));
    }
    return absl::OkStatus();
#else
    return absl::UnimplementedError("imucald is not built");
#endif
  }

  std::string db_path_;
  std::vector<std::string> extra_args_;
  int port_ = 0;
  pid_t pid_ = -1;
};

// Registers `device` (200 Hz, m/s^2 and rad/s) and opens a session of `protocol` for it on
// `channel`; the session's id, or "" (with a test failure) when either call fails.
inline std::string RegisterAndOpenSession(const std::shared_ptr<grpc::Channel>& channel,
                                          const std::string& device,
                                          imucal::v1::Protocol protocol) {
  imucal::v1::RegisterDeviceRequest reg;
  reg.mutable_device()->set_id(device);
  reg.mutable_device()->set_sensor_model("sim");
  reg.mutable_device()->set_nominal_rate_hz(200);
  reg.mutable_device()->set_accel_unit("m/s^2");
  reg.mutable_device()->set_gyro_unit("rad/s");
  imucal::v1::Device d;
  grpc::ClientContext c1;
  grpc::Status s = imucal::v1::DeviceService::NewStub(channel)->RegisterDevice(&c1, reg, &d);
  EXPECT_TRUE(s.ok()) << s.error_message();
  imucal::v1::CreateSessionRequest create;
  create.set_device_id(device);
  create.set_protocol(protocol);
  imucal::v1::Session session;
  grpc::ClientContext c2;
  s = imucal::v1::SessionService::NewStub(channel)->CreateSession(&c2, create, &session);
  EXPECT_TRUE(s.ok()) << s.error_message();
  return s.ok() ? session.id() : "";
}

// A test against a real imucald with its database in a fresh per-test directory (skipped when
// imucald is not built). `prefix` names the directory, e.g. "imucal_uploader_test".
class ImucaldTest : public ::testing::Test {
 protected:
  explicit ImucaldTest(std::string prefix, std::vector<std::string> extra_args = {})
      : prefix_(std::move(prefix)), extra_args_(std::move(extra_args)) {}
  void SetUp() override {
    if (!kHaveImucald) GTEST_SKIP() << "imucald is not built yet";
    dir_ =
        std::filesystem::path(::testing::TempDir()) /
        absl::StrCat(prefix_, "_", ::testing::UnitTest::GetInstance()->current_test_info()->name(),
                     "_", ::getpid());
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
    auto server = ImucaldProcess::Start(dir_.string(), extra_args_);
    ASSERT_TRUE(server.ok()) << server.status();
    server_ = *std::move(server);
  }
  void TearDown() override {
    server_.reset();
    if (!dir_.empty()) std::filesystem::remove_all(dir_);
  }

  std::filesystem::path dir_;
  std::unique_ptr<ImucaldProcess> server_;

 private:
  std::string prefix_;
  std::vector<std::string> extra_args_;
};

}  // namespace imucal::testing_util

#endif  // IMUCAL_TESTS_CLIENT_IMUCALD_PROCESS_H_
