// Meshes the viewer serves to browsers by content hash (GET /mesh/<hash>).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <string_view>

#include "hapticpd/v1/types.pb.h"

namespace hapticpd::viewer {

/// The compact binary form of a mesh a browser fetches, little-endian:
///   bytes 0-3   "HPDM"
///   uint32      format version (1)
///   uint32      vertex count V
///   uint32      triangle count T
///   float32[3V] vertex positions (m, the mesh's own frame)
///   uint32[3T]  vertex indices, counter-clockwise seen from outside
/// Returns an empty string when `mesh` is empty or malformed (a vertex
/// array not a multiple of 3, an index out of range).
std::string EncodeMesh(const v1::InlineMesh& mesh);

/// 32 lowercase hex digits: the first 16 bytes of the SHA-256 of `blob`.
std::string ContentHash(std::string_view blob);

/// Whether `text` has the form ContentHash returns.
bool IsContentHash(std::string_view text);

/// The viewer's default limit for SimplifyForDisplay (--display-triangles):
/// what software WebGL draws at 30 frames/s or more beside a device session
/// on two cores (tests/bench/README.md "Viewer").
inline constexpr std::size_t kDefaultDisplayTriangles = 5000;

/// A mesh of at most `max_triangles` triangles that looks like `mesh` from
/// a viewer's distance, for drawing in software WebGL: vertices are merged
/// on a grid (vertex clustering, each cell's vertices replaced by their
/// mean) whose cell grows until the triangles that do not collapse fit.
/// Works on any triangle soup (holes, non-manifold edges). Returns `mesh`
/// unchanged when it fits or when `max_triangles` is 0.
v1::InlineMesh SimplifyForDisplay(const v1::InlineMesh& mesh, std::size_t max_triangles);

/// Hash -> encoded mesh, shared by the Watch thread (which adds and
/// retires) and the HTTP handlers (which read). Thread-safe.
class MeshStore {
 public:
  /// `max_display_triangles` > 0: meshes over it are stored simplified to
  /// it (SimplifyForDisplay), once per distinct mesh.
  explicit MeshStore(std::size_t max_display_triangles = 0)
      : max_display_triangles_(max_display_triangles) {}
  /// Encodes and stores `mesh` (simplified if over the display limit);
  /// returns the hash of what is stored, or "" for an empty or malformed
  /// mesh.
  std::string Add(const v1::InlineMesh& mesh);
  /// The encoded mesh, or null when unknown.
  std::shared_ptr<const std::string> Find(std::string_view hash) const;
  /// Drops every mesh whose hash is not in `keep`.
  void Retain(const std::set<std::string>& keep);
  std::size_t size() const;

 private:
  std::size_t max_display_triangles_;
  mutable std::mutex mu_;
  std::map<std::string, std::shared_ptr<const std::string>, std::less<>> meshes_;
  /// The hash of a mesh as it came -> the hash of its simplified form.
  std::map<std::string, std::string> simplified_;
};

}  // namespace hapticpd::viewer
