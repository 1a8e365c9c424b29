#include "pd/queries.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "pd/primitives.h"

namespace hapticpd::pd {
namespace {

using internal::BoxFrame;

// A's triangle in B's frame.
struct TriB {
  std::array<Vec3, 3> v;
};

inline TriB TriangleOfA(const Mesh& A, const Pose& X_BA, Index f) {
  const Triangle& t = A.triangles()[f];
  const auto& V = A.vertices();
  return {{X_BA * V[t[0]], X_BA * V[t[1]], X_BA * V[t[2]]}};
}

// A's triangle (and its face normal and box) in B's frame, recomputed only
// when the triangle changes: the leaf loops pair each A triangle with
// several B triangles in a row, and re-transforming it for each pair was
// half the arithmetic of a cheap leaf test. `Source::Make(f, &tri, &normal)`
// supplies the triangle (CRTP: no virtual call on the hot path).
template <typename Source>
class LastATriangle {
 public:
  const TriB& Tri(Index f) {
    Load(f);
    return tri_;
  }
  const Vec3& Normal(Index f) {
    Load(f);
    return normal_;
  }
  /// Corners of the triangle's axis-aligned box in B's frame.
  const Vec3& Lo(Index f) {
    Load(f);
    return lo_;
  }
  const Vec3& Hi(Index f) {
    Load(f);
    return hi_;
  }

 private:
  void Load(Index f) {
    if (f == f_) return;
    f_ = f;
    static_cast<Source*>(this)->Make(f, &tri_, &normal_);
    lo_ = tri_.v[0].cwiseMin(tri_.v[1]).cwiseMin(tri_.v[2]);
    hi_ = tri_.v[0].cwiseMax(tri_.v[1]).cwiseMax(tri_.v[2]);
  }
  Index f_ = -1;
  TriB tri_;
  Vec3 normal_ = Vec3::Zero();
  Vec3 lo_ = Vec3::Zero();
  Vec3 hi_ = Vec3::Zero();
};

// The triangles of A transformed by X_BA as they are met.
class ATriangleCache : public LastATriangle<ATriangleCache> {
 public:
  ATriangleCache(const Mesh& A, const Pose& X_BA) : A_(A), X_BA_(X_BA) {}

 private:
  friend class LastATriangle<ATriangleCache>;
  void Make(Index f, TriB* tri, Vec3* normal) const {
    *tri = TriangleOfA(A_, X_BA_, f);
    *normal = X_BA_.R * A_.face_normals()[f];
  }
  const Mesh& A_;
  const Pose& X_BA_;
};

// A's BVH boxes and triangles rotated into B's frame, and B's boxes onto
// A's axes, through the scratch's lazily filled tables: every sweep of a
// PDt query shares one rotation, so each node and triangle is rotated once
// per query instead of once per pair test. Its triangles are A's at the
// sweep's start (the rotated table plus the start translation).
class RotationCache : public LastATriangle<RotationCache> {
 public:
  RotationCache(const GeometryModel& A, const GeometryModel& B, const Pose& X_BA,
                const internal::SweptBoxFrame& swept, QueryScratch* s)
      : A_(A), B_(B), t_(X_BA.t), swept_(swept), s_(*s) {
    if (s_.rotated_model != A.uid() || s_.rotated_b_model != B.uid() || s_.rotated_R != X_BA.R) {
      s_.rotated_model = A.uid();
      s_.rotated_b_model = B.uid();
      s_.rotated_R = X_BA.R;
      if (++s_.rotated_stamp == 0) {  // wrapped: forget every entry
        for (auto* v : {&s_.rotated_node_stamp, &s_.rotated_b_node_stamp,
                        &s_.rotated_triangle_stamp, &s_.rotated_vertex_stamp}) {
          std::fill(v->begin(), v->end(), 0u);
        }
        s_.rotated_stamp = 1;
      }
    }
    Fit(A.bvh().nodes().size(), &s_.rotated_nodes, &s_.rotated_node_stamp);
    Fit(B.bvh().nodes().size(), &s_.rotated_b_nodes, &s_.rotated_b_node_stamp);
    Fit(A.mesh().triangles().size(), &s_.rotated_triangles, &s_.rotated_triangle_stamp);
    Fit(A.mesh().vertices().size(), &s_.rotated_vertices, &s_.rotated_vertex_stamp);
  }

  // A leaf's box on B's axes is the tight box of its rotated vertices
  // (needed by the leaf tests anyway); an internal node's of up to
  // kTightBoxTriangles triangles is the union of its children's, a larger
  // one's the rotated box's. The tight box is often much smaller: a box turned
  // by R has an axis-aligned hull up to sqrt(3) times wider per axis.
  static constexpr Index kTightBoxTriangles = 64;
  const internal::RotatedBox& NodeA(const BvhNode& n) {
    return Cached(&n - A_.bvh().nodes().data(), &s_.rotated_nodes, &s_.rotated_node_stamp,
                  [&](internal::RotatedBox* r) {
                    if (!n.leaf() && n.size > kTightBoxTriangles) {
                      *r = internal::RotateBoxA(swept_, n);
                      return;
                    }
                    if (!n.leaf()) {
                      // The union of the children's tight boxes.
                      const internal::RotatedBox& c0 = NodeA(A_.bvh().nodes()[n.first]);
                      const internal::RotatedBox& c1 = NodeA(A_.bvh().nodes()[n.first + 1]);
                      const Vec3 lo = (c0.c - c0.r).cwiseMin(c1.c - c1.r);
                      const Vec3 hi = (c0.c + c0.r).cwiseMax(c1.c + c1.r);
                      r->c = 0.5 * (lo + hi);
                      r->r = 0.5 * (hi - lo);
                      return;
                    }
                    const auto& prims = A_.bvh().primitives();
                    const auto& tris = A_.mesh().triangles();
                    Vec3 lo = RotatedVertex(tris[prims[n.first]][0]), hi = lo;
                    for (Index i = 0; i < n.count; ++i) {
                      for (Index k : tris[prims[n.first + i]]) {
                        const Vec3& v = RotatedVertex(k);
                        lo = lo.cwiseMin(v);
                        hi = hi.cwiseMax(v);
                      }
                    }
                    r->c = 0.5 * (lo + hi);
                    r->r = 0.5 * (hi - lo);
                  });
  }
  const internal::RotatedBox& NodeB(const BvhNode& n) {
    return Cached(&n - B_.bvh().nodes().data(), &s_.rotated_b_nodes, &s_.rotated_b_node_stamp,
                  [&](internal::RotatedBox* r) { *r = internal::RotateBoxB(swept_, n); });
  }

 private:
  friend class LastATriangle<RotationCache>;
  const QueryScratch::RotatedTriangle& Rotated(Index f) {
    return Cached(f, &s_.rotated_triangles, &s_.rotated_triangle_stamp,
                  [&](QueryScratch::RotatedTriangle* o) {
                    const Triangle& t = A_.mesh().triangles()[f];
                    for (int k = 0; k < 3; ++k) o->v[k] = RotatedVertex(t[k]);
                    o->n = s_.rotated_R * A_.mesh().face_normals()[f];
                  });
  }
  // Each vertex is shared by about six triangles: rotated once.
  const Vec3& RotatedVertex(Index i) {
    return Cached(i, &s_.rotated_vertices, &s_.rotated_vertex_stamp,
                  [&](Vec3* o) { *o = s_.rotated_R * A_.mesh().vertices()[i]; });
  }
  void Make(Index f, TriB* tri, Vec3* normal) {
    const QueryScratch::RotatedTriangle& r = Rotated(f);
    for (int k = 0; k < 3; ++k) tri->v[k] = r.v[k] + t_;
    *normal = r.n;
  }
  // Grows a table (and its stamps, as "not computed") to n entries: warm-up
  // only, the tables keep their size across queries.
  template <typename T>
  static void Fit(std::size_t n, std::vector<T>* table, std::vector<std::uint32_t>* stamps) {
    if (stamps->size() >= n) return;
    table->resize(n);
    stamps->resize(n, 0u);
  }
  template <typename T, typename Fill>
  const T& Cached(std::ptrdiff_t i, std::vector<T>* table, std::vector<std::uint32_t>* stamps,
                  Fill&& fill) {
    const auto k = static_cast<std::size_t>(i);
    T& entry = (*table)[k];
    if ((*stamps)[k] != s_.rotated_stamp) {
      (*stamps)[k] = s_.rotated_stamp;
      fill(&entry);
    }
    return entry;
  }
  const GeometryModel& A_;
  const GeometryModel& B_;
  const Vec3 t_;
  const internal::SweptBoxFrame& swept_;
  QueryScratch& s_;
};

inline TriB TriangleOfB(const Mesh& B, Index f) {
  const Triangle& t = B.triangles()[f];
  const auto& V = B.vertices();
  return {{V[t[0]], V[t[1]], V[t[2]]}};
}

// Round-off slack of box culls against B's triangles: relative to B's
// coordinates (and `extra`, e.g. a sweep's length), far below any real gap;
// the exact tests decide touching.
inline double BoxSlack(const Mesh& mb, double extra = 0) {
  return 1e-12 * (1.0 + mb.bounds().hi.cwiseAbs().maxCoeff() +
                  mb.bounds().lo.cwiseAbs().maxCoeff() + extra);
}

// Whether A's triangle fa (from a triangle cache) and B's triangle tb have
// disjoint boxes, by more than `slack`: then they cannot intersect.
template <typename ACache>
inline bool TriangleBoxesApart(ACache* a_tris, Index fa, const TriB& tb, double slack) {
  const Vec3 b_lo = tb.v[0].cwiseMin(tb.v[1]).cwiseMin(tb.v[2]);
  const Vec3 b_hi = tb.v[0].cwiseMax(tb.v[1]).cwiseMax(tb.v[2]);
  return ((a_tris->Lo(fa).array() - slack) > b_hi.array()).any() ||
         (b_lo.array() > (a_tris->Hi(fa).array() + slack)).any();
}

// The scratch's crossing witnesses (QueryScratch::witnesses): tested first
// by first-crossing queries, remembered when a traversal finds a crossing.
// (Kept out of line: inlined, it tipped GCC into calling the CCD's leaf
// test out of line, 4% more instructions on the slowest PDt frames.)
template <typename ACache>
[[gnu::noinline]] bool WitnessCrosses(const QueryScratch& s, const GeometryModel& A,
                                      const GeometryModel& B, ACache* a_tris) {
  if (s.witness_model_a != A.uid() || s.witness_model_b != B.uid()) return false;
  const Mesh& mb = B.mesh();
  const double slack = BoxSlack(mb);
  for (int k = 0; k < s.witness_count; ++k) {
    const auto [fa, fb] = s.witnesses[k];
    const TriB& ta = a_tris->Tri(fa);
    const TriB tb = TriangleOfB(mb, fb);
    // Most stale witnesses are far apart: their boxes say so cheaply.
    if (TriangleBoxesApart(a_tris, fa, tb, slack)) continue;
    if (internal::TrianglesIntersect(ta.v[0], ta.v[1], ta.v[2], tb.v[0], tb.v[1], tb.v[2])) {
      return true;
    }
  }
  return false;
}
inline void RememberWitness(const GeometryModel& A, const GeometryModel& B, Index fa, Index fb,
                            QueryScratch* s) {
  if (s->witness_model_a != A.uid() || s->witness_model_b != B.uid()) {
    s->witness_model_a = A.uid();
    s->witness_model_b = B.uid();
    s->witness_count = 0;
    s->witness_next = 0;
  }
  s->witnesses[s->witness_next] = {fa, fb};
  s->witness_next = (s->witness_next + 1) % QueryScratch::kWitnesses;
  s->witness_count = std::min(s->witness_count + 1, QueryScratch::kWitnesses);
}

// Which node of a pair to split: the non-leaf one, else the one holding more
// triangles. Splitting by box size instead stalls on probes made of long
// sliver triangles (the stick: every node is as long as the stick), where it
// cost 1.3-1.9x more box tests on stick-vs-bunny poses.
inline bool SplitA(const BvhNode& a, const BvhNode& b) {
  if (a.leaf()) return false;
  if (b.leaf()) return true;
  return a.size >= b.size;
}

// For distance queries the box size decides: pruning works on distance
// bounds, which shrink only when boxes do.
inline bool SplitAForDistance(const BvhNode& a, const BvhNode& b) {
  if (a.leaf()) return false;
  if (b.leaf()) return true;
  return a.half.squaredNorm() >= b.half.squaredNorm();
}

// Signed distances of a triangle's corners to a plane (n, point o), and
// whether they all lie beyond `tol` on one side: then no feature of that
// triangle comes within `tol` of anything lying in the plane.
struct PlaneSides {
  std::array<double, 3> s;
  bool far_all = false;
};
// All three signed distances beyond `tol` on the same side.
inline bool AllBeyond(const std::array<double, 3>& s, double tol) {
  return (s[0] > tol && s[1] > tol && s[2] > tol) || (s[0] < -tol && s[1] < -tol && s[2] < -tol);
}
inline PlaneSides Sides(const Vec3& n, const Vec3& o, const TriB& t, double tol) {
  PlaneSides p;
  for (int k = 0; k < 3; ++k) p.s[k] = n.dot(t.v[k] - o);
  p.far_all = AllBeyond(p.s, tol);
  return p;
}
inline bool SegmentFar(const PlaneSides& p, int i, double tol) {
  const double a = p.s[i], b = p.s[(i + 1) % 3];
  return (a > tol && b > tol) || (a < -tol && b < -tol);
}
// Lower bound on the distance between triangle `other` and triangle `t`
// (normal n): the smallest corner distance of `other` to t's plane when all
// corners lie on one side, else 0.
inline double PlaneBound(const Vec3& n, const TriB& t, const TriB& other) {
  if (n.squaredNorm() == 0) return 0;
  const double s0 = n.dot(other.v[0] - t.v[0]);
  const double s1 = n.dot(other.v[1] - t.v[0]);
  const double s2 = n.dot(other.v[2] - t.v[0]);
  if (s0 > 0 && s1 > 0 && s2 > 0) return std::min({s0, s1, s2});
  if (s0 < 0 && s1 < 0 && s2 < 0) return -std::max({s0, s1, s2});
  return 0;
}

// Same side at both ends of a translation by `shift` (signed distance change).
inline bool StaysSide(double s0, double shift, double margin) {
  const double s1 = s0 + shift;
  return (s0 > margin && s1 > margin) || (s0 < -margin && s1 < -margin);
}

// The triangle pairs of the leaf pair (na, nb), counted as tested: false as
// soon as `leaf(fa, fb)` returns false.
template <typename LeafFn>
[[gnu::always_inline]] inline bool ForLeafPair(const Bvh& ba, const Bvh& bb, const BvhNode& na,
                                               const BvhNode& nb, QueryScratch* scratch,
                                               LeafFn&& leaf) {
  scratch->triangle_tests += static_cast<std::uint64_t>(na.count) * nb.count;
  const Index* pa = ba.primitives().data() + na.first;
  const Index* pb = bb.primitives().data() + nb.first;
  for (Index i = 0; i < na.count; ++i) {
    for (Index j = 0; j < nb.count; ++j) {
      if (!leaf(pa[i], pb[j])) return false;
    }
  }
  return true;
}

// Depth-first pair traversal. `overlap(na, nb)` prunes node pairs;
// `leaf(fa, fb)` handles a triangle pair and returns false to stop.
template <typename OverlapFn, typename LeafFn>
void TraversePairs(const Bvh& ba, const Bvh& bb, QueryScratch* scratch, OverlapFn&& overlap,
                   LeafFn&& leaf) {
  auto& stack = scratch->stack;
  stack.clear();
  stack.emplace_back(0, 0);
  const auto& NA = ba.nodes();
  const auto& NB = bb.nodes();
  while (!stack.empty()) {
    const auto [ia, ib] = stack.back();
    stack.pop_back();
    const BvhNode& na = NA[ia];
    const BvhNode& nb = NB[ib];
    ++scratch->node_tests;
    if (!overlap(na, nb)) continue;
    if (na.leaf() && nb.leaf()) {
      if (!ForLeafPair(ba, bb, na, nb, scratch, leaf)) {
        stack.clear();
        return;
      }
      continue;
    }
    if (SplitA(na, nb)) {
      stack.emplace_back(na.first + 1, ib);
      stack.emplace_back(na.first, ib);
    } else {
      stack.emplace_back(ia, nb.first + 1);
      stack.emplace_back(ia, nb.first);
    }
  }
}

// Best-first pair traversal: node pairs are expanded in increasing `key` (a
// lower bound such as the earliest possible contact time) from a binary heap,
// and skipped once their key exceeds `*cutoff`, which the leaf callback may
// lower. With loose boxes (sliver triangles, long sweeps) a depth-first order
// can spend most of a query on pairs behind the first contact; best-first
// stops as soon as nothing earlier remains.
//
// At a leaf pair, `a_near(fa, nb)` first decides whether A's triangle fa can
// matter against B's leaf box at all (a cull the per-pair test would also
// make, done once for the leaf's few B triangles).
template <typename OverlapFn, typename KeyFn, typename ANearFn, typename LeafFn>
void TraversePairsBestFirst(const Bvh& ba, const Bvh& bb, QueryScratch* scratch,
                            OverlapFn&& overlap, KeyFn&& key, const double* cutoff,
                            ANearFn&& a_near, LeafFn&& leaf) {
  auto& heap = scratch->heap;
  heap.clear();
  const auto& NA = ba.nodes();
  const auto& NB = bb.nodes();
  const auto& PA = ba.primitives();
  const auto& PB = bb.primitives();
  auto later = [](const QueryScratch::KeyedPair& x, const QueryScratch::KeyedPair& y) {
    return x.key > y.key;
  };
  // Pairs that can meet at t = 0 (key 0) come before everything else and are
  // all visited whatever happens later: they go on a plain stack (depth
  // first, no heap upkeep); the heap orders the rest.
  auto& now = scratch->stack;
  now.clear();
  auto push = [&](Index ia, Index ib) {
    ++scratch->node_tests;
    const double k = key(NA[ia], NB[ib]);
    if (k > *cutoff) return;
    if (k <= 0) {
      now.emplace_back(ia, ib);
      return;
    }
    heap.push_back({k, ia, ib});
    std::push_heap(heap.begin(), heap.end(), later);
  };
  push(0, 0);
  while (!now.empty() || !heap.empty()) {
    QueryScratch::KeyedPair top;
    if (!now.empty()) {
      top = {0.0, now.back().first, now.back().second};
      now.pop_back();
    } else {
      std::pop_heap(heap.begin(), heap.end(), later);
      top = heap.back();
      heap.pop_back();
      if (top.key > *cutoff) break;  // everything left starts later
    }
    const BvhNode& na = NA[top.a];
    const BvhNode& nb = NB[top.b];
    if (!overlap(na, nb)) continue;
    if (na.leaf() && nb.leaf()) {
      for (Index i = 0; i < na.count; ++i) {
        const Index fa = PA[na.first + i];
        if (!a_near(fa, nb)) continue;
        scratch->triangle_tests += static_cast<std::uint64_t>(nb.count);
        for (Index j = 0; j < nb.count; ++j) {
          if (!leaf(fa, PB[nb.first + j], top.key)) {
            heap.clear();
            now.clear();
            return;
          }
        }
      }
      continue;
    }
    if (SplitA(na, nb)) {
      push(na.first, top.b);
      push(na.first + 1, top.b);
    } else {
      push(top.a, nb.first);
      push(top.a, nb.first + 1);
    }
  }
  heap.clear();
  now.clear();
}

// Oriented normal of an edge-edge pair from the edges' cross product, or
// false when the edges are parallel.
// Shape of a mesh edge for contact normals: its face normals (rotated by R)
// and whether the solid's wedge there is flat, convex or reflex.
enum class EdgeShape : std::uint8_t { kBoundary, kFlat, kConvex, kReflex };

EdgeShape ShapeOfEdge(const Mesh& mesh, Index e, const Mat3& R, Vec3* n1, Vec3* n2) {
  const Edge& edge = mesh.edges()[e];
  if (edge.f[0] < 0 || edge.f[1] < 0) {
    *n1 = R * mesh.face_normals()[edge.f[0] >= 0 ? edge.f[0] : edge.f[1]];
    *n2 = *n1;
    return EdgeShape::kBoundary;
  }
  const Vec3& m1 = mesh.face_normals()[edge.f[0]];
  const Vec3& m2 = mesh.face_normals()[edge.f[1]];
  *n1 = R * m1;
  *n2 = R * m2;
  if (m1.dot(m2) > 1 - 1e-9) return EdgeShape::kFlat;
  // The second face's far vertex lies below the first face's plane at a
  // convex edge.
  const Triangle& t2 = mesh.triangles()[edge.f[1]];
  Index far = t2[0];
  for (Index v : t2) {
    if (v != edge.v[0] && v != edge.v[1]) far = v;
  }
  const double side = m1.dot(mesh.vertices()[far] - mesh.vertices()[edge.v[0]]);
  return side < 0 ? EdgeShape::kConvex : EdgeShape::kReflex;
}

// Is unit v (perpendicular to a convex edge) between its face normals n1, n2?
bool InNormalCone(const Vec3& v, const Vec3& n1, const Vec3& n2) {
  const Vec3 m = n1.cross(n2);
  const double tol = -1e-9 * m.norm();
  return n1.cross(v).dot(m) >= tol && v.cross(n2).dot(m) >= tol && v.dot(n1 + n2) > 0;
}

// Oriented normal of an edge-edge pair (false for parallel edges; a zero
// normal when the pair gives no contact plane of its own). The normal must separate the two solids'
// wedges at the contact: it lies in B's normal cone and its opposite in A's. Where an edge is flat
// (both faces coplanar) the contact is a face contact and the face's normal is used; where both
// edges are convex and the edges' cross product lies in neither orientation's cones, the normal is
// zero (the vertex-face pairs around it describe the contact). Boundary and reflex edges fall back
// to orienting the cross product away from B's faces and against A's.
bool EdgeEdgeNormal(const GeometryModel& A, const Mat3& R_BA, Index ea, const GeometryModel& B,
                    Index eb, const Vec3& a0, const Vec3& a1, const Vec3& b0, const Vec3& b1,
                    const Vec3& witness_dir, double parallel_sine, Vec3* n) {
  const Vec3 da = a1 - a0, db = b1 - b0;
  Vec3 c = da.cross(db);
  const double len = c.norm();
  if (!(len > parallel_sine * da.norm() * db.norm()) || len == 0) return false;
  c /= len;
  Vec3 nb1, nb2, na1, na2;
  const EdgeShape sb = ShapeOfEdge(B.mesh(), eb, Mat3::Identity(), &nb1, &nb2);
  const EdgeShape sa = ShapeOfEdge(A.mesh(), ea, R_BA, &na1, &na2);
  if (sb == EdgeShape::kFlat) {
    *n = nb1;
    return true;
  }
  if (sa == EdgeShape::kFlat) {
    *n = -na1;
    return true;
  }
  if (sb == EdgeShape::kConvex && sa == EdgeShape::kConvex) {
    const bool pos = InNormalCone(c, nb1, nb2) && InNormalCone(-c, na1, na2);
    const bool neg = InNormalCone(-c, nb1, nb2) && InNormalCone(c, na1, na2);
    if (pos != neg) {
      *n = pos ? c : Vec3(-c);
      return true;
    }
    if (!pos) {
      n->setZero();  // no contact plane of its own
      return true;
    }
  }
  // Away from B's solid and into the direction opposite A's outward faces.
  double s = c.dot(nb1 + nb2) - c.dot(na1 + na2);
  if (std::abs(s) < 1e-12) s = c.dot(witness_dir);
  *n = s < 0 ? -c : c;
  return true;
}

}  // namespace

// ---------------------------------------------------------------------------
// Collision and containment

void TrianglesWithinSphere(const GeometryModel& model, const Vec3& p_M, double radius,
                           std::vector<TriangleDistance>* out, QueryScratch* scratch) {
  out->clear();
  if (!(radius >= 0)) return;
  const double r_sq = radius * radius;
  const auto& nodes = model.bvh().nodes();
  const auto& prims = model.bvh().primitives();
  const auto& V = model.mesh().vertices();
  const auto& T = model.mesh().triangles();
  if (nodes.empty() || T.empty()) return;
  auto& stack = scratch->stack;
  stack.clear();
  stack.emplace_back(0, 0);
  while (!stack.empty()) {
    const BvhNode& n = nodes[stack.back().first];
    stack.pop_back();
    ++scratch->node_tests;
    // Distance from the point to the box: a box farther than the radius
    // holds no triangle within it (with a round-off slack, so that a
    // triangle on the sphere is never lost to the box's rounding).
    const Vec3 gap = ((p_M - n.center).cwiseAbs() - n.half).cwiseMax(0.0);
    const double slack = 1e-12 * (p_M.norm() + n.center.norm() + n.half.norm());
    if (gap.squaredNorm() > r_sq + slack * (2 * radius + slack)) continue;
    if (!n.leaf()) {
      stack.emplace_back(n.first, 0);
      stack.emplace_back(n.first + 1, 0);
      continue;
    }
    for (Index k = n.first; k < n.first + n.count; ++k) {
      const Index f = prims[k];
      const Triangle& t = T[f];
      ++scratch->triangle_tests;
      const Vec3 q = internal::ClosestPointOnTriangle(p_M, V[t[0]], V[t[1]], V[t[2]], nullptr);
      const double d = (q - p_M).norm();
      if (d <= radius) out->push_back({f, d});
    }
  }
}

bool PointInside(const GeometryModel& model, const Vec3& p_M, QueryScratch* scratch) {
  // Directions chosen to be far from any axis or diagonal, so a ray through
  // an edge of a CAD-like mesh is unlikely; an exact zero in any predicate
  // still triggers a retry with the next one.
  static const std::array<Vec3, 8> kDirs = {
      Vec3(0.5773502691896258, 0.5345224838248488, 0.6172133998483676).normalized(),
      Vec3(-0.3713906763541037, 0.7427813527082074, 0.5570860145311556).normalized(),
      Vec3(0.8017837257372732, -0.2672612419124244, 0.5345224838248488).normalized(),
      Vec3(-0.6246950475544243, -0.4685212856658182, 0.6246950475544243).normalized(),
      Vec3(0.2182178902359924, 0.8728715609439696, -0.4364357804719848).normalized(),
      Vec3(-0.7071067811865476, 0.1414213562373095, -0.6928203230275509).normalized(),
      Vec3(0.4472135954999579, -0.7745966692414834, -0.4472135954999579).normalized(),
      Vec3(-0.1825741858350554, -0.3651483716701107, -0.9128709291752769).normalized()};
  const Mesh& mesh = model.mesh();
  if (!(mesh.bounds().lo.array() <= p_M.array()).all() ||
      !(p_M.array() <= mesh.bounds().hi.array()).all()) {
    return false;
  }
  const double reach =
      2.0 * ((p_M - mesh.bounds().Center()).norm() + mesh.bounding_radius()) + mesh.size();
  const auto& nodes = model.bvh().nodes();
  const auto& prims = model.bvh().primitives();
  const auto& V = mesh.vertices();
  const auto& T = mesh.triangles();
  auto& stack = scratch->stack;
  int winding = 0;
  for (const Vec3& dir : kDirs) {
    const Vec3 q = p_M + reach * dir;
    const Vec3 inv(1.0 / dir.x(), 1.0 / dir.y(), 1.0 / dir.z());
    bool ambiguous = false;
    int crossings = 0;
    stack.clear();
    stack.emplace_back(0, 0);
    while (!stack.empty() && !ambiguous) {
      const Index i = stack.back().first;
      stack.pop_back();
      const BvhNode& n = nodes[i];
      // Slab test of the segment [p, q] against the (slightly padded) box.
      const Vec3 pad = n.half.array() + 1e-12 * (n.half.norm() + n.center.norm());
      const Vec3 t0 = ((n.center - pad - p_M).array() * inv.array()).matrix();
      const Vec3 t1 = ((n.center + pad - p_M).array() * inv.array()).matrix();
      const double tmin = t0.cwiseMin(t1).maxCoeff();
      const double tmax = t0.cwiseMax(t1).minCoeff();
      if (tmax < std::max(tmin, 0.0) || tmin > reach) continue;
      if (!n.leaf()) {
        stack.emplace_back(n.first + 1, 0);
        stack.emplace_back(n.first, 0);
        continue;
      }
      for (Index k = 0; k < n.count; ++k) {
        const Triangle& t = T[prims[n.first + k]];
        const Vec3 &a = V[t[0]], &b = V[t[1]], &c = V[t[2]];
        const double sp = internal::Orient3d(a, b, c, p_M);
        const double sq = internal::Orient3d(a, b, c, q);
        if ((sp > 0 && sq > 0) || (sp < 0 && sq < 0)) continue;
        const double s0 = internal::Orient3d(p_M, q, a, b);
        const double s1 = internal::Orient3d(p_M, q, b, c);
        const double s2 = internal::Orient3d(p_M, q, c, a);
        const bool all_pos = s0 > 0 && s1 > 0 && s2 > 0;
        const bool all_neg = s0 < 0 && s1 < 0 && s2 < 0;
        if (sp == 0 || sq == 0) {
          // The point lies on the triangle's plane (or the far end does).
          if ((s0 >= 0 && s1 >= 0 && s2 >= 0) || (s0 <= 0 && s1 <= 0 && s2 <= 0)) {
            ambiguous = true;
            break;
          }
          continue;
        }
        if (all_pos || all_neg) {
          // Signed crossing: +1 leaving through an outward face, -1 entering.
          crossings += sp < 0 ? 1 : -1;
        } else if ((s0 >= 0 && s1 >= 0 && s2 >= 0) || (s0 <= 0 && s1 <= 0 && s2 <= 0)) {
          ambiguous = true;  // through an edge or vertex
          break;
        }
      }
    }
    if (!ambiguous) return crossings != 0;
    winding = crossings;
  }
  return winding != 0;
}

namespace {

// Given that no triangles of A and B cross, A (at X_BA in B's mesh frame) and
// B are either disjoint or one lies wholly inside the other: one vertex of
// each decides.
Containment ContainmentWithoutCrossing(const GeometryModel& A, const GeometryModel& B,
                                       const Pose& X_BA, QueryScratch* scratch) {
  const Mesh& ma = A.mesh();
  const Mesh& mb = B.mesh();
  if (B.closed()) {
    const Vec3 p_B = X_BA * ma.vertices()[ma.triangles()[0][0]];
    if (PointInside(B, p_B, scratch)) return Containment::kAInsideB;
  }
  if (A.closed()) {
    const Vec3 p_A = X_BA.Inverse() * mb.vertices()[mb.triangles()[0][0]];
    if (PointInside(A, p_A, scratch)) return Containment::kBInsideA;
  }
  return Containment::kNone;
}

}  // namespace

bool Collide(const GeometryModel& A, const Pose& X_WA, const GeometryModel& B, const Pose& X_WB,
             const CollisionRequest& request, CollisionResult* result, QueryScratch* scratch) {
  result->colliding = false;
  result->surfaces_intersect = false;
  result->containment = Containment::kNone;
  result->pairs.clear();
  result->pairs_truncated = false;
  const Pose X_BA = X_WB.Inverse() * X_WA;
  const BoxFrame frame(X_BA);
  const Mesh& ma = A.mesh();
  const Mesh& mb = B.mesh();
  const Vec3 zero = Vec3::Zero();
  ATriangleCache a_tris(ma, X_BA);
  if (!request.all_pairs && WitnessCrosses(*scratch, A, B, &a_tris)) {
    result->surfaces_intersect = true;
    result->colliding = true;
    return true;
  }
  const double box_slack = BoxSlack(mb);
  TraversePairs(
      A.bvh(), B.bvh(), scratch,
      [&](const BvhNode& na, const BvhNode& nb) {
        return internal::BoxesOverlap(frame, na, nb, 0.0, zero);
      },
      [&](Index fa, Index fb) {
        const TriB& ta = a_tris.Tri(fa);
        const TriB tb = TriangleOfB(mb, fb);
        if (TriangleBoxesApart(&a_tris, fa, tb, box_slack)) return true;
        if (!internal::TrianglesIntersect(ta.v[0], ta.v[1], ta.v[2], tb.v[0], tb.v[1], tb.v[2])) {
          return true;
        }
        result->surfaces_intersect = true;
        if (!request.all_pairs) {
          RememberWitness(A, B, fa, fb, scratch);
          return false;
        }
        if (result->pairs.size() >= request.max_pairs) {
          result->pairs_truncated = true;
          return false;
        }
        result->pairs.push_back({fa, fb});
        return true;
      });
  if (result->surfaces_intersect) {
    result->colliding = true;
    return true;
  }
  if (!request.containment) return false;
  result->containment = ContainmentWithoutCrossing(A, B, X_BA, scratch);
  result->colliding = result->containment != Containment::kNone;
  return result->colliding;
}

// ---------------------------------------------------------------------------
// Proximity

namespace {

// Appends the feature pairs of triangle pair (fa, fb) within `tol`.
// Everything in B's frame; witnesses are mapped to W on output.
// Returns false when max_pairs was reached.
bool CollectFeatures(const GeometryModel& A, const Pose& X_BA, const GeometryModel& B,
                     const Pose& X_WB, Index fa, Index fb, double tol,
                     const ProximityRequest& request, ATriangleCache* a_tris,
                     std::vector<FeaturePair>* out) {
  const Mesh& ma = A.mesh();
  const Mesh& mb = B.mesh();
  const TriB& ta = a_tris->Tri(fa);
  const TriB tb = TriangleOfB(mb, fb);
  const std::uint8_t own_a = ma.owned_mask(fa);
  const std::uint8_t own_b = mb.owned_mask(fb);
  const double tol2 = tol * tol;
  // Plane filters (exact: a feature in a triangle's plane is at least as far
  // as the other feature's distance to that plane). A small slack keeps
  // round-off from rejecting a pair at exactly the tolerance.
  const double slack = tol + 1e-12 * (1.0 + tb.v[0].cwiseAbs().maxCoeff());
  const Vec3& nb = mb.face_normals()[fb];
  const Vec3& na = a_tris->Normal(fa);
  const bool has_nb = nb.squaredNorm() > 0, has_na = na.squaredNorm() > 0;
  const PlaneSides a_vs_b = has_nb ? Sides(nb, tb.v[0], ta, slack) : PlaneSides{{0, 0, 0}, false};
  const PlaneSides b_vs_a = has_na ? Sides(na, ta.v[0], tb, slack) : PlaneSides{{0, 0, 0}, false};
  // One triangle wholly beyond the tolerance on one side of the other's
  // plane: every feature of the other lies in that plane, so no pair is near.
  if (a_vs_b.far_all || b_vs_a.far_all) return true;
  auto emit = [&](FeatureType type, Index a, Index b, const Vec3& pa, const Vec3& pb,
                  const Vec3& n_B) {
    if (out->size() >= request.max_pairs) return false;
    FeaturePair fp;
    fp.type = type;
    fp.a = a;
    fp.b = b;
    fp.p_WA = X_WB * pa;
    fp.p_WB = X_WB * pb;
    fp.n_W = X_WB.R * n_B;
    fp.distance = (pa - pb).norm();
    fp.signed_distance = (pa - pb).dot(n_B);
    out->push_back(fp);
    return true;
  };
  // Vertex of A against face of B.
  if (has_nb) {
    for (int k = 0; k < 3; ++k) {
      if (!(own_a & (1u << k)) || std::abs(a_vs_b.s[k]) > slack) continue;
      const Vec3 q = internal::ClosestPointOnTriangle(ta.v[k], tb.v[0], tb.v[1], tb.v[2], nullptr);
      if ((ta.v[k] - q).squaredNorm() <= tol2) {
        if (!emit(FeatureType::kVertexFace, ma.triangles()[fa][k], fb, ta.v[k], q, nb)) {
          return false;
        }
      }
    }
  }
  // Face of A against vertex of B.
  if (has_na) {
    for (int k = 0; k < 3; ++k) {
      if (!(own_b & (1u << k)) || std::abs(b_vs_a.s[k]) > slack) continue;
      const Vec3 p = internal::ClosestPointOnTriangle(tb.v[k], ta.v[0], ta.v[1], ta.v[2], nullptr);
      if ((p - tb.v[k]).squaredNorm() <= tol2) {
        if (!emit(FeatureType::kFaceVertex, fa, mb.triangles()[fb][k], p, tb.v[k], -na)) {
          return false;
        }
      }
    }
  }
  // Edge of A against edge of B.
  for (int i = 0; i < 3; ++i) {
    if (!(own_a & (1u << (3 + i))) || SegmentFar(a_vs_b, i, slack)) continue;
    const Vec3& a0 = ta.v[i];
    const Vec3& a1 = ta.v[(i + 1) % 3];
    for (int j = 0; j < 3; ++j) {
      if (!(own_b & (1u << (3 + j))) || SegmentFar(b_vs_a, j, slack)) continue;
      const Vec3& b0 = tb.v[j];
      const Vec3& b1 = tb.v[(j + 1) % 3];
      const internal::SegmentClosest sc = internal::ClosestSegmentSegment(a0, a1, b0, b1);
      if (sc.dist_sq > tol2) continue;
      // A closest point at an edge's end is a vertex contact: its pairs with
      // the adjacent faces describe it, and the edges' cross product there is
      // no contact normal (it would push along an arbitrary diagonal).
      if (!(sc.s > kEdgeInterior && sc.s < 1 - kEdgeInterior && sc.t > kEdgeInterior &&
            sc.t < 1 - kEdgeInterior)) {
        continue;
      }
      Vec3 n;
      const Index ea = ma.face_edges(fa)[i];
      const Index eb = mb.face_edges(fb)[j];
      if (!EdgeEdgeNormal(A, X_BA.R, ea, B, eb, a0, a1, b0, b1, sc.p - sc.q, request.parallel_sine,
                          &n)) {
        continue;
      }
      if (!emit(FeatureType::kEdgeEdge, ea, eb, sc.p, sc.q, n)) return false;
    }
  }
  return true;
}

}  // namespace

void Proximity(const GeometryModel& A, const Pose& X_WA, const GeometryModel& B, const Pose& X_WB,
               const ProximityRequest& request, ProximityResult* result, QueryScratch* scratch) {
  result->pairs.clear();
  result->truncated = false;
  const Pose X_BA = X_WB.Inverse() * X_WA;
  const BoxFrame frame(X_BA);
  const Vec3 zero = Vec3::Zero();
  const double tol = std::max(0.0, request.tolerance);
  ATriangleCache a_tris(A.mesh(), X_BA);
  TraversePairs(
      A.bvh(), B.bvh(), scratch,
      [&](const BvhNode& na, const BvhNode& nb) {
        return internal::BoxesOverlap(frame, na, nb, tol, zero);
      },
      [&](Index fa, Index fb) {
        if (!CollectFeatures(A, X_BA, B, X_WB, fa, fb, tol, request, &a_tris, &result->pairs)) {
          result->truncated = true;
          return false;
        }
        return true;
      });
}

// ---------------------------------------------------------------------------
// Distance

double Distance(const GeometryModel& A, const Pose& X_WA, const GeometryModel& B, const Pose& X_WB,
                DistanceResult* result, QueryScratch* scratch, double lower_cutoff) {
  const Pose X_BA = X_WB.Inverse() * X_WA;
  const BoxFrame frame(X_BA);
  const Mesh& ma = A.mesh();
  const Mesh& mb = B.mesh();
  double best = std::numeric_limits<double>::infinity();
  Vec3 best_pa = Vec3::Zero(), best_pb = Vec3::Zero();
  Index best_fa = -1, best_fb = -1;
  auto& stack = scratch->stack;
  stack.clear();
  stack.emplace_back(0, 0);
  const auto& NA = A.bvh().nodes();
  const auto& NB = B.bvh().nodes();
  const auto& PA = A.bvh().primitives();
  const auto& PB = B.bvh().primitives();
  while (!stack.empty()) {
    const auto [ia, ib] = stack.back();
    stack.pop_back();
    const BvhNode& na = NA[ia];
    const BvhNode& nb = NB[ib];
    ++scratch->node_tests;
    if (internal::BoxesDistanceLowerBound(frame, na, nb) >= best) continue;
    if (na.leaf() && nb.leaf()) {
      scratch->triangle_tests += static_cast<std::uint64_t>(na.count) * nb.count;
      for (Index i = 0; i < na.count; ++i) {
        const Index fa = PA[na.first + i];
        const TriB ta = TriangleOfA(ma, X_BA, fa);
        for (Index j = 0; j < nb.count; ++j) {
          const Index fb = PB[nb.first + j];
          const TriB tb = TriangleOfB(mb, fb);
          // Cheap bound first: if one triangle lies wholly on one side of
          // the other's plane, its nearest corner's plane distance bounds the
          // triangle distance from below.
          if (PlaneBound(mb.face_normals()[fb], tb, ta) >= best ||
              PlaneBound(X_BA.R * ma.face_normals()[fa], ta, tb) >= best) {
            continue;
          }
          const internal::TriangleClosest tc = internal::ClosestTriangleTriangle(
              ta.v[0], ta.v[1], ta.v[2], tb.v[0], tb.v[1], tb.v[2]);
          const double d = std::sqrt(tc.dist_sq);
          if (d < best) {
            best = d;
            best_pa = tc.p;
            best_pb = tc.q;
            best_fa = fa;
            best_fb = fb;
          }
        }
      }
      if (best <= lower_cutoff) break;
      continue;
    }
    // Visit the nearer child first (pushed last).
    std::pair<Index, Index> c0, c1;
    if (SplitAForDistance(na, nb)) {
      c0 = {na.first, ib};
      c1 = {na.first + 1, ib};
    } else {
      c0 = {ia, nb.first};
      c1 = {ia, nb.first + 1};
    }
    const double d0 = internal::BoxesDistanceLowerBound(frame, NA[c0.first], NB[c0.second]);
    const double d1 = internal::BoxesDistanceLowerBound(frame, NA[c1.first], NB[c1.second]);
    if (d0 <= d1) {
      stack.push_back(c1);
      stack.push_back(c0);
    } else {
      stack.push_back(c0);
      stack.push_back(c1);
    }
  }
  stack.clear();
  if (result) {
    result->distance = best;
    result->p_WA = X_WB * best_pa;
    result->p_WB = X_WB * best_pb;
    result->triangle_a = best_fa;
    result->triangle_b = best_fb;
  }
  return best;
}

// ---------------------------------------------------------------------------
// Continuous collision

namespace {

void CollectContactFeatures(const GeometryModel& A, const GeometryModel& B, const Pose& X_WB,
                            const CcdRequest& request, CcdResult* result, QueryScratch* scratch) {
  result->features.clear();
  result->features_truncated = false;
  if (request.feature_tolerance <= 0) return;
  ProximityRequest preq;
  preq.tolerance = request.feature_tolerance;
  preq.max_pairs = request.max_features;
  ProximityResult pres;
  pres.pairs.swap(result->features);
  Proximity(A, result->X_WA_contact, B, X_WB, preq, &pres, scratch);
  result->features.swap(pres.pairs);
  result->features_truncated = pres.truncated;
}

// Each vertex's signed distance to the other triangle's plane at t = 0, and
// whether it stays strictly on one side of that plane over [0, t_best] while
// A's triangle moves by t d_B: a feature that stays on one side of the other
// triangle's plane cannot touch it.
struct SweptPlaneSides {
  std::array<double, 3> sa{0, 0, 0}, sb{0, 0, 0};
  std::array<bool, 3> a_side{false, false, false}, b_side{false, false, false};
  double margin = 0;
  /// Some event is possible: neither triangle stays wholly on one side of
  /// the other's plane (where every feature of the other lies).
  bool events = true;
  /// One triangle stays farther than the feature tolerance from the other's
  /// plane, on one side: no feature pair of the two comes within it either.
  bool apart = false;

  void Compute(const TriB& ta, const Vec3& na, const TriB& tb, const Vec3& nb, const Vec3& d_B,
               double t_best, double feature_tol) {
    margin = 1e-12 * (1.0 + tb.v[0].cwiseAbs().maxCoeff() + d_B.norm());
    auto one_side = [](const std::array<bool, 3>& side, const std::array<double, 3>& sv) {
      return side[0] && side[1] && side[2] && ((sv[0] > 0) == (sv[1] > 0)) &&
             ((sv[1] > 0) == (sv[2] > 0));
    };
    std::array<bool, 3> far{false, false, false};
    if (nb.squaredNorm() > 0) {
      const double shift = t_best * nb.dot(d_B);
      for (int k = 0; k < 3; ++k) {
        sa[k] = nb.dot(ta.v[k] - tb.v[0]);
        a_side[k] = StaysSide(sa[k], shift, margin);
        far[k] = StaysSide(sa[k], shift, margin + feature_tol);
      }
      events = !one_side(a_side, sa);
      apart = one_side(far, sa);
      if (apart) return;
    }
    if (na.squaredNorm() > 0) {
      const double shift = -t_best * na.dot(d_B);
      for (int k = 0; k < 3; ++k) {
        sb[k] = na.dot(tb.v[k] - ta.v[0]);
        b_side[k] = StaysSide(sb[k], shift, margin);
        far[k] = StaysSide(sb[k], shift, margin + feature_tol);
      }
      events = events && !one_side(b_side, sb);
      apart = one_side(far, sb);
    }
  }
};

// The vertex-face and edge-edge events of one triangle pair, A's triangle
// moving by t d_B, t in [0, *t_best]: features another triangle owns
// (owned masks) and those `sides` rules out are skipped. An event lowers
// *t_best (once `hit`, only a strictly earlier one); returns whether any
// event is known, `hit` included.
inline bool SweptPairEvents(const TriB& ta, std::uint8_t own_a, const TriB& tb, std::uint8_t own_b,
                            const SweptPlaneSides& sides, const Vec3& d_B, bool hit,
                            double* t_best) {
  auto edge_stays = [](const std::array<bool, 3>& side, const std::array<double, 3>& sv, int i) {
    const int j = (i + 1) % 3;
    return side[i] && side[j] && ((sv[i] > 0) == (sv[j] > 0));
  };
  double t;
  for (int k = 0; k < 3; ++k) {
    if ((own_a & (1u << k)) && !sides.a_side[k] &&
        internal::PointTriangleToi(ta.v[k], d_B, tb.v[0], tb.v[1], tb.v[2], *t_best, &t) &&
        (!hit || t < *t_best)) {
      *t_best = t;
      hit = true;
    }
    if ((own_b & (1u << k)) && !sides.b_side[k] &&
        internal::PointTriangleToi(tb.v[k], -d_B, ta.v[0], ta.v[1], ta.v[2], *t_best, &t) &&
        (!hit || t < *t_best)) {
      *t_best = t;
      hit = true;
    }
  }
  // Sweep-plane filter for edge pairs: edge a moving along d stays in
  // the plane through it spanned by d, so edge b must reach that plane
  // (and edge a the plane through edge b spanned by d). Both endpoints
  // beyond it by more than a pad far above SegmentSegmentToi's contact
  // tolerance (kContactTol times the coordinates' scale): no event.
  double pad = -1;  // computed for the first edge pair that needs it
  auto beyond = [&](const Vec3& p0, const Vec3& p1, const Vec3& q0, const Vec3& q1) {
    const Vec3 m = (p1 - p0).cross(d_B);
    const double mm = m.squaredNorm();
    if (!(mm > 0)) return false;
    const double s0 = m.dot(q0 - p0), s1 = m.dot(q1 - p0);
    if ((s0 > 0) != (s1 > 0)) return false;
    if (pad < 0) {
      double scale = 0;
      for (int k = 0; k < 3; ++k) {
        scale = std::max({scale, ta.v[k].cwiseAbs().maxCoeff(), tb.v[k].cwiseAbs().maxCoeff()});
      }
      pad = 1e3 * internal::kContactTol * scale;
    }
    const double s = std::min(std::abs(s0), std::abs(s1));
    return s * s > pad * pad * mm;
  };
  for (int i = 0; i < 3; ++i) {
    if (!(own_a & (1u << (3 + i))) || edge_stays(sides.a_side, sides.sa, i)) continue;
    for (int j = 0; j < 3; ++j) {
      if (!(own_b & (1u << (3 + j))) || edge_stays(sides.b_side, sides.sb, j)) continue;
      const Vec3 &a0 = ta.v[i], &a1 = ta.v[(i + 1) % 3];
      const Vec3 &b0 = tb.v[j], &b1 = tb.v[(j + 1) % 3];
      if (beyond(a0, a1, b0, b1) || beyond(b0, b1, a0, a1)) continue;
      if (internal::SegmentSegmentToi(ta.v[i], ta.v[(i + 1) % 3], d_B, tb.v[j], tb.v[(j + 1) % 3],
                                      *t_best, &t) &&
          (!hit || t < *t_best)) {
        *t_best = t;
        hit = true;
      }
    }
  }
  return hit;
}

}  // namespace

// Leaf pairs StartCrossingFirst may spend before leaving the start to the
// sweep.
constexpr int kStartCrossingLeafPairs = 256;

// A depth-first search for a triangle pair crossing at the sweep's start:
// A's node boxes (the rotation cache's, shared by the query's sweeps, moved
// by the start translation t) against B's on both bodies' face axes, then
// the triangles' boxes, their planes and the crossing test. Of a node pair's
// two child pairs, the one whose boxes overlap deeper on B's axes is
// searched first (a third fewer node and triangle tests than a fixed order
// on the cold benchmark's early-outs). True at the first crossing
// (remembered as a witness); false when none turned up within
// `max_leaf_pairs` leaf pairs, which says nothing.
bool StartCrossingFirst(const GeometryModel& A, const GeometryModel& B, const Mat3& R,
                        const Vec3& t, RotationCache* a_tris, QueryScratch* scratch,
                        int max_leaf_pairs) {
  if (A.bvh().nodes().empty() || B.bvh().nodes().empty()) return false;
  const Mesh& mb = B.mesh();
  const double slack = BoxSlack(mb, t.cwiseAbs().maxCoeff());
  const Vec3 rtt = R.transpose() * t;  // A's origin offset on A's axes
  int leaves = 0;
  const auto& NA = A.bvh().nodes();
  const auto& NB = B.bvh().nodes();
  // B's face axes: the largest gap (> slack: apart; more negative: deeper).
  auto gap_b = [&](const BvhNode& na, const BvhNode& nb) {
    const internal::RotatedBox& ra = a_tris->NodeA(na);
    return ((ra.c + t - nb.center).cwiseAbs() - ra.r - nb.half).maxCoeff();
  };
  auto apart_a = [&](const BvhNode& na, const BvhNode& nb) {
    const internal::RotatedBox& rb = a_tris->NodeB(nb);
    return (((na.center + rtt - rb.c).cwiseAbs() - na.half - rb.r).array() > slack).any();
  };
  auto crosses = [&](Index fa, Index fb) {
    const TriB& ta = a_tris->Tri(fa);
    const TriB tb = TriangleOfB(mb, fb);
    if (TriangleBoxesApart(a_tris, fa, tb, slack)) return false;
    // A triangle strictly on one side of the other's plane does not cross
    // it.
    if (Sides(a_tris->Normal(fa), ta.v[0], tb, slack).far_all ||
        Sides(mb.face_normals()[fb], tb.v[0], ta, slack).far_all) {
      return false;
    }
    return internal::TrianglesIntersect(ta.v[0], ta.v[1], ta.v[2], tb.v[0], tb.v[1], tb.v[2]);
  };
  auto& stack = scratch->stack;
  stack.clear();
  if (gap_b(NA[0], NB[0]) > slack) return false;
  stack.emplace_back(0, 0);
  while (!stack.empty()) {
    const auto [ia, ib] = stack.back();
    stack.pop_back();
    const BvhNode& na = NA[ia];
    const BvhNode& nb = NB[ib];
    ++scratch->node_tests;
    if (apart_a(na, nb)) continue;
    if (na.leaf() && nb.leaf()) {
      if (++leaves > max_leaf_pairs) break;
      if (!ForLeafPair(A.bvh(), B.bvh(), na, nb, scratch, [&](Index fa, Index fb) {
            if (!crosses(fa, fb)) return true;
            RememberWitness(A, B, fa, fb, scratch);
            return false;
          })) {
        stack.clear();
        return true;
      }
      continue;
    }
    std::pair<Index, Index> c0, c1;
    double g0, g1;
    if (SplitA(na, nb)) {
      c0 = {na.first, ib};
      c1 = {na.first + 1, ib};
      g0 = gap_b(NA[na.first], nb);
      g1 = gap_b(NA[na.first + 1], nb);
    } else {
      c0 = {ia, nb.first};
      c1 = {ia, nb.first + 1};
      g0 = gap_b(na, NB[nb.first]);
      g1 = gap_b(na, NB[nb.first + 1]);
    }
    // The deeper overlap first (pushed last): where the boxes overlap
    // deeply the surfaces are likelier to cross than where they graze.
    if (g0 < g1) {
      std::swap(c0, c1);
      std::swap(g0, g1);
    }
    if (g0 <= slack) stack.push_back(c0);
    if (g1 <= slack) stack.push_back(c1);
  }
  stack.clear();
  return false;
}

bool TranslationalCcd(const GeometryModel& A, const Pose& X_WA0, const Vec3& d_W,
                      const GeometryModel& B, const Pose& X_WB, const CcdRequest& request,
                      CcdResult* result, QueryScratch* scratch) {
  result->hit = false;
  result->toi = 1;
  result->iterations = 0;
  result->start_colliding = false;
  result->near_pairs.clear();
  const Pose X_BA = X_WB.Inverse() * X_WA0;
  const Vec3 d_B = X_WB.R.transpose() * d_W;
  bool start_crossing = false;
  const internal::SweptBoxFrame swept(X_BA, d_B);
  const Mesh& ma = A.mesh();
  const Mesh& mb = B.mesh();
  double t_best = 1;
  bool hit = false;
  // Leaf pairs whose (feature-tolerance inflated) boxes can meet by t_best
  // are recorded with their entry time: the contact features at the final
  // toi are then collected from those pairs alone, without a second
  // traversal.
  const double feature_tol = std::max(0.0, request.feature_tolerance);
  auto& visited = scratch->leaf_pairs;
  visited.clear();
  RotationCache a_tris(A, B, X_BA, swept, scratch);
  // Round-off slack for the per-triangle box cull (relative to the scene's
  // coordinates and the sweep).
  const double box_slack = BoxSlack(mb, d_B.norm());
  // Earliest time a node pair can touch (swept separating-axis interval),
  // infinity when it cannot within [0, t_best]: the best-first traversal
  // finds the first contact early and prunes everything behind it.
  auto start_colliding = [&] {
    result->start_colliding = true;
    result->X_WA_contact = X_WA0;
    result->features.clear();
    result->features_truncated = false;
    visited.clear();
    return false;
  };
  // A crossing at the start settles a start check at once.
  if (request.check_start && WitnessCrosses(*scratch, A, B, &a_tris)) return start_colliding();
  if (request.check_start && request.start_crossing_first &&
      StartCrossingFirst(A, B, X_BA.R, X_BA.t, &a_tris, scratch, kStartCrossingLeafPairs)) {
    return start_colliding();
  }
  auto earliest = [&](const BvhNode& na, const BvhNode& nb) {
    double t;
    return internal::BoxesSweptEnter(swept, na, a_tris.NodeA(na), nb, a_tris.NodeB(nb), t_best, &t,
                                     feature_tol)
               ? t
               : std::numeric_limits<double>::infinity();
  };
  // A's triangle's box swept over [0, t_best], inflated by the feature
  // tolerance (and round-off slack); kept for the leaf's pairs with that
  // triangle (the leaf cull and each pair test ask for the same box).
  Index box_fa = -1;
  double box_t = -1;
  Vec3 box_lo, box_hi;
  auto swept_a_box = [&](Index fa, Vec3* lo, Vec3* hi) {
    if (fa != box_fa || t_best != box_t) {
      box_fa = fa;
      box_t = t_best;
      const Vec3 step = t_best * d_B;
      const Vec3 pad = Vec3::Constant(feature_tol + box_slack);
      box_lo = a_tris.Lo(fa) + step.cwiseMin(0.0) - pad;
      box_hi = a_tris.Hi(fa) + step.cwiseMax(0.0) + pad;
    }
    *lo = box_lo;
    *hi = box_hi;
  };
  TraversePairsBestFirst(
      A.bvh(), B.bvh(), scratch, [](const BvhNode&, const BvhNode&) { return true; }, earliest,
      &t_best,
      [&](Index fa, const BvhNode& nb) {
        // B's leaf box holds every triangle of the leaf: an A triangle whose
        // swept box misses it meets none of them.
        Vec3 a_lo, a_hi;
        swept_a_box(fa, &a_lo, &a_hi);
        return !((a_lo - nb.center).array() > nb.half.array()).any() &&
               !((nb.center - a_hi).array() > nb.half.array()).any();
      },
      [&](Index fa, Index fb, double key) {
        const TriB& ta = a_tris.Tri(fa);
        const TriB tb = TriangleOfB(mb, fb);
        {
          // The triangles' own boxes (A's swept over [0, t_best], both
          // inflated by the feature tolerance) cull most pairs of a leaf
          // pair: nothing of them can meet or come within tolerance.
          Vec3 a_lo, a_hi;
          swept_a_box(fa, &a_lo, &a_hi);
          const Vec3 b_lo = tb.v[0].cwiseMin(tb.v[1]).cwiseMin(tb.v[2]);
          const Vec3 b_hi = tb.v[0].cwiseMax(tb.v[1]).cwiseMax(tb.v[2]);
          if ((a_lo.array() > b_hi.array()).any() || (b_lo.array() > a_hi.array()).any()) {
            return true;
          }
        }
        SweptPlaneSides sides;
        sides.Compute(ta, a_tris.Normal(fa), tb, mb.face_normals()[fb], d_B, t_best, feature_tol);
        // Only pairs that may come within the feature tolerance by t_best
        // (then also by the final toi <= t_best) are kept for the features.
        if (feature_tol > 0 && !sides.apart) visited.push_back({key, fa, fb});
        if (!sides.events) return true;  // neither triangle reaches the other's plane
        // Pairs whose boxes overlap at t = 0 (key 0) come first in the
        // best-first order and are all met: the start check lives here
        // (after the plane filter: a triangle strictly on one side of the
        // other's plane at t = 0 does not cross it, which spares most start
        // pairs the exact test).
        if (request.check_start && key <= 0 && !AllBeyond(sides.sa, sides.margin) &&
            !AllBeyond(sides.sb, sides.margin) &&
            internal::TrianglesIntersect(ta.v[0], ta.v[1], ta.v[2], tb.v[0], tb.v[1], tb.v[2])) {
          start_crossing = true;
          RememberWitness(A, B, fa, fb, scratch);
          return false;
        }
        hit =
            SweptPairEvents(ta, ma.owned_mask(fa), tb, mb.owned_mask(fb), sides, d_B, hit, &t_best);
        // Contact at t = 0 ends the search, unless features are wanted or
        // the start is being checked: then every pair that can touch at
        // t = 0 must still be met.
        return !(hit && t_best <= 0 && feature_tol == 0 && !request.check_start);
      });
  if (request.check_start &&
      (start_crossing || ContainmentWithoutCrossing(A, B, X_BA, scratch) != Containment::kNone)) {
    return start_colliding();
  }
  result->hit = hit;
  result->toi = hit ? t_best : 1.0;
  result->X_WA_contact = X_WA0;
  result->X_WA_contact.t += result->toi * d_W;
  result->features.clear();
  result->features_truncated = false;
  if (hit && feature_tol > 0 && request.near_pairs) {
    for (const QueryScratch::KeyedPair& p : visited) {
      if (p.key <= result->toi) result->near_pairs.push_back({p.a, p.b});
    }
  }
  if (hit && feature_tol > 0) {
    const Pose X_BAc{X_BA.R, X_BA.t + result->toi * d_B};
    ATriangleCache a_tris_c(ma, X_BAc);
    ProximityRequest preq;
    preq.tolerance = feature_tol;
    preq.max_pairs = request.max_features;
    for (const QueryScratch::KeyedPair& p : visited) {
      if (p.key > result->toi) continue;
      if (!CollectFeatures(A, X_BAc, B, X_WB, p.a, p.b, feature_tol, preq, &a_tris_c,
                           &result->features)) {
        result->features_truncated = true;
        break;
      }
    }
  }
  visited.clear();
  return hit;
}

Pose InterpolateRigid(const Pose& X_WA0, const Pose& X_WA1, const Vec3& p_AC, double t) {
  const Vec3 c0 = X_WA0 * p_AC;
  const Vec3 c1 = X_WA1 * p_AC;
  const Eigen::AngleAxisd aa(X_WA1.R * X_WA0.R.transpose());
  Pose X;
  X.R = Eigen::AngleAxisd(t * aa.angle(), aa.axis()).toRotationMatrix() * X_WA0.R;
  X.t = c0 + t * (c1 - c0) - X.R * p_AC;
  return X;
}

bool RigidCcd(const GeometryModel& A, const Pose& X_WA0, const Pose& X_WA1, const GeometryModel& B,
              const Pose& X_WB, const CcdRequest& request, CcdResult* result,
              QueryScratch* scratch) {
  result->hit = false;
  result->toi = 1;
  result->iterations = 0;
  result->features.clear();
  const Vec3& p_AC = A.mass().p_MC;
  const double lin = (X_WA1 * p_AC - X_WA0 * p_AC).norm();
  const double ang = Eigen::AngleAxisd(X_WA1.R * X_WA0.R.transpose()).angle();
  const double speed = lin + ang * A.radius_about_com();
  const double tol = std::max(request.distance_tolerance, 0.0);
  double t = 0;
  for (int it = 0; it < request.max_iterations; ++it) {
    result->iterations = it + 1;
    const Pose X = InterpolateRigid(X_WA0, X_WA1, p_AC, t);
    const double d = Distance(A, X, B, X_WB, nullptr, scratch, tol);
    if (d <= tol) {
      result->hit = true;
      result->toi = t;
      result->X_WA_contact = X;
      CollectContactFeatures(A, B, X_WB, request, result, scratch);
      return true;
    }
    if (speed <= 0) break;
    // No point moves farther than speed * dt, so nothing can touch before
    // the distance is used up. Advancing by (d - tol/2) keeps the final
    // distance near tol instead of crawling towards zero.
    const double dt = (d - 0.5 * tol) / speed;
    t += dt;
    if (t > 1) break;
  }
  if (t <= 1 && result->iterations >= request.max_iterations) {
    // Cap reached while still approaching: report the last safe time.
    result->hit = true;
    result->toi = t;
    result->X_WA_contact = InterpolateRigid(X_WA0, X_WA1, p_AC, t);
    CollectContactFeatures(A, B, X_WB, request, result, scratch);
    return true;
  }
  result->X_WA_contact = X_WA1;
  return false;
}

}  // namespace hapticpd::pd
