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
  W->setZero();
  K->setZero();
  const Vec6 dx = Delta(ir.X_WP_ref, X_WP);
  if (ir.use_target) {
    const Vec6 d = Delta(ir.X_WP_ref, ir.X_WP_target);
    Vec6 kd;
    kd.head<3>() = ir.target_stiffness * d.head<3>();
    kd.tail<3>() = ir.target_rotational_stiffness * d.tail<3>();
    const double dkd = d.dot(kd);
    if (dkd <= 0) return;
    // Fraction of the way from the target back to the reference pose.
    const double s = 1.0 - kd.dot(dx) / dkd;
    if (s <= 0) return;
    *W = s * kd;
    *K = kd * kd.transpose() / dkd;
    return;
  }
  for (int i = 0; i < ir.num_rows; ++i) {
    const IrRow& r = ir.rows[static_cast<std::size_t>(i)];
    Vec6 J;
    J.head<3>() = r.n_W;
    J.tail<3>() = r.m_W;
    const double depth = r.depth - J.dot(dx);
    if (depth <= 0) continue;  // unilateral: a separating row stops pushing
    *W += (r.stiffness * depth) * J;
    *K += r.stiffness * (J * J.transpose());
  }
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
  blend_tick_ = 0;
  fade_ = 0;
}

void IrEvaluator::Accept(const IntermediateRep& ir, const Pose& X_WP) {
  ir_ = ir;
  Vec6 W_new;
  Mat6 K;
  EvaluateIrRaw(ir_, X_WP, &W_new, &K);
  // First IR: nothing to blend from (the fade-in ramps it).
  offset_ = has_ir_ ? Vec6(last_W_ - W_new) : Vec6::Zero();
  blend_tick_ = 0;
  has_ir_ = true;
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
  info->age_s = 1e-9 * static_cast<double>(now_ns - ir_.receive_time_ns);
  info->stale = info->age_s > params_.max_age_s;
  info->outside_validity = !InsideValidity(ir_, X_WP);
  const double target = (info->stale || info->outside_validity) ? 0.0 : 1.0;
  const double down = params_.fade_time_s > 0 ? dt_s / params_.fade_time_s : 1.0;
  const double up = params_.fade_in_time_s > 0 ? dt_s / params_.fade_in_time_s : 1.0;
  fade_ = target > fade_ ? std::min(target, fade_ + up) : std::max(target, fade_ - down);

  EvaluateIrRaw(ir_, X_WP, W, K);
  if (!ir_.use_target) {
    const Vec6 dx = Delta(ir_.X_WP_ref, X_WP);
    for (int i = 0; i < ir_.num_rows; ++i) {
      const IrRow& r = ir_.rows[static_cast<std::size_t>(i)];
      if (r.depth - r.n_W.dot(dx.head<3>()) - r.m_W.dot(dx.tail<3>()) > 0) ++info->active_rows;
    }
  } else if (W->squaredNorm() > 0) {
    info->active_rows = 1;
  }
  const int n = std::max(1, params_.blend_ticks);
  if (blend_tick_ < n) {
    ++blend_tick_;
    const double remaining = 1.0 - static_cast<double>(blend_tick_) / n;
    *W += remaining * offset_;
    info->blend = 1.0 - remaining;
  }
  last_W_ = *W;
  *W *= fade_;
  *K *= fade_;
  info->fade = fade_;
}

}  // namespace hapticpd::device
