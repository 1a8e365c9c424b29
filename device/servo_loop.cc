#include "device/servo_loop.h"

#include <pthread.h>
#include <sched.h>
#include <time.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <utility>

#include "device/math.h"
#include "pd/enum_names.h"

namespace hapticpd::device {

namespace {
// Run fires catch-up ticks while it is at most this many periods behind, and
// resyncs beyond.
constexpr int kCatchUpPeriods = 5;
}  // namespace

std::int64_t SteadyClock::NowNs() const {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

const SteadyClock& SteadyClock::Instance() {
  static const SteadyClock clock;
  return clock;
}

namespace {
constexpr std::pair<DeviceStatus, const char*> kDeviceStatusNames[] = {
    {DeviceStatus::kOk, "ok"},
    {DeviceStatus::kNotOpen, "not-open"},
    {DeviceStatus::kEndOfData, "end-of-data"},
    {DeviceStatus::kError, "error"}};
constexpr std::pair<TickSource, const char*> kTickSourceNames[] = {
    {TickSource::kServer, "server"}, {TickSource::kLocal, "local"}, {TickSource::kFaded, "faded"}};
constexpr std::pair<FailSafe, const char*> kFailSafeNames[] = {{FailSafe::kWaiting, "waiting"},
                                                               {FailSafe::kRamping, "ramping"},
                                                               {FailSafe::kOk, "ok"},
                                                               {FailSafe::kFading, "fading"},
                                                               {FailSafe::kStale, "stale"}};
}  // namespace

const char* ToString(DeviceStatus s) { return EnumName<kDeviceStatusNames>(s, "?"); }
const char* ToString(TickSource s) { return EnumName<kTickSourceNames>(s, "?"); }
const char* ToString(FailSafe s) { return EnumName<kFailSafeNames>(s, "?"); }

ServoLoop::ServoLoop(HapticDevice* device, const ServoConfig& config, const Clock* clock)
    : device_(device),
      config_(config),
      clock_(clock),
      coupling_(config.coupling ? *config.coupling : ChooseCoupling(device->info(), config.design)),
      eval_(config.ir),
      samples_(config.sample_ring_capacity) {
  // Compose the declared effects once; a scene without torque renders 3-DoF.
  EffectParams fx = config_.effect_params;
  fx.proxy_mass = coupling_.proxy.mass;
  fx.period_s = config_.period_s;
  effects_ = EffectPipeline(config_.effects, fx);
  if (!config_.effects.Has(Effect::kTorque)) coupling_.gains.max_torque = 0;
}

ServoLoop::~ServoLoop() { Stop(); }

void ServoLoop::ClearStats() { stats_.Clear(); }

void ServoLoop::ResetContact() {
  eval_.Reset();
  effects_.Reset();
  engaged_ = false;
  quiet_count_ = 0;
  startup_gain_ = 0;
  link_lost_ = false;
  stale_last_tick_ = false;
}

void ServoLoop::Tick(std::int64_t now_ns) {
  const std::int64_t t_begin = SteadyClock::Instance().NowNs();
  const double h = config_.period_s;
  TickRecord& r = rec_;
  r.tick = stats_.ticks + 1;
  r.time_ns = now_ns;
  r.new_ir = false;
  const double dt = MeasurePeriod(now_ns);
  if (!ReadDevice(&r)) {
    PushSample(r);
    ++stats_.ticks;
    return;
  }
  const Mat3& R_WD = config_.X_WD.R;
  const Vec3 v_WH = R_WD * r.state.v_DH_D;
  const Vec3 w_WH = R_WD * r.state.w_DH_D;
  if (!proxy_init_) {
    proxy_.X_WP = r.X_WH;
    proxy_.v_W = v_WH;
    proxy_.w_W = w_WH;
    proxy_init_ = true;
  }
  TakeLinkRequestsAndIr(&r);
  StepProxyAgainstContact(now_ns, h, dt, v_WH, w_WH, &r);
  UpdateLinkFade(dt, h, v_WH, w_WH, &r);
  ClassifySource(&r);
  r.proxy = proxy_;
  r.wrench_coupling = CouplingWrench(coupling_.gains, r.X_WH, v_WH, w_WH, proxy_, &r.clamped);
  if (r.clamped) ++stats_.clamped_ticks;
  UpdateStartup(h, &r);
  r.fail_safe = FailSafeOf(r);
  CommandDevice(&r);
  AccumulateForceAndEnergy(r, dt, v_WH, w_WH);
  PublishProxy(r, now_ns);
  PushSample(r);
  ++stats_.ticks;
  live_.ticks.store(stats_.ticks, std::memory_order_relaxed);
  stats_.compute_us.Add(1e-3 * static_cast<double>(SteadyClock::Instance().NowNs() - t_begin));
}

double ServoLoop::MeasurePeriod(std::int64_t now_ns) {
  // Period statistics (from the loop's own clock).
  double dt = config_.period_s;
  if (stats_.ticks > 0) {
    dt = 1e-9 * static_cast<double>(now_ns - last_tick_ns_);
    stats_.period_us.Add(dt * 1e6);
    if (dt > 1.5 * config_.period_s) {
      ++stats_.late_ticks;
      live_.late_ticks.fetch_add(1, std::memory_order_relaxed);
    }
  }
  last_tick_ns_ = now_ns;
  return dt;
}

bool ServoLoop::ReadDevice(TickRecord* r) {
  r->device_status = device_->Read(&r->state);
  if (r->device_status != DeviceStatus::kOk && r->device_status != DeviceStatus::kEndOfData) {
    // A device that cannot be read gets zero output at once.
    ++stats_.device_errors;
    r->F_cmd_D = Wrench{};
    r->F_cmd_W = Wrench{};
    device_->Command(r->F_cmd_D);
    r->source = TickSource::kFaded;
    r->fail_safe = FailSafeOf(*r);
    return false;
  }
  r->X_WH = config_.X_WD * r->state.X_DH;
  return true;
}

void ServoLoop::TakeLinkRequestsAndIr(TickRecord* r) {
  if (link_request_.load(std::memory_order_relaxed) != kLinkNone) {
    const int request = link_request_.exchange(kLinkNone, std::memory_order_acq_rel);
    if (request == kLinkReset) {
      ResetContact();
    } else if (request == kLinkLost) {
      eval_.Expire();
      link_lost_ = true;
    }
  }
  if (ir_in_.Fetch() && !link_lost_) {
    eval_.Accept(ir_in_.front(), proxy_.X_WP);
    r->new_ir = true;
    ++stats_.ir_updates;
    live_.ir_updates.fetch_add(1, std::memory_order_relaxed);
  }
}

void ServoLoop::StepProxyAgainstContact(std::int64_t now_ns, double h, double dt, const Vec3& v_WH,
                                        const Vec3& w_WH, TickRecord* r) {
  Mat6 K_ir;
  eval_.Evaluate(proxy_.X_WP, now_ns, h, &r->wrench_ir, &K_ir, &r->ir);
  if (r->ir.have_ir) {
    stats_.ir_age_ms.Add(r->ir.age_s * 1e3);
    if (r->ir.stale) ++stats_.stale_ticks;
    if (r->ir.outside_validity) ++stats_.outside_ticks;
  }
  // Effects hook (effects.h): only the stages the scene declared run.
  Mat6 K_fx;
  effects_.Apply(EffectInput{&eval_.current(), r->wrench_ir, K_ir, proxy_.X_WP, proxy_.v_W,
                             proxy_.w_W, 1e-9 * static_cast<double>(now_ns)},
                 &r->wrench_effects, &K_fx);
  r->contact_weight = config_.free_space_follows_handle
                          ? ContactWeight(r->ir.max_depth, config_.free_space_margin_m)
                          : 1.0;
  // The handle moves in real time and the step is one period: a late tick
  // finds the handle more than a period's motion on, and the catch-up ticks
  // after it find it barely moved, so the proxy would lag, then overshoot,
  // and the hand feel a tap in free space. Away from contact the proxy is
  // carried by the handle's motion over the difference, weighted like the
  // free-space damping; in contact it is not moved (and a still hand moves
  // nothing anywhere). Within Run's catch-up span the handle's velocity
  // stands for that motion, and the catch-up ticks carry back what the late
  // one carried on. After a longer stall Run resyncs and no catch-up tick
  // follows: the proxy is carried by the handle's whole motion since the
  // last tick, less the period's worth the step accounts for. This holds
  // whatever the IR's state: without a fresh IR whose validity region holds
  // the proxy (none yet, stale, or answering a pose the proxy has left, as
  // under long delays) nothing pushes on the proxy, and its own dynamics
  // would take it to the handle within a few ticks anyway; carried, it gets
  // there without the tap. Where rows still say the proxy is near a surface,
  // the contact weight keeps it from being carried.
  // Before the step, so the step sees the stretch a period's motion left.
  const double carry = 1.0 - r->contact_weight;
  if (carry > 0 && dt > kCatchUpPeriods * h && have_last_handle_) {
    proxy_.X_WP.t += carry * ((r->X_WH.t - X_WH_last_.t) - h * v_WH);
    const Vec3 turn = internal::LogRotation(internal::ExpRotation(-h * w_WH) * r->X_WH.R *
                                            X_WH_last_.R.transpose());
    proxy_.X_WP.R = internal::Orthonormalize(internal::ExpRotation(carry * turn) * proxy_.X_WP.R);
  } else if (carry > 0 && dt != h) {
    const double lag_s = carry * (std::clamp(dt, 0.0, kCatchUpPeriods * h) - h);
    proxy_.X_WP.t += lag_s * v_WH;
    proxy_.X_WP.R = internal::Orthonormalize(internal::ExpRotation(lag_s * w_WH) * proxy_.X_WP.R);
  }
  X_WH_last_ = r->X_WH;
  have_last_handle_ = true;
  StepProxy(coupling_, r->X_WH, v_WH, w_WH, r->wrench_effects, K_fx, h, &proxy_, r->contact_weight);
  // An IR no valid answer produces (numbers that overflow on their way,
  // from a broken or foreign server) must not leave the proxy non-finite
  // for good: put it back on the handle and drop the IR.
  if (!proxy_.X_WP.t.allFinite() || !proxy_.X_WP.R.allFinite() || !proxy_.v_W.allFinite() ||
      !proxy_.w_W.allFinite()) {
    proxy_.X_WP = r->X_WH;
    proxy_.v_W = v_WH;
    proxy_.w_W = w_WH;
    eval_.Reset();
    ++stats_.nonfinite_resets;
  }
}

void ServoLoop::UpdateLinkFade(double dt, double h, const Vec3& v_WH, const Vec3& w_WH,
                               TickRecord* r) {
  // Link loss (stale IR): fade the output to zero in real time (a late tick
  // within a loss fades faster); once it is zero, hold the proxy on the handle so the
  // coupling stretches nothing and nothing stale is felt when IRs return.
  // The ramp back counts ticks (a late tick never makes it a step).
  // A late tick is no evidence of a lost link: the IR's age then includes
  // the loop's own stall, and on one machine that is most often a stall of
  // the whole process, the session's and the local model's threads with
  // it. Fading there (in one step, as the stall is longer than the fade)
  // would put the proxy on a handle that sank meanwhile, inside the body,
  // and the answers a tick later would push it and the hand out with energy
  // nobody put in. The fade starts if the next tick still finds it stale.
  const bool stale = r->ir.have_ir && r->ir.stale;
  const bool late = dt > kCatchUpPeriods * h;
  const bool link_down = stale && (!late || stale_last_tick_ || link_lost_);
  stale_last_tick_ = stale;
  if (link_down) {
    link_gain_ = config_.link_fade_time_s > 0
                     ? std::max(0.0, link_gain_ - dt / config_.link_fade_time_s)
                     : 0.0;
  } else if (!stale && link_gain_ < 1) {  // a stale IR on a late tick holds the gain
    link_gain_ = config_.link_fade_in_time_s > 0
                     ? std::min(1.0, link_gain_ + h / config_.link_fade_in_time_s)
                     : 1.0;
  }
  if (link_gain_ == 0) {
    proxy_.X_WP = r->X_WH;
    proxy_.v_W = v_WH;
    proxy_.w_W = w_WH;
  }
  r->link_gain = link_gain_;
}

void ServoLoop::ClassifySource(TickRecord* r) {
  if (!r->ir.have_ir || r->ir.fade <= 0 || link_gain_ <= 0) {
    ++stats_.ticks_faded;
    r->source = TickSource::kFaded;
  } else if (r->ir.source == 1) {
    ++stats_.ticks_local;
    r->source = TickSource::kLocal;
  } else {
    ++stats_.ticks_server;
    r->source = TickSource::kServer;
  }
}

void ServoLoop::UpdateStartup(double h, TickRecord* r) {
  // Start-up safety: engage once the would-be command has been quiet.
  const StartupParams& su = config_.startup;
  if (!engaged_) {
    const bool quiet =
        r->wrench_coupling.force.norm() < su.quiet_force &&
        (coupling_.gains.max_torque <= 0 || r->wrench_coupling.torque.norm() < su.quiet_torque);
    quiet_count_ = quiet ? quiet_count_ + 1 : 0;
    if (quiet_count_ >= su.quiet_ticks) engaged_ = true;
  } else {
    startup_gain_ = su.ramp_time_s > 0 ? std::min(1.0, startup_gain_ + h / su.ramp_time_s) : 1.0;
  }
  r->startup_gain = startup_gain_;
}

void ServoLoop::CommandDevice(TickRecord* r) {
  const Mat3& R_WD = config_.X_WD.R;
  const double gain = startup_gain_ * link_gain_;
  r->F_cmd_W.force =
      internal::ClampNorm(-gain * r->wrench_coupling.force, coupling_.gains.max_force);
  r->F_cmd_W.torque =
      internal::ClampNorm(-gain * r->wrench_coupling.torque, coupling_.gains.max_torque);
  r->F_cmd_D.force = R_WD.transpose() * r->F_cmd_W.force;
  r->F_cmd_D.torque = R_WD.transpose() * r->F_cmd_W.torque;
  if (device_->Command(r->F_cmd_D) != DeviceStatus::kOk) ++stats_.device_errors;
}

void ServoLoop::AccumulateForceAndEnergy(const TickRecord& r, double dt, const Vec3& v_WH,
                                         const Vec3& w_WH) {
  // Force statistics and energy into the hand. The wrench of the previous
  // tick was held over the interval that just ended; its work is estimated
  // with the mean of the velocities at both ends.
  const double F = r.F_cmd_W.force.norm();
  const double T = r.F_cmd_W.torque.norm();
  stats_.max_force = std::max(stats_.max_force, F);
  stats_.max_torque = std::max(stats_.max_torque, T);
  if (stats_.ticks > 0) {
    stats_.max_dforce = std::max(stats_.max_dforce, (r.F_cmd_W.force - last_cmd_W_.force).norm());
    stats_.max_dtorque =
        std::max(stats_.max_dtorque, (r.F_cmd_W.torque - last_cmd_W_.torque).norm());
    stats_.energy_into_hand_j += dt * (last_cmd_W_.force.dot(0.5 * (v_WH + last_v_W_)) +
                                       last_cmd_W_.torque.dot(0.5 * (w_WH + last_w_W_)));
    stats_.passivity_min_j = std::min(stats_.passivity_min_j, -stats_.energy_into_hand_j);
  }
  last_cmd_W_ = r.F_cmd_W;
  last_v_W_ = v_WH;
  last_w_W_ = w_WH;
  live_.last_force.store(F, std::memory_order_relaxed);
}

void ServoLoop::PublishProxy(const TickRecord& r, std::int64_t now_ns) {
  ProxySample& s = proxy_out_.back();
  s.sequence = stats_.ticks + 1;
  s.time_ns = now_ns;
  s.X_WP = proxy_.X_WP;
  s.X_WA = proxy_.X_WP * config_.X_PA;
  s.v_W = proxy_.v_W;
  s.w_W = proxy_.w_W;
  s.X_WH = r.X_WH;
  s.F_cmd_W = r.F_cmd_W;
  if (config_.recorder != nullptr) {
    config_.recorder->OnTick(r, s, eval_.has_ir() ? &eval_.current() : nullptr);
  }
  proxy_out_.Publish();
}

FailSafe ServoLoop::FailSafeOf(const TickRecord& r) const {
  if (!r.ir.have_ir) return FailSafe::kWaiting;
  if (r.ir.stale) return link_gain_ > 0 ? FailSafe::kFading : FailSafe::kStale;
  if (!engaged_) return FailSafe::kWaiting;
  if (startup_gain_ < 1 || link_gain_ < 1) return FailSafe::kRamping;
  return FailSafe::kOk;
}

void ServoLoop::PushSample(const TickRecord& r) {
  if (config_.sample_ring_capacity == 0) return;
  TickSample s;
  s.time_ns = r.time_ns;
  s.force = static_cast<float>(r.F_cmd_W.force.norm());
  s.torque = static_cast<float>(r.F_cmd_W.torque.norm());
  s.ir_age_ms = r.ir.have_ir ? static_cast<float>(r.ir.age_s * 1e3) : -1.0F;
  s.source = r.source;
  s.fail_safe = r.fail_safe;
  samples_.Push(s);
}

void ServoLoop::Start() {
  if (thread_.joinable()) return;
  thread_ = std::jthread([this](std::stop_token st) { Run(st); });
}

void ServoLoop::Stop() {
  if (!thread_.joinable()) return;
  thread_.request_stop();
  thread_.join();
  thread_ = std::jthread();
}

namespace {
timespec ToTimespec(std::int64_t ns) {
  timespec ts;
  ts.tv_sec = static_cast<time_t>(ns / 1'000'000'000);
  ts.tv_nsec = static_cast<long>(ns % 1'000'000'000);
  return ts;
}
}  // namespace

void ServoLoop::Run(std::stop_token st) {
  if (config_.realtime_priority > 0) {
    sched_param sp{};
    sp.sched_priority = config_.realtime_priority;
    got_rt_.store(pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp) == 0);
  }
  const auto period = static_cast<std::int64_t>(config_.period_s * 1e9);
  const auto spin = static_cast<std::int64_t>(config_.spin_s * 1e9);
  // The deadlines are on CLOCK_MONOTONIC, the clock SteadyClock reads; a
  // custom clock only timestamps the ticks.
  const SteadyClock& mono = SteadyClock::Instance();
  std::int64_t deadline = mono.NowNs() + period;
  while (!st.stop_requested()) {
    const timespec wake = ToTimespec(deadline - spin);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &wake, nullptr) == EINTR) {
    }
    while (mono.NowNs() < deadline) {
    }
    Tick(clock_ == &mono ? mono.NowNs() : clock_->NowNs());
    deadline += period;
    // Fell behind by more than a few periods (debugger, suspend): resync
    // rather than firing a burst of catch-up ticks.
    const std::int64_t now = mono.NowNs();
    if (now > deadline + kCatchUpPeriods * period) deadline = now + period;
  }
  device_->Command(Wrench{});
}

}  // namespace hapticpd::device
