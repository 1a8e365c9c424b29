// The 1 kHz servo loop (../shared/docs/HAPTICS.md): per tick, read the
// device, render the latest IR at the proxy, integrate the proxy under the IR
// wrench and the virtual coupling, command minus the coupling wrench clamped
// to the device's limits, publish the proxy pose. The tick never allocates,
// locks or logs; IRs come in and proxy poses go out through LatestMailboxes,
// so the producer (a network Session, or LocalPdIrSource) runs on its own
// thread at its own pace.
//
// Two ways to run it: Tick(now_ns) steps it once (tests drive it with a
// ManualClock, so nothing depends on wall time), and Start()/Stop() run it on
// its own thread at absolute deadlines (clock_nanosleep TIMER_ABSTIME on
// CLOCK_MONOTONIC, then a short spin).
#pragma once

#include <atomic>
#include <cstdint>
#include <optional>
#include <thread>

#include "device/coupling.h"
#include "device/effects.h"
#include "device/haptic_device.h"
#include "device/ir.h"
#include "device/mailbox.h"
#include "device/spsc_ring.h"
#include "device/stats.h"

namespace hapticpd::device {

class TickRecorder;

/// The proxy pose the loop publishes every tick (what a Session sends to the
/// server as a ProbePose, and what LocalPdIrSource computes PD for).
struct ProxySample {
  std::uint64_t sequence = 0;  ///< tick number, strictly increasing from 1
  std::int64_t time_ns = 0;    ///< loop clock at the tick
  Pose X_WP;                   ///< proxy (centre-of-mass) frame
  Pose X_WA;                   ///< probe mesh frame: X_WP * X_PA
  Vec3 v_W = Vec3::Zero();
  Vec3 w_W = Vec3::Zero();
  Pose X_WH;       ///< the device handle, for observers
  Wrench F_cmd_W;  ///< wrench commanded on the handle this tick (W)
};

/// Which model a tick's contact came from (v1::ContactSource on the wire).
enum class TickSource : std::uint8_t { kServer = 1, kLocal = 2, kFaded = 3 };
/// The loop's output safety at a tick (v1::FailSafeState on the wire):
/// waiting (no IR, or the start-up wait for a quiet command), ramping (the
/// start-up ramp or the fade-in after a link loss), ok (full output on a
/// fresh IR), fading (the IR went stale: output fading to zero), stale
/// (faded out: zero output, the proxy held on the handle).
enum class FailSafe : std::uint8_t { kWaiting = 1, kRamping = 2, kOk = 3, kFading = 4, kStale = 5 };
const char* ToString(TickSource s);
const char* ToString(FailSafe s);

/// One tick as telemetry sees it (ServoLoop::samples()).
struct TickSample {
  std::int64_t time_ns = 0;  ///< loop clock at the tick
  float force = 0;           ///< N, |F_cmd| commanded on the handle
  float torque = 0;          ///< N m, |tau_cmd|
  float ir_age_ms = -1;      ///< age of the IR rendered; < 0: no IR
  TickSource source = TickSource::kFaded;
  FailSafe fail_safe = FailSafe::kWaiting;
};
using SampleRing = SpscRing<TickSample>;

using IrMailbox = LatestMailbox<IntermediateRep>;
using ProxyMailbox = LatestMailbox<ProxySample>;

/// CHAI3D's start-up safety: output stays zero until the would-be command has
/// been small for `quiet_ticks` ticks in a row, then ramps up linearly.
struct StartupParams {
  double quiet_force = 0.5;    ///< N
  double quiet_torque = 0.02;  ///< N m
  int quiet_ticks = 20;
  double ramp_time_s = 0.2;
};

struct ServoConfig {
  double period_s = 0.001;
  /// Coupling gains and proxy; when unset, ChooseCoupling(device.info(), design).
  std::optional<Coupling> coupling;
  CouplingDesign design;
  IrEvalParams ir;
  StartupParams startup;
  /// Link loss: once the IR is stale (no answer for ir.max_age_s, e.g. the
  /// server went away, or RequestLinkLost), the commanded wrench fades to
  /// exactly zero over this time (s) and the proxy is then held on the
  /// handle, so no coupling stretch survives the loss; when fresh IRs come
  /// again it ramps back over link_fade_in_time_s. Both are measured on the
  /// loop's clock. This is the only fade on link loss: the IR's own fade
  /// (IrEvalParams::fade_time_s) is for leaving its validity region. A
  /// late tick (more than the catch-up span after the last) that finds the
  /// IR stale holds the gain, neither fading nor ramping back: the IR's age
  /// then holds the loop's own stall, most often the whole process's, whose
  /// next answer is a tick away; the fade starts if the next tick still
  /// finds the IR stale (RequestLinkLost fades at once).
  double link_fade_time_s = 0.020;
  double link_fade_in_time_s = 0.100;
  /// m: within this distance of a contact row's surface (and inside it) the
  /// proxy damps against the world; farther out, against the handle, so
  /// free motion is not dragged (coupling.h, ContactWeight).
  double free_space_margin_m = 1e-3;
  /// False: the proxy damps against the world everywhere (free motion is
  /// dragged by that damping, as before the margin existed).
  bool free_space_follows_handle = true;
  Pose X_WD;  ///< device base frame in the world
  Pose X_PA;  ///< probe mesh frame A in the proxy frame P (P: at the probe's centre of mass)
  /// Real-time runner: spin this long before each deadline (after sleeping).
  double spin_s = 50e-6;
  /// Real-time runner: try SCHED_FIFO at this priority (0: do not try).
  int realtime_priority = 80;
  /// The scene's effects (effects.h), composed once at construction.
  /// Without kTorque the loop commands no torque (3-DoF rendering).
  EffectSet effects = EffectSet::ContactAndTorque();
  EffectParams effect_params;  ///< proxy_mass and period_s are set by the loop
  /// Ticks the sample ring (ServoLoop::samples()) holds for its consumer; a
  /// tick that finds it full is counted lost. 0: no ring, no samples.
  std::size_t sample_ring_capacity = 4096;
  /// Sees every tick (not owned; must outlive the loop); null: none.
  TickRecorder* recorder = nullptr;
};

/// Everything one tick saw and did (for tests, traces and the recorder).
struct TickRecord {
  std::uint64_t tick = 0;
  std::int64_t time_ns = 0;
  DeviceStatus device_status = DeviceStatus::kNotOpen;
  DeviceState state;
  Pose X_WH;
  ProxyState proxy;                    ///< after the step
  Vec6 wrench_ir = Vec6::Zero();       ///< contact wrench on the proxy (W, about P)
  Vec6 wrench_effects = Vec6::Zero();  ///< the declared effects' wrench on the proxy
  Wrench wrench_coupling;              ///< coupling wrench on the proxy after the step
  Wrench F_cmd_W;                      ///< commanded on the handle, W
  Wrench F_cmd_D;                      ///< commanded on the handle, D
  IrEvalInfo ir;
  bool new_ir = false;
  double startup_gain = 0;
  double link_gain = 1;  ///< output gain for link loss (1: fresh IR or none yet)
  bool clamped = false;
  /// StepProxy's contact weight this tick: 1 in or near contact, 0 free.
  double contact_weight = 1;
  TickSource source = TickSource::kFaded;  ///< the model this tick's contact came from
  FailSafe fail_safe = FailSafe::kWaiting;
};

/// Sees every tick at its end, on the servo thread (e.g. RecordingDevice,
/// for a replay that shows the proxy and its contacts). OnTick must not
/// allocate, lock or log. `ir` is the IR rendered, or null before the first.
class TickRecorder {
 public:
  virtual ~TickRecorder() = default;
  virtual void OnTick(const TickRecord& r, const ProxySample& s, const IntermediateRep* ir) = 0;
};

/// Counters other threads may read while the loop runs.
struct LiveCounters {
  std::atomic<std::uint64_t> ticks{0};
  std::atomic<std::uint64_t> late_ticks{0};
  std::atomic<std::uint64_t> ir_updates{0};
  std::atomic<double> last_force{0};
};

class ServoLoop {
 public:
  /// `device` must be open and outlive the loop; `clock` is the time base
  /// for the real-time runner and IR ages (tests pass a ManualClock and call
  /// Tick themselves).
  ServoLoop(HapticDevice* device, const ServoConfig& config,
            const Clock* clock = &SteadyClock::Instance());
  ~ServoLoop();
  ServoLoop(const ServoLoop&) = delete;
  ServoLoop& operator=(const ServoLoop&) = delete;

  /// Where IRs go in (one writer: the Session or LocalPdIrSource thread).
  IrMailbox& ir_mailbox() { return ir_in_; }
  /// Where proxy poses come out (one reader).
  ProxyMailbox& proxy_mailbox() { return proxy_out_; }
  /// Every tick's sample, in order (one reader, e.g. a Session's telemetry
  /// step); a tick that finds the ring full is counted in samples().lost().
  SampleRing& samples() { return samples_; }

  /// One servo tick at time now_ns. No allocation, lock or logging.
  void Tick(std::int64_t now_ns);

  /// Runs Tick on a dedicated thread at absolute deadlines until Stop().
  void Start();
  void Stop();
  bool running() const { return thread_.joinable(); }
  /// Whether the real-time thread obtained SCHED_FIFO.
  bool got_realtime_priority() const { return got_rt_.load(); }

  /// Owned by the servo thread: read after Stop(), or between Tick calls.
  const ServoStats& stats() const { return stats_; }
  void ClearStats();
  const TickRecord& last_tick() const { return rec_; }
  const LiveCounters& live() const { return live_; }
  const Coupling& coupling() const { return coupling_; }
  const ServoConfig& config() const { return config_; }
  /// The effect stages this loop runs, and their run counters.
  const EffectPipeline& effects() const { return effects_; }
  /// Forget the IR and re-arm the start-up ramp (e.g. after a reconnect).
  /// Servo thread only (or between Tick calls).
  void ResetContact();
  /// The same from any other thread (a Session on reconnect): the next tick
  /// calls ResetContact() before it takes a new IR. Wait-free.
  void RequestResetContact() { link_request_.store(kLinkReset, std::memory_order_release); }
  /// From any other thread (a Session whose stream has ended): the next tick
  /// treats the IR it holds as stale at once (IrEvaluator::Expire), so the
  /// link fade starts now rather than ir.max_age_s after the last answer,
  /// and drops IRs still in flight until RequestResetContact() (a new
  /// stream). Of the two, the later request wins. Wait-free.
  void RequestLinkLost() { link_request_.store(kLinkLost, std::memory_order_release); }

 private:
  void Run(std::stop_token st);
  /// The output safety state after this tick's gains (r: this tick's record).
  // Tick's stages, in order.
  double MeasurePeriod(std::int64_t now_ns);
  bool ReadDevice(TickRecord* r);  ///< false: unreadable, zero output sent
  void TakeLinkRequestsAndIr(TickRecord* r);
  void StepProxyAgainstContact(std::int64_t now_ns, double h, double dt, const Vec3& v_WH,
                               const Vec3& w_WH, TickRecord* r);
  void UpdateLinkFade(double dt, double h, const Vec3& v_WH, const Vec3& w_WH, TickRecord* r);
  void ClassifySource(TickRecord* r);
  void UpdateStartup(double h, TickRecord* r);
  void CommandDevice(TickRecord* r);
  void AccumulateForceAndEnergy(const TickRecord& r, double dt, const Vec3& v_WH, const Vec3& w_WH);
  void PublishProxy(const TickRecord& r, std::int64_t now_ns);
  FailSafe FailSafeOf(const TickRecord& r) const;
  void PushSample(const TickRecord& r);

  HapticDevice* device_;
  ServoConfig config_;
  const Clock* clock_;
  Coupling coupling_;
  IrEvaluator eval_;
  EffectPipeline effects_;
  IrMailbox ir_in_;
  ProxyMailbox proxy_out_;
  SampleRing samples_;
  ServoStats stats_;
  LiveCounters live_;
  TickRecord rec_;
  ProxyState proxy_;
  bool proxy_init_ = false;
  std::int64_t last_tick_ns_ = 0;
  Pose X_WH_last_;  ///< the handle at the last tick that read the device
  bool have_last_handle_ = false;
  Wrench last_cmd_W_;
  Vec3 last_v_W_ = Vec3::Zero();
  Vec3 last_w_W_ = Vec3::Zero();
  int quiet_count_ = 0;
  double startup_gain_ = 0;
  double link_gain_ = 1;
  bool stale_last_tick_ = false;  // the IR was stale at the last tick
  bool engaged_ = false;
  std::jthread thread_;
  std::atomic<bool> got_rt_{false};
  static constexpr int kLinkNone = 0, kLinkReset = 1, kLinkLost = 2;
  std::atomic<int> link_request_{kLinkNone};
  bool link_lost_ = false;  // RequestLinkLost() taken, no reset since
};

}  // namespace hapticpd::device
