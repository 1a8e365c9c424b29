#include "pd/convex.h"

#include <cmath>
#include <limits>

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
  Vec3 centroid = Vec3::Zero();
};

Placed Place(const Mesh& m, const Pose& X) {
  Placed p;
  p.v.reserve(m.num_vertices());
  for (const Vec3& x : m.vertices()) {
    p.v.push_back(X * x);
    p.centroid += p.v.back();
  }
  p.centroid /= static_cast<double>(p.v.size());
  p.n.reserve(m.num_triangles());
  for (const Vec3& n : m.face_normals()) p.n.push_back(X.R * n);
  return p;
}

double MinAlong(const std::vector<Vec3>& v, const Vec3& u) {
  double m = std::numeric_limits<double>::infinity();
  for (const Vec3& x : v) m = std::min(m, u.dot(x));
  return m;
}

}  // namespace

ConvexPdtResult ConvexPdt(const Mesh& A, const Pose& X_WA, const Mesh& B, const Pose& X_WB) {
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
  // Faces of B: u = n_B (outward of B), B's support is the face itself.
  const auto& TB = B.triangles();
  for (std::size_t f = 0; f < TB.size(); ++f) {
    const Vec3& n = b.n[f];
    if (n.squaredNorm() == 0) continue;
    consider(n, MinAlong(a.v, n) - n.dot(b.v[TB[f][0]]));
  }
  // Faces of A: u = -n_A; A's support along u is the face itself.
  const auto& TA = A.triangles();
  for (std::size_t f = 0; f < TA.size(); ++f) {
    const Vec3 u = -a.n[f];
    if (u.squaredNorm() == 0) continue;
    consider(u, u.dot(a.v[TA[f][0]]) + MinAlong(b.v, -u));
  }
  // Edge pairs that form Minkowski faces.
  for (const Edge& ea : A.edges()) {
    const Vec3& n1 = a.n[ea.f[0]];
    const Vec3& n2 = a.n[ea.f[1]];
    const Vec3 pa = a.v[ea.v[0]];
    const Vec3 da = a.v[ea.v[1]] - pa;
    if (n1.cross(n2).squaredNorm() < 1e-24) continue;  // flat edge
    for (const Edge& eb : B.edges()) {
      // Arcs (n1, n2) of A and (-m1, -m2) of B must cross on the sphere.
      const Vec3 c = -b.n[eb.f[0]];
      const Vec3 d = -b.n[eb.f[1]];
      if (c.cross(d).squaredNorm() < 1e-24) continue;
      const Vec3 bxa = n2.cross(n1);
      const Vec3 dxc = d.cross(c);
      const double cba = c.dot(bxa), dba = d.dot(bxa);
      const double adc = n1.dot(dxc), bdc = n2.dot(dxc);
      if (!(cba * dba < 0 && adc * bdc < 0 && cba * bdc > 0)) continue;
      const Vec3 pb = b.v[eb.v[0]];
      const Vec3 db = b.v[eb.v[1]] - pb;
      Vec3 u = da.cross(db);
      const double len = u.norm();
      if (len < 1e-12 * da.norm() * db.norm()) continue;
      u /= len;
      // Orient from B to A: A's outward normals there point against u.
      if (u.dot(n1 + n2) > 0) u = -u;
      consider(u, u.dot(pa - pb));
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
