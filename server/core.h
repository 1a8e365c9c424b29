// State shared by the services of one server (internal to server/).
#pragma once

#include <grpcpp/support/status.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>

#include "server/auth.h"
#include "server/scene.h"
#include "server/server.h"
#include "server/shard_map.h"
#include "server/stats.h"
#include "server/store.h"

#if defined(HAPTICPD_TSAN)
#include <sanitizer/tsan_interface.h>
#endif

namespace hapticpd::server::internal {

// ThreadSanitizer cannot see gRPC's own synchronisation (the distribution's
// gRPC is not built with -fsanitize=thread), so it would report every hand-over
// of a reactor between gRPC's threads. These state what the callback API
// guarantees: a reaction (On*) runs after the Start*/Finish call or reaction
// that led to it, and OnDone after all of them. GrpcHandOff(this) goes before
// each Start*/Finish (GrpcStart does both, and at the end of each reaction,
// see Reaction), GrpcTakeOver(this) at the start of each reaction and of
// OnDone. The server hands its services to gRPC the same way (see
// ServiceCall): gRPC's threads outlive a server and serve the next one in the
// process. No-ops without TSan.
#if defined(HAPTICPD_TSAN)
inline void GrpcHandOff(const void* reactor) { __tsan_release(const_cast<void*>(reactor)); }
inline void GrpcTakeOver(const void* reactor) { __tsan_acquire(const_cast<void*>(reactor)); }
extern "C" void __tsan_ignore_thread_begin();
extern "C" void __tsan_ignore_thread_end();
#else
inline void GrpcHandOff(const void*) {}
inline void GrpcTakeOver(const void*) {}
#endif

/// A service handler (RAII, first line of each): takes over what
/// HapticServer::Start handed to gRPC with GrpcHandOff(service), and hands
/// what it did back for HapticServer::Shutdown (GrpcTakeOver(ServiceDoneKey)
/// after grpc::Server::Wait). Two keys, so that handlers stay unordered among
/// themselves for TSan.
inline const void* ServiceDoneKey(const void* service) {
  return static_cast<const char*>(service) + 1;
}
class ServiceCall {
 public:
  explicit ServiceCall(const void* service) : service_(service) { GrpcTakeOver(service_); }
  ~ServiceCall() { GrpcHandOff(ServiceDoneKey(service_)); }
  ServiceCall(const ServiceCall&) = delete;
  ServiceCall& operator=(const ServiceCall&) = delete;

 private:
  const void* service_;
};

/// A Start*/Finish of the reactor's base class: GrpcHandOff(reactor), then
/// `start` with TSan not recording the memory accesses made inside it. Those
/// are gRPC's own header code after the hand-off (the base class reads its
/// stream pointer, Finish marks the server context as having sent its
/// metadata), which gRPC orders before it frees the call with its own locks;
/// TSan would pair them with that free. Synchronisation is still seen, and no
/// reaction of ours runs inside a Start*/Finish (gRPC never inlines them).
/// Evaluate arguments that read our members before (capture a copy).
template <class F>
void GrpcStart(const void* reactor, F&& start) {
  GrpcHandOff(reactor);
#if defined(HAPTICPD_TSAN)
  __tsan_ignore_thread_begin();
  start();
  __tsan_ignore_thread_end();
#else
  start();
#endif
}

/// GrpcTakeOver on entry to a reaction, GrpcHandOff when it returns (not in
/// OnDone, which deletes the reactor: call GrpcTakeOver there).
class Reaction {
 public:
  explicit Reaction(const void* reactor) : reactor_(reactor) { GrpcTakeOver(reactor_); }
  ~Reaction() { GrpcHandOff(reactor_); }
  Reaction(const Reaction&) = delete;
  Reaction& operator=(const Reaction&) = delete;

 private:
  const void* reactor_;
};

/// The server's logger ("server"), sharing the default logger's sinks.
std::shared_ptr<spdlog::logger> Log();

/// The pool that runs mesh parsing and BVH builds, off the gRPC threads and
/// off the haptic path. Jobs start in the order they were submitted, except
/// that a job whose client already runs `per_client` jobs waits (and the
/// next job of another client goes first): one client's large upload never
/// holds up another client's small one.
class BuildPool {
 public:
  BuildPool(int threads, int per_client);
  ~BuildPool();
  /// False after Stop() (the job is not run). `client` keys the bound.
  bool Submit(std::string client, std::function<void()> job);
  /// Runs the queued jobs, then joins the threads.
  void Stop();

 private:
  struct Job {
    std::string client;
    std::function<void()> run;
  };
  void Loop();
  const int per_client_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<Job> jobs_;
  std::map<std::string, int> running_;
  bool stopping_ = false;
  std::vector<std::thread> threads_;
};

/// A streaming call the server can end early (shutdown, scene deleted).
class StoppableCall {
 public:
  virtual ~StoppableCall() = default;
  /// Ends the call with `status` as soon as possible. Thread-safe, idempotent.
  virtual void Stop(const grpc::Status& status) = 0;
  virtual const Scene* scene() const = 0;
};

class ObserverPublishers;

struct Core {
  explicit Core(const Limits& l)
      : limits(l), builds(std::max(1, l.build_threads), std::max(1, l.max_builds_per_client)) {}

  Limits limits;
  /// The state directory's database; null when the server keeps everything
  /// in memory only.
  std::unique_ptr<SceneStore> store;
  /// Outcomes of mutations sent with a request id (set by HapticServer::Start).
  std::unique_ptr<RequestLog> requests;
  TokenStore tokens;
  /// Sharded: the map and this process's name in it (null: not sharded).
  std::unique_ptr<const ShardMap> shards;
  std::string shard;
  /// OK when this process may hold scene `id`: always unsharded; sharded,
  /// when the map gives it to `shard`, else FAILED_PRECONDITION naming the owner.
  grpc::Status CheckOwner(const std::string& id) const;
  ChangeSignal signal;
  SceneRegistry scenes{&signal};
  Stats stats;
  BuildPool builds;
  /// Tests only: called on the build thread before each AddBody build with
  /// the body's label (orders builds without timing).
  std::function<void(const std::string& label)> before_build;
  ObserverPublishers* publishers = nullptr;
  std::atomic<bool> shutting_down{false};
  /// The state store and scene files are being loaded (the port is bound and
  /// health answers NOT_SERVING): every call is refused with UNAVAILABLE.
  std::atomic<bool> loading{false};
  std::atomic<int> sessions{0};
  std::atomic<int> observers{0};

  /// Every live reactor that is not a unary default reactor registers here
  /// from its constructor to its OnDone.
  void Register(StoppableCall* call);
  void Unregister(StoppableCall* call);
  /// Stops the calls on `scene` (every call when null).
  void StopCalls(const Scene* scene, const grpc::Status& status);
  int active_calls() const;
  /// Waits until no call is registered or `timeout` passes; true when none is left.
  bool WaitNoCalls(std::chrono::milliseconds timeout);

  /// Writes `fill` durably in one transaction when there is a store (else
  /// OK at once): call it from a write hook, before the change is published.
  grpc::Status Commit(const std::function<void(SceneStore::Txn&)>& fill) {
    return store ? store->Write(fill) : grpc::Status::OK;
  }

  grpc::Status Unavailable() const {
    return grpc::Status(grpc::StatusCode::UNAVAILABLE, "server is shutting down");
  }
  /// UNAVAILABLE while loading or shutting down, else OK: the first check
  /// of every call.
  grpc::Status Gate() const {
    if (loading.load()) {
      return grpc::Status(grpc::StatusCode::UNAVAILABLE,
                          "server is loading its state (health: NOT_SERVING); retry shortly");
    }
    if (shutting_down.load()) return Unavailable();
    return grpc::Status::OK;
  }

 private:
  mutable std::mutex calls_mu_;
  std::condition_variable calls_cv_;
  std::set<StoppableCall*> calls_;
};

/// Whether `mode` is a PD mode the server serves (none, PDt, PDg).
grpc::Status CheckModeSupported(int mode);

/// `s` with its message cut to wire::kMaxStatusMessage bytes when longer (a
/// default gRPC client refuses trailers over 8 KiB and would see "metadata
/// size exceeds limit" instead of the error). Every status a call ends with
/// goes through it.
grpc::Status Bounded(const grpc::Status& s);

/// Who a call comes from, for per-client bounds: its token, or its peer
/// address without the port when the server runs open.
std::string ClientKey(const TokenStore& tokens, const grpc::ServerContextBase& ctx);

}  // namespace hapticpd::server::internal
