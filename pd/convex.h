// Exact translational penetration depth for convex polytopes by the
// separating-axis theorem with Gauss-map pruning of edge pairs (only edge
// pairs whose arcs cross on the unit sphere form faces of the Minkowski
// difference; Gregorius, "The Separating Axis Test between Convex
// Polyhedra", GDC 2013). Used by PDt for cold starts between convex models,
// where the contact-space iteration could stop on a local optimum.
#pragma once

#include <vector>

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

/// The edges' arcs on a convex mesh's Gauss map, in the mesh's own frame, in
/// a tree of bounding caps: ConvexPdt hands only the edge pairs whose caps
/// meet to its arc-crossing test. An edge's arc runs between its two faces'
/// normals (the minor arc: a convex polytope's dihedral angles are below 180
/// degrees); its cap is centred on the arc's midpoint with half the arc's
/// angle as radius. GeometryModel builds one per convex model, so that a
/// query does not.
class GaussArcTree {
 public:
  struct Arc {
    Vec3 n0, n1;  ///< the arc's end points (unit face normals)
    Vec3 plane;   ///< n1 x n0: the normal of the arc's great circle
    Vec3 c;       ///< cap centre (unit)
    double r;     ///< cap radius (rad)
    std::size_t edge;
  };
  struct Node {
    Vec3 c;                     ///< cap centre (unit)
    double r;                   ///< cap radius (rad), covering every arc below
    double cos_r, sin_r;        ///< of r, so that the cap test needs no trigonometry
    int first, count;           ///< the arcs [first, first + count) below
    Index support = 0;          ///< the arcs' edge end point farthest along c
    int left = -1, right = -1;  ///< inner node: children
    bool leaf() const { return left < 0; }
  };

  explicit GaussArcTree(const Mesh& mesh);
  const std::vector<Arc>& arcs() const { return arcs_; }
  const std::vector<Node>& nodes() const { return nodes_; }

 private:
  static constexpr int kLeafSize = 4;
  int Build(int first, int count);
  std::vector<Arc> arcs_;
  std::vector<Node> nodes_;
};

/// Exact PDt of convex A (pose X_WA) against convex B (X_WB).
/// Cost: each face axis one product with the last support vertex, and a
/// scan of the other body's vertices only where that bound does not rule
/// it out; the edge pairs whose Gauss-map arcs' bounding caps meet (found
/// by the two meshes' arc trees, built here), instead of all E_A E_B, less
/// the cap pairs where the caps' support vertices bound every axis's
/// separation below the best so far.
ConvexPdtResult ConvexPdt(const Mesh& A, const Pose& X_WA, const Mesh& B, const Pose& X_WB);

/// The same with the meshes' arc trees built beforehand (`arcs_A` from A,
/// `arcs_B` from B), as PDt's convex shortcut does with the models'.
ConvexPdtResult ConvexPdt(const Mesh& A, const GaussArcTree& arcs_A, const Pose& X_WA,
                          const Mesh& B, const GaussArcTree& arcs_B, const Pose& X_WB);

}  // namespace hapticpd::pd
