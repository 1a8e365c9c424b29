// A loopback TCP forwarder for tests that adds a one-way delay with jitter
// to each direction of every connection it carries (no netem, no root).
// Bytes keep their order: each read chunk is released at
// max(arrival + delay + U(-jitter, +jitter), previous release).
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

namespace hapticpd::testing {

class DelayProxy {
 public:
  struct Options {
    std::chrono::microseconds delay{0};   ///< one way, each direction
    std::chrono::microseconds jitter{0};  ///< uniform +-jitter on top of delay
    std::uint64_t seed = 1;
  };
  /// Listens on 127.0.0.1 (ephemeral port) and forwards to
  /// 127.0.0.1:`upstream_port`.
  DelayProxy(int upstream_port, Options options);
  ~DelayProxy();
  DelayProxy(const DelayProxy&) = delete;
  DelayProxy& operator=(const DelayProxy&) = delete;

  int port() const { return port_; }
  /// Bytes forwarded so far, both directions.
  std::uint64_t bytes() const { return bytes_.load(); }

 private:
  struct Pipe;
  void AcceptLoop();

  int upstream_port_;
  Options options_;
  int listen_fd_ = -1;
  int port_ = 0;
  std::atomic<bool> stop_{false};
  std::atomic<std::uint64_t> bytes_{0};
  std::thread accept_thread_;
  std::mutex mu_;
  std::vector<std::unique_ptr<Pipe>> pipes_;
};

}  // namespace hapticpd::testing
