// The JSON scene-file format (README "Scene files"), parsed in one place for
// `hapticpd serve --scene`, `hapticpd demo --scene` and the tests:
//
//   {"scene": ID, "description": TEXT, "mode": "none"|"pdt"|"pdg",
//    "effects": ["contact", "torque", "damping", "friction", "weight", "texture"],
//    "gravity": [x, y, z], "texture": {"amplitude": N, "frequency": HZ},
//    "probe": {"shape": SPEC | "mesh": FILE, "mass": KG, "inertia": KG_M2},
//    "bodies": [{"id": ID, "label": TEXT, "mesh": FILE | "shape": SPEC,
//                "pose": {"position": [x, y, z], "orientation": [w, x, y, z]},
//                "material": {"stiffness": K, "rotational_stiffness": XI, "damping": B,
//                             "static_friction": MU_S, "dynamic_friction": MU_D},
//                "movable": BOOL,
//                "velocity": {"linear": [x, y, z], "angular": [x, y, z]}}]}
//
// Every key is optional except a body's mesh or shape. Unknown keys, wrong
// types and invalid values (a number outside its range of ranges.h, a
// malformed shape spec, a missing mesh file, an unknown effect or mode) are
// errors: SceneFileError, whose message is "FILE: KEY: problem" (KEY a path
// such as bodies[1].material.stiffness). The checks are the RPCs' own
// (convert.h, ranges.h), so a scene file accepts exactly what CreateScene and
// AddBody accept. Mesh paths are relative to the scene file's folder.
#pragma once

#include <cstddef>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "hapticpd/v1/haptic.pb.h"
#include "hapticpd/v1/scene.pb.h"

namespace hapticpd::wire {

class SceneFileError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct SceneFileBody {
  v1::BodySpec spec;      ///< id, label, pose, material, movable, velocity
  std::string mesh_path;  ///< resolved mesh file (empty for a shape)
  std::string shape;      ///< procedural shape spec (empty for a mesh)
};

struct SceneFileProbe {
  bool given = false;
  std::string shape;      ///< procedural shape spec, or
  std::string mesh_path;  ///< resolved mesh file
  double mass = 0;        ///< kg; 0: not given
  /// kg m^2 (isotropic, about the centre of mass); 0: not given. Needs
  /// `mass`: PDg's object norm then weighs rotations by 4 inertia / mass
  /// instead of the mesh's uniform-solid inertia (PdgMetricDiagonal).
  double inertia = 0;
};

struct SceneFile {
  std::string path;
  std::string scene_id = "default";
  std::string description;
  std::vector<SceneFileBody> bodies;
  SceneFileProbe probe;
  /// Declared effects (declared = the file has "effects"), PD mode, gravity,
  /// texture and probe parameters: what SceneService stores with the scene.
  v1::SceneConfig config;
};

/// Triangle limit of a shape checked without a server's own limit (the
/// server checks its --max-triangles again when it builds the shape).
inline constexpr std::size_t kDefaultMaxShapeTriangles = 2'000'000;

/// Reads and validates a scene file; shapes (bodies and probe) are checked
/// against `max_triangles` without being built. Throws SceneFileError.
SceneFile ParseSceneFile(const std::string& path,
                         std::size_t max_triangles = kDefaultMaxShapeTriangles);
/// The same from text; `path` names the file in errors and anchors relative
/// mesh paths.
SceneFile ParseSceneJson(const std::string& text, const std::string& path,
                         std::size_t max_triangles = kDefaultMaxShapeTriangles);

/// Checks a SceneConfig received over the wire (CreateSceneRequest): known,
/// distinct effects, a known PD mode, gravity in kGravity per component,
/// texture amplitude and frequency in kTextureAmplitude / kTextureFrequency,
/// probe_mass and probe_inertia in kProbeMass / kProbeInertia (0: not given;
/// inertia needs a mass), probe_shape empty or a valid shape spec within
/// `max_triangles` (CheckShapeSpec). Returns "" or "FIELD.sub: problem".
std::string CheckSceneConfig(const v1::SceneConfig& c, const std::string& field,
                             std::size_t max_triangles = kDefaultMaxShapeTriangles);

/// "contact", "damping", ... ("?" for an unknown value).
const char* EffectName(v1::Effect e);
/// Parses an effect name; false when unknown.
bool EffectFromName(std::string_view name, v1::Effect* out);
/// "none", "pdt", "pdg" ("?" otherwise).
const char* PdModeName(v1::PdMode m);
/// Whether a scene config lets `e` run: a config that declares nothing
/// (legacy scenes) means contact and torque.
bool SceneHasEffect(const v1::SceneConfig& c, v1::Effect e);

}  // namespace hapticpd::wire
