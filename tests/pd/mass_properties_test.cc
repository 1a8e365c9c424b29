// Mass properties against closed forms, and invariance under rigid motion.
#include "pd/mass_properties.h"

#include <gtest/gtest.h>

#include <random>

#include "pd/shapes.h"
#include "tests/test_util.h"

namespace hapticpd::pd {
namespace {

TEST(MassProperties, BoxMatchesClosedForm) {
  const Vec3 h(0.1, 0.2, 0.3);
  const MassProperties mp = ComputeMassProperties(shapes::Box(h));
  const Vec3 s = 2 * h;
  const double V = s.prod();
  EXPECT_NEAR(mp.volume, V, 1e-15);
  EXPECT_LT(mp.p_MC.norm(), 1e-15);
  // Unit density: I_xx = V (b^2 + c^2) / 12.
  const Vec3 I(V * (s.y() * s.y() + s.z() * s.z()) / 12, V * (s.x() * s.x() + s.z() * s.z()) / 12,
               V * (s.x() * s.x() + s.y() * s.y()) / 12);
  EXPECT_NEAR(mp.principal_moments[0], I.minCoeff(), 1e-15);
  EXPECT_NEAR(mp.principal_moments[2], I.maxCoeff(), 1e-15);
  EXPECT_TRUE(mp.exact);
  EXPECT_NEAR(mp.X_MB.R.determinant(), 1.0, 1e-12);
}

TEST(MassProperties, SphereAndCylinderConvergeToClosedForm) {
  const double r = 0.05;
  const MassProperties s = ComputeMassProperties(shapes::Sphere(r, 5));
  const double Vs = 4.0 / 3.0 * M_PI * r * r * r;
  EXPECT_NEAR(s.volume / Vs, 1.0, 2e-3);
  EXPECT_NEAR(s.principal_moments[0] / (0.4 * Vs * r * r), 1.0, 4e-3);
  EXPECT_NEAR(s.principal_moments[2] / s.principal_moments[0], 1.0, 1e-3);

  const double h = 0.1;  // half length
  const MassProperties c = ComputeMassProperties(shapes::Cylinder(r, h, 256));
  const double Vc = M_PI * r * r * 2 * h;
  EXPECT_NEAR(c.volume / Vc, 1.0, 1e-3);
  const double Iz = 0.5 * Vc * r * r;
  const double Ix = Vc * (3 * r * r + 4 * h * h) / 12;
  // Principal moments ascending: the axis moment is the smallest here.
  EXPECT_NEAR(c.principal_moments[0] / Iz, 1.0, 2e-3);
  EXPECT_NEAR(c.principal_moments[2] / Ix, 1.0, 2e-3);
  // The smallest-moment principal axis is the cylinder axis (z).
  EXPECT_NEAR(std::abs(c.X_MB.R.col(0).z()), 1.0, 1e-9);
}

TEST(MassProperties, InvariantUnderRigidTransforms) {
  std::mt19937_64 rng(testing::TestSeed());
  std::uniform_real_distribution<double> u(-1, 1);
  const Mesh base = shapes::Hammer();
  const MassProperties m0 = ComputeMassProperties(base);
  for (int i = 0; i < 10; ++i) {
    const Quat q = Quat(u(rng), u(rng), u(rng), u(rng)).normalized();
    const Vec3 t(u(rng) * 10, u(rng) * 10, u(rng) * 10);
    const Pose X = Pose::FromQuaternion(q, t);
    const MassProperties m1 = ComputeMassProperties(base.Transformed(X));
    EXPECT_NEAR(m1.volume, m0.volume, 1e-12 * m0.volume);
    EXPECT_LT((m1.p_MC - X * m0.p_MC).norm(), 1e-10);
    EXPECT_LT((m1.principal_moments - m0.principal_moments).norm(),
              1e-9 * m0.principal_moments.norm());
    // Inertia tensor transforms as R I R^T.
    EXPECT_LT((m1.I_C_M - X.R * m0.I_C_M * X.R.transpose()).norm(), 1e-9 * m0.I_C_M.norm());
  }
}

TEST(MassProperties, OpenSurfaceFallsBackAndIsFlagged) {
  const std::vector<Vec3> v = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(1, 1, 0), Vec3(0, 1, 0)};
  const MassProperties mp =
      ComputeMassProperties(Mesh::FromArrays(v, {{0, 1, 2}, {0, 2, 3}}, "sq"));
  EXPECT_TRUE(mp.surface_fallback);
  EXPECT_FALSE(mp.exact);
  EXPECT_LT((mp.p_MC - Vec3(0.5, 0.5, 0)).norm(), 1e-12);
  EXPECT_TRUE(mp.principal_moments.allFinite());
}

TEST(MassProperties, ObjectNormMetricUsesPrincipalMoments) {
  const MassProperties mp = ComputeMassProperties(shapes::Box(Vec3(0.1, 0.2, 0.3)));
  const Mat6 M = ObjectNormMetric(mp);
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(M(i, i), 4 * mp.principal_moments[i] / mp.volume, 1e-15);
    EXPECT_EQ(M(3 + i, 3 + i), 1.0);
  }
}

// A mesh stretched by `e` along the unit direction d.
Mesh StretchedAlong(const Mesh& mesh, const Vec3& d, double e) {
  std::vector<Vec3> V = mesh.vertices();
  for (Vec3& v : V) v += e * d.dot(v) * d;
  return Mesh::FromArrays(V, mesh.triangles(), "stretched");
}

// The same axes up to their signs (which nothing downstream sees: the cold
// start sweeps along both signs, the object norm is quadratic).
double AxesApart(const Mat3& Ra, const Mat3& Rb) {
  return ((Ra.transpose() * Rb).cwiseAbs() - Mat3::Identity()).norm();
}

void ExpectProperRotation(const Mat3& R) {
  EXPECT_LT((R.transpose() * R - Mat3::Identity()).norm(), 1e-12);
  EXPECT_NEAR(R.determinant(), 1, 1e-12);
}

// Equal principal moments leave the eigensolver free to return any axes of
// their eigenspace; a change of the mesh far below float precision must not
// turn them (it turned a cube's by 55 degrees).
TEST(MassProperties, EqualMomentsGetAxesThatAChangeBelowPrecisionDoesNotTurn) {
  const Vec3 diagonal = Vec3(1, 1, 1).normalized();
  // Three equal moments: the file frame's axes.
  const Mesh cube = shapes::Box(Vec3(0.1, 0.1, 0.1));
  for (double e : {0.0, 1e-9, 1e-8}) {
    SCOPED_TRACE(e);
    const MassProperties mp = ComputeMassProperties(StretchedAlong(cube, diagonal, e));
    EXPECT_LT((mp.X_MB.R - Mat3::Identity()).norm(), 1e-12);
  }
  // Two equal moments (a square bar along a tilted axis): the distinct axis
  // (the smallest moment, axis 0) is the bar's; the other two stay put
  // under the change.
  const Pose X_tilt = Pose::FromQuaternion(
      Quat(Eigen::AngleAxisd(0.4, Vec3(1, -2, 0.5).normalized())), Vec3(0.3, -0.1, 0.2));
  const Mesh bar = shapes::Box(Vec3(0.1, 0.1, 0.4)).Transformed(X_tilt);
  const MassProperties base = ComputeMassProperties(bar);
  ExpectProperRotation(base.X_MB.R);
  EXPECT_NEAR(std::abs(base.X_MB.R.col(0).dot(X_tilt.R.col(2))), 1, 1e-12);
  for (const Vec3& d : {diagonal, Vec3(Vec3::UnitX()), Vec3(0.3, -0.8, 0.2).normalized()}) {
    const MassProperties mp = ComputeMassProperties(StretchedAlong(bar, d, 1e-9));
    ExpectProperRotation(mp.X_MB.R);
    EXPECT_LT(AxesApart(mp.X_MB.R, base.X_MB.R), 1e-6) << d.transpose();
  }
  // Distinct moments: the eigenvectors as they are (a tilted box's edges,
  // the longest edge's axis first: the smallest moment).
  const Mesh box = shapes::Box(Vec3(0.1, 0.2, 0.3)).Transformed(X_tilt);
  const MassProperties mp = ComputeMassProperties(box);
  ExpectProperRotation(mp.X_MB.R);
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(std::abs(mp.X_MB.R.col(k).dot(X_tilt.R.col(2 - k))), 1, 1e-12) << k;
  }
}

}  // namespace
}  // namespace hapticpd::pd
