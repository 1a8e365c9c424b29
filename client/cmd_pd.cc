// `hapticpd pd --probe A --scene B [--scene C ...] --pose "..." [--mode pdt|pdg]`:
// penetration depth of a probe against one or more scene bodies, one PD query
// per body, and the combined wrench on the probe (penalty wrench for PDt,
// spring to the answer pose for PDg).
#include <nlohmann/json.hpp>

#include <array>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <iomanip>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "client/commands.h"
#include "pd/geometry_model.h"
#include "pd/material.h"
#include "pd/mesh.h"
#include "pd/pdg.h"
#include "pd/pdt.h"
#include "pd/penetration.h"
#include "pd/shapes.h"

namespace hapticpd::cli {
namespace {

constexpr char kShapePrefix[] = "shape:";

struct PdOptions {
  std::string probe;
  std::vector<std::string> scenes;
  std::string pose;
  std::vector<std::string> scene_poses;
  std::string mode = "pdt";
  bool json = false;
  // Numbers are parsed here rather than by CLI11 so that every bad value gets
  // the same one-line error.
  std::string stiffness = "1000";
  std::string rotational_stiffness = "0.05";
  std::string epsilon;
  std::string max_iterations;
  std::string pdg_budget = "0";
  std::string cold_directions = std::to_string(pd::kColdSearchDirections);
};

std::string Fmt(double x) {
  std::ostringstream os;
  os << std::setprecision(9) << x;
  return os.str();
}

/// Parses a whole token as a double (strtod syntax, which also accepts
/// nan/inf: the caller checks finiteness so it can say which value it was).
bool ParseDouble(const std::string& token, double* x) {
  if (token.empty()) return false;
  char* end = nullptr;
  errno = 0;
  *x = std::strtod(token.c_str(), &end);
  return end == token.c_str() + token.size();
}

double ParsePositive(const std::string& option, const std::string& text) {
  double x = 0;
  if (!ParseDouble(text, &x)) throw CommandError(option + ": '" + text + "' is not a number");
  if (!std::isfinite(x) || x <= 0) {
    throw CommandError(option + ": must be a positive finite number, got " + text);
  }
  return x;
}

int ParsePositiveInt(const std::string& option, const std::string& text) {
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || end != text.c_str() + text.size() || errno == ERANGE || v <= 0 ||
      v > 1'000'000) {
    throw CommandError(option + ": must be a positive integer (at most 1000000), got '" + text +
                       "'");
  }
  return static_cast<int>(v);
}

std::uint64_t ParseBudget(const std::string& option, const std::string& text) {
  char* end = nullptr;
  errno = 0;
  const long long v = std::strtoll(text.c_str(), &end, 10);
  if (text.empty() || end != text.c_str() + text.size() || errno == ERANGE || v < 0 ||
      v > 1'000'000'000'000LL) {
    throw CommandError(option + ": must be a non-negative integer (0 for no budget), got '" + text +
                       "'");
  }
  return static_cast<std::uint64_t>(v);
}

/// "tx ty tz qw qx qy qz" (ParseNumbers: spaces, commas or both): a world
/// pose, translation in metres and a unit quaternion (IsUnitQuaternion: a
/// norm within 1e-3 of 1 is normalised; any other is an error, which
/// usually means the numbers are in the wrong order).
Pose ParsePose(const std::string& option, const std::string& text) {
  static constexpr const char* kNames[7] = {"tx", "ty", "tz", "qw", "qx", "qy", "qz"};
  const std::vector<double> v = ParseNumbers(text, option);
  if (v.size() != 7) {
    throw CommandError(option + ": expected 7 numbers \"tx ty tz qw qx qy qz\", got " +
                       std::to_string(v.size()));
  }
  for (int i = 0; i < 7; ++i) {
    if (!std::isfinite(v[i])) {
      throw CommandError(option + ": " + kNames[i] + " is " + Fmt(v[i]) +
                         ", expected a finite number");
    }
  }
  const Quat q(v[3], v[4], v[5], v[6]);
  if (!IsUnitQuaternion(q)) {
    throw CommandError(option + ": quaternion (w x y z) has norm " + Fmt(q.norm()) +
                       ", expected 1 (within 1e-3)");
  }
  return Pose::FromQuaternion(q, Vec3(v[0], v[1], v[2]));
}

/// A mesh file (OBJ/OFF/STL/PLY) or a built-in shape `shape:SPEC`.
pd::Mesh LoadSource(const std::string& source) {
  if (source.rfind(kShapePrefix, 0) == 0) {
    return pd::shapes::MakeShape(source.substr(sizeof(kShapePrefix) - 1));
  }
  return pd::LoadMesh(source);
}

nlohmann::json Vec(const Vec3& v) { return {v.x(), v.y(), v.z()}; }

/// [tx, ty, tz, qw, qx, qy, qz], the quaternion in the hemisphere of `q_ref`
/// so that an unrotated answer echoes the input quaternion.
std::array<double, 7> PoseArray(const Pose& X, const Quat& q_ref) {
  Quat q(X.R);
  if (q.coeffs().dot(q_ref.coeffs()) < 0) q.coeffs() = -q.coeffs();
  return {X.t.x(), X.t.y(), X.t.z(), q.w(), q.x(), q.y(), q.z()};
}

std::string Str(const Vec3& v) {
  std::ostringstream os;
  os << std::setprecision(6) << "(" << v.x() << ", " << v.y() << ", " << v.z() << ")";
  return os.str();
}

// What the command line asks for, checked.
struct PdInputs {
  bool generalized = false;
  pd::Material material;
  pd::PenetrationRequest request;
  Pose X_WA;
  std::vector<Pose> X_WB;  ///< one per --scene
};

PdInputs ParsePdInputs(const PdOptions& o) {
  // Cheap checks first, so a typo does not wait for a large mesh to load.
  if (o.mode != "pdt" && o.mode != "pdg") {
    throw CommandError("pd: unknown mode '" + o.mode + "' (valid modes: pdt, pdg)");
  }
  PdInputs in;
  in.generalized = o.mode == "pdg";
  if (o.probe.empty()) throw CommandError("pd: --probe FILE|shape:SPEC is required");
  if (o.scenes.empty()) throw CommandError("pd: at least one --scene FILE|shape:SPEC is required");
  if (o.pose.empty()) throw CommandError("pd: --pose \"tx ty tz qw qx qy qz\" is required");
  if (o.scene_poses.size() > o.scenes.size()) {
    throw CommandError("pd: " + std::to_string(o.scene_poses.size()) + " --scene-pose given for " +
                       std::to_string(o.scenes.size()) + " --scene");
  }
  in.material.stiffness = ParsePositive("--stiffness", o.stiffness);
  in.material.rotational_stiffness =
      ParsePositive("--rotational-stiffness", o.rotational_stiffness);
  pd::PenetrationRequest& request = in.request;
  if (!o.epsilon.empty()) request.contact_epsilon = ParsePositive("--epsilon", o.epsilon);
  if (!o.max_iterations.empty()) {
    request.max_iterations = ParsePositiveInt("--max-iterations", o.max_iterations);
    request.pdg_cold_max_iterations = request.max_iterations;
  }
  // A one-shot query has no next query to carry a budgeted optimisation on:
  // no budget unless asked for.
  request.pdg_iteration_budget = ParseBudget("--pdg-budget", o.pdg_budget);
  // Nor does it have a previous answer to start from: every query is cold
  // (the cold search, tests/bench/README.md "Cold queries").
  request.cold_start_directions = ParsePositiveInt("--cold-directions", o.cold_directions);
  if (request.cold_start_directions > pd::kMaxColdSearchDirections) {
    throw CommandError("pd: --cold-directions must be at most " +
                       std::to_string(pd::kMaxColdSearchDirections) + ", got " + o.cold_directions);
  }
  in.X_WA = ParsePose("--pose", o.pose);
  in.X_WB.assign(o.scenes.size(), Pose::Identity());
  for (std::size_t i = 0; i < o.scene_poses.size(); ++i) {
    in.X_WB[i] = ParsePose("--scene-pose " + std::to_string(i), o.scene_poses[i]);
  }
  return in;
}

// One query per body and their sum.
struct PdAnswers {
  std::vector<pd::PenetrationResult> results;  ///< per body
  Vec3 p_WAcm = Vec3::Zero();                  ///< the probe's centre of mass (torque point)
  Wrench wrench;                               ///< summed over the bodies
  int deepest = -1;                            ///< the deepest penetrated body, -1: none
  bool colliding = false;
  int iterations = 0;
  std::size_t contacts = 0;
  double time_us = 0;
};

PdAnswers QueryEachBody(const PdInputs& in, const pd::GeometryModel& probe,
                        const std::vector<pd::ModelPtr>& bodies) {
  // Each with its own session data (no coherence to carry in a one-shot
  // command, but it is the same call the servo loop makes).
  PdAnswers a;
  a.p_WAcm = in.X_WA * probe.mass().p_MC;
  a.results.resize(bodies.size());
  for (std::size_t i = 0; i < bodies.size(); ++i) {
    if (in.generalized) {
      pd::PdgQueryData data;
      pd::ComputePdg(probe, in.X_WA, *bodies[i], in.X_WB[i], in.request, &data, &a.results[i]);
    } else {
      pd::PdQueryData data;
      pd::ComputePdt(probe, in.X_WA, *bodies[i], in.X_WB[i], in.request, &data, &a.results[i]);
    }
    const pd::PenetrationResult& r = a.results[i];
    const Wrench w = pd::PdWrench(r, in.material, a.p_WAcm);
    a.wrench.force += w.force;
    a.wrench.torque += w.torque;
    a.iterations += r.iterations;
    a.contacts += r.features.size();
    a.time_us += r.time_us;
    if (r.status == pd::PdStatus::kSeparated) continue;
    a.colliding = true;
    if (a.deepest < 0 || r.depth > a.results[a.deepest].depth) a.deepest = static_cast<int>(i);
  }
  return a;
}

nlohmann::json PdJson(const PdOptions& o, const PdInputs& in, const pd::GeometryModel& probe,
                      const std::vector<pd::ModelPtr>& bodies, const PdAnswers& a) {
  const bool generalized = in.generalized;
  const Quat q_WA(in.X_WA.R);
  const pd::PenetrationResult* top = a.deepest >= 0 ? &a.results[a.deepest] : nullptr;
  nlohmann::json j;
  j["colliding"] = a.colliding;
  j["mode"] = o.mode;
  j["status"] = top ? pd::ToString(top->status) : "separated";
  j["deepest_body"] = a.deepest >= 0 ? nlohmann::json(a.deepest) : nlohmann::json(nullptr);
  j["depth"] = top ? top->depth : 0.0;
  j["translation"] = Vec(top ? top->translation_W : Vec3::Zero());
  j["pose"] = PoseArray(in.X_WA, q_WA);
  j["result_pose"] = PoseArray(top ? top->X_WA_result : in.X_WA, q_WA);
  if (generalized) {
    j["sigma"] = top ? top->sigma : 0.0;
    j["rotation_angle"] = top ? top->rotation_angle : 0.0;
    j["rotation_axis"] = Vec(top ? top->rotation_axis_W : Vec3(Vec3::UnitZ()));
  }
  j["iterations"] = a.iterations;
  j["contacts"] = a.contacts;
  j["regions"] = nlohmann::json::array();
  j["force"] = Vec(a.wrench.force);
  j["torque"] = Vec(a.wrench.torque);
  j["torque_about"] = Vec(a.p_WAcm);
  j["stiffness"] = in.material.stiffness;
  if (generalized) j["rotational_stiffness"] = in.material.rotational_stiffness;
  j["time_us"] = a.time_us;
  j["probe"] = {{"source", o.probe}, {"triangles", probe.mesh().num_triangles()}};
  j["bodies"] = nlohmann::json::array();
  for (std::size_t i = 0; i < bodies.size(); ++i) {
    const pd::PenetrationResult& r = a.results[i];
    for (const pd::ContactRegion& reg : r.regions) {
      j["regions"].push_back(
          {{"point", Vec(reg.p_W)}, {"normal", Vec(reg.n_W)}, {"depth", reg.depth}, {"body", i}});
    }
    nlohmann::json b = {{"body", i},
                        {"source", o.scenes[i]},
                        {"triangles", bodies[i]->mesh().num_triangles()},
                        {"scene_pose", PoseArray(in.X_WB[i], Quat(in.X_WB[i].R))},
                        {"status", pd::ToString(r.status)},
                        {"depth", r.depth},
                        {"translation", Vec(r.translation_W)},
                        {"result_pose", PoseArray(r.X_WA_result, q_WA)},
                        {"iterations", r.iterations},
                        {"contacts", r.features.size()},
                        {"regions", r.regions.size()},
                        {"time_us", r.time_us}};
    if (generalized) {
      b["sigma"] = r.sigma;
      b["rotation_angle"] = r.rotation_angle;
      b["rotation_axis"] = Vec(r.rotation_axis_W);
    }
    if (r.status == pd::PdStatus::kFailed) b["failure"] = r.failure;
    j["bodies"].push_back(std::move(b));
  }
  return j;
}

// The human-readable form of `j` (PdJson's).
void PrintPd(const PdOptions& o, const PdInputs& in, const pd::GeometryModel& probe,
             const std::vector<pd::ModelPtr>& bodies, const PdAnswers& a, const nlohmann::json& j) {
  const bool generalized = in.generalized;
  const pd::PenetrationResult* top = a.deepest >= 0 ? &a.results[a.deepest] : nullptr;
  const auto& rp = j["result_pose"];
  std::cout << std::setprecision(6);
  std::cout << "probe        " << o.probe << " (" << probe.mesh().num_triangles() << " triangles)\n"
            << "mode         " << o.mode << "\n"
            << "colliding    " << (a.colliding ? "yes" : "no") << "\n"
            << "status       " << j["status"].get<std::string>();
  if (a.deepest >= 0) std::cout << " (deepest: body " << a.deepest << ")";
  std::cout << "\n"
            << "depth        " << j["depth"].get<double>() << " m\n"
            << "translation  " << Str(top ? top->translation_W : Vec3::Zero()) << " m"
            << (generalized ? " (of the centre of mass)" : "") << "\n";
  if (generalized && top) {
    std::cout << "sigma        " << top->sigma << " m^2\n"
              << "rotation     " << top->rotation_angle << " rad about "
              << Str(top->rotation_axis_W) << "\n";
  }
  std::cout << "result pose  t (" << rp[0].get<double>() << ", " << rp[1].get<double>() << ", "
            << rp[2].get<double>() << ")  q (" << rp[3].get<double>() << ", " << rp[4].get<double>()
            << ", " << rp[5].get<double>() << ", " << rp[6].get<double>() << ")\n"
            << "force        " << Str(a.wrench.force) << " N  (k = " << in.material.stiffness
            << " N/m)\n"
            << "torque       " << Str(a.wrench.torque) << " N m about the probe's centre of mass "
            << Str(a.p_WAcm);
  if (generalized) std::cout << "  (xi = " << in.material.rotational_stiffness << " N m/rad)";
  std::cout << "\n"
            << "iterations   " << a.iterations << ", contacts " << a.contacts << ", regions "
            << j["regions"].size() << "\n"
            << "PD time      " << a.time_us << " us\n";
  for (std::size_t i = 0; i < bodies.size(); ++i) {
    const pd::PenetrationResult& r = a.results[i];
    std::cout << "body " << i << "       " << o.scenes[i] << " ("
              << bodies[i]->mesh().num_triangles() << " triangles): " << pd::ToString(r.status)
              << ", depth " << r.depth << " m along " << Str(r.translation_W) << ", ";
    if (generalized) {
      std::cout << "rotation " << r.rotation_angle << " rad about " << Str(r.rotation_axis_W)
                << ", ";
    }
    std::cout << r.iterations << " iterations, " << r.features.size() << " contacts, " << r.time_us
              << " us";
    if (r.status == pd::PdStatus::kFailed) std::cout << ", failure: " << r.failure;
    std::cout << "\n";
    for (const pd::ContactRegion& reg : r.regions) {
      std::cout << "  region     at " << Str(reg.p_W) << " normal " << Str(reg.n_W) << " depth "
                << reg.depth << " m\n";
    }
  }
}

void RunPd(const PdOptions& o) {
  const PdInputs in = ParsePdInputs(o);
  const pd::ModelPtr probe = pd::MakeModel(LoadSource(o.probe));
  std::vector<pd::ModelPtr> bodies;
  for (const auto& s : o.scenes) bodies.push_back(pd::MakeModel(LoadSource(s)));
  const PdAnswers answers = QueryEachBody(in, *probe, bodies);
  const nlohmann::json j = PdJson(o, in, *probe, bodies, answers);
  if (o.json) {
    std::cout << j.dump(2) << "\n";
    return;
  }
  PrintPd(o, in, *probe, bodies, answers, j);
}

}  // namespace

void RegisterPd(CLI::App& app) {
  auto opts = std::make_shared<PdOptions>();
  auto* cmd = app.add_subcommand(
      "pd", "Penetration depth of a probe mesh against scene meshes, with the penalty wrench");
  cmd->add_option("--probe", opts->probe,
                  "Probe: a mesh file (.obj, .off, .stl, .ply) or a built-in shape "
                  "'shape:SPEC', e.g. shape:stick or shape:box:0.1,0.1,0.1")
      ->type_name("FILE|shape:SPEC");
  cmd->add_option("--scene", opts->scenes,
                  "Scene body (repeatable): a mesh file or 'shape:SPEC'; placed at the identity "
                  "unless --scene-pose is given")
      ->type_name("FILE|shape:SPEC")
      ->allow_extra_args(false);
  cmd->add_option("--pose", opts->pose,
                  "World pose of the probe's mesh (file) frame: \"tx ty tz qw qx qy qz\", metres "
                  "and a unit quaternion (norm within 1e-3 of 1, then normalised)")
      ->type_name("\"tx ty tz qw qx qy qz\"");
  cmd->add_option("--scene-pose", opts->scene_poses,
                  "World pose of a scene body, one per --scene in order (repeatable); bodies "
                  "without one sit at the identity")
      ->type_name("\"tx ty tz qw qx qy qz\"")
      ->allow_extra_args(false);
  cmd->add_option("--mode", opts->mode,
                  "PD method: pdt (translational PD, PolyDepth) or pdg (generalized PD under the "
                  "object norm, PolyDepth++: translation and rotation)")
      ->type_name("MODE")
      ->capture_default_str();
  cmd->add_flag("--json", opts->json, "Print one JSON object");
  cmd->add_option("--stiffness", opts->stiffness, "Penalty stiffness k for the wrench (N/m)")
      ->type_name("K")
      ->capture_default_str();
  cmd->add_option("--rotational-stiffness", opts->rotational_stiffness,
                  "Rotational stiffness xi for the PDg torque xi theta omega (N m/rad)")
      ->type_name("XI")
      ->capture_default_str();
  cmd->add_option("--epsilon", opts->epsilon,
                  "Contact tolerance as a fraction of the smaller body's size (default 1e-4)")
      ->type_name("E");
  cmd->add_option("--max-iterations", opts->max_iterations,
                  "Cap on projection iterations per body (default 12; PDg without "
                  "--pdg-budget 48)")
      ->type_name("N");
  cmd->add_option("--cold-directions", opts->cold_directions,
                  "Escape directions of the cold search (1 to " +
                      std::to_string(pd::kMaxColdSearchDirections) +
                      ": 1 the centroid direction only, 13 the centroid direction and both "
                      "bodies' principal axes, more adds a sphere lattice; fewer is faster and "
                      "more often in a wrong, deeper basin)")
      ->type_name("N")
      ->capture_default_str();
  cmd->add_option("--pdg-budget", opts->pdg_budget,
                  "PDg: work budget of the iterations in box and triangle pair tests, 0 for "
                  "none (a device session's queries use " +
                      std::to_string(pd::PenetrationRequest{}.pdg_iteration_budget) +
                      "; a one-shot query has no next query to carry the optimisation on)")
      ->type_name("N")
      ->capture_default_str();
  cmd->footer(
      "Each scene body gets its own PD query. The top-level depth, translation (world frame) "
      "and result_pose (the probe's file-frame pose at the answer: pose translated by "
      "translation) are those of the DEEPEST body (largest depth); per-body answers are listed "
      "under bodies. status is that body's status, or 'separated' if no body touches the "
      "probe; colliding is true if any body is not separated. force and torque are the sum of "
      "the penalty wrenches of all bodies (f = sum k d_i over contact regions, torque about the "
      "probe's centre of mass at --pose, world frame); iterations, contacts and time_us are "
      "sums over bodies.\n"
      "With --mode pdg, depth is sqrt(sigma) (sigma: the object norm, the mean squared "
      "displacement of the probe's points, m^2), translation is the displacement of the probe's "
      "centre of mass, result_pose the full answer pose (rotation included), rotation_angle "
      "(rad) and rotation_axis (unit, world) the rotation from --pose to result_pose about the "
      "centre of mass; the wrench is f = k translation and torque = xi rotation_angle "
      "rotation_axis, summed over bodies.\n");
  cmd->callback([opts] { RunPd(*opts); });
}

}  // namespace hapticpd::cli
