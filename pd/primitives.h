// Low-level geometric primitives for the BVH leaf tests: exact orientation
// predicates, exact closed-triangle intersection, closest points between
// points, segments and triangles, and translational time of impact.
//
// All functions take coordinates in one common frame (whichever frame the
// caller works in, typically the frame of mesh B) and return results in that
// frame; lengths are in the units of the input (metres in hapticpd), times are
// multiples of the given displacement `d`.
//
// These are called millions of times per second from BVH traversals: they
// never allocate, throw or log. The orientation filters are inline here; the
// exact fallback and the larger routines live in primitives.cc.
//
// Assumptions shared by every routine: finite inputs whose magnitudes stay in
// roughly [1e-100, 1e100] (the expansion arithmetic of the exact predicates
// must neither underflow nor overflow), IEEE double arithmetic with
// round-to-nearest-even, no -ffast-math.
//
// Tolerances (all relative to the scale S of the input, S = the largest
// absolute coordinate involved, so that they scale with coordinates of 1e-3
// or 1e4 alike):
//   * Orient2d, Orient3d, TrianglesIntersect: exact, no tolerance.
//   * Closest-point routines: plain double arithmetic (FMA for thin shapes);
//     no tolerance decides their output, only how degenerate and nearly
//     degenerate input is handled (kThinRatio, kDegenerateRatio). Distances
//     are accurate to a few ulp of S, slivers and nearly parallel segments
//     included (checked to 1e-12 S by the tests).
//   * Time of impact: contact means "within kContactTol * S" (see below).
#pragma once

#include <cmath>

#include "pd/types.h"

namespace hapticpd::pd::internal {

// ---------------------------------------------------------------------------
// Tolerances and thresholds (dimensionless; see the file comment).

/// Time of impact: a feature counts as touching another when it is within
/// kContactTol * S of it, S the largest absolute input coordinate. 1e-12 is
/// about 4500 ulp of S: well above the round-off of the plane and edge
/// functions (so exact grazing contacts and points that were placed "on" a
/// triangle by floating-point arithmetic are never missed), and far below any
/// geometric feature size of a haptic mesh.
inline constexpr double kContactTol = 1e-12;

/// Shape ratio below which a triangle (2 * area / longest_edge^2, about its
/// height over its longest edge) or a segment pair (sine of the angle between
/// them) counts as thin: its normal is then recomputed with fused
/// multiply-adds, since the plain cross product keeps only ~1e-16 / ratio
/// relative accuracy. The accurate normal is the exact normal of the rounded
/// input, so a sliver's plane can only be tilted about the sliver's own long
/// axis, which keeps projections onto it and in-plane motion near it exact to
/// round-off. (std::fma is a library call without hardware FMA; only thin
/// shapes pay for it.)
inline constexpr double kThinRatio = 1e-3;

/// Shape ratio at or below which a triangle is treated as the segments it
/// (numerically) is, and a segment pair as parallel: its plane is then not
/// used at all. 64 ulp.
inline constexpr double kDegenerateRatio = 64 * 0x1p-53;

// ---------------------------------------------------------------------------
// Exact orientation predicates (Shewchuk-style adaptive evaluation).

/// Exact fallbacks of Orient3d/Orient2d (expansion arithmetic: the
/// coordinate differences as exact two-term expansions, then exact products
/// and sums). Called only when the floating-point filter cannot certify the
/// sign; same return convention as the filtered versions.
double Orient3dExact(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d);
double Orient2dExact(const Vec2& a, const Vec2& b, const Vec2& c);

/// Six times the signed volume of tetrahedron (a, b, c, d):
///   Orient3d(a, b, c, d) = det[a - d; b - d; c - d]  (rows).
/// Convention (Shewchuk's): POSITIVE when d lies BELOW the plane through a, b,
/// c, where "above" is the side from which a, b, c appear counter-clockwise,
/// i.e. the side the normal (b - a) x (c - a) points to. So with a = 0,
/// b = x, c = y (normal +z): d = -z gives > 0, d = +z gives < 0. Zero exactly
/// when the four points are coplanar. The sign is always exact; the magnitude
/// is approximate (relative error ~1e-15 when the sign needed the exact path).
/// Swapping any two arguments flips the sign.
inline double Orient3d(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  const double adx = a.x() - d.x(), bdx = b.x() - d.x(), cdx = c.x() - d.x();
  const double ady = a.y() - d.y(), bdy = b.y() - d.y(), cdy = c.y() - d.y();
  const double adz = a.z() - d.z(), bdz = b.z() - d.z(), cdz = c.z() - d.z();
  const double bdxcdy = bdx * cdy, cdxbdy = cdx * bdy;
  const double cdxady = cdx * ady, adxcdy = adx * cdy;
  const double adxbdy = adx * bdy, bdxady = bdx * ady;
  const double det = adz * (bdxcdy - cdxbdy) + bdz * (cdxady - adxcdy) + cdz * (adxbdy - bdxady);
  const double permanent = (std::abs(bdxcdy) + std::abs(cdxbdy)) * std::abs(adz) +
                           (std::abs(cdxady) + std::abs(adxcdy)) * std::abs(bdz) +
                           (std::abs(adxbdy) + std::abs(bdxady)) * std::abs(cdz);
  // Shewchuk's o3derrboundA = (7 + 56 eps) eps, eps = 2^-53: a bound on the
  // error of the expression above (including the rounded differences)
  // relative to the permanent. Beyond it the sign of `det` is certain.
  constexpr double kEps = 0x1p-53;
  constexpr double kErrBound = (7.0 + 56.0 * kEps) * kEps;
  const double bound = kErrBound * permanent;
  if (det > bound || -det > bound) return det;
  return Orient3dExact(a, b, c, d);
}

/// Twice the signed area of triangle (a, b, c):
///   Orient2d(a, b, c) = det[a - c; b - c].
/// POSITIVE when a, b, c are counter-clockwise (x right, y up), negative when
/// clockwise, exactly zero when collinear. The sign is always exact.
inline double Orient2d(const Vec2& a, const Vec2& b, const Vec2& c) {
  const double detleft = (a.x() - c.x()) * (b.y() - c.y());
  const double detright = (a.y() - c.y()) * (b.x() - c.x());
  const double det = detleft - detright;
  double detsum;
  if (detleft > 0) {
    if (detright <= 0) return det;  // no cancellation possible
    detsum = detleft + detright;
  } else if (detleft < 0) {
    if (detright >= 0) return det;
    detsum = -detleft - detright;
  } else {
    return det;  // exact: one product is zero, the other is rounded but signed
  }
  // Shewchuk's ccwerrboundA = (3 + 16 eps) eps.
  constexpr double kEps = 0x1p-53;
  constexpr double kErrBound = (3.0 + 16.0 * kEps) * kEps;
  const double bound = kErrBound * detsum;
  if (det >= bound || -det >= bound) return det;
  return Orient2dExact(a, b, c);
}

// ---------------------------------------------------------------------------
// Exact intersection.

/// True when the closed triangles p0p1p2 and q0q1q2 share at least one point
/// (touching at a vertex, along an edge, or overlapping in a common plane all
/// count). Every decision is an exact Orient3d/Orient2d sign (Guigue-Devillers
/// for the general position case), so the answer is exact for the given
/// doubles. A degenerate (collinear) triangle is treated as the segment or
/// point it is.
bool TrianglesIntersect(const Vec3& p0, const Vec3& p1, const Vec3& p2, const Vec3& q0,
                        const Vec3& q1, const Vec3& q2);

// ---------------------------------------------------------------------------
// Closest points (plain double arithmetic, see the file comment).

/// Closest points between segments a0a1 and b0b1:
/// p = a0 + s (a1 - a0), q = b0 + t (b1 - b0), s, t in [0, 1],
/// dist_sq = |p - q|^2. p is exactly a0 (a1) when s == 0 (1), likewise q.
struct SegmentClosest {
  double dist_sq;
  double s;
  double t;
  Vec3 p;
  Vec3 q;
};

/// Closest pair of points of two closed segments: the interior critical point
/// when it lies in both segments, else the best of the four
/// endpoint-to-segment candidates. Robust for parallel, nearly parallel (even
/// crossing) and zero-length segments (a zero-length segment reports
/// parameter 0); the distance is accurate to a few ulp of the coordinates.
SegmentClosest ClosestSegmentSegment(const Vec3& a0, const Vec3& a1, const Vec3& b0,
                                     const Vec3& b1);

/// Closest point to p on the closed triangle abc. When `bary` is not null it
/// receives barycentric weights (u, v, w), u + v + w = 1, all >= 0, with
/// result = u a + v b + w c to round-off. Barycentric weights of a sliver are
/// ill-conditioned (accurate to ~1e-16 / ratio, ratio = height / longest
/// edge), so for a point inside the triangle the result is the orthogonal
/// projection itself, which stays accurate, and only the weights carry that
/// error. A degenerate triangle (ratio <= kDegenerateRatio) is treated as its
/// edges, or as a point when its vertices coincide.
Vec3 ClosestPointOnTriangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c, Vec3* bary);

/// Closest points between two triangles: p on triangle P, q on triangle Q,
/// dist_sq = |p - q|^2.
struct TriangleClosest {
  double dist_sq;
  Vec3 p;
  Vec3 q;
};

/// Distance between the closed triangles P = p0p1p2 and Q = q0q1q2. When
/// they intersect (exact test) dist_sq is 0 and p == q is a common point (to
/// round-off). Otherwise the minimum over the 6 vertex-triangle and 9
/// edge-edge pairs. Degenerate triangles are handled.
TriangleClosest ClosestTriangleTriangle(const Vec3& p0, const Vec3& p1, const Vec3& p2,
                                        const Vec3& q0, const Vec3& q1, const Vec3& q2);

// ---------------------------------------------------------------------------
// Translational time of impact (tolerance kContactTol, see above).
//
// Both routines return the smallest t in [0, t_max] at which the moving
// feature touches the fixed one, where "touch" means within
// tol = kContactTol * S (S = largest absolute coordinate of the features, not
// including d). If the features are already within tol at t = 0 the answer is
// t = 0. Otherwise t is the time the features come into exact contact when
// that happens while they are within tol (the generic case: exact to
// round-off), else the nearest time at which they are within tol (grazing
// contacts that round-off makes miss by less than tol). Return false (and
// leave *t untouched) when there is no contact in [0, t_max], when t_max is
// negative or NaN. Never produce NaN; t_max may be +infinity.

/// Point p moving as p + t d against the closed triangle abc. Handles motion
/// in the triangle's plane (2-D entry through an edge or vertex), p already on
/// the triangle (t = 0), slivers, and degenerate triangles (as their edges).
/// Implementation: the moving point is clipped (Liang-Barsky) against the
/// triangle's zero-thickness slab, side walls and a cap along its longest
/// edge, all inflated by tol.
bool PointTriangleToi(const Vec3& p, const Vec3& d, const Vec3& a, const Vec3& b, const Vec3& c,
                      double t_max, double* t);

/// Segment a0a1 moving as a + t d against the fixed closed segment b0b1. The
/// generic case is the solution of a0 + s (a1 - a0) + t d = b0 + u (b1 - b0)
/// with s, u in [0, 1] (the origin moving along d against the parallelogram
/// {b(u) - a(s)}, clipped as in PointTriangleToi, which also covers motion in
/// the plane of both segments); parallel, collinear and zero-length segments
/// reduce to the four endpoint events (an endpoint of a moving along d against
/// segment b, an endpoint of b moving along -d against segment a).
bool SegmentSegmentToi(const Vec3& a0, const Vec3& a1, const Vec3& d, const Vec3& b0,
                       const Vec3& b1, double t_max, double* t);

}  // namespace hapticpd::pd::internal
