#include "server/convert.h"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "pd/shapes.h"

namespace hapticpd::server {
namespace {

std::string Join(std::string_view field, std::string_view sub) {
  std::string s(field);
  s += '.';
  s += sub;
  return s;
}

bool Finite(double x) { return std::isfinite(x); }

grpc::Status CheckFinite(double x, std::string_view field) {
  if (!Finite(x))
    return InvalidArgument(field, "must be a finite number, got " + std::to_string(x));
  return grpc::Status::OK;
}

grpc::Status CheckTriangleLimit(std::size_t triangles, std::size_t limit, std::string_view field) {
  if (triangles > limit) {
    return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                        std::string(field) + ": " + std::to_string(triangles) +
                            " triangles exceed the server limit of " + std::to_string(limit));
  }
  return grpc::Status::OK;
}

/// MeshError messages start with the source name; replace it by the field.
std::string StripSource(const std::string& what, const std::string& source) {
  if (what.rfind(source, 0) == 0) {
    std::string rest = what.substr(source.size());
    if (rest.rfind(": ", 0) == 0) rest = rest.substr(2);
    return rest;
  }
  return what;
}

}  // namespace

grpc::Status InvalidArgument(std::string_view field, std::string_view what) {
  std::string msg(field);
  msg += ": ";
  msg += what;
  return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, msg);
}

grpc::Status FromProto(const v1::Vec3& v, std::string_view field, Vec3* out) {
  for (auto [x, name] : {std::pair{v.x(), "x"}, std::pair{v.y(), "y"}, std::pair{v.z(), "z"}}) {
    if (auto s = CheckFinite(x, Join(field, name)); !s.ok()) return s;
  }
  *out = Vec3(v.x(), v.y(), v.z());
  return grpc::Status::OK;
}

grpc::Status FromProto(const v1::Pose& p, std::string_view field, Pose* out) {
  Vec3 t = Vec3::Zero();
  if (p.has_position()) {
    if (auto s = FromProto(p.position(), Join(field, "position"), &t); !s.ok()) return s;
  }
  Quat q = Quat::Identity();
  if (p.has_orientation()) {
    const auto& o = p.orientation();
    const std::string f = Join(field, "orientation");
    for (auto [x, name] : {std::pair{o.w(), "w"}, std::pair{o.x(), "x"}, std::pair{o.y(), "y"},
                           std::pair{o.z(), "z"}}) {
      if (auto s = CheckFinite(x, Join(f, name)); !s.ok()) return s;
    }
    q = Quat(o.w(), o.x(), o.y(), o.z());
    const double n = q.norm();
    if (!(std::abs(n - 1.0) <= kQuaternionNormTolerance)) {
      return InvalidArgument(f, "quaternion norm " + std::to_string(n) +
                                    " is not 1 (a unit quaternion w, x, y, z is required)");
    }
    q.normalize();
  }
  *out = Pose::FromQuaternion(q, t);
  return grpc::Status::OK;
}

grpc::Status FromProto(const v1::Material& m, std::string_view field, pd::Material* out) {
  const std::pair<double, const char*> fields[] = {
      {m.stiffness(), "stiffness"},
      {m.rotational_stiffness(), "rotational_stiffness"},
      {m.damping(), "damping"},
      {m.static_friction(), "static_friction"},
      {m.dynamic_friction(), "dynamic_friction"}};
  for (auto [x, name] : fields) {
    if (!Finite(x) || x < 0) {
      return InvalidArgument(Join(field, name),
                             "must be finite and non-negative, got " + std::to_string(x));
    }
  }
  out->stiffness = m.stiffness();
  out->rotational_stiffness = m.rotational_stiffness();
  out->damping = m.damping();
  out->static_friction = m.static_friction();
  out->dynamic_friction = m.dynamic_friction();
  return grpc::Status::OK;
}

grpc::Status ValidateTwist(const v1::Twist& t, std::string_view field) {
  Vec3 v;
  if (auto s = FromProto(t.linear(), Join(field, "linear"), &v); !s.ok()) return s;
  return FromProto(t.angular(), Join(field, "angular"), &v);
}

grpc::Status MeshFromInline(const v1::InlineMesh& m, std::string_view field,
                            std::size_t max_triangles, std::optional<pd::Mesh>* out) {
  const std::string fv = Join(field, "vertices");
  const std::string ft = Join(field, "triangles");
  if (m.vertices_size() == 0) return InvalidArgument(fv, "is empty");
  if (m.vertices_size() % 3 != 0) {
    return InvalidArgument(fv, "length " + std::to_string(m.vertices_size()) +
                                   " is not a multiple of 3 (x, y, z per vertex)");
  }
  if (m.triangles_size() == 0) return InvalidArgument(ft, "is empty");
  if (m.triangles_size() % 3 != 0) {
    return InvalidArgument(ft, "length " + std::to_string(m.triangles_size()) +
                                   " is not a multiple of 3 (three indices per triangle)");
  }
  if (auto s = CheckTriangleLimit(m.triangles_size() / 3, max_triangles, field); !s.ok()) return s;
  const std::size_t nv = m.vertices_size() / 3;
  std::vector<Vec3> vertices(nv);
  for (std::size_t i = 0; i < nv; ++i) {
    for (int k = 0; k < 3; ++k) {
      const double x = m.vertices(static_cast<int>(3 * i + k));
      if (!Finite(x)) {
        return InvalidArgument(fv + "[" + std::to_string(3 * i + k) + "]",
                               "must be a finite number, got " + std::to_string(x));
      }
      vertices[i][k] = x;
    }
  }
  std::vector<pd::Triangle> triangles(m.triangles_size() / 3);
  for (int i = 0; i < m.triangles_size(); ++i) {
    const std::uint32_t idx = m.triangles(i);
    if (idx >= nv) {
      return InvalidArgument(ft + "[" + std::to_string(i) + "]",
                             "vertex index " + std::to_string(idx) + " is out of range (" +
                                 std::to_string(nv) + " vertices)");
    }
    triangles[i / 3][i % 3] = static_cast<Index>(idx);
  }
  try {
    *out = pd::Mesh::FromArrays(std::move(vertices), std::move(triangles), std::string(field));
  } catch (const pd::MeshError& e) {
    return InvalidArgument(field, StripSource(e.what(), std::string(field)));
  }
  return grpc::Status::OK;
}

grpc::Status MeshFromBytes(const std::string& bytes, v1::MeshFormat format, std::string_view field,
                           std::size_t max_triangles, std::optional<pd::Mesh>* out) {
  const char* ext = nullptr;
  switch (format) {
    case v1::MESH_FORMAT_OBJ:
      ext = ".obj";
      break;
    case v1::MESH_FORMAT_STL:
      ext = ".stl";
      break;
    case v1::MESH_FORMAT_PLY:
      ext = ".ply";
      break;
    case v1::MESH_FORMAT_OFF:
      ext = ".off";
      break;
    default:
      return InvalidArgument(Join(field, "format"), "unspecified or unknown mesh format");
  }
  if (bytes.empty()) return InvalidArgument(field, "no mesh bytes were sent");
  // pd::LoadMesh reads files (with format pre-scans); give it a private one.
  static std::atomic<std::uint64_t> counter{0};
  const std::filesystem::path dir = std::filesystem::temp_directory_path();
  const std::filesystem::path path = dir / ("hapticpd-upload-" + std::to_string(::getpid()) + "-" +
                                            std::to_string(counter.fetch_add(1)) + ext);
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
  if (fd < 0) {
    return grpc::Status(grpc::StatusCode::INTERNAL, "cannot create a temporary file for the mesh");
  }
  std::size_t written = 0;
  while (written < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + written, bytes.size() - written);
    if (n <= 0) break;
    written += static_cast<std::size_t>(n);
  }
  ::close(fd);
  struct Remove {
    std::filesystem::path p;
    ~Remove() {
      std::error_code ec;
      std::filesystem::remove(p, ec);
    }
  } remove{path};
  if (written != bytes.size()) {
    return grpc::Status(grpc::StatusCode::INTERNAL, "cannot write the mesh to a temporary file");
  }
  try {
    pd::Mesh mesh = pd::LoadMesh(path.string());
    if (auto s = CheckTriangleLimit(mesh.num_triangles(), max_triangles, field); !s.ok()) return s;
    *out = std::move(mesh);
  } catch (const pd::MeshError& e) {
    return InvalidArgument(field, StripSource(e.what(), path.string()));
  }
  return grpc::Status::OK;
}

grpc::Status MeshFromShape(const std::string& spec, std::string_view field,
                           std::size_t max_triangles, std::optional<pd::Mesh>* out) {
  try {
    pd::Mesh mesh = pd::shapes::MakeShape(spec);
    if (auto s = CheckTriangleLimit(mesh.num_triangles(), max_triangles, field); !s.ok()) return s;
    *out = std::move(mesh);
  } catch (const pd::MeshError& e) {
    return InvalidArgument(field, e.what());
  }
  return grpc::Status::OK;
}

grpc::Status ValidateId(const std::string& id, std::string_view field) {
  if (id.empty()) return InvalidArgument(field, "is empty");
  if (id.size() > 64) return InvalidArgument(field, "is longer than 64 characters");
  for (char c : id) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '-' || c == '.';
    if (!ok) return InvalidArgument(field, "may only contain A-Z a-z 0-9 _ . - (got '" + id + "')");
  }
  return grpc::Status::OK;
}

void ToProto(const Vec3& v, v1::Vec3* out) {
  out->set_x(v.x());
  out->set_y(v.y());
  out->set_z(v.z());
}

void ToProto(const Pose& p, v1::Pose* out) {
  ToProto(p.t, out->mutable_position());
  const Quat q = p.Rotation();
  auto* o = out->mutable_orientation();
  o->set_w(q.w());
  o->set_x(q.x());
  o->set_y(q.y());
  o->set_z(q.z());
}

void ToProto(const pd::Material& m, v1::Material* out) {
  out->set_stiffness(m.stiffness);
  out->set_rotational_stiffness(m.rotational_stiffness);
  out->set_damping(m.damping);
  out->set_static_friction(m.static_friction);
  out->set_dynamic_friction(m.dynamic_friction);
}

void ToProto(const pd::Mesh& mesh, v1::InlineMesh* out) {
  out->mutable_vertices()->Reserve(static_cast<int>(3 * mesh.num_vertices()));
  for (const Vec3& v : mesh.vertices()) {
    out->add_vertices(v.x());
    out->add_vertices(v.y());
    out->add_vertices(v.z());
  }
  out->mutable_triangles()->Reserve(static_cast<int>(3 * mesh.num_triangles()));
  for (const auto& t : mesh.triangles()) {
    for (Index i : t) out->add_triangles(static_cast<std::uint32_t>(i));
  }
}

std::int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

}  // namespace hapticpd::server
