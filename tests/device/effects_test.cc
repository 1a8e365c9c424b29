// The haptic effects (device/effects.h): each effect's signature on a
// simulated device in simulated time, the pipeline composing only the
// declared effects, and the tick staying allocation-free with all of them.
#include "device/effects.h"

#include <gtest/gtest.h>

#include <cmath>
#include <complex>
#include <memory>
#include <numbers>

#include "device/servo_loop.h"
#include "device/simulated_device.h"
#include "tests/alloc_counter.h"

namespace hapticpd::device {
namespace {

constexpr double kRadius = 0.01;  // the probe: a sphere of this radius about P

struct FloorMaterial {
  double stiffness = 3000;
  double static_friction = 0;
  double dynamic_friction = 0;
  double damping = 0;
};

/// A floor z = 0 answered every tick at the proxy's pose, as a server
/// answering at 1 kHz would: one row under the sphere probe.
struct FloorRig {
  ManualClock clock;
  std::unique_ptr<SimulatedDevice> device;
  std::unique_ptr<ServoLoop> loop;
  FloorMaterial material;
  bool floor = true;
  std::int64_t tick = 0;

  FloorRig(const ScriptParams& script, EffectSet effects, const EffectParams& params = {},
           FloorMaterial m = {}, bool with_floor = true)
      : material(m), floor(with_floor) {
    device = std::make_unique<SimulatedDevice>(script, &clock);
    device->Open();
    ServoConfig config;
    config.effects = effects;
    config.effect_params = params;
    loop = std::make_unique<ServoLoop>(device.get(), config, &clock);
  }

  double time_s() const { return 1e-9 * static_cast<double>(clock.NowNs()); }

  void Answer() {
    ProxyMailbox& out = loop->proxy_mailbox();
    if (!floor || !out.Fetch()) return;
    const ProxySample& s = out.front();
    IntermediateRep& ir = loop->ir_mailbox().back();
    ir.sequence = s.sequence;
    ir.sample_time_ns = s.time_ns;
    ir.receive_time_ns = clock.NowNs();
    ir.X_WP_ref = s.X_WP;
    ir.num_rows = 0;
    const double cx = s.X_WP.t.x(), cy = s.X_WP.t.y(), cz = s.X_WP.t.z();
    const double depth = kRadius - cz;
    if (depth > 0) {
      IrRow row;
      row.p_W << cx, cy, 0;
      row.n_W << 0, 0, 1;
      row.m_W.setZero();  // (p - c) x n with p - c = (0, 0, -cz) parallel to n
      row.depth = depth;
      row.stiffness = material.stiffness;
      row.static_friction = material.static_friction;
      row.dynamic_friction = material.dynamic_friction;
      row.damping = material.damping;
      ir.rows[0] = row;
      ir.num_rows = 1;
    }
    loop->ir_mailbox().Publish();
  }

  void Step() {
    clock.Set(++tick * 1'000'000);
    loop->Tick(clock.NowNs());
    Answer();
  }

  template <typename F>
  void Run(double seconds, F&& each) {
    const auto n = static_cast<std::int64_t>(seconds * 1000 + 0.5);
    for (std::int64_t i = 0; i < n; ++i) {
      Step();
      each(loop->last_tick());
    }
  }
};

/// Start: the sphere's bottom 2 mm above the floor.
ScriptParams Script(HandScript s, double duration_s, double travel = 0.01) {
  ScriptParams p;
  p.script = s;
  p.duration_s = duration_s;
  p.travel = travel;
  p.lateral = 0.04;
  p.X_DS.t = Vec3(0, 0, kRadius + 0.002);
  return p;
}

// --- The pipeline -------------------------------------------------------------

TEST(EffectPipeline, ComposesOnlyTheDeclaredEffects) {
  EXPECT_EQ(EffectPipeline(EffectSet::ContactAndTorque()).description(), "contact(force+torque)");
  EXPECT_EQ(EffectPipeline(EffectSet().With(Effect::kContact)).description(), "contact(force)");
  EXPECT_EQ(EffectPipeline(EffectSet()).description(), "none");
  EXPECT_EQ(EffectPipeline(EffectSet()).num_stages(), 0);
  const EffectPipeline all(EffectSet::All());
  EXPECT_EQ(all.num_stages(), 5);  // torque selects the contact stage, it adds none
  EXPECT_EQ(all.description(), "contact(force+torque) > friction > damping > texture > weight");
  EXPECT_EQ(EffectSet::All().ToString(), "contact,damping,friction,weight,texture,torque");
}

TEST(EffectPipeline, ContactOnlySceneRunsNoOtherEffectCode) {
  FloorMaterial m;
  m.static_friction = 0.8;  // the material has them; the scene does not declare them
  m.dynamic_friction = 0.5;
  m.damping = 1;
  FloorRig rig(Script(HandScript::kSlide, 2), EffectSet().With(Effect::kContact), {}, m);
  double max_force = 0, max_torque = 0;
  rig.Run(2, [&](const TickRecord& r) {
    max_force = std::max(max_force, r.F_cmd_W.force.norm());
    max_torque = std::max(max_torque, r.F_cmd_W.torque.norm());
  });
  const EffectState& s = rig.loop->effects().state();
  EXPECT_EQ(s.runs[static_cast<int>(Effect::kContact)], 2000u);
  for (Effect e : {Effect::kFriction, Effect::kDamping, Effect::kTexture, Effect::kWeight}) {
    EXPECT_EQ(s.runs[static_cast<int>(e)], 0u) << ToString(e);
  }
  EXPECT_GT(max_force, 1.0);  // it did touch the floor
  // No torque declared: 3-DoF rendering, no rotational output.
  EXPECT_EQ(rig.loop->coupling().gains.max_torque, 0);
  EXPECT_EQ(max_torque, 0);
}

TEST(EffectPipeline, EmptyPipelineGivesNoWrench) {
  EffectPipeline p(EffectSet{});
  EffectInput in;
  in.wrench_ir << 1, 2, 3, 4, 5, 6;
  in.K_ir = Mat6::Identity();
  Vec6 W = Vec6::Constant(7);
  Mat6 K = Mat6::Constant(7);
  p.Apply(in, &W, &K);
  EXPECT_TRUE(W.isZero());
  EXPECT_TRUE(K.isZero());
}

// Friction on its own: move the proxy tangentially step by step on a floor
// pressing with N; the force grows like a spring up to mu_s N, then the
// contact slips and the force is mu_d N, opposing the motion.
TEST(Friction, StickUpToMuSThenSlipAtMuD) {
  EffectParams params;
  params.friction_stiffness = 1000;
  EffectPipeline p(EffectSet().With(Effect::kFriction), params);
  IntermediateRep ir;
  ir.num_rows = 1;
  ir.rows[0].n_W = Vec3::UnitZ();
  ir.rows[0].depth = 0.002;
  ir.rows[0].stiffness = 1000;
  ir.rows[0].static_friction = 0.6;
  ir.rows[0].dynamic_friction = 0.4;
  const double N = 2.0;
  EffectInput in;
  in.ir = &ir;
  in.wrench_ir.head<3>() = Vec3(0, 0, N);
  Vec6 W;
  Mat6 K;
  double peak = 0;
  bool slipped = false;
  for (int i = 0; i <= 400; ++i) {
    in.X_WP.t = Vec3(1e-5 * i, 0, 0);  // 10 um per tick along +x
    p.Apply(in, &W, &K);
    const double fx = W(0);
    EXPECT_LE(fx, 1e-12);            // opposes the motion
    EXPECT_LE(-fx, 0.6 * N + 1e-9);  // inside the friction cone
    EXPECT_NEAR(W(2), 0, 1e-12);     // tangential only
    if (!p.state().slipping) {
      EXPECT_NEAR(-fx, 1000 * 1e-5 * i, 1e-9);  // sticking: a spring to the anchor
      EXPECT_FALSE(slipped);
    } else {
      slipped = true;
      EXPECT_NEAR(-fx, 0.4 * N, 1e-9);  // slipping: mu_d N
      EXPECT_NEAR(K(0, 0), 0, 1e-12);
    }
    peak = std::max(peak, -fx);
  }
  EXPECT_TRUE(slipped);
  EXPECT_NEAR(peak, 0.6 * N, 0.01 * N);
  // Stop and come back a little: sticks again, the force falls below mu_d N.
  in.X_WP.t.x() -= 2e-4;
  p.Apply(in, &W, &K);
  EXPECT_FALSE(p.state().slipping);
  EXPECT_NEAR(-W(0), 0.4 * N - 1000 * 2e-4, 1e-9);
  // Lift off: no normal force, no friction, anchor forgotten.
  in.wrench_ir.setZero();
  p.Apply(in, &W, &K);
  EXPECT_TRUE(W.isZero());
  EXPECT_FALSE(p.state().anchored);
}

// --- Signatures on the simulated device -----------------------------------

struct SlideStats {
  double ratio_slide = 0;       // mean |F_t| / F_n while the proxy slides
  double ratio_peak = 0;        // largest |F_t| / F_n
  double peak_proxy_speed = 0;  // proxy speed when the ratio peaked
  double opposing = 1;  // smallest sign-corrected F_x while sliding (> 0: opposes +x motion)
  double proxy_travel = 0;
};

SlideStats Slide(EffectSet fx, const FloorMaterial& m) {
  FloorRig rig(Script(HandScript::kSlide, 3), fx, {}, m);
  SlideStats st;
  double sum = 0;
  int n = 0;
  double x0 = 0;
  rig.Run(3, [&](const TickRecord& r) {
    const double t = 1e-9 * static_cast<double>(r.time_ns);
    const Vec3 F = r.F_cmd_W.force;  // on the handle
    if (t < 0.6) x0 = r.proxy.X_WP.t.x();
    if (t < 0.6 || t > 2.4 || F.z() < 0.5) return;
    const double ratio = std::abs(F.x()) / F.z();
    if (ratio > st.ratio_peak) {
      st.ratio_peak = ratio;
      st.peak_proxy_speed = std::abs(r.proxy.v_W.x());
    }
    if (t > 1.2 && t < 1.8) {
      sum += ratio;
      ++n;
      st.opposing = std::min(st.opposing, -F.x());
    }
    st.proxy_travel = r.proxy.X_WP.t.x() - x0;
  });
  st.ratio_slide = n > 0 ? sum / n : 0;
  return st;
}

TEST(Friction, SimulatedSlideOpposesUpToMuSNThenSlipsAtMuDN) {
  FloorMaterial m;
  m.static_friction = 0.6;
  m.dynamic_friction = 0.4;
  const SlideStats none = Slide(EffectSet().With(Effect::kContact), m);
  const SlideStats fr = Slide(EffectSet().With(Effect::kContact).With(Effect::kFriction), m);
  // Without friction the tangential force is only the coupling's drag.
  EXPECT_LT(none.ratio_slide, 0.1);
  // With it: the hand feels a force opposing the slide, ...
  EXPECT_GT(fr.opposing, 0);
  // ... about mu_d N while slipping (plus the small drag), ...
  EXPECT_NEAR(fr.ratio_slide, 0.4 + none.ratio_slide, 0.06);
  // ... never more than mu_s N (plus drag), reached while the proxy still sticks,
  EXPECT_NEAR(fr.ratio_peak, 0.6, 0.1);
  EXPECT_LT(fr.peak_proxy_speed, 0.01);
  // ... and the probe does slide along (slip, not stuck forever).
  EXPECT_GT(fr.proxy_travel, 0.02);
}

/// Least-squares b in F_x = -b v_x over the steady part of a slide.
double DampingCoefficient(EffectSet fx, double duration_s, double b_material) {
  FloorMaterial m;
  m.damping = b_material;
  FloorRig rig(Script(HandScript::kSlide, duration_s), fx, {}, m);
  double fv = 0, vv = 0;
  rig.Run(duration_s, [&](const TickRecord& r) {
    const double s = 1e-9 * static_cast<double>(r.time_ns) / duration_s;
    if (s < 0.3 || s > 0.7) return;
    // The commanded force on the handle is minus the force on the proxy.
    fv += r.F_cmd_W.force.x() * r.proxy.v_W.x();
    vv += r.proxy.v_W.x() * r.proxy.v_W.x();
  });
  return -fv / vv;
}

TEST(Damping, SimulatedForceIsProportionalToVelocity) {
  const double b = 2.0;
  const EffectSet with = EffectSet().With(Effect::kContact).With(Effect::kDamping);
  const EffectSet without = EffectSet().With(Effect::kContact);
  // Two speeds (the same slide in 2 s and in 4 s).
  const double fast = DampingCoefficient(with, 2, b), slow = DampingCoefficient(with, 4, b);
  const double drag_fast = DampingCoefficient(without, 2, b);
  const double drag_slow = DampingCoefficient(without, 4, b);
  // The effect adds b N s/m of viscous force at either speed: F proportional to v.
  EXPECT_NEAR(fast - drag_fast, b, 0.15 * b);
  EXPECT_NEAR(slow - drag_slow, b, 0.15 * b);
}

TEST(Damping, NoDampingOutsideContact) {
  FloorMaterial m;
  m.damping = 2;
  ScriptParams sp = Script(HandScript::kSlide, 2, /*travel=*/0.0);  // glides above the floor
  FloorRig rig(sp, EffectSet().With(Effect::kContact).With(Effect::kDamping), {}, m);
  double max_force = 0;
  rig.Run(2, [&](const TickRecord& r) { max_force = std::max(max_force, r.F_cmd_W.force.norm()); });
  EXPECT_EQ(rig.loop->effects().state().runs[static_cast<int>(Effect::kDamping)], 2000u);
  EXPECT_LT(max_force, 0.2);  // only the coupling's drag
}

TEST(Weight, SimulatedConstantDownwardForceAtRest) {
  EffectParams p;
  p.probe_mass = 0.03;
  for (bool declared : {false, true}) {
    FloorRig rig(Script(HandScript::kHold, 2),
                 declared ? EffectSet().With(Effect::kWeight) : EffectSet(), p, {},
                 /*with_floor=*/false);
    double fz_min = 1e9, fz_max = -1e9, fxy = 0;
    rig.Run(2, [&](const TickRecord& r) {
      if (1e-9 * static_cast<double>(r.time_ns) < 1.0) return;  // after the start-up ramp
      fz_min = std::min(fz_min, r.F_cmd_W.force.z());
      fz_max = std::max(fz_max, r.F_cmd_W.force.z());
      fxy = std::max(fxy, r.F_cmd_W.force.head<2>().norm());
    });
    const double mg = declared ? 0.03 * 9.81 : 0;
    EXPECT_NEAR(fz_min, -mg, 0.01 * 0.03 * 9.81 + 1e-6) << declared;
    EXPECT_NEAR(fz_max, -mg, 0.01 * 0.03 * 9.81 + 1e-6) << declared;
    EXPECT_LT(fxy, 1e-9);
  }
}

/// Amplitude of the f-Hz component of x(t) sampled at 1 kHz.
double Amplitude(const std::vector<double>& x, double f) {
  std::complex<double> s = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    s += x[i] * std::polar(1.0, -2 * std::numbers::pi * f * 1e-3 * static_cast<double>(i));
  }
  return 2 * std::abs(s) / static_cast<double>(x.size());
}

TEST(Texture, SimulatedVibrationAtTheDeclaredFrequency) {
  EffectParams p;
  p.texture_amplitude = 0.3;
  p.texture_frequency = 60;
  // A slow press: the hand holds in contact from 4.5 s to 5.5 s.
  for (bool declared : {false, true}) {
    const EffectSet fx = declared ? EffectSet().With(Effect::kContact).With(Effect::kTexture)
                                  : EffectSet().With(Effect::kContact);
    FloorRig rig(Script(HandScript::kPress, 10), fx, p);
    std::vector<double> fz;
    rig.Run(5.5, [&](const TickRecord& r) {
      const double t = 1e-9 * static_cast<double>(r.time_ns);
      if (t > 4.5) fz.push_back(r.F_cmd_W.force.z());
    });
    ASSERT_EQ(fz.size(), 1000u);
    const double at = Amplitude(fz, 60), off = Amplitude(fz, 37);
    if (declared) {
      // The vibration acts on the proxy, so the hand feels the coupling's
      // share of it against the contact stiffness (here 1000 / (1000 + 3000)
      // statically, more near the proxy's resonance; 0.27 measured): clearly
      // there, at 60 Hz and nowhere else.
      EXPECT_GT(at, 0.25 * 0.3) << "felt amplitude at 60 Hz";
      EXPECT_LT(at, 0.3 * 1.2);
      EXPECT_LT(off, 0.1 * at);
    } else {
      EXPECT_LT(at, 0.01);
    }
  }
}

TEST(Effects, AllEffectsTickDoesNotAllocate) {
  if (!hapticpd::testing::CountAllocations::Available()) GTEST_SKIP() << "sanitizer build";
  FloorMaterial m;
  m.static_friction = 0.5;
  m.dynamic_friction = 0.3;
  m.damping = 1;
  FloorRig rig(Script(HandScript::kSlide, 2), EffectSet::All(), {}, m);
  rig.Run(0.9, [](const TickRecord&) {});
  std::size_t allocations = 0;
  for (int i = 0; i < 500; ++i) {
    rig.clock.Set(++rig.tick * 1'000'000);
    {
      hapticpd::testing::CountAllocations count;
      rig.loop->Tick(rig.clock.NowNs());
      allocations += count.count();
    }
    rig.Answer();
  }
  EXPECT_EQ(allocations, 0u);
  EXPECT_GT(rig.loop->effects().state().runs[static_cast<int>(Effect::kFriction)], 1000u);
}

}  // namespace
}  // namespace hapticpd::device
