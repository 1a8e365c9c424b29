// The immutable triangle-mesh model every query runs on.
//
// A `Mesh` is built once (from a mesh file, from arrays, or from a
// procedural shape) and then shared read-only, typically as
// `std::shared_ptr<const Mesh>`. Coordinates are in the mesh's own frame M.
#pragma once

#include <array>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "pd/types.h"

namespace hapticpd::pd {

/// Thrown when a mesh cannot be loaded or built. `what()` names the source
/// (file path or shape name) and the problem, e.g.
/// "bunny.obj: vertex 12 has a non-finite coordinate (nan)".
class MeshError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

using Triangle = std::array<Index, 3>;

/// An undirected edge with up to two incident faces. `f[1] == -1` on a
/// boundary edge. Non-manifold edges (three or more faces) keep their first
/// two faces here and are counted in `Mesh::nonmanifold_edge_count()`.
struct Edge {
  std::array<Index, 2> v{-1, -1};  // v[0] < v[1]
  std::array<Index, 2> f{-1, -1};
};

/// Axis-aligned box, `lo <= hi` componentwise when non-empty.
struct Aabb {
  Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity());
  Vec3 hi = Vec3::Constant(-std::numeric_limits<double>::infinity());
  void Extend(const Vec3& p) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  Vec3 Center() const { return 0.5 * (lo + hi); }
  Vec3 HalfExtent() const { return 0.5 * (hi - lo); }
  Vec3 Size() const { return hi - lo; }
};

/// How `Mesh::FromArrays` treats degenerate triangles. Triangles that repeat a
/// vertex index are never kept (they have no surface); collinear, zero-area
/// triangles are kept by default, since PD must cope with them (they have a
/// zero normal and never create contact planes), and listed in diagnostics.
enum class DegeneratePolicy {
  kKeepAndReport,  // default: keep zero-area ones, drop index-repeating ones
  kReject,         // throw MeshError on any degenerate triangle
};

struct MeshOptions {
  DegeneratePolicy degenerate = DegeneratePolicy::kKeepAndReport;
  /// Hard limits against hostile input.
  std::size_t max_vertices = 20'000'000;
  std::size_t max_triangles = 20'000'000;
};

class Mesh {
 public:
  /// Builds a mesh from arrays. `source` names the origin in error messages.
  /// Throws MeshError on: no triangles, a non-finite vertex coordinate, a
  /// vertex index out of range, a size limit exceeded, or (with
  /// DegeneratePolicy::kReject) any degenerate triangle.
  static Mesh FromArrays(std::vector<Vec3> vertices, std::vector<Triangle> triangles,
                         std::string source, const MeshOptions& options = {});

  const std::string& source() const { return source_; }
  const std::vector<Vec3>& vertices() const { return vertices_; }
  const std::vector<Triangle>& triangles() const { return triangles_; }
  const std::vector<Edge>& edges() const { return edges_; }
  /// Unit outward normal of each face (counter-clockwise winding seen from
  /// outside); exactly zero for a zero-area face.
  const std::vector<Vec3>& face_normals() const { return face_normals_; }
  /// Edge ids of face f: edge k joins triangle[f][k] and triangle[f][(k+1)%3].
  const std::array<Index, 3>& face_edges(Index f) const { return face_edges_[f]; }

  /// Feature ownership, used to enumerate vertex-face, face-vertex and
  /// edge-edge pairs exactly once per triangle pair: each vertex and each edge
  /// is owned by one incident face (-1 for unreferenced vertices).
  Index vertex_owner(Index v) const { return vertex_owner_[v]; }
  Index edge_owner(Index e) const { return edges_[e].f[0]; }
  /// Bit k of owned_mask(f): vertex k of f is owned by f; bit 3+k: edge k is.
  std::uint8_t owned_mask(Index f) const { return owned_mask_[f]; }

  std::size_t num_vertices() const { return vertices_.size(); }
  std::size_t num_triangles() const { return triangles_.size(); }

  int boundary_edge_count() const { return boundary_edges_; }
  int nonmanifold_edge_count() const { return nonmanifold_edges_; }
  /// Manifold edges whose two faces traverse them in the same direction.
  int misoriented_edge_count() const { return misoriented_edges_; }
  int degenerate_triangle_count() const { return degenerate_kept_; }
  int dropped_triangle_count() const { return dropped_; }
  /// Closed, two-manifold and consistently oriented: inside/outside is defined.
  bool watertight() const {
    return boundary_edges_ == 0 && nonmanifold_edges_ == 0 && misoriented_edges_ == 0;
  }
  /// Human-readable notes about what was dropped or flagged while building.
  const std::vector<std::string>& diagnostics() const { return diagnostics_; }

  const Aabb& bounds() const { return bounds_; }
  /// Largest distance of a vertex from the bounds' centre.
  double bounding_radius() const { return bounding_radius_; }
  /// Length of the bounding-box diagonal: the model's size for relative
  /// tolerances.
  double size() const { return bounds_.Size().norm(); }

  /// Appends a note to diagnostics() (used by loaders).
  void AddDiagnostic(std::string note) { diagnostics_.push_back(std::move(note)); }

  /// A copy with every vertex mapped through X_NM (new frame N from M).
  Mesh Transformed(const Pose& X_NM) const;

 private:
  void Build(const MeshOptions& options);
  // Build's stages, in order.
  void CheckSizesAndVertices(const MeshOptions& options) const;
  void DropRepeatedVertexTriangles(const MeshOptions& options);
  void ComputeFaceNormals(const MeshOptions& options);
  void BuildEdges();
  void AssignFeatureOwners();
  void ComputeBounds();

  std::string source_;
  std::vector<Vec3> vertices_;
  std::vector<Triangle> triangles_;
  std::vector<Edge> edges_;
  std::vector<Vec3> face_normals_;
  std::vector<std::array<Index, 3>> face_edges_;
  std::vector<Index> vertex_owner_;
  std::vector<std::uint8_t> owned_mask_;
  std::vector<std::string> diagnostics_;
  Aabb bounds_;
  double bounding_radius_ = 0;
  int boundary_edges_ = 0;
  int nonmanifold_edges_ = 0;
  int misoriented_edges_ = 0;
  int degenerate_kept_ = 0;
  int dropped_ = 0;
};

/// Loads OBJ, STL (ASCII or binary) through OpenMesh's readers, and plain OFF
/// and PLY (ASCII or binary) through our own (pd/mesh_readers.h, memory
/// O(file size)), keeping the polygon soup as written (polygons are
/// fan-triangulated, non-manifold faces are kept, not split off). Coordinates
/// are read in single precision in every format. Throws MeshError naming the
/// file on a missing or unreadable file, an unknown extension, a parse
/// failure (with the line for OBJ, OFF and ASCII PLY), or any error of
/// Mesh::FromArrays.
Mesh LoadMesh(const std::string& path, const MeshOptions& options = {});

}  // namespace hapticpd::pd
