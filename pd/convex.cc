#include "pd/convex.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <utility>

namespace hapticpd::pd {

bool IsConvexMesh(const Mesh& mesh) {
  if (!mesh.watertight()) return false;
  const long chi = static_cast<long>(mesh.num_vertices()) - static_cast<long>(mesh.edges().size()) +
                   static_cast<long>(mesh.num_triangles());
  if (chi != 2) return false;  // one genus-0 component (no stray vertices)
  const auto& V = mesh.vertices();
  const auto& T = mesh.triangles();
  const double tol = 1e-9 * mesh.size();
  for (const Edge& e : mesh.edges()) {
    const Index f0 = e.f[0], f1 = e.f[1];
    const Vec3& n0 = mesh.face_normals()[f0];
    // The vertex of f1 not on the edge must not lie above f0's plane.
    for (int k = 0; k < 3; ++k) {
      const Index v = T[f1][k];
      if (v == e.v[0] || v == e.v[1]) continue;
      if (n0.dot(V[v] - V[e.v[0]]) > tol) return false;
    }
  }
  return true;
}

namespace {

struct Placed {
  std::vector<Vec3> v;  // world vertices
  std::vector<Vec3> n;  // world face normals
};

Placed Place(const Mesh& m, const Pose& X) {
  Placed p;
  p.v.reserve(m.num_vertices());
  for (const Vec3& x : m.vertices()) p.v.push_back(X * x);
  p.n.reserve(m.num_triangles());
  for (const Vec3& n : m.face_normals()) p.n.push_back(X.R * n);
  return p;
}

// An upper bound on the angle between unit vectors a and b, tight for small
// angles: 2 asin(h) with h half the chord, and asin(h) <= h + h^3 /
// (6 (1 - h^2)) (every term of asin's series past the first has a
// coefficient of at most 1/6). Larger angles get the exact value.
double CapAngle(const Vec3& a, const Vec3& b) {
  const double h = 0.5 * (a - b).norm();
  if (h < 0.5) return 2 * (h + h * h * h / (6 * (1 - h * h))) + 1e-12;
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

// Whether two caps of the arc trees (centres ca, cb) can share a point: the
// angle between the centres is at most ra + rb, i.e. ca.cb >= cos(ra + rb),
// expanded from the radii's stored cosines and sines. Generous by 2e-7 (more
// than a 1e-7 rad wider reach) so that rounding never drops a crossing.
bool CapsMeet(const Vec3& ca, const GaussArcTree::Node& a, const Vec3& cb,
              const GaussArcTree::Node& b) {
  if (a.r + b.r + 1e-7 >= std::numbers::pi) return true;
  return ca.dot(cb) >= a.cos_r * b.cos_r - a.sin_r * b.sin_r - 2e-7;
}

// The largest -n.w over the unit vectors n of the cap with centre c (unit)
// and the node's radius: |w| cos(max(0, theta - r)), theta the angle
// between c and -w; len = |w|.
double CapMaxAgainst(const Vec3& c, const GaussArcTree::Node& node, const Vec3& w, double len) {
  const double k = -c.dot(w);  // |w| cos(theta)
  if (node.r >= std::numbers::pi || k >= len * node.cos_r) return len;
  return k * node.cos_r + std::sqrt(std::max(0.0, len * len - k * k)) * node.sin_r;
}

}  // namespace

GaussArcTree::GaussArcTree(const Mesh& mesh) {
  const std::vector<Edge>& edges = mesh.edges();
  const std::vector<Vec3>& n = mesh.face_normals();
  arcs_.reserve(edges.size());
  for (std::size_t e = 0; e < edges.size(); ++e) {
    if (edges[e].f[0] < 0 || edges[e].f[1] < 0) continue;  // boundary: not a polytope edge
    const Vec3& n0 = n[edges[e].f[0]];
    const Vec3& n1 = n[edges[e].f[1]];
    const Vec3 plane = n1.cross(n0);
    if (plane.squaredNorm() < 1e-24) continue;  // flat edge: no arc
    const Vec3 mid = n0 + n1;
    const double len = mid.norm();
    if (len > 1e-9) {
      arcs_.push_back({n0, n1, plane, mid / len, 0.5 * CapAngle(n0, n1), e});
    } else {
      arcs_.push_back({n0, n1, plane, n0, std::numbers::pi, e});
    }
  }
  nodes_.reserve(2 * arcs_.size() / kLeafSize + 2);
  if (!arcs_.empty()) Build(0, static_cast<int>(arcs_.size()));
  // Each cap's support vertex: ConvexPdt bounds the separation along every
  // axis of a node pair by the two supports' difference.
  const std::vector<Vec3>& v = mesh.vertices();
  for (Node& node : nodes_) {
    double far = -std::numeric_limits<double>::infinity();
    for (int i = node.first; i < node.first + node.count; ++i) {
      for (const Index k : edges[arcs_[i].edge].v) {
        if (node.c.dot(v[k]) > far) {
          far = node.c.dot(v[k]);
          node.support = k;
        }
      }
    }
  }
}

int GaussArcTree::Build(int first, int count) {
  const int index = static_cast<int>(nodes_.size());
  nodes_.push_back({Vec3::UnitZ(), std::numbers::pi, -1, 0, first, count});
  Vec3 mean = Vec3::Zero();
  Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (int i = first; i < first + count; ++i) {
    mean += arcs_[i].c;
    lo = lo.cwiseMin(arcs_[i].c);
    hi = hi.cwiseMax(arcs_[i].c);
  }
  const bool split = count > kLeafSize;
  if (split) {
    int axis;
    (hi - lo).maxCoeff(&axis);
    const int half = count / 2;
    std::nth_element(arcs_.begin() + first, arcs_.begin() + first + half,
                     arcs_.begin() + first + count,
                     [axis](const Arc& a, const Arc& b) { return a.c[axis] < b.c[axis]; });
    const int left = Build(first, half);
    const int right = Build(first + half, count - half);
    nodes_[index].left = left;
    nodes_[index].right = right;
  }
  // The cap: around the mean direction, wide enough for the children's caps
  // (inner node) or the arcs' own (leaf).
  if (mean.norm() > 1e-6 * count) {
    const Vec3 c = mean.normalized();
    double r = 0;
    if (split) {
      for (const int k : {nodes_[index].left, nodes_[index].right}) {
        r = std::max(r, CapAngle(c, nodes_[k].c) + nodes_[k].r);
      }
    } else {
      for (int i = first; i < first + count; ++i) {
        r = std::max(r, CapAngle(c, arcs_[i].c) + arcs_[i].r);
      }
    }
    nodes_[index].c = c;
    nodes_[index].r = std::min(r, std::numbers::pi);
  }
  nodes_[index].cos_r = std::cos(nodes_[index].r);
  nodes_[index].sin_r = std::sin(nodes_[index].r);
  return index;
}

ConvexPdtResult ConvexPdt(const Mesh& A, const Pose& X_WA, const Mesh& B, const Pose& X_WB) {
  return ConvexPdt(A, GaussArcTree(A), X_WA, B, GaussArcTree(B), X_WB);
}

ConvexPdtResult ConvexPdt(const Mesh& A, const GaussArcTree& arcs_a, const Pose& X_WA,
                          const Mesh& B, const GaussArcTree& arcs_b, const Pose& X_WB) {
  const Placed a = Place(A, X_WA);
  const Placed b = Place(B, X_WB);
  // Separation along u: how far A's support lies beyond B's, i.e.
  // min_a u.a - max_b u.b when u points from B to A. Negative = overlap; the
  // PD is -max over candidate axes, attained moving A by |s| along u.
  double best_sep = -std::numeric_limits<double>::infinity();
  Vec3 best_u = Vec3::UnitZ();
  auto consider = [&](const Vec3& u, double sep) {
    if (sep > best_sep) {
      best_sep = sep;
      best_u = u;
    }
  };
  // Face axes. A face's separation needs the other body's support (a scan
  // of its vertices); the vertex that gave the last support bounds it from
  // above in one product, which settles most faces (neighbouring faces have
  // nearby supports, and most are far below the best).
  auto faces = [&](const Placed& self, const std::vector<Triangle>& T, double sign,
                   const Placed& other) {
    std::size_t hint = 0;
    for (std::size_t f = 0; f < T.size(); ++f) {
      // Separation along u = sign n: the other body's support below minus
      // the face's own plane (sign +1: faces of B, the other is A; sign -1:
      // faces of A, the other is B, seen along -n).
      const Vec3 u = sign * self.n[f];
      if (u.squaredNorm() == 0) continue;
      const double plane = u.dot(self.v[T[f][0]]);
      const double bound = sign * (u.dot(other.v[hint]) - plane);
      if (bound <= best_sep) continue;
      double m = std::numeric_limits<double>::infinity();
      for (std::size_t i = 0; i < other.v.size(); ++i) {
        const double x = sign * u.dot(other.v[i]);
        if (x < m) {
          m = x;
          hint = i;
        }
      }
      consider(u, m - sign * plane);
    }
  };
  // Faces of B: u = n_B (outward of B), B's support is the face itself, A's
  // is its lowest vertex along u.
  faces(b, B.triangles(), 1.0, a);
  // Faces of A: u = -n_A; A's support along u is the face itself, B's is its
  // highest vertex along u.
  faces(a, A.triangles(), -1.0, b);
  // Edge pairs that form Minkowski faces: their arcs cross on the Gauss map
  // (of A's normals and B's negated normals). The cap trees hand over only
  // pairs whose caps meet. The trees are in the meshes' own frames: A's
  // caps and arcs are turned into B's frame by R, B's are negated there.
  const Mat3 R = X_WB.R.transpose() * X_WA.R;
  const auto& EA = A.edges();
  const auto& EB = B.edges();
  // A's arc x turned into B's frame (n1, n2 and their plane n2 x n1)
  // against B's arc y, whose negation (c, d) = (-m1, -m2) must cross it.
  auto edge_pair = [&](const Vec3& n1, const Vec3& n2, const Vec3& bxa, std::size_t edge_a,
                       const GaussArcTree::Arc& y) {
    const Vec3& dxc = y.plane;  // d x c = m2 x m1
    const double cba = -y.n0.dot(bxa), dba = -y.n1.dot(bxa);
    const double adc = n1.dot(dxc), bdc = n2.dot(dxc);
    if (!(cba * dba < 0 && adc * bdc < 0 && cba * bdc > 0)) return;
    const Edge& ea = EA[edge_a];
    const Edge& eb = EB[y.edge];
    const Vec3 pa = a.v[ea.v[0]];
    const Vec3 da = a.v[ea.v[1]] - pa;
    const Vec3 pb = b.v[eb.v[0]];
    const Vec3 db = b.v[eb.v[1]] - pb;
    Vec3 u = da.cross(db);
    const double len = u.norm();
    if (len < 1e-12 * da.norm() * db.norm()) return;
    u /= len;
    // Orient from B to A: A's outward normals there point against u.
    if (u.dot(X_WB.R * (n1 + n2)) > 0) u = -u;
    consider(u, u.dot(pa - pb));
  };
  if (!arcs_a.nodes().empty() && !arcs_b.nodes().empty()) {
    const auto& NA = arcs_a.nodes();
    const auto& NB = arcs_b.nodes();
    // A's cap centres and arcs turned into B's frame once (a node or an arc
    // meets many of B's), and both trees' support vertices placed there.
    std::vector<Vec3> centre_a(NA.size()), support_a(NA.size()), support_b(NB.size());
    const Mat3 R_BW = X_WB.R.transpose();
    for (std::size_t k = 0; k < NA.size(); ++k) {
      centre_a[k] = R * NA[k].c;
      support_a[k] = R_BW * a.v[NA[k].support];
    }
    for (std::size_t k = 0; k < NB.size(); ++k) support_b[k] = R_BW * b.v[NB[k].support];
    struct TurnedArc {
      Vec3 n1, n2, plane;
      std::size_t edge;
    };
    std::vector<TurnedArc> arc_a(arcs_a.arcs().size());
    for (std::size_t k = 0; k < arc_a.size(); ++k) {
      const GaussArcTree::Arc& x = arcs_a.arcs()[k];
      arc_a[k] = {R * x.n0, R * x.n1, R * x.plane, x.edge};
    }
    std::vector<std::pair<int, int>> stack{{0, 0}};
    while (!stack.empty()) {
      const auto [ia, ib] = stack.back();
      stack.pop_back();
      const GaussArcTree::Node& na = NA[ia];
      const GaussArcTree::Node& nb = NB[ib];
      if (!CapsMeet(centre_a[ia], na, -nb.c, nb)) continue;
      // Every axis u of this pair's edge pairs is -n for a normal n of A in
      // both caps, and the separation along u is at most u.(p_A - p_B) for
      // any points of A and B: with the caps' supports, nothing here can
      // beat the best axis so far once that bound falls below it.
      const Vec3 w = support_a[ia] - support_b[ib];
      const double len = w.norm();
      if (std::min(CapMaxAgainst(centre_a[ia], na, w, len), CapMaxAgainst(-nb.c, nb, w, len)) <
          best_sep - 1e-9 * len) {
        continue;
      }
      if (na.leaf() && nb.leaf()) {
        for (int i = na.first; i < na.first + na.count; ++i) {
          const TurnedArc& x = arc_a[i];
          for (int j = nb.first; j < nb.first + nb.count; ++j) {
            edge_pair(x.n1, x.n2, x.plane, x.edge, arcs_b.arcs()[j]);
          }
        }
      } else if (nb.leaf() || (!na.leaf() && na.r >= nb.r)) {
        stack.push_back({na.left, ib});
        stack.push_back({na.right, ib});
      } else {
        stack.push_back({ia, nb.left});
        stack.push_back({ia, nb.right});
      }
    }
  }
  ConvexPdtResult r;
  r.overlapping = best_sep < 0;
  if (r.overlapping) {
    r.depth = -best_sep;
    r.translation_W = best_u * r.depth;
  }
  return r;
}

}  // namespace hapticpd::pd
