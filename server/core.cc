#include "server/core.h"

#include <fmt/format.h>

#include <algorithm>

#include "hapticpd/v1/haptic.pb.h"
#include "proto/wire/text.h"

namespace hapticpd::server::internal {

std::shared_ptr<spdlog::logger> Log() {
  static std::shared_ptr<spdlog::logger> logger = [] {
    auto l = spdlog::default_logger()->clone("server");
    return l;
  }();
  return logger;
}

BuildPool::BuildPool(int threads, int per_client) : per_client_(per_client) {
  for (int i = 0; i < threads; ++i) threads_.emplace_back([this] { Loop(); });
}

BuildPool::~BuildPool() { Stop(); }

bool BuildPool::Submit(std::string client, std::function<void()> job) {
  {
    std::lock_guard lock(mu_);
    if (stopping_) return false;
    jobs_.push_back({std::move(client), std::move(job)});
  }
  cv_.notify_all();
  return true;
}

void BuildPool::Stop() {
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  cv_.notify_all();
  for (auto& t : threads_) {
    if (t.joinable()) t.join();
  }
  threads_.clear();
}

void BuildPool::Loop() {
  std::unique_lock lock(mu_);
  for (;;) {
    // The oldest job whose client is under its bound.
    auto next = jobs_.end();
    cv_.wait(lock, [&] {
      next = std::find_if(jobs_.begin(), jobs_.end(), [&](const Job& j) {
        const auto it = running_.find(j.client);
        return it == running_.end() || it->second < per_client_;
      });
      return next != jobs_.end() || (stopping_ && jobs_.empty());
    });
    if (next == jobs_.end()) return;  // stopping, nothing left
    Job job = std::move(*next);
    jobs_.erase(next);
    ++running_[job.client];
    lock.unlock();
    job.run();
    lock.lock();
    if (--running_[job.client] == 0) running_.erase(job.client);
    cv_.notify_all();  // a job of this client may be startable now
  }
}

grpc::Status Core::CheckOwner(const std::string& id) const {
  if (!shards) return grpc::Status::OK;
  const std::string owner = shards->Owner(id);
  if (owner == shard) return grpc::Status::OK;
  if (owner.empty()) {
    return grpc::Status(
        grpc::StatusCode::FAILED_PRECONDITION,
        fmt::format("scene_id: no shard owns scene '{}': no prefix in the shard map {} matches it "
                    "(add a line 'PREFIX SHARD' for it, on every server and the balancer)",
                    wire::Printable(id), shards->path()));
  }
  return grpc::Status(
      grpc::StatusCode::FAILED_PRECONDITION,
      fmt::format("scene_id: scene '{}' belongs to shard '{}' (shard map {}), and this is shard "
                  "'{}': send the call through the balancer with the header x-hapticpd-scene, or "
                  "to '{}'",
                  wire::Printable(id), owner, shards->path(), shard, owner));
}

void Core::Register(StoppableCall* call) {
  std::lock_guard lock(calls_mu_);
  calls_.insert(call);
}

void Core::Unregister(StoppableCall* call) {
  // Notify under the lock: once WaitNoCalls sees no call left, Shutdown may
  // return and the Core (this condition variable) be destroyed, so the last
  // reactor's OnDone must be done with calls_cv_ before the waiter can wake.
  std::lock_guard lock(calls_mu_);
  calls_.erase(call);
  calls_cv_.notify_all();
}

void Core::StopCalls(const Scene* scene, const grpc::Status& status) {
  std::lock_guard lock(calls_mu_);
  for (StoppableCall* c : calls_) {
    if (scene == nullptr || c->scene() == scene) c->Stop(status);
  }
}

int Core::active_calls() const {
  std::lock_guard lock(calls_mu_);
  return static_cast<int>(calls_.size());
}

bool Core::WaitNoCalls(std::chrono::milliseconds timeout) {
  std::unique_lock lock(calls_mu_);
  return calls_cv_.wait_for(lock, timeout, [&] { return calls_.empty(); });
}

grpc::Status CheckModeSupported(int mode) {
  switch (mode) {
    case v1::PD_MODE_NONE:
    case v1::PD_MODE_PDT:
    case v1::PD_MODE_PDG:
      return grpc::Status::OK;
    default:
      return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT,
                          "hello.mode: say which PD mode (PD_MODE_NONE, PD_MODE_PDT, PD_MODE_PDG)");
  }
}

grpc::Status Bounded(const grpc::Status& s) {
  if (s.error_message().size() <= wire::kMaxStatusMessage) return s;
  return grpc::Status(s.error_code(), wire::BoundedMessage(s.error_message()));
}

std::string ClientKey(const TokenStore& tokens, const grpc::ServerContextBase& ctx) {
  if (!tokens.open()) {
    const auto& md = ctx.client_metadata();
    if (auto it = md.find("authorization"); it != md.end()) {
      return "token:" + std::string(it->second.data(), it->second.size());
    }
  }
  // "ipv4:127.0.0.1:54321", "ipv6:[::1]:54321": the address without the port.
  std::string peer = ctx.peer();
  if (const auto colon = peer.rfind(':'); colon != std::string::npos && colon > 5) {
    peer.resize(colon);
  }
  return "peer:" + peer;
}

}  // namespace hapticpd::server::internal
