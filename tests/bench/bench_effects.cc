// Cost of the haptic effects (device/effects.h) per servo tick. For scenes
// declaring no effect, contact only, contact plus each other effect, and all
// of them: the whole ServoLoop::Tick (simulated device, IR evaluation,
// effects, proxy step, coupling) and the effect pipeline alone, p50/p99 ns
// per tick. Goals: an undeclared effect costs 0 (a scene runs only
// its stages), the full set adds <= 5 us per tick.
//
//   bench_effects [--ticks N] [--csv FILE]
//
// --csv FILE also writes one row per scene (tests/bench/update_readme.py
// renders the README's table from it).
//
// The IR is refreshed every tick (a server answering at 1 kHz): four contact
// rows 1 mm deep under the proxy, so every contact effect is active.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include "device/effects.h"
#include "device/servo_loop.h"
#include "device/simulated_device.h"

using namespace hapticpd;
using namespace hapticpd::device;

namespace {

std::int64_t Now() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  const auto k = static_cast<std::size_t>(q * static_cast<double>(v.size() - 1));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

/// Four rows 1 mm deep around the proxy's centre, normal +z.
void ContactIr(const Pose& X_WP, std::uint64_t seq, std::int64_t now_ns, IntermediateRep* ir) {
  ir->sequence = seq;
  ir->sample_time_ns = now_ns;
  ir->receive_time_ns = now_ns;
  ir->X_WP_ref = X_WP;
  ir->num_rows = 4;
  const Vec3 c = X_WP.t;
  for (int i = 0; i < 4; ++i) {
    IrRow& r = ir->rows[static_cast<std::size_t>(i)];
    r.p_W = c + Vec3((i & 1) ? 0.004 : -0.004, (i & 2) ? 0.004 : -0.004, -0.01);
    r.n_W = Vec3::UnitZ();
    r.m_W = (r.p_W - c).cross(r.n_W);
    r.depth = 0.001;
    r.stiffness = 800;
    r.static_friction = 0.5;
    r.dynamic_friction = 0.3;
    r.damping = 1.0;
  }
}

struct Result {
  double tick_p50 = 0, tick_p99 = 0, fx_p50 = 0, fx_p99 = 0;
};

Result Measure(EffectSet set, int ticks) {
  Result res;
  // The whole tick, with a circling hand.
  ManualClock clock;
  ScriptParams sp;
  sp.script = HandScript::kCircle;
  sp.radius = 0.01;
  sp.duration_s = 2;
  SimulatedDevice dev(sp, &clock);
  dev.Open();
  ServoConfig cfg;
  cfg.effects = set;
  ServoLoop loop(&dev, cfg, &clock);
  std::vector<double> tick_ns;
  tick_ns.reserve(static_cast<std::size_t>(ticks));
  const int warm = 1000;
  for (int i = 1; i <= ticks + warm; ++i) {
    clock.Set(static_cast<std::int64_t>(i) * 1'000'000);
    const std::int64_t t0 = Now();
    loop.Tick(clock.NowNs());
    const std::int64_t t1 = Now();
    if (i > warm) tick_ns.push_back(static_cast<double>(t1 - t0));
    ContactIr(loop.last_tick().proxy.X_WP, static_cast<std::uint64_t>(i), clock.NowNs(),
              &loop.ir_mailbox().back());
    loop.ir_mailbox().Publish();
  }
  res.tick_p50 = Quantile(tick_ns, 0.5);
  res.tick_p99 = Quantile(tick_ns, 0.99);

  // The pipeline alone, timed over batches of 64 ticks (timer overhead).
  EffectPipeline p(set);
  IntermediateRep ir;
  ContactIr(Pose::Identity(), 1, 0, &ir);
  EffectInput in;
  in.ir = &ir;
  in.wrench_ir << 0, 0, 3.2, 0.001, -0.002, 0;
  in.K_ir = 3200 * Mat6::Identity();
  std::vector<double> fx_ns;
  constexpr int kBatch = 64;
  Vec6 W;
  Mat6 K;
  double sink = 0;
  for (int b = 0; b < ticks / kBatch; ++b) {
    const std::int64_t t0 = Now();
    for (int i = 0; i < kBatch; ++i) {
      in.t_s = 1e-3 * (b * kBatch + i);
      in.X_WP.t.x() = 1e-5 * ((b * kBatch + i) % 400);  // slides back and forth
      in.v_W.x() = (i % 2) ? 0.01 : -0.01;
      p.Apply(in, &W, &K);
      sink += W(0);
    }
    fx_ns.push_back(static_cast<double>(Now() - t0) / kBatch);
  }
  if (sink == 12345.678) std::printf(" ");  // keep the work observable
  res.fx_p50 = Quantile(fx_ns, 0.5);
  res.fx_p99 = Quantile(fx_ns, 0.99);
  return res;
}

}  // namespace

int main(int argc, char** argv) {
  int ticks = 100000;
  std::string csv;
  for (int i = 1; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--ticks")) ticks = std::max(1000, std::atoi(argv[i + 1]));
    if (!std::strcmp(argv[i], "--csv")) csv = argv[i + 1];
  }
  const EffectSet contact = EffectSet().With(Effect::kContact);
  struct Config {
    const char* name;
    EffectSet set;
  };
  const Config configs[] = {
      {"0 effects (none)", EffectSet()},
      {"1 effect (contact, 3-DoF)", contact},
      {"contact + torque (6-DoF)", EffectSet::ContactAndTorque()},
      {"contact + friction", contact.With(Effect::kFriction)},
      {"contact + damping", contact.With(Effect::kDamping)},
      {"contact + texture", contact.With(Effect::kTexture)},
      {"contact + weight", contact.With(Effect::kWeight)},
      {"all effects", EffectSet::All()},
  };
  std::printf(
      "bench_effects: %d ticks per scene; ns per tick (whole ServoLoop::Tick, and the\n"
      "effect pipeline alone)\n\n",
      ticks);
  std::printf("%-28s %-58s %9s %9s %9s %9s\n", "scene declares", "pipeline", "tick p50", "tick p99",
              "fx p50", "fx p99");
  Measure(EffectSet::All(), ticks / 4);  // warm up caches and the CPU clock; discarded
  std::vector<Result> results;
  for (const Config& c : configs) {
    const Result r = Measure(c.set, ticks);
    results.push_back(r);
    std::printf("%-28s %-58s %9.0f %9.0f %9.1f %9.1f\n", c.name,
                EffectPipeline(c.set).description().c_str(), r.tick_p50, r.tick_p99, r.fx_p50,
                r.fx_p99);
  }
  if (!csv.empty()) {
    std::ofstream out(csv);
    out << "scene,ticks,tick_p50_ns,tick_p99_ns,pipeline_p50_ns,pipeline_p99_ns\n";
    for (std::size_t i = 0; i < results.size(); ++i) {
      const Result& r = results[i];
      out << '"' << configs[i].name << '"' << "," << ticks << "," << r.tick_p50 << "," << r.tick_p99
          << "," << r.fx_p50 << "," << r.fx_p99 << "\n";
    }
    if (!out) std::fprintf(stderr, "bench_effects: cannot write %s\n", csv.c_str());
  }
  const Result& none = results[0];
  const Result& one = results[1];
  const Result& all = results.back();
  std::printf(
      "\nper effect (pipeline p50, ns, over contact only): friction %.1f, damping %.1f, "
      "texture %.1f, weight %.1f, torque %.1f\n",
      results[3].fx_p50 - one.fx_p50, results[4].fx_p50 - one.fx_p50,
      results[5].fx_p50 - one.fx_p50, results[6].fx_p50 - one.fx_p50,
      results[2].fx_p50 - one.fx_p50);
  std::printf(
      "all effects over none: pipeline p50 +%.1f ns (p99 +%.1f), tick p50 %+.0f ns "
      "(p99 %+.0f); goal: <= 5000 ns\n",
      all.fx_p50 - none.fx_p50, all.fx_p99 - none.fx_p99, all.tick_p50 - none.tick_p50,
      all.tick_p99 - none.tick_p99);
  return 0;
}
