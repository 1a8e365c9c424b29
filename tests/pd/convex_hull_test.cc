// ConvexHull: exact containment of every input point (exact orientation),
// watertight convex output, analytic volumes, degenerate input (coplanar,
// collinear, repeated points), procedural shapes, and random clouds against
// Bullet's btConvexHullComputer and a brute-force facet enumeration.
#include "pd/convex_hull.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <set>

#include "pd/convex.h"
#include "pd/primitives.h"
#include "pd/shapes.h"
#include "tests/oracles/bullet_oracle.h"
#include "tests/test_util.h"

namespace hapticpd::pd {
namespace {

using internal::Orient3d;

double Volume(const Mesh& m) {
  double v = 0;
  for (const Triangle& t : m.triangles()) {
    const auto& p = m.vertices();
    v += p[t[0]].dot(p[t[1]].cross(p[t[2]])) / 6;
  }
  return v;
}

// The properties every hull must have, checked exactly where it matters:
// closed, convex, outward, no zero-area triangle, every input point on or
// below every face plane (exact Orient3d; `slack` > 0 allows points left
// out as sliver vertices to be that far outside, relative to the hull's
// size), and its vertices are input points.
void ExpectValidHull(const Mesh& hull, const std::vector<Vec3>& points, double slack = 0) {
  EXPECT_TRUE(hull.watertight());
  EXPECT_TRUE(IsConvexMesh(hull));
  EXPECT_EQ(hull.degenerate_triangle_count(), 0);
  EXPECT_TRUE(hull.diagnostics().empty()) << hull.diagnostics().front();
  EXPECT_GT(Volume(hull), 0);
  // Euler: V - E + F = 2 (no stray vertices).
  EXPECT_EQ(static_cast<long>(hull.num_vertices()) - static_cast<long>(hull.edges().size()) +
                static_cast<long>(hull.num_triangles()),
            2);
  const auto& V = hull.vertices();
  int outside = 0;
  double worst = 0;
  for (std::size_t f = 0; f < hull.num_triangles(); ++f) {
    const Triangle& t = hull.triangles()[f];
    for (const Vec3& p : points) {
      // Orient3d > 0: p below the outward-facing triangle; 0: on its plane.
      if (Orient3d(V[t[0]], V[t[1]], V[t[2]], p) < 0) {
        ++outside;
        worst = std::max(worst, hull.face_normals()[f].dot(p - V[t[0]]));
      }
    }
  }
  if (slack == 0) {
    EXPECT_EQ(outside, 0) << "input points strictly outside a hull face, by up to " << worst;
  } else {
    EXPECT_LE(worst, slack * hull.size()) << outside << " point-face pairs outside";
  }
  std::set<std::array<double, 3>> input;
  for (const Vec3& p : points) input.insert({p.x(), p.y(), p.z()});
  std::set<std::array<double, 3>> seen;
  for (const Vec3& v : V) {
    EXPECT_TRUE(input.contains({v.x(), v.y(), v.z()})) << "hull vertex is not an input point";
    EXPECT_TRUE(seen.insert({v.x(), v.y(), v.z()}).second) << "hull vertex repeated";
  }
}

std::vector<Vec3> CubeCorners(double h) {
  std::vector<Vec3> p;
  for (int i = 0; i < 8; ++i) p.emplace_back(i & 1 ? h : -h, i & 2 ? h : -h, i & 4 ? h : -h);
  return p;
}

TEST(ConvexHull, CubeCornersGiveTwelveTrianglesAndExactVolume) {
  const std::vector<Vec3> p = CubeCorners(0.5);
  const Mesh hull = ConvexHull(p);
  ExpectValidHull(hull, p);
  EXPECT_EQ(hull.num_vertices(), 8u);
  EXPECT_EQ(hull.num_triangles(), 12u);
  EXPECT_DOUBLE_EQ(Volume(hull), 1.0);
}

TEST(ConvexHull, OctahedronVolume) {
  const double r = 0.3;
  std::vector<Vec3> p;
  for (int k = 0; k < 3; ++k) {
    p.push_back(Vec3::Unit(k) * r);
    p.push_back(-Vec3::Unit(k) * r);
  }
  const Mesh hull = ConvexHull(p);
  ExpectValidHull(hull, p);
  EXPECT_EQ(hull.num_vertices(), 6u);
  EXPECT_EQ(hull.num_triangles(), 8u);
  EXPECT_NEAR(Volume(hull), 4.0 / 3.0 * r * r * r, 1e-15);
}

TEST(ConvexHull, LatticeWithFaceEdgeAndInteriorPointsKeepsOnlyTheCorners) {
  // 6x6x6 grid: points on faces (coplanar), on edges (collinear) and inside,
  // in an order that inserts non-extreme boundary points before the corners.
  std::vector<Vec3> p;
  for (int i = 0; i < 6; ++i) {
    for (int j = 0; j < 6; ++j) {
      for (int k = 0; k < 6; ++k) p.emplace_back(0.1 * i, 0.1 * j, 0.1 * k);
    }
  }
  std::mt19937_64 rng(testing::TestSeed());
  for (int pass = 0; pass < 5; ++pass) {
    std::shuffle(p.begin(), p.end(), rng);
    const Mesh hull = ConvexHull(p);
    ExpectValidHull(hull, p);
    EXPECT_EQ(hull.num_vertices(), 8u);
    EXPECT_EQ(hull.num_triangles(), 12u);
    EXPECT_NEAR(Volume(hull), 0.125, 1e-15);
  }
}

TEST(ConvexHull, RepeatedPointsAppearOnce) {
  std::vector<Vec3> p;
  for (int r = 0; r < 4; ++r) {
    for (const Vec3& c : CubeCorners(2.0)) p.push_back(c);
  }
  p.push_back(Vec3::Zero());
  p.push_back(Vec3::Zero());
  const Mesh hull = ConvexHull(p);
  ExpectValidHull(hull, p);
  EXPECT_EQ(hull.num_vertices(), 8u);
  EXPECT_DOUBLE_EQ(Volume(hull), 64.0);
}

TEST(ConvexHull, ManyCoplanarPointsOnAFace) {
  // A pyramid whose square base carries a dense random cloud of points
  // exactly in its plane (z = 0 exactly) and points along its edges.
  std::mt19937_64 rng(testing::TestSeed() + 1);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<Vec3> p = {Vec3(-1, -1, 0), Vec3(1, -1, 0), Vec3(1, 1, 0), Vec3(-1, 1, 0),
                         Vec3(0, 0, 2)};
  for (int i = 0; i < 400; ++i) p.emplace_back(u(rng), u(rng), 0);
  for (int i = 0; i < 50; ++i) p.emplace_back(u(rng), 1, 0);
  for (int i = 0; i < 50; ++i) p.emplace_back(-1, u(rng), 0);
  std::shuffle(p.begin(), p.end(), rng);
  const Mesh hull = ConvexHull(p);
  ExpectValidHull(hull, p);
  EXPECT_EQ(hull.num_vertices(), 5u);
  EXPECT_EQ(hull.num_triangles(), 6u);
  EXPECT_NEAR(Volume(hull), 4.0 * 2 / 3, 1e-15);
}

TEST(ConvexHull, CoplanarCirclesFormAPrism) {
  // Two exactly planar rings (z = +-0.1) of points in convex position plus
  // their centres: the caps are triangulated without zero-area triangles.
  const int n = 64;
  std::vector<Vec3> p = {Vec3(0, 0, -0.1), Vec3(0, 0, 0.1)};
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * i / n;
    p.emplace_back(std::cos(a), std::sin(a), -0.1);
    p.emplace_back(std::cos(a), std::sin(a), 0.1);
  }
  const Mesh hull = ConvexHull(p);
  ExpectValidHull(hull, p);
  EXPECT_EQ(hull.num_vertices(), 2u * n);
  EXPECT_EQ(hull.num_triangles(), 2u * (n - 2) + 2u * n);
  EXPECT_NEAR(Volume(hull), 0.2 * 0.5 * n * std::sin(2 * M_PI / n), 1e-13);
}

TEST(ConvexHull, PointsOnASphereAreAllVertices) {
  std::mt19937_64 rng(testing::TestSeed() + 2);
  std::normal_distribution<double> g(0, 1);
  for (int n : {4, 5, 50, 2000}) {
    SCOPED_TRACE(n);
    std::vector<Vec3> p;
    for (int i = 0; i < n; ++i) p.push_back(Vec3(g(rng), g(rng), g(rng)).normalized() * 0.07);
    const Mesh hull = ConvexHull(p);
    ExpectValidHull(hull, p);
    EXPECT_EQ(hull.num_vertices(), static_cast<std::size_t>(n));
    EXPECT_EQ(hull.num_triangles(), static_cast<std::size_t>(2 * n - 4));
    // Bullet rounds to a fixed-point grid (~5e-6 of the extent), so points
    // that are barely extreme may merge into a face there: volumes agree to
    // that level.
    const testing::BulletHullSummary bt = testing::BulletConvexHull(p);
    EXPECT_GE(bt.input_vertices.size(), static_cast<std::size_t>(n * 99 / 100));
    EXPECT_NEAR(Volume(hull), bt.volume, 2e-5 * bt.volume);
    EXPECT_GE(Volume(hull), bt.volume * (1 - 1e-12));  // ours keeps every extreme point
    if (n == 2000) {
      EXPECT_NEAR(Volume(hull), 4.0 / 3 * M_PI * std::pow(0.07, 3), 0.01 * bt.volume);
    }
  }
}

// Every triple of points with all others on or below its plane spans a
// facet's plane; the hull must have a triangle in each such plane, and each
// of its triangles must lie in one (brute force, O(n^4), small n only).
void ExpectSameFacetsAsBruteForce(const Mesh& hull, const std::vector<Vec3>& p) {
  const int n = static_cast<int>(p.size());
  const auto& V = hull.vertices();
  int facets = 0;
  for (int i = 0; i < n; ++i) {
    for (int j = i + 1; j < n; ++j) {
      for (int k = j + 1; k < n; ++k) {
        int above = 0, below = 0;
        for (int m = 0; m < n; ++m) {
          const double o = Orient3d(p[i], p[j], p[k], p[m]);
          above += o < 0;
          below += o > 0;
        }
        if ((above > 0 && below > 0) || above + below == 0) continue;  // not supporting
        ++facets;
        bool found = false;
        for (const Triangle& t : hull.triangles()) {
          found = found || (Orient3d(p[i], p[j], p[k], V[t[0]]) == 0 &&
                            Orient3d(p[i], p[j], p[k], V[t[1]]) == 0 &&
                            Orient3d(p[i], p[j], p[k], V[t[2]]) == 0);
        }
        EXPECT_TRUE(found) << "supporting plane through points " << i << ", " << j << ", " << k
                           << " has no hull triangle";
      }
    }
  }
  EXPECT_GE(facets, static_cast<int>(hull.num_triangles()));
}

TEST(ConvexHull, RandomCloudsAgreeWithBulletAndBruteForce) {
  std::mt19937_64 rng(testing::TestSeed() + 3);
  std::normal_distribution<double> g(0, 1);
  std::uniform_real_distribution<double> u(-1, 1);
  const int count = testing::TestCount(40);
  for (int trial = 0; trial < count; ++trial) {
    SCOPED_TRACE(trial);
    const int n = trial % 4 == 0 ? 30 : 300;
    std::vector<Vec3> p;
    const Vec3 scale(std::exp(g(rng)), std::exp(g(rng)), std::exp(g(rng)));
    for (int i = 0; i < n; ++i) {
      const Vec3 x = trial % 2 ? Vec3(g(rng), g(rng), g(rng)) : Vec3(u(rng), u(rng), u(rng));
      p.push_back(x.cwiseProduct(scale) + Vec3(5, -3, 1));
    }
    const Mesh hull = ConvexHull(p);
    ExpectValidHull(hull, p);
    const testing::BulletHullSummary bt = testing::BulletConvexHull(p);
    EXPECT_NEAR(Volume(hull), bt.volume, 2e-5 * bt.volume);
    EXPECT_GE(Volume(hull), bt.volume * (1 - 1e-12));  // ours keeps every extreme point
    // Bullet's grid may drop a barely extreme point (see above); otherwise
    // the vertex sets are the same.
    std::vector<int> ours;
    for (const Vec3& v : hull.vertices()) {
      ours.push_back(static_cast<int>(std::find(p.begin(), p.end(), v) - p.begin()));
    }
    std::sort(ours.begin(), ours.end());
    std::vector<int> missing;
    std::set_difference(bt.input_vertices.begin(), bt.input_vertices.end(), ours.begin(),
                        ours.end(), std::back_inserter(missing));
    EXPECT_TRUE(missing.empty()) << "Bullet has a hull vertex we lack: point " << missing[0];
    EXPECT_LE(ours.size(), bt.input_vertices.size() + 2);
    if (n <= 30) ExpectSameFacetsAsBruteForce(hull, p);
  }
}

TEST(ConvexHull, RotatedLatticeIsStillAValidHull) {
  // Rounded rotation: the lattice's faces are no longer exactly planar, so
  // the exact hull keeps whatever is (barely) extreme; it must stay valid.
  std::vector<Vec3> p;
  const Mat3 R = Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  for (int i = 0; i < 5; ++i) {
    for (int j = 0; j < 5; ++j) {
      for (int k = 0; k < 5; ++k) p.push_back(R * Vec3(0.1 * i, 0.1 * j, 0.1 * k));
    }
  }
  // Slivers removed (default): valid, with left-out points within the slack.
  const Mesh hull = ConvexHull(p);
  ExpectValidHull(hull, p, 1e-10);
  EXPECT_NEAR(Volume(hull), 0.064, 1e-14);
  // The exact hull: every point inside or on it, whatever its triangles.
  const Mesh exact = ConvexHull(p, "lattice", ConvexHullOptions{.sliver_ratio = 0});
  EXPECT_TRUE(exact.watertight());
  const auto& V = exact.vertices();
  for (const Triangle& t : exact.triangles()) {
    for (const Vec3& q : p) EXPECT_GE(Orient3d(V[t[0]], V[t[1]], V[t[2]], q), 0);
  }
  EXPECT_GE(exact.num_vertices(), hull.num_vertices());
  EXPECT_NEAR(Volume(exact), 0.064, 1e-14);
}

TEST(ConvexHull, BarelyExtremePointsMakeSliversOnlyWhenAskedFor) {
  // A box with a point 1e-13 outside the middle of an edge: exactly extreme.
  std::vector<Vec3> p = CubeCorners(1);
  p.emplace_back(0, 1 + 1e-13, 1);
  const Mesh exact = ConvexHull(p, "box", ConvexHullOptions{.sliver_ratio = 0});
  EXPECT_EQ(exact.num_vertices(), 9u);
  EXPECT_TRUE(exact.watertight());
  const Mesh hull = ConvexHull(p, "box");
  ExpectValidHull(hull, p, 1e-12);
  EXPECT_EQ(hull.num_vertices(), 8u);
}

TEST(ConvexHull, HullsOfProceduralShapes) {
  for (const char* spec : {"torus", "spoon", "hammer", "torusknot", "cup", "sphere:0.05,2"}) {
    SCOPED_TRACE(spec);
    const Mesh shape = shapes::MakeShape(spec);
    const Mesh hull = ConvexHull(shape.vertices(), std::string("hull of ") + spec);
    // The cup's revolved straight profile rounds into barely extreme points.
    ExpectValidHull(hull, shape.vertices(), 1e-10);
    const testing::BulletHullSummary bt = testing::BulletConvexHull(shape.vertices());
    EXPECT_NEAR(Volume(hull), bt.volume, 2e-5 * bt.volume);
    EXPECT_GE(Volume(hull), bt.volume * (1 - 1e-12));  // ours keeps every extreme point
    EXPECT_EQ(hull.source(), std::string("hull of ") + spec);
    // The hull encloses the shape: at least its (positive) volume.
    EXPECT_GE(Volume(hull), 0.999 * Volume(shapes::MakeShape(spec)) / 2);
  }
}

TEST(ConvexHull, RejectsTooFewNonFiniteAndFlatInput) {
  auto expect_error = [](const std::vector<Vec3>& p, const std::string& needle) {
    try {
      ConvexHull(p, "pts");
      ADD_FAILURE() << "no MeshError; expected one mentioning '" << needle << "'";
    } catch (const MeshError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
      EXPECT_EQ(std::string(e.what()).rfind("pts: ", 0), 0u) << e.what();
    }
  };
  expect_error({}, "at least 4 points");
  expect_error({Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0)}, "at least 4 points");
  expect_error(std::vector<Vec3>(10, Vec3(1, 2, 3)), "at least 4 distinct");
  std::vector<Vec3> line, plane;
  for (int i = 0; i < 20; ++i) line.emplace_back(0.1 * i, 0.2 * i, -0.3 * i);
  expect_error(line, "coplanar");
  std::mt19937_64 rng(testing::TestSeed());
  std::uniform_real_distribution<double> u(-1, 1);
  for (int i = 0; i < 200; ++i) {
    const double x = u(rng), y = u(rng);
    plane.emplace_back(x, y, 0.25);  // exactly planar
  }
  expect_error(plane, "coplanar");
  std::vector<Vec3> bad = CubeCorners(1);
  bad[3].y() = std::numeric_limits<double>::quiet_NaN();
  expect_error(bad, "point 3");
  bad[3].y() = std::numeric_limits<double>::infinity();
  expect_error(bad, "not finite");
  bad[3].y() = 1e200;
  expect_error(bad, "1e100");
}

TEST(ConvexHull, RejectsABadSliverRatio) {
  for (double r : {-1.0, 0.5, std::numeric_limits<double>::quiet_NaN()}) {
    EXPECT_THROW(ConvexHull(CubeCorners(1), "c", ConvexHullOptions{.sliver_ratio = r}), MeshError);
  }
}

}  // namespace
}  // namespace hapticpd::pd
