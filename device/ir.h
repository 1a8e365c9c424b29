// The intermediate representation (IR) the servo loop renders from
// (../shared/docs/HAPTICS.md "Intermediate representation"), and its local
// evaluation: unilateral contact rows, blending of a new IR over a few ticks,
// fade to zero when the proxy leaves its validity region. A stale IR (link
// loss) is reported here and faded by the servo loop (ServoConfig).
//
// Frames: P is the proxy frame (origin at the probe's centre of mass; the
// probe's mesh frame A sits at X_PA in it). Every vector is in the world W.
// A contact row i is J_i = [n_i; m_i] with m_i = (p_i - c_ref) x n_i, c_ref
// the origin of P at X_WP_ref. At a proxy pose X_WP,
//   dx = [p - p_ref; theta u(R R_ref^T)],   depth_i(x) = d_i - J_i . dx,
//   W(x) = sum_i k_i max(0, depth_i(x)) J_i   (force; torque about P's origin)
// which equals the penalty wrench sum k_i d_i [n_i; m_i] at X_WP_ref.
//
// An IR is a fixed-size value (no heap), so it crosses threads through a
// LatestMailbox and is copied without allocation.
#pragma once

#include <array>
#include <cstdint>
#include <limits>

#include "device/haptic_device.h"

namespace hapticpd::device {

/// Most rows an IR carries; a producer keeps the deepest ones beyond this.
inline constexpr int kMaxIrRows = 32;

/// One linearised contact constraint (one contact region) at X_WP_ref.
struct IrRow {
  Vec3 p_W = Vec3::Zero();  ///< representative contact point at X_WP_ref
  Vec3 n_W = Vec3::Zero();  ///< unit normal from the body towards the probe
  Vec3 m_W = Vec3::Zero();  ///< (p_W - c_ref) x n_W
  double depth = 0;         ///< m, >= 0 at X_WP_ref
  double stiffness = 0;     ///< N/m
  /// The body's material, for the friction and damping effects (effects.h).
  double static_friction = 0;
  double dynamic_friction = 0;
  double damping = 0;  ///< N s/m
};

struct IntermediateRep {
  std::uint64_t sequence = 0;        ///< of the proxy sample this IR answers
  std::int64_t sample_time_ns = 0;   ///< client clock when that sample was taken
  std::int64_t receive_time_ns = 0;  ///< client clock when the IR arrived (age is from here)
  Pose X_WP_ref;                     ///< proxy pose the rows linearise about
  int num_rows = 0;
  std::array<IrRow, kMaxIrRows> rows{};
  /// PDg: spring towards the nearest free pose instead of rows. Rendered
  /// unilaterally along the 6-D PD direction (it never pulls the proxy back
  /// in once the proxy has passed the target).
  bool use_target = false;
  Pose X_WP_target;
  double target_stiffness = 0;             ///< N/m
  double target_rotational_stiffness = 0;  ///< N m/rad
  double validity_radius = 0;              ///< m from p_ref; <= 0: unbounded
  double validity_angle = 0;               ///< rad from R_ref; <= 0: unbounded
  double compute_time_us = 0;              ///< producer's PD time
  /// Which model answered: 0 the server's PD answer, 1 the local patch
  /// model (device/local_model.h); counted per tick in ServoStats.
  std::uint8_t source = 0;
};

/// Adds a row to `ir`; when it already holds kMaxIrRows, the new row
/// replaces the shallowest one if it is deeper (the deepest rows are kept).
void AddIrRow(const IrRow& row, IntermediateRep* ir);

/// Raw (unblended, unfaded) IR wrench at X_WP: W = [force; torque about P's
/// origin] and its stiffness K = -dW/dx (6x6, symmetric positive
/// semi-definite; the rows active at X_WP). No allocation.
void EvaluateIrRaw(const IntermediateRep& ir, const Pose& X_WP, Vec6* W, Mat6* K);

/// The IR's potential at a pose: U = sum_i k_i max(0, depth_i - shift)^2 / 2,
/// the energy (J) its springs hold (W = -dU/dx), and the largest row depth.
/// A PDg target is one generalised row (J = kd/|kd|, k = |kd|^2/(d.kd)).
struct IrPotential {
  double energy_j = 0;
  double max_depth = -1e300;  ///< of depth_i(x) before the shift (m; PDg: generalised)
  int touching_rows = 0;      ///< rows with depth_i(x) > 0 (before the shift)
};

/// EvaluateIrRaw with every row's depth reduced by `shift` >= 0 (a contact
/// surface moved `shift` into the body along each row), and the potential.
/// No allocation.
void EvaluateIrShifted(const IntermediateRep& ir, const Pose& X_WP, double shift, Vec6* W, Mat6* K,
                       IrPotential* pot);

/// True when X_WP is inside the IR's validity region.
bool InsideValidity(const IntermediateRep& ir, const Pose& X_WP);

struct IrEvalParams {
  /// A new IR's step is spread over this many ticks (VRPN uses 10).
  int blend_ticks = 10;
  /// An IR older than this (s, from its receive time) is stale.
  double max_age_s = 0.020;
  /// Time (s) for the contact wrench to fade from full to zero once the
  /// proxy leaves the IR's validity region. A stale IR does not fade here:
  /// the servo loop fades its whole output on link loss
  /// (ServoConfig::link_fade_time_s), one fade for one event.
  double fade_time_s = 0.020;
  /// Time (s) to ramp it back from zero to full (the first IR after a reset,
  /// or back inside the validity region; slower, since the proxy may have
  /// sunk into the body meanwhile: Mark et al. 1996).
  double fade_in_time_s = 0.100;
  /// Coming back into the validity region, raise the gain without adding
  /// energy: the rows' surface is moved into the body (IrEvalInfo::shift) so
  /// that gain x potential never grows at a fixed pose, and it returns to the
  /// true surface only where that costs nothing (rows not pushing). Fading a
  /// stiffness up at depth is what pumps under delay. The first IR after a
  /// reset, and a rise after a fade-down during a link loss, keep the plain
  /// ramp (Mark et al. 1996).
  bool energy_neutral_reentry = true;
};

/// What one evaluation did (for statistics and tests).
struct IrEvalInfo {
  bool have_ir = false;
  bool stale = false;
  bool outside_validity = false;
  int active_rows = 0;
  double age_s = 0;
  double fade = 0;   ///< fade gain in [0, 1]
  double blend = 1;  ///< progress of the current blend in [0, 1]
  double shift = 0;  ///< m the rows' surface is moved into the body (energy-neutral re-entry)
  std::uint8_t source = 0;  ///< IntermediateRep::source of the IR rendered
  /// m, the deepest row at the proxy pose (PDg: the generalised target row);
  /// negative: the proxy is that far outside every row's surface. -inf
  /// without an IR or rows.
  double max_depth = -std::numeric_limits<double>::infinity();
};

/// Renders the latest IR at the proxy pose, once per servo tick. Blending:
/// on arrival, the jump between the wrench the old IR gave and the one the
/// new IR gives at the current proxy pose is kept as an offset that decays
/// to zero over `blend_ticks`, so the output is continuous even when IRs
/// arrive faster than the blend. Fading: a gain that moves towards 0 (outside
/// validity; a stale IR is the servo loop's to fade) at 1/fade_time per second, or towards 1 at
/// 1/fade_in_time; back inside the validity region the rise is made
/// energy-neutral (IrEvalParams::energy_neutral_reentry). An IR that arrives
/// for a pose whose validity region the proxy is already outside of (a late
/// answer under delay) never pushes until the proxy has been inside it: its
/// rows, linearised centimetres away, say nothing about where the proxy is,
/// and fading them out would push with them for the fade's 20 ms (the blend
/// takes the old IR's wrench to zero instead). Not thread-safe:
/// owned by the servo thread. No allocation after construction.
class IrEvaluator {
 public:
  explicit IrEvaluator(const IrEvalParams& params = {}) : params_(params) {}

  const IrEvalParams& params() const { return params_; }
  /// Drops the IR and zeroes the fade (e.g. on disconnect).
  void Reset();
  /// Installs a new IR (by copy); the next Evaluate blends it in.
  void Accept(const IntermediateRep& ir, const Pose& X_WP);
  /// The IR held is stale from now on, whatever its age (its stream ended):
  /// Evaluate fades it as it would an old one, until Accept or Reset.
  void Expire() { expired_ = true; }
  /// Contact wrench on the proxy at X_WP at time now_ns, its stiffness K for
  /// the implicit step, and what happened. Advances blend and fade by `dt_s`.
  void Evaluate(const Pose& X_WP, std::int64_t now_ns, double dt_s, Vec6* W, Mat6* K,
                IrEvalInfo* info);
  bool has_ir() const { return has_ir_; }
  const IntermediateRep& current() const { return ir_; }

 private:
  // The share of the blend offset kept where the current IR's rows hold
  // `energy_j` of potential energy (see offset_energy_j_).
  double OffsetScale(double energy_j) const;

  IrEvalParams params_;
  IntermediateRep ir_;
  bool has_ir_ = false;
  Vec6 last_W_ = Vec6::Zero();  // unfaded output of the last Evaluate
  Vec6 offset_ = Vec6::Zero();  // blend offset at the IR's arrival
  // The rows' potential energy at the pose the IR arrived at (J): the offset
  // is scaled by sqrt(energy now / offset_energy_j_), at most 1, so it
  // fades with the push it was blended against.
  double offset_energy_j_ = 0;
  int blend_tick_ = 0;
  double fade_ = 0;
  double shift_ = 0;  // m, see IrEvalParams::energy_neutral_reentry
  // The IR arrived with the proxy outside its validity region, and the proxy
  // has not been inside it since: its rows do not push.
  bool unvisited_ = false;
  bool expired_ = false;  // see Expire()
  // The last fade-down was while the IR was stale (or there was no IR yet):
  // the next rise is the plain recovery ramp.
  bool ramp_recovery_ = true;
};

}  // namespace hapticpd::device
