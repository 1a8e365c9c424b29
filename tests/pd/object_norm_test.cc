// The object norm sigma(q0, q1) = (4/V)(Ixx v1^2 + Iyy v2^2 + Izz v3^2) + |t|^2
// (ObjectNormMetric, ObjectNormSquared, the PDg configuration chart) against
// its definition, the mean squared displacement of the body's points,
// integrated independently: a degree-2 tetrahedral quadrature over the signed
// tetrahedra (origin, triangle) of the mesh (exact for this quadratic
// integrand) and, as a cross-check of the quadrature itself, Monte Carlo
// sampling of a box with its exact inside test.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "pd/mass_properties.h"
#include "pd/pdg.h"
#include "pd/shapes.h"
#include "tests/pd/random_poses.h"
#include "tests/test_util.h"

namespace hapticpd::pd {
namespace {

using testing::RandomRotation;

// (1/V) integral over the solid of |X1 p - X0 p|^2, by the 4-point degree-2
// rule on each signed tetrahedron (o, a, b, c); o is any reference point.
double MeanSquaredDisplacementSolid(const Mesh& mesh, const Pose& X0, const Pose& X1) {
  constexpr double kA = 0.5854101966249685, kB = 0.1381966011250105;
  const Vec3 o = mesh.bounds().Center();
  double integral = 0, volume = 0;
  for (const Triangle& t : mesh.triangles()) {
    const Vec3 a = mesh.vertices()[t[0]], b = mesh.vertices()[t[1]], c = mesh.vertices()[t[2]];
    const double vol = (a - o).dot((b - o).cross(c - o)) / 6;
    const Vec3 corners[4] = {o, a, b, c};
    double sum = 0;
    for (int k = 0; k < 4; ++k) {
      Vec3 p = Vec3::Zero();
      for (int j = 0; j < 4; ++j) p += (j == k ? kA : kB) * corners[j];
      sum += 0.25 * (X1 * p - X0 * p).squaredNorm();
    }
    integral += vol * sum;
    volume += vol;
  }
  return integral / volume;
}

// (1/Area) integral over the surface of |X1 p - X0 p|^2 (edge-midpoint rule,
// exact for quadratics on triangles).
double MeanSquaredDisplacementSurface(const Mesh& mesh, const Pose& X0, const Pose& X1) {
  double integral = 0, area = 0;
  for (const Triangle& t : mesh.triangles()) {
    const Vec3 a = mesh.vertices()[t[0]], b = mesh.vertices()[t[1]], c = mesh.vertices()[t[2]];
    const double ar = 0.5 * (b - a).cross(c - a).norm();
    double sum = 0;
    for (const Vec3& p : {Vec3(0.5 * (a + b)), Vec3(0.5 * (b + c)), Vec3(0.5 * (c + a))}) {
      sum += (X1 * p - X0 * p).squaredNorm() / 3;
    }
    integral += ar * sum;
    area += ar;
  }
  return integral / area;
}

// A tetrahedron with no symmetry: principal axes are not the mesh axes.
Mesh IrregularTetrahedron() {
  return Mesh::FromArrays(
      {Vec3(0, 0, 0), Vec3(0.3, 0.02, -0.01), Vec3(0.05, 0.12, 0.03), Vec3(0.04, 0.03, 0.07)},
      {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}}, "tet");
}

struct NormShape {
  std::string name;
  Mesh mesh;
};

std::vector<NormShape> Shapes() {
  std::vector<NormShape> v;
  v.push_back({"box", shapes::Box(Vec3(0.1, 0.02, 0.05))});
  // A box whose principal axes are rotated off the mesh axes and whose
  // centre of mass is far from the mesh origin.
  v.push_back({"rotated-box", shapes::Box(Vec3(0.1, 0.02, 0.05))
                                  .Transformed(Pose::FromQuaternion(Quat(0.9, 0.2, -0.3, 0.1),
                                                                    Vec3(1, -2, 0.5)))});
  v.push_back({"tetrahedron", IrregularTetrahedron()});
  v.push_back({"stick", shapes::Stick()});
  v.push_back({"torus", shapes::Torus(0.06, 0.02, 24, 12)});
  v.push_back({"capsule", shapes::Capsule(0.02, 0.04, 12, 4)});
  return v;
}

// Relative poses: small, moderate and near-half-turn rotations, with and
// without translation.
std::vector<Pose> RelativeMotions(std::mt19937_64& rng) {
  std::normal_distribution<double> n(0, 1);
  std::vector<Pose> v;
  for (double angle : {0.0, 1e-3, 0.3, 1.5, 3.0, M_PI - 1e-6, M_PI}) {
    for (double shift : {0.0, 0.07}) {
      const Vec3 axis = Vec3(n(rng), n(rng), n(rng)).normalized();
      const Vec3 t = Vec3(n(rng), n(rng), n(rng)) * shift;
      v.push_back(Pose{Eigen::AngleAxisd(angle, axis).toRotationMatrix(), t});
    }
  }
  return v;
}

TEST(ObjectNorm, EqualsMeanSquaredDisplacementOverTheSolid) {
  std::mt19937_64 rng(testing::TestSeed());
  std::normal_distribution<double> n(0, 1);
  for (const NormShape& s : Shapes()) {
    SCOPED_TRACE(s.name);
    const MassProperties mp = ComputeMassProperties(s.mesh);
    ASSERT_TRUE(mp.exact);
    for (const Pose& D : RelativeMotions(rng)) {
      const Pose X0 = Pose::FromQuaternion(RandomRotation(rng), Vec3(n(rng), n(rng), n(rng)));
      // The relative motion acts about the world origin: it rotates and
      // moves the centre of mass at once.
      const Pose X1 = D * X0;
      const double reference = MeanSquaredDisplacementSolid(s.mesh, X0, X1);
      const Vec6 z = RelativeConfiguration(mp, X0, X1);
      const double sigma = ObjectNormSquared(mp, z);
      EXPECT_NEAR(sigma, reference, 1e-9 * reference + 1e-15);
      // The same through the 6x6 metric.
      EXPECT_NEAR(z.dot(ObjectNormMetric(mp) * z), reference, 1e-9 * reference + 1e-15);
      // The chart is invertible: z gives back X1 (to about sqrt(machine
      // epsilon) at a half turn, where w = sqrt(1 - |v|^2) loses digits).
      const Pose X1b = PoseAtConfiguration(mp, X0, z);
      EXPECT_LT((X1b.R - X1.R).norm(), 2e-7);
      EXPECT_LT((X1b.t - X1.t).norm(), 2e-7 * (1 + X1.t.norm()));
    }
  }
}

TEST(ObjectNorm, QuadratureAgreesWithMonteCarloOnABox) {
  // Cross-check of the reference integration: uniform samples of the box.
  const Vec3 h(0.1, 0.02, 0.05);
  const Mesh box = shapes::Box(h);
  std::mt19937_64 rng(testing::TestSeed() + 3);
  std::uniform_real_distribution<double> u(-1, 1);
  const Pose X0 = Pose::FromQuaternion(RandomRotation(rng), Vec3(0.3, 0.1, -0.2));
  const Pose X1 = Pose{Eigen::AngleAxisd(0.8, Vec3(1, 2, 3).normalized()).toRotationMatrix(),
                       Vec3(0.02, -0.05, 0.01)} *
                  X0;
  const int samples = 200000;
  double sum = 0;
  for (int i = 0; i < samples; ++i) {
    const Vec3 p(u(rng) * h.x(), u(rng) * h.y(), u(rng) * h.z());
    sum += (X1 * p - X0 * p).squaredNorm();
  }
  const double mc = sum / samples;
  const double quad = MeanSquaredDisplacementSolid(box, X0, X1);
  EXPECT_NEAR(mc, quad, 0.01 * quad);
  const MassProperties mp = ComputeMassProperties(box);
  EXPECT_NEAR(ObjectNormSquared(mp, RelativeConfiguration(mp, X0, X1)), mc, 0.01 * mc);
}

TEST(ObjectNorm, OpenSheetAveragesOverItsSurface) {
  // No enclosed volume: the norm is the mean over the area (it used to divide
  // the shell inertia by a zero volume).
  const Mesh sheet =
      Mesh::FromArrays({Vec3(0, 0, 0), Vec3(0.2, 0, 0), Vec3(0.2, 0.1, 0), Vec3(0, 0.1, 0)},
                       {{0, 1, 2}, {0, 2, 3}}, "sheet");
  const MassProperties mp = ComputeMassProperties(sheet);
  ASSERT_TRUE(mp.surface_fallback);
  EXPECT_TRUE(ObjectNormMetric(mp).allFinite());
  std::mt19937_64 rng(testing::TestSeed() + 5);
  for (const Pose& D : RelativeMotions(rng)) {
    const Pose X1 = D;
    const double reference = MeanSquaredDisplacementSurface(sheet, Pose::Identity(), X1);
    EXPECT_NEAR(ObjectNormSquared(mp, RelativeConfiguration(mp, Pose::Identity(), X1)), reference,
                1e-9 * reference + 1e-15);
  }
}

TEST(ObjectNorm, InwardWoundMeshGivesAFiniteMetric) {
  const Mesh box = shapes::Box(Vec3(0.1, 0.2, 0.3));
  std::vector<Triangle> flipped = box.triangles();
  for (Triangle& t : flipped) std::swap(t[1], t[2]);
  const MassProperties mp =
      ComputeMassProperties(Mesh::FromArrays(box.vertices(), flipped, "inward"));
  const Mat6 M = ObjectNormMetric(mp);
  EXPECT_TRUE(M.allFinite());
  for (int i = 0; i < 3; ++i) EXPECT_GT(M(i, i), 0);
}

TEST(ObjectNorm, ChartRoundTripsThroughAHalfTurn) {
  const MassProperties mp = ComputeMassProperties(IrregularTetrahedron());
  std::mt19937_64 rng(testing::TestSeed() + 9);
  for (double angle : {M_PI - 1e-9, M_PI, M_PI + 1e-9}) {
    const Pose X0 = Pose::FromQuaternion(RandomRotation(rng), Vec3(0.1, 0.2, 0.3));
    const Pose X1 =
        Pose{Eigen::AngleAxisd(angle, Vec3(0.3, -1, 0.2).normalized()).toRotationMatrix(),
             Vec3(0.01, 0, 0)} *
        X0;
    const Vec6 z = RelativeConfiguration(mp, X0, X1);
    EXPECT_TRUE(z.allFinite());
    EXPECT_LE(z.head<3>().norm(), 1 + 1e-12);
    const Pose X1b = PoseAtConfiguration(mp, X0, z);
    EXPECT_LT((X1b.R - X1.R).norm(), 1e-7);
    EXPECT_LT((X1b.t - X1.t).norm(), 1e-7);
  }
}

}  // namespace
}  // namespace hapticpd::pd
