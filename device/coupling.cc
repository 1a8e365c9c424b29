#include "device/coupling.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>

#include "device/math.h"

namespace hapticpd::device {

Coupling ChooseCoupling(const DeviceInfo& info, const CouplingDesign& design) {
  Coupling c;
  CouplingGains& g = c.gains;
  g.k_lin = design.stiffness_fraction * info.max_linear_stiffness;
  g.b_lin = design.damping_fraction * info.max_linear_damping;
  g.max_force = info.max_force;
  const bool torque = info.dof_actuated >= 6 && info.max_torque > 0;
  if (torque) {
    g.k_ang = design.stiffness_fraction * info.max_angular_stiffness;
    g.b_ang = design.damping_fraction * info.max_angular_damping;
    g.max_torque = info.max_torque;
  } else {
    g.k_ang = design.fallback_k_ang;
    g.b_ang = design.fallback_b_ang;
    g.max_torque = 0;
  }
  ProxyParams& p = c.proxy;
  p.mass = g.k_lin / (design.omega_lin * design.omega_lin);
  p.inertia = g.k_ang / (design.omega_ang * design.omega_ang);
  p.lin_damping = std::max(0.0, 2.0 * std::sqrt(g.k_lin * p.mass) - g.b_lin);
  p.ang_damping = std::max(0.0, 2.0 * std::sqrt(g.k_ang * p.inertia) - g.b_ang);
  return c;
}

std::pair<double, double> MinPhysicalDamping(const CouplingGains& g, double period_s) {
  return {g.k_lin * period_s / 2 + g.b_lin, g.k_ang * period_s / 2 + g.b_ang};
}

Wrench CouplingWrench(const CouplingGains& g, const Pose& X_WH, const Vec3& v_WH, const Vec3& w_WH,
                      const ProxyState& proxy, bool* clamped) {
  Vec3 stretch = X_WH.t - proxy.X_WP.t;
  Vec3 twist = internal::LogRotation(X_WH.R * proxy.X_WP.R.transpose());
  bool c = false;
  if (g.max_force > 0 && g.k_lin * stretch.norm() > g.max_force) {
    stretch = internal::ClampNorm(stretch, g.max_force / g.k_lin);
    c = true;
  }
  if (g.max_torque > 0 && g.k_ang * twist.norm() > g.max_torque) {
    twist = internal::ClampNorm(twist, g.max_torque / g.k_ang);
    c = true;
  }
  if (clamped) *clamped = c;
  Wrench w;
  w.force = g.k_lin * stretch + g.b_lin * (v_WH - proxy.v_W);
  w.torque = g.k_ang * twist + g.b_ang * (w_WH - proxy.w_W);
  return w;
}

double ContactWeight(double max_depth, double margin) {
  if (!(max_depth > -margin)) return 0.0;  // also -inf and NaN: no row near
  if (max_depth >= 0 || margin <= 0) return 1.0;
  return 1.0 + max_depth / margin;
}

void StepProxy(const Coupling& c, const Pose& X_WH, const Vec3& v_WH, const Vec3& w_WH,
               const Vec6& wrench_ir, const Mat6& K_ir, double h, ProxyState* proxy,
               double contact_weight) {
  const CouplingGains& g = c.gains;
  const ProxyParams& p = c.proxy;
  const Wrench Wc = CouplingWrench(g, X_WH, v_WH, w_WH, *proxy, nullptr);
  Vec6 v;
  v << proxy->v_W, proxy->w_W;
  Vec6 f;
  // Damping of the proxy's velocity relative to a blend of the world (at
  // rest) and the handle: the same derivative in v, so the implicit matrix
  // below is the same either way.
  const double free = 1.0 - std::clamp(contact_weight, 0.0, 1.0);
  f.head<3>() = Wc.force - p.lin_damping * (proxy->v_W - free * v_WH);
  f.tail<3>() = Wc.torque - p.ang_damping * (proxy->w_W - free * w_WH);
  f += wrench_ir;
  Mat6 A = h * h * K_ir;
  Vec6 Kv = K_ir * v;
  for (int i = 0; i < 3; ++i) {
    A(i, i) += p.mass + h * (g.b_lin + p.lin_damping) + h * h * g.k_lin;
    A(i + 3, i + 3) += p.inertia + h * (g.b_ang + p.ang_damping) + h * h * g.k_ang;
    Kv(i) += g.k_lin * v(i);
    Kv(i + 3) += g.k_ang * v(i + 3);
  }
  const Vec6 dv = A.ldlt().solve(h * (f - h * Kv));
  v += dv;
  proxy->v_W = v.head<3>();
  proxy->w_W = v.tail<3>();
  proxy->X_WP.t += h * proxy->v_W;
  proxy->X_WP.R = internal::Orthonormalize(internal::ExpRotation(h * proxy->w_W) * proxy->X_WP.R);
}

}  // namespace hapticpd::device
