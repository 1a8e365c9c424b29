#include "pd/mesh.h"

#include <OpenMesh/Core/IO/MeshIO.hh>
#include <OpenMesh/Core/IO/importer/ImporterT.hh>
#include <OpenMesh/Core/Mesh/PolyMesh_ArrayKernelT.hh>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <mutex>
#include <sstream>

#include "pd/mesh_readers.h"

namespace hapticpd::pd {
namespace {

struct DoubleTraits : public OpenMesh::DefaultTraits {
  using Point = OpenMesh::Vec3d;
  using Normal = OpenMesh::Vec3d;
};
using OmMesh = OpenMesh::PolyMesh_ArrayKernelT<DoubleTraits>;

// Records the polygon soup exactly as the reader produces it. OpenMesh's own
// importer splits faces that would make an edge non-manifold onto duplicated
// vertices; we keep our own copy of the indices so nothing is hidden, and let
// the base importer run only so the readers' bookkeeping stays valid.
class SoupImporter final : public OpenMesh::IO::ImporterT<OmMesh> {
 public:
  explicit SoupImporter(OmMesh& m) : ImporterT<OmMesh>(m) {}

  OpenMesh::VertexHandle add_vertex(const OpenMesh::Vec3f& p) override {
    soup.points.emplace_back(p[0], p[1], p[2]);
    return ImporterT<OmMesh>::add_vertex(p);
  }
  OpenMesh::VertexHandle add_vertex(const OpenMesh::Vec3d& p) override {
    soup.points.emplace_back(p[0], p[1], p[2]);
    return ImporterT<OmMesh>::add_vertex(p);
  }
  OpenMesh::VertexHandle add_vertex() override {
    soup.points.emplace_back(0.0, 0.0, 0.0);
    return ImporterT<OmMesh>::add_vertex();
  }
  void set_point(OpenMesh::VertexHandle vh, const OpenMesh::Vec3f& p) override {
    if (vh.is_valid() && static_cast<std::size_t>(vh.idx()) < soup.points.size()) {
      soup.points[vh.idx()] = Vec3(p[0], p[1], p[2]);
    }
    ImporterT<OmMesh>::set_point(vh, p);
  }

  OpenMesh::FaceHandle add_face(const VHandles& idx) override {
    bool valid = idx.size() >= 3;
    for (const auto& vh : idx) {
      soup.corners.push_back(static_cast<Index>(vh.idx()));
      if (!vh.is_valid() || static_cast<std::size_t>(vh.idx()) >= soup.points.size()) {
        valid = false;
      }
    }
    soup.EndFace();
    for (std::size_t i = 0; valid && i < idx.size(); ++i) {
      for (std::size_t j = i + 1; j < idx.size(); ++j) valid = valid && idx[i] != idx[j];
    }
    // Only hand the base importer faces it can take without complaint.
    if (!valid) return OpenMesh::FaceHandle();
    return ImporterT<OmMesh>::add_face(idx);
  }

  internal::PolygonSoup soup;
};

// OpenMesh's OBJ reader silently skips a vertex line it cannot parse (e.g.
// "v nan 0 0"), which would shift every later index, and silently drops faces
// that repeat a vertex. Scan the text first so such files fail with the real
// reason. Returns the number of face lines.
std::size_t PrescanObj(const std::string& path) {
  std::ifstream in(path);
  std::string line;
  std::size_t lineno = 0, faces = 0;
  while (std::getline(in, line)) {
    ++lineno;
    // The keyword ends at any white space, as OpenMesh's reader reads it
    // (`stream >> keyword`): "f\t/x/" is a face line too.
    internal::Tokens tokens(line);
    std::string_view key;
    if (!tokens.Next(&key)) continue;
    if (key != "v") {
      if (key == "f") {
        ++faces;
        // Every corner ("v", "v/vt", "v//vn", "v/vt/vn") starts with an index;
        // OpenMesh's reader aborts the process (an assert) on a face whose
        // corners yield none, e.g. "f /x/".
        for (std::string_view c; tokens.Next(&c);) {
          const std::size_t d = c[0] == '-' ? 1 : 0;
          if (d >= c.size() || !std::isdigit(static_cast<unsigned char>(c[d]))) {
            throw MeshError(path + ": line " + std::to_string(lineno) + ": face corner '" +
                            internal::Printable(c) + "' does not start with a vertex index");
          }
        }
      }
      continue;
    }
    const char* p = tokens.rest().data();
    for (int k = 0; k < 3; ++k) {
      char* end = nullptr;
      const double x = std::strtod(p, &end);
      if (end == p) {
        throw MeshError(path + ": line " + std::to_string(lineno) +
                        ": vertex has fewer than 3 numeric coordinates");
      }
      if (!std::isfinite(x)) {
        throw MeshError(
            path + ": line " + std::to_string(lineno) + ": vertex has a non-finite coordinate (" +
            internal::Printable(line.substr(line.find_first_not_of(internal::kSpace)), 80) + ")");
      }
      p = end;
    }
  }
  return faces;
}

// STL: a binary file's size is fixed by its triangle count; a mismatch is a
// truncated or foreign file unless it is ASCII ("solid ... facet").
void PrescanStl(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string head(512, '\0');
  in.read(head.data(), static_cast<std::streamsize>(head.size()));
  head.resize(static_cast<std::size_t>(in.gcount()));
  const auto size = std::filesystem::file_size(path);
  const bool ascii = head.rfind("solid", 0) == 0 && head.find("facet") != std::string::npos;
  if (size >= 84) {
    std::uint32_t n = 0;
    std::memcpy(&n, head.data() + 80, 4);
    const std::uint64_t expect = 84 + 50ull * n;
    if (expect == size) return;
    if (!ascii) {
      throw MeshError(path + ": not a valid STL: binary header says " + std::to_string(n) +
                      " triangles (" + std::to_string(expect) + " bytes) but the file has " +
                      std::to_string(size) + " bytes, and it is not ASCII STL");
    }
    return;
  }
  if (!ascii) throw MeshError(path + ": not a valid STL: too short for binary and not ASCII");
}

std::string Lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

}  // namespace

Mesh Mesh::FromArrays(std::vector<Vec3> vertices, std::vector<Triangle> triangles,
                      std::string source, const MeshOptions& options) {
  Mesh m;
  m.source_ = std::move(source);
  m.vertices_ = std::move(vertices);
  m.triangles_ = std::move(triangles);
  m.Build(options);
  return m;
}

void Mesh::Build(const MeshOptions& options) {
  CheckSizesAndVertices(options);
  DropRepeatedVertexTriangles(options);
  ComputeFaceNormals(options);
  BuildEdges();
  AssignFeatureOwners();
  ComputeBounds();
}

// Counts against the limits, then every vertex finite.
void Mesh::CheckSizesAndVertices(const MeshOptions& options) const {
  const std::string& src = source_;
  if (vertices_.size() > options.max_vertices) {
    throw MeshError(src + ": " + std::to_string(vertices_.size()) +
                    " vertices exceed the limit of " + std::to_string(options.max_vertices));
  }
  if (triangles_.size() > options.max_triangles) {
    throw MeshError(src + ": " + std::to_string(triangles_.size()) +
                    " triangles exceed the limit of " + std::to_string(options.max_triangles));
  }
  if (triangles_.empty()) throw MeshError(src + ": the mesh has no triangles");
  const auto nv = static_cast<Index>(vertices_.size());
  for (Index i = 0; i < nv; ++i) {
    const Vec3& p = vertices_[i];
    if (!p.allFinite()) {
      std::ostringstream os;
      os << src << ": vertex " << i << " has a non-finite coordinate (" << p.x() << ", " << p.y()
         << ", " << p.z() << ")";
      throw MeshError(os.str());
    }
  }
}

// Indices in range; triangles repeating a vertex index dropped (or refused).
void Mesh::DropRepeatedVertexTriangles(const MeshOptions& options) {
  const std::string& src = source_;
  const auto nv = static_cast<Index>(vertices_.size());
  std::vector<Triangle> kept;
  kept.reserve(triangles_.size());
  for (std::size_t f = 0; f < triangles_.size(); ++f) {
    const Triangle& t = triangles_[f];
    for (int k = 0; k < 3; ++k) {
      if (t[k] < 0 || t[k] >= nv) {
        throw MeshError(src + ": triangle " + std::to_string(f) + " refers to vertex " +
                        std::to_string(t[k]) + ", out of range [0, " + std::to_string(nv) + ")");
      }
    }
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) {
      if (options.degenerate == DegeneratePolicy::kReject) {
        throw MeshError(src + ": triangle " + std::to_string(f) + " repeats a vertex index");
      }
      ++dropped_;
      continue;
    }
    kept.push_back(t);
  }
  if (dropped_ > 0) {
    diagnostics_.push_back(std::to_string(dropped_) +
                           " triangle(s) repeating a vertex index were dropped");
  }
  triangles_ = std::move(kept);
  if (triangles_.empty()) throw MeshError(src + ": the mesh has no non-degenerate triangles");
}

// Unit normals; zero-area triangles keep a zero normal (or are refused).
void Mesh::ComputeFaceNormals(const MeshOptions& options) {
  const std::string& src = source_;
  const auto nf = static_cast<Index>(triangles_.size());
  face_normals_.resize(nf);
  int first_zero_area = -1;
  for (Index f = 0; f < nf; ++f) {
    const Triangle& t = triangles_[f];
    const Vec3 n = (vertices_[t[1]] - vertices_[t[0]]).cross(vertices_[t[2]] - vertices_[t[0]]);
    const double len = n.norm();
    // Zero area relative to the triangle's own edge lengths (scale free).
    const double scale = std::max({(vertices_[t[1]] - vertices_[t[0]]).squaredNorm(),
                                   (vertices_[t[2]] - vertices_[t[1]]).squaredNorm(),
                                   (vertices_[t[0]] - vertices_[t[2]]).squaredNorm()});
    if (!(len > 1e-14 * scale)) {
      face_normals_[f] = Vec3::Zero();
      if (first_zero_area < 0) first_zero_area = f;
      ++degenerate_kept_;
    } else {
      face_normals_[f] = n / len;
    }
  }
  if (degenerate_kept_ > 0) {
    if (options.degenerate == DegeneratePolicy::kReject) {
      throw MeshError(src + ": triangle " + std::to_string(first_zero_area) + " has zero area (" +
                      std::to_string(degenerate_kept_) + " degenerate triangle(s) in all)");
    }
    diagnostics_.push_back(std::to_string(degenerate_kept_) +
                           " zero-area triangle(s) kept (first: triangle " +
                           std::to_string(first_zero_area) + ")");
  }
}

// Edge adjacency: sort directed half-edges by their undirected key; counts
// boundary, non-manifold and misoriented edges.
void Mesh::BuildEdges() {
  const auto nf = static_cast<Index>(triangles_.size());
  struct HalfEdge {
    Index a, b;  // a < b
    Index face;
    std::int8_t k;  // edge slot in the face
    bool forward;   // face traverses a -> b
  };
  std::vector<HalfEdge> he;
  he.reserve(3 * static_cast<std::size_t>(nf));
  for (Index f = 0; f < nf; ++f) {
    for (int k = 0; k < 3; ++k) {
      const Index u = triangles_[f][k];
      const Index v = triangles_[f][(k + 1) % 3];
      he.push_back({std::min(u, v), std::max(u, v), f, static_cast<std::int8_t>(k), u < v});
    }
  }
  std::sort(he.begin(), he.end(), [](const HalfEdge& x, const HalfEdge& y) {
    return x.a != y.a ? x.a < y.a : (x.b != y.b ? x.b < y.b : x.face < y.face);
  });
  face_edges_.assign(nf, {-1, -1, -1});
  edges_.clear();
  edges_.reserve(he.size() / 2 + 1);
  for (std::size_t i = 0; i < he.size();) {
    std::size_t j = i;
    while (j < he.size() && he[j].a == he[i].a && he[j].b == he[i].b) ++j;
    const auto e = static_cast<Index>(edges_.size());
    Edge edge;
    edge.v = {he[i].a, he[i].b};
    edge.f[0] = he[i].face;
    if (j - i >= 2) edge.f[1] = he[i + 1].face;
    edges_.push_back(edge);
    for (std::size_t k = i; k < j; ++k) face_edges_[he[k].face][he[k].k] = e;
    const std::size_t count = j - i;
    if (count == 1) {
      ++boundary_edges_;
    } else if (count > 2) {
      ++nonmanifold_edges_;
    } else if (he[i].forward == he[i + 1].forward) {
      ++misoriented_edges_;
    }
    i = j;
  }
  if (boundary_edges_ > 0) {
    diagnostics_.push_back("open mesh: " + std::to_string(boundary_edges_) + " boundary edge(s)");
  }
  if (nonmanifold_edges_ > 0) {
    diagnostics_.push_back("non-manifold: " + std::to_string(nonmanifold_edges_) +
                           " edge(s) shared by three or more triangles");
  }
  if (misoriented_edges_ > 0) {
    diagnostics_.push_back("inconsistent orientation: " + std::to_string(misoriented_edges_) +
                           " edge(s) traversed the same way by both triangles");
  }
}

// Feature ownership: the first face (lowest index) touching a vertex/edge.
void Mesh::AssignFeatureOwners() {
  const auto nf = static_cast<Index>(triangles_.size());
  vertex_owner_.assign(vertices_.size(), -1);
  owned_mask_.assign(nf, 0);
  for (Index f = 0; f < nf; ++f) {
    for (int k = 0; k < 3; ++k) {
      Index& owner = vertex_owner_[triangles_[f][k]];
      if (owner < 0) {
        owner = f;
        owned_mask_[f] |= static_cast<std::uint8_t>(1u << k);
      }
      if (edges_[face_edges_[f][k]].f[0] == f) {
        owned_mask_[f] |= static_cast<std::uint8_t>(1u << (3 + k));
      }
    }
  }
  // Faces are sorted by index inside each edge group, so f[0] is the lowest;
  // a non-manifold edge's extra faces never own it.
}

// Bounds and bounding radius of the vertices some triangle uses.
void Mesh::ComputeBounds() {
  const auto nv = static_cast<Index>(vertices_.size());
  bounds_ = Aabb{};
  for (Index v = 0; v < nv; ++v) {
    if (vertex_owner_[v] >= 0) bounds_.Extend(vertices_[v]);
  }
  const Vec3 c = bounds_.Center();
  bounding_radius_ = 0;
  for (Index v = 0; v < nv; ++v) {
    if (vertex_owner_[v] >= 0) {
      bounding_radius_ = std::max(bounding_radius_, (vertices_[v] - c).norm());
    }
  }
}

Mesh Mesh::Transformed(const Pose& X_NM) const {
  std::vector<Vec3> v(vertices_.size());
  for (std::size_t i = 0; i < v.size(); ++i) v[i] = X_NM * vertices_[i];
  MeshOptions opt;
  return FromArrays(std::move(v), triangles_, source_, opt);
}

Mesh LoadMesh(const std::string& path, const MeshOptions& options) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(path, ec)) throw MeshError(path + ": no such file");
  if (fs::is_directory(path, ec)) throw MeshError(path + ": is a directory, not a mesh file");
  {
    std::ifstream probe(path, std::ios::binary);
    if (!probe) throw MeshError(path + ": cannot be opened for reading");
  }
  const std::string ext = Lower(fs::path(path).extension().string());
  if (ext != ".obj" && ext != ".off" && ext != ".stl" && ext != ".ply") {
    throw MeshError(path + ": unsupported extension '" + ext +
                    "' (supported: .obj, .off, .stl, .ply)");
  }
  if (fs::file_size(path, ec) == 0) throw MeshError(path + ": file is empty");

  internal::PolygonSoup soup;
  std::string why;
  std::size_t obj_faces = 0;
  if (ext == ".off" || ext == ".ply") {
    // Our own readers (pd/mesh_readers.h): OpenMesh's trust the header counts
    // and can allocate gigabytes on a body that does not match them.
    std::ifstream in(path, std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (!in && !in.eof()) throw MeshError(path + ": cannot be read");
    soup = ext == ".off" ? internal::ReadOff(path, bytes) : internal::ReadPly(path, bytes);
  } else {
    if (ext == ".obj") obj_faces = PrescanObj(path);
    if (ext == ".stl") PrescanStl(path);
    OmMesh om;
    SoupImporter importer(om);
    OpenMesh::IO::Options opt;
    // OpenMesh prints parse complaints on its own error stream; capture them
    // so they become part of our error message instead of stray stderr
    // output. The capture stream is connected once for the process
    // (OpenMesh's disconnect leaks its wrapper, so no connect/disconnect per
    // load), and reads are serialised: the stream and OpenMesh's reader
    // registry are process-wide.
    static std::mutex io_mutex;
    static std::ostringstream om_errors;
    bool ok = false;
    {
      std::lock_guard<std::mutex> lock(io_mutex);
      static const bool redirected = [] {
        ::omerr().connect(om_errors);
        ::omerr().disconnect(std::cerr);
        return true;
      }();
      (void)redirected;
      om_errors.str(std::string());
      om_errors.clear();
      try {
        ok = OpenMesh::IO::IOManager().read(path, importer, opt);
      } catch (const std::exception& e) {
        om_errors << e.what();
      }
      why = om_errors.str();
    }
    std::replace(why.begin(), why.end(), '\n', ' ');
    while (!why.empty() && why.back() == ' ') why.pop_back();
    if (!ok && importer.soup.num_faces() == 0) {
      throw MeshError(path + ": could not be parsed as " + ext.substr(1) +
                      (why.empty() ? std::string() : " (" + why + ")"));
    }
    soup = std::move(importer.soup);
  }

  // Polygons are fan-triangulated; faces with fewer than 3 corners are errors.
  std::vector<Triangle> tris;
  tris.reserve(soup.num_faces());
  const auto nv = static_cast<Index>(soup.points.size());
  for (std::size_t f = 0; f < soup.num_faces(); ++f) {
    const Index* poly = soup.corners.data() + soup.face_begin(f);
    const std::size_t n = soup.face_end[f] - soup.face_begin(f);
    for (std::size_t k = 0; k < n; ++k) {
      if (poly[k] < 0 || poly[k] >= nv) {
        throw MeshError(path + ": face " + std::to_string(f) + " refers to vertex " +
                        std::to_string(poly[k]) + ", out of range [0, " + std::to_string(nv) + ")");
      }
    }
    if (n < 3) {
      throw MeshError(path + ": face " + std::to_string(f) + " has fewer than 3 vertices");
    }
    for (std::size_t k = 1; k + 1 < n; ++k) tris.push_back({poly[0], poly[k], poly[k + 1]});
  }
  if (tris.empty() && obj_faces > 0) {
    throw MeshError(path + ": no non-degenerate triangles (the reader skipped all " +
                    std::to_string(obj_faces) + " face(s): repeated or invalid vertex indices)");
  }
  if (tris.empty()) {
    throw MeshError(path + ": no faces found" + (why.empty() ? std::string() : " (" + why + ")"));
  }
  const std::size_t faces_read = soup.num_faces();
  Mesh mesh = Mesh::FromArrays(std::move(soup.points), std::move(tris), path, options);
  if (obj_faces > faces_read) {
    mesh.AddDiagnostic(std::to_string(obj_faces - faces_read) +
                       " face(s) skipped by the OBJ reader (repeated or invalid vertex indices)");
  }
  return mesh;
}

}  // namespace hapticpd::pd
