// Exact translational penetration depth for convex polytopes by the
// separating-axis theorem with Gauss-map pruning of edge pairs (only edge
// pairs whose arcs cross on the unit sphere form faces of the Minkowski
// difference; Gregorius, "The Separating Axis Test between Convex
// Polyhedra", GDC 2013). Used by PDt for cold starts between convex models,
// where the contact-space iteration could stop on a local optimum.
#pragma once

#include "pd/mesh.h"
#include "pd/types.h"

namespace hapticpd::pd {

/// A closed, genus-0 mesh with no reflex edge (within a relative tolerance):
/// a convex polytope. Coplanar neighbouring faces are allowed.
bool IsConvexMesh(const Mesh& mesh);

struct ConvexPdtResult {
  bool overlapping = false;
  double depth = 0;                   ///< m; 0 when separated or touching
  Vec3 translation_W = Vec3::Zero();  ///< moves A out of B, |t| = depth
};

/// Exact PDt of convex A (pose X_WA) against convex B (X_WB).
/// Cost: each face axis one product with the last support vertex, and a
/// scan of the other body's vertices only where that bound does not rule
/// it out; the edge pairs whose Gauss-map arcs' bounding caps meet (found
/// by two cap trees built per call), instead of all E_A E_B.
ConvexPdtResult ConvexPdt(const Mesh& A, const Pose& X_WA, const Mesh& B, const Pose& X_WB);

}  // namespace hapticpd::pd
