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

}  // namespace
}  // namespace hapticpd::pd
