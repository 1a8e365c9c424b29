// Virtual coupling: gains inside the device's limits, critically damped
// proxy, Colgate's passivity bound, and a closed loop against a stiff
// static wall that must not put energy into the hand.
#include "device/coupling.h"

#include <gtest/gtest.h>

#include <cmath>

#include "device/servo_loop.h"
#include "device/simulated_device.h"

namespace hapticpd::device {
namespace {

// Proxy response to a 1 cm handle step (handle held still): returns the
// largest overshoot (m) and the time (s) to come within 2% of the step.
std::pair<double, double> StepResponse(const Coupling& c) {
  ProxyState p;
  const Pose X_WH = Pose::FromTranslation(Vec3(0.01, 0, 0));
  double overshoot = 0, settle = -1;
  for (int i = 1; i <= 500; ++i) {
    StepProxy(c, X_WH, Vec3::Zero(), Vec3::Zero(), Vec6::Zero(), Mat6::Zero(), 1e-3, &p);
    overshoot = std::max(overshoot, p.X_WP.t.x() - 0.01);
    if (std::abs(p.X_WP.t.x() - 0.01) > 0.0002)
      settle = -1;
    else if (settle < 0)
      settle = i * 1e-3;
  }
  return {overshoot, settle};
}

TEST(Coupling, GainsStayInsideTheDeviceLimits) {
  const DeviceInfo info = SimulatedDeviceInfo();
  const Coupling c = ChooseCoupling(info);
  EXPECT_GT(c.gains.k_lin, 0);
  EXPECT_LE(c.gains.k_lin, info.max_linear_stiffness);
  EXPECT_LE(c.gains.b_lin, info.max_linear_damping);
  EXPECT_LE(c.gains.k_ang, info.max_angular_stiffness);
  EXPECT_LE(c.gains.b_ang, info.max_angular_damping);
  EXPECT_EQ(c.gains.max_force, info.max_force);
  // 3-DoF actuated: no torque output, but the proxy still follows rotation.
  DeviceInfo falcon = info;
  falcon.dof_actuated = 3;
  falcon.max_torque = 0;
  const Coupling f = ChooseCoupling(falcon);
  EXPECT_EQ(f.gains.max_torque, 0);
  EXPECT_GT(f.gains.k_ang, 0);
}

TEST(Coupling, PassivityBoundHoldsForTheChosenGains) {
  // Colgate: the handle's physical damping must exceed k T/2 + b.
  const Coupling c = ChooseCoupling(SimulatedDeviceInfo());
  const HandModel hand;
  const auto [b_lin, b_ang] = MinPhysicalDamping(c.gains, 1e-3);
  EXPECT_LT(b_lin, hand.handle_damping);
  EXPECT_LT(b_ang, hand.handle_ang_damping);
  // Even at the device's full limits.
  CouplingDesign full;
  full.stiffness_fraction = full.damping_fraction = 1;
  const auto [bl, ba] = MinPhysicalDamping(ChooseCoupling(SimulatedDeviceInfo(), full).gains, 1e-3);
  EXPECT_LT(bl, hand.handle_damping);
  EXPECT_LT(ba, hand.handle_ang_damping);
}

TEST(Coupling, CriticallyDampedStepResponse) {
  const Coupling c = ChooseCoupling(SimulatedDeviceInfo());
  const double omega = CouplingDesign{}.omega_lin;
  const auto [overshoot, settle] = StepResponse(c);
  EXPECT_LT(overshoot, 1e-6);  // no overshoot
  // A critically damped second-order system is within 2% after ~5.8/omega
  // (implicit Euler adds a little lag).
  EXPECT_GT(settle, 4.0 / omega);
  EXPECT_LT(settle, 9.0 / omega);
  // The same proxy with a fifth of the damping overshoots: the check can tell.
  Coupling under = c;
  under.proxy.lin_damping *= 0.2;
  under.gains.b_lin *= 0.2;
  EXPECT_GT(StepResponse(under).first, 1e-4);
}

TEST(Coupling, StretchIsClampedToTheForceLimit) {
  const Coupling c = ChooseCoupling(SimulatedDeviceInfo());
  ProxyState p;
  bool clamped = false;
  const Wrench w = CouplingWrench(c.gains, Pose::FromTranslation(Vec3(0, 0, -0.5)), Vec3::Zero(),
                                  Vec3::Zero(), p, &clamped);
  EXPECT_TRUE(clamped);
  EXPECT_NEAR(w.force.norm(), c.gains.max_force, 1e-9);
  EXPECT_NEAR(w.force.z(), -c.gains.max_force, 1e-9);
}

// A fixed IR: a 20 kN/m floor under the handle's start (20x the coupling).
class FloorSource {
 public:
  explicit FloorSource(double top) {
    ir_.num_rows = 1;
    ir_.rows[0].n_W = Vec3::UnitZ();
    ir_.rows[0].stiffness = 20000;
    top_ = top;
  }
  // A new linearisation at the proxy's pose every tick (as a fast server would).
  void Feed(ServoLoop* loop, std::int64_t now) {
    if (!loop->proxy_mailbox().Fetch()) return;
    const ProxySample& s = loop->proxy_mailbox().front();
    ir_.X_WP_ref = s.X_WP;
    ir_.rows[0].p_W = Vec3(s.X_WP.t.x(), s.X_WP.t.y(), top_);
    ir_.rows[0].m_W = (ir_.rows[0].p_W - s.X_WP.t).cross(Vec3::UnitZ());
    ir_.rows[0].depth = std::max(0.0, top_ - s.X_WP.t.z());
    ir_.receive_time_ns = now;
    loop->ir_mailbox().Write(ir_);
  }

 private:
  IntermediateRep ir_;
  double top_;
};

double RunAgainstFloor(HandScript script, const CouplingDesign& design, double* observer_min,
                       double* max_force) {
  ManualClock clock;
  ScriptParams sp;
  sp.script = script;
  sp.X_DS = Pose::FromTranslation(Vec3(0, 0, 0.005));
  sp.travel = 0.02;
  sp.duration_s = 2;
  SimulatedDevice dev(sp, &clock);
  dev.Open();
  ServoConfig cfg;
  cfg.design = design;
  ServoLoop loop(&dev, cfg, &clock);
  FloorSource floor(0.0);
  for (int i = 1; i <= 2500; ++i) {
    clock.Set(i * 1'000'000LL);
    loop.Tick(clock.NowNs());
    floor.Feed(&loop, clock.NowNs());
  }
  *observer_min = loop.stats().passivity_min_j;
  *max_force = loop.stats().max_force;
  return dev.energy_into_hand_j();
}

TEST(Coupling, ClosedLoopAgainstStiffWallPutsNoEnergyIntoTheHand) {
  for (HandScript s : {HandScript::kPress, HandScript::kLoop, HandScript::kCircle}) {
    double obs_min = 0, fmax = 0;
    const double e = RunAgainstFloor(s, CouplingDesign{}, &obs_min, &fmax);
    SCOPED_TRACE(ToString(s));
    EXPECT_GT(fmax, 1.0);       // it did touch
    EXPECT_LT(e, 1e-4);         // J over the closed path
    EXPECT_GT(obs_min, -1e-4);  // the passivity observer never goes (meaningfully) negative
  }
}

}  // namespace
}  // namespace hapticpd::device
