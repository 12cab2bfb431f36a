// The HTTP endpoint that serves a replica's Prometheus metrics (server/metrics.h), on GNU
// libmicrohttpd (Debian's libmicrohttpd-dev).
//
// What it answers:
//   GET /metrics, HEAD /metrics   200, text/plain; version=0.0.4 (Prometheus's text format)
//   any other method on /metrics  405, with "Allow: GET, HEAD"
//   any other path                404
//   a malformed request           400 (or 414/431 when its line or headers are too long, 505
//                                 for an HTTP version other than 1.0/1.1), or the connection
//                                 closed: libmicrohttpd answers these before our handler runs.
//
// Why libmicrohttpd rather than prometheus-cpp's Exposer: the Exposer runs Debian's civetweb
// 1.15, whose worker threads have a ~100 KB stack that mg_send_http_error overflows: one
// `GET /` killed imucald. The stack size is fixed when civetweb is built, so it cannot be fixed
// from here. libmicrohttpd serves every connection from one event loop (poll(2)), so a client that
// sends half a request and stalls holds no worker: others are answered meanwhile, and the idle
// timeout below closes it. Its thread has the process's default stack (8 MiB). Not its epoll
// mode: in 0.9.75 that misses a client's close that arrives with the request's last bytes, and
// holds such a connection until the idle timeout; poll over at most 64 connections costs
// nothing a scrape would notice.
//
// Thread-safe: `text` is called on the endpoint's thread, one scrape at a time.
#ifndef IMUCAL_SERVER_METRICS_HTTP_H_
#define IMUCAL_SERVER_METRICS_HTTP_H_

#include <cstddef>
#include <functional>
#include <memory>
#include <string>
#include <utility>

#include "absl/status/statusor.h"
#include "absl/time/time.h"

struct MHD_Daemon;

namespace imucal::server {

// What one client may take of the endpoint. Prometheus scrapes a replica every few seconds
// over one connection; these bound what anyone else can hold.
struct MetricsHttpLimits {
  // A connection that sends nothing for this long is closed: a stalled request or an idle
  // keep-alive. Whole seconds (libmicrohttpd's unit); at least 1 s.
  absl::Duration idle_timeout = absl::Seconds(10);
  // Each connection's memory pool, which holds its request line and headers: a request whose
  // line and headers do not fit is answered 414 (the line) or 431 (the headers). 32 KiB is
  // libmicrohttpd's default; a scrape's request is about 200 bytes.
  size_t connection_memory_bytes = 32 * 1024;
  // Connections open at once, in all and from one address; past these a new connection is
  // closed at once (accepted and closed), so one address cannot take every slot.
  int max_connections = 64;
  int max_connections_per_address = 16;
};

class MetricsHttpEndpoint {
 public:
  // Serves `text()` at http://`listen`/metrics. `listen` is "HOST:PORT" (HOST a name or an
  // address of this machine, an IPv6 address in brackets; port 0 picks a free one).
  // InvalidArgument naming `metrics_listen` when it is not HOST:PORT; Unavailable, saying why,
  // when it cannot listen there.
  static absl::StatusOr<std::unique_ptr<MetricsHttpEndpoint>> Start(
      const std::string& listen, std::function<std::string()> text,
      const MetricsHttpLimits& limits = {});
  // Stops serving: open connections are closed, `text` is not called again.
  ~MetricsHttpEndpoint();
  MetricsHttpEndpoint(const MetricsHttpEndpoint&) = delete;
  MetricsHttpEndpoint& operator=(const MetricsHttpEndpoint&) = delete;

  int port() const { return port_; }

 private:
  friend struct MetricsHttpHandler;  // libmicrohttpd's callback, in metrics_http.cc
  explicit MetricsHttpEndpoint(std::function<std::string()> text) : text_(std::move(text)) {}

  std::function<std::string()> text_;
  MHD_Daemon* daemon_ = nullptr;
  int port_ = 0;
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_METRICS_HTTP_H_
