#include "server/scene_file.h"

#include <nlohmann/json.hpp>

#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <sstream>

#include "pd/material.h"

namespace hapticpd::server {

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
  Parser(std::string path) : path_(std::move(path)) {
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
    const double v = j.get<double>();
    if (!std::isfinite(v)) Fail(key, "must be finite");
    return v;
  }

  double NonNegative(const Json& j, const std::string& key) const {
    const double v = Number(j, key);
    if (v < 0) Fail(key, "must be >= 0 (got " + Format(v) + ")");
    return v;
  }

  template <std::size_t N>
  std::array<double, N> Numbers(const Json& j, const std::string& key, const char* shape) const {
    if (!j.is_array() || j.size() != N) Fail(key, std::string("expected ") + shape);
    std::array<double, N> out{};
    for (std::size_t i = 0; i < N; ++i) out[i] = Number(j[i], key + "[" + std::to_string(i) + "]");
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
      const auto a = Numbers<3>(j["position"], key + ".position", "[x, y, z]");
      p.mutable_position()->set_x(a[0]);
      p.mutable_position()->set_y(a[1]);
      p.mutable_position()->set_z(a[2]);
    }
    if (j.contains("orientation")) {
      const auto a = Numbers<4>(j["orientation"], key + ".orientation", "[w, x, y, z]");
      auto* q = p.mutable_orientation();
      q->set_w(a[0]);
      q->set_x(a[1]);
      q->set_y(a[2]);
      q->set_z(a[3]);
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
      return j.contains(name) ? NonNegative(j[name], key + "." + name) : def;
    };
    v1::Material m;
    m.set_stiffness(get("stiffness", d.stiffness));
    m.set_rotational_stiffness(get("rotational_stiffness", d.rotational_stiffness));
    m.set_damping(get("damping", d.damping));
    m.set_static_friction(get("static_friction", d.static_friction));
    m.set_dynamic_friction(get("dynamic_friction", d.dynamic_friction));
    if (m.dynamic_friction() > m.static_friction()) {
      Fail(key + ".dynamic_friction", "must not exceed static_friction (" +
                                          Format(m.dynamic_friction()) + " > " +
                                          Format(m.static_friction()) + ")");
    }
    return m;
  }

  SceneFileBody ParseBody(const Json& b, const std::string& key) {
    RequireObject(b, key);
    OnlyKeys(b, key, {"id", "label", "mesh", "shape", "pose", "material", "movable"});
    SceneFileBody out;
    if (b.contains("mesh") == b.contains("shape")) {
      Fail(key, "give exactly one of \"mesh\" (a file) or \"shape\"");
    }
    if (b.contains("mesh")) {
      out.mesh_path = MeshPath(b["mesh"], key + ".mesh");
    } else {
      out.shape = String(b["shape"], key + ".shape");
    }
    v1::BodySpec& spec = out.spec;
    if (b.contains("id")) spec.set_body_id(String(b["id"], key + ".id"));
    spec.set_label(b.contains("label")  ? String(b["label"], key + ".label")
                   : b.contains("mesh") ? b["mesh"].get<std::string>()
                                        : out.shape);
    if (b.contains("movable")) spec.set_movable(Bool(b["movable"], key + ".movable"));
    if (b.contains("pose")) *spec.mutable_pose() = ParsePose(b["pose"], key + ".pose");
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
    if (j.contains("shape")) p.shape = String(j["shape"], key + ".shape");
    auto positive = [&](const char* name) {
      if (!j.contains(name)) return 0.0;
      const double v = NonNegative(j[name], key + "." + name);
      if (v == 0) Fail(key + "." + name, "must be > 0");
      return v;
    };
    p.mass = positive("mass");
    p.inertia = positive("inertia");
    // The override is the probe's inertia per mass (PDg's object norm).
    if (p.inertia > 0 && p.mass == 0) {
      Fail(key + ".inertia", "needs \"mass\" too (the override is inertia / mass)");
    }
    if (p.inertia > 0 && !std::isfinite(p.inertia / p.mass)) {
      Fail(key + ".inertia", "inertia / mass is not finite");
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
    if (j.contains("gravity")) g = Numbers<3>(j["gravity"], "gravity", "[x, y, z]");
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
        c.set_texture_amplitude(NonNegative(t["amplitude"], "texture.amplitude"));
      }
      if (t.contains("frequency")) {
        const double hz = NonNegative(t["frequency"], "texture.frequency");
        // Above half the 1 kHz servo rate a vibration aliases.
        if (hz <= 0 || hz > 500) Fail("texture.frequency", "must be in (0, 500] Hz");
        c.set_texture_frequency(hz);
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

  static std::string Format(double v) {
    std::ostringstream s;
    s << v;
    return s.str();
  }

 private:
  std::string path_;
  std::filesystem::path dir_;
};

}  // namespace

SceneFile ParseSceneJson(const std::string& text, const std::string& path) {
  return Parser(path).Parse(text);
}

SceneFile ParseSceneFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw SceneFileError(path + ": cannot open scene file");
  std::ostringstream ss;
  ss << in.rdbuf();
  return ParseSceneJson(ss.str(), path);
}

std::string CheckSceneConfig(const v1::SceneConfig& c, const std::string& field) {
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
  if (!std::isfinite(g.x()) || !std::isfinite(g.y()) || !std::isfinite(g.z())) {
    return field + ".gravity: must be finite";
  }
  const std::pair<const char*, double> nonneg[] = {{"texture_amplitude", c.texture_amplitude()},
                                                   {"texture_frequency", c.texture_frequency()},
                                                   {"probe_mass", c.probe_mass()},
                                                   {"probe_inertia", c.probe_inertia()}};
  for (const auto& [name, v] : nonneg) {
    if (!std::isfinite(v) || v < 0) return field + "." + name + ": must be finite and >= 0";
  }
  if (c.texture_frequency() > 500) return field + ".texture_frequency: must be <= 500 Hz";
  if (c.probe_inertia() > 0 && !(c.probe_mass() > 0)) {
    return field + ".probe_inertia: needs probe_mass > 0 (the override is inertia / mass)";
  }
  if (c.probe_inertia() > 0 && !std::isfinite(c.probe_inertia() / c.probe_mass())) {
    return field + ".probe_inertia: probe_inertia / probe_mass is not finite";
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

}  // namespace hapticpd::server
