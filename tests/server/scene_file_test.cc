// The JSON scene-file parser (server/scene_file.h) and what the server does
// with a scene's declared effects: stores them (CreateScene, GetScene,
// ListScenes, scene files), sends them in the Welcome, skips torque terms
// for a scene without torque, never runs PD in mode none, and weighs PDg's
// rotations by the scene's probe inertia override.
#include "server/scene_file.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>

#include "server/server.h"
#include "tests/readme_table.h"
#include "tests/server/server_harness.h"

namespace hapticpd::testing {
namespace {

namespace fs = std::filesystem;

class SceneFileParse : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("hapticpd_scenefile_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    std::ofstream(dir_ / "tet.obj")
        << "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string Write(const std::string& name, const std::string& text) {
    std::ofstream(dir_ / name) << text;
    return (dir_ / name).string();
  }

  /// The error message of parsing `text`, or "" when it parsed.
  std::string Error(const std::string& text) {
    const std::string path = Write("bad.json", text);
    try {
      server::ParseSceneFile(path);
    } catch (const server::SceneFileError& e) {
      const std::string what = e.what();
      EXPECT_EQ(what.rfind(path + ": ", 0), 0u) << "names the file: " << what;
      return what.substr(path.size() + 2);
    }
    return "";
  }

  fs::path dir_;
};

TEST_F(SceneFileParse, FullFile) {
  const std::string path = Write("full.json", R"({
    "scene": "desk", "description": "a pen on a desk", "mode": "pdg",
    "effects": ["contact", "friction", "damping", "weight", "texture", "torque"],
    "gravity": [0, 0, -9.8], "texture": {"amplitude": 0.1, "frequency": 80},
    "probe": {"shape": "stick", "mass": 0.02, "inertia": 1e-6},
    "bodies": [
      {"id": "tet", "mesh": "tet.obj", "movable": true,
       "pose": {"position": [0, 0, 1], "orientation": [0, 0, 0, 1]},
       "material": {"stiffness": 2500, "rotational_stiffness": 0.1, "damping": 3,
                    "static_friction": 0.6, "dynamic_friction": 0.4}},
      {"id": "floor", "shape": "plate:1,1,0.01"}]})");
  const server::SceneFile f = server::ParseSceneFile(path);
  EXPECT_EQ(f.scene_id, "desk");
  EXPECT_EQ(f.description, "a pen on a desk");
  const v1::SceneConfig& c = f.config;
  EXPECT_TRUE(c.declared());
  EXPECT_EQ(c.pd_mode(), v1::PD_MODE_PDG);
  ASSERT_EQ(c.effects_size(), 6);
  EXPECT_EQ(c.effects(0), v1::EFFECT_CONTACT);
  EXPECT_EQ(c.effects(5), v1::EFFECT_TORQUE);
  EXPECT_DOUBLE_EQ(c.gravity().z(), -9.8);
  EXPECT_DOUBLE_EQ(c.texture_amplitude(), 0.1);
  EXPECT_DOUBLE_EQ(c.texture_frequency(), 80);
  EXPECT_EQ(c.probe_shape(), "stick");
  EXPECT_DOUBLE_EQ(c.probe_mass(), 0.02);
  EXPECT_DOUBLE_EQ(c.probe_inertia(), 1e-6);
  ASSERT_EQ(f.bodies.size(), 2u);
  EXPECT_EQ(f.bodies[0].mesh_path, (dir_ / "tet.obj").string());
  EXPECT_TRUE(f.bodies[0].spec.movable());
  EXPECT_DOUBLE_EQ(f.bodies[0].spec.material().dynamic_friction(), 0.4);
  EXPECT_DOUBLE_EQ(f.bodies[0].spec.material().damping(), 3);
  EXPECT_DOUBLE_EQ(f.bodies[0].spec.pose().orientation().z(), 1);
  EXPECT_EQ(f.bodies[1].shape, "plate:1,1,0.01");
  EXPECT_FALSE(f.bodies[1].spec.has_material());
}

TEST_F(SceneFileParse, MinimalFileIsALegacyScene) {
  const server::SceneFile f =
      server::ParseSceneFile(Write("min.json", R"({"bodies": [{"shape": "box"}]})"));
  EXPECT_EQ(f.scene_id, "default");
  EXPECT_FALSE(f.config.declared());
  EXPECT_EQ(f.config.pd_mode(), v1::PD_MODE_UNSPECIFIED);
  EXPECT_TRUE(server::SceneHasEffect(f.config, v1::EFFECT_CONTACT));
  EXPECT_TRUE(server::SceneHasEffect(f.config, v1::EFFECT_TORQUE));
  EXPECT_FALSE(server::SceneHasEffect(f.config, v1::EFFECT_FRICTION));
  EXPECT_FALSE(f.probe.given);
}

TEST_F(SceneFileParse, CommittedScenesParse) {
  for (const auto& e : fs::directory_iterator(fs::path(HAPTICPD_TESTDATA_DIR) / "scenes")) {
    if (e.path().extension() != ".json") continue;
    SCOPED_TRACE(e.path().string());
    EXPECT_NO_THROW(server::ParseSceneFile(e.path().string()));
  }
}

// A case with a `readme` description is a row of tests/README.md "Bad
// input", "Scene files": its message is checked whole ("…" stands for text
// the check skips), and HAPTICPD_PRINT_TABLE=1 prints it as the row
// (tests/update_tables.py); the others are checked up to their length.
TEST_F(SceneFileParse, BadFilesNameKeyAndFile) {
  struct Case {
    const char* text;
    const char* expect;            // the message after "FILE: "
    const char* readme = nullptr;  // the bad input, for a README row
  };
  const Case cases[] = {
      // unknown keys, at every level
      {R"({"scenes": "x"})", "scenes: unknown key"},
      {R"({"bodies": [{"shape": "box", "colour": 1}]})",
       "bodies[0].colour: unknown key (expected one of: id, label, mesh, shape, pose, material, "
       "movable, velocity)",
       "unknown key"},
      {R"({"bodies": [{"shape": "box", "material": {"stifness": 1}}]})",
       "bodies[0].material.stifness: unknown key"},
      {R"({"probe": {"shape": "stick", "weight": 1}})", "probe.weight: unknown key"},
      {R"({"bodies": [{"shape": "box", "pose": {"positon": [0, 0, 0]}}]})",
       "bodies[0].pose.positon: unknown key"},
      // wrong types
      {R"({"scene": 3})", "scene: expected a string"},
      {R"({"bodies": {"shape": "box"}})", "bodies: expected a list"},
      {R"({"bodies": [{"shape": "box", "movable": "yes"}]})", "bodies[0].movable: expected true"},
      {R"({"bodies": [{"shape": "box", "material": {"stiffness": "hard"}}]})",
       "bodies[0].material.stiffness: expected a number"},
      {R"({"bodies": [{"shape": "box", "pose": {"position": [0, 0]}}]})",
       "bodies[0].pose.position: expected [x, y, z]"},
      {R"({"effects": "contact"})", "effects: expected a list"},
      // invalid values
      {R"({"bodies": [{"shape": "box", "material": {"stiffness": -5}}]})",
       "bodies[0].material.stiffness: must be in [0, 1e+07] N/m, got -5", "value out of its range"},
      {R"({"bodies": [{"shape": "box", "material": {"stiffness": 1e9}}]})",
       "bodies[0].material.stiffness: must be in [0, 1e+07] N/m, got 1e+09"},
      {R"({"bodies": [{"shape": "box", "pose": {"position": [0, 2e4, 0]}}]})",
       "bodies[0].pose.position[1]: must be in [-10000, 10000] m, got 20000"},
      {R"({"bodies": [{"shape": "box", "pose": {"orientation": [2, 0, 0, 0]}}]})",
       "bodies[0].pose.orientation: quaternion norm 2.000000 is not 1"},
      {R"({"bodies": [{"shape": "sphere:1e-300"}]})",
       "bodies[0].shape: shape spec 'sphere:1e-300': radius must be in [1e-06, 10000] m, got "
       "1e-300"},
      {R"({"bodies": [{"shape": "stick "}]})",
       "bodies[0].shape: shape spec 'stick ': whitespace is not allowed in a shape spec (at byte "
       "5)"},
      {R"({"bodies": [{"shape": "box:0.1"}]})",
       "bodies[0].shape: shape spec 'box:0.1': 'box' needs all of hx,hy,hz or none (for the "
       "defaults); missing hy,hz",
       "malformed shape spec"},
      {R"({"bodies": [{"shape": "box:0.1,0.1,0.1,1000000"}]})",
       "bodies[0].shape: 12000000000000 triangles exceed the server limit of 2000000"},
      {R"({"probe": {"shape": "teapot"}})", "probe.shape: shape spec 'teapot': unknown shape"},
      {R"({"gravity": [0, 0, -1000]})", "gravity[2]: must be in [-100, 100] m/s^2, got -1000"},
      {R"({"texture": {"amplitude": 11}})", "texture.amplitude: must be in [0, 10] N, got 11"},
      {R"({"bodies": [{"shape": "box", "material": {"static_friction": 0.2,
          "dynamic_friction": 0.5}}]})",
       "bodies[0].material.dynamic_friction: must not exceed static_friction (0.5 > 0.2)",
       "dynamic friction above static"},
      {R"({"probe": {"shape": "stick", "mass": -1}})",
       "probe.mass: must be 0 (not given) or in [1e-06, 1000] kg, got -1"},
      {R"({"probe": {"shape": "stick", "mass": 1, "inertia": 1e4}})",
       "probe.inertia: must be 0 (not given) or in [1e-12, 1000] kg m^2, got 10000"},
      {R"({"probe": {"shape": "stick", "inertia": 1e-6}})", "probe.inertia: needs \"mass\""},
      {R"({"texture": {"frequency": 2000}})",
       "texture.frequency: must be in [0, 500] Hz, got 2000"},
      {R"({"mode": "pdx"})", "mode: unknown PD mode 'pdx' (expected none, pdt or pdg)",
       "unknown PD mode"},
      {R"({"effects": ["contact", "frication"]})",
       "effects[1]: unknown effect 'frication' (expected contact, damping, friction, weight, "
       "texture or torque)",
       "unknown effect"},
      {R"({"effects": ["contact", "contact"]})", "effects[1]: effect 'contact' is listed twice"},
      // missing files and shapes
      {R"({"bodies": [{"id": "a", "mesh": "nope.obj"}]})", "bodies[0].mesh: mesh file '"},
      {R"({"bodies": [{"id": "a", "mesh": "/nonexistent/nope.obj"}]})",
       "bodies[0].mesh: mesh file '/nonexistent/nope.obj' not found", "missing mesh file"},
      {R"({"probe": {"mesh": "nope.obj"}})", "probe.mesh: mesh file '"},
      {R"({"bodies": [{"id": "a"}]})", "bodies[0]: give exactly one of"},
      {R"({"bodies": [{"mesh": "tet.obj", "shape": "box"}]})", "bodies[0]: give exactly one of"},
      // not JSON at all
      {R"({"bodies": [)", "not valid JSON"},
      {"{\"bodies\": [\n",
       "not valid JSON ([json.exception.parse_error.101] parse error at line 2, column 1: …)",
       "not JSON"},
  };
  for (const Case& c : cases) {
    const std::string e = Error(c.text);
    if (c.readme == nullptr) {
      EXPECT_EQ(e.rfind(c.expect, 0), 0u) << c.text << "\n  gave: " << e;
      continue;
    }
    EXPECT_TRUE(MessageMatches(e, c.expect)) << c.text << "\n  gave: " << e;
    PrintTableRow({c.readme}, c.expect);
  }
}

// --- The server with declared effects ----------------------------------------

server::ServerOptions InProcess(std::vector<std::string> files = {}) {
  server::ServerOptions o;
  o.listen = "";
  o.status_interval_s = 0;
  o.scene_files = std::move(files);
  return o;
}

/// Poses a sphere probe into a box at the origin until an answer with
/// contact arrives; returns it.
std::optional<v1::ContactUpdate> PressIntoBox(Session& s) {
  for (std::uint64_t seq = 1; seq < 200; ++seq) {
    s.Send(seq, MakePose(0.02, 0.01, 0.045));  // touches the box's top face off-centre
    auto u = s.Next();
    if (!u) return std::nullopt;
    if (u->rows_size() > 0) return u;
  }
  return std::nullopt;
}

TEST_F(SceneFileParse, ServerStoresAndSendsTheConfig) {
  const std::string path = Write("fx.json", R"({"scene": "fx", "mode": "pdt",
    "effects": ["contact", "friction"],
    "bodies": [{"id": "box", "shape": "box:0.1,0.1,0.05",
                "material": {"static_friction": 0.7, "dynamic_friction": 0.5, "damping": 2}}]})");
  ServerHarness h(Transport::kInProcess, InProcess({path}));
  auto scenes = h.Scenes();
  const v1::Scene scene = GetScene(*scenes, "fx");
  EXPECT_TRUE(scene.config().declared());
  EXPECT_EQ(scene.config().effects_size(), 2);
  EXPECT_EQ(scene.config().pd_mode(), v1::PD_MODE_PDT);

  auto haptics = h.Haptics();
  Session s(*haptics);
  // A hello without a mode gets the scene's.
  ASSERT_TRUE(s.Open(Session::DefaultHello("fx", v1::PD_MODE_UNSPECIFIED)).ok());
  EXPECT_EQ(s.welcome().mode(), v1::PD_MODE_PDT);
  EXPECT_EQ(s.welcome().scene_config().effects(1), v1::EFFECT_FRICTION);
  const auto u = PressIntoBox(s);
  ASSERT_TRUE(u);
  // No torque declared: the rows are pure forces and the answer has no torque.
  for (const v1::ContactRow& r : u->rows()) {
    EXPECT_FALSE(r.has_moment());
    EXPECT_DOUBLE_EQ(r.static_friction(), 0.7);  // the material, for client-side friction
    EXPECT_DOUBLE_EQ(r.dynamic_friction(), 0.5);
    EXPECT_DOUBLE_EQ(r.damping(), 2);
  }
  EXPECT_FALSE(u->has_torque());
  EXPECT_GT(h.server().counts().pd_calls, 0u);
  EXPECT_EQ(h.server().counts().torque_skipped, h.server().counts().pd_calls);
}

TEST_F(SceneFileParse, LegacySceneKeepsTorque) {
  ServerHarness h(Transport::kInProcess, InProcess());
  auto scenes = h.Scenes();
  ASSERT_TRUE(AddShape(*scenes, "default", "box:0.1,0.1,0.05", "box", MakePose(0, 0, 0)).ok());
  auto haptics = h.Haptics();
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello("default", v1::PD_MODE_PDT)).ok());
  EXPECT_FALSE(s.welcome().scene_config().declared());
  const auto u = PressIntoBox(s);
  ASSERT_TRUE(u);
  bool any_moment = false;
  for (const v1::ContactRow& r : u->rows()) any_moment = any_moment || r.has_moment();
  EXPECT_TRUE(any_moment);
  EXPECT_EQ(h.server().counts().torque_skipped, 0u);
}

TEST_F(SceneFileParse, ModeNoneNeverCallsPd) {
  const std::string path = Write("none.json", R"({"scene": "none", "mode": "none",
    "effects": ["contact", "torque"], "bodies": [{"id": "box", "shape": "box:0.1,0.1,0.05"}]})");
  ServerHarness h(Transport::kInProcess, InProcess({path}));
  auto haptics = h.Haptics();
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello("none", v1::PD_MODE_UNSPECIFIED)).ok());
  EXPECT_EQ(s.welcome().mode(), v1::PD_MODE_NONE);
  for (std::uint64_t seq = 1; seq <= 20; ++seq) {
    s.Send(seq, MakePose(0, 0, 0.04));  // deep inside the box
    const auto u = s.Next();
    ASSERT_TRUE(u);
    EXPECT_EQ(u->status(), v1::CONTACT_STATUS_NONE);
    EXPECT_EQ(u->rows_size(), 0);
  }
  EXPECT_EQ(h.server().counts().pd_calls, 0u);
  // The counter does count: a PDt session on the same scene runs PD.
  Session pdt(*haptics);
  ASSERT_TRUE(pdt.Open(Session::DefaultHello("none", v1::PD_MODE_PDT)).ok());
  pdt.Send(1, MakePose(0, 0, 0.04));
  ASSERT_TRUE(pdt.Next());
  EXPECT_GT(h.server().counts().pd_calls, 0u);
}

TEST_F(SceneFileParse, WeightOnlySceneNeedsNoPd) {
  const std::string path = Write("w.json", R"({"scene": "w", "mode": "pdt",
    "effects": ["weight"], "bodies": [{"id": "box", "shape": "box:0.1,0.1,0.05"}]})");
  ServerHarness h(Transport::kInProcess, InProcess({path}));
  auto haptics = h.Haptics();
  Session s(*haptics);
  ASSERT_TRUE(s.Open(Session::DefaultHello("w", v1::PD_MODE_PDT)).ok());
  for (std::uint64_t seq = 1; seq <= 5; ++seq) {
    s.Send(seq, MakePose(0, 0, 0.04));
    ASSERT_TRUE(s.Next());
  }
  EXPECT_EQ(h.server().counts().pd_calls, 0u);
}

TEST_F(SceneFileParse, CreateSceneStoresAndValidatesTheConfig) {
  ServerHarness h(Transport::kInProcess, InProcess());
  auto scenes = h.Scenes();
  v1::CreateSceneRequest req;
  req.set_scene_id("pen");
  req.mutable_config()->set_declared(true);
  req.mutable_config()->add_effects(v1::EFFECT_CONTACT);
  req.mutable_config()->add_effects(v1::EFFECT_WEIGHT);
  req.mutable_config()->set_pd_mode(v1::PD_MODE_PDT);
  v1::SceneSummary sum;
  auto ctx = Ctx();
  ASSERT_TRUE(scenes->CreateScene(ctx.get(), req, &sum).ok());
  EXPECT_EQ(sum.config().effects_size(), 2);
  EXPECT_EQ(GetScene(*scenes, "pen").config().effects(1), v1::EFFECT_WEIGHT);
  v1::ListScenesResponse list;
  auto ctx2 = Ctx();
  ASSERT_TRUE(scenes->ListScenes(ctx2.get(), {}, &list).ok());
  bool found = false;
  for (const auto& s : list.scenes())
    found = found || (s.scene_id() == "pen" && s.config().declared());
  EXPECT_TRUE(found);

  req.set_scene_id("bad");
  req.mutable_config()->add_effects(v1::EFFECT_WEIGHT);  // twice
  auto ctx3 = Ctx();
  const grpc::Status st = scenes->CreateScene(ctx3.get(), req, &sum);
  EXPECT_EQ(st.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(st.error_message().rfind("config.effects[2]", 0), 0u) << st.error_message();

  // An inertia override needs the mass it is relative to.
  v1::CreateSceneRequest no_mass;
  no_mass.set_scene_id("no_mass");
  no_mass.mutable_config()->set_probe_inertia(1e-6);
  auto ctx4 = Ctx();
  const grpc::Status st2 = scenes->CreateScene(ctx4.get(), no_mass, &sum);
  EXPECT_EQ(st2.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(st2.error_message().rfind("config.probe_inertia: needs probe_mass", 0), 0u)
      << st2.error_message();
}

/// The PDg answer of a session on `scene` for a 20 cm stick (1 cm square)
/// standing in a 2 cm slot, tilted 0.1 rad about y, its lower end 2 mm into
/// the left wall: pivoting out is cheaper than translating (as in
/// tests/pd/pdg_test.cc).
std::optional<v1::ContactUpdate> StickInSlot(v1::HapticService::Stub& haptics,
                                             const std::string& scene) {
  Session s(haptics);
  if (!s.Open(Session::DefaultHello(scene, v1::PD_MODE_PDG, "box:0.005,0.005,0.1")).ok()) {
    return std::nullopt;
  }
  const double tilt = 0.1;
  const double corner_x = -0.005 * std::cos(tilt) - 0.1 * std::sin(tilt);
  s.Send(1, MakePose(-0.002 - corner_x, 0, 0.02, std::cos(tilt / 2), 0, std::sin(tilt / 2), 0));
  return s.Next();
}

TEST_F(SceneFileParse, ProbeInertiaOverrideWeighsPdgRotations) {
  // The same scene twice, the second with a probe whose inertia per mass is
  // ten times the uniform stick's largest (I/m = (0.1^2 + 0.005^2) / 3 m^2):
  // PDg turns it much less.
  const char* bodies = R"("bodies": [
      {"id": "left", "shape": "box:0.05,0.1,0.05", "pose": {"position": [-0.05, 0, -0.05]}},
      {"id": "right", "shape": "box:0.05,0.1,0.05", "pose": {"position": [0.07, 0, -0.05]}}]})";
  const double i_over_m = 10 * (0.1 * 0.1 + 0.005 * 0.005) / 3;
  const std::string plain = Write("plain.json", std::string(R"({"scene": "plain", "mode": "pdg",
    "effects": ["contact", "torque"], "probe": {"shape": "box:0.005,0.005,0.1", "mass": 0.02},)") +
                                                    bodies);
  const std::string heavy =
      Write("heavy.json",
            std::string(R"({"scene": "heavy", "mode": "pdg", "effects": ["contact", "torque"],
    "probe": {"shape": "box:0.005,0.005,0.1", "mass": 0.02, "inertia": )") +
                std::to_string(0.02 * i_over_m) + "}," + bodies);
  ServerHarness h(Transport::kInProcess, InProcess({plain, heavy}));
  auto haptics = h.Haptics();
  const auto a = StickInSlot(*haptics, "plain");
  const auto b = StickInSlot(*haptics, "heavy");
  ASSERT_TRUE(a && b);
  ASSERT_EQ(a->status(), v1::CONTACT_STATUS_PENETRATING);
  ASSERT_EQ(b->status(), v1::CONTACT_STATUS_PENETRATING);
  std::cout << "[ inertia override ] rotation " << a->rotation_angle() << " rad -> "
            << b->rotation_angle() << " rad, sigma " << a->sigma() << " -> " << b->sigma()
            << " m^2\n";
  EXPECT_GT(a->rotation_angle(), 1e-3);
  EXPECT_LT(b->rotation_angle(), 0.5 * a->rotation_angle());
  EXPECT_GT(b->sigma(), a->sigma());
  // Both still push the stick's lower end out of the left wall (+x).
  EXPECT_GT(a->force().x(), 0);
  EXPECT_GT(b->force().x(), 0);
}

}  // namespace
}  // namespace hapticpd::testing
