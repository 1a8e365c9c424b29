// The physical ranges of the wire API, field by field: both ends accepted,
// just outside rejected with the exact message, NaN and infinities rejected,
// and the same values in a scene file accepted or rejected alike (the RPCs
// and the scene-file parser share one validator).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <limits>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "proto/wire/convert.h"
#include "proto/wire/ranges.h"
#include "proto/wire/scene_file.h"

namespace hapticpd::wire {
namespace {

std::string Num(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

/// Full precision, for JSON and shape specs.
std::string Exact(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

grpc::Status FromMessage(const std::string& problem) {
  return problem.empty() ? grpc::Status::OK
                         : grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, problem);
}

/// Whether ParseSceneJson accepts the text.
bool SceneAccepts(const std::string& json, std::string* error) {
  try {
    ParseSceneJson(json, "scene.json");
    return true;
  } catch (const SceneFileError& e) {
    *error = e.what();
    return false;
  }
}

struct FieldRow {
  std::string field;  // as named in the RPC's message
  double lo, hi;
  std::string range;  // the documented range, as the message prints it
  bool zero_unset;    // 0 accepted too ("not given")
  std::function<grpc::Status(double)> rpc;
  std::function<std::string(double)> scene;  // scene JSON with the value; null: no scene key
  /// The message for an out-of-range value, when it is not "FIELD: must be in RANGE, got V".
  std::function<std::string(double)> message = nullptr;
};

v1::Material WithMaterial(const std::function<void(v1::Material*)>& f) {
  v1::Material m;
  f(&m);
  return m;
}

std::vector<FieldRow> Rows() {
  std::vector<FieldRow> rows;
  auto material = [](const char* name, double lo, double hi, const char* range,
                     std::function<void(v1::Material*, double)> set, std::string other) {
    return FieldRow{std::string("m.") + name,
                    lo,
                    hi,
                    range,
                    false,
                    [set](double v) {
                      pd::Material out;
                      return FromProto(WithMaterial([&](v1::Material* m) { set(m, v); }), "m",
                                       &out);
                    },
                    [name, other](double v) {
                      return R"({"bodies": [{"shape": "box", "material": {")" + std::string(name) +
                             "\": " + Exact(v) + other + "}}]}";
                    }};
  };
  rows.push_back({"pose.position.x", -1e4, 1e4, "[-10000, 10000] m", false,
                  [](double v) {
                    v1::Pose p;
                    p.mutable_position()->set_x(v);
                    Pose out;
                    return FromProto(p, "pose", &out);
                  },
                  [](double v) {
                    return R"({"bodies": [{"shape": "box", "pose": {"position": [)" + Exact(v) +
                           ", 0, 0]}}]}";
                  }});
  rows.push_back({"velocity.linear.y", -100, 100, "[-100, 100] m/s", false,
                  [](double v) {
                    v1::Twist t;
                    t.mutable_linear()->set_y(v);
                    return ValidateTwist(t, "velocity");
                  },
                  nullptr});
  rows.push_back({"velocity.angular.z", -1e3, 1e3, "[-1000, 1000] rad/s", false,
                  [](double v) {
                    v1::Twist t;
                    t.mutable_angular()->set_z(v);
                    return ValidateTwist(t, "velocity");
                  },
                  nullptr});
  rows.push_back(material(
      "stiffness", 0, 1e7, "[0, 1e+07] N/m", [](v1::Material* m, double v) { m->set_stiffness(v); },
      ""));
  rows.push_back(material(
      "rotational_stiffness", 0, 1e5, "[0, 100000] N m/rad",
      [](v1::Material* m, double v) { m->set_rotational_stiffness(v); }, ""));
  rows.push_back(material(
      "damping", 0, 1e5, "[0, 100000] N s/m", [](v1::Material* m, double v) { m->set_damping(v); },
      ""));
  // The other friction coefficient is set so that the order dynamic <=
  // static holds at both ends.
  rows.push_back(material(
      "static_friction", 0, 10, "[0, 10]",
      [](v1::Material* m, double v) { m->set_static_friction(v); }, R"(, "dynamic_friction": 0)"));
  rows.push_back(material(
      "dynamic_friction", 0, 10, "[0, 10]",
      [](v1::Material* m, double v) {
        m->set_static_friction(10);
        m->set_dynamic_friction(v);
      },
      R"(, "static_friction": 10)"));
  rows.push_back({"mesh.vertices[3]", -1e4, 1e4, "[-10000, 10000] m", false,
                  [](double v) {
                    v1::InlineMesh m;
                    for (double x : {0.0, 0.0, 0.0, v, 0.0, 1.0, 0.0, 1.0, 0.0}) m.add_vertices(x);
                    for (std::uint32_t i : {0u, 1u, 2u}) m.add_triangles(i);
                    std::optional<pd::Mesh> out;
                    return MeshFromInline(m, "mesh", 100, &out);
                  },
                  nullptr});
  rows.push_back(
      {"shape", 1e-6, 1e4, "[1e-06, 10000] m", false,
       [](double v) {
         std::optional<pd::Mesh> out;
         return MeshFromShape("sphere:" + Exact(v) + ",0", "shape", 100, &out);
       },
       [](double v) { return R"({"bodies": [{"shape": "sphere:)" + Exact(v) + R"(,0"}]})"; },
       [](double v) {
         return "shape: shape spec 'sphere:" + Exact(v) +
                ",0': radius must be in [1e-06, 10000] m, got " + Num(v);
       }});
  auto config = [](const std::string& field, double lo, double hi, const char* range,
                   bool zero_unset, std::function<void(v1::SceneConfig*, double)> set,
                   std::function<std::string(double)> scene) {
    return FieldRow{"config." + field,
                    lo,
                    hi,
                    range,
                    zero_unset,
                    [set](double v) {
                      v1::SceneConfig c;
                      set(&c, v);
                      return FromMessage(CheckSceneConfig(c, "config"));
                    },
                    std::move(scene)};
  };
  rows.push_back(config(
      "gravity.z", -100, 100, "[-100, 100] m/s^2", false,
      [](v1::SceneConfig* c, double v) { c->mutable_gravity()->set_z(v); },
      [](double v) { return R"({"gravity": [0, 0, )" + Exact(v) + "]}"; }));
  rows.push_back(config(
      "texture_amplitude", 0, 10, "[0, 10] N", false,
      [](v1::SceneConfig* c, double v) { c->set_texture_amplitude(v); },
      [](double v) { return R"({"texture": {"amplitude": )" + Exact(v) + "}}"; }));
  rows.push_back(config(
      "texture_frequency", 0, 500, "[0, 500] Hz", false,
      [](v1::SceneConfig* c, double v) { c->set_texture_frequency(v); },
      [](double v) { return R"({"texture": {"frequency": )" + Exact(v) + "}}"; }));
  rows.push_back(config(
      "probe_mass", 1e-6, 1e3, "[1e-06, 1000] kg", true,
      [](v1::SceneConfig* c, double v) { c->set_probe_mass(v); },
      [](double v) { return R"({"probe": {"shape": "stick", "mass": )" + Exact(v) + "}}"; }));
  rows.push_back(config(
      "probe_inertia", 1e-12, 1e3, "[1e-12, 1000] kg m^2", true,
      [](v1::SceneConfig* c, double v) {
        c->set_probe_mass(1);
        c->set_probe_inertia(v);
      },
      [](double v) {
        return R"({"probe": {"shape": "stick", "mass": 1, "inertia": )" + Exact(v) + "}}";
      }));
  rows.push_back({"hello.max_rate_hz", 0, 1e5, "[0, 100000] Hz", false,
                  [](double v) { return CheckRange(v, kMaxRateHz, "hello.max_rate_hz"); },
                  nullptr});
  rows.push_back({"rate_hz", 0, 1e3, "[0, 1000] Hz", false,
                  [](double v) { return CheckRange(v, kWatchRateHz, "rate_hz"); }, nullptr});
  return rows;
}

TEST(WireRanges, EveryFieldTable) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  for (const FieldRow& r : Rows()) {
    SCOPED_TRACE(r.field);
    // Just outside: 0.1% beyond the end (of the span for an end at 0).
    const double span = r.hi - r.lo;
    const double below = r.lo - (r.lo == 0 ? span : std::abs(r.lo)) * 1e-3;
    const double above = r.hi + (r.hi == 0 ? span : std::abs(r.hi)) * 1e-3;
    auto expected = [&](double v) {
      if (r.message) return r.message(v);
      return r.field + ": must be " + (r.zero_unset ? "0 (not given) or " : "") + "in " + r.range +
             ", got " + Num(v);
    };
    std::vector<double> inside = {r.lo, r.hi, (r.lo + r.hi) / 2};
    if (r.zero_unset) inside.push_back(0);
    for (double v : inside) {
      const grpc::Status s = r.rpc(v);
      EXPECT_TRUE(s.ok()) << v << ": " << s.error_message();
    }
    std::vector<double> outside = {below, above};
    if (r.zero_unset) outside.push_back(r.lo / 2);  // between 0 and lo
    for (double v : outside) {
      const grpc::Status s = r.rpc(v);
      EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << v;
      EXPECT_EQ(s.error_message(), expected(v));
    }
    for (double v : {nan, inf, -inf}) {
      const grpc::Status s = r.rpc(v);
      EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << v;
      if (!r.message) {
        EXPECT_EQ(s.error_message(), r.field + ": must be a finite number, got " + Num(v));
      }
    }
    if (!r.scene) continue;
    // The scene file decides alike (JSON has no NaN or infinity).
    for (double v : inside) {
      std::string error;
      EXPECT_TRUE(SceneAccepts(r.scene(v), &error)) << r.scene(v) << ": " << error;
    }
    for (double v : outside) {
      std::string error;
      EXPECT_FALSE(SceneAccepts(r.scene(v), &error)) << r.scene(v);
      // Same problem text after the key.
      const std::string rpc = expected(v);
      const std::string problem = rpc.substr(rpc.find(": must") + 2);
      EXPECT_NE(error.find(problem), std::string::npos) << error << "\n  vs " << problem;
    }
  }
}

TEST(WireRanges, FrictionOrder) {
  auto rpc = [](double s, double d) {
    v1::Material m;
    m.set_static_friction(s);
    m.set_dynamic_friction(d);
    pd::Material out;
    return FromProto(m, "m", &out);
  };
  auto scene = [](double s, double d) {
    std::string error;
    return SceneAccepts(R"({"bodies": [{"shape": "box", "material": {"static_friction": )" +
                            Exact(s) + R"(, "dynamic_friction": )" + Exact(d) + "}}]}",
                        &error);
  };
  EXPECT_TRUE(rpc(0.5, 0.5).ok());
  EXPECT_TRUE(scene(0.5, 0.5));
  EXPECT_TRUE(rpc(0.5, 0.3).ok());
  EXPECT_TRUE(scene(0.5, 0.3));
  const grpc::Status s = rpc(0.3, 0.5);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(s.error_message(), "m.dynamic_friction: must not exceed static_friction (0.5 > 0.3)");
  EXPECT_FALSE(scene(0.3, 0.5));
}

TEST(WireRanges, MeshExtent) {
  auto mesh = [](double size) {
    v1::InlineMesh m;
    for (double x : {0.0, 0.0, 0.0, size, 0.0, 0.0, 0.0, size, 0.0}) m.add_vertices(x);
    for (std::uint32_t i : {0u, 1u, 2u}) m.add_triangles(i);
    std::optional<pd::Mesh> out;
    return MeshFromInline(m, "mesh", 100, &out);
  };
  // Diagonal size * sqrt(2).
  EXPECT_TRUE(mesh(1e-6 / std::sqrt(2.0) * 1.001).ok()) << mesh(1e-6).error_message();
  const grpc::Status s = mesh(1e-300);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(s.error_message(),
            "mesh: bounding-box diagonal 1.41421e-300 m is below the minimum of 1e-06 m");
  EXPECT_FALSE(mesh(1e-6 / std::sqrt(2.0) * 0.999).ok());
}

TEST(WireRanges, ShapeLengthsAndReach) {
  std::optional<pd::Mesh> out;
  // Capsule half_length may be 0 (a sphere); other lengths may not.
  EXPECT_TRUE(MeshFromShape("capsule:0.02,0", "s", 100000, &out).ok());
  EXPECT_EQ(MeshFromShape("box:1e300,1,1", "s", 100, &out).error_message(),
            "s: shape spec 'box:1e300,1,1': hx must be in [1e-06, 10000] m, got 1e+300");
  EXPECT_EQ(MeshFromShape("sphere:1e-300", "s", 100000, &out).error_message(),
            "s: shape spec 'sphere:1e-300': radius must be in [1e-06, 10000] m, got 1e-300");
  // Each length in range, but the torus reaches beyond the world.
  EXPECT_EQ(MeshFromShape("torus:9000,5000", "s", 100000, &out).error_message(),
            "s: shape spec 'torus:9000,5000': reaches 14000 m from its origin, beyond the "
            "coordinate range [-10000, 10000] m");
}

// The limit is checked on the counted triangles before anything is built:
// a build of these would throw (over kMaxShapeTriangles) or take hours, so
// only the arithmetic count can name the exact number.
TEST(WireRanges, ShapeLimitBeforeBuild) {
  std::optional<pd::Mesh> out;
  grpc::Status s = MeshFromShape("box:0.1,0.1,0.1,1000000", "s", 500, &out);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_EQ(s.error_message(), "s: 12000000000000 triangles exceed the server limit of 500");
  EXPECT_FALSE(out.has_value());
  s = MeshFromShape("sphere:0.05,9", "s", 2000000, &out);
  EXPECT_EQ(s.error_message(), "s: 5242880 triangles exceed the server limit of 2000000");
  // Within a generous limit but over what pd builds: still not built.
  s = MeshFromShape("sphere:0.05,9", "s", 100000000, &out);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(s.error_message(),
            "s: shape spec 'sphere:0.05,9': resolution too high: 5242880 triangles, more than the "
            "limit of 5000000");
  EXPECT_TRUE(MeshFromShape("sphere:0.05,2", "s", 320, &out).ok());
  EXPECT_EQ(out->num_triangles(), 320u);
}

TEST(WireRanges, ProbeShapeInSceneConfig) {
  v1::SceneConfig c;
  c.set_probe_shape("sphere:0.01");
  EXPECT_EQ(CheckSceneConfig(c, "config"), "");
  c.set_probe_shape("stick ");
  EXPECT_EQ(CheckSceneConfig(c, "config"),
            "config.probe_shape: shape spec 'stick ': whitespace is not allowed in a shape spec "
            "(at byte 5)");
  c.set_probe_shape("sphere:0.01,8");
  EXPECT_EQ(CheckSceneConfig(c, "config", 1000),
            "config.probe_shape: 1310720 triangles exceed the server limit of 1000");
  std::string error;
  EXPECT_FALSE(SceneAccepts(R"({"probe": {"shape": "stick "}})", &error));
  EXPECT_EQ(error,
            "scene.json: probe.shape: shape spec 'stick ': whitespace is not allowed in a shape "
            "spec (at byte 5)");
  EXPECT_FALSE(SceneAccepts(R"({"bodies": [{"shape": "box:0.1"}]})", &error));
  EXPECT_EQ(error,
            "scene.json: bodies[0].shape: shape spec 'box:0.1': 'box' needs all of hx,hy,hz or "
            "none (for the defaults); missing hy,hz");
}

// proto/README.md's "Ranges" table names each constant with its range; it
// must agree with ranges.h.
TEST(WireRanges, ReadmeTableMatchesConstants) {
  std::ifstream in(std::string(HAPTICPD_SOURCE_DIR) + "/proto/README.md");
  ASSERT_TRUE(in) << "proto/README.md";
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  for (const NamedRange& r : AllRanges()) {
    SCOPED_TRACE(r.name);
    // A row "| ... | `kName` | RANGE |" (RANGE as Describe prints it, with
    // "or 0" for ranges where 0 means not given).
    const std::string cell = std::string("`") + r.name + "` | " +
                             (r.range.zero_means_unset ? "0 or " : "") + Describe(r.range) + " |";
    EXPECT_NE(text.find(cell), std::string::npos) << "missing or different: " << cell;
  }
  std::ostringstream extent;
  extent << "`kMinMeshExtent` | >= " << kMinMeshExtent << " m |";
  EXPECT_NE(text.find(extent.str()), std::string::npos) << extent.str();
}

}  // namespace
}  // namespace hapticpd::wire
