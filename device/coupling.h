// 6-DoF virtual coupling between the device handle H and the proxy P
// (Colgate, Stanley & Brown 1995; Adams & Hannaford 1999), and the proxy's
// implicit integration under the coupling and the IR contact wrench.
//
//   F_c = k_l (p_H - p_P) + b_l (v_H - v_P)            (force on the proxy, W)
//   tau_c = k_r theta u + b_r (w_H - w_P)              (theta u = log(R_H R_P^T))
//
// The spring stretch is clamped to the device's force (torque) limit before
// the damper is added, so the spring never stores energy the device could not
// render and nothing springs back after a clamp. The device receives -F_c,
// -tau_c. The proxy (mass m, isotropic inertia I, viscous damping b_p, b_rp
// that the user does not feel) is integrated by linearised backward Euler
// with the contact stiffness of the active IR rows, so contact rows far
// stiffer than the coupling stay stable at 1 kHz.
//
// Where the proxy damps against matters for free space. Damping to the
// world holds a proxy in contact still, but in free motion the hand drags
// it: at handle speed v the coupling stretches until it pulls b_p v, and
// the user feels that (0.3-0.6 N at 0.1-0.3 m/s with the default design).
// Damping relative to the handle settles the proxy just as fast but is
// zero at any steady velocity, so the proxy follows the hand and the hand
// feels only the tiny proxy's inertia. StepProxy blends the two by a
// contact weight in [0, 1]: 1 in contact and within a margin of a contact
// row (as before: stiffness and passivity in contact are unchanged), 0 in
// free space, continuous in between so no state jumps.
#pragma once

#include "device/haptic_device.h"

namespace hapticpd::device {

struct CouplingGains {
  double k_lin = 0;       ///< N/m
  double b_lin = 0;       ///< N s/m (felt by the user)
  double k_ang = 0;       ///< N m/rad
  double b_ang = 0;       ///< N m s/rad (felt by the user)
  double max_force = 0;   ///< N, stretch and output clamp
  double max_torque = 0;  ///< N m; 0: torque not rendered (the proxy still follows)
};

struct ProxyParams {
  double mass = 0.01;      ///< kg
  double inertia = 5e-6;   ///< kg m^2 (isotropic, about the centre of mass)
  double lin_damping = 0;  ///< N s/m to the world (not felt)
  double ang_damping = 0;  ///< N m s/rad to the world (not felt)
};

/// How to pick gains inside a device's limits.
struct CouplingDesign {
  double stiffness_fraction = 0.5;  ///< k = fraction * device max stiffness
  double damping_fraction = 0.5;    ///< b = fraction * device max damping
  /// rad/s, proxy natural frequency against the coupling spring. High keeps
  /// the proxy light, so the drag felt in free motion (k times the proxy's
  /// lag, about 2 sqrt(k m) v) stays small; implicit integration keeps it
  /// stable whatever omega * period.
  double omega_lin = 600;
  double omega_ang = 600;
  /// Rotational stiffness/damping for devices that sense but do not actuate
  /// orientation (the proxy must still follow the handle's rotation).
  double fallback_k_ang = 0.5;
  double fallback_b_ang = 0.0005;
};

struct Coupling {
  CouplingGains gains;
  ProxyParams proxy;
};

/// Gains inside the device's limits (k <= fraction * K_max, b <= fraction *
/// B_max) and a proxy that is critically damped against the coupling spring
/// with the handle held still: b_l + b_p = 2 sqrt(k_l m), m = k_l / omega^2
/// (rotation likewise).
Coupling ChooseCoupling(const DeviceInfo& info, const CouplingDesign& design = {});

/// Colgate's passivity condition for a sampled spring-damper (k, b) at period
/// T: the device's own physical damping must exceed k T / 2 + b. Returns that
/// bound for the translational (first) and rotational (second) parts.
std::pair<double, double> MinPhysicalDamping(const CouplingGains& g, double period_s);

struct ProxyState {
  Pose X_WP;
  Vec3 v_W = Vec3::Zero();
  Vec3 w_W = Vec3::Zero();
};

/// Coupling wrench on the proxy (W; torque about P's origin) for the handle
/// pose/velocity, with the stretch clamped. Sets *clamped when the stretch
/// was limited.
Wrench CouplingWrench(const CouplingGains& g, const Pose& X_WH, const Vec3& v_WH, const Vec3& w_WH,
                      const ProxyState& proxy, bool* clamped);

/// One linearised backward-Euler step of length h: the proxy under the
/// coupling to the (held) handle, its damping, and the contact wrench wrench_ir
/// with stiffness K_ir (both at the proxy's current pose). `contact_weight`
/// in [0, 1] puts the proxy's own damping to the world (1, contact) or
/// relative to the handle's velocity (0, free space). No allocation.
void StepProxy(const Coupling& c, const Pose& X_WH, const Vec3& v_WH, const Vec3& w_WH,
               const Vec6& wrench_ir, const Mat6& K_ir, double h, ProxyState* proxy,
               double contact_weight = 1.0);

/// The contact weight for StepProxy from the deepest contact row at the
/// proxy pose (IrEvalInfo::max_depth): 1 at or past the surface, falling
/// linearly to 0 at `margin` m outside it.
double ContactWeight(double max_depth, double margin);

}  // namespace hapticpd::device
