// A TCP forwarder on 127.0.0.1 for tests that cut a server off its database without touching
// the database: the server is given the proxy's port, Cut() closes every connection through it
// and stops listening (new connections are refused, as when the database's host is down), and
// Restore() listens again on the same port. The run's shared PostgreSQL cluster stays up for the
// other tests.
#ifndef IMUCAL_TESTS_SERVER_TCP_PROXY_H_
#define IMUCAL_TESTS_SERVER_TCP_PROXY_H_

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <thread>
#include <utility>
#include <vector>

namespace imucal::testing_util {

class TcpProxy {
 public:
  // Forwards 127.0.0.1:port() to 127.0.0.1:target_port; null when it cannot listen.
  static std::unique_ptr<TcpProxy> Start(int target_port) {
    std::unique_ptr<TcpProxy> p(new TcpProxy(target_port));
    p->wake_ = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (p->wake_ < 0 || !p->Listen(0)) return nullptr;
    p->thread_ = std::thread([raw = p.get()] { raw->Loop(); });
    return p;
  }

  ~TcpProxy() {
    Command(kStop);
    thread_.join();
    ::close(wake_);
  }
  TcpProxy(const TcpProxy&) = delete;
  TcpProxy& operator=(const TcpProxy&) = delete;

  int port() const { return port_; }

  // Closes every forwarded connection and the listening socket; returns once they are closed.
  void Cut() { Command(kCut); }
  // Listens again on port(); false when the port was taken meanwhile.
  bool Restore() {
    Command(kRestore);
    std::lock_guard lock(mu_);
    return listen_fd_ >= 0;
  }

 private:
  enum Op { kNone, kCut, kRestore, kStop };
  struct Pair {
    int client, upstream;
  };

  explicit TcpProxy(int target_port) : target_port_(target_port) {}

  bool Listen(int port) {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    const int on = 1;
    ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &on, sizeof(on));
    sockaddr_in a = Loopback(port);
    if (fd < 0 || ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0 ||
        ::listen(fd, 64) != 0) {
      if (fd >= 0) ::close(fd);
      return false;
    }
    socklen_t len = sizeof(a);
    ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
    port_ = ntohs(a.sin_port);
    listen_fd_ = fd;
    return true;
  }

  static sockaddr_in Loopback(int port) {
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<uint16_t>(port));
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    return a;
  }

  // Hands `op` to the loop's thread and waits until it is done.
  void Command(Op op) {
    std::unique_lock lock(mu_);
    op_ = op;
    const uint64_t one = 1;
    (void)::write(wake_, &one, sizeof(one));
    done_.wait(lock, [this] { return op_ == kNone; });
  }

  void CloseAll() {
    for (const Pair& p : pairs_) {
      ::close(p.client);
      ::close(p.upstream);
    }
    pairs_.clear();
    if (listen_fd_ >= 0) ::close(listen_fd_);
    listen_fd_ = -1;
  }

  // Copies what `from` has to `to`; false when either side is done.
  static bool Forward(int from, int to) {
    char buf[65536];
    const ssize_t n = ::recv(from, buf, sizeof(buf), 0);
    if (n <= 0) return false;
    for (ssize_t sent = 0; sent < n;) {
      const ssize_t w = ::send(to, buf + sent, static_cast<size_t>(n - sent), MSG_NOSIGNAL);
      if (w <= 0) return false;
      sent += w;
    }
    return true;
  }

  void Loop() {
    for (;;) {
      std::vector<pollfd> fds = {{wake_, POLLIN, 0}};
      {
        std::lock_guard lock(mu_);
        if (listen_fd_ >= 0) fds.push_back({listen_fd_, POLLIN, 0});
      }
      const size_t first_pair = fds.size();
      for (const Pair& p : pairs_) {
        fds.push_back({p.client, POLLIN, 0});
        fds.push_back({p.upstream, POLLIN, 0});
      }
      if (::poll(fds.data(), fds.size(), -1) < 0 && errno != EINTR) return;
      if (fds[0].revents != 0) {
        uint64_t count;
        (void)::read(wake_, &count, sizeof(count));
        std::lock_guard lock(mu_);
        if (op_ == kCut || op_ == kStop) CloseAll();
        if (op_ == kRestore && listen_fd_ < 0) Listen(port_);
        const bool stop = op_ == kStop;
        op_ = kNone;
        done_.notify_all();
        if (stop) return;
        continue;
      }
      // The pairs polled are the first `polled`; one accepted below was not polled yet.
      const size_t polled = pairs_.size();
      std::vector<Pair> kept;
      for (size_t i = 0; i < polled; ++i) {
        const pollfd& c = fds[first_pair + 2 * i];
        const pollfd& u = fds[first_pair + 2 * i + 1];
        bool alive = true;
        if (c.revents != 0) alive = Forward(c.fd, u.fd);
        if (alive && u.revents != 0) alive = Forward(u.fd, c.fd);
        if (alive) {
          kept.push_back(pairs_[i]);
        } else {
          ::close(pairs_[i].client);
          ::close(pairs_[i].upstream);
        }
      }
      pairs_ = std::move(kept);
      if (first_pair == 2 && fds[1].revents != 0) Accept();
    }
  }

  void Accept() {
    const int client = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
    if (client < 0) return;
    const int upstream = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a = Loopback(target_port_);
    if (upstream < 0 || ::connect(upstream, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0) {
      ::close(client);
      if (upstream >= 0) ::close(upstream);
      return;
    }
    pairs_.push_back({client, upstream});
  }

  const int target_port_;
  int port_ = 0;
  int wake_ = -1;
  std::thread thread_;
  std::vector<Pair> pairs_;  // the loop's thread only

  std::mutex mu_;
  std::condition_variable done_;
  Op op_ = kNone;       // guarded by mu_
  int listen_fd_ = -1;  // guarded by mu_ (written by the loop's thread, and before it starts)
};

}  // namespace imucal::testing_util

#endif  // IMUCAL_TESTS_SERVER_TCP_PROXY_H_
