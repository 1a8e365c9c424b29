// A Watch stream read on its own thread that keeps every event, for the
// tests of Watch's options (tests/server/telemetry_test.cc) and of device
// telemetry end to end (tests/client/telemetry_e2e_test.cc).
#pragma once

#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "tests/server/server_harness.h"

namespace hapticpd::testing {

/// A Watch stream read on its own thread, keeping every event.
class Watcher {
 public:
  Watcher(v1::SceneService::Stub& stub, bool contacts, bool telemetry, bool meshes = false,
          double rate_hz = 100)
      : ctx_(Ctx()) {
    v1::WatchRequest req;
    req.set_scene_id("default");
    req.set_rate_hz(rate_hz);
    req.set_include_contacts(contacts);
    req.set_include_telemetry(telemetry);
    req.set_include_meshes(meshes);
    reader_ = stub.Watch(ctx_.get(), req);
    thread_ = std::thread([this] {
      v1::SceneEvent ev;
      while (reader_->Read(&ev)) {
        std::lock_guard lock(mu_);
        events_.push_back(ev);
      }
    });
  }
  ~Watcher() { Stop(); }
  void Stop() {
    if (!thread_.joinable()) return;
    ctx_->TryCancel();
    thread_.join();
    reader_->Finish();
  }
  std::vector<v1::SceneEvent> events() const {
    std::lock_guard lock(mu_);
    return events_;
  }
  /// Waits until some event satisfies `pred`.
  bool WaitFor(const std::function<bool(const v1::SceneEvent&)>& pred) {
    return WaitUntil([&] {
      std::lock_guard lock(mu_);
      for (const auto& e : events_) {
        if (pred(e)) return true;
      }
      return false;
    });
  }

 private:
  std::unique_ptr<grpc::ClientContext> ctx_;
  std::unique_ptr<grpc::ClientReader<v1::SceneEvent>> reader_;
  std::thread thread_;
  mutable std::mutex mu_;
  std::vector<v1::SceneEvent> events_;
};

inline bool Removed(const v1::SceneEvent& e, const std::string& id) {
  if (!e.has_sessions()) return false;
  for (const auto& r : e.sessions().removed()) {
    if (r == id) return true;
  }
  return false;
}
inline bool Added(const v1::SceneEvent& e, const std::string& id) {
  if (!e.has_sessions()) return false;
  for (const auto& a : e.sessions().added()) {
    if (a.session_id() == id) return true;
  }
  return false;
}

}  // namespace hapticpd::testing
