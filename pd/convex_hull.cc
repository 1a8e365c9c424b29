#include "pd/convex_hull.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <sstream>
#include <vector>

#include "pd/primitives.h"

namespace hapticpd::pd {
namespace {

using internal::Orient2d;
using internal::Orient3d;

// Exactly collinear: the three coordinate projections (the components of
// (b - a) x (c - a)) all have exactly zero area.
bool Collinear(const Vec3& a, const Vec3& b, const Vec3& c) {
  auto proj = [](const Vec3& p, int i, int j) { return Vec2(p[i], p[j]); };
  for (auto [i, j] : {std::pair{0, 1}, std::pair{1, 2}, std::pair{2, 0}}) {
    if (Orient2d(proj(a, i, j), proj(b, i, j), proj(c, i, j)) != 0) return false;
  }
  return true;
}

struct Face {
  std::array<int, 3> v{};    // counter-clockwise seen from outside
  std::array<int, 3> nb{};   // face across edge v[k] -> v[(k + 1) % 3]
  std::vector<int> outside;  // unprocessed points strictly above this face
  bool alive = true;
  bool visible = false;
};

// Quickhull (Barber, Dobkin, Huhdanpaa 1996) with exact visibility: a face is
// visible from q iff q is strictly above its plane. A point on the plane of a
// face is not "above" it, so a point that extends a planar face of the hull
// adds coplanar triangles next to it (never a zero-area one: each new
// triangle joins q to a horizon edge of a face q is strictly above). Points
// on the hull's boundary or inside it are dropped; points that were extreme
// when inserted but end up on a face or an edge of the final hull stay as
// vertices (see NonExtremeVertices).
class Quickhull {
 public:
  Quickhull(const std::vector<Vec3>& p, const std::string& source) : p_(p), source_(source) {}

  std::vector<Triangle> Run() {
    InitialSimplex();
    start_of_.assign(p_.size(), -1);
    end_of_.assign(p_.size(), -1);
    std::vector<int> stack = {0, 1, 2, 3};
    std::vector<int> visible, created;
    while (!stack.empty()) {
      const int f = stack.back();
      stack.pop_back();
      if (!faces_[f].alive || faces_[f].outside.empty()) continue;
      // The farthest conflict point (heights over one face are comparable).
      int q = -1;
      double best = 0;
      for (int r : faces_[f].outside) {
        const double h = Height(f, r);
        if (q < 0 || h > best) {
          q = r;
          best = h;
        }
      }
      // Visible region: connected, grown from f.
      visible.assign(1, f);
      faces_[f].visible = true;
      for (std::size_t i = 0; i < visible.size(); ++i) {
        for (int k = 0; k < 3; ++k) {
          const int g = faces_[visible[i]].nb[k];
          if (!faces_[g].visible && Height(g, q) > 0) {
            faces_[g].visible = true;
            visible.push_back(g);
          }
        }
      }
      // Cone from q over the horizon.
      created.clear();
      for (int vf : visible) {
        for (int k = 0; k < 3; ++k) {
          const int outer = faces_[vf].nb[k];
          if (faces_[outer].visible) continue;
          const int u = faces_[vf].v[k], w = faces_[vf].v[(k + 1) % 3];
          const int g = static_cast<int>(faces_.size());
          faces_.push_back(Face{{u, w, q}, {outer, -1, -1}, {}, true, false});
          ReplaceNeighbour(outer, vf, g);
          if (start_of_[u] >= 0 || end_of_[w] >= 0) Internal("the horizon is not a simple cycle");
          start_of_[u] = g;
          end_of_[w] = g;
          created.push_back(g);
        }
      }
      for (int g : created) {
        Face& face = faces_[g];
        face.nb[1] = start_of_[face.v[1]];  // edge w -> q: the face starting at w
        face.nb[2] = end_of_[face.v[0]];    // edge q -> u: the face ending at u
        if (face.nb[1] < 0 || face.nb[2] < 0) Internal("the horizon is not closed");
      }
      for (int g : created) {
        start_of_[faces_[g].v[0]] = -1;
        end_of_[faces_[g].v[1]] = -1;
      }
      // Hand the conflict points of the removed faces to the new ones: a
      // point above a removed face is either inside the new hull or above a
      // new face.
      for (int vf : visible) {
        for (int r : faces_[vf].outside) {
          if (r == q) continue;
          for (int g : created) {
            if (Height(g, r) > 0) {
              faces_[g].outside.push_back(r);
              break;
            }
          }
        }
        faces_[vf].alive = false;
        faces_[vf].visible = false;
        std::vector<int>().swap(faces_[vf].outside);
      }
      stack.insert(stack.end(), created.begin(), created.end());
    }
    std::vector<Triangle> out;
    for (const Face& f : faces_) {
      if (f.alive) out.push_back({f.v[0], f.v[1], f.v[2]});
    }
    return out;
  }

 private:
  // > 0 iff point r is strictly above face f (on the side its normal points
  // to); the magnitude is six times the tetrahedron's volume.
  double Height(int f, int r) const {
    const auto& v = faces_[f].v;
    return -Orient3d(p_[v[0]], p_[v[1]], p_[v[2]], p_[r]);
  }

  void ReplaceNeighbour(int f, int old_nb, int new_nb) {
    for (int& n : faces_[f].nb) {
      if (n == old_nb) {
        n = new_nb;
        return;
      }
    }
    Internal("broken face adjacency");
  }

  [[noreturn]] void Internal(const char* what) const {
    throw MeshError(source_ + ": convex hull internal error: " + what);
  }

  [[noreturn]] void Coplanar() const {
    throw MeshError(source_ + ": convex hull needs 4 points that are not coplanar; all " +
                    std::to_string(p_.size()) + " distinct points are coplanar");
  }

  void InitialSimplex() {
    const int n = static_cast<int>(p_.size());
    // Far-apart points first (a well-shaped start), with exact fallbacks.
    int i0 = 0;
    for (int i = 1; i < n; ++i) {
      if (p_[i].x() < p_[i0].x()) i0 = i;
    }
    int i1 = -1;
    double d1 = -1;
    for (int i = 0; i < n; ++i) {
      const double d = (p_[i] - p_[i0]).squaredNorm();
      if (i != i0 && d > d1) {
        i1 = i;
        d1 = d;
      }
    }
    if (i1 < 0) Coplanar();
    int i2 = -1;
    double d2 = -1;
    for (int i = 0; i < n; ++i) {
      const double d = (p_[i] - p_[i0]).cross(p_[i1] - p_[i0]).squaredNorm();
      if (i != i0 && i != i1 && d > d2) {
        i2 = i;
        d2 = d;
      }
    }
    if (i2 < 0) Coplanar();
    if (Collinear(p_[i0], p_[i1], p_[i2])) {
      i2 = -1;
      for (int i = 0; i < n && i2 < 0; ++i) {
        if (!Collinear(p_[i0], p_[i1], p_[i])) i2 = i;
      }
      if (i2 < 0) Coplanar();
    }
    int i3 = -1;
    double d3 = 0;
    for (int i = 0; i < n; ++i) {
      const double d = std::abs(Orient3d(p_[i0], p_[i1], p_[i2], p_[i]));
      if (d > d3) {  // the sign is exact: d == 0 exactly on the plane
        i3 = i;
        d3 = d;
      }
    }
    if (i3 < 0) Coplanar();
    // Base (a, b, c) outward: the apex d lies below it.
    if (Orient3d(p_[i0], p_[i1], p_[i2], p_[i3]) < 0) std::swap(i1, i2);
    const int a = i0, b = i1, c = i2, d = i3;
    // Faces 0..3: (a b c), (a d b), (b d c), (c d a); nb[k] across v[k]->v[k+1].
    faces_.push_back(Face{{a, b, c}, {1, 2, 3}, {}, true, false});
    faces_.push_back(Face{{a, d, b}, {3, 2, 0}, {}, true, false});
    faces_.push_back(Face{{b, d, c}, {1, 3, 0}, {}, true, false});
    faces_.push_back(Face{{c, d, a}, {2, 1, 0}, {}, true, false});
    for (int i = 0; i < n; ++i) {
      if (i == a || i == b || i == c || i == d) continue;
      for (int f = 0; f < 4; ++f) {
        if (Height(f, i) > 0) {
          faces_[f].outside.push_back(i);
          break;
        }
      }
    }
  }

  const std::vector<Vec3>& p_;
  const std::string& source_;
  std::vector<Face> faces_;
  std::vector<int> start_of_;  // new face starting at a horizon vertex
  std::vector<int> end_of_;    // new face ending at a horizon vertex
};

// Marks vertices that are not vertices of the hull polytope: those whose
// incident triangles lie in fewer than three distinct planes (one plane: the
// interior of a planar face; two: the interior of an edge). Facets of a
// convex polytope are never coplanar, so distinct planes are distinct facets.
std::vector<bool> NonExtremeVertices(const std::vector<Vec3>& p,
                                     const std::vector<Triangle>& tris) {
  std::vector<std::vector<int>> incident(p.size());
  for (int f = 0; f < static_cast<int>(tris.size()); ++f) {
    for (Index v : tris[f]) incident[v].push_back(f);
  }
  auto off_plane = [&](int f, int g) {  // triangle g does not lie in f's plane
    const Triangle& t = tris[f];
    for (Index v : tris[g]) {
      if (Orient3d(p[t[0]], p[t[1]], p[t[2]], p[v]) != 0) return true;
    }
    return false;
  };
  std::vector<bool> non_extreme(p.size(), false);
  for (std::size_t v = 0; v < p.size(); ++v) {
    const std::vector<int>& inc = incident[v];
    if (inc.empty()) continue;
    const int f0 = inc[0];
    int f1 = -1;
    for (int g : inc) {
      if (off_plane(f0, g)) {
        f1 = g;
        break;
      }
    }
    bool third = false;
    if (f1 >= 0) {
      for (int g : inc) {
        if (off_plane(f0, g) && off_plane(f1, g)) {
          third = true;
          break;
        }
      }
    }
    non_extreme[v] = !third;
  }
  return non_extreme;
}

// The exact hull of *p; on return *p may have been reduced to its extreme
// points (the triangles index into it).
std::vector<Triangle> ExactHull(std::vector<Vec3>* p, const std::string& source) {
  std::vector<Triangle> tris = Quickhull(*p, source).Run();
  std::vector<bool> non_extreme = NonExtremeVertices(*p, tris);
  if (std::find(non_extreme.begin(), non_extreme.end(), true) == non_extreme.end()) return tris;
  // Points that were extreme when inserted but lie on a face or an edge of
  // the final hull: hull the polytope's vertices alone, where no point can
  // end up non-extreme.
  std::vector<bool> used(p->size(), false);
  for (const Triangle& t : tris) {
    for (Index v : t) used[v] = true;
  }
  std::vector<Vec3> q;
  for (std::size_t i = 0; i < p->size(); ++i) {
    if (used[i] && !non_extreme[i]) q.push_back((*p)[i]);
  }
  *p = std::move(q);
  tris = Quickhull(*p, source).Run();
  non_extreme = NonExtremeVertices(*p, tris);
  if (std::find(non_extreme.begin(), non_extreme.end(), true) != non_extreme.end()) {
    throw MeshError(source + ": convex hull internal error: a non-extreme vertex remains");
  }
  return tris;
}

}  // namespace

Mesh ConvexHull(std::span<const Vec3> points, const std::string& source,
                const ConvexHullOptions& options) {
  if (!(options.sliver_ratio >= 0 && options.sliver_ratio < 0.1)) {
    throw MeshError(source + ": convex hull sliver_ratio must be in [0, 0.1)");
  }
  if (points.size() < 4) {
    throw MeshError(source + ": convex hull needs at least 4 points, got " +
                    std::to_string(points.size()));
  }
  for (std::size_t i = 0; i < points.size(); ++i) {
    for (int k = 0; k < 3; ++k) {
      const double x = points[i][k];
      if (!std::isfinite(x) || std::abs(x) > 1e100) {
        std::ostringstream os;
        os << source << ": point " << i << " has coordinate " << x
           << (std::isfinite(x) ? " beyond 1e100 in magnitude (exact predicates' range)"
                                : " that is not finite");
        throw MeshError(os.str());
      }
    }
  }
  // Distinct points, in input order of first occurrence.
  std::vector<int> order(points.size());
  std::iota(order.begin(), order.end(), 0);
  auto less = [&](int i, int j) {
    const Vec3 &a = points[i], &b = points[j];
    if (a.x() != b.x()) return a.x() < b.x();
    if (a.y() != b.y()) return a.y() < b.y();
    if (a.z() != b.z()) return a.z() < b.z();
    return i < j;
  };
  std::sort(order.begin(), order.end(), less);
  std::vector<int> distinct;
  for (std::size_t k = 0; k < order.size(); ++k) {
    if (k == 0 || points[order[k]] != points[order[k - 1]]) distinct.push_back(order[k]);
  }
  std::sort(distinct.begin(), distinct.end());
  if (distinct.size() < 4) {
    throw MeshError(source + ": convex hull needs at least 4 distinct points, got " +
                    std::to_string(distinct.size()));
  }

  std::vector<Vec3> p;
  p.reserve(distinct.size());
  for (int i : distinct) p.push_back(points[i]);
  std::vector<Triangle> tris;
  for (;;) {
    tris = ExactHull(&p, source);
    // Slivers: drop the vertex opposite the longest edge (it lies within
    // ratio * |edge| of that edge) and hull again; each round removes points.
    std::vector<bool> drop(p.size(), false);
    bool any = false;
    for (const Triangle& t : tris) {
      int longest = 0;
      double longest_sq = 0;
      for (int k = 0; k < 3; ++k) {
        const double e = (p[t[(k + 1) % 3]] - p[t[k]]).squaredNorm();
        if (e > longest_sq) {
          longest_sq = e;
          longest = k;
        }
      }
      const double twice_area = (p[t[1]] - p[t[0]]).cross(p[t[2]] - p[t[0]]).norm();
      if (twice_area < options.sliver_ratio * longest_sq) {
        drop[t[(longest + 2) % 3]] = true;
        any = true;
      }
    }
    if (!any) break;
    std::vector<bool> used(p.size(), false);
    for (const Triangle& t : tris) {
      for (Index v : t) used[v] = true;
    }
    std::vector<Vec3> q;
    for (std::size_t i = 0; i < p.size(); ++i) {
      if (used[i] && !drop[i]) q.push_back(p[i]);
    }
    p = std::move(q);
  }
  // Compact: hull vertices only, in input order.
  std::vector<Index> remap(p.size(), -1);
  for (const Triangle& t : tris) {
    for (Index v : t) remap[v] = 0;
  }
  std::vector<Vec3> vertices;
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (remap[i] == 0) {
      remap[i] = static_cast<Index>(vertices.size());
      vertices.push_back(p[i]);
    }
  }
  for (Triangle& t : tris) {
    for (Index& v : t) v = remap[v];
  }
  return Mesh::FromArrays(std::move(vertices), std::move(tris), source);
}

}  // namespace hapticpd::pd
