#include "pd/primitives.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace hapticpd::pd::internal {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// ===========================================================================
// Expansion arithmetic (J. R. Shewchuk, "Adaptive Precision Floating-Point
// Arithmetic and Fast Robust Geometric Predicates", 1997). An expansion is an
// array of doubles, smallest magnitude first, pairwise nonoverlapping, whose
// exact sum is the represented value; its sign is the sign of its last
// (largest) component once zeros are eliminated. Correct under IEEE
// round-to-nearest-even without extended precision (true for x86-64 SSE2 and
// AArch64); these helpers must not be compiled with -ffast-math.

// x + y == a + b exactly, x = fl(a + b).
inline void TwoSum(double a, double b, double& x, double& y) {
  x = a + b;
  const double bv = x - a;
  const double av = x - bv;
  y = (a - av) + (b - bv);
}

// As TwoSum, valid when |a| >= |b| (or a == 0).
inline void FastTwoSum(double a, double b, double& x, double& y) {
  x = a + b;
  y = b - (x - a);
}

// x + y == a - b exactly, x = fl(a - b).
inline void TwoDiff(double a, double b, double& x, double& y) {
  x = a - b;
  const double bv = a - x;
  const double av = x + bv;
  y = (a - av) + (bv - b);
}

// x + y == a * b exactly. std::fma is exact by definition; contraction of the
// other helpers cannot happen since they contain no products.
inline void TwoProduct(double a, double b, double& x, double& y) {
  x = a * b;
  y = std::fma(a, b, -x);
}

// h = b * e; h may not alias e. Returns the length of h (>= 1), at most 2 elen.
int ScaleExpansionZeroElim(int elen, const double* e, double b, double* h) {
  double q, hh;
  TwoProduct(e[0], b, q, hh);
  int hindex = 0;
  if (hh != 0) h[hindex++] = hh;
  for (int i = 1; i < elen; ++i) {
    double p1, p0, sum;
    TwoProduct(e[i], b, p1, p0);
    TwoSum(q, p0, sum, hh);
    if (hh != 0) h[hindex++] = hh;
    FastTwoSum(p1, sum, q, hh);
    if (hh != 0) h[hindex++] = hh;
  }
  if (q != 0 || hindex == 0) h[hindex++] = q;
  return hindex;
}

// h = e + f; h may alias neither. Returns the length of h (>= 1), at most
// elen + flen. Shewchuk's fast_expansion_sum_zeroelim, with the reads past the
// end of e and f (harmless in the original, undefined behaviour in C++)
// removed.
int FastExpansionSumZeroElim(int elen, const double* e, int flen, const double* f, double* h) {
  int ei = 0, fi = 0, hindex = 0;
  double q, qnew, hh;
  // Takes the next component of smaller magnitude from e or f.
  auto take_e = [&]() {
    return fi >= flen || (ei < elen && ((f[fi] > e[ei]) == (f[fi] > -e[ei])));
  };
  if (take_e()) {
    q = e[ei++];
  } else {
    q = f[fi++];
  }
  if (ei < elen && fi < flen) {
    if (take_e()) {
      FastTwoSum(e[ei++], q, qnew, hh);
    } else {
      FastTwoSum(f[fi++], q, qnew, hh);
    }
    q = qnew;
    if (hh != 0) h[hindex++] = hh;
    while (ei < elen && fi < flen) {
      if (take_e()) {
        TwoSum(q, e[ei++], qnew, hh);
      } else {
        TwoSum(q, f[fi++], qnew, hh);
      }
      q = qnew;
      if (hh != 0) h[hindex++] = hh;
    }
  }
  while (ei < elen) {
    TwoSum(q, e[ei++], qnew, hh);
    q = qnew;
    if (hh != 0) h[hindex++] = hh;
  }
  while (fi < flen) {
    TwoSum(q, f[fi++], qnew, hh);
    q = qnew;
    if (hh != 0) h[hindex++] = hh;
  }
  if (q != 0 || hindex == 0) h[hindex++] = q;
  return hindex;
}

// An exact coordinate difference: one or two components.
struct Diff2 {
  double v[2];
  int n;
};

inline Diff2 ExactDiff(double a, double b) {
  Diff2 d;
  double hi, lo;
  TwoDiff(a, b, hi, lo);
  if (lo != 0) {
    d.v[0] = lo;
    d.v[1] = hi;
    d.n = 2;
  } else {
    d.v[0] = hi;
    d.n = 1;
  }
  return d;
}

// h = e * f for a short f (1 or 2 components). h holds at least 4 elen
// doubles; elen <= kMaxLen.
template <int kMaxLen>
int MulShort(int elen, const double* e, const Diff2& f, double* h) {
  if (f.n == 1) return ScaleExpansionZeroElim(elen, e, f.v[0], h);
  double t0[2 * kMaxLen], t1[2 * kMaxLen];
  const int n0 = ScaleExpansionZeroElim(elen, e, f.v[0], t0);
  const int n1 = ScaleExpansionZeroElim(elen, e, f.v[1], t1);
  return FastExpansionSumZeroElim(n0, t0, n1, t1, h);
}

// h = x * y - z * w for exact differences; h holds 16 doubles.
int TwoByTwo(const Diff2& x, const Diff2& y, const Diff2& z, const Diff2& w, double* h) {
  double p[8], q[8];
  const int np = MulShort<2>(x.n, x.v, y, p);
  int nq = MulShort<2>(z.n, z.v, w, q);
  for (int i = 0; i < nq; ++i) q[i] = -q[i];
  return FastExpansionSumZeroElim(np, p, nq, q, h);
}

}  // namespace

double Orient3dExact(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  const Diff2 adx = ExactDiff(a.x(), d.x()), ady = ExactDiff(a.y(), d.y()),
              adz = ExactDiff(a.z(), d.z());
  const Diff2 bdx = ExactDiff(b.x(), d.x()), bdy = ExactDiff(b.y(), d.y()),
              bdz = ExactDiff(b.z(), d.z());
  const Diff2 cdx = ExactDiff(c.x(), d.x()), cdy = ExactDiff(c.y(), d.y()),
              cdz = ExactDiff(c.z(), d.z());
  // Cofactor expansion along z, as in the filter:
  // det = adz (bdx cdy - cdx bdy) + bdz (cdx ady - adx cdy) + cdz (adx bdy - bdx ady).
  double m[16], t1[64], t2[64], t3[64], s12[128], det[192];
  int nm = TwoByTwo(bdx, cdy, cdx, bdy, m);
  const int n1 = MulShort<16>(nm, m, adz, t1);
  nm = TwoByTwo(cdx, ady, adx, cdy, m);
  const int n2 = MulShort<16>(nm, m, bdz, t2);
  nm = TwoByTwo(adx, bdy, bdx, ady, m);
  const int n3 = MulShort<16>(nm, m, cdz, t3);
  const int n12 = FastExpansionSumZeroElim(n1, t1, n2, t2, s12);
  const int n = FastExpansionSumZeroElim(n12, s12, n3, t3, det);
  return det[n - 1];
}

double Orient2dExact(const Vec2& a, const Vec2& b, const Vec2& c) {
  const Diff2 acx = ExactDiff(a.x(), c.x()), acy = ExactDiff(a.y(), c.y());
  const Diff2 bcx = ExactDiff(b.x(), c.x()), bcy = ExactDiff(b.y(), c.y());
  double det[16];
  const int n = TwoByTwo(acx, bcy, acy, bcx, det);
  return det[n - 1];
}

namespace {

// ===========================================================================
// Exact intersection helpers. Every branch below is decided by exact signs.

inline int Sign(double x) { return (x > 0) - (x < 0); }

// Sign of the side of d relative to the plane abc: +1 on the side the normal
// (b - a) x (c - a) points to. This is the convention of Guigue and
// Devillers' paper and code, the opposite of Orient3d.
inline int Side(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  return -Sign(Orient3d(a, b, c, d));
}

// Projection dropping axis k; the two kept axes are in cyclic order, so the
// 2-D orientation of a projected triangle has the sign of the k-th component
// of its 3-D normal.
inline Vec2 Drop(const Vec3& v, int k) {
  switch (k) {
    case 0:
      return Vec2(v.y(), v.z());
    case 1:
      return Vec2(v.z(), v.x());
    default:
      return Vec2(v.x(), v.y());
  }
}

// The axis along which the normal of abc has its largest component (each
// component is an exact-sign Orient2d of a projection), or -1 when a, b, c
// are exactly collinear. Dropping that axis projects the plane of abc
// injectively.
int DominantAxis(const Vec3& a, const Vec3& b, const Vec3& c) {
  int best = -1;
  double best_abs = 0;
  for (int k = 0; k < 3; ++k) {
    const double o = std::abs(Orient2d(Drop(a, k), Drop(b, k), Drop(c, k)));
    if (o > best_abs) {
      best_abs = o;
      best = k;
    }
  }
  return best;
}

// p within the axis-aligned box of a and b: for p collinear with a and b this
// is exactly "p on the closed segment ab".
inline bool InBox2(const Vec2& p, const Vec2& a, const Vec2& b) {
  return std::min(a.x(), b.x()) <= p.x() && p.x() <= std::max(a.x(), b.x()) &&
         std::min(a.y(), b.y()) <= p.y() && p.y() <= std::max(a.y(), b.y());
}

inline bool InBox3(const Vec3& p, const Vec3& a, const Vec3& b) {
  for (int k = 0; k < 3; ++k) {
    if (p[k] < std::min(a[k], b[k]) || p[k] > std::max(a[k], b[k])) return false;
  }
  return true;
}

// Closed 2-D segments ab and cd (either may have zero length).
bool SegmentsIntersect2(const Vec2& a, const Vec2& b, const Vec2& c, const Vec2& d) {
  const int o1 = Sign(Orient2d(a, b, c)), o2 = Sign(Orient2d(a, b, d));
  const int o3 = Sign(Orient2d(c, d, a)), o4 = Sign(Orient2d(c, d, b));
  if (o1 * o2 < 0 && o3 * o4 < 0) return true;  // proper crossing
  return (o1 == 0 && InBox2(c, a, b)) || (o2 == 0 && InBox2(d, a, b)) ||
         (o3 == 0 && InBox2(a, c, d)) || (o4 == 0 && InBox2(b, c, d));
}

// p in the closed non-degenerate 2-D triangle abc (either orientation).
bool PointInTriangle2(const Vec2& p, const Vec2& a, const Vec2& b, const Vec2& c) {
  const int s0 = Sign(Orient2d(a, b, p)), s1 = Sign(Orient2d(b, c, p)),
            s2 = Sign(Orient2d(c, a, p));
  const bool has_pos = s0 > 0 || s1 > 0 || s2 > 0;
  const bool has_neg = s0 < 0 || s1 < 0 || s2 < 0;
  return !(has_pos && has_neg);
}

// Closed segment s0s1 against the closed non-degenerate 2-D triangle abc: an
// endpoint inside, or a crossing of an edge.
bool SegmentTriangle2(const Vec2& s0, const Vec2& s1, const Vec2& a, const Vec2& b, const Vec2& c) {
  return PointInTriangle2(s0, a, b, c) || SegmentsIntersect2(s0, s1, a, b) ||
         SegmentsIntersect2(s0, s1, b, c) || SegmentsIntersect2(s0, s1, c, a);
}

// p on the closed 3-D segment ab (ab may have zero length).
bool PointOnSegment3(const Vec3& p, const Vec3& a, const Vec3& b) {
  return DominantAxis(p, a, b) < 0 && InBox3(p, a, b);
}

// Closed 3-D segments a0a1 and b0b1 (either may have zero length).
bool SegmentsIntersect3(const Vec3& a0, const Vec3& a1, const Vec3& b0, const Vec3& b1) {
  if (a0 == a1) return PointOnSegment3(a0, b0, b1);
  if (b0 == b1) return PointOnSegment3(b0, a0, a1);
  if (Orient3d(a0, a1, b0, b1) != 0) return false;  // skew
  int k = DominantAxis(a0, a1, b0);
  if (k < 0) k = DominantAxis(a0, a1, b1);
  if (k >= 0) {
    return SegmentsIntersect2(Drop(a0, k), Drop(a1, k), Drop(b0, k), Drop(b1, k));
  }
  // All four points collinear: compare intervals along an axis on which the
  // line is not constant (projection onto it is injective on the line).
  int axis = 0;
  const Vec3 e = (a1 - a0).cwiseAbs();
  if (e.y() > e[axis]) axis = 1;
  if (e.z() > e[axis]) axis = 2;
  const double lo = std::max(std::min(a0[axis], a1[axis]), std::min(b0[axis], b1[axis]));
  const double hi = std::min(std::max(a0[axis], a1[axis]), std::max(b0[axis], b1[axis]));
  return lo <= hi;
}

// p on the closed non-degenerate triangle abc.
bool PointInTriangle3(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  if (Orient3d(a, b, c, p) != 0) return false;
  const int k = DominantAxis(a, b, c);
  return PointInTriangle2(Drop(p, k), Drop(a, k), Drop(b, k), Drop(c, k));
}

// Closed segment s0s1 (possibly of zero length) against the closed
// non-degenerate triangle abc.
bool SegmentTriangle3(const Vec3& s0, const Vec3& s1, const Vec3& a, const Vec3& b, const Vec3& c) {
  if (s0 == s1) return PointInTriangle3(s0, a, b, c);
  const int o0 = Sign(Orient3d(a, b, c, s0)), o1 = Sign(Orient3d(a, b, c, s1));
  if (o0 == o1 && o0 != 0) return false;  // strictly on one side
  if (o0 == 0 && o1 == 0) {
    const int k = DominantAxis(a, b, c);
    return SegmentTriangle2(Drop(s0, k), Drop(s1, k), Drop(a, k), Drop(b, k), Drop(c, k));
  }
  // The segment meets the plane in one point; it lies in the closed triangle
  // iff the line s0s1 passes on the same side of all three edges (zero: on an
  // edge line; two zeros: through a vertex; three zeros are impossible here).
  const int e0 = Sign(Orient3d(s0, s1, a, b)), e1 = Sign(Orient3d(s0, s1, b, c)),
            e2 = Sign(Orient3d(s0, s1, c, a));
  const bool has_pos = e0 > 0 || e1 > 0 || e2 > 0;
  const bool has_neg = e0 < 0 || e1 < 0 || e2 < 0;
  return !(has_pos && has_neg);
}

// A triangle classified exactly: non-degenerate (axis >= 0), or the closed
// segment s0s1 it reduces to when its vertices are collinear (s0 == s1 when
// they coincide).
struct Classified {
  int axis;
  Vec3 s0, s1;
};

Classified Classify(const Vec3& a, const Vec3& b, const Vec3& c) {
  Classified r;
  r.axis = DominantAxis(a, b, c);
  if (r.axis >= 0) return r;
  // Collinear: the hull is spanned by the extreme points along the axis of
  // largest extent (non-zero unless all three coincide; a line that is not
  // constant along an axis is ordered by it).
  const Vec3 lo = a.cwiseMin(b).cwiseMin(c), hi = a.cwiseMax(b).cwiseMax(c);
  int k = 0;
  const Vec3 ext = hi - lo;
  if (ext.y() > ext[k]) k = 1;
  if (ext.z() > ext[k]) k = 2;
  const Vec3* v[3] = {&a, &b, &c};
  const Vec3 *vmin = v[0], *vmax = v[0];
  for (const Vec3* x : v) {
    if ((*x)[k] < (*vmin)[k]) vmin = x;
    if ((*x)[k] > (*vmax)[k]) vmax = x;
  }
  r.s0 = *vmin;
  r.s1 = *vmax;
  return r;
}

// Two triangles known to lie in one plane (both non-degenerate).
bool CoplanarTrianglesIntersect(const Vec3 P[3], const Vec3 Q[3], int axis) {
  Vec2 p[3], q[3];
  for (int i = 0; i < 3; ++i) {
    p[i] = Drop(P[i], axis);
    q[i] = Drop(Q[i], axis);
  }
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      if (SegmentsIntersect2(p[i], p[(i + 1) % 3], q[j], q[(j + 1) % 3])) return true;
    }
  }
  // No boundary crossing: disjoint, or one contains the other.
  return PointInTriangle2(p[0], q[0], q[1], q[2]) || PointInTriangle2(q[0], p[0], p[1], p[2]);
}

// Coplanar or degenerate configurations (at least one triangle has all three
// vertices of the other on its plane, or is itself collinear).
bool SpecialTrianglesIntersect(const Vec3 P[3], const Vec3 Q[3]) {
  const Classified cp = Classify(P[0], P[1], P[2]);
  const Classified cq = Classify(Q[0], Q[1], Q[2]);
  if (cp.axis >= 0 && cq.axis >= 0) {
    // Both proper triangles, so Q lies in P's plane (the caller saw all of
    // Q's vertices on it, or all of P's on Q's, which is the same plane).
    return CoplanarTrianglesIntersect(P, Q, cp.axis);
  }
  if (cp.axis >= 0) return SegmentTriangle3(cq.s0, cq.s1, P[0], P[1], P[2]);
  if (cq.axis >= 0) return SegmentTriangle3(cp.s0, cp.s1, Q[0], Q[1], Q[2]);
  return SegmentsIntersect3(cp.s0, cp.s1, cq.s0, cq.s1);
}

// Guigue-Devillers interval test. On entry p1 is alone on the non-negative
// side of plane (p2, q2, r2) with q1, r1 on the non-positive side, and p2 is
// alone on the non-negative side of plane (p1, q1, r1) likewise. The two
// segments in which the triangles cut the common line overlap iff both
// orientation tests below are non-positive.
inline bool CheckMinMax(const Vec3& p1, const Vec3& q1, const Vec3& r1, const Vec3& p2,
                        const Vec3& q2, const Vec3& r2) {
  if (Side(p2, p1, q1, q2) > 0) return false;
  if (Side(p2, r1, p1, r2) > 0) return false;
  return true;
}

// Second permutation stage: bring Q's lone vertex first; flip P's
// orientation (swap q1, r1) when that vertex is on P's negative side.
bool TriTri3d(const Vec3& p1, const Vec3& q1, const Vec3& r1, const Vec3& p2, const Vec3& q2,
              const Vec3& r2, int dp2, int dq2, int dr2, const Vec3 P[3], const Vec3 Q[3]) {
  if (dp2 > 0) {
    if (dq2 > 0) return CheckMinMax(p1, r1, q1, r2, p2, q2);
    if (dr2 > 0) return CheckMinMax(p1, r1, q1, q2, r2, p2);
    return CheckMinMax(p1, q1, r1, p2, q2, r2);
  }
  if (dp2 < 0) {
    if (dq2 < 0) return CheckMinMax(p1, q1, r1, r2, p2, q2);
    if (dr2 < 0) return CheckMinMax(p1, q1, r1, q2, r2, p2);
    return CheckMinMax(p1, r1, q1, p2, q2, r2);
  }
  if (dq2 < 0) {
    if (dr2 >= 0) return CheckMinMax(p1, r1, q1, q2, r2, p2);
    return CheckMinMax(p1, q1, r1, p2, q2, r2);
  }
  if (dq2 > 0) {
    if (dr2 > 0) return CheckMinMax(p1, r1, q1, p2, q2, r2);
    return CheckMinMax(p1, q1, r1, q2, r2, p2);
  }
  if (dr2 > 0) return CheckMinMax(p1, q1, r1, r2, p2, q2);
  if (dr2 < 0) return CheckMinMax(p1, r1, q1, r2, p2, q2);
  return SpecialTrianglesIntersect(P, Q);  // unreachable: filtered by the caller
}

}  // namespace

bool TrianglesIntersect(const Vec3& p0, const Vec3& p1, const Vec3& p2, const Vec3& q0,
                        const Vec3& q1, const Vec3& q2) {
  // Q's vertices against P's plane. A collinear P gives three exact zeros,
  // so a strict one-sided result also proves P non-degenerate.
  const int dq0 = Side(p0, p1, p2, q0), dq1 = Side(p0, p1, p2, q1), dq2 = Side(p0, p1, p2, q2);
  if (dq0 == dq1 && dq1 == dq2 && dq0 != 0) return false;
  const int dp0 = Side(q0, q1, q2, p0), dp1 = Side(q0, q1, q2, p1), dp2 = Side(q0, q1, q2, p2);
  if (dp0 == dp1 && dp1 == dp2 && dp0 != 0) return false;
  const Vec3 P[3] = {p0, p1, p2}, Q[3] = {q0, q1, q2};
  if ((dq0 == 0 && dq1 == 0 && dq2 == 0) || (dp0 == 0 && dp1 == 0 && dp2 == 0)) {
    return SpecialTrianglesIntersect(P, Q);
  }
  // Both triangles are non-degenerate and their planes differ. First
  // permutation stage: bring P's lone vertex first; flip Q's orientation
  // (swap q1, q2) when that vertex is on Q's negative side.
  if (dp0 > 0) {
    if (dp1 > 0) return TriTri3d(p2, p0, p1, q0, q2, q1, dq0, dq2, dq1, P, Q);
    if (dp2 > 0) return TriTri3d(p1, p2, p0, q0, q2, q1, dq0, dq2, dq1, P, Q);
    return TriTri3d(p0, p1, p2, q0, q1, q2, dq0, dq1, dq2, P, Q);
  }
  if (dp0 < 0) {
    if (dp1 < 0) return TriTri3d(p2, p0, p1, q0, q1, q2, dq0, dq1, dq2, P, Q);
    if (dp2 < 0) return TriTri3d(p1, p2, p0, q0, q1, q2, dq0, dq1, dq2, P, Q);
    return TriTri3d(p0, p1, p2, q0, q2, q1, dq0, dq2, dq1, P, Q);
  }
  if (dp1 < 0) {
    if (dp2 >= 0) return TriTri3d(p1, p2, p0, q0, q2, q1, dq0, dq2, dq1, P, Q);
    return TriTri3d(p0, p1, p2, q0, q1, q2, dq0, dq1, dq2, P, Q);
  }
  if (dp1 > 0) {
    if (dp2 > 0) return TriTri3d(p0, p1, p2, q0, q2, q1, dq0, dq2, dq1, P, Q);
    return TriTri3d(p1, p2, p0, q0, q1, q2, dq0, dq1, dq2, P, Q);
  }
  if (dp2 > 0) return TriTri3d(p2, p0, p1, q0, q1, q2, dq0, dq1, dq2, P, Q);
  if (dp2 < 0) return TriTri3d(p2, p0, p1, q0, q2, q1, dq0, dq2, dq1, P, Q);
  return SpecialTrianglesIntersect(P, Q);  // unreachable: filtered above
}

namespace {

// ===========================================================================
// Closest-point helpers (plain double arithmetic).

inline double Clamp01(double x) { return x < 0 ? 0 : (x > 1 ? 1 : x); }

// a + t (b - a), exactly a at t = 0 and exactly b at t = 1.
inline Vec3 Lerp(const Vec3& a, const Vec3& b, const Vec3& ab, double t) {
  if (t == 0) return a;
  if (t == 1) return b;
  return a + t * ab;
}

// Parameter in [0, 1] of the point of segment a + t ab closest to p;
// ab2 = |ab|^2 (0 for a point).
inline double ClosestParam(const Vec3& p, const Vec3& a, const Vec3& ab, double ab2) {
  if (!(ab2 > 0)) return 0;
  return Clamp01((p - a).dot(ab) / ab2);  // finite numerator, so never NaN
}

// x*y - z*w to ~1 ulp of the result (Kahan's algorithm). Only used for thin
// shapes: without hardware FMA std::fma is a library call.
inline double DiffOfProducts(double x, double y, double z, double w) {
  const double zw = z * w;
  const double err = std::fma(-z, w, zw);
  return std::fma(x, y, -zw) + err;
}

// u x v with every component accurate to ~1 ulp, even when u and v are
// nearly parallel (where the plain cross product has only ~1e-16 / sin
// relative accuracy).
inline Vec3 AccurateCross(const Vec3& u, const Vec3& v) {
  return Vec3(DiffOfProducts(u.y(), v.z(), u.z(), v.y()),
              DiffOfProducts(u.z(), v.x(), u.x(), v.z()),
              DiffOfProducts(u.x(), v.y(), u.y(), v.x()));
}

// u x v, recomputed with fused multiply-adds when the shape ratio
// |u x v| / scale2 falls below kThinRatio (scale2: the squared length scale of
// u and v), where the plain cross product keeps only ~1e-16 / ratio relative
// accuracy. The result is then the exact normal of the rounded input.
inline Vec3 ShapeNormal(const Vec3& u, const Vec3& v, double scale2) {
  const Vec3 n = u.cross(v);
  if (n.squaredNorm() >= kThinRatio * kThinRatio * scale2 * scale2) return n;
  return AccurateCross(u, v);
}

inline double MaxAbs(const Vec3& v) { return v.cwiseAbs().maxCoeff(); }

}  // namespace

SegmentClosest ClosestSegmentSegment(const Vec3& a0, const Vec3& a1, const Vec3& b0,
                                     const Vec3& b1) {
  const Vec3 d1 = a1 - a0, d2 = b1 - b0;
  const double l1 = d1.squaredNorm(), l2 = d2.squaredNorm();
  auto make = [&](double s, double t) {
    SegmentClosest r;
    r.s = s;
    r.t = t;
    r.p = Lerp(a0, a1, d1, s);
    r.q = Lerp(b0, b1, d2, t);
    r.dist_sq = (r.p - r.q).squaredNorm();
    return r;
  };
  if (!(l1 > 0)) return make(0, ClosestParam(a0, b0, d2, l2));
  if (!(l2 > 0)) return make(ClosestParam(b0, a0, d1, l1), 0);

  // Interior critical point of |a0 + s d1 - b0 - t d2|^2 through the common
  // normal n = d1 x d2: s |n|^2 = ((b0 - a0) x d2) . n. Unlike the usual
  // normal-equation form (denominator l1 l2 - (d1.d2)^2, which cancels
  // catastrophically) this keeps nearly parallel segments accurate.
  // The plain cross product suffices: its error for nearly parallel
  // segments only moves s along the valley (see below).
  const Vec3 n = d1.cross(d2);
  const double nn = n.squaredNorm();
  if (nn > kDegenerateRatio * kDegenerateRatio * l1 * l2) {
    const double s = (b0 - a0).cross(d2).dot(n) / nn;
    // t as the foot of p(s) on line b rather than from its own formula: for
    // nearly parallel segments s and t are each uncertain by ~1e-16 / sin
    // along the common direction, and independent errors would pull the two
    // witnesses apart by that much; matched, the error only moves the pair
    // along the valley of the distance, which costs ~1e-16 |b0 - a0|.
    const double t = (a0 + s * d1 - b0).dot(d2) / l2;
    // Inside the parameter square it is the global minimum (strictly convex
    // objective); otherwise the minimum is on the square's boundary.
    if (s >= 0 && s <= 1 && t >= 0 && t <= 1) return make(s, t);
  }
  // Boundary of the parameter square: the four endpoint-to-segment distances.
  // This also covers (nearly) parallel segments, whose minimum set always
  // reaches the boundary.
  SegmentClosest best = make(0, ClosestParam(a0, b0, d2, l2));
  SegmentClosest c = make(1, ClosestParam(a1, b0, d2, l2));
  if (c.dist_sq < best.dist_sq) best = c;
  c = make(ClosestParam(b0, a0, d1, l1), 0);
  if (c.dist_sq < best.dist_sq) best = c;
  c = make(ClosestParam(b1, a0, d1, l1), 1);
  if (c.dist_sq < best.dist_sq) best = c;
  return best;
}

Vec3 ClosestPointOnTriangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c,
                            Vec3* bary) {
  const Vec3 ab = b - a, bc = c - b, ca = a - c;
  const double lab = ab.squaredNorm(), lbc = bc.squaredNorm(), lca = ca.squaredNorm();
  const double l2 = std::max({lab, lbc, lca});
  if (!(l2 > 0)) {  // all three vertices coincide
    if (bary) *bary = Vec3(1, 0, 0);
    return a;
  }
  const Vec3 n = ShapeNormal(ab, -ca, l2);
  const double nn = n.squaredNorm();
  bool edge_ab = true, edge_bc = true, edge_ca = true;
  if (nn > kDegenerateRatio * kDegenerateRatio * l2 * l2) {
    // Unnormalised barycentric weights of p's projection onto the plane,
    // from in-plane edge normals (n x edge, pointing inwards): the weight of
    // a vertex is |n| times the distance of the projection from the opposite
    // edge's line. Sum = |n|^2 in exact arithmetic.
    const double wa = n.cross(bc).dot(p - b);
    const double wb = n.cross(ca).dot(p - c);
    const double wc = n.cross(ab).dot(p - a);
    const double sum = wa + wb + wc;
    if (wa >= 0 && wb >= 0 && wc >= 0 && sum > 0) {
      if (bary) *bary = Vec3(wa / sum, wb / sum, wc / sum);
      // The orthogonal projection, not sum(w_i v_i): it stays accurate for
      // slivers, where the weights are ill-conditioned.
      return p - ((p - a).dot(n) / nn) * n;
    }
    // Outside: the closest point lies on an edge whose line separates the
    // projection from the triangle, i.e. opposite a negative weight.
    edge_bc = wa < 0;
    edge_ca = wb < 0;
    edge_ab = wc < 0;
  }
  Vec3 best = a, best_bary(1, 0, 0);
  double best_d2 = kInf;
  auto try_edge = [&](const Vec3& e0, const Vec3& e1, const Vec3& e, double le, int i0, int i1) {
    const double t = ClosestParam(p, e0, e, le);
    const Vec3 x = Lerp(e0, e1, e, t);
    const double d2 = (p - x).squaredNorm();
    if (d2 < best_d2) {
      best_d2 = d2;
      best = x;
      best_bary.setZero();
      best_bary[i0] = 1 - t;
      best_bary[i1] = t;
    }
  };
  if (edge_ab) try_edge(a, b, ab, lab, 0, 1);
  if (edge_bc) try_edge(b, c, bc, lbc, 1, 2);
  if (edge_ca) try_edge(c, a, ca, lca, 2, 0);
  if (bary) *bary = best_bary;
  return best;
}

TriangleClosest ClosestTriangleTriangle(const Vec3& p0, const Vec3& p1, const Vec3& p2,
                                        const Vec3& q0, const Vec3& q1, const Vec3& q2) {
  const Vec3 P[3] = {p0, p1, p2}, Q[3] = {q0, q1, q2};
  TriangleClosest best{kInf, p0, q0};
  auto consider = [&](const Vec3& x, const Vec3& y) {
    const double d2 = (x - y).squaredNorm();
    if (d2 < best.dist_sq) best = {d2, x, y};
  };
  for (int i = 0; i < 3; ++i) {
    consider(P[i], ClosestPointOnTriangle(P[i], q0, q1, q2, nullptr));
    consider(ClosestPointOnTriangle(Q[i], p0, p1, p2, nullptr), Q[i]);
  }
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      const SegmentClosest sc = ClosestSegmentSegment(P[i], P[(i + 1) % 3], Q[j], Q[(j + 1) % 3]);
      if (sc.dist_sq < best.dist_sq) best = {sc.dist_sq, sc.p, sc.q};
    }
  }
  if (best.dist_sq == 0 || !TrianglesIntersect(p0, p1, p2, q0, q1, q2)) return best;

  // Intersecting, but no vertex or edge pair touches: an edge of one
  // triangle pierces the other. The pierce points are among the crossings of
  // each edge with the other triangle's plane; keep the best as witness.
  auto crossings = [&](const Vec3 E[3], const Vec3 T[3], bool e_is_p) {
    const Vec3 n = (T[1] - T[0]).cross(T[2] - T[0]);
    if (!(n.squaredNorm() > 0)) return;
    for (int i = 0; i < 3; ++i) {
      const Vec3& e0 = E[i];
      const Vec3& e1 = E[(i + 1) % 3];
      const double h0 = n.dot(e0 - T[0]), h1 = n.dot(e1 - T[0]);
      if ((h0 > 0 && h1 > 0) || (h0 < 0 && h1 < 0) || h0 == h1) continue;
      const Vec3 x = Lerp(e0, e1, e1 - e0, Clamp01(h0 / (h0 - h1)));
      const Vec3 y = ClosestPointOnTriangle(x, T[0], T[1], T[2], nullptr);
      if (e_is_p) {
        consider(x, y);
      } else {
        consider(y, x);
      }
    }
  };
  crossings(P, Q, true);
  crossings(Q, P, false);
  const Vec3 mid = 0.5 * (best.p + best.q);
  return {0.0, mid, mid};
}

namespace {

// ===========================================================================
// Time of impact by ray clipping. A moving point o + t d (o the origin of the
// local coordinates, so positions below are relative to o) is clipped
// against the convex region {x : m_k . x >= c_k for all k} inflated by tol,
// i.e. m_k . x >= c_k - tol with unit m_k. Flat features (a polygon, a
// segment, a point) are described as slabs of zero thickness, so the
// inflated region is the set of points within about tol of the feature.

struct HalfSpace {
  Vec3 m;    // unit inward normal
  double c;  // offset: the half-space is m . x >= c
};

// Enough for every feature below (a parallelogram needs 2 + 4 + 2).
constexpr int kMaxHalfSpaces = 8;

inline int AddSlab(HalfSpace* hs, const Vec3& m, double lo, double hi) {
  hs[0] = {m, lo};
  hs[1] = {-m, -hi};
  return 2;
}

// The earliest t in [0, t_max] inside the inflated region; see the contract
// of PointTriangleToi for how t is refined within it.
bool ClipRay(const Vec3& d, double t_max, double tol, const HalfSpace* hs, int count,
             double* t_out) {
  double lo = 0, hi = t_max, entry_exact = 0;
  bool entered = false;
  for (int k = 0; k < count; ++k) {
    const double rate = hs[k].m.dot(d);
    const double c = hs[k].c - tol;  // inflated: rate * t >= c
    if (rate > 0) {
      const double te = c / rate;
      if (te > lo) {
        lo = te;
        // The latest entering constraint decides where contact begins; its
        // uninflated boundary is where the features actually touch.
        entry_exact = hs[k].c / rate;
        entered = true;
      }
    } else if (rate < 0) {
      hi = std::min(hi, c / rate);
    } else if (c > 0) {
      return false;  // parallel to this face and outside it
    }
  }
  if (!(lo <= hi)) return false;
  // Already within tol at t = 0 when no constraint had to be entered.
  const double t = entered ? std::clamp(entry_exact, lo, hi) : 0.0;
  if (!(t >= 0 && t <= t_max)) return false;  // belt and braces against NaN
  *t_out = t;
  return true;
}

// Any unit vector perpendicular to the unit vector u.
inline Vec3 AnyPerpendicular(const Vec3& u) {
  const Vec3 au = u.cwiseAbs();
  Vec3 axis = Vec3::UnitX();
  if (au.y() < au.x() && au.y() <= au.z()) {
    axis = Vec3::UnitY();
  } else if (au.z() < au.x() && au.z() < au.y()) {
    axis = Vec3::UnitZ();
  }
  return u.cross(axis).normalized();
}

// The origin moving along d against the closed segment s0s1 (positions
// relative to the moving point's start): a box of half-width tol around it.
bool PointSegmentToiLocal(const Vec3& s0, const Vec3& s1, const Vec3& d, double t_max, double tol,
                          double* t) {
  HalfSpace hs[kMaxHalfSpaces];
  int k = 0;
  const Vec3 e = s1 - s0;
  const double len = e.norm();
  if (!(len > tol)) {
    // Shorter than the tolerance: a point (the midpoint is within tol / 2 of
    // every point of the segment).
    const Vec3 m = 0.5 * (s0 + s1);
    for (int axis = 0; axis < 3; ++axis) {
      k += AddSlab(hs + k, Vec3::Unit(axis), m[axis], m[axis]);
    }
  } else {
    const Vec3 u = e / len;
    const Vec3 v = AnyPerpendicular(u);
    const Vec3 w = u.cross(v);
    k += AddSlab(hs + k, u, u.dot(s0), u.dot(s1));
    const double v0 = v.dot(s0), w0 = w.dot(s0);
    k += AddSlab(hs + k, v, v0, v0);
    k += AddSlab(hs + k, w, w0, w0);
  }
  return ClipRay(d, t_max, tol, hs, k, t);
}

// The origin moving along d against the closed convex polygon v[0..count)
// (count <= 4, counter-clockwise seen from the side n points to; n unit):
// the polygon's zero-thickness slab, its side walls, and a cap slab along its
// longest vertex-to-vertex direction. The cap matters for slivers: inflated
// by tol, two walls meeting at a vertex of angle theta cross tol / sin(theta
// / 2) beyond it, which for a thin triangle (or nearly parallel segments)
// reaches far along the sliver's line. The sharp vertices of a convex
// polygon are the ends of its longest diagonal or edge, so the cap bounds
// the overshoot to about tol.
bool PointPolygonToiLocal(const Vec3* v, int count, const Vec3& n, const Vec3& d, double t_max,
                          double tol, double* t) {
  HalfSpace hs[kMaxHalfSpaces];
  const double h = n.dot(v[0]);
  int k = AddSlab(hs, n, h, h);
  Vec3 longest = Vec3::Zero();
  for (int i = 0; i < count; ++i) {
    const Vec3& a = v[i];
    const Vec3& b = v[(i + 1) % count];
    const Vec3 m = n.cross(b - a).normalized();  // inward: n x edge for CCW order
    hs[k++] = {m, m.dot(a)};
    for (int j = i + 1; j < count; ++j) {
      const Vec3 e = v[j] - a;
      if (e.squaredNorm() > longest.squaredNorm()) longest = e;
    }
  }
  const Vec3 u = longest.normalized();
  double lo = kInf, hi = -kInf;
  for (int i = 0; i < count; ++i) {
    lo = std::min(lo, u.dot(v[i]));
    hi = std::max(hi, u.dot(v[i]));
  }
  k += AddSlab(hs + k, u, lo, hi);
  return ClipRay(d, t_max, tol, hs, k, t);
}

// Keeps the earliest of several contact times.
struct Earliest {
  bool hit = false;
  double t = kInf;
  void Take(bool h, double tt) {
    if (h && tt < t) {
      t = tt;
      hit = true;
    }
  }
};

// Earliest event of the origin moving along d against the closed polygon
// boundary v[0..n) taken as its edges: the fallback when the polygon is
// (numerically) flat to a segment or a point.
bool PolygonEdgesToi(const Vec3* v, int n, const Vec3& d, double t_max, double tol, double* t) {
  Earliest best;
  for (int i = 0; i < n; ++i) {
    double tt = kInf;
    const bool h = PointSegmentToiLocal(v[i], v[(i + 1) % n], d, t_max, tol, &tt);
    best.Take(h, tt);
  }
  if (best.hit) *t = best.t;
  return best.hit;
}

}  // namespace

bool PointTriangleToi(const Vec3& p, const Vec3& d, const Vec3& a, const Vec3& b, const Vec3& c,
                      double t_max, double* t) {
  if (!(t_max >= 0)) return false;
  const double scale = std::max({MaxAbs(p), MaxAbs(a), MaxAbs(b), MaxAbs(c)});
  const double tol = kContactTol * scale;
  // Work relative to p: the moving point is the origin, and the triangle's
  // coordinates keep their precision near the contact even far from 0.
  const Vec3 v[3] = {a - p, b - p, c - p};
  const Vec3 ab = b - a, ac = c - a;
  const double l2 = std::max({ab.squaredNorm(), ac.squaredNorm(), (c - b).squaredNorm()});
  if (l2 > tol * tol) {
    const Vec3 n = ShapeNormal(ab, ac, l2);
    const double nn = n.squaredNorm();
    // Thin triangles get an FMA-accurate normal (ShapeNormal): the plane is
    // then the exact plane of the rounded vertices, whose tilt against the
    // intended plane (~1e-16 / ratio) is about the sliver's own long axis,
    // so in-plane motion still crosses it at the sliver. (A plain cross
    // product would tilt it about any axis and lift far in-plane motion out
    // of the tol slab.)
    if (nn > kDegenerateRatio * kDegenerateRatio * l2 * l2) {
      return PointPolygonToiLocal(v, 3, n / std::sqrt(nn), d, t_max, tol, t);
    }
  }
  // Degenerate: the triangle is (numerically) its edges.
  return PolygonEdgesToi(v, 3, d, t_max, tol, t);
}

bool SegmentSegmentToi(const Vec3& a0, const Vec3& a1, const Vec3& d, const Vec3& b0,
                       const Vec3& b1, double t_max, double* t) {
  if (!(t_max >= 0)) return false;
  const double scale = std::max({MaxAbs(a0), MaxAbs(a1), MaxAbs(b0), MaxAbs(b1)});
  const double tol = kContactTol * scale;
  // a(s) + t d = b(u) iff t d lies in the Minkowski difference
  // M = {b(u) - a(s)}, a parallelogram with corners b0 - a0, b1 - a0,
  // b1 - a1, b0 - a1 (counter-clockwise about ea x eb). Its sides are the
  // four endpoint events: [V0, V1] is endpoint a0 against segment b,
  // [V1, V2] endpoint b1 against segment a, and so on.
  const Vec3 V[4] = {b0 - a0, b1 - a0, b1 - a1, b0 - a1};
  const Vec3 ea = a1 - a0, eb = b1 - b0;
  const double la2 = ea.squaredNorm(), lb2 = eb.squaredNorm();
  if (la2 > tol * tol && lb2 > tol * tol) {
    const Vec3 n = ShapeNormal(ea, eb, std::sqrt(la2 * lb2));
    const double nn = n.squaredNorm();
    if (nn > kDegenerateRatio * kDegenerateRatio * la2 * lb2) {
      // Generic case: the plane crossing of the parallelogram is the Cramer
      // solution of a0 + s ea + t d = b0 + u eb; the side walls are s, u in
      // [0, 1]. Nearly parallel segments: accurate normal, as for slivers in
      // PointTriangleToi.
      return PointPolygonToiLocal(V, 4, n / std::sqrt(nn), d, t_max, tol, t);
    }
  }
  // Parallel or zero-length: M is (numerically) the union of its sides, the
  // four endpoint events.
  return PolygonEdgesToi(V, 4, d, t_max, tol, t);
}

}  // namespace hapticpd::pd::internal
