// The metrics endpoint (server/metrics_http.h) against what reaches a port bound to 0.0.0.0:
// browsers, port scanners, broken and hostile clients. An in-process imucald with
// --metrics-listen on a loopback port, spoken to in raw HTTP over TCP sockets. Every wait is
// bounded by a deadline on poll(2); nothing sleeps.
//
// What must hold: /metrics answers GET and HEAD (200, Prometheus text), any other path 404, any
// other method on /metrics 405; a malformed or oversized request gets a 4xx status line or a
// closed connection, never a hang or a crash; a stalled client holds no one else up; and after
// all of it the server still serves gRPC and /metrics.
#include "server/metrics_http.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdint>
#include <memory>
#include <random>
#include <string>
#include <string_view>
#include <vector>

#include "gmock/gmock.h"
#include "grpcpp/grpcpp.h"
#include "gtest/gtest.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/server.h"
#include "tests/test_dir.h"

namespace imucal::server {
namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;
using std::chrono::seconds;
using ::testing::AnyOf;
using ::testing::HasSubstr;

// How a read of a reply ended.
enum class End { kClosed, kReset, kDeadline };

struct Reply {
  std::string bytes;
  End end = End::kDeadline;

  // The status code of the reply's status line ("HTTP/1.x NNN ..."); 0 when there is none.
  int status() const {
    if (bytes.size() < 12 || bytes.compare(0, 7, "HTTP/1.") != 0 || bytes[8] != ' ') return 0;
    int code = 0;
    for (int i = 9; i < 12; ++i) {
      if (bytes[i] < '0' || bytes[i] > '9') return 0;
      code = code * 10 + (bytes[i] - '0');
    }
    return code;
  }
  std::string head() const { return bytes.substr(0, bytes.find("\r\n\r\n")); }
  std::string body() const {
    const size_t at = bytes.find("\r\n\r\n");
    return at == std::string::npos ? "" : bytes.substr(at + 4);
  }
  // An HTTP answer, or the connection closed (a server may drop what it cannot parse); not a
  // hang until the deadline, and not something else.
  bool AnsweredOrClosed() const {
    return status() != 0 || (bytes.empty() && end != End::kDeadline);
  }
};

std::string Describe(const Reply& r) {
  const char* end = r.end == End::kClosed ? "closed" : r.end == End::kReset ? "reset" : "deadline";
  return std::string("ended by ") + end + " after " + std::to_string(r.bytes.size()) + " bytes: '" +
         r.bytes.substr(0, 200) + "'";
}

// A non-blocking TCP connection to 127.0.0.1:port; every wait ends at `deadline`.
class Conn {
 public:
  Conn(int port, Clock::time_point deadline) : deadline_(deadline) {
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd_ < 0) return;
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(static_cast<uint16_t>(port));
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::connect(fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof(addr)) == 0) {
      connected_ = true;
    } else if (errno == EINPROGRESS && Wait(POLLOUT)) {
      int err = 0;
      socklen_t len = sizeof(err);
      connected_ = ::getsockopt(fd_, SOL_SOCKET, SO_ERROR, &err, &len) == 0 && err == 0;
    }
  }
  ~Conn() {
    if (fd_ >= 0) ::close(fd_);
  }
  Conn(const Conn&) = delete;
  Conn& operator=(const Conn&) = delete;

  bool connected() const { return connected_; }

  // Sends `bytes`; false when the peer stopped taking them (closed, reset, or the deadline).
  // A server that answers a 100 KB request line before reading it all closes mid-send.
  bool Send(std::string_view bytes) {
    while (!bytes.empty()) {
      const ssize_t n = ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL);
      if (n > 0) {
        bytes.remove_prefix(static_cast<size_t>(n));
      } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
        if (!Wait(POLLOUT)) return false;
      } else if (n < 0 && errno != EINTR) {
        return false;
      }
    }
    return true;
  }

  void CloseWrite() { ::shutdown(fd_, SHUT_WR); }

  // Reads until the server closes the connection (or resets it), or the deadline.
  Reply ReadToEnd() {
    Reply r;
    r.end = ReadMore(&r.bytes, [](const std::string&) { return false; });
    return r;
  }

  // Reads one reply on a kept-alive connection: up to the end of its body (Content-Length).
  Reply ReadOne() {
    Reply r;
    r.end = ReadMore(&r.bytes, [](const std::string& got) {
      const size_t head_end = got.find("\r\n\r\n");
      if (head_end == std::string::npos) return false;
      const std::string head = got.substr(0, head_end);
      const size_t cl = head.find("Content-Length: ");
      if (cl == std::string::npos) return false;
      return got.size() >= head_end + 4 + std::stoul(head.substr(cl + 16));
    });
    return r;
  }

  // True when nothing has arrived and the connection is still open after `wait` (poll's
  // timeout, not a sleep: any byte or a close ends it at once).
  bool QuietFor(milliseconds wait) {
    pollfd p{fd_, POLLIN, 0};
    return ::poll(&p, 1, static_cast<int>(wait.count())) == 0;
  }

 private:
  // Polls for `events` until the deadline; true when ready.
  bool Wait(short events) {
    for (;;) {
      const auto left = std::chrono::duration_cast<milliseconds>(deadline_ - Clock::now()).count();
      if (left <= 0) return false;
      pollfd p{fd_, events, 0};
      const int n = ::poll(&p, 1, static_cast<int>(left));
      if (n > 0) return true;
      if (n < 0 && errno != EINTR) return false;
    }
  }

  template <typename Done>
  End ReadMore(std::string* out, Done done) {
    char buf[16384];
    for (;;) {
      if (done(*out)) return End::kClosed;
      const ssize_t n = ::recv(fd_, buf, sizeof(buf), 0);
      if (n > 0) {
        out->append(buf, static_cast<size_t>(n));
      } else if (n == 0) {
        return End::kClosed;
      } else if (errno == EAGAIN || errno == EWOULDBLOCK) {
        if (!Wait(POLLIN)) return End::kDeadline;
      } else if (errno != EINTR) {
        return End::kReset;
      }
    }
  }

  int fd_ = -1;
  bool connected_ = false;
  Clock::time_point deadline_;
};

// Sends `request` on a new connection, half-closes, and reads what comes back.
Reply Exchange(int port, std::string_view request, seconds within = seconds(10)) {
  Conn c(port, Clock::now() + within);
  if (!c.connected()) return Reply{"", End::kReset};
  c.Send(request);  // a server may answer and close before taking all of it
  c.CloseWrite();
  return c.ReadToEnd();
}

std::string Get(std::string_view method, std::string_view path) {
  return std::string(method) + " " + std::string(path) +
         " HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n";
}

class MetricsHttpTest : public testing::Test {
 protected:
  void SetUp() override {
    ServerOptions options;
    options.listen = "127.0.0.1:0";
    options.security.insecure = true;  // loopback, no TLS: the HTTP endpoint is under test
    options.db_path = dir_.File("imucal.db");
    options.metrics_listen = "127.0.0.1:0";
    auto server = Server::Start(options);
    ASSERT_TRUE(server.ok()) << server.status();
    server_ = *std::move(server);
    port_ = server_->metrics_port();
    ASSERT_GT(port_, 0);
    channel_ = grpc::CreateChannel(server_->address(), grpc::InsecureChannelCredentials());
    devices_ = v1::DeviceService::NewStub(channel_);
  }

  // The server still answers a gRPC call and a scrape.
  void ExpectStillServing(const std::string& device) {
    v1::RegisterDeviceRequest reg;
    reg.mutable_device()->set_id(device);
    reg.mutable_device()->set_sensor_model("sim");
    reg.mutable_device()->set_nominal_rate_hz(200);
    reg.mutable_device()->set_accel_unit("m/s^2");
    reg.mutable_device()->set_gyro_unit("rad/s");
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + seconds(10));
    v1::Device out;
    const grpc::Status s = devices_->RegisterDevice(&ctx, reg, &out);
    EXPECT_TRUE(s.ok()) << s.error_message();
    const Reply scrape = Exchange(port_, Get("GET", "/metrics"));
    EXPECT_EQ(scrape.status(), 200) << Describe(scrape);
    EXPECT_THAT(scrape.body(), HasSubstr("imucal_rpc_total{code=\"OK\",method=\"/imucal.v1."
                                         "DeviceService/RegisterDevice\"}"));
  }

  testing_util::TestDir dir_{"metrics_http_test"};  // first: outlives the server
  std::unique_ptr<Server> server_;
  int port_ = 0;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::DeviceService::Stub> devices_;
};

// /metrics serves the families in Prometheus's text format to GET, and the same head without a
// body to HEAD; other paths are not found (what a browser asks first: / and /favicon.ico).
TEST_F(MetricsHttpTest, ServesMetricsAndNothingElse) {
  const Reply get = Exchange(port_, Get("GET", "/metrics"));
  ASSERT_EQ(get.status(), 200) << Describe(get);
  EXPECT_THAT(get.head(), HasSubstr("Content-Type: text/plain; version=0.0.4"));
  for (const char* family :
       {"# TYPE imucal_samples_received_total counter",
        "# TYPE imucal_samples_acknowledged_total counter",
        "# TYPE imucal_sessions_in_memory gauge", "# TYPE imucal_streams_open gauge",
        "# TYPE imucal_solve_queue_depth gauge"}) {
    EXPECT_THAT(get.body(), HasSubstr(family));
  }

  const Reply head = Exchange(port_, Get("HEAD", "/metrics"));
  EXPECT_EQ(head.status(), 200) << Describe(head);
  EXPECT_EQ(head.body(), "");
  EXPECT_THAT(head.head(), HasSubstr("Content-Length: "));

  for (const char* path : {"/", "/favicon.ico", "/metrics/", "/metricsx", "/Metrics", "/../metrics",
                           "/robots.txt", "*"}) {
    const Reply r = Exchange(port_, Get("GET", path));
    EXPECT_THAT(r.status(), AnyOf(404, 400)) << path << ": " << Describe(r);
  }
  EXPECT_EQ(Exchange(port_, Get("GET", "/")).status(), 404);
  EXPECT_EQ(Exchange(port_, Get("GET", "/favicon.ico")).status(), 404);
  EXPECT_EQ(Exchange(port_, Get("POST", "/")).status(), 404);
  ExpectStillServing("robot-paths");
}

// Any other method on /metrics is refused with 405 and the methods it takes; a body sent along
// is not waited for.
TEST_F(MetricsHttpTest, OtherMethodsOnMetricsAre405) {
  for (const char* method : {"POST", "PUT", "DELETE", "PATCH", "OPTIONS", "TRACE", "BREW"}) {
    const Reply r = Exchange(port_, Get(method, "/metrics"));
    EXPECT_EQ(r.status(), 405) << method << ": " << Describe(r);
    EXPECT_THAT(r.head(), HasSubstr("Allow: GET, HEAD")) << method;
  }
  const Reply post = Exchange(port_,
                              "POST /metrics HTTP/1.1\r\nHost: x\r\nContent-Length: 1000000\r\n"
                              "\r\nonly a little of the body");
  EXPECT_EQ(post.status(), 405) << Describe(post);
  ExpectStillServing("robot-methods");
}

// Bytes that are not HTTP: an answer (400) or a closed connection, and the server lives on.
TEST_F(MetricsHttpTest, GarbageIsRefusedOrDropped) {
  const std::vector<std::string> garbage = {
      std::string("\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03", 11),  // a TLS ClientHello
      std::string(4096, '\0'),
      "\r\n\r\n\r\n\r\n",
      "GET\r\n\r\n",
      "GET /metrics\r\n\r\n",  // HTTP/0.9
      "GET /metrics HTTP/9.9\r\n\r\n",
      "GET /metrics HTTP/1.1\r\n\r\n",  // no Host on HTTP/1.1
      "GET /metrics HTTP/1.1\r\nHost: x\r\nNo colon here\r\n\r\n",
      "GET /metrics HTTP/1.1\r\nHost: x\r\n: empty name\r\n\r\n",
      "GET /metrics HTTP/1.1\r\nHost: x\r\nContent-Length: -1\r\n\r\n",
      "GET /metrics HTTP/1.1\r\nHost: x\r\nContent-Length: 99999999999999999999999\r\n\r\n",
      "GET /metrics HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\nzz\r\n",
      std::string("GET /met\0rics HTTP/1.1\r\nHost: x\r\n\r\n", 35),
      "GET /%zz%00%ff HTTP/1.1\r\nHost: x\r\n\r\n",
      "GET  /metrics  HTTP/1.1\r\nHost: x\r\n\r\n",
      "GET /metrics HTTP/1.1\nHost: x\n\n",  // bare LF
      "GET /metrics HTTP/1.1\rHost: x\r\r",  // bare CR
      "\xff\xfe\xfd GET / HTTP/1.1\r\n\r\n",
  };
  for (const std::string& g : garbage) {
    const Reply r = Exchange(port_, g);
    EXPECT_TRUE(r.AnsweredOrClosed()) << "'" << g.substr(0, 40) << "': " << Describe(r);
    EXPECT_THAT(r.status(), AnyOf(0, 200, 400, 404, 405, 411, 413, 505)) << Describe(r);
  }
  ExpectStillServing("robot-garbage");
}

// A 100 KB request line, one 100 KB header, and a flood of 10,000 headers: refused with a 4xx
// (414, 431 or 400) without reading them to the end, and the server lives on.
TEST_F(MetricsHttpTest, OversizedRequestsAreRefused) {
  const std::string long_path = "/" + std::string(100 * 1024, 'a');
  const Reply line = Exchange(port_, Get("GET", long_path));
  EXPECT_THAT(line.status(), AnyOf(400, 414, 431)) << Describe(line);

  const Reply one_header =
      Exchange(port_, "GET /metrics HTTP/1.1\r\nHost: x\r\nX-Big: " + std::string(100 * 1024, 'b') +
                          "\r\n\r\n");
  EXPECT_THAT(one_header.status(), AnyOf(400, 431)) << Describe(one_header);

  std::string flood = "GET /metrics HTTP/1.1\r\nHost: x\r\n";
  for (int i = 0; i < 10000; ++i) flood += "X-Flood-" + std::to_string(i) + ": v\r\n";
  flood += "\r\n";
  const Reply many = Exchange(port_, flood);
  EXPECT_THAT(many.status(), AnyOf(400, 431)) << Describe(many);
  ExpectStillServing("robot-oversized");
}

// Clients that send half a request and stall hold no one up: scrapes on other connections are
// answered meanwhile, and a stalled client that goes on is answered too.
TEST_F(MetricsHttpTest, StalledClientsHoldNoOneUp) {
  const auto deadline = Clock::now() + seconds(10);
  std::vector<std::unique_ptr<Conn>> stalled;
  for (int i = 0; i < 4; ++i) {
    stalled.push_back(std::make_unique<Conn>(port_, deadline));
    ASSERT_TRUE(stalled.back()->connected());
    ASSERT_TRUE(stalled.back()->Send("GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: "));
  }
  for (int i = 0; i < 20; ++i) {
    const Reply r = Exchange(port_, Get("GET", "/metrics"), seconds(5));
    ASSERT_EQ(r.status(), 200) << "scrape " << i << " beside 4 stalled clients: " << Describe(r);
  }
  // The stalled ones were not answered (their requests are not complete) nor dropped early.
  EXPECT_TRUE(stalled[0]->QuietFor(milliseconds(50)));
  ASSERT_TRUE(stalled[0]->Send("1\r\nConnection: close\r\n\r\n"));
  const Reply late = stalled[0]->ReadToEnd();
  EXPECT_EQ(late.status(), 200) << Describe(late);
  ExpectStillServing("robot-stalled");
}

// A keep-alive client gets several answers on one connection.
TEST_F(MetricsHttpTest, KeepAliveServesSeveralRequests) {
  Conn c(port_, Clock::now() + seconds(10));
  ASSERT_TRUE(c.connected());
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(c.Send("GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"));
    const Reply r = c.ReadOne();
    EXPECT_EQ(r.status(), 200) << i << ": " << Describe(r);
  }
  ASSERT_TRUE(c.Send("GET /favicon.ico HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"));
  EXPECT_EQ(c.ReadOne().status(), 404);
}

// 300 connections at once: each is answered or closed (past the connection limits), none hangs,
// and once they are gone the endpoint serves as before.
TEST_F(MetricsHttpTest, ManyConnectionsAtOnce) {
  const auto deadline = Clock::now() + seconds(20);
  std::vector<std::unique_ptr<Conn>> conns;
  for (int i = 0; i < 300; ++i) {
    conns.push_back(std::make_unique<Conn>(port_, deadline));
    ASSERT_TRUE(conns.back()->connected()) << i;
  }
  for (auto& c : conns) {
    c->Send(Get("GET", "/metrics"));
    c->CloseWrite();
  }
  int answered = 0;
  for (auto& c : conns) {
    const Reply r = c->ReadToEnd();
    ASSERT_TRUE(r.AnsweredOrClosed()) << Describe(r);
    if (r.status() != 0) {
      EXPECT_EQ(r.status(), 200) << Describe(r);
      ++answered;
    }
  }
  EXPECT_GT(answered, 0);
  conns.clear();
  ExpectStillServing("robot-many");
}

// A seeded fuzz: 400 requests of random methods, paths, versions, headers and bodies. Each is
// answered with a status line or closed, within 5 s; the server lives on.
TEST_F(MetricsHttpTest, RandomRequestsAreAnsweredOrClosed) {
  const uint32_t seed = 26;
  std::mt19937 rng(seed);
  auto pick = [&](const std::vector<std::string>& from) {
    return from[std::uniform_int_distribution<size_t>(0, from.size() - 1)(rng)];
  };
  auto chance = [&](double p) { return std::bernoulli_distribution(p)(rng); };
  auto bytes = [&](int max_len, bool printable) {
    std::string s(std::uniform_int_distribution<int>(0, max_len)(rng), ' ');
    for (char& c : s) {
      c = printable ? static_cast<char>(std::uniform_int_distribution<int>(0x21, 0x7e)(rng))
                    : static_cast<char>(std::uniform_int_distribution<int>(0, 255)(rng));
    }
    return s;
  };
  const std::vector<std::string> methods = {"GET",     "HEAD",  "POST", "PUT",  "DELETE", "OPTIONS",
                                            "CONNECT", "TRACE", "get",  "G ET", "",       "\x01"};
  const std::vector<std::string> paths = {"/metrics",
                                          "/",
                                          "/favicon.ico",
                                          "/metrics?x=1",
                                          "/metrics#f",
                                          "//metrics",
                                          "/%2e%2e/",
                                          "*",
                                          "http://h/metrics",
                                          "/\xc3\xa9",
                                          ""};
  const std::vector<std::string> versions = {"HTTP/1.1", "HTTP/1.0", "HTTP/2.0",      "HTTP/1.",
                                             "http/1.1", "",         "HTTP/1.1 extra"};
  const std::vector<std::string> names = {
      "Host", "Content-Length", "Transfer-Encoding", "Connection", "Expect", "Accept", "Range",
      "X"};
  for (int i = 0; i < 400; ++i) {
    std::string req = pick(methods) + " " + pick(paths);
    if (chance(0.3)) req += bytes(30, chance(0.7));
    req += " " + pick(versions) + "\r\n";
    const int headers = std::uniform_int_distribution<int>(0, 12)(rng);
    for (int h = 0; h < headers; ++h) {
      const std::string name = chance(0.7) ? pick(names) : bytes(20, chance(0.8));
      std::string value;
      if (name == "Content-Length") {
        value = pick({"0", "5", "-3", "1e3", "18446744073709551616", "", "abc"});
      } else if (name == "Transfer-Encoding") {
        value = pick({"chunked", "gzip", "chunked, chunked", ""});
      } else if (name == "Expect") {
        value = "100-continue";
      } else {
        value = bytes(60, chance(0.8));
      }
      req += name + (chance(0.9) ? ": " : " ") + value + (chance(0.95) ? "\r\n" : "\n");
    }
    req += "\r\n";
    if (chance(0.3)) req += bytes(200, false);
    const Reply r = Exchange(port_, req, seconds(5));
    ASSERT_TRUE(r.AnsweredOrClosed()) << "seed " << seed << ", request " << i << " '"
                                      << req.substr(0, 120) << "': " << Describe(r);
    if (r.status() != 0) {
      EXPECT_THAT(r.status(), AnyOf(200, 400, 404, 405, 413, 414, 431, 501, 505))
          << "seed " << seed << ", request " << i << ": " << Describe(r);
    }
  }
  ExpectStillServing("robot-fuzz");
}

// ---- The endpoint alone (server/metrics_http.h), with limits small enough to reach in a test.

// A client that stalls mid-request is closed after the idle timeout, without an answer: it
// cannot hold a connection slot for ever.
TEST(MetricsHttpEndpointTest, AStalledClientIsClosedAfterTheIdleTimeout) {
  MetricsHttpLimits limits;
  limits.idle_timeout = absl::Seconds(1);
  auto endpoint = MetricsHttpEndpoint::Start(
      "127.0.0.1:0", [] { return "x 1\n"; }, limits);
  ASSERT_TRUE(endpoint.ok()) << endpoint.status();
  Conn stalled((*endpoint)->port(), Clock::now() + seconds(10));
  ASSERT_TRUE(stalled.connected());
  ASSERT_TRUE(stalled.Send("GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\n"));
  const auto start = Clock::now();
  const Reply r = stalled.ReadToEnd();
  EXPECT_NE(r.end, End::kDeadline) << "still open 10 s after it stalled";
  EXPECT_EQ(r.bytes, "");
  // Not closed at once: a client gets its idle timeout (poll's wait, not a sleep, measures it).
  EXPECT_GE(Clock::now() - start, milliseconds(900));
}

// Past the connections one address may hold, its next connection is closed at once; the
// others are served, and once one goes the address is served again.
TEST(MetricsHttpEndpointTest, OneAddressCannotTakeEveryConnection) {
  MetricsHttpLimits limits;
  limits.max_connections_per_address = 2;
  auto endpoint = MetricsHttpEndpoint::Start(
      "127.0.0.1:0", [] { return "x 1\n"; }, limits);
  ASSERT_TRUE(endpoint.ok()) << endpoint.status();
  const int port = (*endpoint)->port();
  const auto deadline = Clock::now() + seconds(10);
  auto first = std::make_unique<Conn>(port, deadline);
  Conn second(port, deadline);
  ASSERT_TRUE(first->Send("GET /metrics HTTP/1.1\r\n"));
  ASSERT_TRUE(second.Send("GET /metrics HTTP/1.1\r\n"));
  const Reply third = Exchange(port, Get("GET", "/metrics"));
  EXPECT_EQ(third.bytes, "") << Describe(third);
  EXPECT_NE(third.end, End::kDeadline);
  first.reset();  // frees a slot (the endpoint sees the close on its next poll)
  Reply again;
  for (int i = 0; i < 1000 && again.status() == 0; ++i)
    again = Exchange(port, Get("GET", "/metrics"));
  EXPECT_EQ(again.status(), 200) << Describe(again);
  EXPECT_EQ(again.body(), "x 1\n");
}

// Where it cannot listen, the error says why and names the option.
TEST(MetricsHttpEndpointTest, ListenErrorsSayWhy) {
  auto text = [] { return std::string(); };
  auto not_here = MetricsHttpEndpoint::Start("192.0.2.1:0", text);  // TEST-NET-1: not ours
  ASSERT_FALSE(not_here.ok());
  EXPECT_EQ(not_here.status().code(), absl::StatusCode::kUnavailable);
  EXPECT_THAT(std::string(not_here.status().message()),
              HasSubstr("metrics_listen: cannot listen on 192.0.2.1:0: the host is not an "
                        "address of this machine"));
  auto unknown = MetricsHttpEndpoint::Start("no-such-host.invalid:0", text);
  ASSERT_FALSE(unknown.ok());
  EXPECT_THAT(std::string(unknown.status().message()), HasSubstr("host 'no-such-host.invalid'"));
  auto by_name = MetricsHttpEndpoint::Start("localhost:0", text);
  ASSERT_TRUE(by_name.ok()) << by_name.status();
  EXPECT_GT((*by_name)->port(), 0);
}

// Stopping closes the listening socket: a restarted endpoint binds the same port at once.
TEST(MetricsHttpEndpointTest, StoppingFreesThePort) {
  auto text = [] { return std::string("x 1\n"); };
  auto first = MetricsHttpEndpoint::Start("127.0.0.1:0", text);
  ASSERT_TRUE(first.ok()) << first.status();
  const std::string listen = "127.0.0.1:" + std::to_string((*first)->port());
  EXPECT_EQ(Exchange((*first)->port(), Get("GET", "/metrics")).status(), 200);
  auto in_use = MetricsHttpEndpoint::Start(listen, text);
  ASSERT_FALSE(in_use.ok());
  EXPECT_THAT(std::string(in_use.status().message()), HasSubstr("the port is in use"));
  first->reset();
  auto again = MetricsHttpEndpoint::Start(listen, text);
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_EQ(Exchange((*again)->port(), Get("GET", "/metrics")).status(), 200);
}

}  // namespace
}  // namespace imucal::server
