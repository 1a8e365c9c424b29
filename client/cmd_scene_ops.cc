// Thin CLIs over SceneService: `hapticpd inject`, `move`, `remove` and
// `scene list|create|delete|get|load|export|import`. Each prints what it did
// on stdout (the body id first) and fails with "hapticpd: CMD: STATUS:
// message". Every mutation carries a fresh request id (NewRequestId).
#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <string>
#include <vector>

#include "client/rpc_util.h"
#include "hapticpd/v1/scene.grpc.pb.h"
#include "proto/wire/scene_file.h"

namespace hapticpd::cli {
namespace {

/// The upload format of a mesh file, from its extension; `what` prefixes the
/// error (the option or scene-file key that named the file).
v1::MeshFormat FormatOf(const std::string& path, const std::string& what) {
  std::string ext = path.substr(
      path.find_last_of('.') == std::string::npos ? path.size() : path.find_last_of('.'));
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  if (ext == ".obj") return v1::MESH_FORMAT_OBJ;
  if (ext == ".stl") return v1::MESH_FORMAT_STL;
  if (ext == ".ply") return v1::MESH_FORMAT_PLY;
  if (ext == ".off") return v1::MESH_FORMAT_OFF;
  throw CommandError(what + ": unsupported extension '" + ext + "' (use .obj, .stl, .ply or .off)");
}

/// The whole file, or CommandError "WHAT: cannot open PATH".
std::string ReadBytes(const std::string& path, const std::string& what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw CommandError(what + ": cannot open " + path);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

/// One AddBody call: the header, then `bytes` (a mesh file, may be empty) in
/// chunks of `chunk` bytes. Returns the server's status; fills `body`.
grpc::Status UploadBody(v1::SceneService::Stub& stub, const ConnectionOptions& conn,
                        const v1::AddBodyHeader& header, const std::string& bytes,
                        std::size_t chunk, v1::Body* body) {
  auto ctx = MakeSceneContext(conn, header.scene_id());
  auto writer = stub.AddBody(ctx.get(), body);
  v1::AddBodyRequest head;
  *head.mutable_header() = header;
  bool ok = writer->Write(head);
  v1::AddBodyRequest part;
  for (std::size_t off = 0; ok && off < bytes.size(); off += chunk) {
    part.set_chunk(bytes.substr(off, chunk));
    ok = writer->Write(part);
  }
  writer->WritesDone();
  return writer->Finish();
}

struct InjectOptions {
  ConnectionOptions conn;
  std::string scene = "default";
  std::string mesh, shape, pose = "0,0,0", velocity, id, label;
  bool movable = false;
  double stiffness = -1;
  std::size_t chunk_kib = 64;
};

void RunInject(const InjectOptions& o) {
  if (o.mesh.empty() == o.shape.empty()) {
    throw CommandError("inject: give exactly one of --mesh FILE or --shape SPEC");
  }
  v1::AddBodyHeader h;
  h.set_scene_id(o.scene);
  h.set_request_id(NewRequestId());
  auto* spec = h.mutable_spec();
  spec->set_body_id(o.id);
  *spec->mutable_pose() = ParsePose(o.pose, "--pose");
  if (!o.velocity.empty()) *spec->mutable_velocity() = ParseTwist(o.velocity, "--velocity");
  spec->set_movable(o.movable);
  spec->set_label(o.label.empty() ? (o.mesh.empty() ? o.shape : o.mesh) : o.label);
  if (o.stiffness >= 0) {
    spec->mutable_material()->set_stiffness(o.stiffness);
    spec->mutable_material()->set_rotational_stiffness(0.05);
  }
  std::string bytes;
  if (!o.mesh.empty()) {
    h.set_format(FormatOf(o.mesh, "inject: --mesh"));
    bytes = ReadBytes(o.mesh, "inject: --mesh");
    h.set_total_bytes(bytes.size());
  } else {
    h.set_shape(o.shape);
  }
  auto stub = v1::SceneService::NewStub(MakeChannel(o.conn));
  v1::Body body;
  const std::size_t chunk = std::max<std::size_t>(1, o.chunk_kib) * 1024;
  Check(UploadBody(*stub, o.conn, h, bytes, chunk, &body), "inject");
  std::cout << body.body_id() << "\n";
}

struct MoveOptions {
  ConnectionOptions conn;
  std::string scene = "default", body, pose, velocity;
};

void RunMove(const MoveOptions& o) {
  v1::MoveBodyRequest req;
  req.set_scene_id(o.scene);
  req.set_body_id(o.body);
  req.set_request_id(NewRequestId());
  *req.mutable_pose() = ParsePose(o.pose, "--pose");
  if (!o.velocity.empty()) *req.mutable_velocity() = ParseTwist(o.velocity, "--velocity");
  auto stub = v1::SceneService::NewStub(MakeChannel(o.conn));
  auto ctx = MakeSceneContext(o.conn, req.scene_id());
  v1::MoveBodyResponse resp;
  Check(stub->MoveBody(ctx.get(), req, &resp), "move");
  std::cout << o.body << " revision " << resp.revision() << "\n";
}

struct RemoveOptions {
  ConnectionOptions conn;
  std::string scene = "default", body;
};

void RunRemove(const RemoveOptions& o) {
  v1::RemoveBodyRequest req;
  req.set_scene_id(o.scene);
  req.set_body_id(o.body);
  req.set_request_id(NewRequestId());
  auto stub = v1::SceneService::NewStub(MakeChannel(o.conn));
  auto ctx = MakeSceneContext(o.conn, req.scene_id());
  v1::RemoveBodyResponse resp;
  Check(stub->RemoveBody(ctx.get(), req, &resp), "remove");
  std::cout << o.body << " removed, revision " << resp.revision() << "\n";
}

struct SceneOptions {
  ConnectionOptions conn;
  std::string action;
  std::string scene;    ///< the scene id, or for `load` the scene file
  std::string load_id;  ///< `load --scene ID`: overrides the file's scene id
  std::string description;
  std::string dir;  ///< `export ID DIR`
  std::size_t chunk_kib = 64;
  std::vector<std::string> servers;  ///< `list --servers A,B`: each process directly
};

/// `scene list --servers A,B,C`: every process behind a balancer asked
/// directly (the balancer sends a ListScenes to one of them). One line per
/// scene, prefixed by its server; a scene held by two servers (a copy the
/// shard map should have prevented) and a server that cannot answer are
/// reported, and make the command fail after the listing.
void RunSceneListAll(const SceneOptions& o) {
  std::map<std::string, std::vector<std::string>> holders;  // scene -> servers
  std::vector<std::string> problems;
  for (const std::string& server : o.servers) {
    ConnectionOptions conn = o.conn;
    conn.server = server;
    auto stub = v1::SceneService::NewStub(MakeChannel(conn));
    auto ctx = MakeContext(conn);
    v1::ListScenesResponse resp;
    if (const grpc::Status s = stub->ListScenes(ctx.get(), {}, &resp); !s.ok()) {
      problems.push_back(fmt::format("{}: {}", server, StatusText(s)));
      continue;
    }
    for (const auto& s : resp.scenes()) {
      std::cout << fmt::format("{}  {}  bodies {}  sessions {}  observers {}  revision {}{}\n",
                               server, s.scene_id(), s.bodies(), s.sessions(), s.observers(),
                               s.revision(), s.description().empty() ? "" : "  " + s.description());
      holders[s.scene_id()].push_back(server);
    }
  }
  for (const auto& [id, where] : holders) {
    if (where.size() > 1) {
      problems.push_back(fmt::format("scene '{}' is held by {} servers: {}", id, where.size(),
                                     fmt::join(where, ", ")));
    }
  }
  if (!problems.empty()) {
    throw CommandError(fmt::format("scene list: {}", fmt::join(problems, "; ")));
  }
}

/// A mesh file written by `scene export` (only "v X Y Z" and "f A B C"
/// lines, numbers in full double precision), read back exactly: the mesh
/// readers of `pd` read coordinates in single precision. False for any other
/// file (it is then uploaded as a file).
bool ReadExportedObj(const std::string& path, v1::InlineMesh* out) {
  std::ifstream in(path);
  std::string line;
  if (!std::getline(in, line) || line != "# hapticpd scene export") return false;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    char* end = nullptr;
    const char* p = line.c_str() + 2;
    if (line.rfind("v ", 0) == 0) {
      for (int k = 0; k < 3; ++k) {
        out->add_vertices(std::strtod(p, &end));
        if (end == p) return false;
        p = end;
      }
    } else if (line.rfind("f ", 0) == 0) {
      for (int k = 0; k < 3; ++k) {
        const unsigned long i = std::strtoul(p, &end, 10);
        if (end == p || i == 0) return false;
        out->add_triangles(static_cast<std::uint32_t>(i - 1));
        p = end;
      }
    } else {
      return false;
    }
    while (*p == ' ') ++p;
    if (*p != 0) return false;
  }
  return out->triangles_size() > 0;
}

/// `scene load FILE`: the scene file's scene (id, description, SceneConfig)
/// created through CreateScene, then its bodies added in file order through
/// AddBody, exactly as `serve --scene` preloads them. Everything local (the
/// file, mesh extensions, mesh bytes) is checked before anything is sent; a
/// body the server rejects deletes the scene again, so no half-loaded scene
/// stays. Prints the scene id, then one body id a line.
void RunSceneLoad(const SceneOptions& o, const std::string& file, bool exact_meshes) {
  const std::string cmd = exact_meshes ? "scene import" : "scene load";
  wire::SceneFile f;
  try {
    f = wire::ParseSceneFile(file);
  } catch (const wire::SceneFileError& e) {
    throw CommandError(cmd + ": " + e.what());
  }
  const std::string id = o.load_id.empty() ? f.scene_id : o.load_id;
  struct Upload {
    v1::AddBodyHeader header;
    std::string bytes;
  };
  std::vector<Upload> uploads;
  for (std::size_t i = 0; i < f.bodies.size(); ++i) {
    const wire::SceneFileBody& b = f.bodies[i];
    Upload& u = uploads.emplace_back();
    u.header.set_scene_id(id);
    u.header.set_request_id(NewRequestId());
    *u.header.mutable_spec() = b.spec;
    if (b.mesh_path.empty()) {
      u.header.set_shape(b.shape);
      continue;
    }
    // Inline (exact doubles) when it fits well within a gRPC message.
    if (exact_meshes && std::filesystem::file_size(b.mesh_path) < (2u << 20) &&
        ReadExportedObj(b.mesh_path, u.header.mutable_inline_mesh())) {
      continue;
    }
    u.header.clear_mesh();
    const std::string key = cmd + ": " + f.path + ": bodies[" + std::to_string(i) + "].mesh";
    u.header.set_format(FormatOf(b.mesh_path, key));
    u.bytes = ReadBytes(b.mesh_path, key);
    u.header.set_total_bytes(u.bytes.size());
  }

  auto stub = v1::SceneService::NewStub(MakeChannel(o.conn));
  {
    v1::CreateSceneRequest req;
    req.set_scene_id(id);
    req.set_description(o.description.empty() ? f.description : o.description);
    *req.mutable_config() = f.config;
    req.set_request_id(NewRequestId());
    v1::SceneSummary resp;
    auto ctx = MakeSceneContext(o.conn, req.scene_id());
    Check(stub->CreateScene(ctx.get(), req, &resp), cmd + ": " + f.path);
  }
  const std::size_t chunk = std::max<std::size_t>(1, o.chunk_kib) * 1024;
  std::vector<std::string> body_ids;
  for (std::size_t i = 0; i < uploads.size(); ++i) {
    v1::Body body;
    const grpc::Status s =
        UploadBody(*stub, o.conn, uploads[i].header, uploads[i].bytes, chunk, &body);
    if (s.ok()) {
      body_ids.push_back(body.body_id());
      continue;
    }
    // Roll back: the scene is ours (CreateScene succeeded above).
    v1::DeleteSceneRequest del;
    del.set_scene_id(id);
    del.set_request_id(NewRequestId());
    v1::DeleteSceneResponse del_resp;
    auto ctx = MakeSceneContext(o.conn, del.scene_id());
    const grpc::Status d = stub->DeleteScene(ctx.get(), del, &del_resp);
    const std::string& body_id = uploads[i].header.spec().body_id();
    throw CommandError(
        cmd + ": " + f.path + ": bodies[" + std::to_string(i) + "]" +
        (body_id.empty() ? "" : " ('" + body_id + "')") + ": " + StatusText(s) +
        (d.ok() ? "; scene '" + id + "' deleted again"
                : "; rollback failed, scene '" + id + "' is left half-loaded: " + StatusText(d)));
  }
  std::cout << id << "\n";
  for (const std::string& b : body_ids) std::cout << b << "\n";
}

nlohmann::json Vec(const v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }

/// `scene export ID DIR`: DIR/scene.json (a scene file: config, bodies with
/// ids, labels, poses, velocities, materials, movable flags) and
/// DIR/meshes/BODY.obj, each mesh in full double precision. `scene import
/// DIR` reads them back into a server.
void RunSceneExport(const SceneOptions& o) {
  namespace fs = std::filesystem;
  if (o.scene.empty() || o.dir.empty()) throw CommandError("scene export: give ID DIR");
  const fs::path dir = o.dir;
  const fs::path file = dir / "scene.json";
  if (fs::exists(file)) {
    throw CommandError("scene export: " + file.string() + " exists (export into a new folder)");
  }
  auto stub = v1::SceneService::NewStub(MakeChannel(o.conn));
  v1::GetSceneRequest req;
  req.set_scene_id(o.scene);
  req.set_include_meshes(true);
  v1::Scene sc;
  auto ctx = MakeSceneContext(o.conn, req.scene_id());
  Check(stub->GetScene(ctx.get(), req, &sc), "scene export");
  std::error_code ec;
  fs::create_directories(dir / "meshes", ec);
  if (ec) throw CommandError("scene export: " + dir.string() + ": " + ec.message());

  const v1::SceneConfig& c = sc.config();
  nlohmann::json j;
  j["scene"] = sc.scene_id();
  j["description"] = sc.description();
  // Every config field written out, so that the import gets the same config.
  if (c.pd_mode() != v1::PD_MODE_UNSPECIFIED) j["mode"] = wire::PdModeName(c.pd_mode());
  if (c.declared()) {
    j["effects"] = nlohmann::json::array();
    for (int e : c.effects()) j["effects"].push_back(wire::EffectName(v1::Effect(e)));
  }
  j["gravity"] = Vec(c.gravity());
  j["texture"] = {{"amplitude", c.texture_amplitude()}, {"frequency", c.texture_frequency()}};
  if (!c.probe_shape().empty() || c.probe_mass() > 0 || c.probe_inertia() > 0) {
    nlohmann::json p = nlohmann::json::object();
    if (!c.probe_shape().empty()) p["shape"] = c.probe_shape();
    if (c.probe_mass() > 0) p["mass"] = c.probe_mass();
    if (c.probe_inertia() > 0) p["inertia"] = c.probe_inertia();
    j["probe"] = p;
  }
  j["bodies"] = nlohmann::json::array();
  for (const v1::Body& b : sc.bodies()) {
    const std::string mesh = "meshes/" + b.body_id() + ".obj";
    const fs::path mesh_path = dir / mesh;
    std::FILE* out = std::fopen(mesh_path.c_str(), "w");
    if (out == nullptr) throw CommandError("scene export: cannot write " + mesh_path.string());
    std::fprintf(out, "# hapticpd scene export\n");
    const auto& v = b.mesh().vertices();
    for (int i = 0; i + 2 < v.size(); i += 3) {
      std::fprintf(out, "v %.17g %.17g %.17g\n", v[i], v[i + 1], v[i + 2]);
    }
    const auto& t = b.mesh().triangles();
    for (int i = 0; i + 2 < t.size(); i += 3) {
      std::fprintf(out, "f %u %u %u\n", t[i] + 1, t[i + 1] + 1, t[i + 2] + 1);
    }
    if (std::fclose(out) != 0) {
      throw CommandError("scene export: cannot write " + mesh_path.string());
    }
    const auto& q = b.pose().orientation();
    const auto& m = b.material();
    j["bodies"].push_back(
        {{"id", b.body_id()},
         {"label", b.label()},
         {"mesh", mesh},
         {"pose",
          {{"position", Vec(b.pose().position())}, {"orientation", {q.w(), q.x(), q.y(), q.z()}}}},
         {"velocity",
          {{"linear", Vec(b.velocity().linear())}, {"angular", Vec(b.velocity().angular())}}},
         {"material",
          {{"stiffness", m.stiffness()},
           {"rotational_stiffness", m.rotational_stiffness()},
           {"damping", m.damping()},
           {"static_friction", m.static_friction()},
           {"dynamic_friction", m.dynamic_friction()}}},
         {"movable", b.movable()}});
  }
  std::ofstream f(file);
  f << j.dump(2) << "\n";
  if (!f.flush()) throw CommandError("scene export: cannot write " + file.string());
  std::cout << file.string() << "\n";
}

void RunScene(const SceneOptions& o) {
  if (o.action == "load") {
    if (o.scene.empty()) throw CommandError("scene load: give FILE.json");
    RunSceneLoad(o, o.scene, false);
    return;
  }
  if (o.action == "import") {
    if (o.scene.empty()) throw CommandError("scene import: give DIR (written by scene export)");
    RunSceneLoad(o, (std::filesystem::path(o.scene) / "scene.json").string(), true);
    return;
  }
  if (o.action == "export") {
    RunSceneExport(o);
    return;
  }
  if (!o.dir.empty()) throw CommandError("scene " + o.action + ": too many arguments");
  if (!o.load_id.empty()) {
    throw CommandError("scene " + o.action + ": --scene is for load only");
  }
  auto stub = v1::SceneService::NewStub(MakeChannel(o.conn));
  // `list` names no scene; every other action is for the scene `o.scene`.
  auto ctx = o.action == "list" ? MakeContext(o.conn) : MakeSceneContext(o.conn, o.scene);
  if (o.action != "list" && o.scene.empty()) throw CommandError("scene " + o.action + ": give ID");
  if (!o.servers.empty() && o.action != "list") {
    throw CommandError("scene " + o.action + ": --servers is for list only");
  }
  if (o.action == "list" && !o.servers.empty()) {
    RunSceneListAll(o);
  } else if (o.action == "list") {
    v1::ListScenesResponse resp;
    Check(stub->ListScenes(ctx.get(), {}, &resp), "scene list");
    for (const auto& s : resp.scenes()) {
      std::cout << s.scene_id() << "  bodies " << s.bodies() << "  sessions " << s.sessions()
                << "  observers " << s.observers() << "  revision " << s.revision()
                << (s.description().empty() ? "" : "  " + s.description()) << "\n";
    }
  } else if (o.action == "create") {
    v1::CreateSceneRequest req;
    req.set_scene_id(o.scene);
    req.set_description(o.description);
    req.set_request_id(NewRequestId());
    v1::SceneSummary resp;
    Check(stub->CreateScene(ctx.get(), req, &resp), "scene create");
    std::cout << resp.scene_id() << "\n";
  } else if (o.action == "delete") {
    v1::DeleteSceneRequest req;
    req.set_scene_id(o.scene);
    req.set_request_id(NewRequestId());
    v1::DeleteSceneResponse resp;
    Check(stub->DeleteScene(ctx.get(), req, &resp), "scene delete");
    std::cout << o.scene << " deleted\n";
  } else if (o.action == "get") {
    v1::GetSceneRequest req;
    req.set_scene_id(o.scene);
    v1::Scene resp;
    Check(stub->GetScene(ctx.get(), req, &resp), "scene get");
    nlohmann::json j;
    j["scene"] = resp.scene_id();
    j["revision"] = resp.revision();
    j["bodies"] = nlohmann::json::array();
    for (const auto& b : resp.bodies()) {
      const auto& q = b.pose().orientation();
      j["bodies"].push_back({{"id", b.body_id()},
                             {"label", b.label()},
                             {"movable", b.movable()},
                             {"triangles", b.mesh_info().triangles()},
                             {"position", Vec(b.pose().position())},
                             {"orientation", {q.w(), q.x(), q.y(), q.z()}},
                             {"stiffness", b.material().stiffness()}});
    }
    std::cout << j.dump(2) << "\n";
  } else {
    throw CommandError("scene: unknown action '" + o.action +
                       "' (list, create, delete, get, load, export, import)");
  }
}

}  // namespace

void RegisterSceneOps(CLI::App& app) {
  {
    auto o = std::make_shared<InjectOptions>();
    auto* cmd = app.add_subcommand("inject", "Add a body (mesh file or built-in shape) to a scene");
    AddConnectionOptions(cmd, &o->conn);
    cmd->add_option("--scene", o->scene, "Scene id")->capture_default_str();
    cmd->add_option("--mesh", o->mesh, "Mesh file (.obj, .stl, .ply, .off), uploaded in chunks");
    cmd->add_option("--shape", o->shape, "Built-in shape instead, e.g. 'box:0.05,0.05,0.05'");
    cmd->add_option("--pose", o->pose,
                    "\"x y z [qw qx qy qz]\" in metres (commas or spaces between numbers)")
        ->capture_default_str();
    cmd->add_option("--velocity", o->velocity, "\"vx vy vz [wx wy wz]\" (commas or spaces)");
    cmd->add_option("--id", o->id, "Body id (default: assigned by the server)");
    cmd->add_option("--label", o->label, "Label shown to observers (default: the file or shape)");
    cmd->add_flag("--movable", o->movable, "Allow `hapticpd move` on this body");
    cmd->add_option("--stiffness", o->stiffness, "Contact stiffness N/m (default: server's 1000)");
    cmd->add_option("--chunk-kib", o->chunk_kib, "Upload chunk size in KiB")->capture_default_str();
    cmd->callback([o] { RunInject(*o); });
  }
  {
    auto o = std::make_shared<MoveOptions>();
    auto* cmd = app.add_subcommand("move", "Set a movable body's pose");
    AddConnectionOptions(cmd, &o->conn);
    cmd->add_option("--scene", o->scene, "Scene id")->capture_default_str();
    cmd->add_option("--body", o->body, "Body id")->required();
    cmd->add_option("--pose", o->pose,
                    "\"x y z [qw qx qy qz]\" in metres (commas or spaces between numbers)")
        ->required();
    cmd->add_option("--velocity", o->velocity, "\"vx vy vz [wx wy wz]\" (commas or spaces)");
    cmd->callback([o] { RunMove(*o); });
  }
  {
    auto o = std::make_shared<RemoveOptions>();
    auto* cmd = app.add_subcommand("remove", "Remove a body from a scene");
    AddConnectionOptions(cmd, &o->conn);
    cmd->add_option("--scene", o->scene, "Scene id")->capture_default_str();
    cmd->add_option("--body", o->body, "Body id")->required();
    cmd->callback([o] { RunRemove(*o); });
  }
  {
    auto o = std::make_shared<SceneOptions>();
    auto* cmd = app.add_subcommand(
        "scene",
        "List, create, delete or show scenes, load a scene file (scene load FILE.json), or "
        "move a scene between servers (scene export ID DIR, then scene import DIR)");
    AddConnectionOptions(cmd, &o->conn);
    cmd->add_option("action", o->action, "list | create | delete | get | load | export | import")
        ->required();
    cmd->add_option("id", o->scene,
                    "Scene id (create, delete, get, export), FILE.json (load) or DIR (import)");
    cmd->add_option("dir", o->dir,
                    "export: the folder to write (scene.json and meshes/BODY.obj, every number "
                    "in full precision)");
    cmd->add_option("--description", o->description,
                    "Description (create; load: instead of the file's)");
    cmd->add_option("--scene", o->load_id,
                    "load, import: scene id instead of the file's \"scene\"");
    cmd->add_option("--chunk-kib", o->chunk_kib, "load: mesh upload chunk size in KiB")
        ->capture_default_str();
    cmd->add_option("--servers", o->servers,
                    "list: ask each of these HOST:PORT processes directly (comma-separated; "
                    "those behind a balancer) and prefix each scene with its server; fails when "
                    "one cannot answer or a scene is held twice")
        ->delimiter(',');
    cmd->callback([o] { RunScene(*o); });
  }
}

}  // namespace hapticpd::cli
