// The cells wholly inside a closed model (pd/interior_grid.h) and the probe
// sample points a cold query tests against them (GeometryModel::
// sample_points). A point in an inside cell must be inside the solid: checked
// against the analytic ball for the sphere and against PointInside (a ray
// count, independent of the grid's rasterisation and flood fill) elsewhere.
// The scene points a cold query tests against the probe's cells
// (PointsEnclosedBy), and the cold queries' cull with them against an open
// scene, which has no inside cells of its own.
// Presets: every preset (pd_tests).
#include "pd/interior_grid.h"

#include <gtest/gtest.h>

#include <random>

#include "pd/geometry_model.h"
#include "pd/pdg.h"
#include "pd/pdt.h"
#include "pd/primitives.h"
#include "pd/queries.h"
#include "pd/shapes.h"

namespace hapticpd::pd {
namespace {

// `count` uniformly random points in the model's bounding box.
std::vector<Vec3> PointsInBounds(const Mesh& mesh, int count, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(0, 1);
  std::vector<Vec3> out;
  const Aabb& b = mesh.bounds();
  for (int k = 0; k < count; ++k) {
    out.push_back(b.lo + Vec3(unit(rng), unit(rng), unit(rng)).cwiseProduct(b.Size()));
  }
  return out;
}

// The mesh with its triangles turned inside out.
Mesh Inverted(const Mesh& m) {
  std::vector<Triangle> t = m.triangles();
  for (Triangle& f : t) std::swap(f[1], f[2]);
  return Mesh::FromArrays(m.vertices(), std::move(t), "inverted");
}

// Two meshes as one (the second's vertex indices shifted).
Mesh Joined(const Mesh& a, const Mesh& b, const std::string& name) {
  std::vector<Vec3> v = a.vertices();
  std::vector<Triangle> t = a.triangles();
  const auto offset = static_cast<Index>(v.size());
  v.insert(v.end(), b.vertices().begin(), b.vertices().end());
  for (Triangle f : b.triangles()) {
    for (Index& i : f) i += offset;
    t.push_back(f);
  }
  return Mesh::FromArrays(std::move(v), std::move(t), name);
}

// Distance from p to the nearest triangle of the mesh (brute force).
double DistanceToSurface(const Mesh& m, const Vec3& p) {
  double best = std::numeric_limits<double>::infinity();
  for (const Triangle& t : m.triangles()) {
    const Vec3 q = internal::ClosestPointOnTriangle(p, m.vertices()[t[0]], m.vertices()[t[1]],
                                                    m.vertices()[t[2]], nullptr);
    best = std::min(best, (q - p).norm());
  }
  return best;
}

TEST(InteriorGrid, SphereCellsLieInsideTheBallAndFillIt) {
  constexpr double kRadius = 0.05;
  const GeometryModel model(shapes::Sphere(kRadius, 3));
  ASSERT_TRUE(model.closed());
  ASSERT_FALSE(model.interior().empty());
  int deep = 0, deep_covered = 0;
  for (const Vec3& p : PointsInBounds(model.mesh(), 20000, 1)) {
    // The icosphere is inscribed in the ball: its inside is within it.
    if (model.interior().Inside(p)) {
      EXPECT_LT(p.norm(), kRadius) << p.transpose();
    }
    if (p.norm() < 0.85 * kRadius) {
      ++deep;
      deep_covered += model.interior().Inside(p);
    }
  }
  // Three cells (about 3 mm) from the surface every point is in an inside
  // cell.
  ASSERT_GT(deep, 1000);
  EXPECT_GE(deep_covered, 0.99 * deep) << deep_covered << " of " << deep;
}

TEST(InteriorGrid, InsideCellsAgreeWithPointInside) {
  for (Mesh mesh : {shapes::Torus(), shapes::Cup(), shapes::TorusKnot(), shapes::Hammer()}) {
    SCOPED_TRACE(mesh.source());
    const GeometryModel model(std::move(mesh));
    ASSERT_TRUE(model.closed());
    QueryScratch scratch;
    int inside = 0, covered = 0;
    for (const Vec3& p : PointsInBounds(model.mesh(), 4000, 2)) {
      const bool in = PointInside(model, p, &scratch);
      inside += in;
      if (model.interior().Inside(p)) {
        ++covered;
        EXPECT_TRUE(in) << p.transpose();
      }
    }
    // The torus and the hammer are thick enough for most of their inside to
    // be covered; the cup's walls and the knot's tube hold fewer cells.
    EXPECT_GT(covered, 0);
    EXPECT_LE(covered, inside);
  }
}

TEST(InteriorGrid, ACavityOfAHollowSolidStaysOut) {
  // A box with a box-shaped void: the inner surface faces inwards.
  const GeometryModel model(Joined(shapes::Box(Vec3::Constant(0.05)),
                                   Inverted(shapes::Box(Vec3::Constant(0.03))), "hollow box"));
  ASSERT_TRUE(model.closed());
  int wall = 0, wall_covered = 0;
  for (const Vec3& p : PointsInBounds(model.mesh(), 20000, 3)) {
    const double m = p.cwiseAbs().maxCoeff();
    if (m < 0.03) {
      EXPECT_FALSE(model.interior().Inside(p)) << "in the void: " << p.transpose();
    }
    if (m > 0.034 && m < 0.046) {
      ++wall;
      wall_covered += model.interior().Inside(p);
    }
  }
  ASSERT_GT(wall, 1000);
  EXPECT_GE(wall_covered, 0.99 * wall);
}

TEST(InteriorGrid, AnOpenMeshHasNone) {
  const Mesh sphere = shapes::Sphere(0.05, 3);
  std::vector<Triangle> t = sphere.triangles();
  t.pop_back();  // a hole
  const GeometryModel model(Mesh::FromArrays(sphere.vertices(), std::move(t), "holed sphere"));
  ASSERT_FALSE(model.closed());
  EXPECT_TRUE(model.interior().empty());
  for (const Vec3& p : {Vec3(0, 0, 0), Vec3(0.01, 0, 0)}) EXPECT_FALSE(model.interior().Inside(p));
}

TEST(InteriorGrid, PointsOutsideTheGridOrNotFiniteAreNotInside) {
  const GeometryModel model(shapes::Sphere(0.05, 3));
  ASSERT_TRUE(model.interior().Inside(Vec3::Zero()));
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  for (const Vec3& p : {Vec3(1, 0, 0), Vec3(-1, -1, -1), Vec3(nan, 0, 0), Vec3(0, inf, 0),
                        Vec3(0, 0, -inf), Vec3(1e300, 0, 0)}) {
    EXPECT_FALSE(model.interior().Inside(p)) << p.transpose();
  }
}

TEST(InteriorGrid, ManyEnclosedPocketsStopAtTheTestCap) {
  // 17^3 closed cubes, each enclosing its own cells: more components than
  // InteriorGrid classifies with PointInside; the rest stay out.
  constexpr int kPerAxis = 17;
  const Mesh cube = shapes::Box(Vec3::Constant(0.02));
  std::vector<Vec3> v;
  std::vector<Triangle> t;
  std::vector<Vec3> centres;
  for (int i = 0; i < kPerAxis; ++i) {
    for (int j = 0; j < kPerAxis; ++j) {
      for (int k = 0; k < kPerAxis; ++k) {
        const Vec3 c = 0.06 * Vec3(i, j, k);
        centres.push_back(c);
        const auto offset = static_cast<Index>(v.size());
        for (const Vec3& p : cube.vertices()) v.push_back(p + c);
        for (Triangle f : cube.triangles()) {
          for (Index& q : f) q += offset;
          t.push_back(f);
        }
      }
    }
  }
  const GeometryModel model(Mesh::FromArrays(std::move(v), std::move(t), "cubes"));
  ASSERT_TRUE(model.closed());
  int inside = 0;
  for (const Vec3& c : centres) inside += model.interior().Inside(c);
  EXPECT_GT(inside, 0);
  EXPECT_LE(inside, InteriorGrid::kMaxInsideTests);
  EXPECT_LT(inside, static_cast<int>(centres.size()));
}

TEST(SamplePoints, SpreadOverTheSurfaceOfTheFirstComponent) {
  // The stick's vertices sit on its end caps only: the samples must cover
  // its length too (points inside its long side triangles).
  const GeometryModel stick(shapes::Stick());
  const auto& s = stick.sample_points();
  ASSERT_EQ(static_cast<int>(s.size()), GeometryModel::kSamplePoints);
  const Vec3 extent = stick.mesh().bounds().Size();
  Eigen::Index axis = 0;
  extent.maxCoeff(&axis);
  std::vector<double> along;
  for (const Vec3& p : s) {
    EXPECT_LT(DistanceToSurface(stick.mesh(), p), 1e-12 * extent.norm()) << p.transpose();
    along.push_back(p[axis]);
  }
  std::sort(along.begin(), along.end());
  double largest_gap = 0;
  for (std::size_t k = 1; k < along.size(); ++k) {
    largest_gap = std::max(largest_gap, along[k] - along[k - 1]);
  }
  EXPECT_LT(largest_gap, 0.25 * extent[axis]);

  // Two boxes apart: every sample on the one holding triangle 0.
  Mesh far_box = shapes::Box(Vec3::Constant(0.02));
  std::vector<Vec3> v = far_box.vertices();
  for (Vec3& p : v) p.x() += 0.5;
  const GeometryModel two(Joined(shapes::Box(Vec3::Constant(0.02)),
                                 Mesh::FromArrays(std::move(v), far_box.triangles(), "far box"),
                                 "two boxes"));
  ASSERT_FALSE(two.sample_points().empty());
  for (const Vec3& p : two.sample_points()) EXPECT_LT(p.x(), 0.1) << p.transpose();
}

TEST(PointsEnclosedBy, SceneVerticesInsideTheProbeOfTheSampledComponentOnly) {
  const GeometryModel probe(shapes::Sphere(0.03, 3));
  ASSERT_FALSE(probe.interior().empty());
  // The scene: a torus (triangle 0's component) and a small box apart from
  // it. The probe overlaps the torus's tube and holds the box wholly.
  Mesh box = shapes::Box(Vec3::Constant(0.004));
  std::vector<Vec3> v = box.vertices();
  for (Vec3& p : v) p += Vec3(0.06, 0.0, 0.045);
  const GeometryModel scene(Joined(
      shapes::Torus(), Mesh::FromArrays(std::move(v), box.triangles(), "box"), "torus and box"));
  QueryScratch scratch;
  std::array<Vec3, GeometryModel::kSamplePoints> out;
  const Pose X_BA{Mat3::Identity(), Vec3(0.06, 0.0, 0.025)};  // over the tube, and the box
  const int n = PointsEnclosedBy(probe, X_BA, scene, out, &scratch);
  ASSERT_GT(n, 8);
  ASSERT_LE(n, GeometryModel::kSamplePoints);
  const Pose X_AB = X_BA.Inverse();
  for (int k = 0; k < n; ++k) {
    const Vec3& p = out[static_cast<std::size_t>(k)];
    // A vertex of the torus (|p.z| within its tube), inside the probe by
    // the exact test.
    EXPECT_LT(std::abs(p.z()), 0.021) << p.transpose();
    EXPECT_TRUE(std::any_of(scene.mesh().vertices().begin(), scene.mesh().vertices().end(),
                            [&](const Vec3& q) { return q == p; }));
    EXPECT_TRUE(PointInside(probe, X_AB * p, &scratch)) << p.transpose();
  }
  // Over the box alone: its component is not the one a containment test
  // looks at, so none of its vertices may count.
  const Pose X_box{Mat3::Identity(), Vec3(0.06, 0.0, 0.06)};
  EXPECT_EQ(PointsEnclosedBy(probe, X_box, scene, out, &scratch), 0);
  // An open probe has no inside cells.
  std::vector<Triangle> t = probe.mesh().triangles();
  t.pop_back();
  const GeometryModel holed(Mesh::FromArrays(probe.mesh().vertices(), std::move(t), "holed"));
  EXPECT_EQ(PointsEnclosedBy(holed, X_BA, scene, out, &scratch), 0);
}

// A closed probe against an open scene: only the probe's cells can cull a
// cold start, and the answers must be those of the exact start checks.
TEST(PointsEnclosedBy, ColdQueriesAgainstAnOpenSceneKeepTheirAnswersWithFewerSweeps) {
  const GeometryModel probe(shapes::Capsule(0.015, 0.03));
  std::vector<Triangle> t = shapes::Torus().triangles();
  t.erase(t.begin() + 7);  // a hole: the scene has no inside
  const GeometryModel scene(Mesh::FromArrays(shapes::Torus().vertices(), std::move(t), "holed"));
  ASSERT_FALSE(scene.closed());
  ASSERT_FALSE(probe.interior().empty());
  PenetrationRequest on;
  on.use_coherence = false;
  on.pdg_iteration_budget = 0;
  PenetrationRequest off = on;
  off.cold_interior_cull = false;
  std::mt19937_64 rng(5);
  std::uniform_int_distribution<std::size_t> vertex(0, scene.mesh().vertices().size() - 1);
  std::normal_distribution<double> normal;
  long sweeps_on = 0, sweeps_off = 0;
  int poses = 0;
  for (int k = 0; k < 80 && poses < 16; ++k) {
    const Eigen::Quaterniond q =
        Eigen::Quaterniond(normal(rng), normal(rng), normal(rng), normal(rng)).normalized();
    const Pose X_WA{q.toRotationMatrix(), scene.mesh().vertices()[vertex(rng)]};
    PdQueryData d_on, d_off;
    PenetrationResult t_on, t_off;
    ComputePdt(probe, X_WA, scene, Pose::Identity(), on, &d_on, &t_on);
    if (t_on.status == PdStatus::kSeparated) continue;
    ++poses;
    ComputePdt(probe, X_WA, scene, Pose::Identity(), off, &d_off, &t_off);
    ASSERT_EQ(t_on.status, t_off.status);
    EXPECT_EQ(t_on.translation_W, t_off.translation_W);
    sweeps_on += t_on.ccd_queries;
    sweeps_off += t_off.ccd_queries;
    PdgQueryData g_on, g_off;
    PenetrationResult r_on, r_off;
    ComputePdg(probe, X_WA, scene, Pose::Identity(), on, &g_on, &r_on);
    ComputePdg(probe, X_WA, scene, Pose::Identity(), off, &g_off, &r_off);
    ASSERT_EQ(r_on.status, r_off.status);
    EXPECT_EQ(r_on.sigma, r_off.sigma);
    EXPECT_EQ(r_on.X_WA_result.t, r_off.X_WA_result.t);
  }
  ASSERT_EQ(poses, 16);
  EXPECT_LT(sweeps_on, 0.6 * sweeps_off) << sweeps_on << " against " << sweeps_off;
}

}  // namespace
}  // namespace hapticpd::pd
