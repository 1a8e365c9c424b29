#include "proto/wire/scene_file.h"

#include <nlohmann/json.hpp>

#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <sstream>
#include <tuple>
#include <utility>

#include "pd/material.h"
#include "proto/wire/convert.h"
#include "proto/wire/ranges.h"

namespace hapticpd::wire {

namespace {

using Json = nlohmann::json;

struct Effects {
  v1::Effect effect;
  const char* name;
};
constexpr Effects kEffects[] = {
    {v1::EFFECT_CONTACT, "contact"},   {v1::EFFECT_DAMPING, "damping"},
    {v1::EFFECT_FRICTION, "friction"}, {v1::EFFECT_WEIGHT, "weight"},
    {v1::EFFECT_TEXTURE, "texture"},   {v1::EFFECT_TORQUE, "torque"},
};

/// Parsing context: the file (for messages) and its folder.
class Parser {
 public:
  Parser(std::string path, std::size_t max_triangles)
      : path_(std::move(path)), max_triangles_(max_triangles) {
    dir_ = std::filesystem::path(path_).parent_path();
  }

  [[noreturn]] void Fail(const std::string& key, const std::string& what) const {
    throw SceneFileError(path_ + ": " + (key.empty() ? std::string() : key + ": ") + what);
  }

  void RequireObject(const Json& j, const std::string& key) const {
    if (!j.is_object()) Fail(key.empty() ? "(top level)" : key, "expected an object");
  }

  void OnlyKeys(const Json& j, const std::string& key, std::initializer_list<const char*> allowed) {
    for (auto it = j.begin(); it != j.end(); ++it) {
      bool ok = false;
      for (const char* a : allowed) ok = ok || it.key() == a;
      if (!ok) {
        std::string list;
        for (const char* a : allowed) list += std::string(list.empty() ? "" : ", ") + a;
        Fail(Join(key, it.key()), "unknown key (expected one of: " + list + ")");
      }
    }
  }

  static std::string Join(const std::string& key, const std::string& sub) {
    return key.empty() ? sub : key + "." + sub;
  }

  std::string String(const Json& j, const std::string& key) const {
    if (!j.is_string()) Fail(key, "expected a string");
    return j.get<std::string>();
  }

  bool Bool(const Json& j, const std::string& key) const {
    if (!j.is_boolean()) Fail(key, "expected true or false");
    return j.get<bool>();
  }

  double Number(const Json& j, const std::string& key) const {
    if (!j.is_number()) Fail(key, "expected a number");
    return j.get<double>();
  }

  /// A number in `range`, with the RPCs' message.
  double InRange(const Json& j, const std::string& key, const Range& range) const {
    const double v = Number(j, key);
    if (std::string p = RangeProblem(v, range); !p.empty()) Fail(key, p);
    return v;
  }

  /// A shape spec, checked as AddBody / CreateScene check it (without
  /// building it).
  std::string Shape(const Json& j, const std::string& key) const {
    const std::string spec = String(j, key);
    if (grpc::Status s = CheckShapeSpec(spec, key, max_triangles_); !s.ok()) {
      // The status message starts with the key already.
      throw SceneFileError(path_ + ": " + s.error_message());
    }
    return spec;
  }

  /// N numbers, each in `range` (nullptr: finite).
  template <std::size_t N>
  std::array<double, N> Numbers(const Json& j, const std::string& key, const char* shape,
                                const Range* range) const {
    if (!j.is_array() || j.size() != N) Fail(key, std::string("expected ") + shape);
    std::array<double, N> out{};
    for (std::size_t i = 0; i < N; ++i) {
      const std::string k = key + "[" + std::to_string(i) + "]";
      out[i] = Number(j[i], k);
      if (range != nullptr) {
        if (std::string p = RangeProblem(out[i], *range); !p.empty()) Fail(k, p);
      } else if (!std::isfinite(out[i])) {
        Fail(k, "must be finite");
      }
    }
    return out;
  }

  std::string MeshPath(const Json& j, const std::string& key) const {
    std::filesystem::path p = String(j, key);
    if (p.empty()) Fail(key, "empty mesh path");
    if (p.is_relative()) p = dir_ / p;
    std::error_code ec;
    if (!std::filesystem::is_regular_file(p, ec)) {
      Fail(key, "mesh file '" + p.string() + "' not found");
    }
    return p.string();
  }

  v1::Pose ParsePose(const Json& j, const std::string& key) {
    RequireObject(j, key);
    OnlyKeys(j, key, {"position", "orientation"});
    v1::Pose p;
    if (j.contains("position")) {
      const auto a = Numbers<3>(j["position"], key + ".position", "[x, y, z]", &kCoordinate);
      p.mutable_position()->set_x(a[0]);
      p.mutable_position()->set_y(a[1]);
      p.mutable_position()->set_z(a[2]);
    }
    if (j.contains("orientation")) {
      const auto a = Numbers<4>(j["orientation"], key + ".orientation", "[w, x, y, z]", nullptr);
      auto* q = p.mutable_orientation();
      q->set_w(a[0]);
      q->set_x(a[1]);
      q->set_y(a[2]);
      q->set_z(a[3]);
    }
    // The RPCs' pose check (unit quaternion).
    Pose pose;
    if (grpc::Status st = FromProto(p, key, &pose); !st.ok()) {
      throw SceneFileError(path_ + ": " + st.error_message());
    }
    return p;
  }

  v1::Material ParseMaterial(const Json& j, const std::string& key) {
    RequireObject(j, key);
    OnlyKeys(
        j, key,
        {"stiffness", "rotational_stiffness", "damping", "static_friction", "dynamic_friction"});
    const pd::Material d;
    auto get = [&](const char* name, double def) {
      return j.contains(name) ? Number(j[name], key + "." + name) : def;
    };
    v1::Material m;
    m.set_stiffness(get("stiffness", d.stiffness));
    m.set_rotational_stiffness(get("rotational_stiffness", d.rotational_stiffness));
    m.set_damping(get("damping", d.damping));
    m.set_static_friction(get("static_friction", d.static_friction));
    m.set_dynamic_friction(get("dynamic_friction", d.dynamic_friction));
    // The RPCs' check (ranges, friction order), message and all.
    if (std::string p = MaterialProblem(m, key); !p.empty()) throw SceneFileError(path_ + ": " + p);
    return m;
  }

  SceneFileBody ParseBody(const Json& b, const std::string& key) {
    RequireObject(b, key);
    OnlyKeys(b, key, {"id", "label", "mesh", "shape", "pose", "material", "movable", "velocity"});
    SceneFileBody out;
    if (b.contains("mesh") == b.contains("shape")) {
      Fail(key, "give exactly one of \"mesh\" (a file) or \"shape\"");
    }
    if (b.contains("mesh")) {
      out.mesh_path = MeshPath(b["mesh"], key + ".mesh");
    } else {
      out.shape = Shape(b["shape"], key + ".shape");
    }
    v1::BodySpec& spec = out.spec;
    if (b.contains("id")) spec.set_body_id(String(b["id"], key + ".id"));
    spec.set_label(b.contains("label")  ? String(b["label"], key + ".label")
                   : b.contains("mesh") ? b["mesh"].get<std::string>()
                                        : out.shape);
    if (b.contains("movable")) spec.set_movable(Bool(b["movable"], key + ".movable"));
    if (b.contains("pose")) *spec.mutable_pose() = ParsePose(b["pose"], key + ".pose");
    if (b.contains("velocity")) {
      // As over the wire (BodySpec.velocity): the body moves at this twist
      // from the time it is added (server/scene.h PoseAt), where the PD and
      // the geometry patches find it; kept by `scene export` / `scene import`.
      const Json& v = b["velocity"];
      const std::string vk = key + ".velocity";
      RequireObject(v, vk);
      OnlyKeys(v, vk, {"linear", "angular"});
      auto set = [&](const char* name, const Range& range, v1::Vec3* out) {
        if (!v.contains(name)) return;
        const auto a = Numbers<3>(v[name], vk + "." + name, "[x, y, z]", &range);
        out->set_x(a[0]);
        out->set_y(a[1]);
        out->set_z(a[2]);
      };
      auto* t = spec.mutable_velocity();
      set("linear", kLinearVelocity, t->mutable_linear());
      set("angular", kAngularVelocity, t->mutable_angular());
    }
    // Absent: the server's default material.
    if (b.contains("material")) {
      *spec.mutable_material() = ParseMaterial(b["material"], key + ".material");
    }
    return out;
  }

  void ParseProbe(const Json& j, const std::string& key, SceneFile* f) {
    RequireObject(j, key);
    OnlyKeys(j, key, {"shape", "mesh", "mass", "inertia"});
    SceneFileProbe& p = f->probe;
    p.given = true;
    if (j.contains("mesh") && j.contains("shape")) {
      Fail(key, "give at most one of \"mesh\" (a file) or \"shape\"");
    }
    if (j.contains("mesh")) p.mesh_path = MeshPath(j["mesh"], key + ".mesh");
    if (j.contains("shape")) p.shape = Shape(j["shape"], key + ".shape");
    auto get = [&](const char* name, const Range& range) {
      if (!j.contains(name)) return 0.0;
      return InRange(j[name], key + "." + name, range);  // 0: not given, as over the wire
    };
    p.mass = get("mass", kProbeMass);
    p.inertia = get("inertia", kProbeInertia);
    // The override is the probe's inertia per mass (PDg's object norm).
    if (p.inertia > 0 && p.mass == 0) {
      Fail(key + ".inertia", "needs \"mass\" too (the override is inertia / mass)");
    }
    v1::SceneConfig& c = f->config;
    c.set_probe_shape(p.shape);
    c.set_probe_mass(p.mass);
    c.set_probe_inertia(p.inertia);
  }

  void ParseEffects(const Json& j, const std::string& key, v1::SceneConfig* c) {
    if (!j.is_array()) Fail(key, "expected a list of effect names");
    c->set_declared(true);
    for (std::size_t i = 0; i < j.size(); ++i) {
      const std::string k = key + "[" + std::to_string(i) + "]";
      const std::string name = String(j[i], k);
      v1::Effect e;
      if (!EffectFromName(name, &e)) {
        Fail(k, "unknown effect '" + name +
                    "' (expected contact, damping, friction, weight, texture or torque)");
      }
      for (int have : c->effects()) {
        if (have == e) Fail(k, "effect '" + name + "' is listed twice");
      }
      c->add_effects(e);
    }
  }

  SceneFile Parse(const std::string& text) {
    Json j;
    try {
      j = Json::parse(text);
    } catch (const Json::exception& e) {
      throw SceneFileError(path_ + ": not valid JSON (" + e.what() + ")");
    }
    RequireObject(j, "");
    OnlyKeys(j, "",
             {"scene", "description", "mode", "effects", "gravity", "texture", "probe", "bodies"});
    SceneFile f;
    f.path = path_;
    if (j.contains("scene")) f.scene_id = String(j["scene"], "scene");
    if (j.contains("description")) f.description = String(j["description"], "description");
    v1::SceneConfig& c = f.config;
    if (j.contains("mode")) {
      const std::string m = String(j["mode"], "mode");
      if (m == "none") {
        c.set_pd_mode(v1::PD_MODE_NONE);
      } else if (m == "pdt") {
        c.set_pd_mode(v1::PD_MODE_PDT);
      } else if (m == "pdg") {
        c.set_pd_mode(v1::PD_MODE_PDG);
      } else {
        Fail("mode", "unknown PD mode '" + m + "' (expected none, pdt or pdg)");
      }
    }
    if (j.contains("effects")) ParseEffects(j["effects"], "effects", &c);
    // Gravity: -z, unless given.
    std::array<double, 3> g{0, 0, -9.81};
    if (j.contains("gravity")) g = Numbers<3>(j["gravity"], "gravity", "[x, y, z]", &kGravity);
    c.mutable_gravity()->set_x(g[0]);
    c.mutable_gravity()->set_y(g[1]);
    c.mutable_gravity()->set_z(g[2]);
    c.set_texture_amplitude(0.2);
    c.set_texture_frequency(150);
    if (j.contains("texture")) {
      const Json& t = j["texture"];
      RequireObject(t, "texture");
      OnlyKeys(t, "texture", {"amplitude", "frequency"});
      if (t.contains("amplitude")) {
        c.set_texture_amplitude(InRange(t["amplitude"], "texture.amplitude", kTextureAmplitude));
      }
      if (t.contains("frequency")) {
        c.set_texture_frequency(InRange(t["frequency"], "texture.frequency", kTextureFrequency));
      }
    }
    if (j.contains("probe")) ParseProbe(j["probe"], "probe", &f);
    if (j.contains("bodies")) {
      const Json& bs = j["bodies"];
      if (!bs.is_array()) Fail("bodies", "expected a list of bodies");
      for (std::size_t i = 0; i < bs.size(); ++i) {
        f.bodies.push_back(ParseBody(bs[i], "bodies[" + std::to_string(i) + "]"));
      }
    }
    return f;
  }

 private:
  std::string path_;
  std::size_t max_triangles_;
  std::filesystem::path dir_;
};

}  // namespace

SceneFile ParseSceneJson(const std::string& text, const std::string& path,
                         std::size_t max_triangles) {
  return Parser(path, max_triangles).Parse(text);
}

SceneFile ParseSceneFile(const std::string& path, std::size_t max_triangles) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw SceneFileError(path + ": cannot open scene file");
  std::ostringstream ss;
  ss << in.rdbuf();
  return ParseSceneJson(ss.str(), path, max_triangles);
}

std::string CheckSceneConfig(const v1::SceneConfig& c, const std::string& field,
                             std::size_t max_triangles) {
  for (int i = 0; i < c.effects_size(); ++i) {
    const std::string k = field + ".effects[" + std::to_string(i) + "]";
    const int e = c.effects(i);
    if (e == v1::EFFECT_UNSPECIFIED || !v1::Effect_IsValid(e)) return k + ": unknown effect";
    for (int j = 0; j < i; ++j) {
      if (c.effects(j) == e) return k + ": effect listed twice";
    }
  }
  if (!v1::PdMode_IsValid(c.pd_mode())) return field + ".pd_mode: unknown PD mode";
  const v1::Vec3& g = c.gravity();
  for (auto [x, name] : {std::pair{g.x(), "x"}, std::pair{g.y(), "y"}, std::pair{g.z(), "z"}}) {
    if (std::string p = RangeProblem(x, kGravity); !p.empty()) {
      return field + ".gravity." + name + ": " + p;
    }
  }
  const std::tuple<const char*, double, const Range*> ranged[] = {
      {"texture_amplitude", c.texture_amplitude(), &kTextureAmplitude},
      {"texture_frequency", c.texture_frequency(), &kTextureFrequency},
      {"probe_mass", c.probe_mass(), &kProbeMass},
      {"probe_inertia", c.probe_inertia(), &kProbeInertia}};
  for (const auto& [name, v, range] : ranged) {
    if (std::string p = RangeProblem(v, *range); !p.empty()) return field + "." + name + ": " + p;
  }
  if (c.probe_inertia() > 0 && !(c.probe_mass() > 0)) {
    return field + ".probe_inertia: needs probe_mass > 0 (the override is inertia / mass)";
  }
  if (!c.probe_shape().empty()) {
    if (grpc::Status s = CheckShapeSpec(c.probe_shape(), field + ".probe_shape", max_triangles);
        !s.ok()) {
      return s.error_message();
    }
  }
  return {};
}

const char* EffectName(v1::Effect e) {
  for (const Effects& x : kEffects) {
    if (x.effect == e) return x.name;
  }
  return "?";
}

bool EffectFromName(std::string_view name, v1::Effect* out) {
  for (const Effects& x : kEffects) {
    if (name == x.name) {
      *out = x.effect;
      return true;
    }
  }
  return false;
}

const char* PdModeName(v1::PdMode m) {
  switch (m) {
    case v1::PD_MODE_NONE:
      return "none";
    case v1::PD_MODE_PDT:
      return "pdt";
    case v1::PD_MODE_PDG:
      return "pdg";
    default:
      return "?";
  }
}

bool SceneHasEffect(const v1::SceneConfig& c, v1::Effect e) {
  if (!c.declared()) return e == v1::EFFECT_CONTACT || e == v1::EFFECT_TORQUE;
  for (int have : c.effects()) {
    if (have == e) return true;
  }
  return false;
}

}  // namespace hapticpd::wire
