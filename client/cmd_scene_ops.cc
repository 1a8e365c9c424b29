// Thin CLIs over SceneService: `hapticpd inject`, `move`, `remove` and
// `scene list|create|delete|get`. Each prints what it did on stdout (the body
// id first) and fails with "hapticpd: CMD: STATUS: message".
#include <nlohmann/json.hpp>

#include <algorithm>
#include <fstream>
#include <iostream>

#include "client/rpc_util.h"
#include "hapticpd/v1/scene.grpc.pb.h"

namespace hapticpd::cli {
namespace {

v1::MeshFormat FormatOf(const std::string& path) {
  std::string ext = path.substr(
      path.find_last_of('.') == std::string::npos ? path.size() : path.find_last_of('.'));
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  if (ext == ".obj") return v1::MESH_FORMAT_OBJ;
  if (ext == ".stl") return v1::MESH_FORMAT_STL;
  if (ext == ".ply") return v1::MESH_FORMAT_PLY;
  if (ext == ".off") return v1::MESH_FORMAT_OFF;
  throw CommandError("inject: --mesh: unsupported extension '" + ext +
                     "' (use .obj, .stl, .ply or .off)");
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
  v1::AddBodyRequest head;
  auto* h = head.mutable_header();
  h->set_scene_id(o.scene);
  auto* spec = h->mutable_spec();
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
    h->set_format(FormatOf(o.mesh));
    std::ifstream in(o.mesh, std::ios::binary);
    if (!in) throw CommandError("inject: --mesh: cannot open " + o.mesh);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
    h->set_total_bytes(bytes.size());
  } else {
    h->set_shape(o.shape);
  }
  auto stub = v1::SceneService::NewStub(MakeChannel(o.conn));
  auto ctx = MakeContext(o.conn);
  v1::Body body;
  auto writer = stub->AddBody(ctx.get(), &body);
  bool ok = writer->Write(head);
  const std::size_t chunk = std::max<std::size_t>(1, o.chunk_kib) * 1024;
  v1::AddBodyRequest part;
  for (std::size_t off = 0; ok && off < bytes.size(); off += chunk) {
    part.set_chunk(bytes.substr(off, chunk));
    ok = writer->Write(part);
  }
  writer->WritesDone();
  Check(writer->Finish(), "inject");
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
  *req.mutable_pose() = ParsePose(o.pose, "--pose");
  if (!o.velocity.empty()) *req.mutable_velocity() = ParseTwist(o.velocity, "--velocity");
  auto stub = v1::SceneService::NewStub(MakeChannel(o.conn));
  auto ctx = MakeContext(o.conn);
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
  auto stub = v1::SceneService::NewStub(MakeChannel(o.conn));
  auto ctx = MakeContext(o.conn);
  v1::RemoveBodyResponse resp;
  Check(stub->RemoveBody(ctx.get(), req, &resp), "remove");
  std::cout << o.body << " removed, revision " << resp.revision() << "\n";
}

struct SceneOptions {
  ConnectionOptions conn;
  std::string action, scene, description;
};

nlohmann::json Vec(const v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }

void RunScene(const SceneOptions& o) {
  auto stub = v1::SceneService::NewStub(MakeChannel(o.conn));
  auto ctx = MakeContext(o.conn);
  if (o.action != "list" && o.scene.empty()) throw CommandError("scene " + o.action + ": give ID");
  if (o.action == "list") {
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
    v1::SceneSummary resp;
    Check(stub->CreateScene(ctx.get(), req, &resp), "scene create");
    std::cout << resp.scene_id() << "\n";
  } else if (o.action == "delete") {
    v1::DeleteSceneRequest req;
    req.set_scene_id(o.scene);
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
    throw CommandError("scene: unknown action '" + o.action + "' (list, create, delete, get)");
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
    cmd->add_option("--pose", o->pose, "x,y,z[,qw,qx,qy,qz] in metres")->capture_default_str();
    cmd->add_option("--velocity", o->velocity, "vx,vy,vz[,wx,wy,wz]");
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
    cmd->add_option("--pose", o->pose, "x,y,z[,qw,qx,qy,qz] in metres")->required();
    cmd->add_option("--velocity", o->velocity, "vx,vy,vz[,wx,wy,wz]");
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
    auto* cmd = app.add_subcommand("scene", "List, create, delete or show scenes");
    AddConnectionOptions(cmd, &o->conn);
    cmd->add_option("action", o->action, "list | create | delete | get")->required();
    cmd->add_option("id", o->scene, "Scene id (create, delete, get)");
    cmd->add_option("--description", o->description, "Description (create)");
    cmd->callback([o] { RunScene(*o); });
  }
}

}  // namespace hapticpd::cli
