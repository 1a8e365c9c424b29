#include "device/ir.h"

#include <algorithm>
#include <cmath>

#include "device/math.h"

namespace hapticpd::device {

namespace {
Vec6 Delta(const Pose& X_ref, const Pose& X) {
  Vec6 dx;
  dx.head<3>() = X.t - X_ref.t;
  dx.tail<3>() = internal::LogRotation(X.R * X_ref.R.transpose());
  return dx;
}
}  // namespace

void EvaluateIrRaw(const IntermediateRep& ir, const Pose& X_WP, Vec6* W, Mat6* K) {
  EvaluateIrShifted(ir, X_WP, 0.0, W, K, nullptr);
}

void EvaluateIrShifted(const IntermediateRep& ir, const Pose& X_WP, double shift, Vec6* W, Mat6* K,
                       IrPotential* pot) {
  W->setZero();
  K->setZero();
  IrPotential p;
  const Vec6 dx = Delta(ir.X_WP_ref, X_WP);
  if (ir.use_target) {
    const Vec6 d = Delta(ir.X_WP_ref, ir.X_WP_target);
    Vec6 kd;
    kd.head<3>() = ir.target_stiffness * d.head<3>();
    kd.tail<3>() = ir.target_rotational_stiffness * d.tail<3>();
    const double dkd = d.dot(kd);
    if (dkd > 0) {
      // One generalised row along kd: depth (d.kd - kd.dx)/|kd|, stiffness
      // |kd|^2/(d.kd); unshifted, W = s kd with s the fraction of the way
      // from the target back to the reference pose.
      const double kd_norm = kd.norm();
      const double depth = (dkd - kd.dot(dx)) / kd_norm;
      p.max_depth = depth;
      if (depth > 0) ++p.touching_rows;
      const double e = depth - shift;
      if (e > 0) {
        const double k = kd_norm * kd_norm / dkd;
        *W = (k * e / kd_norm) * kd;
        *K = kd * kd.transpose() / dkd;
        p.energy_j = 0.5 * k * e * e;
      }
    }
    if (pot) *pot = p;
    return;
  }
  for (int i = 0; i < ir.num_rows; ++i) {
    const IrRow& r = ir.rows[static_cast<std::size_t>(i)];
    Vec6 J;
    J.head<3>() = r.n_W;
    J.tail<3>() = r.m_W;
    const double depth = r.depth - J.dot(dx);
    p.max_depth = std::max(p.max_depth, depth);
    if (depth > 0) ++p.touching_rows;
    const double e = depth - shift;
    if (e <= 0) continue;  // unilateral: a separating row stops pushing
    *W += (r.stiffness * e) * J;
    *K += r.stiffness * (J * J.transpose());
    p.energy_j += 0.5 * r.stiffness * e * e;
  }
  if (pot) *pot = p;
}

void AddIrRow(const IrRow& row, IntermediateRep* ir) {
  if (ir->num_rows < kMaxIrRows) {
    ir->rows[static_cast<std::size_t>(ir->num_rows++)] = row;
    return;
  }
  auto it = std::min_element(ir->rows.begin(), ir->rows.end(),
                             [](const IrRow& a, const IrRow& b) { return a.depth < b.depth; });
  if (it->depth < row.depth) *it = row;
}

bool InsideValidity(const IntermediateRep& ir, const Pose& X_WP) {
  if (ir.validity_radius > 0 && (X_WP.t - ir.X_WP_ref.t).norm() > ir.validity_radius) {
    return false;
  }
  if (ir.validity_angle > 0 &&
      internal::LogRotation(X_WP.R * ir.X_WP_ref.R.transpose()).norm() > ir.validity_angle) {
    return false;
  }
  return true;
}

void IrEvaluator::Reset() {
  has_ir_ = false;
  last_W_.setZero();
  offset_.setZero();
  offset_energy_j_ = 0;
  blend_tick_ = 0;
  fade_ = 0;
  shift_ = 0;
  ramp_recovery_ = true;
  unvisited_ = false;
  expired_ = false;
}

void IrEvaluator::Accept(const IntermediateRep& ir, const Pose& X_WP) {
  Mat6 K;
  // What the old IR (and what is left of its own blend) gives at this pose:
  // the blend smooths the step between the two answers at the same pose,
  // never the wrench's response to the proxy's motion. (Against the output
  // of the previous tick, at the previous pose, the offset held back every
  // tick's change of the wrench along the motion: with a new IR each tick
  // the rendered spring lagged the proxy by half the blend and returned more
  // energy than it took.)
  Vec6 W_old = Vec6::Zero();
  if (has_ir_) {
    IrPotential pot_old;
    EvaluateIrShifted(ir_, X_WP, shift_, &W_old, &K, &pot_old);
    const int n = std::max(1, params_.blend_ticks);
    if (blend_tick_ < n) {
      W_old +=
          OffsetScale(pot_old.energy_j) * (1.0 - static_cast<double>(blend_tick_) / n) * offset_;
    }
  }
  ir_ = ir;
  unvisited_ = !InsideValidity(ir_, X_WP);
  Vec6 W_new = Vec6::Zero();
  IrPotential pot;
  if (!unvisited_) EvaluateIrShifted(ir_, X_WP, shift_, &W_new, &K, &pot);
  // First IR: nothing to blend from (the fade-in ramps it).
  offset_ = has_ir_ ? Vec6(W_old - W_new) : Vec6::Zero();
  // Two answers that agree leave round-off (1e-17 N), which would let a
  // contact that only ever pushes read as a tiny pull.
  if (offset_.cwiseAbs().maxCoeff() < 1e-9) offset_.setZero();
  offset_energy_j_ = pot.energy_j;
  blend_tick_ = 0;
  has_ir_ = true;
  expired_ = false;
}

double IrEvaluator::OffsetScale(double energy_j) const {
  // A new IR that pushes harder than the old one at the same pose leaves an
  // offset that pulls. Added as is, it would pull the proxy in once the new
  // rows go slack as the proxy leaves (and, carried on by the next IR's
  // blend, keep pulling while IRs arrive every tick). Scaled with the new
  // rows' push, by the root of their energy (linear in a row's depth), the
  // blended contact only ever pushes: k e (1 - r) + r c e / e0 for a row
  // e <= e0 deep (e0 at the IR's arrival) and an old push c >= 0. An IR
  // that arrived pushing nothing blends the old push out unscaled.
  if (offset_energy_j_ <= 0) return 1.0;
  return std::sqrt(std::min(1.0, energy_j / offset_energy_j_));
}

void IrEvaluator::Evaluate(const Pose& X_WP, std::int64_t now_ns, double dt_s, Vec6* W, Mat6* K,
                           IrEvalInfo* info) {
  *info = IrEvalInfo{};
  if (!has_ir_) {
    W->setZero();
    K->setZero();
    fade_ = 0;
    last_W_.setZero();
    return;
  }
  info->have_ir = true;
  info->source = ir_.source;
  info->age_s = 1e-9 * static_cast<double>(now_ns - ir_.receive_time_ns);
  info->stale = expired_ || info->age_s > params_.max_age_s;
  info->outside_validity = !InsideValidity(ir_, X_WP);
  if (!info->outside_validity) unvisited_ = false;
  // Staleness is not faded here: the servo loop fades its whole output on
  // link loss (ServoConfig::link_fade_time_s), so one event has one fade.
  // A fade-down while the IR is stale (the proxy, held on the handle, left
  // the validity region during a loss) recovers with the plain ramp, so the
  // fresh IR pushes a hand that sank in meanwhile back out.
  const double target = info->outside_validity ? 0.0 : 1.0;
  if (target == 0) ramp_recovery_ = info->stale;
  const double down = params_.fade_time_s > 0 ? dt_s / params_.fade_time_s : 1.0;
  const double up = params_.fade_in_time_s > 0 ? dt_s / params_.fade_in_time_s : 1.0;
  const double fade_old = fade_;
  fade_ = target > fade_ ? std::min(target, fade_ + up) : std::max(target, fade_ - down);

  IrPotential pot;
  if (unvisited_) {
    W->setZero();
    K->setZero();
  } else {
    EvaluateIrShifted(ir_, X_WP, shift_, W, K, &pot);
  }
  info->active_rows = pot.touching_rows;
  if (ir_.num_rows > 0 || ir_.use_target) info->max_depth = pot.max_depth;
  if (params_.energy_neutral_reentry && !unvisited_) {
    // Energy-neutral re-entry. Scaling the contact wrench by a gain g(t)
    // puts g'(t) U(x) into the loop at a fixed pose (U: the rows' potential):
    // a fade-out dissipates, but a fade-in with the proxy sunk deep (it fell
    // in while the rows were faded out) pushes it and the hand back out with
    // energy nobody put in. Under delay the proxy leaves the validity region
    // whenever it moves faster than radius / round trip (at 20 ms one way,
    // over ~25 mm/s for a 1 mm radius), so this repeats several times a
    // second and pumps. Instead, as g rises, move the rows'
    // surface into the body by `shift` so that g U_shift(x) does not grow,
    // and let it come back to the true surface only where no row pushes
    // (the anchor of a spring moved while it is slack: no work; passive
    // set-position modulation, Lee & Huang 2010). The first IR after a reset
    // or a link loss rises with the plain ramp of Mark et al. 1996.
    const double shift_old = shift_;
    if (pot.max_depth < shift_) shift_ = std::max(0.0, pot.max_depth);  // slack: free
    if (fade_ > fade_old && !ramp_recovery_ && pot.energy_j > 0) {
      // Per row, (depth - shift') <= q (depth - shift) with q^2 = g_old/g_new
      // makes every row's energy, and so U, shrink by g_old/g_new.
      const double q = std::sqrt(fade_old / fade_);
      shift_ = (1 - q) * pot.max_depth + q * shift_;
    }
    if (shift_ != shift_old) EvaluateIrShifted(ir_, X_WP, shift_, W, K, &pot);
  }
  info->shift = shift_;
  const int n = std::max(1, params_.blend_ticks);
  if (blend_tick_ < n) {
    ++blend_tick_;
    const double remaining = 1.0 - static_cast<double>(blend_tick_) / n;
    info->blend = 1.0 - remaining;
    *W += OffsetScale(pot.energy_j) * remaining * offset_;
  }
  last_W_ = *W;
  *W *= fade_;
  *K *= fade_;
  info->fade = fade_;
}

}  // namespace hapticpd::device
