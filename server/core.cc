#include "server/core.h"

#include "hapticpd/v1/haptic.pb.h"

namespace hapticpd::server::internal {

std::shared_ptr<spdlog::logger> Log() {
  static std::shared_ptr<spdlog::logger> logger = [] {
    auto l = spdlog::default_logger()->clone("server");
    return l;
  }();
  return logger;
}

JobQueue::JobQueue(int threads) {
  for (int i = 0; i < threads; ++i) threads_.emplace_back([this] { Loop(); });
}

JobQueue::~JobQueue() { Stop(); }

bool JobQueue::Submit(std::function<void()> job) {
  {
    std::lock_guard lock(mu_);
    if (stopping_) return false;
    jobs_.push_back(std::move(job));
  }
  cv_.notify_one();
  return true;
}

void JobQueue::Stop() {
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

void JobQueue::Loop() {
  for (;;) {
    std::function<void()> job;
    {
      std::unique_lock lock(mu_);
      cv_.wait(lock, [&] { return stopping_ || !jobs_.empty(); });
      if (jobs_.empty()) return;
      job = std::move(jobs_.front());
      jobs_.pop_front();
    }
    job();
  }
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

}  // namespace hapticpd::server::internal
