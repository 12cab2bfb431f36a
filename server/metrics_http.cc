#include "server/metrics_http.h"

#include <fcntl.h>
#include <microhttpd.h>
#include <netdb.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <string_view>

#include "absl/status/status.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"

namespace imucal::server {
namespace {

// Prometheus's text exposition format, version 0.0.4: the type Prometheus asks for first.
constexpr char kContentType[] = "text/plain; version=0.0.4; charset=utf-8";
constexpr char kPlainText[] = "text/plain; charset=utf-8";

struct HostPort {
  std::string host;  // without the brackets of an IPv6 address
  std::string port;
};

// "HOST:PORT" with a port from 0 to 65535, checked here: a socket's error would not say what is
// wrong with the option.
absl::StatusOr<HostPort> ParseListen(const std::string& listen) {
  const size_t colon = listen.rfind(':');
  int port = -1;
  if (colon == std::string::npos || colon == 0 ||
      !absl::SimpleAtoi(listen.substr(colon + 1), &port) || port < 0 || port > 65535) {
    return absl::InvalidArgumentError(absl::StrCat(
        "metrics_listen: expected HOST:PORT with a port from 0 to 65535 (e.g. 127.0.0.1:9464), "
        "got '",
        listen, "'"));
  }
  std::string host = listen.substr(0, colon);
  if (host.size() > 2 && host.front() == '[' && host.back() == ']')
    host = host.substr(1, host.size() - 2);
  return HostPort{std::move(host), std::to_string(port)};
}

// A bound, listening, non-blocking socket for `listen`; its port through `port`. Made here rather
// than by libmicrohttpd so a failure says which of the usual causes it is.
absl::StatusOr<int> ListenSocket(const std::string& listen, int* port) {
  absl::StatusOr<HostPort> hp = ParseListen(listen);
  if (!hp.ok()) return hp.status();
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE | AI_NUMERICSERV;
  addrinfo* found = nullptr;
  if (const int rc = ::getaddrinfo(hp->host.c_str(), hp->port.c_str(), &hints, &found); rc != 0) {
    return absl::UnavailableError(absl::StrCat("metrics_listen: cannot listen on ", listen,
                                               ": host '", hp->host, "': ", gai_strerror(rc)));
  }
  const int fd = ::socket(found->ai_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  int err = fd < 0 ? errno : 0;
  if (fd >= 0) {
    const int on = 1;
    // A restarted server rebinds at once (connections of the last one in TIME_WAIT); a port
    // another socket listens on is still refused.
    ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &on, sizeof(on));
    if (::bind(fd, found->ai_addr, found->ai_addrlen) != 0 || ::listen(fd, SOMAXCONN) != 0)
      err = errno;
  }
  ::freeaddrinfo(found);
  if (err != 0) {
    if (fd >= 0) ::close(fd);
    const std::string why = err == EADDRINUSE      ? "the port is in use"
                            : err == EADDRNOTAVAIL ? "the host is not an address of this machine"
                            : err == EACCES        ? "a port below 1024 needs privileges"
                                                   : std::strerror(err);
    return absl::UnavailableError(
        absl::StrCat("metrics_listen: cannot listen on ", listen, ": ", why));
  }
  sockaddr_storage bound{};
  socklen_t len = sizeof(bound);
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&bound), &len);
  *port = bound.ss_family == AF_INET6
              ? ntohs(reinterpret_cast<const sockaddr_in6*>(&bound)->sin6_port)
              : ntohs(reinterpret_cast<const sockaddr_in*>(&bound)->sin_port);
  return fd;
}

}  // namespace

// libmicrohttpd's access handler. The library calls it once a request's line and headers are in
// (a malformed or oversized request never gets here: the library answers it), then again for
// each piece of a body, then once more when the request is complete.
//
// A scrape (GET or HEAD of /metrics, no body) is answered on that last call, which lets the
// library keep the connection alive for the next scrape. Anything else is answered on the first
// call: a body (a scrape has none) is then never read, and the library closes the connection
// after the answer, so no client can keep it busy streaming one.
struct MetricsHttpHandler {
  static MHD_Result Handle(void* cls, MHD_Connection* connection, const char* url,
                           const char* method, const char* /*version*/, const char* /*upload_data*/,
                           size_t* upload_data_size, void** request_state) {
    const auto* endpoint = static_cast<const MetricsHttpEndpoint*>(cls);
    const std::string_view path(url), verb(method);
    const bool scrape = path == "/metrics" &&
                        (verb == MHD_HTTP_METHOD_GET || verb == MHD_HTTP_METHOD_HEAD) &&
                        !HasBody(connection);
    if (scrape && *request_state == nullptr) {
      *request_state = connection;  // any non-null: "the first call was seen"
      return MHD_YES;
    }
    if (*upload_data_size != 0) return MHD_NO;  // a body after all (cannot happen): drop it
    if (scrape) return Send(connection, MHD_HTTP_OK, kContentType, endpoint->text_());
    if (path != "/metrics") {
      return Send(connection, MHD_HTTP_NOT_FOUND, kPlainText,
                  "not found: this endpoint serves /metrics only\n");
    }
    if (verb != MHD_HTTP_METHOD_GET && verb != MHD_HTTP_METHOD_HEAD) {
      return Send(connection, MHD_HTTP_METHOD_NOT_ALLOWED, kPlainText,
                  absl::StrCat("method ", method, " not allowed: /metrics takes GET and HEAD\n"));
    }
    // A GET or HEAD of /metrics that announces a body: answered, and the body left unread.
    return Send(connection, MHD_HTTP_OK, kContentType, endpoint->text_());
  }

  // Whether the request announces a body (a Content-Length other than 0, or chunks).
  static bool HasBody(MHD_Connection* connection) {
    const char* length =
        MHD_lookup_connection_value(connection, MHD_HEADER_KIND, MHD_HTTP_HEADER_CONTENT_LENGTH);
    return (length != nullptr && std::string_view(length) != "0") ||
           MHD_lookup_connection_value(connection, MHD_HEADER_KIND,
                                       MHD_HTTP_HEADER_TRANSFER_ENCODING) != nullptr;
  }

  static MHD_Result Send(MHD_Connection* connection, unsigned status, const char* content_type,
                         const std::string& body) {
    MHD_Response* response = MHD_create_response_from_buffer(
        body.size(), const_cast<char*>(body.data()), MHD_RESPMEM_MUST_COPY);
    if (response == nullptr) return MHD_NO;  // out of memory: the library closes the connection
    MHD_add_response_header(response, MHD_HTTP_HEADER_CONTENT_TYPE, content_type);
    if (status == MHD_HTTP_METHOD_NOT_ALLOWED)
      MHD_add_response_header(response, MHD_HTTP_HEADER_ALLOW, "GET, HEAD");
    const MHD_Result queued = MHD_queue_response(connection, status, response);
    MHD_destroy_response(response);
    return queued;
  }
};

absl::StatusOr<std::unique_ptr<MetricsHttpEndpoint>> MetricsHttpEndpoint::Start(
    const std::string& listen, std::function<std::string()> text, const MetricsHttpLimits& limits) {
  std::unique_ptr<MetricsHttpEndpoint> e(new MetricsHttpEndpoint(std::move(text)));
  absl::StatusOr<int> fd = ListenSocket(listen, &e->port_);
  if (!fd.ok()) return fd.status();
  const auto timeout_s =
      static_cast<unsigned>(std::max<int64_t>(1, absl::ToInt64Seconds(limits.idle_timeout)));
  // One thread with its own poll(2) loop serves every connection (the header says why not
  // epoll). No MHD_USE_ERROR_LOG: a port scanner's bytes are not worth a log line each.
  e->daemon_ = MHD_start_daemon(
      MHD_USE_POLL_INTERNAL_THREAD | MHD_USE_ITC, /*port=*/0, /*accept_policy=*/nullptr, nullptr,
      &MetricsHttpHandler::Handle, e.get(), MHD_OPTION_LISTEN_SOCKET, static_cast<MHD_socket>(*fd),
      MHD_OPTION_CONNECTION_TIMEOUT, timeout_s, MHD_OPTION_CONNECTION_MEMORY_LIMIT,
      limits.connection_memory_bytes, MHD_OPTION_CONNECTION_LIMIT,
      static_cast<unsigned>(limits.max_connections), MHD_OPTION_PER_IP_CONNECTION_LIMIT,
      static_cast<unsigned>(limits.max_connections_per_address), MHD_OPTION_END);
  if (e->daemon_ == nullptr) {
    ::close(*fd);
    return absl::UnavailableError(
        absl::StrCat("metrics_listen: cannot serve HTTP on ", listen,
                     ": the HTTP server did not start (out of threads or file descriptors?)"));
  }
  return e;
}

MetricsHttpEndpoint::~MetricsHttpEndpoint() {
  // Joins the endpoint's thread and closes its connections and the listening socket.
  if (daemon_ != nullptr) MHD_stop_daemon(daemon_);
}

}  // namespace imucal::server
