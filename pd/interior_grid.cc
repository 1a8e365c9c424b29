#include "pd/interior_grid.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "pd/geometry_model.h"
#include "pd/mesh.h"
#include "pd/queries.h"

namespace hapticpd::pd {

namespace {

// Whether triangle (a, b, c) and the box of half extents e about the origin
// may overlap: false only when a separating axis is found (the triangle's
// normal first, the cheapest and most often separating for a large
// triangle's far cells; then the nine edge cross products; the box's own
// axes are the caller's cell range; Akenine-Moller).
bool TriangleMayTouchBox(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& e) {
  const std::array<Vec3, 3> f = {b - a, c - b, a - c};
  const Vec3 n = f[0].cross(f[1]);
  if (std::abs(n.dot(a)) > e.dot(n.cwiseAbs())) return false;
  const std::array<Vec3, 3> v = {a, b, c};
  for (int i = 0; i < 3; ++i) {
    for (const Vec3& edge : f) {
      const Vec3 axis = Vec3::Unit(i).cross(edge);
      const double p0 = axis.dot(v[0]), p1 = axis.dot(v[1]), p2 = axis.dot(v[2]);
      const double r = e.dot(axis.cwiseAbs());
      if (std::min({p0, p1, p2}) > r || std::max({p0, p1, p2}) < -r) return false;
    }
  }
  return true;
}

}  // namespace

void InteriorGrid::Build(const Mesh& mesh, int max_cells) {
  const Aabb& box = mesh.bounds();
  const Vec3 extent = box.Size();
  const double longest = extent.maxCoeff();
  if (!(longest > 0) || max_cells < 1 || mesh.triangles().empty()) return;
  h_ = longest / max_cells;
  inv_h_ = 1 / h_;
  // One cell of margin on every side: the border is outside.
  lo_ = box.lo - Vec3::Constant(h_);
  for (int i = 0; i < 3; ++i) {
    n_[i] = static_cast<std::int64_t>(std::ceil(extent[i] * inv_h_)) + 2;
    extent_cells_[i] = static_cast<double>(n_[i]);
  }
  cells_.assign(static_cast<std::size_t>(n_[0] * n_[1] * n_[2]), kUnknown);
  // Round-off slack: the cells are tested inflated by it, so a surface cell
  // is never missed.
  const double slack =
      1e-9 * (longest + box.lo.cwiseAbs().maxCoeff() + box.hi.cwiseAbs().maxCoeff());
  const Vec3 half = Vec3::Constant(0.5 * h_ + slack);
  const auto& V = mesh.vertices();
  auto cell_of = [&](double x, int axis) {
    const auto i = static_cast<std::int64_t>(std::floor((x - lo_[axis]) * inv_h_));
    return std::clamp<std::int64_t>(i, 0, n_[axis] - 1);
  };
  for (const Triangle& t : mesh.triangles()) {
    const Vec3 &a = V[t[0]], &b = V[t[1]], &c = V[t[2]];
    const Vec3 tlo = a.cwiseMin(b).cwiseMin(c) - Vec3::Constant(slack);
    const Vec3 thi = a.cwiseMax(b).cwiseMax(c) + Vec3::Constant(slack);
    std::int64_t lo[3], hi[3];
    for (int i = 0; i < 3; ++i) {
      lo[i] = cell_of(tlo[i], i);
      hi[i] = cell_of(thi[i], i);
    }
    // Along the normal's dominant axis d only the cells the plane passes
    // near in each column (a large slanted triangle's box holds many more).
    const Vec3 n = (b - a).cross(c - a);
    int d = 0;
    n.cwiseAbs().maxCoeff(&d);
    const int e1 = (d + 1) % 3, e2 = (d + 2) % 3;
    std::int64_t idx[3];
    for (idx[e1] = lo[e1]; idx[e1] <= hi[e1]; ++idx[e1]) {
      for (idx[e2] = lo[e2]; idx[e2] <= hi[e2]; ++idx[e2]) {
        std::int64_t w_lo = lo[d], w_hi = hi[d];
        if (n[d] != 0) {
          // The plane's d coordinate over the column's (inflated) footprint.
          double p_min = std::numeric_limits<double>::infinity(), p_max = -p_min;
          for (int corner = 0; corner < 4; ++corner) {
            const double x1 = lo_[e1] + h_ * (static_cast<double>(idx[e1]) + (corner & 1)) +
                              (corner & 1 ? slack : -slack);
            const double x2 = lo_[e2] + h_ * (static_cast<double>(idx[e2]) + (corner >> 1)) +
                              (corner >> 1 ? slack : -slack);
            const double p = a[d] - (n[e1] * (x1 - a[e1]) + n[e2] * (x2 - a[e2])) / n[d];
            p_min = std::min(p_min, p);
            p_max = std::max(p_max, p);
          }
          w_lo = std::max(w_lo, cell_of(p_min - slack, d));
          w_hi = std::min(w_hi, cell_of(p_max + slack, d));
        }
        for (idx[d] = w_lo; idx[d] <= w_hi; ++idx[d]) {
          const std::size_t cell =
              static_cast<std::size_t>((idx[2] * n_[1] + idx[1]) * n_[0] + idx[0]);
          if (cells_[cell] == kSurface) continue;
          const Vec3 centre =
              lo_ + h_ * Vec3(static_cast<double>(idx[0]) + 0.5, static_cast<double>(idx[1]) + 0.5,
                              static_cast<double>(idx[2]) + 0.5);
          if (TriangleMayTouchBox(a - centre, b - centre, c - centre, half)) {
            cells_[cell] = kSurface;
          }
        }
      }
    }
  }
  std::vector<std::int64_t> todo;
  Fill(0, kOutside, &todo);  // the corner is in the margin
}

void InteriorGrid::Fill(std::int64_t start, std::uint8_t label, std::vector<std::int64_t>* todo) {
  if (cells_[static_cast<std::size_t>(start)] != kUnknown) return;
  todo->clear();
  todo->push_back(start);
  cells_[static_cast<std::size_t>(start)] = label;
  const std::int64_t nx = n_[0], nxy = n_[0] * n_[1];
  while (!todo->empty()) {
    const std::int64_t c = todo->back();
    todo->pop_back();
    if (label == kInside) ++inside_count_;
    const std::int64_t i = c % nx, j = (c / nx) % n_[1], k = c / nxy;
    auto visit = [&](bool ok, std::int64_t d) {
      if (!ok) return;
      std::uint8_t& cell = cells_[static_cast<std::size_t>(c + d)];
      if (cell != kUnknown) return;
      cell = label;
      todo->push_back(c + d);
    };
    visit(i > 0, -1);
    visit(i + 1 < nx, 1);
    visit(j > 0, -nx);
    visit(j + 1 < n_[1], nx);
    visit(k > 0, -nxy);
    visit(k + 1 < n_[2], nxy);
  }
}

void GeometryModel::BuildInterior() {
  QueryScratch scratch;
  interior_ = InteriorGrid(mesh_, kInteriorCells,
                           [&](const Vec3& p) { return PointInside(*this, p, &scratch); });
}

void GeometryModel::PickSamplePoints() {
  const auto& T = mesh_.triangles();
  const auto& V = mesh_.vertices();
  const auto nv = static_cast<Index>(V.size());
  if (T.empty()) return;
  // Components of the surface: vertices joined by triangles (union-find).
  std::vector<Index> parent(static_cast<std::size_t>(nv));
  for (Index v = 0; v < nv; ++v) parent[static_cast<std::size_t>(v)] = v;
  auto find = [&](Index v) {
    while (parent[static_cast<std::size_t>(v)] != v) {
      Index& p = parent[static_cast<std::size_t>(v)];
      p = parent[static_cast<std::size_t>(p)];
      v = p;
    }
    return v;
  };
  for (const Triangle& t : T) {
    for (int k = 1; k < 3; ++k) parent[static_cast<std::size_t>(find(t[k]))] = find(t[0]);
  }
  const Index root = find(T[0][0]);
  sampled_component_.resize(T.size());
  for (std::size_t f = 0; f < T.size(); ++f) sampled_component_[f] = find(T[f][0]) == root;
  // Candidates: the component's vertices, and a barycentric grid on each of
  // its triangles longer than a sixteenth of the model's size (a stick's
  // or a box's few vertices sit at its ends and corners only).
  std::vector<Vec3> candidates;
  for (Index v = 0; v < nv; ++v) {
    if (find(v) == root) candidates.push_back(V[static_cast<std::size_t>(v)]);
  }
  const double step = mesh_.size() / 16;
  for (const Triangle& t : T) {
    if (find(t[0]) != root) continue;
    const Vec3 &a = V[t[0]], &b = V[t[1]], &c = V[t[2]];
    const double longest = std::max({(b - a).norm(), (c - b).norm(), (a - c).norm()});
    const int m = std::min(16, static_cast<int>(longest / step));
    if (m == 0) {  // a small triangle: its centroid
      const double third = 1.0 / 3;
      candidates.push_back(a + third * (b - a) + third * (c - a));
      continue;
    }
    // The grid of step 1/m on the triangle, without its corners (vertices).
    const double s = 1.0 / m;
    for (int i = 0; i <= m; ++i) {
      for (int j = 0; i + j <= m; ++j) {
        if ((i == 0 && j == 0) || i == m || j == m) continue;
        candidates.push_back(a + (i * s) * (b - a) + (j * s) * (c - a));
      }
    }
  }
  // At most 4,096 of them (evenly by index), then farthest-point picks. A
  // near tie (a symmetric shape: a cube's corners) goes to the lowest index,
  // so that a change of the mesh far below its precision picks the same
  // points: which starts a cold query drops decides how much of PDg's work
  // budget is left, and so a budgeted answer.
  if (candidates.size() > 4096) {
    std::vector<Vec3> kept;
    for (std::size_t k = 0; k < 4096; ++k) kept.push_back(candidates[k * candidates.size() / 4096]);
    candidates.swap(kept);
  }
  std::vector<double> dist(candidates.size(), std::numeric_limits<double>::infinity());
  std::size_t next = 0;
  for (int k = 0; k < kSamplePoints && k < static_cast<int>(candidates.size()); ++k) {
    sample_points_.push_back(candidates[next]);
    double farthest = 0;
    for (std::size_t q = 0; q < candidates.size(); ++q) {
      dist[q] = std::min(dist[q], (candidates[q] - candidates[next]).squaredNorm());
      farthest = std::max(farthest, dist[q]);
    }
    if (!(farthest > 0)) break;  // every candidate picked (or repeated)
    std::size_t far = 0;
    while (dist[far] < farthest * (1 - 1e-6)) ++far;
    next = far;
  }
}

int PointsEnclosedBy(const GeometryModel& A, const Pose& X_BA, const GeometryModel& B,
                     std::span<Vec3> out, QueryScratch* scratch) {
  if (A.interior().empty() || B.bvh().nodes().empty() || out.empty()) return 0;
  const auto& NB = B.bvh().nodes();
  const auto& PB = B.bvh().primitives();
  const auto& V = B.mesh().vertices();
  const auto& T = B.mesh().triangles();
  const Pose X_AB = X_BA.Inverse();
  const Mat3 abs_R_AB = X_AB.R.cwiseAbs();
  const Aabb& a_box = A.mesh().bounds();
  const Vec3 a_centre = a_box.Center();
  const Vec3 a_half = 0.5 * a_box.Size();
  const double cell = A.mesh().size() / kEnclosedPointSpacing;
  // One candidate per B node of at most `cell` (or leaf) whose box meets
  // A's: the first vertex of its first triangle in the sampled component
  // that lies in an inside cell of A.
  auto& found = scratch->points;
  found.clear();
  auto& stack = scratch->stack;
  stack.clear();
  stack.emplace_back(0, 0);
  while (!stack.empty()) {
    const BvhNode& n = NB[static_cast<std::size_t>(stack.back().first)];
    stack.pop_back();
    const Vec3 c = X_AB * n.center;
    if ((((c - a_centre).cwiseAbs() - a_half - abs_R_AB * n.half).array() > 0).any()) continue;
    if (!n.leaf() && n.half.maxCoeff() > cell) {
      stack.emplace_back(n.first + 1, 0);
      stack.emplace_back(n.first, 0);
      continue;
    }
    const BvhNode* leaf = &n;
    while (!leaf->leaf()) leaf = &NB[static_cast<std::size_t>(leaf->first)];
    for (Index k = 0; k < leaf->count; ++k) {
      const Index f = PB[static_cast<std::size_t>(leaf->first + k)];
      if (!B.in_sampled_component(f)) continue;
      const Vec3& p_B = V[static_cast<std::size_t>(T[static_cast<std::size_t>(f)][0])];
      if (A.interior().Inside(X_AB * p_B)) found.push_back(p_B);
      break;
    }
  }
  // Evenly by the traversal's order (spatially coherent) when there are
  // more than fit.
  const std::size_t n = std::min(found.size(), out.size());
  for (std::size_t k = 0; k < n; ++k) out[k] = found[k * found.size() / n];
  found.clear();
  return static_cast<int>(n);
}

}  // namespace hapticpd::pd
