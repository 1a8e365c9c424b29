// What a device client holds of its session's geometry patches, applied the
// way the GeometryPatch contract says, with every rule of the contract
// checked on the way (consecutive sequences, indices in range, a new
// triangle's vertices held, nothing sent twice, nothing dropped that is not
// held, a vertex held exactly while a held triangle uses it).
#pragma once

#include <gtest/gtest.h>

#include <array>
#include <cstdint>
#include <map>
#include <set>
#include <string>

#include "hapticpd/v1/haptic.pb.h"
#include "pd/mesh.h"
#include "pd/primitives.h"

namespace hapticpd::testing {

struct PatchClient {
  struct Body {
    std::uint64_t key = 0;
    std::uint32_t triangle_count = 0;
    std::uint32_t vertex_count = 0;
    std::map<std::uint32_t, std::array<std::uint32_t, 3>> triangles;
    std::map<std::uint32_t, Vec3> vertices;
    std::map<std::uint32_t, int> refs;
    v1::BodyPatch last;  ///< the latest listing, without its arrays
  };
  std::map<std::string, Body> bodies;
  std::uint64_t sequence = 0;

  void Apply(const v1::GeometryPatch& p) {
    EXPECT_EQ(p.sequence(), sequence + 1) << "a patch was lost or reordered";
    sequence = p.sequence();
    for (const std::string& id : p.dropped_bodies()) {
      EXPECT_EQ(bodies.erase(id), 1u) << "dropped body '" << id << "' was not held";
    }
    std::set<std::string> listed;
    for (const v1::BodyPatch& bp : p.bodies()) {
      EXPECT_TRUE(listed.insert(bp.body_id()).second) << bp.body_id() << " listed twice";
      for (const std::string& id : p.dropped_bodies()) EXPECT_NE(id, bp.body_id());
      Body& b = bodies[bp.body_id()];
      if (b.key != bp.body_key()) b = Body{};
      b.key = bp.body_key();
      b.triangle_count = bp.triangle_count();
      b.vertex_count = bp.vertex_count();
      for (std::uint32_t f : bp.dropped_triangles()) {
        const auto it = b.triangles.find(f);
        ASSERT_NE(it, b.triangles.end()) << "dropped triangle " << f << " was not held";
        for (std::uint32_t v : it->second) {
          if (--b.refs[v] == 0) {
            b.refs.erase(v);
            b.vertices.erase(v);
          }
        }
        b.triangles.erase(it);
      }
      ASSERT_EQ(bp.vertices_size(), 3 * bp.vertex_indices_size());
      for (int k = 0; k < bp.vertex_indices_size(); ++k) {
        const std::uint32_t v = bp.vertex_indices(k);
        EXPECT_LT(v, bp.vertex_count());
        EXPECT_FALSE(b.vertices.contains(v)) << "vertex " << v << " sent while held";
        b.vertices[v] = Vec3(bp.vertices(3 * k), bp.vertices(3 * k + 1), bp.vertices(3 * k + 2));
      }
      ASSERT_EQ(bp.triangles_size(), 3 * bp.triangle_indices_size());
      for (int k = 0; k < bp.triangle_indices_size(); ++k) {
        const std::uint32_t f = bp.triangle_indices(k);
        EXPECT_LT(f, bp.triangle_count());
        EXPECT_FALSE(b.triangles.contains(f)) << "triangle " << f << " sent while held";
        std::array<std::uint32_t, 3> t{};
        for (int j = 0; j < 3; ++j) {
          t[j] = bp.triangles(3 * k + j);
          EXPECT_TRUE(b.vertices.contains(t[j]))
              << "triangle " << f << " uses vertex " << t[j] << ", which the client does not hold";
          ++b.refs[t[j]];
        }
        b.triangles[f] = t;
      }
      // Every held vertex is used by a held triangle.
      EXPECT_EQ(b.refs.size(), b.vertices.size());
      b.last = bp;
      b.last.clear_vertex_indices();
      b.last.clear_vertices();
      b.last.clear_triangle_indices();
      b.last.clear_triangles();
      b.last.clear_dropped_triangles();
    }
  }

  /// The held triangles of `id` (empty when the body is not held).
  std::set<std::uint32_t> Held(const std::string& id) const {
    std::set<std::uint32_t> out;
    const auto it = bodies.find(id);
    if (it == bodies.end()) return out;
    for (const auto& [f, t] : it->second.triangles) out.insert(f);
    return out;
  }
};

/// Triangles of `mesh` within `radius` of `p_M` (brute force).
inline std::set<std::uint32_t> TrianglesWithin(const pd::Mesh& mesh, const Vec3& p_M,
                                               double radius) {
  std::set<std::uint32_t> out;
  const auto& V = mesh.vertices();
  for (std::size_t f = 0; f < mesh.num_triangles(); ++f) {
    const pd::Triangle& t = mesh.triangles()[f];
    const Vec3 q = pd::internal::ClosestPointOnTriangle(p_M, V[t[0]], V[t[1]], V[t[2]], nullptr);
    if ((q - p_M).norm() <= radius) out.insert(static_cast<std::uint32_t>(f));
  }
  return out;
}

/// The held triangles' vertex data equals the mesh's.
inline void ExpectVerticesOf(const pd::Mesh& mesh, const PatchClient::Body& b) {
  EXPECT_EQ(b.vertex_count, mesh.num_vertices());
  EXPECT_EQ(b.triangle_count, mesh.num_triangles());
  for (const auto& [v, p] : b.vertices) EXPECT_EQ(p, mesh.vertices()[v]) << "vertex " << v;
  for (const auto& [f, t] : b.triangles) {
    for (int j = 0; j < 3; ++j) {
      EXPECT_EQ(t[j], static_cast<std::uint32_t>(mesh.triangles()[f][j])) << "triangle " << f;
    }
  }
}

}  // namespace hapticpd::testing
