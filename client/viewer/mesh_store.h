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

/// Hash -> encoded mesh, shared by the Watch thread (which adds and
/// retires) and the HTTP handlers (which read). Thread-safe.
class MeshStore {
 public:
  /// Encodes and stores `mesh`; returns its hash, or "" for an empty or
  /// malformed mesh.
  std::string Add(const v1::InlineMesh& mesh);
  /// The encoded mesh, or null when unknown.
  std::shared_ptr<const std::string> Find(std::string_view hash) const;
  /// Drops every mesh whose hash is not in `keep`.
  void Retain(const std::set<std::string>& keep);
  std::size_t size() const;

 private:
  mutable std::mutex mu_;
  std::map<std::string, std::shared_ptr<const std::string>, std::less<>> meshes_;
};

}  // namespace hapticpd::viewer
