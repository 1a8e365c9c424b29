// IR evaluation: unilateral rows, their stiffness, blending of a new IR, fade
// on staleness and outside the validity region, the PDg target spring.
#include "device/ir.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

namespace hapticpd::device {
namespace {

constexpr std::int64_t kMs = 1'000'000;

IntermediateRep FloorIr(double depth, double k, std::int64_t receive_ns = 0) {
  IntermediateRep ir;
  ir.X_WP_ref = Pose::FromTranslation(Vec3(0, 0, 0.1));
  ir.num_rows = 1;
  // A contact 1 cm to the +x side of the centre, pushing up.
  ir.rows[0].p_W = Vec3(0.01, 0, 0.09);
  ir.rows[0].n_W = Vec3::UnitZ();
  ir.rows[0].m_W = (ir.rows[0].p_W - ir.X_WP_ref.t).cross(ir.rows[0].n_W);
  ir.rows[0].depth = depth;
  ir.rows[0].stiffness = k;
  ir.receive_time_ns = receive_ns;
  ir.validity_radius = 0.01;
  ir.validity_angle = 0.5;
  return ir;
}

// Blend tests' parameters: a 10-tick blend, never stale, faded in by 20 ms.
IrEvalParams BlendParams() {
  IrEvalParams p;
  p.blend_ticks = 10;
  p.max_age_s = 1;
  p.fade_in_time_s = 0.02;
  return p;
}

// The proxy held at X on a 1 mm deep floor row (1 N at 1000 N/m) for 40
// ticks from time 0: the blend done and, with BlendParams, the fade-in too.
// Leaves the last output in *W.
void SettleOnFloor(IrEvaluator* ev, const Pose& X, Vec6* W) {
  Mat6 K;
  IrEvalInfo info;
  ev->Accept(FloorIr(0.001, 1000, 0), X);
  for (int i = 0; i < 40; ++i) ev->Evaluate(X, i * kMs, 1e-3, W, &K, &info);
}

TEST(IrEval, RowPushesAlongNormalWithLinearisedDepth) {
  const IntermediateRep ir = FloorIr(0.002, 1000);
  Vec6 W;
  Mat6 K;
  EvaluateIrRaw(ir, ir.X_WP_ref, &W, &K);
  EXPECT_NEAR(W(2), 2.0, 1e-12);    // k d along +z
  EXPECT_NEAR(W(4), -0.02, 1e-12);  // (r x n) k d: r = +x, n = +z -> -y
  EXPECT_NEAR(K(2, 2), 1000, 1e-9);
  // 1 mm further down: 3 mm deep.
  EvaluateIrRaw(ir, Pose::FromTranslation(Vec3(0, 0, 0.099)), &W, &K);
  EXPECT_NEAR(W(2), 3.0, 1e-9);
  // A small rotation lifting the contact point (+x side up: about -y) reduces its depth.
  Pose X = ir.X_WP_ref;
  X.R = Eigen::AngleAxisd(0.05, -Vec3::UnitY()).toRotationMatrix();
  EvaluateIrRaw(ir, X, &W, &K);
  EXPECT_NEAR(W(2), 1000 * (0.002 - 0.01 * 0.05), 1e-6);
}

TEST(IrEval, UnilateralRowStopsPushingWhenSeparated) {
  const IntermediateRep ir = FloorIr(0.002, 1000);
  Vec6 W;
  Mat6 K;
  EvaluateIrRaw(ir, Pose::FromTranslation(Vec3(0, 0, 0.1025)), &W, &K);  // 0.5 mm above
  EXPECT_EQ(W.norm(), 0.0);
  EXPECT_EQ(K.norm(), 0.0);
}

TEST(IrEval, NewIrIsBlendedOverBlendTicks) {
  IrEvaluator ev(BlendParams());
  const Pose X = Pose::FromTranslation(Vec3(0, 0, 0.1));
  Vec6 W;
  Mat6 K;
  IrEvalInfo info;
  SettleOnFloor(&ev, X, &W);
  ASSERT_NEAR(W(2), 1.0, 1e-9);
  ev.Accept(FloorIr(0.003, 1000, 40 * kMs), X);  // a step from 1 N to 3 N
  double prev = W(2);
  for (int i = 1; i <= 10; ++i) {
    ev.Evaluate(X, (40 + i) * kMs, 1e-3, &W, &K, &info);
    EXPECT_NEAR(W(2) - prev, 0.2, 1e-9) << "tick " << i;  // 2 N over 10 ticks
    prev = W(2);
  }
  ev.Evaluate(X, 51 * kMs, 1e-3, &W, &K, &info);
  EXPECT_NEAR(W(2), 3.0, 1e-9);
}

TEST(IrEval, BlendStaysContinuousWhenIrsArriveEveryTick) {
  IrEvalParams p;
  p.max_age_s = 1;  // never stale here
  IrEvaluator ev(p);
  const Pose X = Pose::FromTranslation(Vec3(0, 0, 0.1));
  Vec6 W;
  Mat6 K;
  IrEvalInfo info;
  SettleOnFloor(&ev, X, &W);
  double prev = W(2), max_step = 0;
  // Depth alternates 1 mm / 3 mm every tick: the output never jumps by the full 2 N.
  for (int i = 0; i < 50; ++i) {
    ev.Accept(FloorIr(i % 2 ? 0.001 : 0.003, 1000, (40 + i) * kMs), X);
    ev.Evaluate(X, (40 + i) * kMs, 1e-3, &W, &K, &info);
    max_step = std::max(max_step, std::abs(W(2) - prev));
    prev = W(2);
  }
  EXPECT_LE(max_step, 0.2 + 1e-9);
}

TEST(IrEval, ABlendTowardsAHarderPushNeverPullsAsTheProxyLeaves) {
  IrEvaluator ev(BlendParams());
  Vec6 W;
  Mat6 K;
  IrEvalInfo info;
  SettleOnFloor(&ev, Pose::FromTranslation(Vec3(0, 0, 0.1)), &W);
  ASSERT_NEAR(W(2), 1.0, 1e-9);
  // The next answers push harder (3 mm) and arrive every tick while the
  // proxy leaves the surface at 0.5 mm per tick: the blend must fade with
  // the push, never leave a pull (an unscaled offset pulled with 0.96 N and
  // each later answer carried what was left of it on: 0.24 N at the end).
  double min_z = 1e9, max_lateral = 0;
  for (int i = 0; i < 20; ++i) {
    const Pose Xi = Pose::FromTranslation(Vec3(0, 0, 0.1 + 0.0005 * i));
    ev.Accept(FloorIr(0.003, 1000, (40 + i) * kMs), Xi);
    ev.Evaluate(Xi, (40 + i) * kMs, 1e-3, &W, &K, &info);
    min_z = std::min(min_z, W(2));
    max_lateral = std::max(max_lateral, std::hypot(W(0), W(1)));
  }
  EXPECT_GE(min_z, 0.0);
  EXPECT_EQ(max_lateral, 0.0);
  EXPECT_EQ(W.norm(), 0.0) << "4 mm above a 3 mm row: free";
}

TEST(IrEval, StaleIrIsReportedAndLeftToTheLoopToFade) {
  IrEvalParams p;
  p.max_age_s = 0.025;
  p.fade_time_s = 0.020;
  p.fade_in_time_s = 0.020;
  IrEvaluator ev(p);
  const Pose X = Pose::FromTranslation(Vec3(0, 0, 0.1));
  ev.Accept(FloorIr(0.002, 1000, 0), X);
  Vec6 W;
  Mat6 K;
  IrEvalInfo info;
  // Fade-in from the first IR: linear over 20 ms.
  ev.Evaluate(X, 1 * kMs, 1e-3, &W, &K, &info);
  EXPECT_NEAR(info.fade, 0.05, 1e-12);
  for (int i = 2; i <= 25; ++i) ev.Evaluate(X, i * kMs, 1e-3, &W, &K, &info);
  EXPECT_NEAR(W(2), 2.0, 1e-9);
  EXPECT_FALSE(info.stale);
  // No new IR: stale from 26 ms (age > 25 ms). The evaluator reports it and
  // keeps rendering the rows; the servo loop fades its whole output on link
  // loss (Servo.StalledIrStreamFadesAndRecovers), one fade for one event.
  for (int i = 26; i <= 80; ++i) {
    ev.Evaluate(X, i * kMs, 1e-3, &W, &K, &info);
    EXPECT_EQ(info.stale, i >= 26) << i;
    EXPECT_NEAR(W(2), 2.0, 1e-9) << i;
    EXPECT_EQ(info.fade, 1.0) << i;
  }
  // Expire (the stream ended) makes it stale at once, whatever its age; a
  // fresh IR is not stale.
  ev.Accept(FloorIr(0.002, 1000, 80 * kMs), X);
  ev.Evaluate(X, 81 * kMs, 1e-3, &W, &K, &info);
  EXPECT_FALSE(info.stale);
  ev.Expire();
  ev.Evaluate(X, 82 * kMs, 1e-3, &W, &K, &info);
  EXPECT_TRUE(info.stale);
  EXPECT_NEAR(W(2), 2.0, 1e-9);
}

TEST(IrEval, LeavingTheValidityRegionFades) {
  IrEvalParams p;
  p.fade_in_time_s = 0.020;
  IrEvaluator ev(p);
  Vec6 W;
  Mat6 K;
  IrEvalInfo info;
  const IntermediateRep ir = FloorIr(0.02, 1000, 0);
  ev.Accept(ir, ir.X_WP_ref);
  for (int i = 1; i <= 20; ++i) ev.Evaluate(ir.X_WP_ref, 0, 1e-3, &W, &K, &info);
  ASSERT_GT(W(2), 19.0);
  const Pose far = Pose::FromTranslation(Vec3(0.02, 0, 0.1));  // 2 cm sideways > 1 cm radius
  for (int i = 21; i <= 41; ++i) {
    ev.Evaluate(far, 0, 1e-3, &W, &K, &info);
    EXPECT_TRUE(info.outside_validity);
    EXPECT_FALSE(info.stale);
  }
  EXPECT_EQ(W.norm(), 0.0);
  Pose turned = ir.X_WP_ref;  // 0.6 rad > 0.5 rad validity angle
  turned.R = Eigen::AngleAxisd(0.6, Vec3::UnitZ()).toRotationMatrix();
  EXPECT_FALSE(InsideValidity(ir, turned));
  EXPECT_TRUE(InsideValidity(ir, ir.X_WP_ref));
}

// A late answer under delay: an IR for a pose the proxy has already left
// (outside its validity region when it arrives). Its row, evaluated by its
// linearisation 2 cm away, would push with 5 N; it must not push at all
// (the blend takes the old IR's wrench to zero) until the proxy has been
// inside its validity region, and then it renders as any IR does.
TEST(IrEval, AnIrArrivingOutsideItsValidityNeverPushesThere) {
  IrEvalParams p;
  p.fade_in_time_s = 0.020;
  IrEvaluator ev(p);
  Vec6 W;
  Mat6 K;
  IrEvalInfo info;
  // The old IR: a shallow contact where the proxy is (1 N).
  const Pose here = Pose::FromTranslation(Vec3(0.02, 0, 0.1));
  IntermediateRep old_ir = FloorIr(0.001, 1000, 0);
  old_ir.X_WP_ref = here;
  ev.Accept(old_ir, here);
  for (int i = 1; i <= 30; ++i) ev.Evaluate(here, 0, 1e-3, &W, &K, &info);
  ASSERT_NEAR(W(2), 1.0, 1e-9);
  // The late IR: 2 cm away (1 cm validity radius), 5 mm deep.
  const IntermediateRep late = FloorIr(0.005, 1000, 0);
  ev.Accept(late, here);
  double last = W.norm();
  for (int i = 1; i <= 30; ++i) {
    ev.Evaluate(here, 0, 1e-3, &W, &K, &info);
    EXPECT_LE(W.norm(), last + 1e-12) << "tick " << i << " after the late IR";
    EXPECT_EQ(info.active_rows, 0);
    last = W.norm();
  }
  EXPECT_EQ(W.norm(), 0.0);
  EXPECT_EQ(K.norm(), 0.0);
  // Inside its validity region, 1 mm above its surface, then pressed 1 mm in.
  const Pose above = Pose::FromTranslation(late.X_WP_ref.t + Vec3(0, 0, 0.006));
  for (int i = 1; i <= 60; ++i) ev.Evaluate(above, 0, 1e-3, &W, &K, &info);
  EXPECT_FALSE(info.outside_validity);
  EXPECT_EQ(W.norm(), 0.0);
  const Pose in = Pose::FromTranslation(late.X_WP_ref.t + Vec3(0, 0, 0.004));
  ev.Evaluate(in, 0, 1e-3, &W, &K, &info);
  EXPECT_EQ(info.active_rows, 1);
  EXPECT_NEAR(W(2), 1.0, 1e-9);
}

// Issue 8: under delay the proxy keeps leaving the validity region, the
// rows fade out, the proxy sinks, and the rows fade back in with it deep
// inside, which pushes it (and the hand) out with energy nobody put in. The
// proxy here runs a closed path: sideways out of validity at 1 mm depth,
// down to 5 mm while faded, back inside, up to 1 mm again. The work the
// contact wrench does on the proxy over the loop is what it pumps into it.
double ContactWorkOverValidityLoop(bool energy_neutral_reentry, double* shift_at_end,
                                   double* force_after_lift) {
  IrEvalParams p;
  p.max_age_s = 10;  // never stale here: only the validity region fades
  p.energy_neutral_reentry = energy_neutral_reentry;
  IrEvaluator ev(p);
  const IntermediateRep ir = FloorIr(0.001, 1000, 0);  // surface at z = 0.101
  Vec6 W;
  Mat6 K;
  IrEvalInfo info;
  std::int64_t tick = 0;
  Vec3 x(0, 0, 0.1);
  ev.Accept(ir, Pose::FromTranslation(x));
  for (int i = 0; i < 150; ++i)
    ev.Evaluate(Pose::FromTranslation(x), ++tick * kMs, 1e-3, &W, &K, &info);
  EXPECT_NEAR(W(2), 1.0, 1e-9);  // faded in, 1 mm deep
  double work = 0;
  // Moves the proxy to `to` in `n` ticks, then holds it for `hold` ticks,
  // summing the work of the wrench held over each step.
  auto move = [&](const Vec3& to, int n, int hold) {
    const Vec3 from = x;
    for (int i = 1; i <= n + hold; ++i) {
      const Vec3 next = from + (to - from) * (std::min(i, n) / static_cast<double>(n));
      work += W.head<3>().dot(next - x);
      x = next;
      ev.Evaluate(Pose::FromTranslation(x), ++tick * kMs, 1e-3, &W, &K, &info);
    }
  };
  move(Vec3(0.02, 0, 0.1), 20, 30);  // 2 cm sideways: outside the 1 cm radius, faded out
  EXPECT_TRUE(info.outside_validity);
  EXPECT_EQ(W.norm(), 0.0);
  move(Vec3(0.02, 0, 0.096), 20, 0);  // sinks to 5 mm while faded
  move(Vec3(0, 0, 0.096), 20, 150);   // back inside: fades in
  EXPECT_FALSE(info.outside_validity);
  EXPECT_EQ(info.fade, 1.0);
  move(Vec3(0, 0, 0.1), 20, 10);  // back to the start
  *shift_at_end = info.shift;
  move(Vec3(0, 0, 0.1015), 10, 10);  // lifted clear of the surface
  move(Vec3(0, 0, 0.1), 10, 10);     // and down to 1 mm again
  *force_after_lift = W(2);
  return work;
}

TEST(IrEval, ReenteringTheValidityRegionAddsNoEnergy) {
  double shift = 0, force = 0;
  // Without: the fade-in at 5 mm stores k (5 mm)^2 / 2 = 12.5 mJ, 12 mJ of
  // which comes back out on the way up to 1 mm.
  const double pumped = ContactWorkOverValidityLoop(false, &shift, &force);
  EXPECT_GT(pumped, 0.010);
  EXPECT_EQ(shift, 0.0);
  // With: the rows' surface moved in with the proxy instead (no work), so
  // the loop gives nothing back (the fade-out at 1 mm dissipated 0.5 mJ).
  const double work = ContactWorkOverValidityLoop(true, &shift, &force);
  EXPECT_LE(work, 1e-9);
  EXPECT_NEAR(shift, 0.001, 1e-6);  // followed the proxy back up, slack all the way
  // Once the proxy has been clear of the body the true surface is back.
  EXPECT_NEAR(force, 1.0, 1e-9);
}

TEST(IrEval, TargetSpringIsUnilateralAlongThePdDirection) {
  IntermediateRep ir;
  ir.use_target = true;
  ir.X_WP_ref = Pose::FromTranslation(Vec3(0, 0, 0));
  ir.X_WP_target = Pose::FromTranslation(Vec3(0, 0, 0.004));
  ir.target_stiffness = 500;
  ir.target_rotational_stiffness = 0.05;
  Vec6 W;
  Mat6 K;
  EvaluateIrRaw(ir, ir.X_WP_ref, &W, &K);
  EXPECT_NEAR(W(2), 2.0, 1e-12);
  EvaluateIrRaw(ir, Pose::FromTranslation(Vec3(0, 0, 0.003)), &W, &K);
  EXPECT_NEAR(W(2), 0.5, 1e-9);
  EvaluateIrRaw(ir, Pose::FromTranslation(Vec3(0, 0, 0.005)), &W, &K);  // past the target
  EXPECT_EQ(W.norm(), 0.0);
}

}  // namespace
}  // namespace hapticpd::device
