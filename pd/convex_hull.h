// Exact 3-D convex hull of a point set, as a closed triangle mesh.
//
// Every geometric decision (is a point above, on or below a face's plane;
// are three points collinear) is an exact orientation predicate
// (pd/primitives.h Orient3d/Orient2d), so the hull is the exact convex hull
// of the given doubles: no tolerance, no dependence on the input's scale or
// order. Coplanar and degenerate input (cube corners, grids of coplanar
// points, points along hull edges, repeated points) is handled without
// special cases in the caller.
#pragma once

#include <span>
#include <string>

#include "pd/mesh.h"
#include "pd/types.h"

namespace hapticpd::pd {

struct ConvexHullOptions {
  /// Sliver removal: a triangle whose height over its longest edge (twice its
  /// area over the longest edge squared) is below this ratio loses the vertex
  /// opposite that edge, and the remaining points are hulled again. Such a
  /// vertex is barely extreme (typically rounding of points that should be
  /// collinear, e.g. a revolved straight profile), lies within
  /// ratio x |edge| of the returned hull, and would otherwise give a triangle
  /// whose normal is accurate only to ~1e-16 / ratio (Mesh sets it to zero
  /// below 1e-14). The default keeps normals accurate to ~1e-6. 0 keeps the
  /// exact hull of the input doubles. Must be in [0, 0.1).
  double sliver_ratio = 1e-10;
};

/// The convex hull of `points` (any frame; the result is in the same frame
/// and units) as a Mesh:
///   * its vertices are strictly extreme input points (vertices of the hull
///     polytope), copied bit for bit and each once: repeated points, interior
///     points and points on a hull face or edge are left out, and so are
///     vertices of slivers (see ConvexHullOptions::sliver_ratio); with
///     sliver_ratio = 0 the vertices are exactly the extreme points and every
///     input point is inside or on the hull (exact orientation);
///   * closed, two-manifold and consistently wound counter-clockwise seen
///     from outside (outward normals, positive volume): `watertight()` and
///     `IsConvexMesh` hold;
///   * a planar face of the polytope with k vertices becomes k - 2 coplanar
///     triangles, none of zero area (an arbitrary triangulation; its
///     diagonals are edges with a dihedral angle of exactly 180 degrees).
/// With sliver_ratio = 0, near-degenerate input is hulled exactly: a point a
/// hair (1e-15 relative) outside a face is a vertex, and its triangles may be
/// thin enough that Mesh reports them as zero-area.
///
/// Cost: expected O(n log n) for points in general position (Quickhull with
/// conflict lists), O(n h) worst case for h hull vertices; a second pass over
/// the hull vertices runs only when coplanar input left non-extreme vertices
/// in the first triangulation.
///
/// `source` names the input in error messages and in Mesh::source().
/// Throws MeshError when: fewer than 4 points are given; a coordinate is NaN,
/// infinite or larger than 1e100 in magnitude (the exact predicates' range,
/// see pd/primitives.h); all points are coplanar (including collinear and
/// all equal), i.e. there is no solid to enclose, or become so once slivers
/// are removed (flatter than sliver_ratio); sliver_ratio is out of range.
Mesh ConvexHull(std::span<const Vec3> points, const std::string& source = "convex hull",
                const ConvexHullOptions& options = {});

}  // namespace hapticpd::pd
