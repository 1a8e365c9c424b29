// Bounding volume hierarchy over a mesh's triangles.
//
// Choice of volume: axis-aligned boxes in the mesh's own frame, tested against
// each other under the relative rigid transform as oriented boxes (the
// 15-axis separating-axis test). Under rotation an AABB becomes an OBB of the
// other model's frame, so the pair test costs the same as OBB-vs-OBB; fitted
// OBBs would be tighter on slanted thin parts but need a covariance fit per
// node, which makes the build several times slower (a mesh upload waits for
// its BVH). Nodes are split by a binned surface-area heuristic along the
// widest centroid axis. Leaves hold up to 4 triangles: smaller leaves mean more
// box tests per query, larger ones more exact triangle tests. How the build
// and queries compare with FCL's: tests/bench/README.md.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include "pd/mesh.h"
#include "pd/types.h"

namespace hapticpd::pd {

struct BvhNode {
  Vec3 center;  ///< box centre, mesh frame
  Vec3 half;    ///< box half extents (>= 0)
  /// Internal node: index of the first child (the second is first + 1).
  /// Leaf: index of its first entry in Bvh::primitives().
  Index first = 0;
  /// Number of triangles in a leaf; 0 for an internal node.
  Index count = 0;
  /// Triangles under this node (leaf or internal).
  Index size = 0;
  bool leaf() const { return count > 0; }
};

class Bvh {
 public:
  /// Largest number of triangles per leaf.
  static constexpr int kMaxLeafSize = 4;

  explicit Bvh(const Mesh& mesh);

  const std::vector<BvhNode>& nodes() const { return nodes_; }
  /// Triangle indices in leaf order.
  const std::vector<Index>& primitives() const { return prims_; }
  const BvhNode& root() const { return nodes_[0]; }
  int depth() const { return depth_; }

 private:
  std::vector<BvhNode> nodes_;
  std::vector<Index> prims_;
  int depth_ = 0;
};

namespace internal {

/// The relative transform of box A's frame into box B's frame, with the
/// absolute rotation (plus a small epsilon against parallel-axis round-off)
/// precomputed for the separating-axis tests.
struct BoxFrame {
  Mat3 R;     ///< R_BA
  Mat3 absR;  ///< |R_BA| + eps
  Vec3 t;     ///< p_BAo
  explicit BoxFrame(const Pose& X_BA);
};

/// Separating-axis test between box a (in A's frame) and box b (in B's
/// frame). Returns true when no axis separates them by more than `margin`.
/// `sweep_B` (may be zero) extends box a along the displacement it undergoes,
/// expressed in B; the test stays conservative (the 15 axes suffice to prove
/// separation of the swept volume; missing axes only cost extra visits).
bool BoxesOverlap(const BoxFrame& f, const BvhNode& a, const BvhNode& b, double margin,
                  const Vec3& sweep_B);

/// A BoxFrame with a sweep: the sweep's projection on each of the 6 face
/// axes and its reciprocal are fixed for a whole query, so they are computed
/// once and the per-pair test needs no division.
struct SweptBoxFrame {
  BoxFrame f;
  Vec3 sweep;                 ///< displacement of A, in B
  std::array<double, 6> v;    ///< sweep . axis (B axes, then A axes)
  std::array<double, 6> inv;  ///< 1 / v (unused where v == 0)
  std::array<double, 6> sgn;  ///< sign of v (+1 or -1; unused where v == 0)
  double r[3][3];             ///< f.R, f.absR and f.t as plain arrays for the
  double ar[3][3];            ///< per-pair test's scalar code
  double t[3];
  double rtt[3];  ///< R^T t: A's origin offset on A's axes
  SweptBoxFrame(const Pose& X_BA, const Vec3& sweep_B);
};

/// Time interval of overlap of box a, moving by t * sf.sweep for t in
/// [0, t_max], with box b, from the 6 face axes of the two boxes (a
/// conservative superset of the true interval: the cross axes cost more
/// than the visits they save). Returns false when no axis
/// admits overlap in [0, t_max]; otherwise *t_enter is a lower bound on the
/// first contact time of anything inside the boxes. `margin` inflates both
/// boxes (m): the interval then covers every time at which the boxes are
/// within `margin` of each other.
bool BoxesSweptEnter(const SweptBoxFrame& sf, const BvhNode& a, const BvhNode& b, double t_max,
                     double* t_enter, double margin = 0);

/// The parts of BoxesSweptEnter that depend on one box and the rotation
/// only, so a caller whose sweeps share the rotation (PDt's) computes them
/// once per node: for box a, c = R a.center and r = |R| a.half (its radii on
/// B's axes); for box b, c = R^T b.center and r = |R|^T b.half (its radii
/// on A's axes). R = sf.f.R, |R| = sf.f.absR.
struct RotatedBox {
  Vec3 c;
  Vec3 r;
};
inline RotatedBox RotateBoxA(const SweptBoxFrame& sf, const BvhNode& a) {
  RotatedBox o;
  const double(&R)[3][3] = sf.r;
  const double(&AR)[3][3] = sf.ar;
  for (int i = 0; i < 3; ++i) {
    o.c[i] = R[i][0] * a.center[0] + R[i][1] * a.center[1] + R[i][2] * a.center[2];
    o.r[i] = AR[i][0] * a.half[0] + AR[i][1] * a.half[1] + AR[i][2] * a.half[2];
  }
  return o;
}
inline RotatedBox RotateBoxB(const SweptBoxFrame& sf, const BvhNode& b) {
  RotatedBox o;
  const double(&R)[3][3] = sf.r;
  const double(&AR)[3][3] = sf.ar;
  for (int j = 0; j < 3; ++j) {
    o.c[j] = R[0][j] * b.center[0] + R[1][j] * b.center[1] + R[2][j] * b.center[2];
    o.r[j] = AR[0][j] * b.half[0] + AR[1][j] * b.half[1] + AR[2][j] * b.half[2];
  }
  return o;
}

// Clips [*lo, *hi] to the times at which |c + t v| <= r on one axis (v the
// sweep's projection, inv its reciprocal, sgn its sign); false once the
// interval is empty. With the sign known, the entry time is (-sgn r - c) inv
// and the exit time (sgn r - c) inv: the same products as ordering the two
// crossing times, without the ordering.
inline bool ClipAxis(double c, double r, double v, double inv, double sgn, double* lo, double* hi) {
  if (v == 0) return std::abs(c) <= r;
  const double sr = sgn * r;
  *lo = std::max(*lo, (-sr - c) * inv);
  *hi = std::min(*hi, (sr - c) * inv);
  return *lo <= *hi;
}

/// BoxesSweptEnter with both boxes' rotated parts given. Inline: it is the
/// translational CCD traversal's per-pair test, the hottest code of a sweep,
/// and would be called across translation units otherwise.
inline bool BoxesSweptEnter(const SweptBoxFrame& sf, const BvhNode& a, const RotatedBox& ra,
                            const BvhNode& b, const RotatedBox& rb, double t_max, double* t_enter,
                            double margin) {
  // The hottest function of a PDt query: plain scalar code on the boxes'
  // rotated parts (computed once per node by the caller).
  double lo = 0, hi = t_max;
  // Along axis L: |T.L + t s.L| <= r must hold at contact, with s.L the
  // sweep's projection. Radii are inflated by the margin and a round-off
  // slack relative to the magnitudes involved.
  auto clip = [&](int k, double c, double r) {
    r += margin + 1e-12 * (std::abs(c) + r);
    return ClipAxis(c, r, sf.v[k], sf.inv[k], sf.sgn[k], &lo, &hi);
  };
  // Face axes of B: centre offset R a.c + t - b.c.
  for (int i = 0; i < 3; ++i) {
    if (!clip(i, ra.c[i] + sf.t[i] - b.center[i], ra.r[i] + b.half[i])) return false;
  }
  // Face axes of A (column j of R): the same offset on A's axes,
  // a.c + R^T t - R^T b.c.
  for (int j = 0; j < 3; ++j) {
    if (!clip(3 + j, a.center[j] + sf.rtt[j] - rb.c[j], a.half[j] + rb.r[j])) return false;
  }
  // No cross axes: they would rule out few more pairs at twice the cost per
  // pair, so a query does less work without them. The six face axes still
  // bound the swept volume conservatively.
  *t_enter = lo;
  return true;
}

/// A lower bound on the distance between box a and box b, from the 6 face
/// axes (0 when they may overlap).
double BoxesDistanceLowerBound(const BoxFrame& f, const BvhNode& a, const BvhNode& b);

}  // namespace internal
}  // namespace hapticpd::pd
