// Structured logs (server/log.h): the line format, and the RPC interceptor on a real server on
// a loopback port (port 0) with a real SQLite file.
#include "server/log.h"

#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <future>
#include <mutex>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "grpcpp/generic/generic_stub.h"
#include "grpcpp/grpcpp.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "server/server.h"

namespace imucal::server {
namespace {

using ::testing::HasSubstr;

// absl::string_view (not std::) on this Debian: matchers want a std::string.
std::string Message(const absl::Status& s) { return std::string(s.message()); }

TEST(LogTest, JsonLinesAreOneObjectPerLineWithEscapedValues) {
  const absl::Time ts = absl::FromUnixMillis(1714564800123);  // 2024-05-01T12:00:00.123Z
  const std::string line = FormatLogLine(LogFormat::kJson, ts, LogLevel::kWarning, "rpc",
                                         {{"method", "/a.B/C"},
                                          {"message", "bad \"x\"\nline"},
                                          {"n", 3},
                                          {"ms", 0.12345},
                                          {"ok", false}});
  ASSERT_TRUE(line.ends_with("}\n"));
  EXPECT_EQ(line.find('\n'), line.size() - 1) << "one line, newlines escaped";
  const nlohmann::json j = nlohmann::json::parse(line);
  EXPECT_EQ(j["ts"], "2024-05-01T12:00:00.123Z");
  EXPECT_EQ(j["level"], "warning");
  EXPECT_EQ(j["event"], "rpc");
  EXPECT_EQ(j["method"], "/a.B/C");
  EXPECT_EQ(j["message"], "bad \"x\"\nline");
  EXPECT_EQ(j["n"], 3);
  EXPECT_DOUBLE_EQ(j["ms"].get<double>(), 0.123);
  EXPECT_EQ(j["ok"], false);
}

TEST(LogTest, TextLinesAreLogfmtQuotingOnlyWhatNeedsIt) {
  const std::string line =
      FormatLogLine(LogFormat::kText, absl::FromUnixMillis(0), LogLevel::kInfo, "server_start",
                    {{"address", "127.0.0.1:50051"}, {"note", "two words"}, {"empty", ""}});
  EXPECT_EQ(line,
            "ts=1970-01-01T00:00:00.000Z level=info event=server_start address=127.0.0.1:50051 "
            "note=\"two words\" empty=\"\"\n");
}

TEST(LogTest, LevelsFilterAndParse) {
  EXPECT_EQ(*ParseLogLevel("warning"), LogLevel::kWarning);
  EXPECT_THAT(Message(ParseLogLevel("loud").status()), HasSubstr("got 'loud'"));
  std::vector<std::string> lines;
  ConfigureLog({.level = LogLevel::kWarning, .format = LogFormat::kJson},
               [&](std::string_view line) { lines.emplace_back(line); });
  Log(LogLevel::kInfo, "quiet");
  Log(LogLevel::kError, "loud", {{"k", "v"}});
  ConfigureLog({});
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_THAT(lines[0], HasSubstr("\"event\":\"loud\",\"k\":\"v\""));
}

// A real server with the RPC log on; the log lines land in `lines_`.
class RpcLogTest : public ::testing::Test {
 protected:
  void StartServer(LogLevel level) {
    ConfigureLog({.level = level, .format = LogFormat::kJson}, [this](std::string_view line) {
      std::lock_guard lock(mu_);
      lines_.emplace_back(line);
    });
    dir_ = ::testing::TempDir() + "imucal_log_test_" + std::to_string(::getpid());
    std::filesystem::create_directories(dir_);
    for (const char* suffix : {"", "-wal", "-shm"}) std::filesystem::remove(dir_ + "/db" + suffix);
    ServerOptions options;
    options.listen = "127.0.0.1:0";
    options.db_path = dir_ + "/db";
    options.security.insecure = true;
    options.log_rpcs = true;
    auto server = Server::Start(options);
    ASSERT_TRUE(server.ok()) << server.status();
    server_ = *std::move(server);
    channel_ = grpc::CreateChannel(server_->address(), grpc::InsecureChannelCredentials());
  }
  void TearDown() override {
    server_.reset();
    ConfigureLog({});
  }

  // A unary call with the given serialised request; returns its status.
  grpc::Status Call(const std::string& method, const std::string& request_bytes) {
    grpc::GenericStub stub(channel_);
    grpc::Slice slice(request_bytes);
    grpc::ByteBuffer request(&slice, 1), response;
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    std::promise<grpc::Status> done;
    stub.UnaryCall(&ctx, method, grpc::StubOptions(), &request, &response,
                   [&](grpc::Status s) { done.set_value(std::move(s)); });
    return done.get_future().get();
  }

  std::vector<nlohmann::json> RpcLines() {
    std::lock_guard lock(mu_);
    std::vector<nlohmann::json> rpcs;
    for (const std::string& line : lines_) {
      nlohmann::json j = nlohmann::json::parse(line);
      if (j["event"] == "rpc") rpcs.push_back(std::move(j));
    }
    return rpcs;
  }

  std::string dir_;
  std::unique_ptr<Server> server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::mutex mu_;
  std::vector<std::string> lines_;
};

TEST_F(RpcLogTest, EachRpcLogsMethodCodeAndDurationBeforeTheClientHasItsAnswer) {
  StartServer(LogLevel::kInfo);
  // GetDevice of an empty id: INVALID_ARGUMENT. The line is written at PRE_SEND_STATUS, so it
  // is there once the client has the status (no waiting).
  const grpc::Status st = Call("/imucal.v1.DeviceService/GetDevice", "");
  ASSERT_FALSE(st.ok());
  const std::vector<nlohmann::json> rpcs = RpcLines();
  ASSERT_EQ(rpcs.size(), 1u);
  EXPECT_EQ(rpcs[0]["method"], "/imucal.v1.DeviceService/GetDevice");
  EXPECT_EQ(rpcs[0]["code"], "INVALID_ARGUMENT");
  EXPECT_EQ(rpcs[0]["level"], "info");
  EXPECT_GE(rpcs[0]["duration_ms"].get<double>(), 0.0);
  EXPECT_LT(rpcs[0]["duration_ms"].get<double>(), 10000.0);
  EXPECT_THAT(rpcs[0]["peer"].get<std::string>(), HasSubstr("127.0.0.1"));
  EXPECT_FALSE(rpcs[0]["message"].get<std::string>().empty());
}

TEST_F(RpcLogTest, HotPathAndHealthSuccessesLogOnlyAtDebugLevel) {
  StartServer(LogLevel::kInfo);
  ASSERT_TRUE(Call("/grpc.health.v1.Health/Check", "").ok());
  // GetActiveParameters of an unknown device: NOT_FOUND, but not intercepted at info level.
  EXPECT_EQ(Call(kHotPathMethod, std::string("\x0a\x01x", 3)).error_code(),
            grpc::StatusCode::NOT_FOUND);
  EXPECT_TRUE(RpcLines().empty());
  server_.reset();
  lines_.clear();

  StartServer(LogLevel::kDebug);
  ASSERT_TRUE(Call("/grpc.health.v1.Health/Check", "").ok());
  EXPECT_EQ(Call(kHotPathMethod, std::string("\x0a\x01x", 3)).error_code(),
            grpc::StatusCode::NOT_FOUND);
  const std::vector<nlohmann::json> rpcs = RpcLines();
  ASSERT_EQ(rpcs.size(), 2u);
  EXPECT_EQ(rpcs[0]["method"], "/grpc.health.v1.Health/Check");
  EXPECT_EQ(rpcs[0]["level"], "debug");
  EXPECT_EQ(rpcs[1]["method"], kHotPathMethod);
  EXPECT_EQ(rpcs[1]["code"], "NOT_FOUND");
  EXPECT_EQ(rpcs[1]["level"], "info");
}

}  // namespace
}  // namespace imucal::server
