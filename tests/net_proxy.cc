#include "tests/net_proxy.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <condition_variable>
#include <deque>
#include <random>
#include <stdexcept>
#include <string>

namespace hapticpd::testing {

using Clock = std::chrono::steady_clock;

/// One direction of one connection: a reader thread timestamps chunks, a
/// writer thread sends each at its release time.
struct DelayProxy::Pipe {
  Pipe(int from_fd, int to_fd, Options o, std::atomic<std::uint64_t>* bytes, std::uint64_t seed)
      : from(from_fd), to(to_fd), options(o), counter(bytes), rng(seed) {
    reader = std::thread([this] { Read(); });
    writer = std::thread([this] { Write(); });
  }
  ~Pipe() {
    Close();
    reader.join();
    writer.join();
  }
  void Close() {
    {
      std::lock_guard lock(mu);
      closed = true;
    }
    cv.notify_all();
    ::shutdown(from, SHUT_RDWR);
    ::shutdown(to, SHUT_RDWR);
  }

  void Read() {
    std::vector<char> buf(64 * 1024);
    Clock::time_point last = Clock::now();
    std::uniform_int_distribution<long> jit(-options.jitter.count(), options.jitter.count());
    while (true) {
      pollfd p{from, POLLIN, 0};
      const int r = ::poll(&p, 1, 50);
      {
        std::lock_guard lock(mu);
        if (closed) break;
      }
      if (r <= 0) continue;
      const ssize_t n = ::recv(from, buf.data(), buf.size(), 0);
      if (n <= 0) break;
      const auto release =
          std::max(last, Clock::now() + options.delay +
                             std::chrono::microseconds(options.jitter.count() > 0 ? jit(rng) : 0));
      last = release;
      {
        std::lock_guard lock(mu);
        queue.push_back({release, std::string(buf.data(), static_cast<std::size_t>(n))});
      }
      cv.notify_all();
    }
    {
      std::lock_guard lock(mu);
      eof = true;
    }
    cv.notify_all();
  }

  void Write() {
    std::unique_lock lock(mu);
    while (true) {
      cv.wait(lock, [&] { return closed || eof || !queue.empty(); });
      if (closed) return;
      if (queue.empty()) {  // eof and drained: pass the half-close on
        ::shutdown(to, SHUT_WR);
        return;
      }
      const auto release = queue.front().first;
      if (Clock::now() < release) {
        cv.wait_until(lock, release, [&] { return closed; });
        continue;
      }
      std::string chunk = std::move(queue.front().second);
      queue.pop_front();
      lock.unlock();
      std::size_t sent = 0;
      while (sent < chunk.size()) {
        const ssize_t n = ::send(to, chunk.data() + sent, chunk.size() - sent, MSG_NOSIGNAL);
        if (n <= 0) break;
        sent += static_cast<std::size_t>(n);
      }
      *counter += sent;
      lock.lock();
      if (sent < chunk.size()) return;
    }
  }

  int from, to;
  Options options;
  std::atomic<std::uint64_t>* counter;
  std::mt19937_64 rng;
  std::mutex mu;
  std::condition_variable cv;
  std::deque<std::pair<Clock::time_point, std::string>> queue;
  bool closed = false, eof = false;
  std::thread reader, writer;
};

DelayProxy::DelayProxy(int upstream_port, Options options)
    : upstream_port_(upstream_port), options_(options) {
  listen_fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = 0;
  socklen_t len = sizeof(a);
  if (listen_fd_ < 0 || ::bind(listen_fd_, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0 ||
      ::listen(listen_fd_, 16) != 0 ||
      ::getsockname(listen_fd_, reinterpret_cast<sockaddr*>(&a), &len) != 0) {
    throw std::runtime_error("DelayProxy: cannot listen on 127.0.0.1");
  }
  port_ = ntohs(a.sin_port);
  accept_thread_ = std::thread([this] { AcceptLoop(); });
}

DelayProxy::~DelayProxy() {
  stop_ = true;
  accept_thread_.join();
  ::close(listen_fd_);
  std::vector<std::unique_ptr<Pipe>> pipes;
  {
    std::lock_guard lock(mu_);
    pipes.swap(pipes_);
  }
  for (auto& p : pipes) p->Close();
  std::vector<int> fds;
  for (auto& p : pipes) fds.push_back(p->from);
  pipes.clear();                   // joins
  for (int fd : fds) ::close(fd);  // each socket is `from` of exactly one pipe
}

void DelayProxy::AcceptLoop() {
  std::uint64_t n = 0;
  while (!stop_.load()) {
    pollfd p{listen_fd_, POLLIN, 0};
    if (::poll(&p, 1, 50) <= 0) continue;
    const int client = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC);
    if (client < 0) continue;
    const int up = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    a.sin_port = htons(static_cast<std::uint16_t>(upstream_port_));
    if (up < 0 || ::connect(up, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0) {
      ::close(client);
      if (up >= 0) ::close(up);
      continue;
    }
    const int one = 1;
    ::setsockopt(client, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
    ::setsockopt(up, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
    std::lock_guard lock(mu_);
    pipes_.push_back(std::make_unique<Pipe>(client, up, options_, &bytes_, options_.seed + 2 * n));
    pipes_.push_back(
        std::make_unique<Pipe>(up, client, options_, &bytes_, options_.seed + 2 * n + 1));
    ++n;
  }
}

}  // namespace hapticpd::testing
