// Couple fuzz: whatever numbers a client sends within (and just beyond) the
// wire's ranges, what the server answers is fit to reach a motor, and a servo
// loop rendering those answers commands a finite wrench within its device's
// limits.
//
// Runs with client_tests in the `test` preset and, labelled `services`,
// under `test-asan` and `test-tsan` (there 12 runs of 2 x 6 poses per session
// instead of 24 runs of 4 x 16). The server is reached over gRPC's
// in-process channel in lock step (one pose, then its answer), so every
// pose is answered and a seed reproduces the inputs: HAPTICPD_TEST_SEED picks
// it, HAPTICPD_TEST_COUNT or --long (20x) the number of runs. A failure names
// the seed, run, session and pose.
//
// EveryUpdateFitForAMotor, per run: a server (every other run with small
// update limits, 50 N and 0.5 N m, so that answers over them are withheld);
// a scene made through CreateScene (random declared effects, PD mode,
// gravity, texture, probe mass and inertia) and AddBody (catalogue shapes
// whose sizes span kShapeLength end to end, positions out to kCoordinate's
// ends, any rotation, materials from 0 to each range's maximum); then device
// sessions with random hellos (probe shapes of extreme sizes or a scene body,
// probe materials at the range ends, PDt, PDg or the scene's mode) that
// stream poses deep and shallow in a body, far away, at the coordinate
// extremes, at denormal distances from the origin, at any rotation. A few
// values are deliberately out of range: the request must be rejected with
// INVALID_ARGUMENT naming the field. Every ContactUpdate must hold only
// finite numbers, a force and torque within the server's limits and a known
// status, and the small-limit runs must have withheld some. Every update also
// goes, as client::Session passes it (IrFromContactUpdate), to a servo loop
// on a simulated device placed at the poses being sent (half of them are its
// own proxy's, closing the loop), and every tick must command a finite wrench
// within the device's limits.
//
// ClientBoundaryKeepsBadNumbersFromTheMotor: an update holding a non-finite
// number in any one of its fields (as a broken or older server might send)
// is either refused by IrFromContactUpdate or rendered as a finite wrench
// within the device's limits. Its disabled sibling shows the gap left for
// finite numbers whose squares overflow.
#include <google/protobuf/descriptor.h>
#include <google/protobuf/message.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "client/session.h"
#include "device/servo_loop.h"
#include "device/simulated_device.h"
#include "proto/wire/convert.h"
#include "proto/wire/ranges.h"
#include "tests/server/server_harness.h"
#include "tests/test_util.h"

namespace hapticpd {
// Named (not anonymous): the sanitizer presets build the tests as one unity
// translation unit, where anonymous-namespace helpers of different files meet.
namespace couple_fuzz {

using testing::kSanitized;

using device::Pose;
using device::Quat;
using device::Vec3;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

// ---- random draws -----------------------------------------------------------

class Rand {
 public:
  explicit Rand(std::uint64_t seed) : g_(seed) {}
  double U(double a = 0, double b = 1) { return std::uniform_real_distribution<double>(a, b)(g_); }
  int I(int a, int b) { return std::uniform_int_distribution<int>(a, b)(g_); }
  bool P(double p) { return U() < p; }
  double LogU(double lo, double hi) { return std::exp(U(std::log(lo), std::log(hi))); }
  double Sign() { return P(0.5) ? 1.0 : -1.0; }
  template <class T>
  const T& Pick(const std::vector<T>& v) {
    return v[static_cast<std::size_t>(I(0, static_cast<int>(v.size()) - 1))];
  }

  /// A length in kShapeLength: either end of it (15 % each) or log-uniform
  /// between them.
  double Length() {
    const double u = U();
    if (u < 0.15) return wire::kShapeLength.lo;
    if (u < 0.30) return wire::kShapeLength.hi;
    return LogU(wire::kShapeLength.lo, wire::kShapeLength.hi);
  }
  /// A value of a range starting at 0: 0 or the maximum (20 % each), or
  /// log-uniform over the twelve decades below the maximum.
  double Value(const wire::Range& r) {
    const double u = U();
    if (u < 0.2) return r.lo;
    if (u < 0.4) return r.hi;
    return LogU(r.hi * 1e-12, r.hi);
  }
  /// A component of a symmetric range: either end, 0, or a random sign and
  /// magnitude over twelve decades.
  double Symmetric(const wire::Range& r) {
    const double u = U();
    if (u < 0.15) return r.hi;
    if (u < 0.30) return r.lo;
    if (u < 0.40) return 0;
    return Sign() * LogU(r.hi * 1e-12, r.hi);
  }
  Quat Rotation() {
    std::normal_distribution<double> n;
    Quat q(n(g_), n(g_), n(g_), n(g_));
    return q.norm() > 1e-6 ? q.normalized() : Quat::Identity();
  }
  /// Any rotation: uniform, identity, within a hair of identity or of a
  /// half turn.
  Quat AnyRotation() {
    const double u = U();
    if (u < 0.5) return Rotation();
    if (u < 0.65) return Quat::Identity();
    const Vec3 axis = Rotation().vec().normalized();
    const double angle = u < 0.8 ? LogU(1e-12, 1e-2) : M_PI - LogU(1e-12, 1e-2);
    return Quat(Eigen::AngleAxisd(angle, axis));
  }

 private:
  std::mt19937_64 g_;
};

std::string Num(double v) {
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, r.ptr);
}

double Clamp(double x, const wire::Range& r) { return std::min(r.hi, std::max(r.lo, x)); }

// ---- requests ---------------------------------------------------------------

/// A status that rejects a request: INVALID_ARGUMENT with a message that
/// starts with the field's path ("header.spec.pose.position.x: ...").
/// Empty when it does; else what is wrong.
std::string RejectionProblem(const grpc::Status& s, const std::string& expected_prefix = "") {
  if (s.error_code() != grpc::StatusCode::INVALID_ARGUMENT) {
    return "status " + std::to_string(s.error_code()) +
           " (not INVALID_ARGUMENT): " + s.error_message();
  }
  const std::string& m = s.error_message();
  const std::size_t colon = m.find(": ");
  bool path = colon != std::string::npos && colon > 0;
  for (std::size_t i = 0; path && i < colon; ++i) {
    const char c = m[i];
    path =
        std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '.' || c == '[' || c == ']';
  }
  if (!path) return "the message names no field: " + m;
  if (m.compare(0, expected_prefix.size(), expected_prefix) != 0) {
    return "the message should name " + expected_prefix + ": " + m;
  }
  return {};
}

/// A catalogue shape with random sizes across kShapeLength (correlated
/// around one scale, or independent: aspect ratios up to 1e10) and small
/// resolutions. `bad_length`: one length deliberately out of range.
std::string RandomShape(Rand& rnd, bool bad_length = false) {
  const double scale = rnd.Length();
  auto length = [&] {
    return rnd.P(0.6) ? std::min(wire::kShapeLength.hi, scale * rnd.LogU(1, 30)) : rnd.Length();
  };
  static const std::vector<std::string> kNames = {"box",   "sphere",    "capsule", "cylinder",
                                                  "torus", "torusknot", "plate",   "stick",
                                                  "spoon", "cup",       "hammer"};
  // Shapes with lengths when one must be out of range.
  const std::string name =
      bad_length ? rnd.Pick(std::vector<std::string>{"box", "sphere", "plate"}) : rnd.Pick(kNames);
  std::vector<double> lengths;
  std::vector<int> counts;
  const bool res = rnd.P(0.7);
  if (name == "box" || name == "plate") {
    lengths = {length(), length(), length()};
    if (res) counts = {rnd.I(1, name == "box" ? 3 : 2)};
  } else if (name == "sphere") {
    lengths = {length()};
    if (res) counts = {rnd.I(0, 2)};
  } else if (name == "capsule") {
    lengths = {length(), rnd.P(0.2) ? 0.0 : length()};
    if (res) counts = {rnd.I(3, 12), rnd.I(1, 3)};
  } else if (name == "cylinder") {
    lengths = {length(), length()};
    if (res) counts = {rnd.I(3, 16)};
  } else if (name == "torus") {
    const double major = length();
    lengths = {major, rnd.P(0.8) ? std::max(wire::kShapeLength.lo, major * rnd.LogU(1e-3, 0.9))
                                 : length()};
    if (res) counts = {rnd.I(3, 16), rnd.I(3, 8)};
  } else if (name == "torusknot") {
    const auto pq = rnd.Pick(std::vector<std::pair<int, int>>{{2, 3}, {3, 2}, {2, 5}, {1, 1}});
    const double radius = length();
    lengths = {radius, std::max(wire::kShapeLength.lo, radius * rnd.LogU(1e-3, 0.5))};
    std::string spec = name + ":" + std::to_string(pq.first) + "," + std::to_string(pq.second);
    for (double l : lengths) spec += "," + Num(l);
    if (res) spec += "," + std::to_string(rnd.I(3, 48)) + "," + std::to_string(rnd.I(3, 6));
    return spec;
  } else if (name != "stick") {  // spoon, cup, hammer: a resolution only
    if (rnd.P(0.8)) counts = {rnd.I(1, 2)};
  }
  if (bad_length) {
    lengths[static_cast<std::size_t>(rnd.I(0, static_cast<int>(lengths.size()) - 1))] =
        rnd.Pick(std::vector<double>{2e4, 5e-7, 0.0, -1e-3, 1e300});
  }
  if (lengths.empty() && counts.empty()) return name;
  std::string spec = name + ":";
  for (double l : lengths) spec += Num(l) + ",";
  for (int c : counts) spec += std::to_string(c) + ",";
  spec.pop_back();
  return spec;
}

/// A material across its ranges; `bad` puts one field out of range.
v1::Material RandomMaterial(Rand& rnd, bool bad = false) {
  v1::Material m;
  m.set_stiffness(rnd.Value(wire::kStiffness));
  m.set_rotational_stiffness(rnd.Value(wire::kRotationalStiffness));
  m.set_damping(rnd.Value(wire::kDamping));
  const double mu_s = rnd.Value(wire::kFriction);
  m.set_static_friction(mu_s);
  m.set_dynamic_friction(rnd.P(0.3) ? mu_s : rnd.P(0.3) ? 0.0 : mu_s * rnd.U());
  if (bad) {
    switch (rnd.I(0, 4)) {
      case 0:
        m.set_stiffness(wire::kStiffness.hi * 1.0001);
        break;
      case 1:
        m.set_stiffness(-1);
        break;
      case 2:
        m.set_damping(kNaN);
        break;
      case 3:
        m.set_rotational_stiffness(kInf);
        break;
      default:
        m.set_static_friction(1);
        m.set_dynamic_friction(1.5);  // dynamic above static
        break;
    }
  }
  return m;
}

/// Writes X to the wire with every position component clamped into
/// kCoordinate and, sometimes, the quaternion off unit by less than the
/// server's tolerance (it normalises those).
void ToWire(const Pose& X, Rand& rnd, v1::Pose* out) {
  out->mutable_position()->set_x(Clamp(X.t.x(), wire::kCoordinate));
  out->mutable_position()->set_y(Clamp(X.t.y(), wire::kCoordinate));
  out->mutable_position()->set_z(Clamp(X.t.z(), wire::kCoordinate));
  Quat q = X.Rotation();
  if (rnd.P(0.1)) q.coeffs() *= 1 + rnd.U(-0.9, 0.9) * kUnitQuaternionTolerance;
  out->mutable_orientation()->set_w(q.w());
  out->mutable_orientation()->set_x(q.x());
  out->mutable_orientation()->set_y(q.y());
  out->mutable_orientation()->set_z(q.z());
}

Pose FromWire(const v1::Pose& p) {
  const auto& q = p.orientation();
  return Pose::FromQuaternion(Quat(q.w(), q.x(), q.y(), q.z()),
                              Vec3(p.position().x(), p.position().y(), p.position().z()));
}

Vec3 V(const v1::Vec3& v) { return Vec3(v.x(), v.y(), v.z()); }

/// A position anywhere in the world: each component at an end of
/// kCoordinate, 0, or any sign and magnitude over twelve decades.
Vec3 AnyPosition(Rand& rnd) {
  return Vec3(rnd.Symmetric(wire::kCoordinate), rnd.Symmetric(wire::kCoordinate),
              rnd.Symmetric(wire::kCoordinate));
}

/// A body of the scene, as the server described it.
struct Body {
  std::string id;
  Vec3 centre_W;                ///< its bounding box's centre
  double radius;                ///< its bounding radius
  std::vector<Vec3> surface_W;  ///< some of its vertices (GetScene), in the world
};

/// What the welcome says about the probe.
struct Probe {
  Vec3 centre_A;  ///< bounding-box centre in its mesh frame
  double radius;
  Pose X_PA;  ///< mesh frame in the proxy frame, as client::Session sets it
};

/// A probe pose X_WA: near a body (its centre within the sum of the two
/// bounding radii, deep or shallow), a little off `prev`, anywhere in the
/// world, at the coordinate extremes, or at denormal distances from the
/// origin.
Pose RandomPose(Rand& rnd, const std::vector<Body>& bodies, const Probe& probe, const Pose& prev) {
  const Quat q = rnd.AnyRotation();
  const double u = rnd.U();
  Vec3 centre_W;
  if (u < 0.6 && !bodies.empty()) {
    const Body& b = rnd.Pick(bodies);
    const Vec3 dir = rnd.Rotation().vec().normalized();
    if (rnd.P(0.7) && !b.surface_W.empty()) {
      // Around a vertex of the body: anything from the probe's centre on
      // the surface to the probe just touching it (or not quite).
      centre_W = rnd.Pick(b.surface_W) + rnd.U(0, 1.1) * probe.radius * dir;
    } else {
      const double reach = b.radius + probe.radius;
      const double v = rnd.U();
      const double t = v < 0.3 ? rnd.U(0, 0.3) : v < 0.7 ? rnd.U(0.7, 1.02) : rnd.U(0, 1.3);
      centre_W = b.centre_W + t * reach * dir;
    }
  } else if (u < 0.72) {
    const double step = rnd.LogU(1e-9, 2 * probe.radius + 1e-9);
    return Pose::FromQuaternion(q, prev.t + step * rnd.Rotation().vec().normalized());
  } else if (u < 0.85) {
    return Pose::FromQuaternion(q, AnyPosition(rnd));
  } else if (u < 0.95) {
    const double e = wire::kCoordinate.hi;
    return Pose::FromQuaternion(q, Vec3(rnd.Sign() * e, rnd.Sign() * e, rnd.Sign() * e));
  } else {
    const std::vector<double> tiny = {0.0, 5e-324, -5e-324, 1e-300, -1e-310};
    return Pose::FromQuaternion(q, Vec3(rnd.Pick(tiny), rnd.Pick(tiny), rnd.Pick(tiny)));
  }
  const Pose R = Pose::FromQuaternion(q, Vec3::Zero());
  return Pose::FromQuaternion(q, centre_W - R.Rotate(probe.centre_A));
}

// ---- checks -----------------------------------------------------------------

/// Calls f(path, value) for every double or float field set in m,
/// recursively ("rows[1].normal.z").
void ForEachNumber(const google::protobuf::Message& m, const std::string& path,
                   const std::function<void(const std::string&, double)>& f) {
  using google::protobuf::FieldDescriptor;
  const auto* d = m.GetDescriptor();
  const auto* r = m.GetReflection();
  for (int i = 0; i < d->field_count(); ++i) {
    const FieldDescriptor* fd = d->field(i);
    const std::string name = path.empty() ? fd->name() : path + "." + fd->name();
    if (fd->is_repeated()) {
      for (int k = 0; k < r->FieldSize(m, fd); ++k) {
        const std::string nk = name + "[" + std::to_string(k) + "]";
        if (fd->cpp_type() == FieldDescriptor::CPPTYPE_DOUBLE)
          f(nk, r->GetRepeatedDouble(m, fd, k));
        if (fd->cpp_type() == FieldDescriptor::CPPTYPE_FLOAT) f(nk, r->GetRepeatedFloat(m, fd, k));
        if (fd->cpp_type() == FieldDescriptor::CPPTYPE_MESSAGE) {
          ForEachNumber(r->GetRepeatedMessage(m, fd, k), nk, f);
        }
      }
    } else if (fd->cpp_type() == FieldDescriptor::CPPTYPE_DOUBLE) {
      f(name, r->GetDouble(m, fd));
    } else if (fd->cpp_type() == FieldDescriptor::CPPTYPE_FLOAT) {
      f(name, r->GetFloat(m, fd));
    } else if (fd->cpp_type() == FieldDescriptor::CPPTYPE_MESSAGE && r->HasField(m, fd)) {
      ForEachNumber(r->GetMessage(m, fd), name, f);
    }
  }
}

/// Sets the n-th double field ForEachNumber visits (message fields present
/// in m only) to v; false when m has fewer.
bool SetNthNumber(google::protobuf::Message* m, int* n, double v) {
  using google::protobuf::FieldDescriptor;
  const auto* d = m->GetDescriptor();
  const auto* r = m->GetReflection();
  for (int i = 0; i < d->field_count(); ++i) {
    const FieldDescriptor* fd = d->field(i);
    if (fd->is_repeated()) {
      for (int k = 0; k < r->FieldSize(*m, fd); ++k) {
        if (fd->cpp_type() == FieldDescriptor::CPPTYPE_DOUBLE && (*n)-- == 0) {
          r->SetRepeatedDouble(m, fd, k, v);
          return true;
        }
        if (fd->cpp_type() == FieldDescriptor::CPPTYPE_MESSAGE &&
            SetNthNumber(r->MutableRepeatedMessage(m, fd, k), n, v)) {
          return true;
        }
      }
    } else if (fd->cpp_type() == FieldDescriptor::CPPTYPE_DOUBLE) {
      if ((*n)-- == 0) {
        r->SetDouble(m, fd, v);
        return true;
      }
    } else if (fd->cpp_type() == FieldDescriptor::CPPTYPE_MESSAGE && r->HasField(*m, fd)) {
      if (SetNthNumber(r->MutableMessage(m, fd), n, v)) return true;
    }
  }
  return false;
}

/// Why a ContactUpdate must not reach a motor, or empty: a non-finite
/// number anywhere, a force or torque over the server's limits, an unknown
/// status, a row or target outside the physical ranges, or a withheld
/// answer that still carries a force or rows.
std::string UpdateProblem(const v1::ContactUpdate& u, double max_force, double max_torque) {
  std::string bad;
  ForEachNumber(u, "", [&](const std::string& path, double x) {
    if (bad.empty() && !std::isfinite(x)) bad = path + " is " + Num(x);
  });
  if (!bad.empty()) return bad;
  if (V(u.force()).norm() > max_force) {
    return "|force| " + Num(V(u.force()).norm()) + " N over the limit " + Num(max_force);
  }
  if (V(u.torque()).norm() > max_torque) {
    return "|torque| " + Num(V(u.torque()).norm()) + " N m over the limit " + Num(max_torque);
  }
  if (!v1::ContactStatus_IsValid(u.status()) || u.status() == v1::CONTACT_STATUS_UNSPECIFIED) {
    return "status " + std::to_string(u.status());
  }
  for (int i = 0; i < u.rows_size(); ++i) {
    const v1::ContactRow& r = u.rows(i);
    const std::string row = "rows[" + std::to_string(i) + "]";
    if (r.depth() < 0) return row + ".depth " + Num(r.depth()) + " < 0";
    if (r.stiffness() < 0 || r.stiffness() > wire::kStiffness.hi) {
      return row + ".stiffness " + Num(r.stiffness()) + " outside " +
             wire::Describe(wire::kStiffness);
    }
    if (r.damping() < 0 || r.damping() > wire::kDamping.hi) {
      return row + ".damping " + Num(r.damping()) + " outside " + wire::Describe(wire::kDamping);
    }
    if (r.static_friction() < 0 || r.static_friction() > wire::kFriction.hi ||
        r.dynamic_friction() < 0 || r.dynamic_friction() > r.static_friction()) {
      return row + ": friction " + Num(r.static_friction()) + " / " + Num(r.dynamic_friction());
    }
  }
  if (u.target_stiffness() < 0 || u.target_stiffness() > wire::kStiffness.hi) {
    return "target_stiffness " + Num(u.target_stiffness());
  }
  if (u.status() == v1::CONTACT_STATUS_WITHHELD &&
      (u.rows_size() > 0 || V(u.force()).norm() > 0 || V(u.torque()).norm() > 0)) {
    return "a withheld answer with rows or a force";
  }
  return {};
}

// ---- the device side --------------------------------------------------------

/// A servo loop on a simulated device in simulated time, its device frame
/// placed so that the handle (held near the device origin by the hand)
/// puts the probe at X_WA.
struct Servo {
  device::ManualClock clock;
  std::unique_ptr<device::SimulatedDevice> dev;
  std::unique_ptr<device::ServoLoop> loop;
  std::int64_t ticks = 0;

  Servo(Rand& rnd, const Pose& X_WA, const Pose& X_PA, const v1::SceneConfig& scene) {
    device::ScriptParams script;
    script.script = rnd.Pick(std::vector<device::HandScript>{
        device::HandScript::kHold, device::HandScript::kPress, device::HandScript::kSlide,
        device::HandScript::kTwist, device::HandScript::kCircle});
    script.duration_s = 1;
    dev = std::make_unique<device::SimulatedDevice>(script, &clock);
    dev->Open();
    device::ServoConfig config;
    config.X_PA = X_PA;
    config.X_WD = X_WA * X_PA.Inverse();
    config.effects = client::EffectsFromSceneConfig(scene);
    config.effect_params = client::EffectParamsFromSceneConfig(scene);
    config.realtime_priority = 0;
    // Engage at once: the start-up ramp only scales the output, and the
    // point is what full gain commands.
    config.startup.quiet_ticks = 1;
    config.startup.ramp_time_s = 0.002;
    loop = std::make_unique<device::ServoLoop>(dev.get(), config, &clock);
  }

  /// The proxy's probe pose (what client::Session would send next).
  Pose X_WA() const { return loop->last_tick().proxy.X_WP * loop->config().X_PA; }

  /// One tick; empty when the command is finite and within the device's
  /// limits, else what is wrong.
  std::string Tick() {
    clock.Set(++ticks * 1'000'000);
    loop->Tick(clock.NowNs());
    const device::TickRecord& r = loop->last_tick();
    const device::DeviceInfo& info = dev->info();
    const auto where = [&] { return " at tick " + std::to_string(ticks); };
    if (!r.F_cmd_D.force.allFinite() || !r.F_cmd_D.torque.allFinite() ||
        !r.F_cmd_W.force.allFinite() || !r.F_cmd_W.torque.allFinite()) {
      return "a non-finite command (" + Num(r.F_cmd_D.force.x()) + ", ...)" + where();
    }
    if (r.F_cmd_D.force.norm() > info.max_force * (1 + 1e-9)) {
      return "|force| " + Num(r.F_cmd_D.force.norm()) + " N over the device's " +
             Num(info.max_force) + where();
    }
    if (r.F_cmd_D.torque.norm() > info.max_torque * (1 + 1e-9)) {
      return "|torque| " + Num(r.F_cmd_D.torque.norm()) + " N m over the device's " +
             Num(info.max_torque) + where();
    }
    if (!r.proxy.X_WP.t.allFinite() || !r.proxy.X_WP.R.allFinite()) {
      return "a non-finite proxy pose" + where();
    }
    return {};
  }
};

/// X_PA as client::Session derives it from the welcome: the mesh frame
/// seen from the probe's centre of mass, axes kept.
Pose XPaFromWelcome(const v1::Welcome& w) {
  return Pose::FromTranslation(-FromWire(w.probe_body_frame()).t);
}

// ---- the fuzz run -----------------------------------------------------------

struct Tally {
  int runs = 0, bodies = 0, sessions = 0, updates = 0, penetrating = 0, pdg = 0, withheld = 0;
  int rejected = 0, servo_ticks = 0, contact_ticks = 0, limit_ticks = 0;
  int by_status[8] = {};
  std::uint64_t server_withheld_small = 0;  ///< counts().updates_withheld, small-limit runs
  int failures = 0;
};

/// Records a failure (the first few in full; later ones only counted, so
/// that a broken guard does not print thousands of lines).
void Fail(Tally& t, const std::string& what) {
  if (t.failures++ < 8) ADD_FAILURE() << what;
}

class FuzzRun {
 public:
  FuzzRun(std::uint64_t seed, int run, Tally& tally) : rnd_(seed), t_(tally) {
    small_limits_ = run % 2 == 0;
    server::ServerOptions o;
    if (small_limits_) {
      o.limits.max_update_force = 50;
      o.limits.max_update_torque = 0.5;
    }
    max_force_ = o.limits.max_update_force;
    max_torque_ = o.limits.max_update_torque;
    harness_ = std::make_unique<testing::ServerHarness>(testing::Transport::kInProcess, o);
    scenes_ = harness_->Scenes();
    haptics_ = harness_->Haptics();
    where_ = "seed " + std::to_string(seed) + " run " + std::to_string(run);
  }

  void Go(int sessions, int clusters, int steps) {
    ++t_.runs;
    if (!CreateScene()) return;
    const int n = rnd_.I(1, 4);
    for (int i = 0; i < n; ++i) AddBody(i);
    SampleSurfaces();
    for (int s = 0; s < sessions; ++s) Couple(s, clusters, steps);
    if (small_limits_) t_.server_withheld_small += harness_->server().counts().updates_withheld;
  }

 private:
  void Rejected(const grpc::Status& s, const std::string& field, const std::string& what) {
    ++t_.rejected;
    if (std::string p = RejectionProblem(s, field); !p.empty()) {
      Fail(t_, where_ + ": " + what + ": " + p);
    }
  }

  bool CreateScene() {
    v1::CreateSceneRequest req;
    req.set_scene_id("fuzz");
    v1::SceneConfig& c = *req.mutable_config();
    if (rnd_.P(0.7)) {
      c.set_declared(true);
      for (v1::Effect e : {v1::EFFECT_CONTACT, v1::EFFECT_DAMPING, v1::EFFECT_FRICTION,
                           v1::EFFECT_WEIGHT, v1::EFFECT_TEXTURE, v1::EFFECT_TORQUE}) {
        if (rnd_.P(e == v1::EFFECT_CONTACT ? 0.85 : 0.4)) c.add_effects(e);
      }
      c.set_pd_mode(rnd_.Pick(std::vector<v1::PdMode>{v1::PD_MODE_UNSPECIFIED, v1::PD_MODE_PDT,
                                                      v1::PD_MODE_PDG, v1::PD_MODE_NONE}));
      if (rnd_.P(0.5)) {
        c.mutable_gravity()->set_x(rnd_.Symmetric(wire::kGravity));
        c.mutable_gravity()->set_y(rnd_.Symmetric(wire::kGravity));
        c.mutable_gravity()->set_z(rnd_.Symmetric(wire::kGravity));
      }
      c.set_texture_amplitude(rnd_.Value(wire::kTextureAmplitude));
      c.set_texture_frequency(rnd_.Value(wire::kTextureFrequency));
      if (rnd_.P(0.5)) {
        c.set_probe_mass(
            rnd_.P(0.3) ? rnd_.Pick(std::vector<double>{wire::kProbeMass.lo, wire::kProbeMass.hi})
                        : rnd_.LogU(wire::kProbeMass.lo, wire::kProbeMass.hi));
        if (rnd_.P(0.6)) {
          c.set_probe_inertia(
              rnd_.P(0.3)
                  ? rnd_.Pick(std::vector<double>{wire::kProbeInertia.lo, wire::kProbeInertia.hi})
                  : rnd_.LogU(wire::kProbeInertia.lo, wire::kProbeInertia.hi));
        }
      }
    }
    if (rnd_.P(0.15)) {  // one value just out of range first: rejected, then the good one
      v1::CreateSceneRequest bad = req;
      std::string field;
      switch (rnd_.I(0, 2)) {
        case 0:
          bad.mutable_config()->mutable_gravity()->set_z(wire::kGravity.hi * 1.01);
          field = "config.gravity.z";
          break;
        case 1:
          bad.mutable_config()->set_texture_frequency(wire::kTextureFrequency.hi + 1);
          field = "config.texture_frequency";
          break;
        default:
          bad.mutable_config()->set_probe_mass(wire::kProbeMass.hi * 2);
          field = "config.probe_mass";
          break;
      }
      v1::SceneSummary out;
      auto ctx = testing::Ctx();
      Rejected(scenes_->CreateScene(ctx.get(), bad, &out), field, "CreateScene");
    }
    v1::SceneSummary out;
    auto ctx = testing::Ctx();
    const grpc::Status s = scenes_->CreateScene(ctx.get(), req, &out);
    if (!s.ok()) {
      Fail(t_, where_ + ": CreateScene " + req.ShortDebugString() + ": " + s.error_message());
      return false;
    }
    return true;
  }

  void AddBody(int i) {
    const bool bad = rnd_.P(0.1);
    const int bad_kind = bad ? rnd_.I(0, 3) : -1;
    const std::string shape = RandomShape(rnd_, bad_kind == 0);
    Pose X_WB = Pose::FromQuaternion(rnd_.AnyRotation(), AnyPosition(rnd_));
    if (!bodies_.empty() && rnd_.P(0.6)) {  // near an earlier body, so the probe meets several
      const Body& b = rnd_.Pick(bodies_);
      X_WB.t = b.centre_W + rnd_.U(0, 1.5) * b.radius * rnd_.Rotation().vec().normalized();
    }
    v1::AddBodyRequest req =
        testing::ShapeHeader("fuzz", shape, "b" + std::to_string(i), v1::Pose(), rnd_.P(0.3));
    v1::BodySpec& spec = *req.mutable_header()->mutable_spec();
    ToWire(X_WB, rnd_, spec.mutable_pose());
    if (rnd_.P(0.8)) *spec.mutable_material() = RandomMaterial(rnd_);
    if (spec.movable() && rnd_.P(0.5)) {
      auto* v = spec.mutable_velocity();
      v->mutable_linear()->set_x(rnd_.Symmetric(wire::kLinearVelocity));
      v->mutable_angular()->set_z(rnd_.Symmetric(wire::kAngularVelocity));
    }
    std::string field = "header.shape";
    if (bad_kind == 1) {
      *spec.mutable_material() = RandomMaterial(rnd_, true);
      field = "header.spec.material";
    } else if (bad_kind == 2) {
      spec.mutable_pose()->mutable_position()->set_y(wire::kCoordinate.lo * (1 + 1e-9));
      field = "header.spec.pose.position.y";
    } else if (bad_kind == 3) {
      spec.mutable_pose()->mutable_orientation()->set_x(kNaN);
      field = "header.spec.pose.orientation";
    }
    v1::Body out;
    const grpc::Status s = testing::AddBodyRaw(*scenes_, {req}, &out);
    if (bad) {
      if (s.ok()) {
        Fail(t_, where_ + ": AddBody accepted an out-of-range value: " + req.ShortDebugString());
      } else {
        Rejected(s, field, "AddBody " + shape);
      }
      return;
    }
    if (!s.ok()) {  // a random size the builders refuse (e.g. a torus's minor >= major)
      Rejected(s, "header.shape", "AddBody " + shape);
      return;
    }
    ++t_.bodies;
    const v1::MeshInfo& mi = out.mesh_info();
    const Vec3 c_B = 0.5 * (V(mi.aabb_min()) + V(mi.aabb_max()));
    bodies_.push_back({out.body_id(), FromWire(out.pose()) * c_B, mi.bounding_radius(), {}});
  }

  /// Up to 64 vertices of each body, in the world, to aim poses at.
  void SampleSurfaces() {
    v1::GetSceneRequest req;
    req.set_scene_id("fuzz");
    req.set_include_meshes(true);
    v1::Scene scene;
    auto ctx = testing::Ctx();
    if (const grpc::Status s = scenes_->GetScene(ctx.get(), req, &scene); !s.ok()) {
      Fail(t_, where_ + ": GetScene: " + s.error_message());
      return;
    }
    for (const v1::Body& wb : scene.bodies()) {
      for (Body& b : bodies_) {
        if (b.id != wb.body_id()) continue;
        const Pose X_WB = FromWire(wb.pose());
        const auto& v = wb.mesh().vertices();
        const int n = v.size() / 3;
        for (int k = 0; k < std::min(n, 64); ++k) {
          const int i = n <= 64 ? k : rnd_.I(0, n - 1);
          b.surface_W.push_back(X_WB * Vec3(v[3 * i], v[3 * i + 1], v[3 * i + 2]));
        }
      }
    }
  }

  v1::Hello RandomHello(std::string* bad_field) {
    v1::Hello h = testing::Session::DefaultHello(
        "fuzz",
        rnd_.Pick(std::vector<v1::PdMode>{v1::PD_MODE_PDT, v1::PD_MODE_PDT, v1::PD_MODE_PDT,
                                          v1::PD_MODE_PDG, v1::PD_MODE_PDG, v1::PD_MODE_PDG,
                                          v1::PD_MODE_UNSPECIFIED, v1::PD_MODE_NONE}),
        RandomShape(rnd_));
    if (!bodies_.empty() && rnd_.P(0.15)) h.set_probe_body_id(rnd_.Pick(bodies_).id);
    if (rnd_.P(0.7)) *h.mutable_material() = RandomMaterial(rnd_);
    if (rnd_.P(0.2)) h.set_max_rate_hz(wire::kMaxRateHz.hi);
    if (rnd_.P(0.1)) {
      // Everything else valid, so that the one bad value is what is refused.
      h.set_mode(v1::PD_MODE_PDT);
      h.set_probe_shape("sphere:0.01,2");
      switch (rnd_.I(0, 2)) {
        case 0:
          *h.mutable_material() = RandomMaterial(rnd_, true);
          *bad_field = "hello.material";
          break;
        case 1:
          h.set_max_rate_hz(wire::kMaxRateHz.hi * 2);
          *bad_field = "hello.max_rate_hz";
          break;
        default:
          h.set_probe_shape(RandomShape(rnd_, true));
          *bad_field = "hello.probe_shape";
          break;
      }
    }
    return h;
  }

  void Couple(int index, int clusters, int steps) {
    const std::string where = where_ + " session " + std::to_string(index);
    std::string bad_field;
    const v1::Hello hello = RandomHello(&bad_field);
    testing::Session session(*haptics_);
    const grpc::Status opened = session.Open(hello);
    if (!bad_field.empty()) {
      if (opened.ok()) {
        Fail(t_, where + ": a hello with an out-of-range value was accepted: " +
                     hello.ShortDebugString());
      } else {
        Rejected(opened, bad_field, "hello");
      }
      return;
    }
    if (!opened.ok()) {
      // A size the builders refuse, or no PD mode in hello or scene.
      Rejected(opened, "hello.", "hello " + hello.ShortDebugString());
      return;
    }
    ++t_.sessions;
    const v1::Welcome& w = session.welcome();
    const v1::MeshInfo& pm = w.probe_mesh_info();
    Probe probe{0.5 * (V(pm.aabb_min()) + V(pm.aabb_max())), pm.bounding_radius(),
                XPaFromWelcome(w)};
    std::vector<Body> others;  // the probe body is not collided with
    for (const Body& b : bodies_) {
      if (hello.probe_case() != v1::Hello::kProbeBodyId || b.id != hello.probe_body_id()) {
        others.push_back(b);
      }
    }
    std::uint64_t seq = 0;
    Pose prev = RandomPose(rnd_, others, probe, Pose::Identity());
    for (int c = 0; c < clusters; ++c) {
      // The device sits at a random pose; the poses sent are its proxy's
      // (closing the loop) or random ones, mostly close by.
      const Pose anchor = RandomPose(rnd_, others, probe, prev);
      Servo servo(rnd_, anchor, probe.X_PA, w.scene_config());
      for (int i = 0; i < 3; ++i) Check(servo.Tick(), where + " before any update");
      prev = anchor;
      for (int k = 0; k < steps; ++k) {
        const std::string at =
            where + " cluster " + std::to_string(c) + " pose " + std::to_string(seq + 1);
        const Pose X = rnd_.P(0.5) ? servo.X_WA() : RandomPose(rnd_, others, probe, prev);
        prev = X;
        v1::Pose wire_pose;
        ToWire(X, rnd_, &wire_pose);
        if (!session.Send(++seq, wire_pose, servo.clock.NowNs())) {
          Fail(t_, at + ": the stream broke: " + session.Finish().error_message());
          return;
        }
        const std::optional<v1::ContactUpdate> u = session.Next();
        if (!u) {
          Fail(t_, at + ": no answer: " + session.Finish().error_message());
          return;
        }
        ++t_.updates;
        if (u->sequence() != seq) Fail(t_, at + ": answer to " + std::to_string(u->sequence()));
        if (std::string p = UpdateProblem(*u, max_force_, max_torque_); !p.empty()) {
          Fail(t_, at + ": " + p + "\n  pose " + wire_pose.ShortDebugString() + "\n  update " +
                       u->ShortDebugString());
        }
        ++t_.by_status[std::clamp(static_cast<int>(u->status()), 0, 7)];
        if (u->status() == v1::CONTACT_STATUS_PENETRATING) ++t_.penetrating;
        if (u->status() == v1::CONTACT_STATUS_WITHHELD) ++t_.withheld;
        if (u->sigma() > 0) ++t_.pdg;
        device::IntermediateRep& ir = servo.loop->ir_mailbox().back();
        if (client::IrFromContactUpdate(*u, probe.X_PA.Inverse(), servo.clock.NowNs(), &ir)) {
          servo.loop->ir_mailbox().Publish();
        } else {
          Fail(t_, at + ": IrFromContactUpdate refused " + u->ShortDebugString());
        }
        // Mostly a tick or a few per answer; sometimes long enough for the
        // IR to go stale and the output to fade.
        const double v = rnd_.U();
        const int n = v < 0.4 ? 1 : v < 0.85 ? rnd_.I(2, 5) : rnd_.I(25, 40);
        for (int i = 0; i < n; ++i) {
          Check(servo.Tick(), at);
          const device::TickRecord& r = servo.loop->last_tick();
          ++t_.servo_ticks;
          if (r.wrench_ir.head<3>().norm() > 0) ++t_.contact_ticks;
          if (r.F_cmd_D.force.norm() > 0.99 * servo.dev->info().max_force) ++t_.limit_ticks;
        }
      }
    }
    if (rnd_.P(0.15)) {  // one pose just out of range ends the session
      v1::Pose bad;
      ToWire(prev, rnd_, &bad);
      std::string field = "pose.pose.position.x";
      switch (rnd_.I(0, 2)) {
        case 0:
          bad.mutable_position()->set_x(wire::kCoordinate.hi * (1 + 1e-9));
          break;
        case 1:
          bad.mutable_position()->set_x(kInf);
          break;
        default: {  // norm 1.01, ten times the server's tolerance
          v1::Quaternion& q = *bad.mutable_orientation();
          for (auto [get, set] : {std::pair{&v1::Quaternion::w, &v1::Quaternion::set_w},
                                  std::pair{&v1::Quaternion::x, &v1::Quaternion::set_x},
                                  std::pair{&v1::Quaternion::y, &v1::Quaternion::set_y},
                                  std::pair{&v1::Quaternion::z, &v1::Quaternion::set_z}}) {
            (q.*set)((q.*get)() * 1.01);
          }
          field = "pose.pose.orientation";
          break;
        }
      }
      session.Send(++seq, bad);
      if (auto u = session.Next()) {
        Fail(t_, where + ": an answer to a bad pose " + bad.ShortDebugString());
        session.Cancel();  // rather than wait for the server's idle timeout
        session.Finish();
        return;
      }
      Rejected(session.Finish(), field, "pose " + bad.ShortDebugString());
      return;
    }
    session.CloseWrites();
    if (session.Next()) Fail(t_, where + ": an update after the writes were closed");
    if (const grpc::Status s = session.Finish(); !s.ok()) {
      Fail(t_, where + ": the session ended with " + s.error_message());
    }
  }

  void Check(const std::string& problem, const std::string& at) {
    if (!problem.empty()) Fail(t_, at + ": servo: " + problem);
  }

  Rand rnd_;
  Tally& t_;
  bool small_limits_ = false;
  double max_force_ = 0, max_torque_ = 0;
  std::unique_ptr<testing::ServerHarness> harness_;
  std::unique_ptr<v1::SceneService::Stub> scenes_;
  std::unique_ptr<v1::HapticService::Stub> haptics_;
  std::string where_;
  std::vector<Body> bodies_;
};

TEST(CoupleFuzz, EveryUpdateFitForAMotor) {
  // Answers over the limits are withheld, and each session that withholds
  // one says so once at warning level.
  testing::ScopedExpectLogs expect_logs;
  const std::uint64_t seed = testing::TestSeed();
  const int runs = testing::TestCount(kSanitized ? 12 : 24);
  const int steps = kSanitized ? 6 : 16;
  Tally t;
  for (int r = 0; r < runs; ++r) {
    FuzzRun run(seed + static_cast<std::uint64_t>(r), r, t);
    run.Go(/*sessions=*/3, /*clusters=*/kSanitized ? 2 : 4, steps);
  }
  std::printf(
      "[ couple fuzz ] seed %llu: %d runs, %d bodies, %d sessions, %d updates (%d penetrating, %d "
      "PDg, %d withheld), %d requests rejected, %d servo ticks (%d in contact, %d at the force "
      "limit)\n",
      static_cast<unsigned long long>(seed), t.runs, t.bodies, t.sessions, t.updates, t.penetrating,
      t.pdg, t.withheld, t.rejected, t.servo_ticks, t.contact_ticks, t.limit_ticks);
  std::printf("[ couple fuzz ] answers by status:");
  for (int i = 1; i < 8; ++i) {
    if (t.by_status[i] > 0) {
      std::printf(" %s %d", v1::ContactStatus_Name(static_cast<v1::ContactStatus>(i)).c_str(),
                  t.by_status[i]);
    }
  }
  std::printf("\n");
  EXPECT_EQ(t.failures, 0) << "failures in all (the first 8 are shown above)";
  // The run must have reached what it is there to check.
  EXPECT_GT(t.penetrating, 0);
  EXPECT_GT(t.pdg, 0);
  EXPECT_GT(t.rejected, 0);
  EXPECT_GT(t.contact_ticks, 0);
  // The sanitizer presets run half the default count (12 runs, fewer steps); there
  // no tick may happen to reach the device's limit (seen under TSan).
  if (!kSanitized) {
    EXPECT_GT(t.limit_ticks, 0);
  }
  EXPECT_GT(t.server_withheld_small, 0u) << "no answer was over the small limits: the guard was "
                                            "never exercised";
  EXPECT_GT(t.withheld, 0);
}

// ---- the client's own boundary ----------------------------------------------

/// A penetrating PDt answer (two rows, force and torque) and a PDg one (a
/// target spring), for a 1 cm probe whose centre of mass is its mesh
/// origin, at the origin.
std::vector<v1::ContactUpdate> GoodUpdates() {
  v1::ContactUpdate pdt;
  pdt.set_sequence(1);
  *pdt.mutable_pose_ref() = testing::MakePose(0, 0, 0);
  *pdt.mutable_target_pose() = testing::MakePose(0, 0, 0.002);
  pdt.set_status(v1::CONTACT_STATUS_PENETRATING);
  for (double x : {-0.004, 0.004}) {
    v1::ContactRow* r = pdt.add_rows();
    r->mutable_point()->set_x(x);
    r->mutable_point()->set_z(-0.01);
    r->mutable_normal()->set_z(1);
    r->set_depth(0.002);
    r->mutable_moment()->set_y(-x);
    r->set_stiffness(2000);
    r->set_static_friction(0.5);
    r->set_dynamic_friction(0.3);
    r->set_damping(2);
  }
  pdt.mutable_force()->set_z(8);
  pdt.mutable_torque()->set_x(0.001);
  pdt.set_depth(0.002);
  pdt.mutable_pd_translation()->set_z(0.002);
  pdt.set_validity_radius(0.003);
  pdt.set_validity_angle(0.3);
  pdt.set_target_stiffness(2000);
  pdt.set_target_rotational_stiffness(0.05);
  pdt.set_compute_time_us(10);
  v1::ContactUpdate pdg = pdt;
  pdg.set_sigma(4e-6);
  pdg.set_rotation_angle(0.01);
  pdg.mutable_rotation_axis()->set_x(1);
  *pdg.mutable_target_pose() = testing::MakePose(0, 0, 0.002, std::cos(0.005), std::sin(0.005));
  return {pdt, pdg};
}

/// Puts each of `values` into each number of GoodUpdates() in turn and
/// passes the update to a servo loop the way client::Session does; every
/// tick must command a finite wrench within the device's limits. Returns
/// how many updates IrFromContactUpdate refused (of *cases).
int BadNumbersToServo(const std::vector<double>& values, int* cases) {
  const Pose X_PA = Pose::Identity();
  const v1::SceneConfig scene;  // declares nothing: contact and torque
  Rand rnd(testing::TestSeed());
  int refused = 0;
  *cases = 0;
  for (const v1::ContactUpdate& good : GoodUpdates()) {
    for (double bad : values) {
      for (int field = 0;; ++field) {
        v1::ContactUpdate u = good;
        int n = field;
        if (!SetNthNumber(&u, &n, bad)) break;
        ++*cases;
        std::string path;
        int k = 0;
        ForEachNumber(u, "", [&](const std::string& p, double x) {
          if (k++ == field) path = p + " = " + Num(x);
        });
        Servo servo(rnd, FromWire(good.pose_ref()), X_PA, scene);
        std::string problem;
        for (int i = 0; i < 5 && problem.empty(); ++i) problem = servo.Tick();
        device::IntermediateRep& ir = servo.loop->ir_mailbox().back();
        if (client::IrFromContactUpdate(u, X_PA.Inverse(), servo.clock.NowNs(), &ir)) {
          servo.loop->ir_mailbox().Publish();
        } else {
          ++refused;
        }
        for (int i = 0; i < 40 && problem.empty(); ++i) problem = servo.Tick();
        EXPECT_EQ(problem, "") << path << " in " << u.ShortDebugString();
      }
    }
  }
  return refused;
}

TEST(CoupleFuzz, ClientBoundaryKeepsBadNumbersFromTheMotor) {
  // Non-finite numbers, and finite ones far outside any physical range
  // (still small enough that their squares are finite).
  int cases = 0;
  const int refused = BadNumbersToServo({kNaN, kInf, -kInf, 1e12, -1e100, 5e-324}, &cases);
  EXPECT_GT(cases, 200);
  EXPECT_GT(refused, 0);
}

// Finite numbers whose squares overflow (a pose_ref coordinate or a row
// point beyond 1e154 m, a row depth of 1e200 m): IrFromContactUpdate refuses
// coordinates and depths beyond 1e6 m, and the servo loop puts a
// non-finite proxy back on the handle and never commands a non-finite force
// (ClampNorm gives zero for one).
TEST(CoupleFuzz, ClientBoundaryKeepsHugeNumbersFromTheMotor) {
  int cases = 0;
  const int refused = BadNumbersToServo({1e155, -1e200, 1e308}, &cases);
  EXPECT_GT(cases, 100);
  EXPECT_GT(refused, 0);
}

}  // namespace couple_fuzz
}  // namespace hapticpd
