#include "tests/fuzz/fuzz_entries.h"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <optional>
#include <string_view>

#include "hapticpd/v1/haptic.pb.h"
#include "hapticpd/v1/scene.pb.h"
#include "proto/wire/ranges.h"
#include "server/convert.h"
#include "server/scene_file.h"
#include "server/services.h"

namespace hapticpd::fuzz {
namespace {

/// Small limits keep each input cheap; they are part of what is validated.
constexpr std::size_t kMaxTriangles = 20000;

[[noreturn]] void Fail(const char* what) {
  std::fprintf(stderr, "fuzz invariant broken: %s\n", what);
  std::abort();
}

/// A rejected request must name the culprit: a non-empty message.
void CheckStatus(const grpc::Status& s) {
  if (!s.ok() && s.error_message().empty()) Fail("rejection without a message");
}

/// An accepted mesh is non-empty, indexed in range, finite and inside the
/// wire's coordinate range (a sphere's normalised vertices may exceed its
/// radius by rounding, hence the relative slack).
void CheckMesh(const grpc::Status& s, const std::optional<pd::Mesh>& mesh) {
  CheckStatus(s);
  if (!s.ok()) return;
  if (!mesh || mesh->triangles().empty()) Fail("accepted an empty mesh");
  for (const auto& v : mesh->vertices()) {
    if (!std::isfinite(v.x()) || !std::isfinite(v.y()) || !std::isfinite(v.z())) {
      Fail("accepted a non-finite vertex");
    }
    if (v.cwiseAbs().maxCoeff() > wire::kCoordinate.hi * (1 + 1e-12)) {
      Fail("accepted a vertex outside the coordinate range");
    }
  }
  for (const auto& t : mesh->triangles()) {
    for (int k = 0; k < 3; ++k) {
      if (t[k] < 0 || static_cast<std::size_t>(t[k]) >= mesh->vertices().size()) {
        Fail("index out of range");
      }
    }
  }
  if (mesh->triangles().size() > kMaxTriangles) Fail("accepted a mesh over the triangle limit");
}

void CheckPose(const v1::Pose& p, std::string_view field) {
  Pose pose;
  const grpc::Status s = server::FromProto(p, field, &pose);
  CheckStatus(s);
  if (s.ok() && (!pose.t.allFinite() || !pose.R.allFinite() ||
                 !(pose.R.transpose() * pose.R).isIdentity(1e-9))) {
    Fail("accepted a pose that is not finite and unit");
  }
  if (s.ok() && pose.t.cwiseAbs().maxCoeff() > wire::kCoordinate.hi) {
    Fail("accepted a position outside the coordinate range");
  }
}

}  // namespace

void MeshImport(const std::string& format, const std::uint8_t* data, std::size_t size) {
  v1::MeshFormat f = v1::MESH_FORMAT_UNSPECIFIED;
  if (format == "obj") f = v1::MESH_FORMAT_OBJ;
  if (format == "stl") f = v1::MESH_FORMAT_STL;
  if (format == "ply") f = v1::MESH_FORMAT_PLY;
  if (format == "off") f = v1::MESH_FORMAT_OFF;
  std::optional<pd::Mesh> mesh;
  const grpc::Status s = server::MeshFromBytes(
      std::string(reinterpret_cast<const char*>(data), size), f, "chunk", kMaxTriangles, &mesh);
  CheckMesh(s, mesh);
}

void SceneFile(const std::uint8_t* data, std::size_t size) {
  try {
    const server::SceneFile sf = server::ParseSceneJson(
        std::string(reinterpret_cast<const char*>(data), size), "/nonexistent/fuzz.json");
    // The server runs its own checks on what the parser accepted (a bad
    // body id, say, is rejected there naming bodies[i].body_id and the
    // file); they must hold up too.
    (void)server::CheckSceneConfig(sf.config, "config");
    for (const auto& b : sf.bodies) CheckStatus(server::internal::ValidateSpec(b.spec, "spec"));
  } catch (const server::SceneFileError& e) {
    if (std::string_view(e.what()).rfind("/nonexistent/fuzz.json: ", 0) != 0) {
      Fail("scene-file error does not start with the file name");
    }
  }
}

void RequestValidation(const std::uint8_t* data, std::size_t size) {
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  {
    v1::AddBodyRequest r;
    if (r.ParseFromArray(bytes.data(), static_cast<int>(bytes.size())) && r.has_header()) {
      const auto& h = r.header();
      CheckStatus(server::ValidateId(h.scene_id(), "header.scene_id"));
      CheckStatus(server::internal::ValidateSpec(h.spec(), "header.spec"));
      CheckPose(h.spec().pose(), "header.spec.pose");
      std::optional<pd::Mesh> mesh;
      if (h.mesh_case() == v1::AddBodyHeader::kInlineMesh) {
        CheckMesh(
            server::MeshFromInline(h.inline_mesh(), "header.inline_mesh", kMaxTriangles, &mesh),
            mesh);
      } else if (h.mesh_case() == v1::AddBodyHeader::kShape) {
        CheckMesh(server::MeshFromShape(h.shape(), "header.shape", kMaxTriangles, &mesh), mesh);
      }
    }
  }
  {
    v1::MoveBodyRequest r;
    if (r.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) {
      CheckStatus(server::ValidateId(r.body_id(), "body_id"));
      CheckPose(r.pose(), "pose");
      CheckStatus(server::ValidateTwist(r.velocity(), "velocity"));
    }
  }
  {
    v1::CreateSceneRequest r;
    if (r.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) {
      CheckStatus(server::ValidateId(r.scene_id(), "scene_id"));
      (void)server::CheckSceneConfig(r.config(), "config");
    }
  }
  {
    v1::Hello h;
    if (h.ParseFromArray(bytes.data(), static_cast<int>(bytes.size()))) {
      pd::Material m;
      CheckStatus(server::FromProto(h.material(), "hello.material", &m));
      std::optional<pd::Mesh> mesh;
      if (h.has_probe_mesh()) {
        CheckMesh(server::MeshFromInline(h.probe_mesh(), "hello.probe_mesh", kMaxTriangles, &mesh),
                  mesh);
      } else if (h.probe_case() == v1::Hello::kProbeShape) {
        CheckMesh(server::MeshFromShape(h.probe_shape(), "hello.probe_shape", kMaxTriangles, &mesh),
                  mesh);
      }
    }
  }
}

std::vector<Target> Targets() {
  return {
      {"mesh_obj", [](const std::uint8_t* d, std::size_t n) { MeshImport("obj", d, n); }},
      {"mesh_stl", [](const std::uint8_t* d, std::size_t n) { MeshImport("stl", d, n); }},
      {"mesh_ply", [](const std::uint8_t* d, std::size_t n) { MeshImport("ply", d, n); }},
      {"mesh_off", [](const std::uint8_t* d, std::size_t n) { MeshImport("off", d, n); }},
      {"scene_file", SceneFile},
      {"requests", RequestValidation},
  };
}

}  // namespace hapticpd::fuzz
