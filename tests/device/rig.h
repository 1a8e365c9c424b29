// A closed haptic loop in simulated time for the device tests: a simulated
// hand + handle, the servo loop, and an in-process PDt source, all stepped
// from one ManualClock (nothing depends on wall time).
#pragma once

#include <functional>
#include <memory>
#include <vector>

#include "device/local_pd_source.h"
#include "device/servo_loop.h"
#include "device/simulated_device.h"
#include "pd/shapes.h"

namespace hapticpd::device::testing {

struct Rig {
  ManualClock clock;
  std::unique_ptr<SimulatedDevice> device;
  std::unique_ptr<LocalPdIrSource> source;
  std::unique_ptr<ServoLoop> loop;
  std::int64_t tick = 0;
  /// The time of tick n (ns) given the previous tick's; unset: n ms, the
  /// loop's period exactly. Tests of late ticks set it.
  std::function<std::int64_t(std::int64_t n, std::int64_t previous_ns)> tick_time_ns;

  Rig(const ScriptParams& script, pd::ModelPtr probe, std::vector<pd::SceneBody> scene,
      ServoConfig config = {}, const LocalPdOptions& options = {}) {
    device = std::make_unique<SimulatedDevice>(script, &clock);
    device->Open();
    source = std::make_unique<LocalPdIrSource>(std::move(probe), std::move(scene), options);
    config.X_PA = source->X_PA();
    loop = std::make_unique<ServoLoop>(device.get(), config, &clock);
  }

  double time_s() const { return 1e-9 * static_cast<double>(clock.NowNs()); }

  /// One servo tick then one pump of the PD source.
  void Step(bool stalled = false) {
    ++tick;
    clock.Set(tick_time_ns ? tick_time_ns(tick, clock.NowNs()) : tick * 1'000'000);
    loop->Tick(clock.NowNs());
    source->Pump(loop.get(), clock.NowNs(), stalled);
  }

  /// Runs for `seconds`; `each` sees every tick's record.
  void Run(double seconds, const std::function<void(const TickRecord&)>& each = nullptr,
           const std::function<bool(double)>& stalled = nullptr) {
    const auto n = static_cast<std::int64_t>(seconds * 1000 + 0.5);
    for (std::int64_t i = 0; i < n; ++i) {
      Step(stalled ? stalled(time_s() + 1e-3) : false);
      if (each) each(loop->last_tick());
    }
  }
};

/// A 2 cm cube probe and a 20 x 20 x 10 cm box whose top face is z = 0.05.
inline pd::ModelPtr CubeProbe() { return pd::MakeModel(pd::shapes::Box(Vec3::Constant(0.01))); }
inline constexpr double kProbeHalf = 0.01;
inline constexpr double kBoxTop = 0.05;
inline std::vector<pd::SceneBody> BoxScene(double stiffness = 5000) {
  pd::Material m;
  m.stiffness = stiffness;
  return {{pd::MakeModel(pd::shapes::Box(Vec3(0.1, 0.1, 0.05))), Pose::Identity(), m}};
}

/// Start pose with the probe's bottom `clearance` above z = top.
inline Pose StartAbove(double top, double clearance) {
  return StartPoseAbove(Vec3(0, 0, top - 1), Vec3(0, 0, top), clearance + kProbeHalf);
}

}  // namespace hapticpd::device::testing
