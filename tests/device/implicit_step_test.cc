// The proxy's stiffness-aware (linearised backward-Euler) step against a
// contact row far stiffer than explicit integration tolerates at 1 kHz with
// the proxy's mass: it must stay stable and settle without ringing. The same
// scenario integrated explicitly (symplectic Euler, in this file) diverges,
// so the test fails if StepProxy ever stops using the rows' stiffness.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "device/coupling.h"
#include "device/ir.h"
#include "device/simulated_device.h"

namespace hapticpd::device {
namespace {

constexpr double kH = 1e-3;  // s, the servo period

struct Trace {
  bool finite = true;
  double first_contact_z = 0;   // where the first tick inside the floor ended (m)
  double min_z = 1e9;           // deepest the proxy went (m)
  double z_10_ticks_later = 0;  // ten ticks after the first contact (m)
  double final_z = 0;           // m
  double final_v = 0;           // m/s
  int crossings = 0;     // sign changes of (z - z_eq) beyond 5% of |z_eq|, after first contact
  double max_abs_z = 0;  // m
};

/// A floor z = 0 with stiffness k (one row, normal +z, under the CoM so it
/// carries no moment), linearised at the origin.
IntermediateRep Floor(double k) {
  IntermediateRep ir;
  ir.X_WP_ref = Pose::Identity();
  ir.num_rows = 1;
  ir.rows[0].p_W = Vec3::Zero();
  ir.rows[0].n_W = Vec3::UnitZ();
  ir.rows[0].m_W = Vec3::Zero();
  ir.rows[0].depth = 0;
  ir.rows[0].stiffness = k;
  return ir;
}

/// The explicit alternative: symplectic Euler on the same forces (coupling,
/// proxy damping, contact), ignoring the contact stiffness in the step.
void ExplicitStep(const Coupling& c, const Pose& X_WH, const Vec6& wrench_ir, ProxyState* p) {
  const Wrench Wc = CouplingWrench(c.gains, X_WH, Vec3::Zero(), Vec3::Zero(), *p, nullptr);
  const Vec3 f = Wc.force - c.proxy.lin_damping * p->v_W + wrench_ir.head<3>();
  p->v_W += kH / c.proxy.mass * f;
  p->X_WP.t += kH * p->v_W;
}

/// The proxy starts 1 mm above the floor falling at 0.1 m/s; the handle is
/// held still 3 mm below the floor, so the coupling presses the proxy on it.
Trace FallOntoFloor(const Coupling& c, double k_row, bool implicit_step, double z_eq) {
  const IntermediateRep ir = Floor(k_row);
  const Pose X_WH = Pose::FromTranslation(Vec3(0, 0, -0.003));
  ProxyState p;
  p.X_WP = Pose::FromTranslation(Vec3(0, 0, 0.001));
  p.v_W = Vec3(0, 0, -0.1);
  Trace t;
  int contact_tick = -1;
  double prev = 0;  // last (z - z_eq) beyond the band
  for (int i = 0; i < 1000; ++i) {
    Vec6 W;
    Mat6 K;
    EvaluateIrRaw(ir, p.X_WP, &W, &K);
    if (implicit_step) {
      StepProxy(c, X_WH, Vec3::Zero(), Vec3::Zero(), W, K, kH, &p);
    } else {
      ExplicitStep(c, X_WH, W, &p);
    }
    const double z = p.X_WP.t.z();
    if (!std::isfinite(z) || std::abs(z) > 1.0) {
      t.finite = false;
      break;
    }
    t.min_z = std::min(t.min_z, z);
    t.max_abs_z = std::max(t.max_abs_z, std::abs(z));
    if (contact_tick < 0 && z < 0) contact_tick = i, t.first_contact_z = z;
    if (contact_tick >= 0 && i == contact_tick + 10) t.z_10_ticks_later = z;
    const double off = z - z_eq;
    if (contact_tick >= 0 && std::abs(off) > 0.05 * std::abs(z_eq)) {
      if (off * prev < 0) ++t.crossings;
      prev = off;
    }
    t.final_z = z;
    t.final_v = p.v_W.z();
  }
  return t;
}

TEST(ImplicitStep, StiffRowStaysStableAndDoesNotRing) {
  const Coupling c = ChooseCoupling(SimulatedDeviceInfo());
  const double m = c.proxy.mass, k_l = c.gains.k_lin;
  // Explicit (symplectic) Euler on a spring k with mass m is stable only for
  // h sqrt(k/m) < 2, i.e. k < 4 m / h^2. The row is a hundred times stiffer.
  const double k_explicit_max = 4 * m / (kH * kH);
  const double k_row = 100 * k_explicit_max;
  // Resting on the floor: k_row (-z) = k_l (z - z_H).
  const double z_eq = k_l * -0.003 / (k_l + k_row);
  std::printf(
      "proxy mass %.3g kg, coupling %.0f N/m: explicit Euler stable below %.3g N/m; "
      "row %.3g N/m (h sqrt(k/m) = %.1f); rest at z = %.3g um\n",
      m, k_l, k_explicit_max, k_row, kH * std::sqrt(k_row / m), z_eq * 1e6);

  const Trace t = FallOntoFloor(c, k_row, /*implicit_step=*/true, z_eq);
  ASSERT_TRUE(t.finite) << "the implicit step blew up";
  // The first tick into the floor happens before the row is active (the
  // one-tick detection delay of any sampled contact); from then on the
  // stiff row only pushes it back: never deeper than that first tick...
  EXPECT_GE(t.min_z, t.first_contact_z);
  // ...within 1% of the rest pose ten ticks later, at rest there in the end...
  EXPECT_NEAR(t.z_10_ticks_later, z_eq, 0.01 * std::abs(z_eq));
  EXPECT_NEAR(t.final_z, z_eq, 1e-3 * std::abs(z_eq));
  EXPECT_LT(std::abs(t.final_v), 1e-6);
  // ...without ringing around it (one overshoot at most).
  EXPECT_LE(t.crossings, 1) << "the proxy oscillated about its rest pose";

  // The scenario does need the stiffness-aware step: explicit integration of
  // exactly the same forces diverges (or rings hugely) here.
  const Trace e = FallOntoFloor(c, k_row, /*implicit_step=*/false, z_eq);
  EXPECT_TRUE(!e.finite || e.crossings > 10 || e.max_abs_z > 0.01)
      << "explicit Euler survived: the row is not stiff enough to tell";
}

TEST(ImplicitStep, StaysStableAcrossStiffnessDecades) {
  const Coupling c = ChooseCoupling(SimulatedDeviceInfo());
  for (double k_row : {1e4, 1e5, 1e6, 1e7, 1e8}) {
    SCOPED_TRACE(k_row);
    const double z_eq = c.gains.k_lin * -0.003 / (c.gains.k_lin + k_row);
    const Trace t = FallOntoFloor(c, k_row, true, z_eq);
    ASSERT_TRUE(t.finite);
    EXPECT_NEAR(t.final_z, z_eq, 1e-3 * std::abs(z_eq) + 1e-9);
    EXPECT_LE(t.crossings, 1);
  }
}

}  // namespace
}  // namespace hapticpd::device
