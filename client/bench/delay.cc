#include "client/bench/delay.h"

#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <memory>
#include <optional>
#include <ostream>
#include <stdexcept>
#include <thread>

#include "client/bench/svg.h"
#include "client/link_emulator.h"
#include "client/session.h"
#include "device/servo_loop.h"
#include "device/simulated_device.h"
#include "pd/geometry_model.h"
#include "pd/mesh.h"
#include "pd/queries.h"
#include "pd/scene_pd.h"
#include "pd/shapes.h"
#include "proto/wire/convert.h"
#include "server/server.h"

namespace hapticpd::bench {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// The scenes (metres). press: a box, top face at z = kBoxTop. twist: two
// walls either side of y = 0 with kSlotGap of clearance each side of the
// stick (radius kStickRadius), tops at z = kWallTop.
constexpr double kBoxTop = 0.05;
constexpr double kStickRadius = 0.005;  // pd::shapes::Stick(): radius 5 mm, half length 75 mm
constexpr double kSlotGap = 0.0015;
constexpr double kWallHalf = 0.02;
constexpr double kWallTop = kWallHalf;
// Every script starts the probe this far above the surface and sends the
// hand's target kPressDepth below it: with the hand's 300 N/m spring and the
// default 1000 N/m material behind the coupling, about 3 N at 0 ms.
constexpr double kClearance = 0.003;
constexpr double kPressDepth = 0.015;
constexpr double kTwistAngle = 0.15;   // rad
constexpr double kFreeMargin = 1e-3;   // m: "free" is farther than this from every body
constexpr double kFreeMaxSpeed = 0.3;  // m/s, the free-space goal's hand speed
constexpr int kMinFitTicks = 20;
// A tick the machine delayed by more than this (s), and the kLateSettle
// ticks after it, are left out of the free-space figure: the simulated hand
// moves on in real time while the proxy takes one step, and the coupling
// stretch that follows is the machine's, not the renderer's (as
// tests/client/session_rig.h's LateTickWindow).
constexpr double kLateGap = 3e-3;
constexpr int kLateSettle = 30;

/// One servo tick as measured afterwards.
struct TickSample {
  double t_s = 0;
  Vec3 F = Vec3::Zero(), tau = Vec3::Zero();
  Pose X_WH, X_WP;
  double handle_speed = 0;
  int active_rows = 0;
  bool have_ir = false, stale = false, outside = false;
  std::uint8_t source = 0;  ///< device::IntermediateRep::source
};

/// A script's scene, probe and hand, and the true geometry to measure
/// against.
struct Scenario {
  std::string name;
  std::string scene_json;  // a scene file for the server
  std::string scene_id;
  v1::Hello hello_probe;  // probe_shape or probe_mesh
  pd::ModelPtr probe;     // the same probe, in process
  std::vector<pd::SceneBody> bodies;
  device::ScriptParams script;  // X_DS identity; duration at time scale 1
  Vec3 start = Vec3::Zero();    // the probe mesh frame's start position (W)
  bool torque_plot = false;
};

std::string PoseJson(const Pose& X) {
  const Quat q = X.Rotation();
  char buf[256];
  std::snprintf(buf, sizeof(buf),
                "{\"position\": [%.17g, %.17g, %.17g], \"orientation\": [%.17g, %.17g, %.17g, "
                "%.17g]}",
                X.t.x(), X.t.y(), X.t.z(), q.w(), q.x(), q.y(), q.z());
  return buf;
}

std::string BodyJson(const std::string& id, const std::string& key, const std::string& value,
                     const Pose& X) {
  return "{\"id\": \"" + id + "\", \"" + key + "\": \"" + value + "\", \"pose\": " + PoseJson(X) +
         "}";
}

std::string SceneJson(const std::string& id, const std::vector<std::string>& bodies) {
  std::string s = "{\"scene\": \"" + id +
                  "\", \"mode\": \"pdt\", \"effects\": [\"contact\", \"torque\"], \"bodies\": [";
  for (std::size_t i = 0; i < bodies.size(); ++i) s += (i ? ", " : "") + bodies[i];
  return s + "]}";
}

/// The height of the probe's mesh frame at which the probe, lowered along z
/// at (x, y), first touches the bodies (bisection on Collide); nullopt when
/// it passes through without touching.
std::optional<double> TouchHeight(const pd::GeometryModel& probe,
                                  const std::vector<pd::SceneBody>& bodies, double x, double y,
                                  double z_top, double z_bottom) {
  pd::QueryScratch scratch;
  pd::CollisionRequest req;
  pd::CollisionResult res;
  auto touches = [&](double z) {
    for (const pd::SceneBody& b : bodies) {
      if (pd::Collide(probe, Pose::FromTranslation(Vec3(x, y, z)), *b.model, b.X_WB, req, &res,
                      &scratch)) {
        return true;
      }
    }
    return false;
  };
  if (touches(z_top)) return std::nullopt;
  // Coarse steps down to the first touching height, then bisect.
  const double step = 1e-3;
  double hi = z_top, lo = z_top;
  for (;;) {
    lo = hi - step;
    if (lo < z_bottom) return std::nullopt;
    if (touches(lo)) break;
    hi = lo;
  }
  for (int i = 0; i < 30; ++i) {
    const double mid = 0.5 * (lo + hi);
    (touches(mid) ? lo : hi) = mid;
  }
  return hi;
}

Scenario PressScenario() {
  Scenario s;
  s.name = "press";
  s.scene_id = "press";
  const Pose X_WB = Pose::Identity();
  s.scene_json = SceneJson("press", {BodyJson("box", "shape", "box:0.1,0.1,0.05", X_WB)});
  s.hello_probe.set_probe_shape("stick");
  s.probe = pd::MakeModel(pd::shapes::MakeShape("stick"));
  s.bodies.push_back({pd::MakeModel(pd::shapes::MakeShape("box:0.1,0.1,0.05")), X_WB, {}});
  const double below = -s.probe->mesh().bounds().lo.z();
  s.start = Vec3(0, 0, kBoxTop + below + kClearance);
  s.script.script = device::HandScript::kPress;
  s.script.travel = kClearance + kPressDepth;
  s.script.duration_s = 1.5;
  return s;
}

Scenario SlideScenario(const std::string& models, std::string* body_name,
                       std::vector<std::string>* notes) {
  Scenario s;
  s.name = "slide";
  s.scene_id = "slide";
  std::filesystem::path bunny;
  if (!models.empty()) bunny = std::filesystem::path(models) / "stanford-bunny.obj";
  pd::Mesh mesh;
  Pose X_WB = Pose::Identity();
  if (!bunny.empty() && std::filesystem::is_regular_file(bunny)) {
    mesh = pd::LoadMesh(bunny.string());
    // The scan is y-up: stand it on the z = 0 plane's side of the world.
    X_WB = Pose::FromQuaternion(Quat(std::sqrt(0.5), std::sqrt(0.5), 0, 0), Vec3::Zero());
    const std::string abs = std::filesystem::absolute(bunny).string();
    s.scene_json = SceneJson("slide", {BodyJson("bunny", "mesh", abs, X_WB)});
    *body_name = "stanford-bunny.obj";
    notes->push_back("slide: " + abs + " (" + std::to_string(mesh.num_triangles()) +
                     " triangles), turned y-up to z-up");
  } else {
    mesh = pd::shapes::MakeShape("torusknot");
    s.scene_json = SceneJson("slide", {BodyJson("knot", "shape", "torusknot", X_WB)});
    *body_name = "torusknot";
    notes->push_back("slide: NOTE: stanford-bunny.obj not found" +
                     (models.empty() ? std::string() : " in " + models) + ": a torus knot (" +
                     std::to_string(mesh.num_triangles()) + " triangles) instead");
  }
  s.bodies.push_back({pd::MakeModel(std::move(mesh)), X_WB, {}});
  s.hello_probe.set_probe_shape("stick");
  s.probe = pd::MakeModel(pd::shapes::MakeShape("stick"));
  // World bounds of the body.
  const auto& bb = s.bodies[0].model->mesh().bounds();
  Vec3 lo = Vec3::Constant(1e9), hi = -lo;
  for (int i = 0; i < 8; ++i) {
    const Vec3 p((i & 1) ? bb.hi.x() : bb.lo.x(), (i & 2) ? bb.hi.y() : bb.lo.y(),
                 (i & 4) ? bb.hi.z() : bb.lo.z());
    lo = lo.cwiseMin(X_WB * p);
    hi = hi.cwiseMax(X_WB * p);
  }
  // On the bunny: the flattest patch near the middle of its back along x,
  // the slide's direction (a stick started on a slope slides off it, or
  // runs its side into the rising neck), from the surface heights on a grid
  // of 4.5 mm (the circle's radius / 2); the knot has a hole in its middle,
  // so its start is above its highest vertex.
  const double below = -s.probe->mesh().bounds().lo.z();
  const double r = 0.5 * (kClearance + kPressDepth);
  Vec3 at = 0.5 * (lo + hi);
  auto height = [&](double x, double y) {
    return TouchHeight(*s.probe, s.bodies, x, y, hi.z() + below + 0.01, lo.z() - below);
  };
  if (*body_name == "torusknot") {
    const auto& V = s.bodies[0].model->mesh().vertices();
    Vec3 top = X_WB * V[0];
    for (const Vec3& v : V) {
      if ((X_WB * v).z() > top.z()) top = X_WB * v;
    }
    at = top;
  } else {
    constexpr int kN = 7;  // grid half-width in cells
    const double step = 0.5 * r;
    std::vector<std::optional<double>> h((2 * kN + 1) * (2 * kN + 1));
    auto cell = [&](int i, int j) -> std::optional<double>& {
      return h[static_cast<std::size_t>((i + kN) * (2 * kN + 1) + (j + kN))];
    };
    for (int i = -kN; i <= kN; ++i) {
      for (int j = -kN; j <= kN; ++j) cell(i, j) = height(at.x() + step * i, at.y() + step * j);
    }
    double best = 1e9;
    Vec3 best_at = at;
    for (int i = -kN + 2; i <= kN - 2; ++i) {
      for (int j = -kN + 1; j <= kN - 1; ++j) {
        const auto& c = cell(i, j);
        const auto &l = cell(i - 2, j), &rr = cell(i + 2, j), &d = cell(i, j - 1),
                   &u = cell(i, j + 1);
        if (!c || !l || !rr || !d || !u) continue;
        const double score = std::abs(*l - *c) + std::abs(*rr - *c) + std::abs(*u - *d);
        if (score < best) {
          best = score;
          best_at = Vec3(at.x() + step * i, at.y() + step * j, *c);
        }
      }
    }
    at = best_at;
  }
  const std::optional<double> z =
      TouchHeight(*s.probe, s.bodies, at.x(), at.y(), hi.z() + below + 0.01, lo.z() - below);
  if (!z) throw std::runtime_error("bench delay: the stick finds no surface to slide on");
  s.start = Vec3(at.x(), at.y(), *z + kClearance);
  // A vertical circle through the start whose lowest point is kPressDepth
  // below the surface: down and across the surface, back up to the start.
  // (The device's `slide` script ends beside its start: not closed.)
  s.script.script = device::HandScript::kCircle;
  s.script.radius = 0.5 * (kClearance + kPressDepth);
  s.script.duration_s = 2.0;
  return s;
}

Scenario TwistScenario() {
  Scenario s;
  s.name = "twist";
  s.scene_id = "twist";
  s.torque_plot = true;
  const double y = kStickRadius + kSlotGap + kWallHalf;
  const Pose X_WL = Pose::FromTranslation(Vec3(0, -y, 0));
  const Pose X_WR = Pose::FromTranslation(Vec3(0, y, 0));
  const std::string wall = "box:0.1,0.02,0.02";
  s.scene_json = SceneJson(
      "twist", {BodyJson("left", "shape", wall, X_WL), BodyJson("right", "shape", wall, X_WR)});
  s.bodies.push_back({pd::MakeModel(pd::shapes::MakeShape(wall)), X_WL, {}});
  s.bodies.push_back({pd::MakeModel(pd::shapes::MakeShape(wall)), X_WR, {}});
  // The stick lying along x (turned a quarter about y), so a twist about
  // the vertical swings its ends into the walls.
  const pd::Mesh stick = pd::shapes::MakeShape("stick").Transformed(
      Pose::FromQuaternion(Quat(std::sqrt(0.5), 0, std::sqrt(0.5), 0), Vec3::Zero()));
  wire::ToProto(stick, s.hello_probe.mutable_probe_mesh());
  s.probe = pd::MakeModel(stick);
  // In the slot, its top level with the walls' tops; down 1 cm, twist, back.
  s.start = Vec3(0, 0, kWallTop - kStickRadius);
  s.script.script = device::HandScript::kTwist;
  s.script.travel = 0.01;
  s.script.angle = kTwistAngle;
  s.script.duration_s = 2.0;
  return s;
}

/// Runs one scenario at one delay in real time; returns the ticks.
std::vector<TickSample> RunOnce(const Scenario& sc, int port, double delay_ms, double jitter_ms,
                                double time_scale, std::uint64_t seed, bool local_model,
                                DelayRun* run) {
  client::SessionOptions so;
  so.local_model = local_model;
  so.server = "127.0.0.1:" + std::to_string(port);
  so.hello = sc.hello_probe;
  so.hello.set_scene_id(sc.scene_id);
  so.hello.set_mode(v1::PD_MODE_PDT);
  so.hello.set_client_name("hapticpd bench delay");
  so.connect_timeout_s = 10;
  if (delay_ms > 0) {
    client::LinkOptions link;
    link.delay_ms = delay_ms;
    link.jitter_ms = jitter_ms;
    link.seed = seed;
    so.link = link;
  }
  client::Session session(so);
  session.Connect();
  const device::Pose X_PA = session.X_PA();
  device::ScriptParams sp = sc.script;
  sp.duration_s *= time_scale;
  // The hand waits for the link: two round trips (and 0.1 s) at the start
  // pose, so every delay's script begins with the session answering (a user
  // does not reach for the scene before the device session is up).
  sp.hold_s = 0.1 + 2.5e-3 * delay_ms;
  const auto& clock = device::SteadyClock::Instance();
  device::SimulatedDevice dev(sp, &clock);
  dev.Open();
  device::ServoConfig config;
  config.X_PA = X_PA;
  // The device frame at the start pose of the proxy (P = A moved to the CoM).
  config.X_WD = Pose::FromTranslation(sc.start) * X_PA.Inverse();
  config.X_WD.R = Mat3::Identity();
  config.effects = client::EffectsFromSceneConfig(session.welcome().scene_config());
  device::ServoLoop loop(&dev, config, &clock);
  session.Start(&loop);
  const int ticks = static_cast<int>(std::lround((sp.hold_s + sp.duration_s + 0.3) * 1000));
  std::vector<TickSample> out;
  out.reserve(static_cast<std::size_t>(ticks));
  // Ticked by this thread at absolute 1 ms deadlines, as the loop's own
  // runner does, so that every tick's record can be kept.
  auto next = std::chrono::steady_clock::now();
  const std::int64_t t0 = clock.NowNs();
  for (int i = 0; i < ticks; ++i) {
    next += std::chrono::milliseconds(1);
    std::this_thread::sleep_until(next);
    if (std::chrono::steady_clock::now() - next > std::chrono::milliseconds(5)) {
      next = std::chrono::steady_clock::now();  // stalled: no burst to catch up
    }
    loop.Tick(clock.NowNs());
    const device::TickRecord& r = loop.last_tick();
    TickSample& s = out.emplace_back();
    s.t_s = 1e-9 * static_cast<double>(r.time_ns - t0) - sp.hold_s;
    s.F = r.F_cmd_W.force;
    s.tau = r.F_cmd_W.torque;
    s.X_WH = r.X_WH;
    s.X_WP = r.proxy.X_WP;
    s.handle_speed = r.state.v_DH_D.norm();
    s.active_rows = r.ir.active_rows;
    s.have_ir = r.ir.have_ir;
    s.stale = r.ir.stale;
    s.outside = r.ir.outside_validity;
    s.source = r.ir.source;
  }
  session.Stop();
  const device::ServoStats& st = loop.stats();
  const client::SessionStats ss = session.stats();
  run->passivity_min_j = st.passivity_min_j;
  run->energy_into_hand_j = st.energy_into_hand_j;
  run->rtt_p50_ms = 1e-3 * ss.rtt_p50_us;
  run->updates = ss.updates;
  run->late_ticks = st.late_ticks;
  const double span_s = ticks / 1000.0;
  run->patch_bytes_per_s = static_cast<double>(ss.local.patch_bytes) / span_s;
  run->local_rate_hz = ss.local.rate_hz;
  run->local_p99_us = ss.local.compute_p99_us;
  // The probe mesh frame A rides on P: keep X_WA in the samples.
  for (TickSample& s : out) {
    s.X_WH = s.X_WH * X_PA;
    s.X_WP = s.X_WP * X_PA;
  }
  return out;
}

/// PDt depth of the probe at X_WA against the bodies (0 when free).
class DepthProbe {
 public:
  explicit DepthProbe(const Scenario& sc) : sc_(sc) {}
  double Depth(const Pose& X_WA) {
    pd::ComputeScenePdt(*sc_.probe, X_WA, sc_.bodies, req_, &data_, &res_);
    if (!res_.colliding) return 0;
    double d = 0;
    for (std::size_t i = 0; i < res_.bodies.size(); ++i) {
      if (res_.tested[i]) d = std::max(d, res_.bodies[i].depth);
    }
    return d;
  }
  /// Whether the probe at X_WA is farther than `margin` from every body.
  bool Clear(const Pose& X_WA, double margin) {
    for (const pd::SceneBody& b : sc_.bodies) {
      pd::DistanceResult r;
      if (pd::Distance(*sc_.probe, X_WA, *b.model, b.X_WB, &r, &scratch_, margin) <= margin) {
        return false;
      }
    }
    return true;
  }

 private:
  const Scenario& sc_;
  pd::PenetrationRequest req_;
  pd::ScenePdData data_;
  pd::ScenePdResult res_;
  pd::QueryScratch scratch_;
};

void Measure(const Scenario& sc, const std::vector<TickSample>& ticks, DelayRun* run) {
  DepthProbe handle(sc), proxy(sc);
  double sx = 0, sy = 0, sxx = 0, sxy = 0, force_sum = 0;
  int n = 0, rows = 0, patch = 0, faded = 0, none = 0;
  Vec3 last_v = Vec3::Zero(), last_F = Vec3::Zero();
  Vec3 last_p = ticks.empty() ? Vec3::Zero() : ticks[0].X_WH.t;
  double last_t = 0;
  int since_late = kLateSettle;
  for (std::size_t i = 0; i < ticks.size(); ++i) {
    const TickSample& s = ticks[i];
    const double F = s.F.norm();
    run->peak_force = std::max(run->peak_force, F);
    run->peak_torque = std::max(run->peak_torque, s.tau.norm());
    // The hand's work into the contact (the passivity tolerance's scale, as
    // in the delay tests).
    const double dt = s.t_s - last_t;
    if (i > 0 && dt > kLateGap) since_late = 0;
    const bool after_late = since_late++ < kLateSettle;
    const Vec3 v = dt > 0 ? Vec3((s.X_WH.t - last_p) / dt) : Vec3::Zero();
    if (i > 0) run->hand_work_in_j += std::max(0.0, -last_F.dot(0.5 * (v + last_v)) * dt);
    last_v = v;
    last_F = s.F;
    last_p = s.X_WH.t;
    last_t = s.t_s;
    const double dh = handle.Depth(s.X_WH);
    const double dp = proxy.Depth(s.X_WP);
    run->handle_max_depth = std::max(run->handle_max_depth, dh);
    run->proxy_max_depth = std::max(run->proxy_max_depth, dp);
    if (dh > 0) {
      ++n;
      sx += dh;
      sy += F;
      sxx += dh * dh;
      sxy += dh * F;
      force_sum += F;
      if (s.stale || s.outside) {
        ++faded;
      } else if (s.active_rows > 0 && s.source == 1) {
        ++patch;
      } else if (s.active_rows > 0) {
        ++rows;
      } else {
        ++none;
      }
    } else if (dp == 0 && s.active_rows == 0 && s.handle_speed <= kFreeMaxSpeed &&
               proxy.Clear(s.X_WP, kFreeMargin)) {
      if (after_late) {
        ++run->free_ticks_after_late;
      } else {
        ++run->free_ticks;
        if (F > run->free_drag) {
          run->free_drag = F;
          run->free_drag_t_s = s.t_s;
        }
      }
    }
    if (i % 2 == 0 && s.t_s >= 0) {
      run->t.push_back(static_cast<float>(s.t_s));
      run->force.push_back(static_cast<float>(F));
      run->torque.push_back(static_cast<float>(s.tau.norm()));
    }
  }
  run->ticks = static_cast<int>(ticks.size());
  run->contact_ticks = n;
  run->mean_force = n > 0 ? force_sum / n : 0;
  if (n > 0) {
    run->from_rows = static_cast<double>(rows) / n;
    run->from_patch = static_cast<double>(patch) / n;
    run->faded = static_cast<double>(faded) / n;
    run->no_rows = static_cast<double>(none) / n;
  }
  const double den = n * sxx - sx * sx;
  // A twist presses the stick's ends sideways into the walls: a force
  // against the depth there says little; its figure is the torque.
  if (n >= kMinFitTicks && den > 0 && !sc.torque_plot) {
    run->stiffness = (n * sxy - sx * sy) / den;
    const double intercept = (sy - run->stiffness * sx) / n;
    run->felt_surface = run->stiffness != 0 ? -intercept / run->stiffness : kNaN;
  } else {
    run->stiffness = run->felt_surface = kNaN;
  }
}

std::string Fmt(const char* f, double a) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), f, a);
  return buf;
}

double Ratio(double a, double b) {
  return b != 0 && std::isfinite(a) && std::isfinite(b) ? a / b : kNaN;
}

/// The passivity tolerance of the delay tests: 2 % of the hand's work into
/// the contact plus 0.1 mJ.
double PassivityEps(const DelayRun& r) { return 0.02 * r.hand_work_in_j + 1e-4; }
bool Passive(const DelayRun& r) { return r.passivity_min_j > -PassivityEps(r); }

void JudgeGoals(DelayReport* report) {
  auto find = [&](const std::string& script, double delay) -> const DelayRun* {
    for (const DelayRun& r : report->runs) {
      if (r.script == script && r.delay_ms == delay) return &r;
    }
    return nullptr;
  };
  auto& goals = report->goals;
  for (const char* script : {"press", "slide"}) {
    const DelayRun* base = find(script, 0);
    for (double d : {50.0, 100.0}) {
      const DelayRun* r = find(script, d);
      if (!base || !r) continue;
      const std::string at = std::string(script) + " at " + Fmt("%g", d) + " ms: ";
      const double pf = Ratio(r->peak_force, base->peak_force);
      goals.push_back({at + "peak force within 10% of 0 ms", std::abs(pf - 1) <= 0.10,
                       Fmt("%.2f N", r->peak_force) + " vs " + Fmt("%.2f N", base->peak_force) +
                           " (x" + Fmt("%.2f", pf) + ")"});
      const double k = Ratio(r->stiffness, base->stiffness);
      goals.push_back({at + "felt stiffness within 15% of 0 ms", std::abs(k - 1) <= 0.15,
                       Fmt("%.0f N/m", r->stiffness) + " vs " + Fmt("%.0f N/m", base->stiffness) +
                           " (x" + Fmt("%.2f", k) + ")"});
      const double dd = r->proxy_max_depth - base->proxy_max_depth;
      goals.push_back({at + "proxy's deepest penetration within 0.5 mm of 0 ms",
                       std::abs(dd) <= 0.5e-3,
                       Fmt("%.2f mm", 1e3 * r->proxy_max_depth) + " vs " +
                           Fmt("%.2f mm", 1e3 * base->proxy_max_depth) + " (" +
                           Fmt("%+.2f mm", 1e3 * dd) + ")"});
    }
    const DelayRun* r200 = find(script, 200);
    if (base && r200) {
      const double pf = Ratio(r200->peak_force, base->peak_force);
      goals.push_back({std::string(script) + " at 200 ms: at least 70% of the 0 ms peak force",
                       pf >= 0.7,
                       Fmt("%.2f N", r200->peak_force) + " vs " + Fmt("%.2f N", base->peak_force) +
                           " (x" + Fmt("%.2f", pf) + ")"});
    }
  }
  if (const DelayRun* base = find("twist", 0)) {
    for (double d : {50.0, 100.0}) {
      const DelayRun* r = find("twist", d);
      if (!r) continue;
      const double pt = Ratio(r->peak_torque, base->peak_torque);
      goals.push_back({"twist at " + Fmt("%g", d) + " ms: peak torque within 15% of 0 ms",
                       std::abs(pt - 1) <= 0.15,
                       Fmt("%.4f N m", r->peak_torque) + " vs " +
                           Fmt("%.4f N m", base->peak_torque) + " (x" + Fmt("%.2f", pt) + ")"});
    }
  }
  // Passive everywhere; free space free everywhere.
  bool passive = true, free_ok = true;
  std::string worst_p, worst_f;
  double worst_margin = 1e9, worst_drag = 0;
  for (const DelayRun& r : report->runs) {
    passive = passive && Passive(r);
    if (r.passivity_min_j + PassivityEps(r) < worst_margin) {
      worst_margin = r.passivity_min_j + PassivityEps(r);
      worst_p = r.script + " " + Fmt("%g", r.delay_ms) + " ms: observer min " +
                Fmt("%.2f mJ", 1e3 * r.passivity_min_j) + " (tolerance " +
                Fmt("%.2f mJ", 1e3 * PassivityEps(r)) + ")";
    }
    free_ok = free_ok && r.free_drag <= 0.05;
    if (r.free_drag >= worst_drag) {
      worst_drag = r.free_drag;
      worst_f = "worst " + r.script + " " + Fmt("%g", r.delay_ms) +
                " ms: " + Fmt("%.4f N", r.free_drag) + " at " + Fmt("%.3f s", r.free_drag_t_s) +
                " over " + std::to_string(r.free_ticks) + " free ticks (" +
                std::to_string(r.free_ticks_after_late) + " more left out after late ticks)";
    }
  }
  if (!report->runs.empty()) {
    goals.push_back({"passive everywhere (observer >= -tolerance)", passive, "closest " + worst_p});
    goals.push_back({"free space <= 0.05 N", free_ok, worst_f});
  }
  // The delay's own share: no run's observer below its script's 0 ms run
  // by more than the tolerance (what the loop shows without any delay is
  // the coupling's, not the link's).
  bool no_worse = true;
  std::string worst_d;
  double worst_dm = 1e9;
  for (const DelayRun& r : report->runs) {
    const DelayRun* base = find(r.script, 0);
    if (!base || r.delay_ms == 0) continue;
    const double margin = r.passivity_min_j - base->passivity_min_j + PassivityEps(r);
    no_worse = no_worse && margin > 0;
    if (margin < worst_dm) {
      worst_dm = margin;
      worst_d = r.script + " " + Fmt("%g", r.delay_ms) + " ms: observer min " +
                Fmt("%.2f mJ", 1e3 * r.passivity_min_j) + " vs " +
                Fmt("%.2f mJ", 1e3 * base->passivity_min_j) + " at 0 ms (tolerance " +
                Fmt("%.2f mJ", 1e3 * PassivityEps(r)) + ")";
    }
  }
  if (!worst_d.empty()) {
    goals.push_back({"delay adds no energy (observer >= the 0 ms run's - tolerance)", no_worse,
                     "closest " + worst_d});
  }
}

}  // namespace

DelayReport RunDelayBench(const DelayBenchOptions& o, std::ostream* log) {
  DelayReport report;
  std::vector<Scenario> scenarios;
  for (const std::string& name : o.scripts) {
    if (name == "press") {
      scenarios.push_back(PressScenario());
    } else if (name == "slide") {
      scenarios.push_back(SlideScenario(o.models, &report.slide_body, &report.notes));
    } else if (name == "twist") {
      scenarios.push_back(TwistScenario());
    } else {
      throw std::invalid_argument("unknown script '" + name + "' (press, slide, twist)");
    }
  }
  // The server loads the scenes from files, as `serve --scene` does.
  const std::filesystem::path dir = std::filesystem::temp_directory_path() /
                                    ("hapticpd-bench-delay-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  server::ServerOptions so = server::ServerOptions::InProcess();
  for (const Scenario& sc : scenarios) {
    const std::filesystem::path f = dir / (sc.name + ".json");
    std::ofstream(f) << sc.scene_json << "\n";
    so.scene_files.push_back(f.string());
  }
  report.notes.push_back(
      "probe: the stick (pd::shapes::Stick, radius 5 mm, 150 mm long), vertical for press and "
      "slide, lying along x for twist; material 1000 N/m; PDt; the simulated hand (300 N/m)");
  report.notes.push_back(
      "press: box:0.1,0.1,0.05, hand 3 mm above to 15 mm into the top and back (press script)");
  report.notes.push_back(
      "slide: hand on a vertical circle from 3 mm above the surface to 15 mm into it and back "
      "(circle script: closed)");
  report.notes.push_back(
      "twist: two box:0.1,0.02,0.02 walls, 1.5 mm clearance each side of the "
      "stick; down 10 mm, twist 0.15 rad about the vertical and back");
  report.notes.push_back(o.local_model
                             ? "device sessions with the local contact model (geometry patches)"
                             : "device sessions without the local contact model (server answers "
                               "only)");
  const auto level = spdlog::get_level();
  spdlog::set_level(spdlog::level::warn);  // the in-process server's info lines
  struct Restore {
    spdlog::level::level_enum level;
    std::filesystem::path dir;
    ~Restore() {
      spdlog::set_level(level);
      std::error_code ec;
      std::filesystem::remove_all(dir, ec);
    }
  } restore{level, dir};
  server::HapticServer server(so);
  server.Start();
  for (const Scenario& sc : scenarios) {
    for (const double delay : o.delays_ms) {
      DelayRun run;
      run.script = sc.name;
      run.delay_ms = delay;
      run.jitter_ms = o.jitter_fraction * delay;
      if (log) {
        *log << "  " << sc.name << " at " << delay << " ms +-" << run.jitter_ms << " ms ..."
             << std::endl;
      }
      const std::vector<TickSample> ticks = RunOnce(sc, server.port(), delay, run.jitter_ms,
                                                    o.time_scale, o.seed, o.local_model, &run);
      Measure(sc, ticks, &run);
      report.runs.push_back(std::move(run));
    }
  }
  server.Shutdown();
  // Surface error against the 0 ms run of the same script.
  for (DelayRun& r : report.runs) {
    r.surface_error = kNaN;
    for (const DelayRun& b : report.runs) {
      if (b.script == r.script && b.delay_ms == 0)
        r.surface_error = r.felt_surface - b.felt_surface;
    }
  }
  JudgeGoals(&report);
  return report;
}

namespace {
nlohmann::json Num(double x) { return std::isfinite(x) ? nlohmann::json(x) : nlohmann::json(); }
}  // namespace

nlohmann::json ToJson(const DelayReport& report) {
  nlohmann::json j;
  j["slide_body"] = report.slide_body;
  j["notes"] = report.notes;
  j["runs"] = nlohmann::json::array();
  for (const DelayRun& r : report.runs) {
    j["runs"].push_back({{"script", r.script},
                         {"delay_ms", r.delay_ms},
                         {"jitter_ms", r.jitter_ms},
                         {"ticks", r.ticks},
                         {"contact_ticks", r.contact_ticks},
                         {"peak_force_n", r.peak_force},
                         {"mean_force_n", r.mean_force},
                         {"peak_torque_nm", r.peak_torque},
                         {"stiffness_n_per_m", Num(r.stiffness)},
                         {"felt_surface_m", Num(r.felt_surface)},
                         {"surface_error_m", Num(r.surface_error)},
                         {"handle_max_depth_m", r.handle_max_depth},
                         {"proxy_max_depth_m", r.proxy_max_depth},
                         {"passivity_min_j", r.passivity_min_j},
                         {"passivity_tolerance_j", PassivityEps(r)},
                         {"energy_into_hand_j", r.energy_into_hand_j},
                         {"free_drag_n", r.free_drag},
                         {"free_ticks", r.free_ticks},
                         {"free_drag_t_s", r.free_drag_t_s},
                         {"free_ticks_after_late", r.free_ticks_after_late},
                         {"patch_bytes_per_s", r.patch_bytes_per_s},
                         {"local_rate_hz", r.local_rate_hz},
                         {"local_p99_us", r.local_p99_us},
                         {"answered",
                          {{"server_rows", r.from_rows},
                           {"local_patch", r.from_patch},
                           {"faded", r.faded},
                           {"no_rows", r.no_rows}}},
                         {"rtt_p50_ms", r.rtt_p50_ms},
                         {"updates", r.updates},
                         {"late_ticks", r.late_ticks}});
  }
  j["goals"] = nlohmann::json::array();
  for (const DelayGoal& g : report.goals) {
    j["goals"].push_back({{"goal", g.name}, {"met", g.met}, {"figures", g.figures}});
  }
  return j;
}

void PrintDelay(std::ostream& os, const DelayReport& report) {
  for (const std::string& n : report.notes) os << n << "\n";
  char line[512];
  std::string script;
  for (const DelayRun& r : report.runs) {
    if (r.script != script) {
      script = r.script;
      os << "\n" << script << "\n";
      std::snprintf(line, sizeof(line),
                    "%8s %7s %7s %8s %7s %8s %7s %7s %8s %8s %7s %6s %5s %5s %5s %5s %7s\n",
                    "delay ms", "peak N", "mean N", "torque", "k N/m", "surf mm", "hand mm",
                    "proxy mm", "obs mJ", "E in mJ", "free N", "patch", "rows", "patch", "faded",
                    "none", "rtt ms");
      os << line;
    }
    std::snprintf(
        line, sizeof(line),
        "%8g %7.2f %7.2f %8.4f %7s %8s %7.2f %7.2f %8.2f %8.2f %7.4f %6s %4.0f%% %4.0f%% %4.0f%% "
        "%4.0f%% %7.1f\n",
        r.delay_ms, r.peak_force, r.mean_force, r.peak_torque,
        std::isfinite(r.stiffness) ? Fmt("%.0f", r.stiffness).c_str() : "n/a",
        std::isfinite(r.surface_error) ? Fmt("%+.2f", 1e3 * r.surface_error).c_str() : "n/a",
        1e3 * r.handle_max_depth, 1e3 * r.proxy_max_depth, 1e3 * r.passivity_min_j,
        1e3 * r.energy_into_hand_j, r.free_drag, Fmt("%.0fk", 1e-3 * r.patch_bytes_per_s).c_str(),
        100 * r.from_rows, 100 * r.from_patch, 100 * r.faded, 100 * r.no_rows, r.rtt_p50_ms);
    os << line;
  }
  os << "\n(jitter +-20% of the delay; peak/mean |F| commanded, mean over the ticks with the "
        "handle's probe inside the true surface; torque = peak |tau| N m; k = felt stiffness, "
        "slope of |F| against the handle's penetration; surf = felt surface against the 0 ms "
        "run, mm, + deeper; hand/proxy = deepest penetration of the handle's / the proxy's "
        "probe below the true surface; obs = passivity observer minimum; E in = energy into "
        "the hand; free = max |F| with no row and the proxy > 1 mm from every body; patch = "
        "patch kB/s; rows/patch/faded/none = which model answered on the "
        "contact ticks; rtt = round trip p50)\n";
  if (!report.goals.empty()) {
    os << "\ngoals (against the 0 ms run of this invocation):\n";
    for (const DelayGoal& g : report.goals) {
      os << "  [" << (g.met ? "met" : "NOT met") << "] " << g.name << ": " << g.figures << "\n";
    }
  }
}

void WriteDelaySvg(const std::filesystem::path& path, const DelayReport& report,
                   const std::string& title) {
  static const char* kColors[] = {"#000000", "#1f5fbf", "#2ca02c", "#ff7f0e",
                                  "#c0392b", "#8e44ad", "#7f7f7f", "#17becf"};
  svg::Figure fig;
  fig.title = title;
  std::string script;
  int k = 0;
  for (const DelayRun& r : report.runs) {
    if (r.script != script) {
      script = r.script;
      k = 0;
      svg::Panel& p = fig.panels.emplace_back();
      const bool torque = script == "twist";
      p.title = script + (torque ? ": commanded torque |tau| (N cm) vs time (s)"
                                 : ": commanded force |F| (N) vs time (s)");
      p.x_label = "s";
      p.y_label = torque ? "N cm" : "N";
    }
    svg::Panel& p = fig.panels.back();
    const bool torque = script == "twist";
    svg::Series& s = p.series.emplace_back();
    s.label = Fmt("%g ms", r.delay_ms);
    s.color = kColors[k++ % 8];
    s.x.assign(r.t.begin(), r.t.end());
    const std::vector<float>& y = torque ? r.torque : r.force;
    s.y.reserve(y.size());
    for (float v : y) s.y.push_back(torque ? 100.0 * v : v);
  }
  svg::Write(path, fig);
}

}  // namespace hapticpd::bench
