// An in-process IR source: PDt of the probe against a scene, computed from
// the servo loop's latest proxy pose (pd/scene_pd.h) and turned into an
// IntermediateRep, exactly what the network Session receives from the
// server in a ContactUpdate. It lets tests, benchmarks and an offline demo
// close the haptic loop without a network, and it is the template for the
// Session: read ProxyMailbox, produce an IR, write IrMailbox.
//
// This is the only part of device/ that links the geometry core (library
// hapticpd_device_localpd); the device library itself knows nothing of PD.
#pragma once

#include <atomic>
#include <cstdint>
#include <deque>
#include <thread>
#include <vector>

#include "device/ir.h"
#include "device/servo_loop.h"
#include "pd/contact_model.h"
#include "pd/scene_pd.h"

namespace hapticpd::device {

struct LocalPdOptions {
  pd::PenetrationRequest request;
  /// Validity region (pd::ContactModelOptions, the proto's definition):
  /// linear radius = fraction * the probe's bounding radius + depth;
  /// angular = that / the probe's radius about its centre of mass.
  double validity_fraction = 0.1;
  /// Synchronous mode (Pump): compute every this many ticks, deliver after
  /// this latency (a deterministic stand-in for the network and PD time).
  int compute_every_ticks = 1;
  int latency_ticks = 1;
};

class LocalPdIrSource {
 public:
  /// The proxy frame P is the probe's mesh frame moved to its centre of
  /// mass: X_PA = X_PA() (a translation). Pass it to ServoConfig::X_PA.
  LocalPdIrSource(pd::ModelPtr probe, std::vector<pd::SceneBody> bodies,
                  const LocalPdOptions& options = {});
  ~LocalPdIrSource();
  LocalPdIrSource(const LocalPdIrSource&) = delete;
  LocalPdIrSource& operator=(const LocalPdIrSource&) = delete;

  Pose X_PA() const;

  /// PD at the sample's probe pose (sample.X_WA) into `ir` (receive time
  /// left for the caller). Allocation-free after warm-up (pd's caches).
  void Compute(const ProxySample& sample, IntermediateRep* ir);

  /// Synchronous, deterministic driver for simulated time: call once per
  /// tick after ServoLoop::Tick(now_ns). Every compute_every_ticks it takes
  /// the newest proxy sample, computes its IR and delivers it into the IR
  /// mailbox latency_ticks later (receive time = delivery time). While
  /// `stalled` is true nothing is computed or delivered (a stalled server).
  void Pump(ServoLoop* loop, std::int64_t now_ns, bool stalled = false);

  /// Threaded driver (real time): waits for new proxy samples, computes and
  /// publishes IRs with receive time from `clock`, until Stop().
  void Start(ServoLoop* loop, const Clock* clock = &SteadyClock::Instance());
  void Stop();

  std::uint64_t computed() const { return computed_.load(); }
  /// Compute times (us) of the threaded driver's PD calls, for benchmarks
  /// (read after Stop()).
  const std::vector<double>& compute_times_us() const { return compute_us_; }

 private:
  pd::ModelPtr probe_;
  std::vector<pd::SceneBody> bodies_;
  LocalPdOptions options_;
  pd::ScenePdData data_;
  pd::ScenePdResult result_;
  pd::ContactModel model_;
  std::uint64_t tick_ = 0;
  struct Pending {
    std::uint64_t due_tick;
    IntermediateRep ir;
  };
  std::deque<Pending> pending_;
  std::jthread thread_;
  std::atomic<std::uint64_t> computed_{0};
  std::vector<double> compute_us_;
};

}  // namespace hapticpd::device
