// The servo loop in real time: a simulated hand pressing a stick probe into
// a torus knot, the 1 kHz loop on its own thread (absolute deadlines), and
// the PDt source on a worker thread on the same machine. Reports tick
// compute time (goal p99 <= 20 us) and period jitter (goal p99 period error
// <= 100 us, < 0.1% late ticks).
//
//   bench_servo [--seconds S] [--script press|slide|twist|circle|loop|plate]
#include <algorithm>
#include <cstdio>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "device/local_pd_source.h"
#include "device/servo_loop.h"
#include "device/simulated_device.h"
#include "pd/shapes.h"

using namespace hapticpd;
using namespace hapticpd::device;

int main(int argc, char** argv) {
  double seconds = 10;
  std::string script = "loop";
  for (int i = 1; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--seconds"))
      seconds = std::atof(argv[i + 1]);
    else if (!std::strcmp(argv[i], "--script"))
      script = argv[i + 1];
  }
  pd::Material m;
  m.stiffness = 3000;
  const pd::ModelPtr knot = pd::MakeModel(pd::shapes::TorusKnot());
  const pd::ModelPtr stick = pd::MakeModel(pd::shapes::Stick());
  std::vector<pd::SceneBody> scene = {{knot, Pose::Identity(), m}};
  Vec3 lo = Vec3::Constant(1e9), hi = Vec3::Constant(-1e9);
  for (const Vec3& v : knot->mesh().vertices()) lo = lo.cwiseMin(v), hi = hi.cwiseMax(v);

  ScriptParams sp;
  sp.script = ParseHandScript(script);
  // Stick upright, its tip 5 mm above the knot's top, over a strand.
  sp.X_DS = Pose::FromTranslation(Vec3(0.075, 0, hi.z() + 0.075 + 0.005));
  sp.travel = 0.02;
  sp.duration_s = 4;
  const SteadyClock& clock = SteadyClock::Instance();
  SimulatedDevice dev(sp, &clock);
  dev.Open();
  LocalPdIrSource source(stick, scene);
  ServoConfig cfg;
  cfg.X_PA = source.X_PA();
  ServoLoop loop(&dev, cfg, &clock);

  // Repeat the script for the whole run (re-open restarts it).
  loop.Start();
  source.Start(&loop, &clock);
  const auto t_end = clock.NowNs() + static_cast<std::int64_t>(seconds * 1e9);
  while (clock.NowNs() < t_end) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  source.Stop();
  loop.Stop();

  const ServoStats& s = loop.stats();
  std::vector<double> pd = source.compute_times_us();
  std::sort(pd.begin(), pd.end());
  auto q = [&](double f) {
    return pd.empty() ? 0.0 : pd[static_cast<std::size_t>(f * (pd.size() - 1))];
  };
  std::printf("bench_servo: %.1f s, script %s, SCHED_FIFO %s\n", seconds, script.c_str(),
              loop.got_realtime_priority() ? "yes" : "no (not permitted)");
  std::printf("tick compute us: p50 %.2f p99 %.2f p99.9 %.2f max %.1f (goal p99 <= 20)\n",
              s.compute_us.Quantile(0.5), s.compute_us.Quantile(0.99), s.compute_us.Quantile(0.999),
              s.compute_us.max());
  std::printf("period us: mean %.2f std %.2f p50 %.1f p99 %.1f p99.9 %.1f max %.1f\n",
              s.period_us.mean(), s.period_us.stddev(), s.period_us.Quantile(0.5),
              s.period_us.Quantile(0.99), s.period_us.Quantile(0.999), s.period_us.max());
  const double err99 = std::max(std::abs(s.period_us.Quantile(0.99) - 1000.0),
                                std::abs(1000.0 - s.period_us.Quantile(0.01)));
  std::printf(
      "period error p99 %.1f us (goal <= 100), late ticks %llu of %llu (%.4f%%, goal < 0.1%%)\n",
      err99, static_cast<unsigned long long>(s.late_ticks),
      static_cast<unsigned long long>(s.ticks),
      s.ticks ? 100.0 * static_cast<double>(s.late_ticks) / static_cast<double>(s.ticks) : 0);
  std::printf("PD worker: %zu answers, PDt us p50 %.1f p99 %.1f; IR age ms p50 %.2f p99 %.2f\n",
              pd.size(), q(0.5), q(0.99), s.ir_age_ms.Quantile(0.5), s.ir_age_ms.Quantile(0.99));
  std::printf("%s\n", s.Summary().c_str());
  return 0;
}
