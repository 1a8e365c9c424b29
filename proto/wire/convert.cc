#include "proto/wire/convert.h"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <sstream>
#include <string>
#include <tuple>

#include "pd/shapes.h"
#include "proto/wire/text.h"

namespace hapticpd::wire {
namespace {

std::string Join(std::string_view field, std::string_view sub) {
  std::string s(field);
  s += '.';
  s += sub;
  return s;
}

bool Finite(double x) { return std::isfinite(x); }

grpc::Status CheckFinite(double x, std::string_view field) {
  if (!Finite(x)) return InvalidArgument(field, RangeProblem(x, kCoordinate));
  return grpc::Status::OK;
}

/// A triangle count as an integer (exact below 2^53, where every count of a
/// procedural shape up to 1e6-sized resolutions lies), else in e-notation.
std::string CountText(double n) {
  if (n < 9.0e15) return std::to_string(static_cast<std::uint64_t>(n));
  std::ostringstream s;
  s << n;
  return s.str();
}

grpc::Status CheckTriangleLimit(double triangles, std::size_t limit, std::string_view field) {
  if (!(triangles <= static_cast<double>(limit))) {
    return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                        std::string(field) + ": " + CountText(triangles) +
                            " triangles exceed the server limit of " + std::to_string(limit));
  }
  return grpc::Status::OK;
}

grpc::Status ShapeError(std::string_view field, const std::string& spec,
                        const std::string& problem) {
  return InvalidArgument(field, "shape spec '" + Printable(spec) + "': " + problem);
}

/// MeshError messages start with the source name; replace it by the field.
grpc::Status CheckExtent(double diagonal, std::string_view field) {
  // PD's tolerances are relative to a body's size; a point-like mesh has none.
  if (!(diagonal >= kMinMeshExtent)) {
    std::ostringstream s;
    s << "bounding-box diagonal " << diagonal << " m is below the minimum of " << kMinMeshExtent
      << " m";
    return InvalidArgument(field, s.str());
  }
  return grpc::Status::OK;
}

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

grpc::Status FromProto(const v1::Vec3& v, std::string_view field, Vec3* out, const Range& range) {
  for (auto [x, name] : {std::pair{v.x(), "x"}, std::pair{v.y(), "y"}, std::pair{v.z(), "z"}}) {
    if (auto s = CheckRange(x, range, Join(field, name)); !s.ok()) return s;
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
    if (!IsUnitQuaternion(q)) {
      return InvalidArgument(f, "quaternion norm " + std::to_string(q.norm()) +
                                    " is not 1 (a unit quaternion w, x, y, z is required)");
    }
    q.normalize();
  }
  *out = Pose::FromQuaternion(q, t);
  return grpc::Status::OK;
}

std::string MaterialProblem(const v1::Material& m, std::string_view field) {
  const std::tuple<double, const char*, const Range*> fields[] = {
      {m.stiffness(), "stiffness", &kStiffness},
      {m.rotational_stiffness(), "rotational_stiffness", &kRotationalStiffness},
      {m.damping(), "damping", &kDamping},
      {m.static_friction(), "static_friction", &kFriction},
      {m.dynamic_friction(), "dynamic_friction", &kFriction}};
  for (auto [x, name, range] : fields) {
    if (std::string p = RangeProblem(x, *range); !p.empty()) return Join(field, name) + ": " + p;
  }
  // Kinetic friction above static would make a sliding contact stick harder
  // than a resting one.
  if (m.dynamic_friction() > m.static_friction()) {
    std::ostringstream s;
    s << Join(field, "dynamic_friction") << ": must not exceed static_friction ("
      << m.dynamic_friction() << " > " << m.static_friction() << ")";
    return s.str();
  }
  return {};
}

grpc::Status FromProto(const v1::Material& m, std::string_view field, pd::Material* out) {
  if (std::string p = MaterialProblem(m, field); !p.empty()) {
    return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, p);
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
  if (auto s = FromProto(t.linear(), Join(field, "linear"), &v, kLinearVelocity); !s.ok()) {
    return s;
  }
  return FromProto(t.angular(), Join(field, "angular"), &v, kAngularVelocity);
}

grpc::Status CheckMeshRanges(const pd::Mesh& mesh, std::string_view field) {
  const auto& vs = mesh.vertices();
  for (std::size_t i = 0; i < vs.size(); ++i) {
    for (int k = 0; k < 3; ++k) {
      if (std::string p = RangeProblem(vs[i][k], kCoordinate); !p.empty()) {
        return InvalidArgument(
            field, "vertex " + std::to_string(i) + " coordinate " + "xyz"[k] + ": " + p);
      }
    }
  }
  return CheckExtent(mesh.bounds().Size().stableNorm(), field);
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
      if (auto s = CheckRange(x, kCoordinate, fv + "[" + std::to_string(3 * i + k) + "]");
          !s.ok()) {
        return s;
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
  Vec3 lo = vertices[0], hi = vertices[0];
  for (const Vec3& v : vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  if (auto s = CheckExtent((hi - lo).stableNorm(), field); !s.ok()) return s;
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
    if (auto s = CheckMeshRanges(mesh, field); !s.ok()) return s;
    *out = std::move(mesh);
  } catch (const pd::MeshError& e) {
    return InvalidArgument(field, StripSource(e.what(), path.string()));
  }
  return grpc::Status::OK;
}

grpc::Status CheckShapeSpec(const std::string& spec, std::string_view field,
                            std::size_t max_triangles, pd::shapes::ShapeSpec* parsed) {
  pd::shapes::ShapeSpec p;
  try {
    p = pd::shapes::ParseShapeSpec(spec);
    for (std::size_t i = 0; i < p.params.size(); ++i) {
      const pd::shapes::ShapeParam& param = p.params[i];
      if (!param.length || (param.zero_ok && p.values[i] == 0)) continue;
      if (std::string r = RangeProblem(p.values[i], kShapeLength); !r.empty()) {
        return ShapeError(field, spec, param.name + " " + r);
      }
    }
    if (p.reach > kCoordinate.hi) {
      std::ostringstream s;
      s << "reaches " << p.reach << " m from its origin, beyond the coordinate range "
        << Describe(kCoordinate);
      return ShapeError(field, spec, s.str());
    }
    pd::shapes::CheckShapeSizes(p);
  } catch (const pd::shapes::ShapeSpecError& e) {
    return ShapeError(field, spec, e.problem());
  }
  // Counted, not built: a huge resolution costs nothing to reject.
  if (auto s = CheckTriangleLimit(p.triangles, max_triangles, field); !s.ok()) return s;
  if (p.triangles > static_cast<double>(pd::shapes::kMaxShapeTriangles)) {
    return ShapeError(field, spec,
                      "resolution too high: " + CountText(p.triangles) +
                          " triangles, more than the limit of " +
                          std::to_string(pd::shapes::kMaxShapeTriangles));
  }
  if (parsed != nullptr) *parsed = std::move(p);
  return grpc::Status::OK;
}

grpc::Status MeshFromShape(const std::string& spec, std::string_view field,
                           std::size_t max_triangles, std::optional<pd::Mesh>* out) {
  pd::shapes::ShapeSpec p;
  if (auto s = CheckShapeSpec(spec, field, max_triangles, &p); !s.ok()) return s;
  try {
    *out = pd::shapes::MakeShape(p);
  } catch (const pd::shapes::ShapeSpecError& e) {
    return ShapeError(field, spec, e.problem());
  } catch (const pd::MeshError& e) {
    return ShapeError(field, spec, e.what());
  }
  return grpc::Status::OK;
}

grpc::Status ValidateId(const std::string& id, std::string_view field) {
  if (id.empty()) return InvalidArgument(field, "is empty");
  if (id.size() > 64) return InvalidArgument(field, "is longer than 64 characters");
  for (char c : id) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '-' || c == '.';
    if (!ok)
      return InvalidArgument(field,
                             "may only contain A-Z a-z 0-9 _ . - (got '" + Printable(id) + "')");
  }
  return grpc::Status::OK;
}

Vec3 FromProtoUnchecked(const v1::Vec3& v) { return Vec3(v.x(), v.y(), v.z()); }

Pose FromProtoUnchecked(const v1::Pose& p) {
  const Vec3 t = FromProtoUnchecked(p.position());
  if (!p.has_orientation()) return Pose::FromTranslation(t);
  const auto& q = p.orientation();
  return Pose::FromQuaternion(Quat(q.w(), q.x(), q.y(), q.z()), t);
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

void ToProto(const pd::GeometryModel& model, v1::MeshInfo* out) {
  const pd::Mesh& m = model.mesh();
  out->set_triangles(static_cast<std::uint32_t>(m.num_triangles()));
  out->set_vertices(static_cast<std::uint32_t>(m.num_vertices()));
  out->set_watertight(m.watertight());
  out->set_convex(model.convex());
  ToProto(m.bounds().lo, out->mutable_aabb_min());
  ToProto(m.bounds().hi, out->mutable_aabb_max());
  ToProto(model.mass().p_MC, out->mutable_center_of_mass());
  out->set_bounding_radius(m.bounding_radius());
  for (const auto& d : m.diagnostics()) out->add_diagnostics(d);
}

std::int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

}  // namespace hapticpd::wire
